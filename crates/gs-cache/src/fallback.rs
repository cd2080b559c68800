//! The fallback to plain path tracing where a level is not to be trusted: per level and per
//! cache pixel, a test of the last training residual decides whether the next frame's paths
//! through that pixel may stop into the level (early and natural termination) or must go on as
//! plain path tracing does. A stale cache (after a transfer-function edit or a light move, or a
//! fresh one) then costs variance, never the brightness of the image.
//!
//! **The test.** Each frame, before its step, level `n`'s drawn value `I(p)` at cache pixel
//! `p` is compared with the mean `T(p)` of the samples binned into `p`, in luminance, with
//! `sigma(p)` the standard error of that mean from the samples' own spread. The pixel is
//! *distrusted* for the next frame when both
//!
//! - `|T - I| > Z sigma`: the difference is not noise (`Z` = [`Z_SCORE`], so a pixel whose
//!   cache is right is distrusted by chance in about 0.3% of frames under normal noise; heavy
//!   tails raise that, which costs only variance), and
//! - `|T - I| > R max(T, I)`: it is large enough to matter (`R` = [`RELATIVE_ERROR`]), so a
//!   pixel with many samples is not distrusted for a difference the image would not show,
//!
//! Two thresholds, for hysteresis: a distrusted pixel is trusted again once its residual is
//! within the noise or within `R`; a trusted pixel is distrusted only when its residual exceeds
//! the noise and [`STALE_ERROR`] of the value in two frames running. The samples' own spread
//! underestimates their noise when they are heavy-tailed (a few paths find a small light): with
//! `R` and one failed test, 11-18% of the tested pixels of a converged cache were distrusted on
//! neghip and hydrogen, which cost 8-17% of relMSE at 1 spp; a stale cache fails by far more,
//! every frame. A pixel with fewer than two samples keeps its state.
//!
//! **When it distrusts.** A scene change (`GsCache::reset_schedule`) distrusts every pixel
//! until its first residual: the frame after an edit is plain path tracing, bit for bit, and the
//! warm start, restarted with it, refits the colours from that frame's samples, so most pixels
//! come back the frame after. A fresh cache's first frame is plain path tracing too (its colours
//! are still the albedo start, and its radiance scales come from that frame's samples); every
//! pixel is trusted from the second frame, whose residuals then take over. Reading the albedo
//! start as radiance on that first frame had made it 35x worse than NEE on headsq, and had
//! inflated the radiance scales (2.7x on headsq) through the self-training samples, which
//! raised the colour learning rate by accident: the default rate was measured again with
//! unbiased scales (`CacheConfig::lr_color`).

//! **What it does not see.** The test is in screen space: after a camera move the last frame's
//! verdicts are read at the same pixels, which for small moves (a 1.5 degree orbit step) is
//! close and for a jump is a guess for one frame; the next frame's residuals correct it. The
//! level's own spread across a cache pixel (the crate docs' bias term) is inside `T`'s spread,
//! so it widens `sigma` rather than tripping the test.

/// How many standard errors the residual must exceed.
pub const Z_SCORE: f32 = 3.0;
/// The fraction of the value within which a distrusted pixel's residual must fall (or within
/// the noise) for the pixel to be trusted again.
pub const RELATIVE_ERROR: f32 = 0.2;
/// The fraction of the value a trusted pixel's residual must exceed (beyond the noise), in two
/// frames running, for the pixel to be distrusted.
pub const STALE_ERROR: f32 = 0.5;

/// One cache pixel's verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Verdict {
    Distrusted,
    Trusted,
    /// Trusted, but its last test failed.
    Struck,
}

/// Per level, per cache pixel: may paths stop into the level here.
#[derive(Debug, Clone, Default)]
pub struct Trust {
    width: u32,
    height: u32,
    levels: Vec<Vec<Verdict>>,
}

impl Trust {
    /// Sized for `levels` levels of `width` x `height` cache pixels; a new size trusts every
    /// pixel (the levels hold radiance whatever the image's size). A fresh cache is distrusted
    /// for its first frame by the cache itself (see the module docs).
    pub fn fit(&mut self, levels: usize, width: u32, height: u32) {
        let n = width as usize * height as usize;
        if self.width != width || self.height != height || self.levels.len() != levels {
            *self = Self {
                width,
                height,
                levels: vec![vec![Verdict::Trusted; n]; levels],
            };
        }
    }

    /// Trusts every pixel of every level (a fresh cache after its first frame).
    pub fn trust_all(&mut self) {
        self.levels
            .iter_mut()
            .for_each(|l| l.fill(Verdict::Trusted));
    }

    /// Distrusts every pixel of every level (the scene changed).
    pub fn distrust_all(&mut self) {
        self.levels
            .iter_mut()
            .for_each(|l| l.fill(Verdict::Distrusted));
    }

