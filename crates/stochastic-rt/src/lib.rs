//! stochastic-rt: ray tracing of transparent 3D Gaussians with one BVH traversal per ray, each
//! intersection accepted with probability equal to its opacity (Sun et al. 2025, "Stochastic ray
//! tracing of transparent 3D Gaussians", Algorithm 1).
//!
//! - [`gaussians`]: per-Gaussian data for tracing (canonical transforms, cut-offs, bounds) and
//!   the ray-Gaussian response.
//! - `isa`: which SIMD lanes run (AVX2 with FMA, or the baseline).
//! - [`random`]: the acceptance numbers: an integer hash, or Sun et al.'s trigonometric hash.
//! - [`scene`]: the BVH over the Gaussians' bounds (obvhs `Bvh2`).
//! - [`camera_grid`]: the stochastic estimator for a camera's own rays in `Center` depth, a
//!   row of pixels at a time through the Gaussians' depth-sorted silhouettes instead of the
//!   BVH, its slots drawn in depth order from one number each (the cache's lookup).
//! - [`estimators`]: `exact` (every hit, sorted, Eq. 3), `kbuffer` (K closest per pass,
//!   3DGRT-style), `stochastic` (closest accepted hit, Eq. 6; N samples per traversal, section
//!   3.5) and `stochastic-pass` (the Vulkan Gaussian-splatting sample's stochastic modes,
//!   section 4).
//!

pub mod camera_grid;
pub mod estimators;
pub mod gaussians;
mod isa;
pub mod random;
pub mod scene;

pub use camera_grid::{CameraTracer, trace_camera_image};
pub use estimators::{Estimator, TraceSettings, trace_image, trace_image_with};
pub use gaussians::{DepthMode, TraceGaussians};
pub use random::RandomKind;
pub use scene::GaussianScene;
