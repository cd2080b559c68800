//! The unbiased estimator's continuation probabilities: what it measures of the frame's paths,
//! per cache pixel and level, and the rule that turns it into `q` (the crate docs derive both).
//!
//! Every path that reaches level `n`'s vertex with throughput `W` (luminance `w`) reads the
//! cache value `C` and goes on with probability `q = clamp(kappa * w, q_min, 1)`, where
//! `kappa` belongs to the level and the path's cache pixel. What a path gives the statistics:
//! - its estimate `I` (luminance), `I^2` and its cost `T` (work in the renderer's own
//!   deterministic unit: volume-pt counts random numbers drawn, one per tracking step, so the
//!   choice, and the image, are the same on any machine and thread count), for the image-wide
//!   variance and cost;
//! - per level where it went on: `e / (w q)` and `w t / q`, where `e = lum(W (R - C))^2` is the
//!   squared error of its tail against the cache and `t` the tail's cost; the `1 / q` makes
//!   both unbiased estimates of their means over every path that reached the vertex.

use crate::resolution::PixelMap;
use glam::Vec3;

/// Relative error's floor, as the experiments' relMSE takes it: `(I - mean)^2 / (mean^2 + EPS)`.
const RELATIVE_EPSILON: f64 = 0.01;

/// How much of the last frames' statistics a new frame keeps: an exponential average over about
/// `1 / (1 - DECAY)` = 10 frames, so `kappa` follows a moving camera or an edit within a few
/// frames and is not spoilt by one frame's noise.
const DECAY: f64 = 0.9;

/// A cache pixel's tail statistics are shrunk towards its level's image-wide ones with the
/// weight of this many paths (after the decay): a pixel's few paths that went on can make its
/// tail error look near zero by chance, and a `kappa` taken from that would stop nearly every
/// path there with the weight `1 / q_min` (measured: relMSE 2.5x NEE's on neghip before).
const PRIOR_PATHS: f64 = 64.0;

/// A level whose best possible gain ([`LevelSummary::best_gain`]) is below this lets every path
/// go on: within 5% of the optimum whatever `q`, and safe from errors in the statistics, which
/// can only cost variance. On all six bundled volumes every level is below it (1.00-1.06x;
/// BENCHMARKS.md), so the unbiased estimator is plain path tracing there.
const MIN_GAIN: f64 = 1.05;

/// What one path gives a level's statistics: `e / (w q)` and `w t / q` where it went on past the
/// level's vertex, zeros elsewhere.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TailSample {
    pub error: f32,
    pub cost: f32,
    /// `e / q` and `t / q`: estimates of the tail's squared error and cost were every path to go
    /// on (the diagnosis in [`LevelSummary`]).
    pub plain_error: f32,
    pub plain_cost: f32,
    /// `q` where the path reached the level's decision, and 1 there (0 elsewhere): the mean
    /// probability of going on.
    pub q: f32,
    pub reached: f32,
}

/// Tail sums per level: error, cost, plain error, plain cost, q, reached.
const TAIL_SUMS: usize = 6;

impl TailSample {
    /// What a path gives a level where it reached the decision with probability `q` of going
    /// on (0: it did not reach it) and throughput luminance `w`; where it went on, `e` is the
    /// squared luminance of `W (R - C)` and `t` its work from there on.
    pub fn from_read(q: f32, went_on: bool, w: f32, e: f32, t: f32) -> Self {
        if !(q > 0.0) {
            return Self::default();
        }
        let mut s = Self {
            q,
            reached: 1.0,
            ..Self::default()
        };
        if went_on && w > 0.0 {
            s.error = e / (w * q);
            s.cost = w * t / q;
            s.plain_error = e / q;
            s.plain_cost = t / q;
        }
        s
    }

    fn sums(&self) -> [f32; TAIL_SUMS] {
        [
            self.error,
            self.cost,
            self.plain_error,
            self.plain_cost,
            self.q,
            self.reached,
        ]
    }
}

/// What the running statistics say of one level: how often paths go on, and how much the
/// unbiased estimator could gain there at best.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelSummary {
    /// The mean probability of going on over the paths that reached the level.
    pub mean_q: f64,
    /// The tail's share of the image's relative variance and of its cost, were every path to
    /// go on (`v` and `t`).
    pub variance_share: f64,
    pub cost_share: f64,
    /// The most any `q` can gain in efficiency over going on always:
    /// `1 / (sqrt((1 - v)(1 - t)) + sqrt(v t))^2`, the two-level multilevel Monte Carlo bound
    /// (crate docs). 1 when `v = t`.
    pub best_gain: f64,
}

