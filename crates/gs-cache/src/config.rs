//! What a cache is asked to be: how many levels and Gaussians, how paths stop into it, how it
//! learns, and how it is read.

pub use crate::schedule::Decay;
use serde::{Deserialize, Serialize};

/// Per-parameter learning rates, before the schedule of Eq. 5: what training uses, built from
/// a [`CacheConfig`] by [`CacheConfig::learning_rates`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearningRates {
    pub position: f32,
    pub color: f32,
    pub rotation: f32,
    pub scale: f32,
    pub opacity: f32,
}

/// How paths stop into the cache (the GSCache paper's sections 3.3-3.4): what one path needs
/// of a [`CacheConfig`], built by [`CacheConfig::termination`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerminationConfig {
    /// Algorithm 1's coefficient C at the first level.
    pub coefficient: f32,
    /// Algorithm 1's coefficient C from the second level on.
    pub deep_coefficient: f32,
    /// Algorithm 1's threshold.
    pub threshold: f32,
    /// Early termination (Algorithm 1) on or off.
    pub early: bool,
    /// Natural termination on or off.
    pub natural: bool,
    /// Training samples weighted by the inverse of the probability of going on.
    pub survivor_weights: bool,
    /// Training samples weighted for the paths that stop: `(1 - q) lum(W) / q`; takes
    /// precedence over `survivor_weights`.
    pub stopper_weights: bool,
    /// Training samples weighted per colour channel by the path's throughput in that channel
    /// (with `stopper_weights`: `(1 - q) W_c / q` for `(1 - q) lum(W) / q`).
    pub channel_weights: bool,
    /// The unbiased estimator: every path reaching a level reads the cache and goes on with
    /// probability `q`, adding `(L - C) / q` (the crate docs). Algorithm 1's selection and
    /// natural termination are off.
    pub unbiased: bool,
    /// The unbiased estimator's floor on `q`.
    pub min_continuation: f32,
}

/// How the renderer reads the cache each frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Lookup {
    /// Rasterise each level with splat-raster (the paper's lookup).
    Raster,
    /// Ray-trace each level with stochastic-rt's single-traversal stochastic estimator (Sun et
    /// al., 2025), `rt_samples` samples per traversal. The lookup's rays all leave the camera,
    /// so each row of pixels walks the Gaussians' depth-sorted silhouettes instead of a BVH and
    /// draws its slots in depth order: the BVH estimator's law (not its bits) at a small
    /// fraction of its cost (`stochastic_rt::camera_grid`); training still uses the
    /// rasteriser's gradients.
    Rt,
}

/// Which optimiser trains the levels. Adam is AdamW without weight decay (the "-REG" ablation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Optimizer {
    #[cfg_attr(feature = "clap", value(name = "adamw"))]
    AdamW,
    Adam,
}

