//! Where a level has earned trust: error-aware termination's two tests (issue 53).
//!
//! **Coverage.** A level's value at a cache pixel is a fit to the samples of the paths that
//! reached its vertex there. Where few of the paths through a cache pixel reach the vertex (a
//! thin halo, a silhouette the pixel's footprint straddles), the fit is made mostly by the
//! Gaussians' reach from denser neighbours, and the bilinear read mixes in cache pixels that
//! hold no target at all: the cache's error there is its reconstruction, not noise, and the
//! denoiser keeps it as blotches and dark rims (docs/results/cache_error.md, points 4 and 5).
//! Per level and cache pixel, the *coverage* is the fraction of the paths through the pixel
//! that reached the level's vertex (stopped or not), kept as decayed sums over the last frames
//! (`reached / paths`, each multiplied by [`DECAY`] per frame, so a camera move forgets in a
//! few frames). Coverage is a property of the volume, the transfer function and the view, not
//! of the cache's state, and is as good after one frame as after many.
//!
//! **Measured bias.** Where the paths do reach the vertex, the fit may still be off: the
//! Gaussians blur a dense core's structure, and what the denoiser leaves of the cache is
//! exactly such a systematic difference (the breakdown's bias², 75-89% of the cache's error
//! after the filter). Per level and cache pixel the test keeps decayed sums over the last
//! frames ([`BIAS_DECAY`]) of the residual between the binned targets `T` and the level as the
//! paths read it `I` (luminance, weighted by the samples behind each target), of the targets,
//! and of the residual's variance from the samples' own spread. One cache pixel's residual is
//! far too noisy to see a few percent (at a quarter of the frame's resolution a cache pixel
//! has about 16 samples a frame), but the denoiser does not act at one cache pixel either: it
//! averages over tens of frame pixels, so what it keeps is the bias of a neighbourhood. The
//! sums are therefore pooled over the (2 [`BIAS_RADIUS`] + 1)² cache pixels around each one,
//! about the filter's footprint, and the pixel is *biased* when the pooled mean residual
//! exceeds `max_bias` of the pooled mean target by more than [`BIAS_Z`] of its standard error:
//! a bias beyond the tolerance that the noise does not explain. Kandlbinder et al.'s heuristic
//! bounds the cache's bias through the targets' variance alone; this test measures the bias
//! itself, at the scale the denoiser keeps it.
//!
//! **The verdict.** Paths may stop into a level at a cache pixel (early or natural
//! termination) only when every cache pixel of its 3x3 neighbourhood, which holds the four the
//! bilinear read interpolates, is covered (coverage at least `min_coverage`) and not biased.
//! Elsewhere they go on as plain path tracing does, which costs variance, never brightness. The
//! targets still come from every path that reaches the vertex, so a pixel distrusted for its
//! bias keeps being measured and is read again once the fit catches up. A cache pixel no path
//! went through has no coverage and blocks its neighbours: the frame's empty border and the
//! volume's outside. The fallback's per-frame residual test ([`crate::fallback`]) answers
//! another question: whether the fit has caught up with a scene change.

/// Each frame, the decayed sums are multiplied by this before the frame's counts are added:
/// about three frames of memory, so a moving view's coverage follows it.
pub const DECAY: f32 = 0.7;

/// The measured bias's memory: each frame its sums are multiplied by this (about ten frames),
/// long enough to pool a few hundred samples a cache pixel, short enough to follow training and
/// a moving view.
pub const BIAS_DECAY: f32 = 0.9;

/// The bias test pools the cache pixels within this many of each (a 5x5 block: 20x20 frame
/// pixels at the default divisor, about a denoiser's footprint).
pub const BIAS_RADIUS: usize = 2;

/// How many standard errors the pooled residual must exceed the tolerance by: a pixel whose
/// level is exactly at the tolerance is distrusted in about 2% of frames by noise alone, one
/// within it far less often (heavy-tailed samples raise this, which costs variance only).
pub const BIAS_Z: f32 = 2.0;

/// One level's decayed residual sums at one cache pixel (luminance).
#[derive(Debug, Clone, Copy, Default)]
struct ResidualSums {
    /// Samples times the residual `T - I`.
    residual: f32,
    /// Samples times the target `T`.
    target: f32,
    /// Samples squared times the variance of the target's mean: the variance of `residual`.
    variance: f32,
}

