//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong while training, checkpointing or exporting.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A checkpoint or its state file is malformed or belongs to another run.
    #[error("{path}: {message}")]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A configuration or input does not fit the data.
    #[error("{what}: {message}")]
    Invalid {
        /// The thing at fault.
        what: &'static str,
        /// What is wrong.
        message: String,
    },
    /// Training produced a non-finite loss.
    #[error("{model}: the loss became {loss} in epoch {epoch} (diverged)")]
    Diverged {
        /// The model.
        model: String,
        /// The epoch (1-based).
        epoch: usize,
        /// The loss.
        loss: f64,
    },
    /// The training data.
    #[error(transparent)]
    Dataset(#[from] sartor_dataset::Error),
    /// The exported model.
    #[error(transparent)]
    Runtime(#[from] sartor_runtime::Error),
    /// The body model.
    #[error(transparent)]
    Core(#[from] sartor_core::Error),
}

impl Error {
    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            message: message.into(),
        }
    }

    pub(crate) fn checkpoint(path: &std::path::Path, message: impl Into<String>) -> Self {
        Self::Checkpoint {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// The crate's result type.
pub type Result<T> = std::result::Result<T, Error>;