/// Everything that defines a cache, in one flat list: the same keys in an experiment file's
/// `cache` table (serde), on the command line as `--cache-KEY` (clap, with the `clap` feature),
/// and in the C ABI's `GsCacheConfig` (a test holds the three to the same names). Defaults are
/// the GSCache paper's, except where the crate docs say why not.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(deny_unknown_fields, default)]
pub struct CacheConfig {
    /// Number of levels; level i (0-based) holds paths of length i + 1.
    #[cfg_attr(feature = "clap", arg(long = "cache-levels", default_value_t = DEFAULT.levels))]
    pub levels: usize,
    /// Gaussians in the first level; level i has points / 2^i. 0 chooses it from the image:
    /// 0.35 per pixel of the cache image (`GAUSSIANS_PER_CACHE_PIXEL`, applied by `for_image`).
    #[cfg_attr(feature = "clap", arg(long = "cache-points", default_value_t = DEFAULT.points))]
    pub points: usize,
    /// How each frame draws the levels: `raster` or `rt`.
    #[cfg_attr(feature = "clap", arg(long = "cache-lookup", value_enum, default_value_t = DEFAULT.lookup))]
    pub lookup: Lookup,
    /// The levels are drawn and trained at 1 / this of the frame's resolution and read back
    /// bilinearly (1: the frame's own; see `resolution.rs`). 4 by measurement: at 320x180 it
    /// cut the cache's cost from 2.3x to 0.3x of path tracing and lowered its error
    /// (docs/results/cost_default, cost_headsq).
    #[cfg_attr(feature = "clap", arg(long = "cache-resolution-divisor", default_value_t = DEFAULT.resolution_divisor))]
    pub resolution_divisor: u32,
    /// Stochastic samples per BVH traversal of the `rt` lookup.
    #[cfg_attr(feature = "clap", arg(long = "cache-rt-samples", default_value_t = DEFAULT.rt_samples))]
    pub rt_samples: u32,
    /// Algorithm 1's coefficient C: the continuation probability is
    /// clamp(C luminance(albedo product), 0, 1); 0 stops every path at its first vertex.
    #[cfg_attr(feature = "clap", arg(long = "cache-c", default_value_t = DEFAULT.c))]
    pub c: f32,
    /// Algorithm 1's C from path length 2 on (the deeper levels), where it differs from `c`;
    /// 0 uses `c` at every level. The deeper levels' bias compounds (each level trains on
    /// paths that stopped into the next), so stopping into them less often can pay where the
    /// first level's stops still do (docs/results/cache_error.md).
    #[cfg_attr(feature = "clap", arg(long = "cache-c-deep", default_value_t = DEFAULT.c_deep))]
    pub c_deep: f32,
    /// Algorithm 1's threshold: paths whose continuation probability is at or above it always
    /// go on.
    #[cfg_attr(feature = "clap", arg(long = "cache-threshold", default_value_t = DEFAULT.threshold))]
    pub threshold: f32,
    /// Early termination (Algorithm 1); false leaves only natural termination.
    #[cfg_attr(feature = "clap", arg(long = "cache-early", action = clap::ArgAction::Set, default_value_t = DEFAULT.early))]
    pub early: bool,
    /// Natural termination: a path that leaves the volume having carried no radiance takes the
    /// cached value of its length instead of zero.
    #[cfg_attr(feature = "clap", arg(long = "cache-natural", action = clap::ArgAction::Set, default_value_t = DEFAULT.natural))]
    pub natural: bool,
    /// Weight each training sample by the inverse of the probability with which Algorithm 1
    /// let its path go on at the level's vertex, so a level learns the mean over every path
    /// that reached the vertex rather than over the survivors (see `CachedPath::samples`).
    #[cfg_attr(feature = "clap", arg(long = "cache-survivor-weights", action = clap::ArgAction::Set, default_value_t = DEFAULT.survivor_weights))]
    pub survivor_weights: bool,
    /// Weight each training sample by `(1 - q) W / q` (`q`: Algorithm 1's probability of
    /// going on at the level's vertex, `W`: the path's throughput there; its luminance, or per
    /// channel with `channel_weights`), so that a level learns what the paths that *stop* into
    /// it would have gathered, which is what the image needs of it (see
    /// `CachedPath::samples`). Takes precedence over `survivor_weights`. On by default, with
    /// `channel_weights` and `weighted_loss`: the three take the raw image's brightness error
    /// from -0.93% to -0.27% on hydrogen and from -0.48% to -0.16% on the blob scene and lower
    /// its relMSE at equal time (the crate docs; docs/results/cache_error.md).
    #[cfg_attr(feature = "clap", arg(long = "cache-stopper-weights", action = clap::ArgAction::Set, default_value_t = DEFAULT.stopper_weights))]
    pub stopper_weights: bool,
    /// Training samples weighted per colour channel by the path's throughput in that channel
    /// (`W_c`; with `stopper_weights` `(1 - q) W_c / q`, with `survivor_weights` `W_c / q`):
    /// a level's channel `c` then holds `E[w W_c R_c] / E[w W_c]`, what a path that stops and
    /// adds `W_c` times it needs, where weighting every channel alike drops the covariance of
    /// a vertex's albedo and the radiance from it on (a red shell round a blue core: the
    /// shell's paths carry more red throughput and gather more red light; the blob scene's red
    /// rendered 2.7% dark without it). See `CachedPath::samples`.
    #[cfg_attr(feature = "clap", arg(long = "cache-channel-weights", action = clap::ArgAction::Set, default_value_t = DEFAULT.channel_weights))]
    pub channel_weights: bool,
    /// Each cache pixel's share of a level's training loss (and of its warm start's fit) is,
    /// per channel, the summed weight of the samples binned into it over the level's running
    /// mean of that sum, instead of one share per pixel. A level's value is then the weighted
    /// mean of its samples pooled over frames (not the mean of each frame's means, in which a
    /// pixel's one sample cancels its own weight), and where the Gaussians' blur must trade one
    /// pixel against another it favours those the weights say the image reads most (with
    /// `stopper_weights`: where paths stop). See `targets.rs`.
    #[cfg_attr(feature = "clap", arg(long = "cache-weighted-loss", action = clap::ArgAction::Set, default_value_t = DEFAULT.weighted_loss))]
    pub weighted_loss: bool,
    /// `adamw` or `adam` (no weight decay).
    #[cfg_attr(feature = "clap", arg(long = "cache-optimizer", value_enum, default_value_t = DEFAULT.optimizer))]
    pub optimizer: Optimizer,
    /// When Eq. 5's decay starts on a still view: `paper` (the first still frame), `plateau`
    /// (once the training error levels off) or `off`.
    #[cfg_attr(feature = "clap", arg(long = "cache-decay", value_enum, default_value_t = DEFAULT.decay))]
    pub decay: Decay,
    /// Learning rate of the means (the GSCache paper's section 4.1).
    #[cfg_attr(feature = "clap", arg(long = "cache-lr-position", default_value_t = DEFAULT.lr_position))]
    pub lr_position: f32,
    /// Learning rate of the colours, relative to each level's mean radiance (with
    /// `normalized_radiance`): 0.1, eight times the GSCache paper's 0.0125 for absolute colours,
    /// by measurement on four volumes after the experiments' orbit warm-up (0.0125, 0.05, 0.1,
    /// 0.25: 0.1 best or within a standard error of the best at 16 spp and 200 ms but for
    /// hydrogen's brightness, -1.5% against -0.6% at 0.05; BENCHMARKS.md).
    #[cfg_attr(feature = "clap", arg(long = "cache-lr-color", default_value_t = DEFAULT.lr_color))]
    pub lr_color: f32,
    /// Learning rate of the rotations.
    #[cfg_attr(feature = "clap", arg(long = "cache-lr-rotation", default_value_t = DEFAULT.lr_rotation))]
    pub lr_rotation: f32,
    /// Learning rate of the log-scales: 0 in the paper (Eq. 2's sizes are kept); the "-CO"
    /// ablation sets 0.0125.
    #[cfg_attr(feature = "clap", arg(long = "cache-lr-scales", default_value_t = DEFAULT.lr_scales))]
    pub lr_scales: f32,
    /// Learning rate of the opacities.
    #[cfg_attr(feature = "clap", arg(long = "cache-lr-opacity", default_value_t = DEFAULT.lr_opacity))]
    pub lr_opacity: f32,
    /// Multiplies every learning rate (sweeps move them together).
    #[cfg_attr(feature = "clap", arg(long = "cache-lr-multiplier", default_value_t = DEFAULT.lr_multiplier))]
    pub lr_multiplier: f32,
    /// AdamW's decoupled weight decay on colours and opacities (means, rotations and scales are
    /// not decayed: decay would pull every Gaussian towards the world origin).
    #[cfg_attr(feature = "clap", arg(long = "cache-weight-decay", default_value_t = DEFAULT.weight_decay))]
    pub weight_decay: f32,
    /// Eq. 2's cap (mean + 2 sd of the neighbour distances) and halving of the initial scales;
    /// false gives 3DGS's plain mean neighbour distance (the "-SC" ablation).
    #[cfg_attr(feature = "clap", arg(long = "cache-size-cap", action = clap::ArgAction::Set, default_value_t = DEFAULT.size_cap))]
    pub size_cap: bool,
    /// Opacity of every Gaussian at initialisation.
    #[cfg_attr(feature = "clap", arg(long = "cache-initial-opacity", default_value_t = DEFAULT.initial_opacity))]
    pub initial_opacity: f32,
    /// Train after each frame; false freezes the cache (it is still read).
    #[cfg_attr(feature = "clap", arg(long = "cache-train", action = clap::ArgAction::Set, default_value_t = DEFAULT.train))]
    pub train: bool,
    /// Take a training step on one frame in this many (1: every frame); the frames between
    /// are read but not trained on, which divides the training time by it.
    #[cfg_attr(feature = "clap", arg(long = "cache-train-every", default_value_t = DEFAULT.train_every))]
    pub train_every: u32,
    /// Train on every frame until the training error levels off on a still view, then on one
    /// frame in 4 (`schedule::SETTLED_TRAIN_EVERY`), back to every frame when the camera, the
    /// transfer function or the lights change: the GSCache paper's suggestion (its section 4.4)
    /// of spending training where it still helps. Frames without a step on a still camera reuse
    /// the last frame's level images, so they cost no cache time at all. Applies on top of
    /// `train_every`. Off by measurement: on chest CT, neghip, hydrogen and headsq it saved 6-15%
    /// of the time at 64 spp but the less-trained cache lost more than that (relMSE at 1 s
    /// 1.10-1.31x higher; BENCHMARKS.md): past the plateau, training still lowers the cache's
    /// error, which is what limits it at high spp.
    #[cfg_attr(feature = "clap", arg(long = "cache-adaptive-training", action = clap::ArgAction::Set, default_value_t = DEFAULT.adaptive_training))]
    pub adaptive_training: bool,
    /// Paths fall back to plain path tracing (no early or natural termination) at the pixels and
    /// levels whose last training residual was large and beyond its noise: a stale cache after
    /// an edit, or a fresh one, then costs variance instead of brightness (see `fallback.rs`).
    #[cfg_attr(feature = "clap", arg(long = "cache-fallback", action = clap::ArgAction::Set, default_value_t = DEFAULT.fallback))]
    pub fallback: bool,
    /// In an image accumulated over frames of a still view (`GsCache::start_image`), the frames
    /// after which paths stop reading the cache and it stops training: from then on the frames
    /// are plain path tracing, at its speed, so the cache's bias in the accumulated image
    /// shrinks as the plain frames add up, where the cache's own error would level off. Counted
    /// in frames whatever their spp. 0 never hands off. A camera move or a scene change ends
    /// the image; interactive frames (no `start_image`) never hand off. 16 by measurement
    /// (8, 16, 32 tried on four volumes after the experiments' warm-up): at 1 s the cache went
    /// from 0.52-0.99x NEE's relMSE to 0.92-1.06x, unchanged at 200 ms (BENCHMARKS.md). An
    /// image that will be denoised hands off after 2 ([`CacheConfig::for_denoiser`]): the
    /// frames a biased cache is worth scale with the noise the denoiser leaves (crate docs).
    #[cfg_attr(feature = "clap", arg(long = "cache-handoff-frames", default_value_t = DEFAULT.handoff_frames))]
    pub handoff_frames: u32,
    /// Frames over which a fresh level's colours are fitted straight to the samples (a running
    /// least-squares mean; see `warm_start.rs`) instead of by Adam; restarted when the scene
    /// changes. 0 leaves every step to Adam (the GSCache paper's).
    #[cfg_attr(feature = "clap", arg(long = "cache-warm-start-frames", default_value_t = DEFAULT.warm_start_frames))]
    pub warm_start_frames: u32,
    /// Train each level only where a path reached it (the per-level masks); false treats pixels
    /// without a sample as zero targets and renders too dark (kept for the ablation; see the
    /// crate docs).
    #[cfg_attr(feature = "clap", arg(long = "cache-masked-targets", action = clap::ArgAction::Set, default_value_t = DEFAULT.masked_targets))]
    pub masked_targets: bool,
    /// Draw each level's cloud times a radiance scale set from its first frame's samples, so the
    /// learning rates act in units of the scene's own radiance (Adam's steps are absolute).
    /// false gives the GSCache paper's absolute colours.
    #[cfg_attr(feature = "clap", arg(long = "cache-normalized-radiance", action = clap::ArgAction::Set, default_value_t = DEFAULT.normalized_radiance))]
    pub normalized_radiance: bool,
    /// The cache as a control variate, so the image is unbiased whatever the cache holds: every
    /// path that reaches a level adds the cached value C and goes on with probability q,
    /// adding (L - C) / q, where L is what it then gathers. q is chosen per level and cache
    /// pixel from the measured error of L - C and the cost of going on (see `control.rs`).
    /// Replaces Algorithm 1's selection (`c`, `threshold`, `early`) and natural termination;
    /// no handoff.
    #[cfg_attr(feature = "clap", arg(long = "cache-unbiased", action = clap::ArgAction::Set, default_value_t = DEFAULT.unbiased))]
    pub unbiased: bool,
    /// With `unbiased`: the least probability of going on past a level, which bounds a tail's
    /// weight 1 / q.
    #[cfg_attr(feature = "clap", arg(long = "cache-min-continuation", default_value_t = DEFAULT.min_continuation))]
    pub min_continuation: f32,
    /// With `unbiased`: a fixed kappa (q = clamp(kappa luminance(W), min_continuation, 1)) for
    /// every level and cache pixel, for ablations and tests; 0 lets the rule choose it from the
    /// measured error and cost.
    #[cfg_attr(feature = "clap", arg(long = "cache-continuation-scale", default_value_t = DEFAULT.continuation_scale))]
    pub continuation_scale: f32,
    /// Paths stop into a level (early or natural termination) only where, in the 3x3 cache
    /// pixels around theirs, at least this fraction of the paths through each reached the
    /// level's vertex over the last frames; elsewhere (thin halos, silhouettes, the volume's
    /// border) they go on as plain path tracing (see `support.rs`). 0 reads the cache
    /// everywhere, the default by measurement: 0.25-0.5 with `stopper_weights` halves what the
    /// denoiser leaves of the cache's error on hydrogen and default in motion, but takes the
    /// raw gain over NEE from 1.9-9.4x to 1.7-3.2x (docs/results/cache_error.md), so it is the
    /// setting for a cache that will be denoised.
    #[cfg_attr(feature = "clap", arg(long = "cache-min-coverage", default_value_t = DEFAULT.min_coverage))]
    pub min_coverage: f32,
    /// Paths stop into a level only where, in the 5x5 cache pixels around theirs, the level's
    /// residual against its targets over the last frames is within this fraction of the
    /// targets (beyond the noise: see `support.rs`); elsewhere they go on as plain path
    /// tracing. 0 turns the test off, the default: with it (0.03, stopper weights, in motion at
    /// equal time) the cache + OIDN's relMSE falls 1.1-1.7x and hydrogen's JOD rises 0.6-0.7,
    /// but the raw image's rises 1.2-1.6x (docs/results/cache_error.md); with `min_coverage` it is
    /// [`CacheConfig::for_denoiser`]'s setting. It also catches a change nobody reported (a
    /// light moved): 8 frames after one, 0.024 relMSE against 0.109 without it.
    #[cfg_attr(feature = "clap", arg(long = "cache-max-bias", default_value_t = DEFAULT.max_bias))]
    pub max_bias: f32,
    /// Adaptive density (`density.rs`): every this many training steps after the warm start,
    /// each level splits the Gaussians whose fit misses its targets by more than
    /// `densify_bias` (rms, relative, beyond the targets' noise) and drops those that draw
    /// nothing. 0 never does, the default (docs/results/cache_error.md measures it).
    #[cfg_attr(feature = "clap", arg(long = "cache-densify-every", default_value_t = DEFAULT.densify_every))]
    pub densify_every: u32,
    /// The relative rms miss over a Gaussian's footprint above which adaptive density splits
    /// it (0.02: 2%, about the error Open Image Denoise leaves of plain NEE at 200 ms).
    #[cfg_attr(feature = "clap", arg(long = "cache-densify-bias", default_value_t = DEFAULT.densify_bias))]
    pub densify_bias: f32,
    /// The most Gaussians adaptive density lets a level grow to, as a multiple of its first
    /// size: a bound on memory and on the lookup's cost.
    #[cfg_attr(feature = "clap", arg(long = "cache-densify-max", default_value_t = DEFAULT.densify_max))]
    pub densify_max: f32,
}

