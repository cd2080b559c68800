//! The cache: its levels and their optimisers, the per-frame lookup images, and training.

use crate::config::{CacheConfig, Lookup, Optimizer};
use crate::control::Continuation;
use crate::density::{Density, PassOutcome};
use crate::error::{CacheError, Result};
use crate::fallback::{Trust, Verdict, update_trust};
use crate::init::{SH_C0, initial_levels};
use crate::resolution::PixelMap;
use crate::schedule::Schedule;
use crate::support::Support;
use crate::targets::TrainingTargets;
use crate::warm_start::{Drawn, apply_fit, warm_sums};
use glam::Vec3;
use rayon::prelude::*;
use splat_raster::adamw::{AdamW, AdamWConfig, GroupSettings};
use splat_raster::loss::{Loss, loss_and_grad};
use splat_raster::raster::ForwardState;
use splat_raster::{Camera, GaussianCloud, PixelGrads, RasterConfig, backward, render};
use std::sync::OnceLock;
use std::time::Instant;
use stochastic_rt::{CameraTracer, TraceGaussians, TraceSettings};

/// One level: the Gaussians for paths of one length, and their optimiser state.
#[derive(Debug, Clone)]
pub struct Level {
    pub cloud: GaussianCloud<f32>,
    optimizer: AdamW,
    /// The level's radiance is its cloud's colour times this (see
    /// [`CacheConfig::normalized_radiance`]); `None` until the first samples set it.
    radiance_scale: Option<f32>,
    /// The cloud's colours are absolute radiance (loaded from disk), not yet divided by the
    /// scale; a fresh cloud's albedo colours are already relative.
    absolute_colors: bool,
    /// Warm-start steps taken since the level was made or the scene last changed (see
    /// [`crate::warm_start`]); a loaded level starts with its warm start done.
    warm_steps: u32,
    /// Per colour channel, its blending weight summed over the warm-start frames so far.
    warm_weights: Vec<f32>,
    /// With `weighted_loss`: per colour channel, the mean summed sample weight of a cache
    /// pixel with a target, averaged over the last frames ([`LOSS_WEIGHT_DECAY`]); `None`
    /// before the first.
    loss_weight_scale: Option<[f64; 3]>,
    /// Adaptive density's sums since its last pass (see [`crate::density`]).
    density: Density,
}

/// How much of the running mean sample weight ([`Level::loss_weight_scale`]) each frame keeps:
/// about ten frames. A pixel's share of the loss is its weight over this mean rather than over
/// its own frame's, so that a frame whose samples weigh more moves the level more, as pooling
/// the frames' samples would.
const LOSS_WEIGHT_DECAY: f64 = 0.9;

impl Level {
    /// The factor from the cloud's colours to radiance.
    pub fn radiance_scale(&self) -> f32 {
        self.radiance_scale.unwrap_or(1.0)
    }

    /// Folds this frame's mean sample weight per channel into the running mean, which it
    /// returns (the frame's own on the first frame).
    fn update_loss_weight_scale(&mut self, frame: [f64; 3]) -> [f64; 3] {
        let scale = match self.loss_weight_scale {
            Some(s) => std::array::from_fn(|c| {
                LOSS_WEIGHT_DECAY * s[c] + (1.0 - LOSS_WEIGHT_DECAY) * frame[c]
            }),
            None => frame,
        };
        self.loss_weight_scale = Some(scale);
        scale
    }

    /// Sets the radiance scale from the level's first samples. Absolute colours (a loaded
    /// cloud) are divided by it; returns whether the cloud changed.
    fn set_radiance_scale(&mut self, target: &[[f32; 3]], mask: &[bool]) -> bool {
        let s = mean_luminance(target, mask);
        self.radiance_scale = Some(s);
        let rescaled = std::mem::replace(&mut self.absolute_colors, false);
        if rescaled {
            scale_colors(&mut self.cloud, 1.0 / s);
        }
        rescaled
    }
}

/// Multiplies a degree-0 cloud's colours (`0.5 + C0 * dc`, before the clamp at 0) by `factor`.
pub(crate) fn scale_colors(cloud: &mut GaussianCloud<f32>, factor: f32) {
    for dc in &mut cloud.colors {
        *dc = ((0.5 + SH_C0 * *dc) * factor - 0.5) / SH_C0;
    }
}

/// The cache as drawn from one camera: what the renderer reads during a pass.
#[derive(Debug, Clone)]
pub struct CacheFrame {
    camera: Camera,
    /// The camera the levels were drawn from: the frame's at the cache's resolution.
    cache_camera: Camera,
    map: PixelMap,
    /// Per level, the cached radiance per cache pixel (row-major), as drawn: paths read it
    /// bilinearly at their pixel's centre ([`CacheFrame::value`]) and training compares it
    /// with the binned targets.
    drawn: Vec<Vec<[f32; 3]>>,
    /// Per level, the drawn image read at every frame pixel, made only when asked for
    /// ([`CacheFrame::image`]). Upsampling every level each frame wrote 33 MB at 1280x720,
    /// three times the reads paths make, and was half of the lookup's time (issue 31).
    upsampled: OnceLock<Vec<Vec<[f32; 3]>>>,
    /// Per level, the rasteriser's state for the backward pass (raster lookup only, and only
    /// while the levels are unchanged since they were drawn).
    states: Vec<Option<ForwardState<f32>>>,
    /// Where paths may stop into each level (`None`: everywhere, the fallback is off). Carried
    /// from frame to frame and updated by training.
    trust: Option<Trust>,
    /// Where enough paths reach each level's vertex for paths to stop into it (`None`: the
    /// support test is off). Carried from frame to frame and updated by training.
    support: Option<Support>,
    /// The still view has had its `handoff_frames`: paths do not read the cache and it does not
    /// train (see [`CacheConfig::handoff_frames`]).
    handed_off: bool,
    /// With the unbiased estimator: per level and cache pixel, `kappa`, the factor of the
    /// throughput's luminance that makes the probability of going on ([`crate::control`]).
    kappa: Option<Vec<Vec<f32>>>,
}

