//! The bookkeeping one path needs to read and train the cache, so that every renderer linking
//! the cache gets it right: the albedo product of Algorithm 1, each level's throughput-relative
//! radiance sum (the training sample), early and natural termination.
//!
//! The renderer keeps its own throughput `W` and radiance sum `L`; it tells the path each change
//! it makes: a new real scattering vertex ([`CachedPath::vertex`]), a re-weighting such as
//! Russian roulette ([`CachedPath::scale`]), and radiance it adds as `W * x`
//! ([`CachedPath::radiance`]). At each vertex it asks either Algorithm 1
//! ([`CachedPath::continue_probability`], then [`CachedPath::stop_into_cache`]) or, with the
//! unbiased estimator, [`CachedPath::control_variate`], which makes the decision itself. See the
//! crate docs for both estimators.

use crate::cache::CacheFrame;
use crate::config::{MAX_LEVELS, TerminationConfig};
use crate::control::{self, PathStatistics, TailSample};
use crate::termination::{continue_probability_at, luminance};
use glam::Vec3;

/// The relative training weight, with `stopper_weights`, of a sample from a path that always
/// goes on at its level's vertex (see [`CachedPath::samples`]).
pub const ALWAYS_ON_WEIGHT: f32 = 1e-3;

/// What the unbiased estimator did at a vertex ([`CachedPath::control_variate`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ControlVariate {
    /// The path stops: the renderer adds `W * cached` and ends it.
    Stop { cached: Vec3 },
    /// The path goes on with probability `q`: the renderer adds `W * (cached - cached / q)`
    /// and divides its throughput by `q`.
    GoOn { cached: Vec3, q: f32 },
}

/// What the unbiased estimator recorded at one level's vertex, for its statistics.
#[derive(Debug, Clone, Copy, Default)]
struct LevelRead {
    /// The renderer's throughput there, before any `1 / q`.
    throughput: Vec3,
    cached: Vec3,
    /// 0 where the level was not read (not reached, or not trusted).
    q: f32,
    went_on: bool,
    /// The path's work at the decision (the vertex's next-event estimation included).
    cost: f32,
}

/// One path's view of the cache.
#[derive(Debug, Clone)]
pub struct CachedPath<'a> {
    frame: &'a CacheFrame,
    pixel: usize,
    /// The cache pixel holding `pixel`, for the fallback's verdicts.
    bin: usize,
    termination: TerminationConfig,
    /// Vertices so far (the path length if it ended now).
    length: usize,
    albedo_product: Vec3,
    /// Per level reached: the albedo product at its vertex (what Algorithm 1 saw there).
    albedo_at: [Vec3; MAX_LEVELS],
    /// Per level reached: the renderer's throughput at its vertex (`W_n`).
    throughput_at: [Vec3; MAX_LEVELS],
    /// Per level reached: the renderer's throughput divided by its throughput at that level's
    /// vertex, kept as a product (never a division by a tiny throughput).
    relative: [Vec3; MAX_LEVELS],
    /// Per level reached: the radiance gathered from its vertex on, per unit of its throughput.
    sums: [Vec3; MAX_LEVELS],
    /// Levels whose sample is complete and unbiased (the path went on past their vertex and
    /// ended without replacing its own future by the cache value of that same level).
    sampled: [bool; MAX_LEVELS],
    /// The path's own key (seed, pixel, sample): the unbiased estimator's decisions hash it.
    key: u64,
    /// The renderer's throughput `W` and radiance `L` as it reported them (the unbiased
    /// estimator's statistics need the path's estimate, not only its per-level sums).
    throughput: Vec3,
    total: Vec3,
    /// The path's work when it ended, in the renderer's unit ([`CachedPath::finished`]).
    cost: f32,
    reads: [LevelRead; MAX_LEVELS],
}

impl<'a> CachedPath<'a> {
    /// A path through row-major pixel `pixel` of the frame's camera. `key` must differ from
    /// path to path (a hash of the seed, the pixel and the sample index): the unbiased
    /// estimator's decisions are drawn from it, and would not be random across a pixel's
    /// samples if it repeated.
    pub fn new(
        frame: &'a CacheFrame,
        pixel: usize,
        key: u64,
        termination: TerminationConfig,
    ) -> Self {
        Self {
            frame,
            pixel,
            bin: frame.bin(pixel),
            termination,
            length: 0,
            albedo_product: Vec3::ONE,
            albedo_at: [Vec3::ONE; MAX_LEVELS],
            throughput_at: [Vec3::ONE; MAX_LEVELS],
            relative: [Vec3::ZERO; MAX_LEVELS],
            sums: [Vec3::ZERO; MAX_LEVELS],
            sampled: [false; MAX_LEVELS],
            key,
            throughput: Vec3::ONE,
            total: Vec3::ZERO,
            cost: 0.0,
            reads: [LevelRead::default(); MAX_LEVELS],
        }
    }

