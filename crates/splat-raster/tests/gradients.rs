//! The hand-written backward pass against f64 central finite differences, for every parameter
//! group, on small random clouds (anisotropic, rotated, some far off screen so the Jacobian's
//! guard band is active), with RGB and SH degree-3 colour, both low-pass filters, a background,
//! and gradients flowing in through colour, transmittance and depth.

mod common;

use common::*;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use splat_raster::raster::backward;
use splat_raster::{Camera, ColorModel, GaussianCloud, LowPass, PixelGrads, RasterConfig, render};

/// A linear functional of the outputs with fixed random weights: its gradient with respect to
/// each output is the weight.
struct Weights {
    color: Vec<[f64; 3]>,
    t: Vec<f64>,
    depth: Vec<f64>,
}

fn weights(n: usize, seed: u64) -> Weights {
    let mut rng = StdRng::seed_from_u64(seed);
    Weights {
        color: (0..n)
            .map(|_| [0; 3].map(|_| rng.random_range(-1.0..1.0)))
            .collect(),
        t: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        depth: (0..n).map(|_| rng.random_range(-0.2..0.2)).collect(),
    }
}

fn loss(cloud: &GaussianCloud<f64>, cam: &Camera, cfg: &RasterConfig, w: &Weights) -> f64 {
    let (out, _) = render(cloud, cam, cfg);
    let mut l = 0.0;
    for (i, c) in out.color.iter().enumerate() {
        l += c[0] * w.color[i][0]
            + c[1] * w.color[i][1]
            + c[2] * w.color[i][2]
            + out.transmittance[i] * w.t[i];
        if let Some(d) = &out.depth {
            l += d[i] * w.depth[i];
        }
    }
    l
}

fn check(model: ColorModel, low_pass: LowPass, seed: u64) {
    let cam = camera(40, 30);
    let cfg = RasterConfig {
        low_pass,
        background: [0.2, 0.1, 0.4],
        depth: true,
        ..Default::default()
    };
    let mut cloud = random_cloud(10, model, seed);
    // A large Gaussian far to the side: its centre is outside the guard band, its tail on screen.
    let stride = 3 * model.coeffs();
    let mut col = vec![0.05; stride];
    col[..3].copy_from_slice(&[0.9, 0.6, 0.3]);
    cloud.push(
        [-4.5, 0.3, 0.5],
        [0.6, 0.2, 0.1],
        [0.9, 0.1, 0.3, -0.2],
        &col,
        0.5,
    );

    let w = weights((cam.width * cam.height) as usize, seed + 1);
    let (_, state) = render(&cloud, &cam, &cfg);
    let g = backward(
        &cloud,
        &cam,
        &state,
        PixelGrads {
            color: &w.color,
            transmittance: Some(&w.t),
            depth: Some(&w.depth),
        },
    );
    // The same backward pass in f32 (the production path).
    let cloud32 = cloud.cast::<f32>();
    let (_, state32) = render(&cloud32, &cam, &cfg);
    let wc32: Vec<[f32; 3]> = w.color.iter().map(|c| c.map(|v| v as f32)).collect();
    let wt32: Vec<f32> = w.t.iter().map(|&v| v as f32).collect();
    let wd32: Vec<f32> = w.depth.iter().map(|&v| v as f32).collect();
    let g32 = backward(
        &cloud32,
        &cam,
        &state32,
        PixelGrads {
            color: &wc32,
            transmittance: Some(&wt32),
            depth: Some(&wd32),
        },
    );

    let names = [
        "means",
        "log_scales",
        "rotations",
        "colors",
        "opacity_logits",
    ];
    for (gi, name) in names.iter().enumerate() {
        let n = cloud.groups()[gi].1.len();
        let mut fd = vec![0.0; n];
        for i in 0..n {
            let h = 1e-6;
            let mut p = cloud.clone();
            p.groups_mut()[gi][i] += h;
            let lp = loss(&p, &cam, &cfg, &w);
            let mut m = cloud.clone();
            m.groups_mut()[gi][i] -= h;
            let lm = loss(&m, &cam, &cfg, &w);
            fd[i] = (lp - lm) / (2.0 * h);
        }
        let analytic = g.groups()[gi].1;
        let a32 = g32.groups()[gi].1;
        let scale = fd.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
        assert!(
            scale > 1e-3,
            "{name}: the loss does not depend on this group"
        );
        let err = analytic
            .iter()
            .zip(&fd)
            .map(|(a, f)| (a - f).abs())
            .fold(0.0, f64::max)
            / scale;
        let err32 = a32
            .iter()
            .zip(&fd)
            .map(|(a, f)| (*a as f64 - f).abs())
            .fold(0.0, f64::max)
            / scale;
        eprintln!(
            "{model:?} {low_pass:?} {name}: max relative error f64 {err:.2e}, f32 {err32:.2e} ({n} values, scale {scale:.3})"
        );
        assert!(
            err <= 1e-4,
            "{model:?} {low_pass:?} {name}: f64 analytic vs finite differences {err:e}"
        );
        assert!(
            err32 <= 2e-3,
            "{model:?} {low_pass:?} {name}: f32 analytic vs finite differences {err32:e}"
        );
    }
}

#[test]
fn gradients_rgb_classic() {
    check(ColorModel::Rgb, LowPass::Classic, 1);
}

#[test]
fn gradients_sh3_mip() {
    check(ColorModel::Sh(3), LowPass::Mip, 2);
}

#[test]
fn gradients_sh1_classic() {
    check(ColorModel::Sh(1), LowPass::Classic, 3);
}