impl CacheFrame {
    pub fn camera(&self) -> &Camera {
        &self.camera
    }
    pub fn levels(&self) -> usize {
        self.drawn.len()
    }
    /// Cached radiance of `level` (0-based: paths of length `level + 1`) at row-major frame
    /// `pixel`: the level's image read bilinearly at the pixel's centre.
    #[inline]
    pub fn value(&self, level: usize, pixel: usize) -> Vec3 {
        let drawn = &self.drawn[level];
        if self.map.is_identity() {
            return Vec3::from_array(drawn[pixel]);
        }
        let w = self.camera.width as usize;
        Vec3::from_array(
            self.map
                .sample(drawn, (pixel % w) as u32, (pixel / w) as u32),
        )
    }
    /// The whole image of a level at the frame's resolution: [`CacheFrame::value`] at every
    /// pixel (upsampled on the first call after the levels were drawn or trained).
    pub fn image(&self, level: usize) -> &[[f32; 3]] {
        if self.map.is_identity() {
            return &self.drawn[level];
        }
        &self.upsampled.get_or_init(|| {
            self.drawn
                .par_iter()
                .map(|d| self.map.upsample(d))
                .collect()
        })[level]
    }
    /// The whole image of a level as drawn, at the cache's resolution.
    pub fn drawn_image(&self, level: usize) -> &[[f32; 3]] {
        &self.drawn[level]
    }
    /// The cache pixel that holds row-major frame pixel `pixel` (what [`CacheFrame::trusted`]
    /// takes; a path computes it once).
    #[inline]
    pub fn bin(&self, pixel: usize) -> usize {
        let w = self.camera.width as usize;
        self.map.bin((pixel % w) as u32, (pixel / w) as u32)
    }
    /// Whether paths through cache pixel `bin` ([`CacheFrame::bin`]) may stop into `level` (see
    /// [`crate::fallback`]); always true with the fallback off.
    #[inline]
    pub fn trusted(&self, level: usize, bin: usize) -> bool {
        !self.handed_off
            && self.trust.as_ref().is_none_or(|t| t.trusted(level, bin))
            && self
                .support
                .as_ref()
                .is_none_or(|s| s.supported(level, bin))
    }
    /// Whether the support test needs each path counted ([`crate::TileTargets::add_path`]);
    /// without it the counts would be work for nothing.
    pub fn counts_paths(&self) -> bool {
        self.support.is_some()
    }
    /// Per level, the fraction of cache pixels paths may stop into (1 with the fallback and the
    /// support test off, 0 once handed off).
    pub fn trusted_fractions(&self) -> Vec<f64> {
        let bins = self.map.width as usize * self.map.height as usize;
        (0..self.levels())
            .map(|l| match (&self.trust, &self.support, self.handed_off) {
                (_, _, true) => 0.0,
                (None, None, false) => 1.0,
                (Some(t), None, false) => t.trusted_fraction(l),
                (_, Some(_), false) => {
                    (0..bins).filter(|&b| self.trusted(l, b)).count() as f64 / bins.max(1) as f64
                }
            })
            .collect()
    }
    /// Whether this frame's paths run without the cache (the still view's handoff).
    pub fn handed_off(&self) -> bool {
        self.handed_off
    }
    /// The unbiased estimator's `kappa` for `level` at cache pixel `bin`: the probability of
    /// going on past the level's vertex is `kappa` times the throughput's luminance, clamped
    /// (see [`crate::control::probability`]). 1 where it has not been set.
    #[inline]
    pub fn continuation_scale(&self, level: usize, bin: usize) -> f32 {
        self.kappa
            .as_ref()
            .and_then(|k| k.get(level)?.get(bin).copied())
            .unwrap_or(1.0)
    }
    /// Sets every `kappa` (per level, per cache pixel); a frozen cache's tests and a renderer
    /// with its own rule set them here.
    pub fn set_continuation_scales(&mut self, kappa: Vec<Vec<f32>>) {
        self.kappa = Some(kappa);
    }
    /// The map from frame pixels to cache pixels.
    pub fn pixel_map(&self) -> PixelMap {
        self.map
    }
    /// Empty training targets for this frame: its levels and size, and with the unbiased
    /// estimator its statistics per cache pixel.
    pub fn training_targets(&self) -> TrainingTargets {
        let t = TrainingTargets::new(self.levels(), self.map);
        if self.kappa.is_some() {
            t.with_statistics()
        } else {
            t
        }
    }
}

