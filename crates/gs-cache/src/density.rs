//! Adaptive density: a level grows Gaussians where its fit keeps missing its targets by more
//! than their noise, within a budget, and drops Gaussians that draw nothing.
//!
//! **Why.** A level's Gaussians are placed and sized once, from the volume's points (Eq. 2).
//! Where the radiance a level must hold changes faster than their spacing (hydrogen's halo
//! round its bright core, a silhouette), the level can only draw their blur of it: a smooth,
//! structured error that a denoiser keeps (issue 53's breakdown: the halo's and the
//! silhouettes' error fell with 16x the Gaussians everywhere). Growing Gaussians only where the
//! fit misses puts them where that error is. Measured, it finds little to split beyond the
//! targets' noise and ties the fixed levels at equal time (docs/results/cache_error.md,
//! "Scouted and closed"), so it is off by default.
//!
//! **What is measured.** 3DGS grows a cloud where its Gaussians' view-space positional
//! gradients are large. A cache's targets are noisy and its Gaussians settle where their
//! positional gradient vanishes on average, with the miss still there, so we measure the miss
//! itself. Per cache pixel and frame, with `r` the luminance of the binned target less the
//! drawn value's and `v` the target's noise variance ([`TrainingTargets::level_spread`]),
//! `r^2 - v` is an unbiased estimate of the fit's squared bias there; divided by the drawn
//! value's square (plus a hundredth of the level's scale squared, relMSE's floor) it is
//! relative. Summed over the frames between two passes it gives an image `E`, and the frames
//! each pixel had a target in give `N`. A Gaussian's score is `sum_p w_p E_p / sum_p w_p N_p`,
//! with `w_p` its blending weight at pixel `p` (the rasteriser's backward pass of `E` and of
//! `N` as colour gradients sums exactly that): the mean squared relative miss over the frames
//! and pixels it is drawn into.
//!
//! **Noise is not a miss.** The estimate is itself noisy: where the fit has no miss, `r` is
//! the target's noise and `r^2 - v` has variance `2 v^2` (normal noise). Over a pass, on the
//! 80x45 cache pixels of a 320x180 frame, that noise is a few times `densify_bias^2` itself,
//! so a fixed threshold would split Gaussians where the targets are merely noisy. A Gaussian
//! is split only where its summed miss beyond the threshold,
//! `sum_p w_p (E_p - densify_bias^2 N_p)`, exceeds three standard errors of the estimate,
//! `3 sqrt(sum_p w_p V_p)` (`V`: the summed `2 v^2`, relative; `w_p^2 <= w_p` makes this an
//! upper bound), a one-sided test whose false alarm rate is 0.13% per Gaussian and pass.
//!
//! **What is done.** Every `densify_every` training steps, the Gaussians that pass the test are
//! split, worst score first, at most a tenth of the level per pass and up to `densify_max`
//! times the level's first size: each becomes two at `mean +- sigma u / sqrt 2`, `sigma` its
//! largest standard deviation and `u` a direction hashed from the level, the pass and the
//! Gaussian (the same on any thread count), with every standard deviation divided by `sqrt 2`
//! (`SPLIT_SHRINK`, `SPLIT_OFFSET`: the pair covers the parent's projected area and keeps its
//! variance along `u`). The children keep the parent's colour, opacity and rotation and start
//! with zero Adam moments. Gaussians whose opacity fell under 1/255 are dropped in the same
//! pass: they draw nothing from any view. In motion a pass's `E` mixes the frames' views (it
//! is kept per cache pixel), which blurs where the score lands by the camera's motion over the
//! interval.

use crate::config::CacheConfig;
use crate::targets::TrainingTargets;
use crate::termination::luminance;
use glam::Vec3;
use splat_raster::adamw::AdamW;
use splat_raster::random::{hash32, unit_f32};
use splat_raster::raster::ForwardState;
use splat_raster::{Camera, GaussianCloud, PixelGrads, SH_C0, backward};

/// The most of a level split in one pass, as a fraction of its Gaussians.
const MAX_SPLIT_FRACTION: f64 = 0.1;

/// The factor by which a split Gaussian's children are smaller: `sqrt(2)`, so that two
/// children cover the parent's projected area (`2 (sigma / sqrt 2)^2 = sigma^2`) and draw as
/// much light where their opacity is low (3DGS's 1.6 loses a fifth of it, which a level then
/// has to win back).
const SPLIT_SHRINK: f32 = std::f32::consts::SQRT_2;