impl ResidualSums {
    fn decay(&mut self) {
        self.residual *= BIAS_DECAY;
        self.target *= BIAS_DECAY;
        self.variance *= BIAS_DECAY * BIAS_DECAY;
    }
    fn add(&mut self, other: &Self) {
        self.residual += other.residual;
        self.target += other.target;
        self.variance += other.variance;
    }
    /// Whether the pooled residual is within `max_bias` of the pooled target, or within
    /// [`BIAS_Z`] standard errors of it. Written so that NaN fails.
    fn within(&self, max_bias: f32) -> bool {
        self.residual.abs() <= max_bias * self.target.abs() + BIAS_Z * self.variance.sqrt()
    }
}

/// Per level, per cache pixel: the decayed path counts and the verdict they give.
#[derive(Debug, Clone, Default)]
pub struct Support {
    width: u32,
    height: u32,
    /// Decayed count of the paths through each cache pixel (the same for every level).
    paths: Vec<f32>,
    /// Per level, the decayed count of those paths that reached its vertex.
    reached: Vec<Vec<f32>>,
    /// Per level, the decayed residual sums (empty while the bias test is off).
    residuals: Vec<Vec<ResidualSums>>,
    /// Per level, whether paths may stop into it at each cache pixel.
    supported: Vec<Vec<bool>>,
}

impl Support {
    /// Sized for `levels` levels of `width` x `height` cache pixels. A new size forgets
    /// everything: no pixel is supported until a frame's paths are counted.
    pub fn fit(&mut self, levels: usize, width: u32, height: u32) {
        if self.width != width || self.height != height || self.reached.len() != levels {
            let n = width as usize * height as usize;
            *self = Self {
                width,
                height,
                paths: vec![0.0; n],
                reached: vec![vec![0.0; n]; levels],
                residuals: vec![Vec::new(); levels],
                supported: vec![vec![false; n]; levels],
            };
        }
    }

    /// Whether paths may stop into `level` at row-major cache pixel `bin`.
    #[inline]
    pub fn supported(&self, level: usize, bin: usize) -> bool {
        self.supported[level][bin]
    }

    /// The fraction of `level`'s cache pixels supported.
    pub fn supported_fraction(&self, level: usize) -> f64 {
        let s = &self.supported[level];
        s.iter().filter(|&&b| b).count() as f64 / s.len().max(1) as f64
    }

    /// Forgets the measured bias (the scene changed: the residuals of the old fit say nothing
    /// of the new one). Coverage stays: it does not depend on the fit.
    pub fn forget_bias(&mut self) {
        self.residuals.iter_mut().for_each(Vec::clear);
    }

    /// Adds a frame's residuals for `level`: `drawn` is the level as the frame's paths read it
    /// and `target` the binned sample means (radiance, cache resolution), `spread` per pixel
    /// the sample count and the variance of the mean's luminance
    /// ([`crate::TrainingTargets::level_spread`]). A pixel with fewer than two samples adds
    /// nothing (its spread is unknown). Call before [`Support::update`].
    pub fn observe(
        &mut self,
        level: usize,
        drawn: &[[f32; 3]],
        target: &[[f32; 3]],
        spread: &[(u64, f32)],
    ) {
        let sums = &mut self.residuals[level];
        sums.resize(self.paths.len(), ResidualSums::default());
        let lum = |c: &[f32; 3]| crate::termination::luminance(glam::Vec3::from_array(*c));
        for (((sum, d), t), &(count, variance)) in
            sums.iter_mut().zip(drawn).zip(target).zip(spread)
        {
            sum.decay();
            let (d, t) = (lum(d), lum(t));
            let n = count as f32;
            // Written so that a NaN anywhere adds nothing.
            if count >= 2 && (t - d).is_finite() && variance.is_finite() {
                sum.add(&ResidualSums {
                    residual: n * (t - d),
                    target: n * t,
                    variance: n * n * variance,
                });
            }
        }
    }