/// The defaults, as a constant so the command line's defaults are these very values.
const DEFAULT: CacheConfig = CacheConfig {
    levels: 3,
    points: 0,
    lookup: Lookup::Raster,
    resolution_divisor: 4,
    rt_samples: 8,
    c: 0.5,
    c_deep: 0.0,
    threshold: 0.9,
    min_coverage: 0.0,
    max_bias: 0.0,
    early: true,
    natural: true,
    survivor_weights: false,
    stopper_weights: true,
    channel_weights: true,
    weighted_loss: true,
    optimizer: Optimizer::AdamW,
    decay: Decay::Plateau,
    lr_position: 1.16e-3,
    lr_color: 0.1,
    lr_rotation: 1e-3,
    lr_scales: 0.0,
    lr_opacity: 1.5e-1,
    lr_multiplier: 1.0,
    weight_decay: 0.01,
    size_cap: true,
    initial_opacity: 0.5,
    train: true,
    train_every: 1,
    adaptive_training: false,
    fallback: true,
    handoff_frames: 16,
    warm_start_frames: 32,
    masked_targets: true,
    normalized_radiance: true,
    unbiased: false,
    min_continuation: 0.05,
    continuation_scale: 0.0,
    densify_every: 0,
    densify_bias: 0.02,
    densify_max: 4.0,
};