/// Where the children of a split sit, in the parent's standard deviations: the pair's variance
/// along the split direction, `(sigma / sqrt 2)^2 + (sigma / sqrt 2)^2`, is the parent's.
const SPLIT_OFFSET: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// Opacity under which a Gaussian draws nothing visible (one 8-bit step) and is dropped.
const MIN_OPACITY: f32 = 1.0 / 255.0;

/// Standard errors by which a Gaussian's summed miss must exceed the threshold's share before
/// it is split: a one-sided false alarm rate of 0.13% per Gaussian and pass (normal noise).
const SPLIT_CONFIDENCE: f32 = 3.0;

/// One level's adaptive-density state: the miss summed since the last pass.
#[derive(Debug, Clone, Default)]
pub struct Density {
    /// Per cache pixel, the summed squared relative miss less noise (`E` in the module docs).
    miss: Vec<f32>,
    /// Per cache pixel, the frames it had a target with a noise estimate in (`N`).
    seen: Vec<f32>,
    /// Per cache pixel, the summed variance of its relative miss estimates where the fit has
    /// no miss, `2 v^2` relative (`V`).
    noise: Vec<f32>,
    /// Training steps summed into `miss` since the last pass.
    frames: u32,
    /// Passes so far (part of the split directions' hash).
    passes: u32,
    /// The level's size when it was made or loaded: `densify_max` is relative to it.
    initial_len: usize,
}

/// What one pass did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PassOutcome {
    pub split: usize,
    pub dropped: usize,
}

impl Density {
    /// The state of a level of `len` Gaussians.
    pub fn new(len: usize) -> Self {
        Self {
            initial_len: len,
            ..Self::default()
        }
    }

    /// Adds one frame's miss of level `level` drawn as `prediction` (absolute radiance, at the
    /// cache's resolution) against its binned `target` where `mask` holds (the training step's
    /// own), with their noise from `targets`; `scale` is the level's radiance scale (the
    /// relative miss's floor). Returns whether a pass is due (`every` frames summed).
    #[allow(clippy::too_many_arguments)]
    pub fn observe(
        &mut self,
        targets: &TrainingTargets,
        level: usize,
        target: &[[f32; 3]],
        mask: &[bool],
        prediction: &[[f32; 3]],
        scale: f32,
        every: u32,
    ) -> bool {
        let spread = targets.level_spread(level);
        if self.miss.len() != prediction.len() {
            self.miss = vec![0.0; prediction.len()];
            self.seen = vec![0.0; prediction.len()];
            self.noise = vec![0.0; prediction.len()];
            self.frames = 0;
        }
        let floor = (0.1 * scale).powi(2);
        for (p, ((drawn, t), (m, (_, variance)))) in prediction
            .iter()
            .zip(target)
            .zip(mask.iter().zip(&spread))
            .enumerate()
        {
            // Below two samples there is no noise estimate: the pixel says nothing (written so
            // a NaN variance fails it).
            if !(*m && variance.is_finite()) {
                continue;
            }
            let d = luminance(Vec3::from_array(*drawn));
            let r = luminance(Vec3::from_array(*t)) - d;
            let relative = 1.0 / (d * d + floor);
            let miss = (r * r - variance) * relative;
            let noise = 2.0 * (variance * relative).powi(2);
            if miss.is_finite() && noise.is_finite() {
                self.miss[p] += miss;
                self.seen[p] += 1.0;
                self.noise[p] += noise;
            }
        }
        self.frames += 1;
        self.frames >= every.max(1)
    }

    /// The Gaussians to split, worst first: those whose summed miss exceeds `densify_bias`
    /// squared's share by three standard errors, within this pass's share of the budget.
    /// `state` must be `cloud`'s forward state from `camera` (the frame's, before the
    /// optimiser's step).
    pub fn choose(
        &self,
        cloud: &GaussianCloud<f32>,
        camera: &Camera,
        state: &ForwardState<f32>,
        config: &CacheConfig,
    ) -> Vec<usize> {
        let budget = ((config.densify_max as f64 * self.initial_len as f64).floor() as usize)
            .min(crate::config::MAX_POINTS);
        let room = budget.saturating_sub(cloud.len());
        let per_pass = (MAX_SPLIT_FRACTION * cloud.len() as f64).ceil() as usize;
        let most = room.min(per_pass);
        if most == 0 || self.miss.iter().all(|&m| m == 0.0) {
            return Vec::new();
        }
        let miss = footprint_sums(cloud, camera, state, &self.miss);
        let seen = footprint_sums(cloud, camera, state, &self.seen);
        let noise = footprint_sums(cloud, camera, state, &self.noise);
        let threshold = config.densify_bias * config.densify_bias;
        let mut worst: Vec<(f32, usize)> = (0..cloud.len())
            // A Gaussian drawn into less than one pixel-frame's weight in all says too little;
            // written so that NaN fails each test.
            .filter(|&g| seen[g] >= 1.0)
            .filter(|&g| {
                miss[g] - threshold * seen[g] > SPLIT_CONFIDENCE * noise[g].max(0.0).sqrt()
            })
            .map(|g| (miss[g] / seen[g], g))
            .collect();
        // Worst first; equal scores by index, so the choice is the same on any machine.
        worst.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        worst.truncate(most);
        let mut chosen: Vec<usize> = worst.into_iter().map(|(_, g)| g).collect();
        chosen.sort_unstable();
        chosen
    }

