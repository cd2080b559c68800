//! viewer: `gscache view`, the render session in a browser. A scientist orbits the volume, edits
//! the transfer function, moves a light and switches between plain path tracing and the caches,
//! and the image refines while the view is still.
//!
//! - [`protocol`]: the messages between page and server, their bounds, and each edit checked as
//!   the scene file's settings are.
//! - [`worker`]: the render thread: it owns the [`render_session::Session`] (the one frame loop),
//!   applies edits between frames, renders at the page's size, and hands each frame to be shown.
//! - [`display`]: what is shown: one publisher of frames (the latest wins, so a slow client
//!   never holds the rendering back) and the filter thread that denoises them beside the
//!   rendering, abandoning a still image's run the moment the view changes.
//! - [`server`]: HTTP and WebSocket on axum: the page, a token on every request, the Origin
//!   checked, a bound on clients and message sizes, Ctrl-C stopping it cleanly.
//! - [`connections`]: accepting connections on hyper's HTTP/1 with a header timeout and a cap,
//!   so that idle or slow sockets cannot hold the viewer.
//! - [`save`]: the image (EXR + PNG), the scene with every edit (TOML that `gscache render`
//!   renders the same way) and the Gaussian cache (PLY), into the output folder only.
//! - The page (`page/`): plain HTML, CSS and JavaScript, embedded in the binary; no build step.
//!
//! It listens on 127.0.0.1 unless told otherwise; the URL it prints carries a random token that
//! every request must present, as Jupyter's does.

#![forbid(unsafe_code)]

pub mod connections;
pub mod display;
pub mod protocol;
pub mod save;
pub mod server;
pub mod worker;

pub use connections::Limits;
pub use server::{ServeOptions, Viewer, serve};
pub use worker::{DenoiseStart, Denoising, Resolution};

/// Errors of the viewer, naming what failed.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("{0}")]
    Session(#[from] render_session::SessionError),
    #[error("cannot listen on {address}: {source}")]
    Bind {
        address: String,
        source: std::io::Error,
    },
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("{0}")]
    Invalid(String),
    #[error("--output {}: {message}", path.display())]
    Output {
        path: std::path::PathBuf,
        message: String,
    },
}

pub type Result<T> = std::result::Result<T, ViewerError>;