    fn active(&self) -> usize {
        self.length.min(self.frame.levels())
    }

    /// The path length so far.
    pub fn length(&self) -> usize {
        self.length
    }

    /// A new real scattering vertex with single-scattering albedo `albedo`, by which the
    /// renderer has just multiplied its throughput.
    pub fn vertex(&mut self, albedo: Vec3) {
        for m in 0..self.active() {
            self.relative[m] *= albedo;
        }
        self.throughput *= albedo;
        self.albedo_product *= albedo;
        self.length += 1;
        if self.length <= self.frame.levels() {
            let n = self.length - 1;
            self.relative[n] = Vec3::ONE;
            self.albedo_at[n] = self.albedo_product;
            self.throughput_at[n] = self.throughput;
            self.sums[n] = Vec3::ZERO;
            self.sampled[n] = true;
        }
    }

    /// The renderer multiplied its throughput by `factor` (e.g. `1 / p` after surviving Russian
    /// roulette with probability `p`).
    pub fn scale(&mut self, factor: Vec3) {
        for m in 0..self.active() {
            self.relative[m] *= factor;
        }
        self.throughput *= factor;
    }

    /// The renderer added `W * x` to its radiance.
    pub fn radiance(&mut self, x: Vec3) {
        for m in 0..self.active() {
            self.sums[m] += self.relative[m] * x;
        }
        self.total += self.throughput * x;
    }

    /// The unbiased estimator at the current vertex (`unbiased` on; `None` otherwise, and where
    /// no level holds this length, the fallback distrusts it here, its value is not finite or
    /// `q` is 1: the path then goes on as plain path tracing). Reads the level's value `C`,
    /// decides with probability `q` ([`control::probability`]) from the path's key, and keeps
    /// the bookkeeping: the shorter levels' samples take `C - C / q` (going on) or `C`
    /// (stopping), and this level's sample is the rest of the path, unweighted. `work` is the
    /// path's work so far (see [`CachedPath::finished`]).
    pub fn control_variate(&mut self, work: f32) -> Option<ControlVariate> {
        if !self.termination.unbiased || self.length == 0 || self.length > self.frame.levels() {
            return None;
        }
        let n = self.length - 1;
        // The level's value stands for what the path gathers after this decision, which comes
        // after the vertex's next-event estimation: its sample starts here, whatever is decided.
        self.sums[n] = Vec3::ZERO;
        let cached = self.frame.value(n, self.pixel);
        if !self.frame.trusted(n, self.bin) || !cached.is_finite() {
            return None;
        }
        let q = control::probability(
            self.frame.continuation_scale(n, self.bin),
            self.throughput,
            self.termination.min_continuation,
        );
        let went_on = q >= 1.0 || control::uniform(self.key, n) < q;
        self.reads[n] = LevelRead {
            throughput: self.throughput,
            cached,
            q,
            went_on,
            cost: work,
        };
        if q >= 1.0 {
            return None;
        }
        if went_on {
            let added = cached - cached / q;
            for m in 0..n {
                self.sums[m] += self.relative[m] * added;
                self.relative[m] /= q;
            }
            self.total += self.throughput * added;
            self.throughput /= q;
            Some(ControlVariate::GoOn { cached, q })
        } else {
            for m in 0..n {
                self.sums[m] += self.relative[m] * cached;
            }
            self.total += self.throughput * cached;
            self.sampled[n] = false;
            Some(ControlVariate::Stop { cached })
        }
    }

    /// The path has ended after `work`, in any deterministic unit of the renderer's (volume-pt
    /// counts the random numbers drawn: one per tracking step): the statistics' cost.
    pub fn finished(&mut self, work: f32) {
        self.cost = work;
    }

    /// What the path gives the unbiased estimator's statistics (see [`control`]), once it has
    /// ended ([`CachedPath::finished`]): `None` unless `unbiased` is on.
    pub fn statistics(&self) -> Option<PathStatistics> {
        if !self.termination.unbiased {
            return None;
        }
        let cost = self.cost;
        let mut tails = [TailSample::default(); MAX_LEVELS];
        for n in 0..self.active() {
            let read = &self.reads[n];
            let error = luminance(read.throughput * (self.sums[n] - read.cached)).powi(2);
            tails[n] = TailSample::from_read(
                read.q,
                read.went_on,
                luminance(read.throughput),
                error,
                (cost - read.cost).max(0.0),
            );
        }
        Some(PathStatistics {
            estimate: luminance(self.total),
            cost,
            tails,
            levels: self.frame.levels(),
        })
    }