/// What one path gives the statistics: its estimate, its cost and its tails.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathStatistics {
    /// Luminance of the path's estimate.
    pub estimate: f32,
    /// Its work, in the renderer's deterministic unit (volume-pt: random numbers drawn, one per
    /// tracking step).
    pub cost: f32,
    /// Per level (`levels` of them).
    pub tails: [TailSample; crate::config::MAX_LEVELS],
    pub levels: usize,
}

/// Sums over paths (for one pixel or one cache pixel).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Sums {
    pub paths: f64,
    pub estimate: f64,
    pub estimate_squared: f64,
    pub cost: f64,
}

impl Sums {
    fn add(&mut self, s: &PathStatistics) {
        let i = s.estimate as f64;
        self.paths += 1.0;
        self.estimate += i;
        self.estimate_squared += i * i;
        self.cost += s.cost as f64;
    }
    fn merge(&mut self, o: &Sums, decay: f64) {
        self.paths = self.paths * decay + o.paths;
        self.estimate = self.estimate * decay + o.estimate;
        self.estimate_squared = self.estimate_squared * decay + o.estimate_squared;
        self.cost = self.cost * decay + o.cost;
    }
}

/// Per pixel (of a tile, a frame or the cache image): the paths' sums and, per level, their
/// tails' sums.
#[derive(Debug, Clone, PartialEq)]
pub struct Statistics {
    levels: usize,
    pixels: Vec<Sums>,
    /// `levels` per pixel: the tails' sums ([`TailSample`]).
    tails: Vec<[f64; TAIL_SUMS]>,
}

impl Statistics {
    pub fn new(levels: usize, pixels: usize) -> Self {
        Self {
            levels,
            pixels: vec![Sums::default(); pixels],
            tails: vec![[0.0; TAIL_SUMS]; pixels * levels],
        }
    }

    pub fn pixels(&self) -> usize {
        self.pixels.len()
    }

    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Files one path through `pixel`. Paths with a non-finite figure are left out (they are
    /// counted apart by the renderer), so one cannot spoil a cache pixel's `kappa`.
    pub fn add(&mut self, pixel: usize, s: &PathStatistics) {
        let finite = s.estimate.is_finite()
            && s.cost.is_finite()
            && s.tails[..s.levels]
                .iter()
                .all(|t| t.sums().iter().all(|v| v.is_finite()));
        if !finite || pixel >= self.pixels.len() {
            return;
        }
        self.pixels[pixel].add(s);
        for (l, t) in s.tails[..s.levels.min(self.levels)].iter().enumerate() {
            let k = &mut self.tails[pixel * self.levels + l];
            for (k, v) in k.iter_mut().zip(t.sums()) {
                *k += v as f64;
            }
        }
    }

    /// Adds pixel `from` of `other` into pixel `to` of these, after multiplying these by `decay`
    /// (1 to sum).
    fn merge_pixel(&mut self, to: usize, other: &Statistics, from: usize, decay: f64) {
        self.pixels[to].merge(&other.pixels[from], decay);
        for l in 0..self.levels.min(other.levels) {
            let a = &mut self.tails[to * self.levels + l];
            let b = other.tails[from * other.levels + l];
            for (a, b) in a.iter_mut().zip(b) {
                *a = *a * decay + b;
            }
        }
    }

    /// Adds a tile's statistics (tile pixel `(i, j)` is frame pixel `(x0 + i, y0 + j)`) into
    /// these per cache pixel of `map`, and each pixel's moments into `moments` (per frame
    /// pixel: paths, summed estimates, summed squares).
    pub fn add_tile(
        &mut self,
        tile: &Statistics,
        (x0, y0, width): (u32, u32, u32),
        map: &PixelMap,
        moments: &mut [[f32; 3]],
    ) {
        let frame_width = map.frame_size().0;
        for p in 0..tile.pixels.len() {
            let s = &tile.pixels[p];
            if s.paths > 0.0 {
                let (x, y) = (x0 + p as u32 % width, y0 + p as u32 / width);
                self.merge_pixel(map.bin(x, y), tile, p, 1.0);
                if let Some(m) = moments.get_mut((y * frame_width + x) as usize) {
                    m[0] += s.paths as f32;
                    m[1] += s.estimate as f32;
                    m[2] += s.estimate_squared as f32;
                }
            }
        }
    }
}

/// The running statistics of the last frames per cache pixel, and the `kappa` they give.
#[derive(Debug, Clone, PartialEq)]
pub struct Continuation {
    map: PixelMap,
    running: Statistics,
    /// Per frame pixel: paths, summed estimates, summed squares (decayed like `running`). A
    /// pixel's variance comes from its own paths: a cache pixel's paths spread over several
    /// frame pixels, whose differences are not noise.
    moments: Vec<[f64; 3]>,
}

impl Continuation {
    pub fn new(levels: usize, map: PixelMap) -> Self {
        let (w, h) = map.frame_size();
        Self {
            map,
            running: Statistics::new(levels, map.width as usize * map.height as usize),
            moments: vec![[0.0; 3]; w as usize * h as usize],
        }
    }