impl Default for CacheConfig {
    fn default() -> Self {
        DEFAULT
    }
}

/// The cache's size when `points` is 0: Gaussians per pixel of the cache image. The GSCache
/// paper's 300k Gaussians served 1920x1080 frames (0.14 per pixel); our size sweeps found 20k
/// best at 320x180 (0.35 per pixel) and the same density best at a quarter of the resolution
/// (1.25k for 80x45: docs/results/cost_*). A cloud cannot show more detail than the image it is
/// drawn into resolves, and each Gaussian more shares the same samples.
pub const GAUSSIANS_PER_CACHE_PIXEL: f64 = 0.35;

/// The most adaptive density may grow a level, as a multiple of its first size (the largest
/// `densify_max`): with the cap of `MAX_POINTS` on any level, a bound on the memory a typo can
/// ask for.
pub const MAX_DENSIFY_GROWTH: f32 = 16.0;

/// The most levels a cache may have (paths longer than this are never cached).
pub const MAX_LEVELS: usize = 8;

/// The most Gaussians the first level may hold (16.8 M): far past what any image needs (the
/// automatic size is 0.35 per cache pixel), and a bound on memory a typo can ask for.
pub const MAX_POINTS: usize = 1 << 24;

/// Bytes one trained Gaussian takes: 14 parameters, their gradients and Adam's two moments, f32.
pub const BYTES_PER_TRAINED_GAUSSIAN: u64 = 14 * 4 * 4;