    /// Algorithm 1 at the current vertex: the probability of going on. 1 where no level holds
    /// this length, early termination is off (or the unbiased estimator is on), or the fallback
    /// distrusts the level at this pixel.
    pub fn continue_probability(&self) -> f32 {
        if self.length == 0
            || self.length > self.frame.levels()
            || !self.frame.trusted(self.length - 1, self.bin)
        {
            return 1.0;
        }
        continue_probability_at(&self.termination, self.length - 1, self.albedo_product)
    }

    /// The path stops into the cache at the current vertex: returns `x`, the cached value of
    /// this length, which the renderer adds as `W * x`. The shorter levels take it into their
    /// samples; this level gets no sample from this path.
    pub fn stop_into_cache(&mut self) -> Vec3 {
        let Some(n) = self
            .length
            .checked_sub(1)
            .filter(|&n| n < self.frame.levels())
        else {
            return Vec3::ZERO;
        };
        let x = self.frame.value(n, self.pixel);
        self.sampled[n] = false;
        for m in 0..n {
            self.sums[m] += self.relative[m] * x;
        }
        x
    }

    /// The path left the volume after its last vertex. If natural termination is on, the level
    /// is trusted at this pixel and the path gathered no radiance at all (`path_radiance` is zero), returns the cached value of
    /// its length, which the renderer adds as `W * x` to the image only: the training samples
    /// stay the true (zero) ones. Otherwise returns zero.
    pub fn escaped(&self, path_radiance: Vec3) -> Vec3 {
        let carried_nothing = !(path_radiance.max_element() > 0.0);
        match self.length.checked_sub(1) {
            Some(n)
                if self.termination.natural
                    && carried_nothing
                    && n < self.frame.levels()
                    && self.frame.trusted(n, self.bin) =>
            {
                self.frame.value(n, self.pixel)
            }
            _ => Vec3::ZERO,
        }
    }

