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
