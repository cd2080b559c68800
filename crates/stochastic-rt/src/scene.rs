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
    /// Summed surface area of the inner nodes when the tree was built: a refit tree whose
    /// area grows past [`REBUILD_GROWTH`] times this is rebuilt.
    built_area: f64,
}

/// A refitted BVH is rebuilt once its inner nodes' summed surface area (the SAH's traversal
/// cost, up to a constant) exceeds its build-time value by this factor.
pub const REBUILD_GROWTH: f64 = 1.3;

/// Summed surface area of a BVH's inner nodes.
fn inner_area(bvh: &Bvh2) -> f64 {
    bvh.nodes
        .iter()
        .filter(|n| !n.is_leaf())
        .map(|n| n.aabb().half_area() as f64)
        .sum()
}

fn bounds(gaussians: &TraceGaussians) -> Vec<Aabb> {
    (0..gaussians.len())
        .map(|i| Aabb::new(gaussians.lower[i].into(), gaussians.upper[i].into()))
        .collect()
}

impl GaussianScene {
    pub fn new(cloud: &GaussianCloud<f32>) -> Self {
        let t0 = Instant::now();
        let gaussians = TraceGaussians::new(cloud);
        let prepare_seconds = t0.elapsed().as_secs_f64();
        let aabbs = bounds(&gaussians);
        let mut core = Duration::ZERO;
        let bvh = build_bvh2(&aabbs, BvhBuildParams::medium_build(), &mut core);
        Self {
            built_area: inner_area(&bvh),
            gaussians,
            bvh,
            build_seconds: core.as_secs_f64(),
            prepare_seconds,
        }
    }

    /// The scene for `cloud` after its Gaussians moved (a trained cache level): the tree's
    /// topology is kept and its boxes refitted from the leaves up, which costs a pass over the
    /// nodes instead of a build. It is rebuilt instead when the set of traceable Gaussians
    /// changed (one faded below 1/255, say) or when the refitted tree's surface area grew past
    /// [`REBUILD_GROWTH`] times its build-time value. Returns whether it was rebuilt.
    pub fn update(&mut self, cloud: &GaussianCloud<f32>) -> bool {
        let t0 = Instant::now();
        let gaussians = TraceGaussians::new(cloud);
        if gaussians.ids != self.gaussians.ids || self.bvh.nodes.is_empty() {
            *self = Self::new(cloud);
            return true;
        }
        let aabbs = bounds(&gaussians);
        self.gaussians = gaussians;
        self.prepare_seconds = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        for node in &mut self.bvh.nodes {
            if node.is_leaf() {
                let first = node.first_index as usize;
                let mut b = Aabb::empty();
                for &p in &self.bvh.primitive_indices[first..first + node.prim_count as usize] {
                    b = b.union(&aabbs[p as usize]);
                }
                node.set_aabb(b);
            }
        }
        self.bvh.refit_all();
        self.build_seconds = t1.elapsed().as_secs_f64();
        if inner_area(&self.bvh) > REBUILD_GROWTH * self.built_area {
            *self = Self::new(cloud);
            return true;
        }
        false
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

impl std::fmt::Debug for GaussianScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GaussianScene")
            .field("gaussians", &self.gaussians.len())
            .field("bvh_nodes", &self.bvh.nodes.len())
            .field("build_seconds", &self.build_seconds)
            .finish()
    }
}
