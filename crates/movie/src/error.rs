//! What can go wrong making a movie.

use std::path::PathBuf;

/// A movie that could not be made (or not all of it); the frames already written stay.
#[derive(Debug, thiserror::Error)]
pub enum MovieError {
    /// The movie's settings, refused before any work.
    #[error("{0}")]
    Invalid(String),
    /// A file or folder of the movie.
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    #[error(transparent)]
    Session(#[from] render_session::SessionError),
    #[error(transparent)]
    Image(#[from] hdr_image::ImageError),
    #[error("denoising a frame: {0}")]
    Denoise(#[from] denoise::DenoiseError),
    #[error(transparent)]
    Path(#[from] render_session::camera_path::PathError),
    /// The video encoder is missing or failed; the frames are written.
    #[error("{0}")]
    Video(String),
}

pub type Result<T, E = MovieError> = std::result::Result<T, E>;

impl MovieError {
    /// An error about `path`.
    pub fn file(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::File {
            path: path.into(),
            message: message.into(),
        }
    }
}
