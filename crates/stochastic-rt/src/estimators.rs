//! The estimators of a ray's colour, all on one BVH.
//!
//! - `Exact`: every intersection is collected, sorted by (depth, id) and composited by seed
//!   000's Eq. 3, `L = sum_i T_i alpha_i c_i + T background`, with no early stop: the reference.
//! - `Stochastic`: Algorithm 1: each intersection met during the single traversal is accepted
//!   with probability alpha (a stateless hash of seed, pixel, sample and Gaussian id); an accepted
//!   one clips the ray, so only nearer ones are examined afterwards; the ray's colour is the
//!   closest accepted Gaussian's (Eq. 6), or the background. Its expectation is Eq. 3.

use crate::gaussians::DepthMode;
use crate::scene::GaussianScene;
use glam::Vec3;
use rayon::prelude::*;
use splat_raster::Camera;
use splat_raster::random::{hash32, unit_f32};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Estimator {
    Exact,
    Stochastic,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceSettings {
    pub estimator: Estimator,
    pub depth_mode: DepthMode,
    /// Samples per pixel (each a camera ray through the pixel centre; stochastic estimates
    /// differ by their random numbers).
    pub spp: u32,
    pub seed: u32,
    pub background: Vec3,
}

impl Default for TraceSettings {
    fn default() -> Self {
        Self {
            estimator: Estimator::Stochastic,
            depth_mode: DepthMode::Mean,
            spp: 1,
            seed: 0,
            background: Vec3::ZERO,
        }
    }
}

/// Every intersection of the ray, unsorted: (t, alpha, Gaussian index).
pub fn all_hits(
    scene: &GaussianScene,
    o: Vec3,
    d: Vec3,
    mode: DepthMode,
    forward: Vec3,
) -> Vec<(f32, f32, usize)> {
    let mut hits = Vec::new();
    scene.traverse(o, d, 0.0, f32::INFINITY, |i, t_max| {
        if let Some(h) = scene
            .gaussians
            .intersect(i, o, d, 0.0, t_max, mode, forward)
        {
            hits.push((h.t, h.alpha, i));
        }
        f32::INFINITY
    });
    hits
}

/// Eq. 3 over every intersection, sorted by (depth, original id).
pub fn trace_exact(
    scene: &GaussianScene,
    o: Vec3,
    d: Vec3,
    mode: DepthMode,
    forward: Vec3,
    background: Vec3,
) -> Vec3 {
    let mut hits = all_hits(scene, o, d, mode, forward);
    let g = &scene.gaussians;
    hits.sort_by(|a, b| a.0.total_cmp(&b.0).then(g.ids[a.2].cmp(&g.ids[b.2])));
    let mut t = 1.0f32;
    let mut c = Vec3::ZERO;
    for (_, alpha, i) in hits {
        c += t * alpha * g.color(i, o);
        t *= 1.0 - alpha;
    }
    c + t * background
}

/// One stochastic estimate (Algorithm 1, Eq. 6) for the ray of `pixel`, `sample`.
#[allow(clippy::too_many_arguments)]
pub fn trace_stochastic(
    scene: &GaussianScene,
    o: Vec3,
    d: Vec3,
    mode: DepthMode,
    forward: Vec3,
    background: Vec3,
    seed: u32,
    pixel: u32,
    sample: u32,
) -> Vec3 {
    let g = &scene.gaussians;
    let hit = scene.traverse(o, d, 0.0, f32::INFINITY, |i, t_max| {
        match g.intersect(i, o, d, 0.0, t_max, mode, forward) {
            Some(h) if unit_f32(hash32(&[seed, pixel, sample, g.ids[i]])) < h.alpha => h.t,
            _ => f32::INFINITY,
        }
    });
    match hit {
        Some((i, _)) => g.color(i, o),
        None => background,
    }
}

/// Traces the camera's image: the mean of `spp` estimates per pixel, row-major.
pub fn trace_image(scene: &GaussianScene, camera: &Camera, settings: &TraceSettings) -> Vec<Vec3> {
    let (_, _, forward) = camera.axes();
    let w = camera.width;
    (0..camera.width * camera.height)
        .into_par_iter()
        .with_min_len(64)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            let d = camera.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
            let o = camera.position;
            match settings.estimator {
                Estimator::Exact => trace_exact(
                    scene,
                    o,
                    d,
                    settings.depth_mode,
                    forward,
                    settings.background,
                ),
                Estimator::Stochastic => {
                    let mut sum = glam::DVec3::ZERO;
                    for s in 0..settings.spp {
                        sum += trace_stochastic(
                            scene,
                            o,
                            d,
                            settings.depth_mode,
                            forward,
                            settings.background,
                            settings.seed,
                            p,
                            s,
                        )
                        .as_dvec3();
                    }
                    (sum / settings.spp.max(1) as f64).as_vec3()
                }
            }
        })
        .collect()
}
