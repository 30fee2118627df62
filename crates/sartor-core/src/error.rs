//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong in `sartor-core`, and in the crates built directly on it that
/// read and check files of the same kinds (`sartor-motion`, `sartor-import`, `sartor-mcap`). Each variant names the file (when there is
/// one) and the fault, so a user can fix the input.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A text file has a fault at a given line (1-based).
    #[error("{}:{line}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A file is malformed as a whole (missing tensor, wrong shape, bad JSON field, ...).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An in-memory value breaks an invariant (a mesh, a pose, a shape vector, ...).
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
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }

    /// A fault at a 1-based `line` of a text file.
    pub fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }

    /// A file malformed as a whole.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// An in-memory value that breaks an invariant.
    pub fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            message: message.into(),
        }
    }

    /// Attach a file to an in-memory validation error (e.g. a mesh that failed validation
    /// after being parsed from that file).
    pub fn in_file(self, path: impl Into<PathBuf>) -> Self {
        match self {
            Self::Invalid { what, message } => Self::Format {
                path: path.into(),
                message: format!("invalid {what}: {message}"),
            },
            other => other,
        }
    }
}