impl CacheConfig {
    /// The settings [`CacheConfig::for_denoiser`] sets, by their names as keys and flags (a
    /// caller that lets the user name some keeps those).
    pub const FOR_DENOISER_KEYS: [&'static str; 3] = ["min_coverage", "max_bias", "handoff_frames"];

    /// These settings for an image that will be denoised: paths stop into a level only where
    /// at least half the paths around them reach its vertex (`min_coverage` 0.5) and its
    /// measured bias is within 3% (`max_bias`), and an image accumulated over passes of one
    /// view reads the cache in its first two only (`handoff_frames` 2). (The stoppers' weights
    /// on the targets, once part of this setting, are the default now.) Against the plain
    /// cache, both denoised by Open Image Denoise at equal time (the six bundled volumes on
    /// stills at 1 spp, 200 ms and 1 s), these settings' relMSE was 1.0-3.0x lower (2% higher
    /// only on chest_ct at 1 spp and 1 s), because the plain cache's structured error is what
    /// the filter keeps; the early handoff matters because a denoiser leaves so little of the
    /// plain passes' noise that the cache's bias outweighs its variance after a pass or two
    /// (the crate docs derive it; docs/results/cache_error.md). Raw, without a denoiser, the
    /// plain cache is the better one (relMSE 2.0-4.3x lower at 1 spp), so these are not the
    /// defaults; the program takes them when `--denoise` is on and none of
    /// [`CacheConfig::FOR_DENOISER_KEYS`] is given.
    pub fn for_denoiser(self) -> Self {
        Self {
            min_coverage: 0.5,
            max_bias: 0.03,
            handoff_frames: 2,
            ..self
        }
    }

    /// Whether error-aware termination's tests run (`support.rs`): coverage or measured bias.
    pub fn tests_support(&self) -> bool {
        self.min_coverage > 0.0 || self.max_bias > 0.0
    }

    /// Checks the settings, naming the one at fault.
    pub fn validate(&self) -> Result<(), crate::CacheError> {
        let bad = |what: String| Err(crate::CacheError::Config(what));
        if self.levels == 0 || self.levels > MAX_LEVELS {
            return bad(format!(
                "levels = {}: expected 1..={MAX_LEVELS}",
                self.levels
            ));
        }
        if self.points > MAX_POINTS {
            return bad(format!(
                "points = {}: expected at most {MAX_POINTS} Gaussians in the first level (about \
                 {} GB with the optimiser's state)",
                self.points,
                MAX_POINTS as u64 * BYTES_PER_TRAINED_GAUSSIAN / 1_000_000_000
            ));
        }
        // 0 is "choose from the image" (`for_image`).
        if self.points != 0 && self.points >> (self.levels - 1) < 4 {
            return bad(format!(
                "points = {} is too few for {} levels: the last level needs at least 4 Gaussians",
                self.points, self.levels
            ));
        }
        if !(self.c >= 0.0 && self.c.is_finite()) {
            return bad(format!(
                "c = {}: Algorithm 1's coefficient must be finite and >= 0",
                self.c
            ));
        }
        if !(self.threshold >= 0.0 && self.threshold <= 1.0) {
            return bad(format!(
                "threshold = {}: expected a value in [0, 1]",
                self.threshold
            ));
        }
        if !(1..=1000).contains(&self.train_every) {
            return bad(format!(
                "train_every = {}: expected 1..=1000 frames",
                self.train_every
            ));
        }
        if self.warm_start_frames > 1000 {
            return bad(format!(
                "warm_start_frames = {}: expected 0..=1000 frames",
                self.warm_start_frames
            ));
        }
        if self.densify_every > 1000 {
            return bad(format!(
                "densify_every = {}: expected 0 (off) or 1..=1000 training steps",
                self.densify_every
            ));
        }
        if !(self.densify_bias >= 0.0 && self.densify_bias.is_finite()) {
            return bad(format!(
                "densify_bias = {}: expected a finite relative error >= 0",
                self.densify_bias
            ));
        }
        if !(self.densify_max >= 1.0 && self.densify_max <= MAX_DENSIFY_GROWTH) {
            return bad(format!(
                "densify_max = {}: expected a growth factor in [1, {MAX_DENSIFY_GROWTH}]",
                self.densify_max
            ));
        }
        if !(1..=16).contains(&self.resolution_divisor) {
            return bad(format!(
                "resolution_divisor = {}: expected 1..=16",
                self.resolution_divisor
            ));
        }
        if self.lookup == Lookup::Rt && !(1..=64).contains(&self.rt_samples) {
            return bad(format!(
                "rt_samples = {}: expected 1..=64 samples per traversal",
                self.rt_samples
            ));
        }
        for (name, v) in [
            ("lr_position", self.lr_position),
            ("lr_color", self.lr_color),
            ("lr_rotation", self.lr_rotation),
            ("lr_scales", self.lr_scales),
            ("lr_opacity", self.lr_opacity),
            ("lr_multiplier", self.lr_multiplier),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return bad(format!("{name} = {v}: expected a finite value >= 0"));
            }
        }
        // A step of more than one unit in logit or log space per frame (the paper's opacity rate
        // is 0.15) throws a cache away in a few frames; refuse what can only explode.
        let lr = self.learning_rates();
        for (name, v) in [
            ("position", lr.position),
            ("color", lr.color),
            ("rotation", lr.rotation),
            ("scales", lr.scale),
            ("opacity", lr.opacity),
        ] {
            if v > 10.0 {
                return bad(format!(
                    "the {name} learning rate is {v} after lr_multiplier: expected at most 10 (a step that large only explodes the cache)"
                ));
            }
        }
        if !(self.min_continuation > 0.0 && self.min_continuation <= 1.0) {
            return bad(format!(
                "min_continuation = {}: expected a probability in (0, 1]",
                self.min_continuation
            ));
        }
        if !(0.0..=1.0).contains(&self.min_coverage) {
            return bad(format!(
                "min_coverage = {}: expected a fraction in [0, 1] (0: the cache is read everywhere)",
                self.min_coverage
            ));
        }
        if !(self.max_bias >= 0.0 && self.max_bias.is_finite()) {
            return bad(format!(
                "max_bias = {}: expected a finite fraction >= 0 (0: no bias test)",
                self.max_bias
            ));
        }
        if !(self.c_deep >= 0.0 && self.c_deep.is_finite()) {
            return bad(format!(
                "c_deep = {}: expected a finite value >= 0 (0: `c` at every level)",
                self.c_deep
            ));
        }
        if !(self.continuation_scale >= 0.0 && self.continuation_scale.is_finite()) {
            return bad(format!(
                "continuation_scale = {}: expected a finite value >= 0 (0: chosen by the rule)",
                self.continuation_scale
            ));
        }
        if !(self.weight_decay >= 0.0 && self.weight_decay.is_finite()) {
            return bad(format!(
                "weight_decay = {}: expected a finite value >= 0",
                self.weight_decay
            ));
        }
        if !(self.initial_opacity > 0.0 && self.initial_opacity < 1.0) {
            return bad(format!(
                "initial_opacity = {}: expected a value in (0, 1)",
                self.initial_opacity
            ));
        }
        Ok(())
    }

