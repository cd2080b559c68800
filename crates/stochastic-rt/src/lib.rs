//! stochastic-rt: ray tracing of transparent 3D Gaussians with one BVH traversal per ray, each
//! intersection accepted with probability equal to its opacity (seed 000, Algorithm 1).
//!
//! - [`gaussians`]: per-Gaussian data for tracing (canonical transforms, cut-offs, bounds) and
//!   the ray-Gaussian response.
//! - [`scene`]: the BVH over the Gaussians' bounds (obvhs `Bvh2`).
//! - [`estimators`]: `exact` (every hit, sorted, Eq. 3) and `stochastic` (closest accepted hit,
//!   Eq. 6).
//!
//! Work in progress (issue 4): the K-buffer, N-sample and stochastic-pass estimators, the
//! trigonometric hash, the `splat trace` program and the benchmarks come next.

pub mod estimators;
pub mod gaussians;
pub mod scene;

pub use estimators::{Estimator, TraceSettings, trace_image};
pub use gaussians::{DepthMode, TraceGaussians};
pub use scene::GaussianScene;
