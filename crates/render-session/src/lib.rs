//! render-session: one object that holds a scene, a camera, a radiance cache and an
//! accumulating image, takes edits, and renders the next frame.
//!
//! Every caller renders through it: `gscache render`, the experiment runner (methods,
//! fly-throughs, ablations, shards), the benches, Python's `Cache`, and the viewer. So there is
//! one frame loop, one rule for which samples a frame takes, and one way to build a cache.
//!
//! Read it in this order:
//! - [`session`]: [`Session`]: `next_frame`, `warm_up`, the image, saving the cache.
//! - [`sampling`]: the one sampling rule (frame `k` of `s` samples per pixel renders sample
//!   indices `k*s .. (k+1)*s` with the scene's seed) and the checked arithmetic behind it.
//! - [`cache`]: [`CacheChoice`] (what to build) and [`Cache`] (none, the Gaussian cache, or the
//!   neural cache behind feature `nrc`): one type above volume-pt's seam.
//! - [`edit`]: [`Edit`], and what each invalidates ([`Invalidated`]).
//! - [`report`]: [`FrameReport`], the time of each part of a frame.
//! - [`camera_path`]: camera paths: the warm-up's orbit, a movie's turntable, key frames.
//!
//! Cancellation and progress go through [`Control`] (from render-base).

#![forbid(unsafe_code)]

pub mod cache;
pub mod camera_path;
pub mod edit;
pub mod error;
pub mod report;
pub mod sampling;
pub mod session;

pub use cache::{Cache, CacheChoice};
pub use camera_path::orbit;
pub use edit::{CacheEffect, Edit, Invalidated};
pub use error::{Result, SessionError};
pub use render_base::Control;
pub use report::FrameReport;
pub use session::{Accumulation, ImageBudget, ImageReport, Session};
