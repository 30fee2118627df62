//! The wrapper's error: the lower crates' errors as they are (they name the file and the
//! fault), plus the wrapper's own faults (a missing file, a bad argument from the page).

/// Errors of the wrapper. On the page each becomes a JavaScript `Error` with this message.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A body, phenotype, motion or BVH fault (sartor-core's and sartor-motion's error).
    #[error(transparent)]
    Core(#[from] sartor_core::Error),
    /// A garment model or binding fault (sartor-runtime's error).
    #[error(transparent)]
    Runtime(#[from] sartor_runtime::Error),
    /// A file the page should have given is missing.
    #[error(
        "missing file {name:?} (the page gives the model folder's and the body folder's files by these names: {expected})"
    )]
    MissingFile {
        /// The file's name.
        name: String,
        /// The names expected.
        expected: String,
    },
    /// A bad argument: the message names it and the fault.
    #[error("{what}: {message}")]
    Invalid {
        /// What was bad.
        what: &'static str,
        /// Why.
        message: String,
    },
}

impl Error {
    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            message: message.into(),
        }
    }
}

/// The wrapper's result.
pub type Result<T> = std::result::Result<T, Error>;