    /// Pixels of the cache image.
    pub fn cache_pixels(&self) -> usize {
        self.running.pixels()
    }

    /// Whether these are for `levels` levels under `map`.
    pub fn fits(&self, levels: usize, map: &PixelMap) -> bool {
        self.running.levels == levels && self.map == *map
    }

    /// One frame's statistics (per cache pixel, and each frame pixel's `moments`) join the
    /// running ones; older frames fade.
    pub fn observe(&mut self, frame: &Statistics, moments: &[[f32; 3]]) {
        if frame.levels != self.running.levels
            || frame.pixels() != self.running.pixels()
            || moments.len() != self.moments.len()
        {
            return;
        }
        for b in 0..frame.pixels() {
            self.running.merge_pixel(b, frame, b, DECAY);
        }
        for (m, f) in self.moments.iter_mut().zip(moments) {
            for k in 0..3 {
                m[k] = m[k] * DECAY + f[k] as f64;
            }
        }
    }

    /// The camera moved: a frame pixel's earlier paths saw other points, and their spread is
    /// not noise, so the pixels' moments start again (the cache pixels' tail statistics are
    /// kept: they fade within frames).
    pub fn camera_moved(&mut self) {
        self.moments.fill([0.0; 3]);
    }

    /// Per cache pixel: the mean variance of one path's estimate over its frame pixels (those
    /// with two paths or more after the decay), or NaN where there are none.
    fn pixel_variances(&self) -> Vec<f64> {
        let (w, h) = self.map.frame_size();
        let mut sums = vec![[0.0f64; 2]; self.running.pixels()];
        for y in 0..h {
            for x in 0..w {
                let [n, s, s2] = self.moments[(y * w + x) as usize];
                if n >= 2.0 {
                    let mean = s / n;
                    let var = (s2 / n - mean * mean).max(0.0) * n / (n - 1.0);
                    let b = &mut sums[self.map.bin(x, y)];
                    b[0] += var;
                    b[1] += 1.0;
                }
            }
        }
        sums.iter()
            .map(|&[v, n]| if n > 0.0 { v / n } else { f64::NAN })
            .collect()
    }

    /// Per level and cache pixel, `kappa`: where the paths' statistics say nothing yet (no path
    /// has gone on past the level, or no pixel has two paths on a still view), `default`.
    ///
    /// The rule (derived in the crate docs): minimise the image's relative variance per path
    /// times its cost per path. A cache pixel `b`'s tail at level `n` adds `A / kappa` to the
    /// variance and costs `B kappa`, with `A = E[e / w] / (mu_b^2 + eps)` and `B = E[w t]`; the
    /// optimum spends where variance is cheapest to remove, `kappa = sqrt(A / B * T / V)`, with
    /// `T` and `V` the image's cost and relative variance per path.
    pub fn kappa(&self, default: f32) -> Vec<Vec<f32>> {
        self.rule(default).0
    }

    /// Per level, what the running statistics say (see [`LevelSummary`]); empty before any.
    pub fn summary(&self) -> Vec<LevelSummary> {
        self.rule(f32::INFINITY).1
    }

