//! The crate's one error type.

use std::path::PathBuf;

use nalgebra::Vector3;

/// Everything that can go wrong in `sartor-runtime`. File faults name the file; call faults name
/// the argument.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading a file or a tensor failed (I/O, not a safetensors file, missing tensor, wrong
    /// dtype or shape, non-finite value); the message names the file.
    #[error(transparent)]
    Core(#[from] sartor_core::Error),
    /// A model file is malformed (bad JSON, unknown field, size mismatch, hash mismatch, ...).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file at fault.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A slice passed to a kernel has the wrong length.
    #[error("{what}: expected length {expected}, got {got}")]
    Size {
        /// The argument.
        what: &'static str,
        /// The length the kernel needs.
        expected: usize,
        /// The length it was given.
        got: usize,
    },
    /// An input (or a result) holds a NaN or an infinity.
    #[error("{what}: non-finite value at index {index}")]
    NonFinite {
        /// The argument or result.
        what: &'static str,
        /// Index of the first non-finite value.
        index: usize,
    },
    /// An in-memory value breaks an invariant.
    #[error("invalid {what}: {message}")]
    Invalid {
        /// What kind of value.
        what: &'static str,
        /// What is wrong.
        message: String,
    },
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            message: message.into(),
        }
    }

    /// Attach a file to an in-memory validation error (a model that failed validation after
    /// being read from that file).
    pub fn in_file(self, path: impl Into<PathBuf>) -> Self {
        match self {
            Self::Invalid { what, message } => Self::Format {
                path: path.into(),
                message: format!("invalid {what}: {message}"),
            },
            Self::Size {
                what,
                expected,
                got,
            } => Self::Format {
                path: path.into(),
                message: format!("{what}: expected size {expected}, got {got}"),
            },
            other => other,
        }
    }
}

/// Check a slice length.
pub(crate) fn check_len(what: &'static str, got: usize, expected: usize) -> Result<()> {
    if got == expected {
        Ok(())
    } else {
        Err(Error::Size {
            what,
            expected,
            got,
        })
    }
}

crate::kernels::widest_where_present! {
    /// The largest `|v|` of `values` as bits (0 for none); built for the widest vectors present (the
    /// baseline x86-64 target has no vector unsigned maximum).
    fn largest_magnitude_bits(values: &[f32]) -> u32 {
        values
            .iter()
            .map(|v| v.to_bits() & 0x7fff_ffff)
            .max()
            .unwrap_or(0)
    }
}

/// Check that every coordinate of `points` is finite (`index`: into `x, y, z, x, …`).
pub(crate) fn check_finite_points(what: &'static str, points: &[Vector3<f32>]) -> Result<()> {
    for (i, p) in points.iter().enumerate() {
        if let Some(k) = p.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                what,
                index: 3 * i + k,
            });
        }
    }
    Ok(())
}

/// Check that every value is finite.
pub(crate) fn check_finite(what: &'static str, values: &[f32]) -> Result<()> {
    // One pass without an early exit first (it vectorises; `position` does not): the largest
    // magnitude's bits are below those of infinity exactly when every value is finite.
    let largest = largest_magnitude_bits(values);
    if largest < f32::INFINITY.to_bits() {
        return Ok(());
    }
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(Error::NonFinite { what, index }),
    }
}