/// What the last frame cost, in seconds, and the losses it reached.
#[derive(Debug, Clone, Default)]
pub struct GsCacheReport {
    /// Drawing the levels (the paper's splat time, ST).
    pub lookup_seconds: f64,
    /// The frame reused the last frame's level images (same camera, no training step since):
    /// see [`GsCache::begin_frame`].
    pub lookup_reused: bool,
    /// The frame ran without the cache: the still view had its `handoff_frames`.
    pub handed_off: bool,
    /// Loss, backward pass and optimiser step of every level (OT).
    pub train_seconds: f64,
    /// HDR loss per level before the step (None: the level had no sample). Its value is not a
    /// measure of fit on noisy targets (its weights depend on the prediction); see `mse`.
    pub losses: Vec<Option<f64>>,
    /// Mean squared error per level before the step, over the pixels with a sample: with the
    /// same targets, lower is closer to their expectation.
    pub mse: Vec<Option<f64>>,
    /// Learning-rate factor of Eq. 5 used for the step.
    pub lr_scale: f32,
    /// Training samples refused this frame (negative or not finite), counted, not trained on.
    pub dropped_samples: u64,
    /// Per level, the fraction of the tested cache pixels whose residual was gross this frame
    /// (see [`crate::fallback`]; `None`: the fallback is off or no pixel had two samples).
    pub stale_fraction: Vec<Option<f64>>,
    /// Per level, what adaptive density did this frame (`None`: no pass was due).
    pub density: Vec<Option<PassOutcome>>,
}

impl GsCacheReport {
    /// No training step's figures: what a frame reports before its step, or without one.
    fn clear_training(&mut self, levels: usize) {
        self.train_seconds = 0.0;
        self.dropped_samples = 0;
        self.losses = vec![None; levels];
        self.mse = vec![None; levels];
        self.stale_fraction = vec![None; levels];
        self.density = vec![None; levels];
    }
}

/// A multi-level radiance cache (see the crate docs for what it estimates).
#[derive(Debug, Clone)]
pub struct GsCache {
    config: CacheConfig,
    levels: Vec<Level>,
    schedule: Schedule,
    /// Calls of [`GsCache::train`] so far (a step is taken on one in `train_every`).
    train_calls: u64,
    /// A fresh cache before its first training frame: its colours are still the albedo start
    /// and it has no radiance scale, so (with the fallback) that frame is plain path tracing.
    fresh: bool,
    /// Frames drawn since [`GsCache::start_image`] on the same camera with the scene unchanged
    /// (`None`: no image is accumulating, so no handoff).
    image_frames: Option<u32>,
    /// The levels (or their radiance scales) changed since `frame` was drawn: a still camera
    /// may reuse the drawn images only while this is false.
    levels_changed: bool,
    frame: Option<CacheFrame>,
    report: GsCacheReport,
    raster: RasterConfig,
    /// With the unbiased estimator: the last frames' statistics per cache pixel.
    continuation: Option<Continuation>,
    /// The last frame's training targets, handed back to be cleared and filled again: a
    /// frame's targets are tens of megabytes at 1280x720, and allocating them afresh cost a
    /// serial 8 ms and their first writes 11 ms of page faults a frame (issue 31).
    spare_targets: Option<TrainingTargets>,
    /// Each level's tracing arrays and camera-grid memory for the ray-traced lookup, kept
    /// from frame to frame for the same reason: fresh, they made the lookup a third slower in
    /// page faults (issue 31).
    tracers: Vec<(TraceGaussians, CameraTracer)>,
}

fn adamw_config(config: &CacheConfig) -> AdamWConfig {
    let lr = config.learning_rates();
    let wd = match config.optimizer {
        Optimizer::AdamW => config.weight_decay,
        Optimizer::Adam => 0.0,
    };
    let g = |lr, weight_decay| GroupSettings { lr, weight_decay };
    AdamWConfig {
        beta1: 0.9,
        beta2: 0.999,
        epsilon: 1e-8,
        means: g(lr.position, 0.0),
        log_scales: g(lr.scale, 0.0),
        rotations: g(lr.rotation, 0.0),
        colors: g(lr.color, wd),
        opacity_logits: g(lr.opacity, wd),
    }
}

impl GsCache {
    /// A cache initialised from points and their albedos (the GSCache paper's section 3.2).
    pub fn new(points: &[Vec3], albedo: &[Vec3], mut config: CacheConfig) -> Result<Self> {
        config.points = points.len();
        let levels = initial_levels(points, albedo, &config)?;
        let mut cache = Self::from_levels(levels, config)?;
        for l in &mut cache.levels {
            l.absolute_colors = false;
            l.warm_steps = 0;
        }
        cache.fresh = true;
        Ok(cache)
    }

    /// A copy of this cache that no longer trains: its levels in absolute radiance, its
    /// settings with `train = false`, and (with the unbiased estimator) its statistics, so it
    /// reads as this one did. A frozen cache renders a still view from fixed values: what the
    /// unbiasedness tests compare with plain path tracing.
    pub fn frozen(&self) -> Result<Self> {
        let clouds = self
            .levels
            .iter()
            .map(|level| {
                let mut cloud = level.cloud.clone();
                scale_colors(&mut cloud, level.radiance_scale());
                cloud
            })
            .collect();
        let mut frozen = Self::from_levels(
            clouds,
            CacheConfig {
                train: false,
                ..self.config
            },
        )?;
        frozen.continuation = self.continuation.clone();
        Ok(frozen)
    }

