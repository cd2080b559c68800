//! Random clouds and cameras for the splat-raster tests.
#![allow(dead_code)]

use glam::Vec3;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use splat_raster::{Camera, ColorModel, GaussianCloud};

pub fn camera(w: u32, h: u32) -> Camera {
    Camera::look_at(Vec3::new(0.3, -0.2, -4.0), Vec3::ZERO, Vec3::Y, 50.0, w, h).unwrap()
}

/// `n` Gaussians around the origin with anisotropic scales, off-axis rotations, moderate
/// opacities (away from the 0.99 cap) and positive colours (away from the clamp at 0).
pub fn random_cloud(n: usize, model: ColorModel, seed: u64) -> GaussianCloud<f64> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut c = GaussianCloud::<f64>::new(model);
    for _ in 0..n {
        let mean = [
            rng.random_range(-1.0..1.0),
            rng.random_range(-0.8..0.8),
            rng.random_range(-1.0..1.0),
        ];
        let ls = [
            rng.random_range(-2.2..-1.0),
            rng.random_range(-2.2..-1.0),
            rng.random_range(-2.5..-1.2),
        ];
        let q = [
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ];
        let stride = 3 * model.coeffs();
        let mut col = vec![0.0; stride];
        for (i, v) in col.iter_mut().enumerate() {
            *v = if i < 3 {
                rng.random_range(0.2..1.5)
            } else {
                rng.random_range(-0.1..0.1)
            };
        }
        let logit = rng.random_range(-1.5..1.2);
        c.push(mean, ls, q, &col, logit);
    }
    c
}

/// The AdamW tests' case (`adamw.rs`, `adamw_burn.rs`): 257 Gaussians with every parameter drawn
/// from [-1, 1), settings with a learning rate and a weight decay of its own per group (burn's
/// defaults differ from ours, so every one is given), and the generator the gradients are
/// drawn from next.
pub fn adamw_case() -> (GaussianCloud<f32>, splat_raster::adamw::AdamWConfig, StdRng) {
    use splat_raster::adamw::{AdamWConfig, GroupSettings};
    let mut rng = StdRng::seed_from_u64(7);
    let mut cloud = GaussianCloud::<f32>::new(ColorModel::Rgb);
    for _ in 0..257 {
        let r = |rng: &mut StdRng| rng.random_range(-1.0f32..1.0);
        cloud.push(
            [r(&mut rng), r(&mut rng), r(&mut rng)],
            [r(&mut rng), r(&mut rng), r(&mut rng)],
            [r(&mut rng), r(&mut rng), r(&mut rng), r(&mut rng)],
            &[r(&mut rng), r(&mut rng), r(&mut rng)],
            r(&mut rng),
        );
    }
    let g = |lr, weight_decay| GroupSettings { lr, weight_decay };
    let config = AdamWConfig {
        beta1: 0.9,
        beta2: 0.999,
        epsilon: 1e-8,
        means: g(1.16e-3, 0.0),
        log_scales: g(5e-3, 0.01),
        rotations: g(1e-3, 0.0),
        colors: g(1.25e-2, 0.05),
        opacity_logits: g(1.5e-1, 0.01),
    };
    (cloud, config, rng)
}

/// The settings of `config`'s groups, in the cloud's group order (means, log-scales,
/// rotations, colours, opacity logits).
pub fn adamw_groups(
    config: &splat_raster::adamw::AdamWConfig,
) -> [splat_raster::adamw::GroupSettings; 5] {
    [
        config.means,
        config.log_scales,
        config.rotations,
        config.colors,
        config.opacity_logits,
    ]
}

/// A gradient of `params`' shape with every element drawn from [-2, 2).
pub fn random_gradient(params: &GaussianCloud<f32>, rng: &mut StdRng) -> GaussianCloud<f32> {
    let mut grads = params.zeros_like();
    for group in grads.groups_mut() {
        for v in group.iter_mut() {
            *v = rng.random_range(-2.0f32..2.0);
        }
    }
    grads
}

/// The learning-rate scale of AdamW test step `step`: decaying, so a step's rate matters.
pub fn adamw_lr_scale(step: usize) -> f32 {
    1.0 / (1.0 + (step as f32 + 1.0).ln())
}
