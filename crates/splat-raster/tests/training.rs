//! Training: the HDR loss recovers the mean of heavy-tailed noisy samples, and a perturbed cloud
//! is fitted back to the image of its target.

mod common;

use common::*;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use splat_raster::adamw::{AdamW, AdamWConfig, GroupSettings};
use splat_raster::loss::{Loss, loss_and_grad};
use splat_raster::train::train_step;
use splat_raster::{ColorModel, RasterConfig, render};

/// Fitting one value to noisy samples of a constant with the HDR loss (detached denominator):
/// the fit converges to the sample mean. Samples are heavy-tailed like path-traced radiance:
/// mostly 0, sometimes very bright (mean 0.8).
#[test]
fn hdr_loss_recovers_the_mean_of_heavy_tailed_samples() {
    let mut rng = StdRng::seed_from_u64(3);
    let n = 4096;
    let samples: Vec<[f32; 3]> = (0..n)
        .map(|_| {
            let v = if rng.random::<f32>() < 0.02 {
                40.0 * rng.random::<f32>()
            } else {
                0.0
            };
            [v, v, v]
        })
        .collect();
    let mean = samples.iter().map(|s| s[0] as f64).sum::<f64>() / n as f64;
    // One parameter y predicted at every pixel; Adam steps on the mean gradient.
    let mut y = 0.1f32;
    let (mut m, mut v) = (0.0f32, 0.0f32);
    for t in 1..=3000 {
        let pred = vec![[y; 3]; n];
        let (_, g) = loss_and_grad(Loss::Hdr, &pred, &samples, None);
        let grad: f32 = g.iter().map(|c| c[0] + c[1] + c[2]).sum();
        m = 0.9 * m + 0.1 * grad;
        v = 0.999 * v + 0.001 * grad * grad;
        let lr = 0.01 / (1.0 + (t as f32 / 500.0));
        y -= lr * (m / (1.0 - 0.9f32.powi(t))) / ((v / (1.0 - 0.999f32.powi(t))).sqrt() + 1e-12);
    }
    eprintln!("HDR fit {y} vs sample mean {mean}");
    assert!(((y as f64) - mean).abs() <= 0.01 * mean, "{y} vs {mean}");
}

/// A cloud perturbed away from a target cloud is fitted back to the target's image.
#[test]
fn perturbed_cloud_is_fitted_back() {
    let target_cloud = random_cloud(60, ColorModel::Rgb, 11).cast::<f32>();
    let cam = camera(64, 48);
    let cfg = RasterConfig {
        background: [0.05, 0.05, 0.05],
        ..Default::default()
    };
    let (target, _) = render(&target_cloud, &cam, &cfg);
    let mut rng = StdRng::seed_from_u64(12);
    let mut cloud = target_cloud.clone();
    for v in cloud.means.iter_mut() {
        *v += rng.random_range(-0.08..0.08);
    }
    for v in cloud.colors.iter_mut() {
        *v = (*v + rng.random_range(-0.4..0.4)).max(0.0);
    }
    for v in cloud.opacity_logits.iter_mut() {
        *v += rng.random_range(-0.8..0.8);
    }
    for v in cloud.log_scales.iter_mut() {
        *v += rng.random_range(-0.2..0.2);
    }
    let g = |lr| GroupSettings {
        lr,
        weight_decay: 0.0,
    };
    let config = AdamWConfig {
        means: g(2e-3),
        log_scales: g(5e-3),
        rotations: g(2e-3),
        colors: g(1e-2),
        opacity_logits: g(2e-2),
        epsilon: 1e-15,
        ..Default::default()
    };
    let mut opt = AdamW::new(config, &cloud);
    let mut first = None;
    let mut last = 0.0;
    for _ in 0..400 {
        let l = train_step(
            &mut cloud,
            &cam,
            &cfg,
            &target.color,
            None,
            Loss::L2,
            &mut opt,
            1.0,
        );
        first.get_or_insert(l);
        last = l;
    }
    let first = first.unwrap();
    eprintln!("L2 loss {first:.3e} -> {last:.3e} ({:.0}x)", first / last);
    assert!(
        last * 10.0 <= first,
        "loss fell only from {first} to {last}"
    );
    assert!(
        cloud
            .groups()
            .iter()
            .all(|(_, v)| v.iter().all(|x| x.is_finite()))
    );
}