    /// The training samples the path produced: `(level, value, weight)` for every level whose
    /// vertex it reached and went on from, the weight one per colour channel. It is 1, or with
    /// `survivor_weights` the inverse of the probability with which Algorithm 1 let the path go
    /// on at that vertex: paths that go on are a selection of those that reach the vertex
    /// (biased towards bright albedo products), and the weight makes the level's target the
    /// mean over all of them.
    ///
    /// With `stopper_weights` the weight is `(1 - q) W_n / q`. What the image needs of level
    /// `n` at a pixel is the value the paths that *stop* there would have gathered, weighted by
    /// their throughput: stopping adds `W_n C` where going on would have added `W_n R_n`, so the
    /// image is unbiased when `C = E[(1 - q) W_n R_n] / E[(1 - q) W_n]` over the paths that
    /// reach the vertex (the crate docs' second bias term then vanishes for a cache that fits
    /// its targets). The samples come from the paths that went on, drawn with probability `q`,
    /// so each carries `(1 - q) W_n / q`. The products are per channel, and so is the weight
    /// with `channel_weights` (`W_n^c`); without it every channel weighs `lum(W_n)`, which
    /// corrects the selection but not the covariance of albedo and radiance within a channel
    /// (the crate docs measure both). On hydrogen's dense core, where the paths through bright
    /// albedo (likely to go on) are the shadowed ones, survivors' samples are darker than the
    /// stoppers' and the unweighted target renders 1.1% dark at the first level; these weights
    /// leave -0.3%, where `survivor_weights` (the mean over all paths) overshoots to +0.7%
    /// (docs/results/cache_error.md). A path that always goes on (`q = 1`) never needs the
    /// level, but keeps a weight of [`ALWAYS_ON_WEIGHT`] times its throughput, so that a pixel
    /// only such paths reach is still trained (natural termination reads it). With
    /// `channel_weights` and neither of the others the weight is `W_n^c` alone.
    pub fn samples(&self) -> impl Iterator<Item = (usize, Vec3, Vec3)> + '_ {
        let t = &self.termination;
        (0..self.active())
            .filter(|&m| self.sampled[m])
            .map(move |m| {
                // The throughput factor: per channel, or (stopper weights) its luminance in every
                // channel, or (otherwise) none.
                let throughput = || {
                    if t.channel_weights {
                        self.throughput_at[m].max(Vec3::ZERO)
                    } else if t.stopper_weights {
                        Vec3::splat(luminance(self.throughput_at[m]).max(0.0))
                    } else {
                        Vec3::ONE
                    }
                };
                let w = if t.stopper_weights || t.survivor_weights {
                    let q = continue_probability_at(t, m, self.albedo_at[m]);
                    let w = throughput();
                    match (t.stopper_weights, q > 0.0 && q < 1.0) {
                        (true, true) => (1.0 - q) * w / q,
                        (true, false) => ALWAYS_ON_WEIGHT * w,
                        (false, true) => w / q,
                        (false, false) => w,
                    }
                } else {
                    throughput()
                };
                (m, self.sums[m], w)
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CacheConfig, GsCache};

    /// A one-level cache of 64 points drawn from a camera looking at them.
    fn drawn_cache(config: CacheConfig) -> GsCache {
        let (mut cache, camera) = crate::test_support::grid_cache(config);
        cache.begin_frame(&camera);
        cache
    }

    /// One path's sample at its first vertex (albedo `albedo`, so `W = albedo`) that gathered
    /// 2: its per-channel weight.
    fn weight_at(config: CacheConfig, albedo: Vec3) -> Vec3 {
        let cache = drawn_cache(config);
        let frame = cache.frame().unwrap();
        let mut path = CachedPath::new(frame, 0, 1, cache.config().termination());
        path.vertex(albedo);
        path.radiance(Vec3::splat(2.0));
        let samples: Vec<_> = path.samples().collect();
        assert_eq!(samples.len(), 1);
        assert_eq!((samples[0].0, samples[0].1), (0, Vec3::splat(2.0)));
        samples[0].2
    }

    /// [`weight_at`] for a grey albedo of 0.8, where every channel weighs the same.
    fn weight(config: CacheConfig) -> f32 {
        let w = weight_at(config, Vec3::splat(0.8));
        assert!(w.x == w.y && w.y == w.z, "{w}");
        w.x
    }

    #[test]
    fn training_weights_follow_the_chosen_population() {
        let c = CacheConfig {
            stopper_weights: false,
            channel_weights: false,
            ..CacheConfig::default()
        };
        // Algorithm 1 with C = 0.5 at albedo 0.8: q = 0.4.
        assert_eq!(weight(c), 1.0);
        let survivors = CacheConfig {
            survivor_weights: true,
            ..c
        };
        assert!((weight(survivors) - 1.0 / 0.4).abs() < 1e-5);
        // The paths that stop: (1 - q) W / q = 0.6 * 0.8 / 0.4, whatever survivor_weights says.
        let stoppers = CacheConfig {
            stopper_weights: true,
            survivor_weights: true,
            ..c
        };
        assert!(
            (weight(stoppers) - 1.2).abs() < 1e-5,
            "{}",
            weight(stoppers)
        );
        // A path that always goes on (C = 2: q = 1.6, clamped to 1) keeps a token weight.
        let always_on = CacheConfig {
            stopper_weights: true,
            c: 2.0,
            ..c
        };
        assert!((weight(always_on) - ALWAYS_ON_WEIGHT * 0.8).abs() < 1e-8);
    }

    /// With `channel_weights` each channel weighs by the throughput in that channel, where
    /// without it every channel weighs by the throughput's luminance.
    #[test]
    fn channel_weights_weigh_each_channel_by_its_own_throughput() {
        let red = Vec3::new(0.9, 0.2, 0.1);
        let lum = crate::termination::luminance(red);
        // q = C lum = 0.5 lum, so (1 - q) / q.
        let q = 0.5 * lum;
        let stoppers = CacheConfig {
            stopper_weights: true,
            channel_weights: false,
            ..CacheConfig::default()
        };
        let w = weight_at(stoppers, red);
        assert!(
            (w - Vec3::splat((1.0 - q) * lum / q)).abs().max_element() < 1e-5,
            "{w}"
        );
        let per_channel = CacheConfig {
            channel_weights: true,
            ..stoppers
        };
        let w = weight_at(per_channel, red);
        assert!((w - (1.0 - q) * red / q).abs().max_element() < 1e-5, "{w}");
        // Without stopper weights, the throughput alone.
        let plain = CacheConfig {
            stopper_weights: false,
            ..per_channel
        };
        assert_eq!(weight_at(plain, red), red);
    }
}
