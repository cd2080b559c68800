//! The estimators of a ray's colour, all on one BVH.
//!
//! - `Exact`: every intersection is collected, sorted by (depth, id) and composited by seed
//!   000's Eq. 3, `L = sum_i T_i alpha_i c_i + T background`, with no early stop: the reference.
//! - `KBuffer`: 3DGRT-style passes, each finding the K closest intersections after the previous
//!   pass (a sorted buffer of K, the ray clipped at the K-th), composited in order; optionally
//!   stopping once transmittance falls below a threshold. Without the stop it equals `Exact`.
//! - `Stochastic`: Algorithm 1: every intersection met during the single traversal is accepted
//!   with probability alpha; an accepted one clips the ray; the colour is the closest accepted
//!   Gaussian's (Eq. 6), or the background. With N samples per traversal (section 3.5) each of N
//!   slots keeps its own closest accepted hit, and the ray is clipped at the farthest slot.
//! - `StochasticPass` (the Vulkan Gaussian-splatting sample's stochastic modes, section 4):
//!   K-buffer passes, each composited from a fresh state to `(L_p, T_p)`; the pass is accepted with probability `1 - T_p`, returning `L_p / (1 -
//!   T_p)`, or discarded; when no hits are left the background is returned. In expectation a
//!   discarded pass weights the rest by `T_p`, so the estimate is unbiased.