    /// A cache from existing level clouds (loaded from disk, or made elsewhere). The clouds must
    /// have SH degree 0 colour; `config.levels` is set to their number, and the settings are
    /// validated as [`GsCache::new`]'s are.
    pub fn from_levels(clouds: Vec<GaussianCloud<f32>>, mut config: CacheConfig) -> Result<Self> {
        config.levels = clouds.len();
        if clouds.is_empty() || clouds.len() > crate::config::MAX_LEVELS {
            return Err(CacheError::Config(format!(
                "{} level clouds: expected 1..={}",
                clouds.len(),
                crate::config::MAX_LEVELS
            )));
        }
        // A loaded cache (from files, or from C through `gs_cache_load`) is held to the same
        // settings checks as a new one.
        config.validate()?;
        let opt = adamw_config(&config);
        let levels = clouds
            .into_iter()
            .enumerate()
            .map(|(i, cloud)| {
                cloud
                    .check()
                    .map_err(|e| CacheError::Init(format!("level {i}: {e}")))?;
                if cloud.color_model != splat_raster::ColorModel::Sh(0) {
                    return Err(CacheError::Init(format!(
                        "level {i} has colour model {:?}: expected SH degree 0",
                        cloud.color_model
                    )));
                }
                let optimizer = AdamW::new(opt, &cloud);
                Ok(Level {
                    optimizer,
                    radiance_scale: None,
                    absolute_colors: true,
                    warm_steps: u32::MAX,
                    warm_weights: Vec::new(),
                    loss_weight_scale: None,
                    density: Density::new(cloud.len()),
                    cloud,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            config,
            levels,
            schedule: Schedule::new(config.decay),
            train_calls: 0,
            image_frames: None,
            fresh: false,
            levels_changed: true,
            frame: None,
            report: GsCacheReport::default(),
            raster: RasterConfig::default(),
            continuation: None,
            spare_targets: None,
            tracers: Vec::new(),
        })
    }

    pub fn config(&self) -> &CacheConfig {
        &self.config
    }

    /// Takes the settings [`CacheConfig::for_denoiser`] sets (its
    /// [`CacheConfig::FOR_DENOISER_KEYS`]: error-aware termination's and the handoff) from
    /// `config`, keeping the levels and everything else: a viewer's denoise toggle switches
    /// between the denoised and the plain cache's settings without losing what the levels
    /// learned. The tests start afresh on the next frame; an image already past the new
    /// handoff hands off on its next frame.
    pub fn set_error_aware_termination(&mut self, config: &CacheConfig) -> Result<()> {
        let changed = CacheConfig {
            min_coverage: config.min_coverage,
            max_bias: config.max_bias,
            handoff_frames: config.handoff_frames,
            ..self.config
        };
        changed.validate()?;
        self.config = changed;
        if let Some(frame) = self.frame.as_mut() {
            frame.support = None;
        }
        Ok(())
    }

    /// Turns training on or off (`train`) without rebuilding the cache: a viewer freezes what
    /// the cache has learnt, and lets it learn again.
    pub fn set_training(&mut self, on: bool) {
        self.config.train = on;
    }

    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// Gaussians over all levels.
    pub fn gaussian_count(&self) -> usize {
        self.levels.iter().map(|l| l.cloud.len()).sum()
    }

    /// Bytes of Gaussian parameters (14 f32 each with degree-0 colour), without the optimiser's
    /// two moments (which double it again).
    pub fn parameter_bytes(&self) -> usize {
        self.levels
            .iter()
            .map(|l| l.cloud.len() * l.cloud.bytes_per_gaussian())
            .sum()
    }

    /// The scene changed (the transfer function or the lights): restarts Eq. 5's schedule and
    /// the warm start, whose colour fits re-converge in a few frames where Adam's steps would
    /// take tens, and (with the fallback) sends every pixel back to plain path tracing until its
    /// residuals show the level fits again. A camera change is noticed by
    /// [`GsCache::begin_frame`] and restarts only the schedule: the levels' world-space colours
    /// stay right when the view moves.
    pub fn reset_schedule(&mut self) {
        self.schedule.reset();
        for level in &mut self.levels {
            level.warm_steps = 0;
            level.warm_weights.clear();
        }
        self.image_frames = None;
        if let Some(frame) = self.frame.as_mut() {
            frame.handed_off = false;
            if let Some(trust) = frame.trust.as_mut() {
                trust.distrust_all();
            }
            if let Some(support) = frame.support.as_mut() {
                support.forget_bias();
            }
        }
    }

    /// The frames from now on are averaged into one image (a progressive render of a still
    /// view): after [`CacheConfig::handoff_frames`] of them, paths run without the cache. Frames
    /// before the call (a warm-up) do not count, and without it there is no handoff, as every
    /// frame of an interactive view is shown alone. A camera move or a scene change ends the
    /// image.
    pub fn start_image(&mut self) {
        self.image_frames = Some(0);
        if let Some(frame) = self.frame.as_mut() {
            frame.handed_off = false;
        }
    }

    /// Draws every level from `camera` for the coming pass. A camera different from the last
    /// frame's restarts the learning-rate schedule. The rasterised images of the last frame are
    /// reused, not drawn again, when neither the camera nor the levels changed since (a frame
    /// without a training step): they would be drawn bit for bit the same.
    pub fn begin_frame(&mut self, camera: &Camera) -> &CacheFrame {
        let start = Instant::now();
        let same_camera = self.frame.as_ref().is_some_and(|f| f.camera == *camera);
        if self.frame.is_some() && !same_camera {
            self.schedule.reset();
        }
        if !same_camera && let Some(c) = self.continuation.as_mut() {
            c.camera_moved();
        }
        // A camera move after the image's first frame ends it (the first frame may move from a
        // warm-up's last view to the image's).
        if !same_camera && self.image_frames.is_some_and(|n| n > 0) {
            self.image_frames = None;
        }
        // The unbiased estimator needs no handoff: its image converges to the right one.
        let handed_off = self.config.handoff_frames > 0
            && !self.config.unbiased
            && self
                .image_frames
                .is_some_and(|n| n >= self.config.handoff_frames);
        self.image_frames = self.image_frames.map(|n| n.saturating_add(1));
        self.report.handed_off = handed_off;
        if handed_off {
            // A handed-off frame trains nothing, so a caller need not call `train` for it
            // (cached-pt does not): its report says so without that call.
            self.report.clear_training(self.levels.len());
        }
        // Handed off, the images are not read: nothing to draw.
        self.report.lookup_reused = same_camera
            && (handed_off || (!self.levels_changed && self.config.lookup == Lookup::Raster));
        if self.report.lookup_reused {
            self.report.lookup_seconds = start.elapsed().as_secs_f64();
            let kappa = self.kappa();
            let frame = self.frame.as_mut().expect("same_camera implies a frame");
            frame.handed_off = handed_off;
            frame.kappa = kappa;
            return frame;
        }
        self.levels_changed = false;
        let (cache_camera, map) = PixelMap::new(camera, self.config.resolution_divisor);
        // The last frame's verdicts, carried to this frame's size.
        let (old_trust, old_support) = self
            .frame
            .take()
            .map_or((None, None), |f| (f.trust, f.support));
        let trust = self.config.fallback.then(|| {
            let mut trust = old_trust.unwrap_or_default();
            trust.fit(self.levels.len(), map.width, map.height);
            if self.fresh {
                trust.distrust_all();
            }
            trust
        });
        let support = self.config.tests_support().then(|| {
            let mut support = old_support.unwrap_or_default();
            support.fit(self.levels.len(), map.width, map.height);
            support
        });
        let draw_camera = &cache_camera;
        // The levels are drawn side by side, as they train (see `LevelStep`): one level's
        // image is too small a problem to keep many cores busy through its serial parts.
        let (mut drawn, states): (Vec<Vec<[f32; 3]>>, Vec<_>) = match self.config.lookup {
            Lookup::Raster => self
                .levels
                .par_iter()
                .map(|l| {
                    let (out, state) = render(&l.cloud, draw_camera, &self.raster);
                    (out.color, Some(state))
                })
                .unzip(),
            Lookup::Rt => {
                // The lookup's rays all leave the camera's centre, so they are traced a row
                // at a time through the Gaussians' depth-sorted silhouettes rather than a BVH,
                // and their slots drawn in depth order: the BVH estimator's law, without its
                // traversal or a random number per hit (`stochastic_rt::camera_grid`).
                let samples = self.config.rt_samples.max(1);
                let defaults = TraceSettings::default();
                self.tracers
                    .resize_with(self.levels.len(), Default::default);
                self.levels
                    .par_iter()
                    .zip(&mut self.tracers)
                    .map(|(l, (gaussians, tracer))| {
                        gaussians.prepare(&l.cloud);
                        let img = tracer.trace(
                            gaussians,
                            draw_camera,
                            samples,
                            1,
                            defaults.seed,
                            defaults.background,
                        );
                        (img.into_iter().map(|c| c.to_array()).collect(), None)
                    })
                    .unzip()
            }
        };
        drawn
            .par_iter_mut()
            .zip(&self.levels)
            .for_each(|(image, level)| {
                let s = level.radiance_scale();
                if s != 1.0 {
                    image.iter_mut().flatten().for_each(|v| *v *= s);
                }
            });
        if self.config.unbiased
            && self
                .continuation
                .as_ref()
                .is_none_or(|c| !c.fits(self.levels.len(), &map))
        {
            self.continuation = Some(Continuation::new(self.levels.len(), map));
        }
        let kappa = self.kappa();
        self.report.lookup_seconds = start.elapsed().as_secs_f64();
        self.frame.insert(CacheFrame {
            camera: *camera,
            cache_camera,
            map,
            drawn,
            upsampled: OnceLock::new(),
            states,
            trust,
            support,
            handed_off,
            kappa,
        })
    }

    /// The unbiased estimator's `kappa` per level and cache pixel from the last frames'
    /// statistics (`None` without it). Where they say nothing yet (a moving camera, the first
    /// frames of a view), every path goes on (`kappa` infinite: plain path tracing), the one
    /// choice that cannot cost variance.
    fn kappa(&self) -> Option<Vec<Vec<f32>>> {
        let fixed = self.config.continuation_scale;
        self.continuation
            .as_ref()
            .filter(|_| self.config.unbiased)
            .map(|c| {
                if fixed > 0.0 {
                    vec![vec![fixed; c.cache_pixels()]; self.levels.len()]
                } else {
                    c.kappa(f32::INFINITY)
                }
            })
    }

    /// The images drawn by the last [`GsCache::begin_frame`].
    pub fn frame(&self) -> Option<&CacheFrame> {
        self.frame.as_ref()
    }

    /// Empty training targets for the last drawn frame: [`CacheFrame::training_targets`], but
    /// reusing the buffers handed back by [`GsCache::recycle_training_targets`] when they fit
    /// (cleared). `None` before the first [`GsCache::begin_frame`].
    pub fn take_training_targets(&mut self) -> Option<TrainingTargets> {
        let frame = self.frame.as_ref()?;
        let statistics = frame.kappa.is_some();
        Some(match self.spare_targets.take() {
            Some(mut spare) if spare.fits(frame.levels(), &frame.map, statistics) => {
                spare.clear();
                spare
            }
            _ => frame.training_targets(),
        })
    }

    /// Hands a frame's targets back after [`GsCache::train`], for the next frame to reuse.
    pub fn recycle_training_targets(&mut self, targets: TrainingTargets) {
        self.spare_targets = Some(targets);
    }

    /// One optimisation step per level against this frame's samples (HDR loss, Eq. 4, with the
    /// prediction detached in the denominator; AdamW; Eq. 5's schedule). Does nothing when
    /// training is off. The targets must match the frame's camera. On a handed-off frame
    /// ([`CacheFrame::handed_off`]) it only counts the frame's paths for the support test, and a
    /// renderer may skip it and the frame's bookkeeping altogether (cached-pt does).
    pub fn train(&mut self, targets: &TrainingTargets) -> Result<&GsCacheReport> {
        let start = Instant::now();
        self.report.clear_training(self.levels.len());
        self.report.dropped_samples = targets.dropped();
        let Some(frame) = self.frame.as_mut() else {
            return Err(CacheError::Config(
                "train() called before begin_frame(): the targets need the frame's camera".into(),
            ));
        };
        let camera = frame.cache_camera;
        let map = frame.map;
        let frame_camera = frame.camera;
        if let (Some(c), Some((stats, moments))) =
            (self.continuation.as_mut(), targets.statistics())
        {
            c.observe(stats, moments);
        }
        if targets.levels() != self.levels.len() || *targets.map() != map {
            return Err(CacheError::Config(format!(
                "training targets are {} levels of {}x{} binned to {}x{}: expected {} levels of \
                 {}x{} binned to {}x{}",
                targets.levels(),
                targets.width(),
                targets.height(),
                targets.map().width,
                targets.map().height,
                self.levels.len(),
                frame_camera.width,
                frame_camera.height,
                map.width,
                map.height
            )));
        }
        if let Some(support) = frame.support.as_mut() {
            // The residuals of the level as this frame's paths read it: not on a fresh cache's
            // first frame (its levels are still the albedo start) nor a handed-off one (not read).
            if self.config.max_bias > 0.0 && !self.fresh && !frame.handed_off {
                for (level, drawn) in frame.drawn.iter().enumerate() {
                    let (target, _) = targets.level_target(level, true);
                    support.observe(level, drawn, &target, &targets.level_spread(level));
                }
            }
            let (paths, reached) = targets.path_counts();
            support.update(
                paths,
                reached,
                self.config.min_coverage,
                self.config.max_bias,
            );
        }
        if frame.handed_off {
            self.report.train_seconds = 0.0;
            return Ok(&self.report);
        }
        let step_now = self
            .train_calls
            .is_multiple_of(self.config.train_every.max(1) as u64)
            && (!self.config.adaptive_training || self.schedule.wants_step());
        self.train_calls += 1;
        if !self.config.train || !step_now {
            // A frozen fresh cache still takes its radiance scale from its first samples.
            for (i, level) in self.levels.iter_mut().enumerate() {
                if self.config.normalized_radiance
                    && level.radiance_scale.is_none()
                    && !level.absolute_colors
                {
                    let (target, mask) = targets.level_target(i, true);
                    if mask.iter().any(|&m| m) {
                        level.set_radiance_scale(&target, &mask);
                        self.levels_changed = true;
                    }
                }
            }
            settle_fresh(&mut self.fresh, frame);
            self.report.train_seconds = 0.0;
            return Ok(&self.report);
        }
        let lr_scale = self.schedule.next_scale();
        self.report.lr_scale = lr_scale;
        self.levels_changed = true;
        // The levels train side by side: each is a small problem (a cache-resolution image,
        // tens of thousands of Gaussians) whose serial parts would otherwise add up level after
        // level and stop the step from scaling past a few cores (issue 31). Each level's step
        // depends on nothing of the others', so the result is the same on any thread count.
        let step = LevelStep {
            targets,
            camera: &camera,
            raster: &self.raster,
            config: &self.config,
            lr_scale,
        };
        let trust = frame.trust.as_mut().filter(|_| !self.fresh);
        let outcomes: Vec<LevelOutcome> =
            LevelSlot::split(&mut self.levels, &mut frame.states, &mut frame.drawn, trust)
                .into_par_iter()
                .enumerate()
                .map(|(i, slot)| step.train(i, slot))
                .collect();
        // The steps left each level's image as they compared it with the targets.
        frame.upsampled = OnceLock::new();
        for (i, outcome) in outcomes.into_iter().enumerate() {
            self.report.losses[i] = outcome.loss;
            self.report.mse[i] = outcome.mse;
            self.report.stale_fraction[i] = outcome.stale_fraction;
            self.report.density[i] = outcome.density;
        }
        settle_fresh(&mut self.fresh, frame);
        // The schedule watches the levels' summed HDR loss (relative to the prediction, so levels
        // of any brightness weigh alike) to see when training levels off.
        let losses: Vec<f64> = self.report.losses.iter().flatten().copied().collect();
        if !losses.is_empty() {
            self.schedule.observe(losses.iter().sum());
        }
        self.report.train_seconds = start.elapsed().as_secs_f64();
        Ok(&self.report)
    }

    /// With the unbiased estimator: per level, the mean probability of going on and what the
    /// running statistics say the estimator can gain at best (empty otherwise, or before the
    /// statistics of a still view).
    pub fn control_summary(&self) -> Vec<crate::control::LevelSummary> {
        self.continuation
            .as_ref()
            .map(|c| c.summary())
            .unwrap_or_default()
    }

    /// Timings and losses of the last frame.
    pub fn report(&self) -> &GsCacheReport {
        &self.report
    }
}

/// What every level's training step shares: the frame's targets, its cameras and the settings.
struct LevelStep<'a> {
    targets: &'a TrainingTargets,
    /// The camera the levels were drawn from (the cache's resolution).
    camera: &'a Camera,
    raster: &'a RasterConfig,
    config: &'a CacheConfig,
    lr_scale: f32,
}

/// One level's part of the cache and of the frame: what its training step may change.
struct LevelSlot<'a> {
    level: &'a mut Level,
    /// The lookup's forward state, when it can be reused for the backward pass.
    state: &'a mut Option<ForwardState<f32>>,
    /// The level's image as drawn.
    drawn: &'a mut Vec<[f32; 3]>,
    /// The fallback's verdicts for this level (`None`: no residual test this frame).
    trust: Option<&'a mut [Verdict]>,
}

