//! What can go wrong in a session.

/// A session's error: building or training a cache, or a request it cannot honour.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    Cache(#[from] gs_cache::CacheError),
    #[error(transparent)]
    Volume(#[from] volume_pt::Error),
    #[error(transparent)]
    Image(#[from] hdr_image::ImageError),
    /// The neural cache's settings were refused.
    #[error("neural cache: {0}")]
    Neural(String),
    /// A request the session refuses (the message names the field and what was expected).
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T, E = SessionError> = std::result::Result<T, E>;
