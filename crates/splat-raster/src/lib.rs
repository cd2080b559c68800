//! splat-raster: the differentiable CPU Gaussian-splatting rasteriser.
//!
//! This crate is the bottom of the workspace's dependency graph: the types that the
//! volume path tracer, the cache and the stochastic ray tracer must agree on live here.
//!
//! - [`camera`]: the pinhole camera and the pixel convention every crate shares.

pub mod camera;

pub use camera::{Camera, CameraError};
