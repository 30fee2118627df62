//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong in an experiment's stages. Errors of the crates below are
/// wrapped as they are (they name their file and fault); [`Error::Context`] adds what was being
/// done.
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
    /// A fault of training or export (burn).
    #[error(transparent)]
    Model(#[from] sartor_model::Error),
    /// A fault of an evaluation or a benchmark.
    #[error(transparent)]
    Eval(#[from] sartor_eval::Error),
    /// An experiment config is malformed: the file, the 1-based line and the fault (an unknown
    /// key is named).
    #[error("{}: {message}", location(path, *line))]
    Config {
        /// The config file.
        path: PathBuf,
        /// 1-based line (0 when the fault is not at one place).
        line: usize,
        /// What is wrong.
        message: String,
    },
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

/// `file:line`, or `file` when the line is 0.
fn location(path: &std::path::Path, line: usize) -> String {
    if line == 0 {
        path.display().to_string()
    } else {
        format!("{}:{line}", path.display())
    }
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

sartor_eval::context_error!();

pub(crate) use sartor_eval::{bail, ensure};
