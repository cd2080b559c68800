//! Stochastic splatting converges to the sorted composite: per-pixel z-tests with the exact
//! variance, an image-wide chi-square, and MSE falling as 1/N.

mod common;

use common::*;
use splat_raster::stochastic::render_stochastic;
use splat_raster::{ColorModel, GaussianCloud, RasterConfig, render};

#[test]
fn stochastic_mean_matches_sorted_and_mse_falls_as_one_over_n() {
    let cloud: GaussianCloud<f32> = random_cloud(40, ColorModel::Rgb, 21).cast();
    let cam = camera(48, 36);
    let cfg = RasterConfig {
        background: [0.3, 0.2, 0.1],
        ..Default::default()
    };
    let (sorted, _) = render(&cloud, &cam, &cfg);
    // No pixel is near the early stop, so the sorted composite is the exact expectation.
    assert!(sorted.transmittance.iter().all(|&t| t > 0.01));
    // Exact per-pixel variance of one sample: E[c^2] - E[c]^2, where E[c^2] is the composite
    // of squared colours over a squared background.
    let mut sq = cloud.clone();
    for v in sq.colors.iter_mut() {
        *v = *v * *v;
    }
    let cfg_sq = RasterConfig {
        background: cfg.background.map(|b| b * b),
        ..cfg
    };
    let (second, _) = render(&sq, &cam, &cfg_sq);
    let var: Vec<f64> = (0..sorted.color.len())
        .map(|i| (second.color[i][0] as f64 - (sorted.color[i][0] as f64).powi(2)).max(0.0))
        .collect();

    let n = 256;
    let st = render_stochastic(&cloud, &cam, &cfg, n, 1);
    let mut scores = test_stats::ZScores::new();
    for i in 0..var.len() {
        if var[i] < 1e-9 {
            assert!(
                (st.color[i][0] - sorted.color[i][0]).abs() < 1e-5,
                "noiseless pixel {i} differs"
            );
            continue;
        }
        scores.add(
            st.color[i][0] as f64 - sorted.color[i][0] as f64,
            var[i] / n as f64,
        );
    }
    // Chi-square under its 1e-5 upper quantile, and |z| < 5.5 per pixel (a family-wise
    // false-alarm rate of about 1e-4 over these pixels).
    scores.assert_unbiased("stochastic vs sorted", 5.5, 500);

    // MSE against the exact mean is (mean variance) / N: the ratio concentrates near 1.
    let mean_var = var.iter().sum::<f64>() / var.len() as f64;
    for (samples, seed) in [(4u32, 2u32), (16, 3), (64, 4)] {
        let st = render_stochastic(&cloud, &cam, &cfg, samples, seed);
        let mse = st
            .color
            .iter()
            .zip(&sorted.color)
            .map(|(a, b)| (a[0] as f64 - b[0] as f64).powi(2))
            .sum::<f64>()
            / var.len() as f64;
        let ratio = mse / (mean_var / samples as f64);
        eprintln!("N = {samples}: MSE {mse:.3e}, MSE * N / variance = {ratio:.3}");
        assert!(
            (0.85..1.15).contains(&ratio),
            "N = {samples}: MSE ratio {ratio}"
        );
    }
}