    /// Whether paths may stop into `level` at row-major cache pixel `bin`.
    #[inline]
    pub fn trusted(&self, level: usize, bin: usize) -> bool {
        self.levels[level][bin] != Verdict::Distrusted
    }

    /// The fraction of `level`'s pixels trusted.
    pub fn trusted_fraction(&self, level: usize) -> f64 {
        let l = &self.levels[level];
        l.iter().filter(|&&t| t != Verdict::Distrusted).count() as f64 / l.len().max(1) as f64
    }

    /// The test above for `level` (see [`update_trust`]).
    pub fn update(
        &mut self,
        level: usize,
        drawn: &[[f32; 3]],
        target: &[[f32; 3]],
        spread: &[(u64, f32)],
    ) -> Option<f64> {
        update_trust(&mut self.levels[level], drawn, target, spread)
    }

    /// Each level's verdicts, to update the levels side by side.
    pub(crate) fn levels_mut(&mut self) -> &mut [Vec<Verdict>] {
        &mut self.levels
    }
}

/// The test above for one level's `verdicts`: `drawn` is the level as the frame's paths read
/// it and `target` the binned sample means (both radiance, cache resolution); `spread` holds per
/// pixel the sample count and the variance of the mean's luminance. Returns the fraction of the
/// tested pixels (two samples or more) whose residual was gross, beyond the noise and
/// [`STALE_ERROR`] of the value (`None`: no pixel was tested).
pub(crate) fn update_trust(
    verdicts: &mut [Verdict],
    drawn: &[[f32; 3]],
    target: &[[f32; 3]],
    spread: &[(u64, f32)],
) -> Option<f64> {
    let (mut tested, mut gross_count) = (0u64, 0u64);
    let lum = |c: &[f32; 3]| crate::termination::luminance(glam::Vec3::from_array(*c));
    for (((verdict, d), t), &(count, variance)) in
        verdicts.iter_mut().zip(drawn).zip(target).zip(spread)
    {
        if count < 2 {
            continue;
        }
        let (d, t) = (lum(d), lum(t));
        let residual = (t - d).abs();
        // Written so that NaN anywhere distrusts the pixel.
        let noise = residual <= Z_SCORE * variance.sqrt();
        let scale = t.max(d);
        let fits = noise || residual <= RELATIVE_ERROR * scale;
        let gross = !(noise || residual <= STALE_ERROR * scale);
        tested += 1;
        gross_count += gross as u64;
        *verdict = match *verdict {
            Verdict::Distrusted if fits => Verdict::Trusted,
            Verdict::Distrusted => Verdict::Distrusted,
            Verdict::Trusted | Verdict::Struck if !gross => Verdict::Trusted,
            Verdict::Trusted => Verdict::Struck,
            Verdict::Struck => Verdict::Distrusted,
        };
    }
    (tested > 0).then(|| gross_count as f64 / tested as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The verdicts per case: noise, a small error, a large error beyond the noise (twice
    /// running to distrust), too few samples, NaN.
    #[test]
    fn a_pixel_is_distrusted_only_for_a_large_error_beyond_the_noise_twice() {
        let mut trust = Trust::default();
        trust.fit(1, 5, 1);
        assert_eq!(trust.trusted_fraction(0), 1.0, "a new map is trusted");
        trust.distrust_all();
        let drawn = [[1.0; 3]; 5];
        let target = [[1.5; 3], [1.1; 3], [3.0; 3], [3.0; 3], [f32::NAN; 3]];
        // Standard errors: 0.2 (0.5 is 2.5 sigma: noise), tiny (0.1 is 10%: small), tiny
        // (2 is 67% and 200 sigma: a failure), one sample (kept), NaN (a failure).
        let spread = [(16, 0.04), (1000, 1e-4), (1000, 1e-4), (1, 0.0), (16, 0.04)];
        let verdicts = |t: &Trust| (0..5).map(|b| t.trusted(0, b)).collect::<Vec<_>>();
        trust.update(0, &drawn, &target, &spread);
        assert_eq!(verdicts(&trust), [true, true, false, false, false]);
        // Trusted pixels fail once: a strike, still trusted; twice: distrusted.
        trust.levels[0].fill(Verdict::Trusted);
        trust.update(0, &drawn, &target, &spread);
        assert_eq!(verdicts(&trust), [true; 5]);
        trust.update(0, &drawn, &target, &spread);
        assert_eq!(verdicts(&trust), [true, true, false, true, false]);
        // A pass clears a strike.
        trust.levels[0][2] = Verdict::Struck;
        trust.update(0, &drawn, &[[1.0; 3]; 5], &spread);
        trust.update(0, &drawn, &target, &spread);
        assert!(trust.trusted(0, 2), "pass then one failure: still trusted");
        trust.distrust_all();
        assert_eq!(trust.trusted_fraction(0), 0.0);
        // A new size starts trusted.
        trust.fit(1, 4, 1);
        assert_eq!(trust.trusted_fraction(0), 1.0);
    }
}
