//! The one error type of volume-pt. Every variant names the file (when there is one), the
//! fault, and what was expected, so the program can print it as it is.

use std::path::PathBuf;

/// Why a volume, scene, transfer function or output could not be read, built or written.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The OS error is in the message, and not also the error's source: a caller printing
    /// the chain (`{:#}`) would show it twice.
    #[error("{path}: cannot read: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("{path}: scene: {message}")]
    Scene { path: PathBuf, message: String },
    #[error("transfer function: {0}")]
    TransferFunction(String),
    #[error("{0}")]
    Invalid(String),
}

impl Error {
    pub(crate) fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            error: source,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