    /// These settings for frames of `width` x `height`: `points` chosen from the cache image's
    /// pixel count when it is 0 (at least 4 Gaussians in the last level).
    pub fn for_image(mut self, width: u32, height: u32) -> Self {
        if self.points == 0 {
            let map = crate::resolution::PixelMap::for_size(width, height, self.resolution_divisor);
            let pixels = map.width as f64 * map.height as f64;
            let least = 4usize << (self.levels.clamp(1, MAX_LEVELS) - 1);
            self.points = ((GAUSSIANS_PER_CACHE_PIXEL * pixels).round() as usize).max(least);
        }
        self
    }

    /// What one path needs: Algorithm 1's settings and natural termination.
    pub fn termination(&self) -> TerminationConfig {
        TerminationConfig {
            coefficient: self.c,
            deep_coefficient: if self.c_deep > 0.0 {
                self.c_deep
            } else {
                self.c
            },
            threshold: self.threshold,
            early: self.early && !self.unbiased,
            natural: self.natural && !self.unbiased,
            survivor_weights: self.survivor_weights && !self.unbiased,
            stopper_weights: self.stopper_weights && !self.unbiased,
            channel_weights: self.channel_weights && !self.unbiased,
            unbiased: self.unbiased,
            min_continuation: self.min_continuation,
        }
    }

