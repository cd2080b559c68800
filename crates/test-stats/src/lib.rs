//! test-stats: the one place the Monte Carlo tests get their statistics from, so every crate's
//! tests state the same statistic and false-alarm rate the same way.
//!
//! The pattern: for every pixel (or ray) an estimate is compared with a reference value (or a
//! second independent estimate) through its z-score; the sum of squared z-scores over `k`
//! pixels is chi-square with `k` degrees of freedom when the estimator is unbiased and the
//! variances are right, so it is held under an upper quantile of that distribution, and every
//! single `|z|` under a bound, which catches a bias confined to a few pixels.

#![forbid(unsafe_code)]

/// Standard-normal upper quantile for a one-sided false-alarm rate of 1e-5.
pub const Z_FALSE_ALARM_1E5: f64 = 4.265;

/// Upper quantile of chi-square with `k` degrees of freedom at the standard-normal quantile `z`,
/// by the Wilson-Hilferty cube-root approximation: at the 1e-5 quantile it is 1.7% above the
/// exact value at k = 10 and 0.1% at k = 100 (above, so the false-alarm rate is at most the one
/// stated), e.g. `z =` [`Z_FALSE_ALARM_1E5`] for a false-alarm rate of 1e-5.
pub fn chi2_upper(k: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Z-scores summed into a chi-square statistic.
#[derive(Debug, Clone, Copy, Default)]
pub struct ZScores {
    /// Sum of squared z-scores.
    pub chi2: f64,
    /// How many were added.
    pub k: usize,
    /// Largest `|z|`.
    pub worst: f64,
}

impl ZScores {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the z-score of a difference `diff` whose variance is `variance` (> 0).
    pub fn add(&mut self, diff: f64, variance: f64) {
        let z = diff / variance.sqrt();
        self.chi2 += z * z;
        self.worst = self.worst.max(z.abs());
        self.k += 1;
    }

    /// Asserts the statistic stays under the 1e-5 upper quantile of chi-square with `k` degrees
    /// of freedom and every `|z|` under `max_abs_z`, with at least `min_k` scores (so a test
    /// whose pixels are all noiseless cannot pass by seeing nothing). Prints the figures.
    pub fn assert_unbiased(&self, what: &str, max_abs_z: f64, min_k: usize) {
        let limit = chi2_upper(self.k as f64, Z_FALSE_ALARM_1E5);
        eprintln!(
            "{what}: chi2 {:.1} over {} scores (limit {limit:.1}, false alarm 1e-5), max |z| {:.2}",
            self.chi2, self.k, self.worst
        );
        assert!(
            self.k >= min_k,
            "{what}: only {} noisy scores (expected at least {min_k}): the test sees too little",
            self.k
        );
        assert!(
            self.chi2 < limit && self.worst < max_abs_z,
            "{what}: chi2 {} (limit {limit}), max |z| {} (limit {max_abs_z})",
            self.chi2,
            self.worst
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_hilferty_matches_tabulated_quantiles() {
        // Exact chi-square upper quantiles at 1 - 1e-5 (regularised incomplete gamma, solved by
        // bisection): k = 10: 41.296, k = 100: 172.099. The approximation lies above each and within 2%.
        for (k, q) in [(10.0, 41.296), (100.0, 172.099)] {
            let got = chi2_upper(k, Z_FALSE_ALARM_1E5);
            assert!(
                got >= q && got / q - 1.0 < 0.02,
                "k = {k}: {got} against {q}"
            );
        }
    }

    #[test]
    #[should_panic(expected = "chi2")]
    fn a_biased_set_of_scores_fails() {
        let mut z = ZScores::new();
        for _ in 0..1000 {
            z.add(0.2, 0.01); // every z = 2: chi2 = 4000 over 1000
        }
        z.assert_unbiased("biased", 5.0, 10);
    }

    #[test]
    #[should_panic(expected = "sees too little")]
    fn too_few_scores_fail() {
        ZScores::new().assert_unbiased("empty", 5.0, 1);
    }
}
