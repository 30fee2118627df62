//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong while evaluating. Errors of the crates below are wrapped as
/// they are (they name their file and fault); [`Error::Context`] adds what was being done.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A fault of the geometry core (body model, mesh, tensor file, ...).
    #[error(transparent)]
    Core(#[from] sartor_core::Error),
    /// A fault of the simulator or a garment.
    #[error(transparent)]
    Cloth(#[from] sartor_cloth::Error),
    /// A fault of the dataset or the simulation folder.
    #[error(transparent)]
    Dataset(#[from] sartor_dataset::Error),
    /// A fault of the runtime (model, binding, kernels).
    #[error(transparent)]
    Runtime(#[from] sartor_runtime::Error),
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// An I/O error whose file a [`Error::Context`] around it names.
    #[error(transparent)]
    UnnamedIo(#[from] std::io::Error),
    /// JSON that could not be written or read; a [`Error::Context`] names the file.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A safetensors file that could not be written or read; a [`Error::Context`] names it.
    #[error(transparent)]
    Safetensors(#[from] safetensors::SafeTensorError),
    /// A report or plot could not be written (JSON, PNG/SVG drawing).
    #[error("{}: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// An input breaks an expectation (sizes, missing sequences, bad arguments).
    #[error("{0}")]
    Invalid(String),
    /// What was being done when `source` happened.
    #[error("{context}: {source}")]
    Context {
        /// What was being done.
        context: String,
        /// The fault.
        source: Box<Error>,
    },
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

crate::context_error!();

pub(crate) use crate::{bail, ensure};
