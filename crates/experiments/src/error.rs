//! The runner's one error type. A message names the file, the table or key, or the part of the
//! run (a method, a fly-through, a unit), then the fault and what was expected, so that the
//! program prints it as it is. What a caller acts on has a variant of its own: an
//! [`Error::Interrupted`] run is resumed, not reported as a failure.
//!
//! As in volume-pt, a wrapped fault's text is in the message and not also its `source()`: a
//! caller printing the chain (anyhow's `{:#}`) would show it twice.

use std::path::{Path, PathBuf};

/// Why an experiment could not be read, run, merged or written.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file or folder the run reads or writes: its path and the fault.
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    /// What the experiment asks for is not possible: the message names the table or key.
    #[error("{0}")]
    Invalid(String),
    /// A fault inside a named part of the experiment (`method `a``, `flythrough `orbit``,
    /// `unit 3`): the part, then the fault.
    #[error("{part}: {}", with_sources(error.as_ref()))]
    Within { part: String, error: Box<Error> },
    /// Reading or rendering the scene.
    #[error(transparent)]
    Scene(#[from] volume_pt::Error),
    /// A method's render session (its cache and frames).
    #[error(transparent)]
    Session(#[from] render_session::SessionError),
    /// The denoised twins.
    #[error(transparent)]
    Denoise(#[from] denoise::DenoiseError),
    /// A reference or an image read or written.
    #[error(transparent)]
    Image(#[from] hdr_image::ImageError),
    /// A cache's settings or files.
    #[error(transparent)]
    Cache(#[from] gs_cache::CacheError),
    /// A report file written atomically.
    #[error(transparent)]
    Write(#[from] render_base::WriteError),
    /// A fly-through's camera path.
    #[error(transparent)]
    CameraPath(#[from] crate::camera_path::PathError),
    /// A report or shard file written as JSON (a fault here is a bug).
    #[error("writing JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A table formatted into text (a fault here is a bug).
    #[error("formatting a table: {0}")]
    Format(#[from] std::fmt::Error),
    /// The run's control was cancelled before every unit was measured. The runner's caller
    /// ([`crate::run_experiment_resumable`]) keeps what was measured and answers
    /// [`Error::Interrupted`].
    #[error("the experiment was interrupted between units")]
    Cancelled,
    /// The run stopped between units and its measured units are on disk, to go on from.
    #[error(transparent)]
    Interrupted(#[from] Interrupted),
}

/// An experiment stopped between units (Ctrl-C): the units measured so far were written to
/// `file`, which `--resume` reads to go on from there.
#[derive(Debug, thiserror::Error)]
#[error(
    "interrupted after {done} of {total} units; the measured units are in {}: go on with \
     `gscache experiment {} --resume {}`",
    file.display(),
    experiment.display(),
    file.display()
)]
pub struct Interrupted {
    pub done: usize,
    pub total: usize,
    pub file: PathBuf,
    pub experiment: PathBuf,
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A fault of the file or folder at `path`.
    pub(crate) fn file(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::File {
            path: path.into(),
            message: message.into(),
        }
    }

    /// An operating-system fault while `doing` something to `path` ("cannot read").
    pub(crate) fn io(path: &Path, doing: &str, error: std::io::Error) -> Self {
        Error::file(path, format!("{doing}: {error}"))
    }

    /// This error inside `part` of the experiment.
    pub(crate) fn within(self, part: impl Into<String>) -> Self {
        Error::Within {
            part: part.into(),
            error: Box::new(self),
        }
    }
}

/// An error's message followed by its sources' (`a: b: c`), as anyhow's `{:#}` prints a chain:
/// a wrapped error keeps the detail its sources hold.
fn with_sources(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        text.push_str(": ");
        text.push_str(&e.to_string());
        source = e.source();
    }
    text
}

/// [`Error::within`] for a result: `result.within(|| format!("method `{name}`"))`.
pub(crate) trait Within<T> {
    fn within(self, part: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: Into<Error>> Within<T> for std::result::Result<T, E> {
    fn within(self, part: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| e.into().within(part()))
    }
}

/// Returns an [`Error::Invalid`] with a formatted message (the runner's `bail!`).
macro_rules! refuse {
    ($($message:tt)*) => {
        return Err($crate::error::Error::Invalid(format!($($message)*)))
    };
}
pub(crate) use refuse;