    /// Splits `chosen` (from [`Density::choose`]) and drops the Gaussians that draw nothing,
    /// reshaping the optimiser's moments and the warm start's summed weights (per colour
    /// value; empty once the warm start is over) to match; starts the next pass's sums. A
    /// split Gaussian's children each take half its warm-start weight: each covers about half
    /// of what it covered.
    pub fn apply(
        &mut self,
        level: usize,
        cloud: &mut GaussianCloud<f32>,
        optimizer: &mut AdamW,
        warm_weights: &mut Vec<f32>,
        chosen: &[usize],
    ) -> PassOutcome {
        self.passes += 1;
        self.miss.fill(0.0);
        self.seen.fill(0.0);
        self.noise.fill(0.0);
        self.frames = 0;
        let mut split = vec![false; cloud.len()];
        chosen.iter().for_each(|&g| split[g] = true);
        let visible = |g: usize| sigmoid(cloud.opacity_logits[g]) >= MIN_OPACITY;
        // Kept Gaussians in order (a split one's first child in its place), then the second
        // children.
        let kept: Vec<usize> = (0..cloud.len())
            .filter(|&g| split[g] || visible(g))
            .collect();
        let rows: Vec<usize> = kept.iter().copied().chain(chosen.iter().copied()).collect();
        let moments: Vec<Option<usize>> = kept
            .iter()
            .map(|&g| (!split[g]).then_some(g))
            .chain(chosen.iter().map(|_| None))
            .collect();
        let mut grown = cloud.gather(&rows);
        let first_children = kept.iter().enumerate().filter(|(_, g)| split[**g]);
        let seconds = kept.len()..rows.len();
        for ((first, &parent), second) in first_children.zip(seconds) {
            let u = split_direction(level as u32, self.passes, parent as u32);
            let sigma = (0..3)
                .map(|k| cloud.log_scales[3 * parent + k])
                .fold(f32::NEG_INFINITY, f32::max)
                .exp();
            let offset = u * (SPLIT_OFFSET * sigma);
            for (row, sign) in [(first, 1.0f32), (second, -1.0)] {
                for k in 0..3 {
                    grown.means[3 * row + k] += sign * offset[k];
                    grown.log_scales[3 * row + k] -= SPLIT_SHRINK.ln();
                }
            }
        }
        let outcome = PassOutcome {
            split: chosen.len(),
            dropped: cloud.len() + chosen.len() - rows.len(),
        };
        if warm_weights.len() == 3 * cloud.len() {
            *warm_weights = rows
                .iter()
                .flat_map(|&g| {
                    let half = if split[g] { 0.5 } else { 1.0 };
                    warm_weights[3 * g..3 * g + 3].iter().map(move |w| w * half)
                })
                .collect();
        }
        *cloud = grown;
        optimizer.gather(&moments);
        outcome
    }
}

/// Per Gaussian, `sum_p w_p image_p` over the pixels it is drawn into (`w_p`: its blending
/// weight there): the backward pass of `image` as the colour's gradient gives it per colour
/// channel, times `SH_C0`, in every channel not clamped at 0; a Gaussian black in every
/// channel gets 0.
fn footprint_sums(
    cloud: &GaussianCloud<f32>,
    camera: &Camera,
    state: &ForwardState<f32>,
    image: &[f32],
) -> Vec<f32> {
    let pixels: Vec<[f32; 3]> = image.iter().map(|&v| [v; 3]).collect();
    let grads = backward(
        cloud,
        camera,
        state,
        PixelGrads {
            color: &pixels,
            transmittance: None,
            depth: None,
        },
    );
    grads
        .colors
        .chunks(3)
        .map(|c| {
            let largest = c
                .iter()
                .copied()
                .fold(0.0f32, |a, v| if v.abs() > a.abs() { v } else { a });
            largest / SH_C0
        })
        .collect()
}