    /// Adds a frame's counts: `paths[b]` paths went through cache pixel `b`, and
    /// `reached[level][b]` of them reached the level's vertex. Then every verdict is taken
    /// again with `min_coverage` and (where it is above 0 and residuals were observed)
    /// `max_bias`. A frame that counted no path at all (a renderer that does not report them)
    /// changes nothing.
    pub fn update(
        &mut self,
        paths: &[u32],
        reached: &[Vec<u32>],
        min_coverage: f32,
        max_bias: f32,
    ) {
        if paths.iter().all(|&p| p == 0) {
            return;
        }
        debug_assert_eq!(paths.len(), self.paths.len());
        for (sum, &p) in self.paths.iter_mut().zip(paths) {
            *sum = *sum * DECAY + p as f32;
        }
        for (sums, counts) in self.reached.iter_mut().zip(reached) {
            for (sum, &r) in sums.iter_mut().zip(counts) {
                *sum = *sum * DECAY + r as f32;
            }
        }
        let (w, h) = (self.width as usize, self.height as usize);
        for (level, supported) in self.supported.iter_mut().enumerate() {
            // Written so that a pixel with no paths (0 / 0) fails the test.
            let mut trusted: Vec<bool> = self.reached[level]
                .iter()
                .zip(&self.paths)
                .map(|(&r, &p)| r >= min_coverage * p && p > 0.0)
                .collect();
            let residuals = &self.residuals[level];
            if max_bias > 0.0 && residuals.len() == trusted.len() {
                let pooled = box_sums(residuals, w, h, BIAS_RADIUS);
                for (t, sums) in trusted.iter_mut().zip(&pooled) {
                    *t &= sums.within(max_bias);
                }
            }
            for j in 0..h {
                for i in 0..w {
                    let rows = j.saturating_sub(1)..(j + 2).min(h);
                    supported[j * w + i] = rows
                        .into_iter()
                        .all(|y| (i.saturating_sub(1)..(i + 2).min(w)).all(|x| trusted[y * w + x]));
                }
            }
        }
    }
}