    fn rule(&self, default: f32) -> (Vec<Vec<f32>>, Vec<LevelSummary>) {
        let s = &self.running;
        let pixel_variances = self.pixel_variances();
        let (mut paths, mut cost, mut variance) = (0.0f64, 0.0f64, 0.0f64);
        // Per level: relative error, cost, relative plain error, plain cost, q, reached.
        let mut relative_tails = vec![[0.0f64; TAIL_SUMS]; s.levels];
        for (b, p) in s.pixels.iter().enumerate() {
            let var = pixel_variances[b];
            if p.paths < 2.0 || var.is_nan() {
                continue;
            }
            let mean = p.estimate / p.paths;
            let weight = 1.0 / (mean * mean + RELATIVE_EPSILON);
            paths += p.paths;
            cost += p.cost;
            variance += var * weight * p.paths;
            for (l, t) in relative_tails.iter_mut().enumerate() {
                let k = s.tails[b * s.levels + l];
                for (i, (t, k)) in t.iter_mut().zip(k).enumerate() {
                    *t += if i == 0 || i == 2 { k * weight } else { k };
                }
            }
        }
        // The image-wide cost and relative variance per path.
        let image_ratio = if paths > 0.0 && variance > 0.0 {
            Some(cost / variance)
        } else {
            None
        };
        let rule = |a: f64, b: f64| -> Option<f32> {
            let k = (a / b * image_ratio?).sqrt();
            // Written so that NaN gives None (the default).
            (k >= 0.0 && k.is_finite()).then_some(k as f32)
        };
        let summary = if paths > 0.0 && variance > 0.0 && cost > 0.0 {
            relative_tails
                .iter()
                .map(|t| {
                    let v = (t[2] / variance).clamp(0.0, 1.0);
                    let c = (t[3] / cost).clamp(0.0, 1.0);
                    LevelSummary {
                        mean_q: if t[5] > 0.0 { t[4] / t[5] } else { f64::NAN },
                        variance_share: v,
                        cost_share: c,
                        best_gain: 1.0 / (((1.0 - v) * (1.0 - c)).sqrt() + (v * c).sqrt()).powi(2),
                    }
                })
                .collect()
        } else {
            Vec::new()
        };
        let kappa = (0..s.levels)
            .map(|l| {
                let [a_level, b_level, ..] = relative_tails[l];
                if summary.get(l).is_some_and(|s| !(s.best_gain >= MIN_GAIN)) {
                    return vec![f32::INFINITY; s.pixels.len()];
                }
                let level_kappa = rule(a_level, b_level).unwrap_or(default);
                let (a_mean, b_mean) = (a_level / paths.max(1.0), b_level / paths.max(1.0));
                s.pixels
                    .iter()
                    .enumerate()
                    .map(|(b, p)| {
                        let k = s.tails[b * s.levels + l];
                        let mean = if p.paths > 0.0 {
                            p.estimate / p.paths
                        } else {
                            0.0
                        };
                        let weight = 1.0 / (mean * mean + RELATIVE_EPSILON);
                        let n = p.paths + PRIOR_PATHS;
                        rule(
                            (k[0] * weight + PRIOR_PATHS * a_mean) / n,
                            (k[1] + PRIOR_PATHS * b_mean) / n,
                        )
                        .unwrap_or(level_kappa)
                    })
                    .collect()
            })
            .collect();
        (kappa, summary)
    }
}

/// The probability that a path of throughput `throughput` goes on past a level's vertex whose
/// `kappa` is `kappa`: `clamp(kappa * luminance, q_min, 1)`. NaN gives 1 (plain path tracing
/// there, which is unbiased too).
pub fn probability(kappa: f32, throughput: Vec3, q_min: f32) -> f32 {
    let q = kappa * crate::termination::luminance(throughput);
    if q >= q_min {
        q.min(1.0)
    } else if q.is_nan() {
        1.0
    } else {
        q_min
    }
}

/// A uniform number in [0, 1) for the decision at `level` of the path whose key is `key`: a
/// stateless hash, not the path's own random stream, so that a path that goes on draws exactly
/// the random numbers it would draw without the cache.
pub fn uniform(key: u64, level: usize) -> f32 {
    let h =
        render_base::hash::splitmix64(key ^ (level as u64 + 1).wrapping_mul(0xd1b5_4a32_d192_ed03));
    (h >> 40) as f32 * (1.0 / 16_777_216.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path of estimate `estimate` and work `cost` that went on past level 0 (with `q = 1`)
    /// with tail error and cost `tail` (as the rule weighs them) and `plain` (were every path
    /// to go on).
    fn path(estimate: f32, cost: f32, tail: (f32, f32), plain: (f32, f32)) -> PathStatistics {
        let mut tails = [TailSample::default(); crate::config::MAX_LEVELS];
        tails[0] = TailSample {
            error: tail.0,
            cost: tail.1,
            plain_error: plain.0,
            plain_cost: plain.1,
            q: 1.0,
            reached: 1.0,
        };
        PathStatistics {
            estimate,
            cost,
            tails,
            levels: 1,
        }
    }

    #[test]
    fn probability_clamps_and_nan_goes_on() {
        assert_eq!(probability(0.5, Vec3::splat(0.8), 0.05), 0.4);
        assert_eq!(probability(10.0, Vec3::ONE, 0.05), 1.0);
        assert_eq!(probability(0.0, Vec3::ONE, 0.05), 0.05);
        assert_eq!(probability(f32::NAN, Vec3::ONE, 0.05), 1.0);
    }

    #[test]
    fn the_hash_is_uniform() {
        // 2^16 draws in 16 bins: chi-square with 15 degrees of freedom, 1e-6 false alarm at 57.
        let mut bins = [0u32; 16];
        for key in 0..1u64 << 16 {
            bins[(uniform(key, 1) * 16.0) as usize] += 1;
        }
        let e = (1u32 << 12) as f64;
        let chi: f64 = bins.iter().map(|&b| (b as f64 - e).powi(2) / e).sum();
        assert!(chi < 57.0, "{chi}");
        // Levels draw different numbers.
        assert_ne!(uniform(7, 0), uniform(7, 1));
    }

    /// The rule against its closed form: two cache pixels of 100 paths each, of mean 1,
    /// variance 100/99 and cost 4; pixel 0's tail error is four times pixel 1's at equal tail
    /// cost. Each pixel's figures are shrunk towards the image's with the weight of
    /// `PRIOR_PATHS` paths, so its `kappa` is `sqrt((400 + 64 * 2.5) / (100 + 64 * 2.5))`
    /// times pixel 1's, not twice.
    #[test]
    fn kappa_follows_the_rule() {
        let map = PixelMap::for_size(2, 1, 1);
        let mut frame = Statistics::new(1, 2);
        let mut tile = Statistics::new(1, 2);
        for k in 0..100 {
            let i = if k % 2 == 0 { 0.0 } else { 2.0 };
            // The tails are 3 of the 4 units of work and hold little of the variance: the
            // bound is far above `MIN_GAIN`, so the rule applies.
            tile.add(0, &path(i, 4.0, (4.0, 1.0), (0.01, 3.0)));
            tile.add(1, &path(i, 4.0, (1.0, 1.0), (0.01, 3.0)));
        }
        let mut moments = vec![[0.0; 3]; 2];
        frame.add_tile(&tile, (0, 0, 2), &map, &mut moments);
        let mut c = Continuation::new(1, map);
        c.observe(&frame, &moments);
        let k = c.kappa(0.5);
        // Relative weight 1 / 1.01; A_0 = (400 + 64 * 2.5) / 164 / 1.01, B = 1,
        // T / V = 4 / (100/99 / 1.01).
        assert_eq!(PRIOR_PATHS, 64.0);
        let v = 100.0f64 / 99.0 / 1.01;
        let a0 = (400.0 + 64.0 * 2.5) / 164.0 / 1.01;
        let expect0 = (a0 * 4.0 / v).sqrt() as f32;
        assert!(
            (k[0][0] - expect0).abs() < 1e-5 * expect0,
            "{k:?} {expect0}"
        );
        let ratio = (560.0f32 / 260.0).sqrt();
        assert!((k[0][0] / k[0][1] - ratio).abs() < 1e-5, "{k:?}");
        let summary = c.summary();
        assert!(summary[0].best_gain > 2.0, "{summary:?}");
        assert_eq!(summary[0].mean_q, 1.0);
        // Where the tail holds as much of the variance as of the work, no q gains: every path
        // goes on.
        let mut even = Continuation::new(1, map);
        let (mut f, mut t) = (Statistics::new(1, 2), Statistics::new(1, 2));
        for k in 0..100 {
            let i = if k % 2 == 0 { 0.0 } else { 2.0 };
            t.add(0, &path(i, 4.0, (4.0, 1.0), (0.5, 2.0)));
            t.add(1, &path(i, 4.0, (1.0, 1.0), (0.5, 2.0)));
        }
        let mut moments = vec![[0.0; 3]; 2];
        f.add_tile(&t, (0, 0, 2), &map, &mut moments);
        even.observe(&f, &moments);
        assert!(
            even.summary()[0].best_gain < MIN_GAIN,
            "{:?}",
            even.summary()
        );
        assert_eq!(even.kappa(0.5), vec![vec![f32::INFINITY; 2]]);
        // Without tails, the default.
        let mut none = Continuation::new(1, map);
        let mut f = Statistics::new(1, 2);
        let mut t = Statistics::new(1, 2);
        for _ in 0..40 {
            t.add(0, &path(1.0, 1.0, (0.0, 0.0), (0.0, 0.0)));
        }
        let mut moments = vec![[0.0; 3]; 2];
        f.add_tile(&t, (0, 0, 2), &map, &mut moments);
        none.observe(&f, &moments);
        assert_eq!(none.kappa(0.5), vec![vec![0.5, 0.5]]);
    }
}
