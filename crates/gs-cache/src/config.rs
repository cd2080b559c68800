//! What a cache is asked to be: how many levels and Gaussians, how paths stop into it, how it
//! learns, and how it is read.

use serde::{Deserialize, Serialize};
use stochastic_rt::Estimator;

/// Per-parameter learning rates (the GSCache paper's section 4.1), before the schedule of Eq. 5.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearningRates {
    pub position: f32,
    pub color: f32,
    pub rotation: f32,
    /// 0 in the paper: the initial scales (Eq. 2) are kept. The ablation "-CO" sets 0.0125.
    pub scale: f32,
    pub opacity: f32,
}

impl Default for LearningRates {
    fn default() -> Self {
        Self {
            position: 1.16e-3,
            color: 1.25e-2,
            rotation: 1e-3,
            scale: 0.0,
            opacity: 1.5e-1,
        }
    }
}

impl LearningRates {
    /// Every rate multiplied by `factor`.
    pub fn scaled(self, factor: f32) -> Self {
        Self {
            position: self.position * factor,
            color: self.color * factor,
            rotation: self.rotation * factor,
            scale: self.scale * factor,
            opacity: self.opacity * factor,
        }
    }
}

/// How paths stop into the cache (the GSCache paper's sections 3.3-3.4; see the crate docs for the
/// estimator these settings define).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TerminationConfig {
    /// Algorithm 1's coefficient C: the continuation probability is
    /// `clamp(C * luminance(albedo product), 0, 1)`. 0 stops every path at its first vertex;
    /// large values never stop early.
    pub coefficient: f32,
    /// Algorithm 1's threshold: paths whose continuation probability is at or above it always
    /// continue.
    pub threshold: f32,
    /// Early termination (Algorithm 1) on or off.
    pub early: bool,
    /// Natural termination: a path that leaves the volume having carried no radiance takes the
    /// cached value of its length instead of zero.
    pub natural: bool,
}

impl Default for TerminationConfig {
    fn default() -> Self {
        Self {
            coefficient: 0.5,
            threshold: 0.9,
            early: true,
            natural: true,
        }
    }
}

/// How the renderer reads the cache each frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lookup {
    /// Rasterise each level with splat-raster (the paper's lookup).
    Raster,
    /// Ray-trace each level with stochastic-rt (BVH rebuilt per frame, since training moves the
    /// Gaussians). Training still uses the rasteriser's gradients.
    RayTrace { estimator: Estimator, spp: u32 },
}

impl Lookup {
    /// The ray-traced lookup with its default estimator: 8 stochastic samples per traversal.
    pub fn ray_traced() -> Self {
        Lookup::RayTrace {
            estimator: Estimator::Stochastic {
                samples_per_traversal: 8,
            },
            spp: 1,
        }
    }
}

/// Which optimiser trains the levels. Adam is AdamW without weight decay (the "-REG" ablation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Optimizer {
    AdamW,
    Adam,
}

/// Everything that defines a cache.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CacheConfig {
    /// Number of levels; level `i` (0-based) holds paths of length `i + 1`.
    pub levels: usize,
    /// Gaussians in the first level; level `i` has `points / 2^i`.
    pub points: usize,
    pub termination: TerminationConfig,
    pub learning_rates: LearningRates,
    pub optimizer: Optimizer,
    /// AdamW's decoupled weight decay on colours and opacities (means, rotations and scales are
    /// not decayed: decay would pull every Gaussian towards the world origin).
    pub weight_decay: f32,
    /// Eq. 2's cap (mean + 2 sd of the neighbour distances) and halving of the initial scales;
    /// off gives 3DGS's plain mean neighbour distance (the "-SC" ablation).
    pub size_cap: bool,
    /// Opacity of every Gaussian at initialisation.
    pub initial_opacity: f32,
    /// Train after each frame; off freezes the cache (it is still read).
    pub train: bool,
    /// Train each level only where a path reached it (the per-level masks). Off treats pixels
    /// without a sample as zero targets: the cache then learns values thinned by the probability
    /// of reaching the level and renders too dark (kept for the ablation; see the crate docs).
    pub masked_targets: bool,
    /// Each level draws its cloud times a radiance scale, set from the mean of its first
    /// frame's samples, so the learning rates act in units of the scene's own radiance (Adam's
    /// steps are absolute: without it, a scene lit 10x brighter adapts 10x slower). Off gives
    /// the GSCache paper's absolute colours.
    pub normalized_radiance: bool,
    pub lookup: Lookup,
}

impl Default for CacheConfig {
    fn default() -> Self {
        Self {
            levels: 3,
            points: 300_000,
            termination: TerminationConfig::default(),
            learning_rates: LearningRates::default(),
            optimizer: Optimizer::AdamW,
            weight_decay: 0.01,
            size_cap: true,
            initial_opacity: 0.5,
            train: true,
            masked_targets: true,
            normalized_radiance: true,
            lookup: Lookup::Raster,
        }
    }
}

/// The most levels a cache may have (paths longer than this are never cached).
pub const MAX_LEVELS: usize = 8;

impl CacheConfig {
    /// Checks the settings, naming the one at fault.
    pub fn validate(&self) -> Result<(), crate::CacheError> {
        let bad = |what: String| Err(crate::CacheError::Config(what));
        if self.levels == 0 || self.levels > MAX_LEVELS {
            return bad(format!(
                "levels = {}: expected 1..={MAX_LEVELS}",
                self.levels
            ));
        }
        if self.points >> (self.levels - 1) < 4 {
            return bad(format!(
                "points = {} is too few for {} levels: the last level needs at least 4 Gaussians",
                self.points, self.levels
            ));
        }
        let t = &self.termination;
        if !(t.coefficient >= 0.0 && t.coefficient.is_finite()) {
            return bad(format!(
                "termination coefficient C = {}: expected a finite value >= 0",
                t.coefficient
            ));
        }
        if !(t.threshold >= 0.0 && t.threshold <= 1.0) {
            return bad(format!(
                "termination threshold = {}: expected a value in [0, 1]",
                t.threshold
            ));
        }
        let lr = &self.learning_rates;
        for (name, v) in [
            ("position", lr.position),
            ("color", lr.color),
            ("rotation", lr.rotation),
            ("scale", lr.scale),
            ("opacity", lr.opacity),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return bad(format!(
                    "{name} learning rate = {v}: expected a finite value >= 0"
                ));
            }
        }
        if !(self.weight_decay >= 0.0 && self.weight_decay.is_finite()) {
            return bad(format!(
                "weight decay = {}: expected a finite value >= 0",
                self.weight_decay
            ));
        }
        if !(self.initial_opacity > 0.0 && self.initial_opacity < 1.0) {
            return bad(format!(
                "initial opacity = {}: expected a value in (0, 1)",
                self.initial_opacity
            ));
        }
        Ok(())
    }
}
