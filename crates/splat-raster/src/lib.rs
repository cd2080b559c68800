//! splat-raster: the differentiable CPU Gaussian-splatting rasteriser.
//!
//! This crate is the bottom of the workspace's dependency graph: the types that the volume
//! path tracer, the cache and the stochastic ray tracer must agree on live here.
//!
//! - [`camera`]: the pinhole camera and the pixel convention every crate shares.
//! - [`cloud`]: the Gaussian cloud, structure of arrays.
//! - [`io`]: 3DGS PLY (read, write) and `.splat` (read).
//! - [`project`]: EWA projection of one Gaussian, and its exact adjoint.
//! - `project_lanes`: the same projection and adjoint, 8 or 4 Gaussians at a time in SIMD lanes.
//! - [`raster`]: tiles, front-to-back compositing, and the backward pass.
//! - [`depth_sort`]: the front-to-back order of a list of depths (a radix sort), which the
//!   stochastic ray tracer's camera grid shares.
//! - [`simd`]: the per-tile kernels across pixels in SIMD lanes, and the choice of lane width.
//! - [`lanes`]: fixed-width f32 lanes and a vector `exp` with a tested error bound.
//! - [`sh`]: spherical harmonics (degree 0-3) and their gradients.
//! - [`train`]: one training step (render, loss, backward, AdamW).
//! - [`stochastic`]: sorting-free stochastic splatting (the Vulkan Gaussian-splatting sample's
//!   stochastic modes, section 1).
//! - [`random`]: stateless hashing for per-fragment random decisions.
//! - [`loss`]: HDR (the GSCache paper's Eq. 4), L1 and L2 losses with masks.
//! - [`adamw`]: the fused AdamW step over the parameter arrays.
//! - [`reference`](mod@reference): a brute-force compositor the tiled one is tested against.
//! - [`real`]: the f32/f64 scalar the kernels are generic over.

pub mod adamw;
/// The camera lives in render-base (every renderer shares it); re-exported here.
pub use render_base::camera;
pub mod cloud;
pub mod depth_sort;
pub mod io;
pub mod lanes;
pub mod loss;
pub mod project;
mod project_lanes;
pub mod random;
pub mod raster;
pub mod real;
pub mod reference;
pub mod sh;
pub mod simd;
pub mod stochastic;
pub mod tile;
pub mod train;

pub use camera::{Camera, CameraError};
pub use cloud::{CloudGradients, ColorModel, GaussianCloud};
pub use project::LowPass;
pub use raster::{PixelGrads, RasterConfig, RenderOutput, backward, render};
/// The degree-0 spherical-harmonic constant (render-base's, the one definition).
pub use render_base::{MAX_SAMPLE_RADIANCE, SH_C0};
pub use simd::Kernel;
