//! splat-raster: the differentiable CPU Gaussian-splatting rasteriser.
//!
//! This crate is the bottom of the workspace's dependency graph: the types that the volume
//! path tracer, the cache and the stochastic ray tracer must agree on live here.
//!
//! - [`camera`]: the pinhole camera and the pixel convention every crate shares.
//! - [`cloud`]: the Gaussian cloud, structure of arrays.
//! - [`project`]: EWA projection of one Gaussian, and its exact adjoint.
//! - [`raster`]: tiles, depth order, front-to-back compositing, and the backward pass.
//! - [`sh`]: spherical harmonics (degree 0-3) and their gradients.
//! - [`real`]: the f32/f64 scalar the kernels are generic over.

pub mod camera;
pub mod cloud;
pub mod project;
pub mod raster;
pub mod real;
pub mod reference;
pub mod sh;

pub use camera::{Camera, CameraError};
pub use cloud::{CloudGradients, ColorModel, GaussianCloud};
pub use project::LowPass;
pub use raster::{PixelGrads, RasterConfig, RenderOutput, backward, render};