/// What one level's step reports.
#[derive(Default)]
struct LevelOutcome {
    loss: Option<f64>,
    mse: Option<f64>,
    stale_fraction: Option<f64>,
    density: Option<PassOutcome>,
}

impl<'a> LevelSlot<'a> {
    /// The per-level slots of the cache's levels and the frame's per-level buffers.
    fn split(
        levels: &'a mut [Level],
        states: &'a mut [Option<ForwardState<f32>>],
        drawn: &'a mut [Vec<[f32; 3]>],
        trust: Option<&'a mut Trust>,
    ) -> Vec<Self> {
        let mut trust = trust.map(|t| t.levels_mut().iter_mut());
        levels
            .iter_mut()
            .zip(states)
            .zip(drawn)
            .map(|((level, state), drawn)| LevelSlot {
                level,
                state,
                drawn,
                trust: trust.as_mut().and_then(|t| t.next()).map(|v| &mut v[..]),
            })
            .collect()
    }
}

impl LevelStep<'_> {
    /// One optimisation step of level `i` against its binned targets.
    fn train(&self, i: usize, slot: LevelSlot<'_>) -> LevelOutcome {
        let LevelSlot {
            level,
            state: saved_state,
            drawn,
            trust,
        } = slot;
        let (target, mask) = self.targets.level_target(i, self.config.masked_targets);
        if !mask.iter().any(|&m| m) {
            return LevelOutcome::default();
        }
        let scale_before = level.radiance_scale();
        if level.radiance_scale.is_none()
            && self.config.normalized_radiance
            && level.set_radiance_scale(&target, &mask)
        {
            // The drawn image no longer matches the cloud: draw it again below.
            *saved_state = None;
        }
        let scale = level.radiance_scale();
        // The lookup's forward pass is reused when it was the rasteriser's: the level has not
        // changed since it was drawn.
        let (mut prediction, state, drawn_scale) = match saved_state.take() {
            Some(state) => (std::mem::take(drawn), state, scale_before),
            None => {
                let (out, state) = render(&level.cloud, self.camera, self.raster);
                (out.color, state, 1.0)
            }
        };
        if scale != drawn_scale {
            let f = scale / drawn_scale;
            prediction.iter_mut().flatten().for_each(|v| *v *= f);
        }
        let mut outcome = LevelOutcome::default();
        if let Some(verdicts) = trust {
            let spread = self.targets.level_spread(i);
            outcome.stale_fraction = update_trust(verdicts, &prediction, &target, &spread);
        }
        let (loss, mut grad) = loss_and_grad(Loss::Hdr, &prediction, &target, Some(&mask));
        let loss_weights = self.config.weighted_loss.then(|| {
            let scale = level.update_loss_weight_scale(self.targets.level_mean_weight(i));
            self.targets
                .level_loss_weights(i, scale, self.config.masked_targets)
        });
        if let Some(weights) = &loss_weights {
            grad.iter_mut()
                .zip(weights)
                .for_each(|(g, w)| g.iter_mut().zip(w).for_each(|(v, w)| *v *= w));
        }
        // The cloud draws radiance / scale: the chain rule multiplies its gradient by scale.
        grad.iter_mut().flatten().for_each(|g| *g *= scale);
        if !loss.is_finite() {
            return outcome;
        }
        // The warm start's sums read the cloud as drawn, like the backward pass: the two run
        // side by side.
        let warm = level.warm_steps < self.config.warm_start_frames;
        let (mut grads, warm_sums) = rayon::join(
            || {
                backward(
                    &level.cloud,
                    self.camera,
                    &state,
                    PixelGrads {
                        color: &grad,
                        transmittance: None,
                        depth: None,
                    },
                )
            },
            || {
                warm.then(|| {
                    let drawn_level = Drawn {
                        camera: self.camera,
                        state: &state,
                        prediction: &prediction,
                        radiance_scale: scale,
                    };
                    warm_sums(
                        &level.cloud,
                        drawn_level,
                        &target,
                        &mask,
                        loss_weights.as_deref(),
                    )
                })
            },
        );
        if let Some(sums) = warm_sums {
            // The warm start sets the colours; Adam trains the rest (see `warm_start`).
            level.warm_steps += 1;
            level.warm_weights.resize(level.cloud.colors.len(), 0.0);
            apply_fit(&mut level.cloud, &sums, &mut level.warm_weights);
            if level.warm_steps == self.config.warm_start_frames {
                level.warm_weights = Vec::new();
            }
            grads.colors.fill(0.0);
        }
        // Adaptive density chooses from the cloud as drawn (its forward state), before the
        // step, and reshapes it after.
        let densify = self.config.densify_every > 0
            && level.density.observe(
                self.targets,
                i,
                &target,
                &mask,
                &prediction,
                scale,
                self.config.densify_every,
            );
        let chosen = densify.then(|| {
            level
                .density
                .choose(&level.cloud, self.camera, &state, self.config)
        });
        level
            .optimizer
            .step(&mut level.cloud, &grads, self.lr_scale);
        if let Some(chosen) = chosen {
            outcome.density = Some(level.density.apply(
                i,
                &mut level.cloud,
                &mut level.optimizer,
                &mut level.warm_weights,
                &chosen,
            ));
        }
        outcome.loss = Some(loss);
        outcome.mse = Some(loss_and_grad(Loss::L2, &prediction, &target, Some(&mask)).0);
        *drawn = prediction;
        outcome
    }
}

