//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong in `sartor-dataset`. File, format and invariant faults are
/// sartor-core's: they name the file, or the value, and the fault.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A fault of a file or a value: I/O, a malformed file (bad JSON, wrong tensor shape, hash
    /// mismatch), or an in-memory value that breaks an invariant (sizes, finiteness, splits).
    #[error(transparent)]
    Core(#[from] sartor_core::Error),
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A value of kind `what` breaks an invariant.
    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Core(sartor_core::Error::invalid(what, message))
    }

    /// File `path` is malformed.
    pub(crate) fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Core(sartor_core::Error::format(path, message))
    }

    /// An I/O error on `path`.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Core(sartor_core::Error::io(path, source))
    }
}
