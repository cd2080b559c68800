//! What can go wrong when making, loading or saving a cache.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    #[error("cache settings: {0}")]
    Config(String),
    #[error("cache initialisation: {0}")]
    Init(String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error(transparent)]
    Ply(#[from] splat_raster::io::IoError),
}

pub type Result<T> = std::result::Result<T, CacheError>;
