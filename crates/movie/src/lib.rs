//! movie: a scientist's fly-through or turntable movie of a volume, from one render session.
//!
//! A movie is N frames along a camera path (a turntable about the scene's up, or key frames),
//! each an image of its own made by any method (NEE, the Gaussian or the neural cache, the
//! caches warmed up along the path first), of a fixed sample count or a time budget, optionally
//! denoised. The frames go into a folder as numbered EXR and PNG files with a table of what
//! each took; a video is encoded from them by ffmpeg; with references, each frame's error and
//! flicker and the movie's ColorVideoVDP JOD say how steady it is.
//!
//! An interrupted movie keeps every finished frame, and resuming goes on from the first frame
//! missing, bit for bit: a frame's samples are fixed by its index and its passes (the table
//! records them), and a cache is brought to the same state by rendering its earlier frames
//! again (its state is a function of them; NEE skips them).
//!
//! Read it in this order:
//! - [`spec`]: [`MovieSpec`]: frames, rate, path, budget, warm-up, denoising, references.
//! - [`folder`]: the movie's folder: its manifest, frame files and table, what a resume finds;
//!   a movie's parts (frame ranges made by several processes) and their merge.
//! - [`render`]: [`render_movie`], the one loop: warm-up, resume, frames, references.
//! - [`quality`]: references per frame, each frame's error and flicker, the movie's JOD.
//! - [`video`]: encoding the frames with ffmpeg.

#![forbid(unsafe_code)]

pub mod error;
pub mod folder;
pub mod quality;
pub mod render;
pub mod spec;
pub mod video;

pub use error::{MovieError, Result};
pub use folder::{FrameRecord, MovieFolder, Part, merge_parts};
pub use render::{MovieSummary, Progress, render_movie};
pub use spec::{DenoiseSpec, FrameBudget, MoviePath, MovieSpec};
pub use video::{VideoFormat, encode_video, ffmpeg_from_env};