/// After a fresh cache's first training frame: its samples set the radiance scales (and the
/// first fit), so from now on the levels are radiance, every pixel is trusted, and the residual
/// test takes over.
fn settle_fresh(fresh: &mut bool, frame: &mut CacheFrame) {
    if std::mem::replace(fresh, false)
        && let Some(trust) = frame.trust.as_mut()
    {
        trust.trust_all();
    }
}

/// The mean luminance of a level's first samples, floored so a black first frame cannot give a
/// zero or NaN scale.
fn mean_luminance(target: &[[f32; 3]], mask: &[bool]) -> f32 {
    let (sum, n) =
        target
            .iter()
            .zip(mask)
            .filter(|(_, m)| **m)
            .fold((0.0f64, 0u64), |(s, n), (t, _)| {
                (
                    s + crate::termination::luminance(Vec3::from_array(*t)) as f64,
                    n + 1,
                )
            });
    let mean = if n > 0 { (sum / n as f64) as f32 } else { 0.0 };
    if mean > 1e-3 { mean } else { 1e-3 }
}

#[cfg(test)]
mod tests {
    //! `weighted_loss`: a level trained on frames whose samples weigh differently holds their
    //! pooled weighted mean, as one fit of all the frames' samples would, where one share of
    //! the loss per cache pixel and frame holds the mean of the frames' means.

