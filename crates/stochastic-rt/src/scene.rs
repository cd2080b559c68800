//! The BVH over Gaussian bounds. obvhs's binary `Bvh2` is used: its node test honours the ray's
//! `t_min` (its CwBvh does not), so rays that start inside a Gaussian's bounds find it.

use crate::gaussians::TraceGaussians;
use glam::Vec3A;
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::ray::{Ray, RayHit};
use splat_raster::GaussianCloud;
use std::time::{Duration, Instant};

/// The Gaussians and the BVH over their bounds.
#[derive(Clone)]
pub struct GaussianScene {
    pub gaussians: TraceGaussians,
    pub bvh: Bvh2,
    /// Seconds to build the BVH (the core build, excluding bound computation).
    pub build_seconds: f64,
    /// Seconds to prepare the Gaussians and their bounds.
    pub prepare_seconds: f64,
}

impl GaussianScene {
    pub fn new(cloud: &GaussianCloud<f32>) -> Self {
        let t0 = Instant::now();
        let gaussians = TraceGaussians::new(cloud);
        let prepare_seconds = t0.elapsed().as_secs_f64();
        let aabbs: Vec<Aabb> = (0..gaussians.len())
            .map(|i| Aabb::new(gaussians.lower[i].into(), gaussians.upper[i].into()))
            .collect();
        let mut core = Duration::ZERO;
        let bvh = build_bvh2(&aabbs, BvhBuildParams::medium_build(), &mut core);
        Self {
            gaussians,
            bvh,
            build_seconds: core.as_secs_f64(),
            prepare_seconds,
        }
    }

    /// Bytes held by the BVH nodes and its primitive index.
    pub fn bvh_bytes(&self) -> usize {
        std::mem::size_of_val(self.bvh.nodes.as_slice())
            + std::mem::size_of_val(self.bvh.primitive_indices.as_slice())
    }

    /// Calls `visit(gaussian index, ray)` for every Gaussian whose box the ray segment reaches;
    /// `visit` returns a distance to clip the ray at (accept) or infinity (reject).
    #[inline]
    pub fn traverse(
        &self,
        o: glam::Vec3,
        d: glam::Vec3,
        t_min: f32,
        t_max: f32,
        mut visit: impl FnMut(usize, f32) -> f32,
    ) -> Option<(usize, f32)> {
        if self.gaussians.is_empty() {
            return None;
        }
        let ray = Ray::new(Vec3A::from(o), Vec3A::from(d), t_min, t_max);
        let mut hit = RayHit::none();
        let found = self.bvh.ray_traverse(ray, &mut hit, |r, prim| {
            let i = self.bvh.primitive_indices[prim] as usize;
            visit(i, r.tmax)
        });
        found.then(|| {
            (
                self.bvh.primitive_indices[hit.primitive_id as usize] as usize,
                hit.t,
            )
        })
    }
}