    /// The learning rates training starts from (before Eq. 5), `lr_multiplier` applied.
    pub fn learning_rates(&self) -> LearningRates {
        let m = self.lr_multiplier;
        LearningRates {
            position: self.lr_position * m,
            color: self.lr_color * m,
            rotation: self.lr_rotation * m,
            scale: self.lr_scales * m,
            opacity: self.lr_opacity * m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_size_follows_the_cache_image() {
        // 320x180 at 1/4 is 80x45 = 3600 pixels: 1260 Gaussians.
        let c = CacheConfig::default().for_image(320, 180);
        assert_eq!(c.points, 1260);
        assert!(c.validate().is_ok());
        // Four times the pixels, four times the Gaussians.
        assert_eq!(CacheConfig::default().for_image(640, 360).points, 5040);
        // A tiny image still leaves 4 Gaussians in the last level.
        assert_eq!(CacheConfig::default().for_image(1, 1).points, 16);
        // A size given is kept.
        let given = CacheConfig {
            points: 777,
            ..Default::default()
        };
        assert_eq!(given.for_image(320, 180).points, 777);
    }

    #[test]
    fn bad_settings_are_refused_by_name() {
        let bad = |c: CacheConfig, key: &str| {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
        };
        let d = CacheConfig::default();
        bad(
            CacheConfig {
                resolution_divisor: 0,
                ..d
            },
            "resolution_divisor",
        );
        bad(
            CacheConfig {
                train_every: 0,
                ..d
            },
            "train_every",
        );
        bad(
            CacheConfig {
                warm_start_frames: 1001,
                ..d
            },
            "warm_start_frames",
        );
        bad(CacheConfig { c: f32::NAN, ..d }, "c = NaN");
        bad(
            CacheConfig {
                lr_multiplier: 1e30,
                ..d
            },
            "learning rate",
        );
        bad(CacheConfig { points: 3, ..d }, "too few");
    }
}