    use super::*;
    use crate::test_support::grid_cache;

    /// Trains for 400 frames on samples `frame_samples(frame)` = (value, weight) at every pixel,
    /// and returns the centre pixel's value averaged over the last 40 frames (so the swing of
    /// alternating frames cancels).
    fn settled_value(
        config: CacheConfig,
        weighted_loss: bool,
        frame_samples: impl Fn(usize) -> (f32, f32),
    ) -> f32 {
        let (mut cache, camera) = grid_cache(CacheConfig {
            weighted_loss,
            resolution_divisor: 1,
            ..config
        });
        let centre = 8 * 16 + 8;
        let (frames, averaged) = (400, 40);
        let mut sum = 0.0f64;
        for frame in 0..frames {
            cache.begin_frame(&camera);
            if frame >= frames - averaged {
                sum += cache.frame().unwrap().value(0, centre).x as f64;
            }
            let mut targets = cache.take_training_targets().unwrap();
            let (value, weight) = frame_samples(frame);
            for pixel in 0..256 {
                targets.add_weighted(0, pixel, [value; 3], weight);
            }
            cache.train(&targets).unwrap();
            cache.recycle_training_targets(targets);
        }
        (sum / averaged as f64) as f32
    }

    /// Frames alternate between samples of 1 weighing 1 and samples of 5 weighing 3. Pooled, their
    /// weighted mean is (1 + 3 * 5) / 4 = 4; the mean of the frames' means is 3.
    ///
    /// Fitted by least squares alone (the warm start throughout, colours only), a level's value is
    /// linear in its targets: each run is compared with a control trained on that constant every
    /// frame (a level does not draw its target exactly: 64 Gaussians over 16x16 pixels), within 3%
    /// (the controls lie 29% apart, and a weighted loss that did not pool would land at 3/4 of its
    /// control).
    ///
    /// Trained by Adam after the warm start (the default), both alternating runs settle below their
    /// controls (Adam's bounded steps on targets that swing 5x from frame to frame: 16-18% here),
    /// but the weighted one stays above the unweighted by the pooled means' ratio 4/3, within 8%.
    #[test]
    fn a_level_holds_the_pooled_weighted_mean_of_its_frames() {
        let alternating = |frame: usize| {
            if frame.is_multiple_of(2) {
                (1.0, 1.0)
            } else {
                (5.0, 3.0)
            }
        };
        let least_squares = CacheConfig {
            warm_start_frames: 1000,
            lr_position: 0.0,
            lr_opacity: 0.0,
            lr_rotation: 0.0,
            ..CacheConfig::default()
        };
        let weighted = settled_value(least_squares, true, alternating);
        let unweighted = settled_value(least_squares, false, alternating);
        let four = settled_value(least_squares, true, |_| (4.0, 1.0));
        let three = settled_value(least_squares, false, |_| (3.0, 1.0));
        eprintln!(
            "least squares: weighted {weighted} (control {four}), unweighted {unweighted} (control {three})"
        );
        assert!(
            (weighted / four - 1.0).abs() < 0.03,
            "weighted loss: {weighted}, want {four}"
        );
        assert!(
            (unweighted / three - 1.0).abs() < 0.03,
            "one share a pixel: {unweighted}, want {three}"
        );
        let adam = CacheConfig::default();
        let ratio =
            settled_value(adam, true, alternating) / settled_value(adam, false, alternating);
        eprintln!("Adam: weighted / unweighted {ratio}");
        assert!(
            (ratio / (4.0 / 3.0) - 1.0).abs() < 0.08,
            "Adam: weighted / unweighted {ratio}"
        );
    }
}
