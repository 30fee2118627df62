//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong in `sartor-dataset`. Each variant names the file (when there is
/// one) and the fault.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A fault reported by `sartor-core` (mesh, skinning, tensor file, ...).
    #[error(transparent)]
    Core(#[from] sartor_core::Error),
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A file is malformed (bad JSON, wrong tensor shape, hash mismatch, ...).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An in-memory value breaks an invariant (sizes, finiteness, splits, ...).
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
    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            message: message.into(),
        }
    }

    #[allow(dead_code)]
    pub(crate) fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}