/// A unit direction from a hash of the level, the pass and the Gaussian (uniform on the
/// sphere).
fn split_direction(level: u32, pass: u32, gaussian: u32) -> Vec3 {
    let z = 2.0 * unit_f32(hash32(&[0x5eed_d5e1, level, pass, gaussian, 0])) - 1.0;
    let phi = std::f32::consts::TAU * unit_f32(hash32(&[0x5eed_d5e1, level, pass, gaussian, 1]));
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    //! A level grows where its fit misses a structure it cannot draw, and not where its targets
    //! are only noisy.

    use super::*;
    use crate::test_support::grid_cache;

    /// The pixels given targets: the central 8x8 of the grid cache's 16x16 image, well inside
    /// the grid's footprint (so its edge is no miss).
    fn central(pixel: usize) -> bool {
        (4..12).contains(&(pixel % 16)) && (4..12).contains(&(pixel / 16))
    }

    /// Trains the grid cache (64 Gaussians, drawn at full resolution) for 300 frames on two
    /// samples a central pixel of `target(pixel, drawn)` times `1 + 0.5 u`, `u` uniform in
    /// [-1, 1] from a hash of the frame, pixel and sample (`drawn`: the level's value there as
    /// this frame drew it), and returns the level's size and the rms relative error of the
    /// drawn level against `target(pixel, 0)` over the central pixels.
    fn trained(densify_every: u32, target: impl Fn(usize, f32) -> f32) -> (usize, f64) {
        let (mut cache, camera) = grid_cache(CacheConfig {
            resolution_divisor: 1,
            densify_every,
            densify_max: 4.0,
            ..CacheConfig::default()
        });
        for frame in 0..300 {
            let drawn: Vec<f32> = (0..256)
                .map(|p| cache.begin_frame(&camera).value(0, p).x)
                .collect();
            let mut targets = cache.take_training_targets().unwrap();
            for pixel in (0..256).filter(|&p| central(p)) {
                for sample in 0..2 {
                    let u = 2.0 * unit_f32(hash32(&[7, frame, pixel as u32, sample])) - 1.0;
                    let value = target(pixel, drawn[pixel]) * (1.0 + 0.5 * u);
                    targets.add_weighted(0, pixel, [value; 3], 1.0);
                }
            }
            cache.train(&targets).unwrap();
            cache.recycle_training_targets(targets);
        }
        let frame = cache.begin_frame(&camera);
        let errors: Vec<f64> = (0..256)
            .filter(|&p| central(p))
            .map(|p| {
                let t = target(p, 0.0) as f64;
                ((frame.value(0, p).x as f64 - t) / t).powi(2)
            })
            .collect();
        let rms = (errors.iter().sum::<f64>() / errors.len() as f64).sqrt();
        (cache.gaussian_count(), rms)
    }

    /// Vertical stripes two pixels wide, 0.4 and 1.6: the grid's Gaussians (one every 2.4
    /// pixels) draw them as a blur. With adaptive density the level must grow by at least a
    /// half and its error against the stripes fall to at most 0.8 of the fixed level's.
    #[test]
    fn a_level_grows_where_its_fit_misses_a_structure() {
        let stripes = |pixel: usize, _| {
            if (pixel % 16 / 2).is_multiple_of(2) {
                0.4
            } else {
                1.6
            }
        };
        let (fixed_size, fixed_error) = trained(0, stripes);
        let (grown_size, grown_error) = trained(5, stripes);
        eprintln!(
            "stripes: fixed {fixed_size} Gaussians, error {fixed_error:.3}; grown {grown_size}, \
             error {grown_error:.3}"
        );
        assert_eq!(fixed_size, 64);
        assert!(grown_size >= 96, "grew to {grown_size} Gaussians");
        assert!(
            grown_error <= 0.8 * fixed_error,
            "error {grown_error} against {fixed_error} without adaptive density"
        );
    }

    /// Targets that are the level's own drawn values, noisy by +-50%: the fit has no miss
    /// at all, and the noise must not pass for one. Each pass tests each Gaussian at a false
    /// alarm rate of at most 0.13% (three standard errors, an upper bound on them, of a sum
    /// over a few pixels and five frames, so the normal approximation is rough); 60 passes over
    /// 64 Gaussians expect a handful of false splits: more than 6 (10% growth) fails. Without
    /// the noise term in the test (`miss - threshold` alone) every pass splits its full share.
    #[test]
    fn noise_alone_does_not_grow_a_level() {
        let (size, _) = trained(5, |_, drawn| drawn.max(1e-3));
        eprintln!("noise alone: {size} Gaussians");
        assert!(size <= 70, "noise alone grew the level to {size} Gaussians");
    }
}