/// The sums of every `(2 radius + 1)²` block of a `w` x `h` image of sums, clipped at the
/// borders: a box filter run along the rows, then the columns (a per-frame pass over a
/// cache-resolution image, linear in its pixels whatever the radius).
fn box_sums(sums: &[ResidualSums], w: usize, h: usize, radius: usize) -> Vec<ResidualSums> {
    let mut rows = vec![ResidualSums::default(); sums.len()];
    for y in 0..h {
        let row = &sums[y * w..(y + 1) * w];
        for x in 0..w {
            let out = &mut rows[y * w + x];
            row[x.saturating_sub(radius)..(x + radius + 1).min(w)]
                .iter()
                .for_each(|s| out.add(s));
        }
    }
    let mut pooled = vec![ResidualSums::default(); sums.len()];
    for y in 0..h {
        for x in 0..w {
            let out = &mut pooled[y * w + x];
            (y.saturating_sub(radius)..(y + radius + 1).min(h))
                .for_each(|yy| out.add(&rows[yy * w + x]));
        }
    }
    pooled
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pixel_is_supported_only_when_its_neighbourhood_is_covered() {
        let mut support = Support::default();
        support.fit(1, 5, 3);
        assert_eq!(support.supported_fraction(0), 0.0, "nothing counted yet");
        // Every pixel saw 10 paths; all reached the vertex but at pixel (4, 0), where 3 did.
        let paths = vec![10u32; 15];
        let mut reached = vec![10u32; 15];
        reached[4] = 3;
        support.update(&paths, &[reached.clone()], 0.5, 0.0);
        let verdicts: Vec<bool> = (0..15).map(|b| support.supported(0, b)).collect();
        // (4, 0)'s neighbours (3, 0), (3, 1), (4, 1) and itself fail; the rest pass.
        let expected: Vec<bool> = (0..15).map(|b| ![3, 4, 8, 9].contains(&b)).collect();
        assert_eq!(verdicts, expected);
        // A frame without counts changes nothing; a low threshold passes everything.
        support.update(&[0; 15], &[vec![0; 15]], 0.5, 0.0);
        assert_eq!(support.supported_fraction(0), 11.0 / 15.0);
        support.update(&paths, &[reached], 0.2, 0.0);
        assert_eq!(support.supported_fraction(0), 1.0);
        // A pixel no path went through blocks its neighbours, whatever the threshold.
        let mut paths = vec![10u32; 15];
        paths[7] = 0;
        let mut fresh = Support::default();
        fresh.fit(1, 5, 3);
        fresh.update(&paths, &[vec![0; 15]], 0.0, 0.0);
        assert!(!fresh.supported(0, 7) && !fresh.supported(0, 1) && fresh.supported(0, 4));
    }

    #[test]
    fn coverage_is_a_decayed_fraction_of_the_paths() {
        let mut support = Support::default();
        support.fit(1, 1, 1);
        // Two frames: 10 paths all reaching, then 10 paths none reaching. Decayed sums:
        // reached 7, paths 17: coverage 0.41.
        support.update(&[10], &[vec![10]], 0.4, 0.0);
        support.update(&[10], &[vec![0]], 0.4, 0.0);
        assert!(support.supported(0, 0));
        let mut again = support.clone();
        again.update(&[0], &[vec![0]], 0.42, 0.0);
        assert!(
            again.supported(0, 0),
            "a frame without counts keeps the verdict"
        );
        support.update(&[10], &[vec![0]], 0.2, 0.0);
        // reached 4.9, paths 21.9: 0.22.
        assert!(support.supported(0, 0));
        support.update(&[10], &[vec![0]], 0.2, 0.0);
        assert!(!support.supported(0, 0), "3.43 of 25.3 paths: 0.14");
    }

    /// The bias test on a 10x10 image whose left half reads 10% too dark against its targets:
    /// distrusted there (and within the 3x3 read around it), trusted where the pooled residual
    /// is within the tolerance; a bias under the tolerance, or within the noise, is not
    /// distrusted; NaN targets add nothing; a scene change forgets the residuals.
    #[test]
    fn a_pixel_is_distrusted_where_its_pooled_residual_exceeds_the_tolerance_beyond_the_noise() {
        let (w, h) = (10usize, 10usize);
        let n = w * h;
        let paths = vec![16u32; n];
        let reached = vec![vec![16u32; n]];
        let drawn = vec![[1.0f32; 3]; n];
        let target = |left: f32| -> Vec<[f32; 3]> {
            (0..n)
                .map(|b| [if b % w < 5 { left } else { 1.0 }; 3])
                .collect()
        };
        // 16 samples behind each target, the mean's standard error 5%.
        let spread = vec![(16u64, 0.0025f32); n];
        let run = |left: f32, spread: &[(u64, f32)], max_bias: f32, frames: usize| {
            let mut support = Support::default();
            support.fit(1, w as u32, h as u32);
            for _ in 0..frames {
                support.observe(0, &drawn, &target(left), spread);
                support.update(&paths, &reached, 0.0, max_bias);
            }
            support
        };
        let verdicts = |s: &Support| (0..n).map(|b| s.supported(0, b)).collect::<Vec<_>>();
        // A 5x5 block at x <= 4 pools a residual of 0.1 over 1 + 0.1 x (its biased columns'
        // share): beyond 3% and the noise for blocks centred at x <= 5; their 3x3 reads reach
        // x = 6. Pooled 25 targets of 16 samples over ten frames, the noise is about 0.4%.
        let biased = run(1.1, &spread, 0.03, 10);
        let expected: Vec<bool> = (0..n).map(|b| b % w >= 7).collect();
        assert_eq!(verdicts(&biased), expected);
        // The same residual under a 12% tolerance, or buried in noise (standard error 50% a
        // target, so about 4% pooled over one frame), is not distrusted.
        assert_eq!(verdicts(&run(1.1, &spread, 0.12, 10)), vec![true; n]);
        let noisy = vec![(16u64, 0.25f32); n];
        assert_eq!(verdicts(&run(1.1, &noisy, 0.03, 1)), vec![true; n]);
        // The test off: only coverage decides.
        assert_eq!(verdicts(&run(1.1, &spread, 0.0, 10)), vec![true; n]);
        // A NaN target adds nothing: an unbiased image stays trusted.
        let mut support = Support::default();
        support.fit(1, w as u32, h as u32);
        let mut with_nan = target(1.0);
        with_nan[0] = [f32::NAN; 3];
        support.observe(0, &drawn, &with_nan, &spread);
        support.update(&paths, &reached, 0.0, 0.03);
        assert_eq!(verdicts(&support), vec![true; n]);
        // Forgotten after a scene change: no residual, no distrust.
        let mut biased = biased;
        biased.forget_bias();
        biased.update(&paths, &reached, 0.0, 0.03);
        assert_eq!(verdicts(&biased), vec![true; n]);
    }
}