use crate::gaussians::DepthMode;
use crate::random::{RandomKind, SampleKey, acceptance};
use crate::scene::GaussianScene;
use glam::Vec3;
use rayon::prelude::*;
use render_base::Control;
use splat_raster::Camera;
use splat_raster::random::{hash32, unit_f32};

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Estimator {
    Exact,
    /// `min_transmittance = 0` disables the early stop.
    KBuffer {
        k: usize,
        min_transmittance: f32,
    },
    Stochastic {
        samples_per_traversal: u32,
    },
    StochasticPass {
        k: usize,
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceSettings {
    pub estimator: Estimator,
    pub depth_mode: DepthMode,
    /// Estimates per pixel (each a camera ray through the pixel centre).
    pub spp: u32,
    pub seed: u32,
    pub background: Vec3,
    pub random: RandomKind,
}

impl Default for TraceSettings {
    fn default() -> Self {
        Self {
            estimator: Estimator::Stochastic {
                samples_per_traversal: 1,
            },
            depth_mode: DepthMode::Mean,
            spp: 1,
            seed: 0,
            background: Vec3::ZERO,
            random: RandomKind::Hash,
        }
    }
}

/// A ray and how its intersections are placed.
#[derive(Debug, Clone, Copy)]
pub struct TraceRay {
    pub o: Vec3,
    pub d: Vec3,
    pub mode: DepthMode,
    /// The camera's forward axis (for `Center` depth).
    pub forward: Vec3,
}

impl TraceRay {
    /// The camera ray through the centre of pixel `p` (row-major index).
    pub fn through_pixel(camera: &Camera, p: u32, mode: DepthMode) -> Self {
        let (x, y) = (p % camera.width, p / camera.width);
        TraceRay {
            o: camera.position,
            d: camera.ray_direction(x as f32 + 0.5, y as f32 + 0.5),
            mode,
            forward: camera.axes().2,
        }
    }
}

/// Every intersection of the ray, unsorted: (t, alpha, Gaussian index).
pub fn all_hits(scene: &GaussianScene, r: &TraceRay) -> Vec<(f32, f32, usize)> {
    let mut hits = Vec::new();
    scene.traverse(r.o, r.d, 0.0, f32::INFINITY, |i, t_max| {
        if let Some(h) = scene
            .gaussians
            .intersect(i, r.o, r.d, 0.0, t_max, r.mode, r.forward)
        {
            hits.push((h.t, h.alpha, i));
        }
        f32::INFINITY
    });
    hits
}

/// The `k` intersections that come first in (depth, id) order after `after`, sorted, into
/// `buf` (cleared first). One traversal; the ray is clipped at the K-th once the buffer is full.
pub fn k_closest_after(
    scene: &GaussianScene,
    r: &TraceRay,
    after: Option<(f32, u32)>,
    k: usize,
    buf: &mut Vec<(f32, f32, usize)>,
) {
    buf.clear();
    let g = &scene.gaussians;
    let margin = g.traversal_margin(r.mode, r.d, r.forward);
    // `key_min` orders hits; the traversal starts `margin` earlier, where a box can end and its
    // centre depth still come after `after`.
    let key_min = after.map_or(0.0, |a| a.0.next_down().max(0.0));
    let traverse_from = after.map_or(0.0, |a| (a.0 - margin).max(0.0));
    scene.traverse(r.o, r.d, traverse_from, f32::INFINITY, |i, t_max| {
        if let Some(h) = g.intersect(i, r.o, r.d, key_min, t_max, r.mode, r.forward) {
            let key = (h.t, g.ids[i]);
            if after.is_none_or(|a| key.0 > a.0 || (key.0 == a.0 && key.1 > a.1)) {
                let pos = buf.partition_point(|e| (e.0, g.ids[e.2]) < key);
                if pos < k {
                    buf.insert(pos, (h.t, h.alpha, i));
                    buf.truncate(k);
                }
            }
        }
        if buf.len() == k {
            buf[k - 1].0.next_up() + margin
        } else {
            f32::INFINITY
        }
    });
}

/// Eq. 3 over every intersection, sorted by (depth, original id).
pub fn trace_exact(scene: &GaussianScene, r: &TraceRay, background: Vec3) -> Vec3 {
    let mut hits = all_hits(scene, r);
    let g = &scene.gaussians;
    hits.sort_by(|a, b| a.0.total_cmp(&b.0).then(g.ids[a.2].cmp(&g.ids[b.2])));
    let mut t = 1.0f32;
    let mut c = Vec3::ZERO;
    for (_, alpha, i) in hits {
        c += t * alpha * g.color(i, r.o);
        t *= 1.0 - alpha;
    }
    c + t * background
}

/// K-buffer passes (3DGRT-style).
pub fn trace_kbuffer(
    scene: &GaussianScene,
    r: &TraceRay,
    background: Vec3,
    k: usize,
    min_transmittance: f32,
) -> Vec3 {
    let g = &scene.gaussians;
    let mut buf = Vec::with_capacity(k + 1);
    let (mut t, mut c) = (1.0f32, Vec3::ZERO);
    let mut after = None;
    loop {
        k_closest_after(scene, r, after, k.max(1), &mut buf);
        for &(_, alpha, i) in &buf {
            c += t * alpha * g.color(i, r.o);
            t *= 1.0 - alpha;
        }
        match buf.last() {
            Some(&(tl, _, i)) if buf.len() == k.max(1) && !(t < min_transmittance) => {
                after = Some((tl, g.ids[i]))
            }
            _ => break,
        }
    }
    c + t * background
}

/// One stochastic estimate (Algorithm 1, Eq. 6) with `n` samples per traversal: the mean of the
/// `n` slots' closest accepted colours.
pub fn trace_stochastic(
    scene: &GaussianScene,
    r: &TraceRay,
    background: Vec3,
    key: &SampleKey,
    n: u32,
    random: RandomKind,
) -> Vec3 {
    let g = &scene.gaussians;
    let n = n.max(1) as usize;
    let mut slots = [(f32::INFINITY, usize::MAX); 64];
    let slots = &mut slots[..n.min(64)];
    let margin = g.traversal_margin(r.mode, r.d, r.forward);
    scene.traverse(r.o, r.d, 0.0, f32::INFINITY, |i, t_max| {
        if let Some(h) = g.intersect(i, r.o, r.d, 0.0, t_max, r.mode, r.forward) {
            let p = r.o + h.t * r.d;
            for (s, slot) in slots.iter_mut().enumerate() {
                if h.t < slot.0 && acceptance(random, key, g.ids[i], s as u32, p) < h.alpha {
                    *slot = (h.t, i);
                }
            }
        }
        // Past the farthest slot's hit (plus the margin) nothing can replace any slot's.
        slots.iter().fold(0.0f32, |m, s| m.max(s.0)) + margin
    });
    let sum: Vec3 = slots
        .iter()
        .map(|&(_, i)| {
            if i == usize::MAX {
                background
            } else {
                g.color(i, r.o)
            }
        })
        .sum();
    sum / slots.len() as f32
}

/// One stochastic-pass estimate (the Vulkan Gaussian-splatting sample's stochastic modes, section
/// 4).
pub fn trace_stochastic_pass(
    scene: &GaussianScene,
    r: &TraceRay,
    background: Vec3,
    key: &SampleKey,
    k: usize,
) -> Vec3 {
    let g = &scene.gaussians;
    let k = k.max(1);
    let mut buf = Vec::with_capacity(k + 1);
    let mut after = None;
    for pass in 0u32.. {
        k_closest_after(scene, r, after, k, &mut buf);
        if buf.is_empty() {
            break;
        }
        let (mut t, mut c) = (1.0f32, Vec3::ZERO);
        for &(_, alpha, i) in &buf {
            c += t * alpha * g.color(i, r.o);
            t *= 1.0 - alpha;
        }
        let opacity = 1.0 - t;
        if unit_f32(hash32(&[
            key.seed,
            key.pixel,
            key.sample,
            0x5bd1_e995 ^ pass,
        ])) < opacity
        {
            return c / opacity;
        }
        if buf.len() < k {
            break;
        }
        let &(tl, _, i) = buf.last().unwrap();
        after = Some((tl, g.ids[i]));
    }
    background
}

/// One estimate of the ray's colour by `settings.estimator`.
pub fn trace_ray(
    scene: &GaussianScene,
    r: &TraceRay,
    settings: &TraceSettings,
    pixel: u32,
    sample: u32,
) -> Vec3 {
    let key = SampleKey::new(settings.seed, pixel, sample);
    match settings.estimator {
        Estimator::Exact => trace_exact(scene, r, settings.background),
        Estimator::KBuffer {
            k,
            min_transmittance,
        } => trace_kbuffer(scene, r, settings.background, k, min_transmittance),
        Estimator::Stochastic {
            samples_per_traversal,
        } => trace_stochastic(
            scene,
            r,
            settings.background,
            &key,
            samples_per_traversal,
            settings.random,
        ),
        Estimator::StochasticPass { k } => {
            trace_stochastic_pass(scene, r, settings.background, &key, k)
        }
    }
}

/// Traces the camera's image: the mean of `spp` estimates per pixel, row-major (one estimate
/// for the deterministic estimators).
pub fn trace_image(scene: &GaussianScene, camera: &Camera, settings: &TraceSettings) -> Vec<Vec3> {
    trace_image_with(scene, camera, settings, &Control::none()).0
}

/// [`trace_image`] that stops when `control` is cancelled (read before every estimate), each
/// pixel keeping the mean of the estimates it finished (a pixel that finished none is black);
/// reports each pixel's estimates to it. Also returns whether it was cancelled. Uncancelled,
/// the image is [`trace_image`]'s bit for bit.
pub fn trace_image_with(
    scene: &GaussianScene,
    camera: &Camera,
    settings: &TraceSettings,
    control: &Control,
) -> (Vec<Vec3>, bool) {
    let spp = match settings.estimator {
        Estimator::Exact | Estimator::KBuffer { .. } => 1,
        _ => settings.spp.max(1),
    };
    let image = (0..camera.width * camera.height)
        .into_par_iter()
        .with_min_len(64)
        .map(|p| {
            let r = TraceRay::through_pixel(camera, p, settings.depth_mode);
            let mut sum = glam::DVec3::ZERO;
            let mut taken = 0u32;
            for s in 0..spp {
                if control.cancelled() {
                    break;
                }
                sum += trace_ray(scene, &r, settings, p, s).as_dvec3();
                taken += 1;
            }
            control.progress(taken as u64);
            if taken == 0 {
                Vec3::ZERO
            } else {
                (sum / taken as f64).as_vec3()
            }
        })
        .collect();
    (image, control.cancelled())
}
