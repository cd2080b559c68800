//! The SIMD lane kernels against the scalar reference kernel: images, gradients, determinism.
//!
//! The lanes differ from the scalar kernel only in rounding (their own `exp`, within 3e-7
//! relative, the exponent's operation order, FMA), so almost every pixel agrees to a few ulps.
//! A pixel where one splat's alpha or the transmittance sits within that rounding of a
//! threshold (alpha 1/255, T = 1e-4) may take the other branch there; such a flip moves the pixel
//! by at most one splat's contribution above the threshold: alpha (1/255) x T x colour. The
//! statistic is therefore two-sided: the share of pixels off by more than 1e-5 (relative to the
//! image's largest value) must stay under 0.2%, and no pixel may be off by more than one
//! threshold flip. A wrong lane, mask or chunk moves whole splats (errors of 1e-2 and more on
//! many pixels) and fails both. The tests are deterministic (fixed seeds): no false alarms.

mod common;

use common::*;
use glam::Vec3;
use splat_raster::raster::backward;
use splat_raster::{
    Camera, CloudGradients, ColorModel, GaussianCloud, Kernel, LowPass, PixelGrads, RasterConfig,
    render,
};

/// The lane kernels this CPU runs.
fn lane_kernels() -> Vec<Kernel> {
    let mut k = vec![Kernel::Lanes4];
    if Kernel::Lanes8.available() {
        k.push(Kernel::Lanes8);
    } else {
        eprintln!("note: this CPU has no AVX2 + FMA; only the 4-lane kernel is checked");
    }
    k
}

/// The scene whose gradients are ill-conditioned in f32 (a needle, a huge and a guard-band
/// Gaussian).
const ILL_CONDITIONED: &str = "degenerate and guard band";

/// Test scenes: random clouds (RGB, SH with the mip low-pass, opaque enough to saturate), a
/// cloud with degenerate and far off-screen (guard-band) Gaussians, and a dense cloud of small
/// splats like the cache's.
fn scenes() -> Vec<(&'static str, GaussianCloud<f32>, Camera, RasterConfig)> {
    let mut out = Vec::new();
    let base = RasterConfig {
        background: [0.1, 0.2, 0.3],
        depth: true,
        ..Default::default()
    };
    let mut opaque = random_cloud(400, ColorModel::Rgb, 11).cast::<f32>();
    for v in opaque.opacity_logits.iter_mut() {
        *v += 2.5;
    }
    out.push(("opaque rgb", opaque, camera(67, 45), base));
    let sh = random_cloud(300, ColorModel::Sh(2), 12).cast::<f32>();
    let mip = RasterConfig {
        low_pass: LowPass::Mip,
        ..base
    };
    out.push(("sh mip", sh, camera(80, 53), mip));

    let mut odd = random_cloud(60, ColorModel::Rgb, 13).cast::<f32>();
    let col = [0.7f32, 0.4, 1.2];
    // Huge, needle-thin, off to the side (guard band), nearly edge-on, at the near plane, NaN.
    odd.push(
        [0.0, 0.0, 0.0],
        [2.0, 2.0, 2.0],
        [1.0, 0.0, 0.0, 0.0],
        &col,
        0.0,
    );
    odd.push(
        [0.1, 0.0, 0.0],
        [1.5, -9.0, -9.0],
        [0.9, 0.3, 0.1, 0.2],
        &col,
        2.0,
    );
    odd.push(
        [6.0, 0.5, 0.0],
        [0.5, 0.5, 0.5],
        [1.0, 0.0, 0.0, 0.0],
        &col,
        1.0,
    );
    odd.push(
        [-7.0, -3.0, 1.0],
        [1.0, 0.2, 0.2],
        [0.5, 0.5, 0.5, 0.5],
        &col,
        1.0,
    );
    odd.push(
        [0.3, -0.2, -3.98],
        [-4.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        &col,
        3.0,
    );
    odd.push(
        [0.0, 0.0, 0.0],
        [-1.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        &[f32::NAN; 3],
        0.0,
    );
    out.push((ILL_CONDITIONED, odd, camera(50, 37), base));

    let mut dense = GaussianCloud::<f32>::new(ColorModel::Rgb);
    for i in 0..20_000u32 {
        let h = |k: u32| {
            let x = (i.wrapping_mul(2_654_435_761) ^ k.wrapping_mul(40_503))
                .wrapping_mul(2_246_822_519);
            (x >> 8) as f32 / (1 << 24) as f32
        };
        dense.push(
            [2.0 * h(1) - 1.0, 2.0 * h(2) - 1.0, 2.0 * h(3) - 1.0],
            [(0.02f32).ln(); 3],
            [1.0, 0.0, 0.0, 0.0],
            &[h(4), h(5), 2.0 * h(6)],
            2.0 * h(7) - 1.0,
        );
    }
    out.push(("dense small splats", dense, camera(160, 96), base));
    out
}

/// Fraction of values off by more than `small`, and the largest difference.
fn compare(a: &[f32], b: &[f32], small: f32) -> (f64, f32) {
    assert_eq!(a.len(), b.len());
    let mut over = 0usize;
    let mut worst = 0.0f32;
    for (x, y) in a.iter().zip(b) {
        let d = (x - y).abs();
        // Written so that a NaN counts as over and as the worst.
        if !(d <= small) {
            over += 1;
        }
        if !(d <= worst) {
            worst = d;
        }
    }
    (over as f64 / a.len() as f64, worst)
}

fn flat(c: &[[f32; 3]]) -> Vec<f32> {
    c.iter().flatten().copied().collect()
}

#[test]
fn lane_images_equal_the_scalar_kernel_within_rounding() {
    for (name, cloud, cam, cfg) in scenes() {
        let scalar = RasterConfig {
            kernel: Kernel::Scalar,
            ..cfg
        };
        let (want, want_state) = render(&cloud, &cam, &scalar);
        assert_eq!(want_state.kernel(), Kernel::Scalar);
        let peak = flat(&want.color).iter().fold(1.0f32, |m, v| m.max(*v));
        for kernel in lane_kernels() {
            let (got, state) = render(&cloud, &cam, &RasterConfig { kernel, ..cfg });
            assert_eq!(state.kernel(), kernel);
            for (what, a, b, scale) in [
                ("colour", flat(&got.color), flat(&want.color), peak),
                (
                    "transmittance",
                    got.transmittance.clone(),
                    want.transmittance.clone(),
                    1.0,
                ),
            ] {
                let (share, worst) = compare(&a, &b, 1e-5 * scale);
                // One threshold flip: a splat of alpha just above 1/255 (times T <= 1 and the
                // colour) moves the pixel by at most 1/255 of the peak; 1.01 for the rounding.
                let flip = 1.01 / 255.0 * scale;
                assert!(
                    share <= 0.002 && worst <= flip,
                    "{name}, {kernel:?}, {what}: {:.4}% of values off by more than 1e-5 x {scale}, worst {worst}",
                    100.0 * share
                );
            }
            let depth_peak = want
                .depth
                .as_ref()
                .unwrap()
                .iter()
                .fold(1.0f32, |m, v| m.max(*v));
            let (share, _) = compare(
                got.depth.as_ref().unwrap(),
                want.depth.as_ref().unwrap(),
                1e-5 * depth_peak,
            );
            assert!(share <= 0.002, "{name}, {kernel:?}, depth: {share}");
            assert!(
                flat(&got.color).iter().all(|v| v.is_finite()),
                "{name}, {kernel:?}: a non-finite pixel"
            );
        }
    }
}

/// Upstream gradients on colour, transmittance and depth, varying across the image.
fn upstream(n: usize) -> (Vec<[f32; 3]>, Vec<f32>, Vec<f32>) {
    let color = (0..n)
        .map(|i| [(i % 7) as f32 - 3.0, 1.0 + (i % 3) as f32, 0.5])
        .collect();
    let trans = (0..n).map(|i| 0.25 * ((i % 5) as f32 - 2.0)).collect();
    let depth = (0..n).map(|i| 0.1 * ((i % 11) as f32 - 5.0)).collect();
    (color, trans, depth)
}

fn gradients<F: splat_raster::real::Real>(
    cloud: &GaussianCloud<F>,
    cam: &Camera,
    cfg: &RasterConfig,
    with_depth: bool,
) -> CloudGradients<F> {
    let (out, state) = render(cloud, cam, cfg);
    let (color, trans, depth) = upstream(out.color.len());
    let c = |v: f32| F::c(v as f64);
    let color: Vec<[F; 3]> = color.iter().map(|v| v.map(c)).collect();
    let trans: Vec<F> = trans.into_iter().map(c).collect();
    let depth: Vec<F> = depth.into_iter().map(c).collect();
    backward(
        cloud,
        cam,
        &state,
        PixelGrads {
            color: &color,
            transmittance: Some(&trans),
            depth: with_depth.then_some(&depth[..]),
        },
    )
}

/// Relative L2 distance of each parameter group from the f64 gradients.
fn distance(got: &CloudGradients<f32>, want: &CloudGradients<f64>) -> Vec<(&'static str, f64)> {
    got.groups()
        .iter()
        .zip(want.groups().iter())
        .map(|((group, a), (_, b))| {
            let (mut diff, mut norm) = (0.0f64, 0.0f64);
            for (x, y) in a.iter().zip(b.iter()) {
                // Written so that a non-finite gradient fails below.
                diff += if x.is_finite() {
                    (*x as f64 - y).powi(2)
                } else {
                    f64::INFINITY
                };
                norm += y.powi(2);
            }
            (*group, (diff / norm.max(1e-30)).sqrt())
        })
        .collect()
}

/// The lanes' gradients are as close to the f64 gradients as the scalar f32 kernel's are.
///
/// Both are measured against f64 because some gradients are ill-conditioned in f32 (a needle
/// Gaussian's rotation: the scalar f32 kernel is itself 0.6% off there), so a direct comparison
/// of two f32 kernels would mostly measure that conditioning. Allowed: 3 times the scalar
/// kernel's distance (measured: at most 1.5x), or 2e-5, whichever is larger; on the scene built
/// to be ill-conditioned, whose sums cancel so that any change of summation order moves them,
/// 20 times (measured: up to 8.8x, on log-scales). Well-conditioned groups sit near 1e-7; a lost
/// or doubled splat contribution, or a wrong term, is 1e-2 or more.
#[test]
fn lane_gradients_are_as_accurate_as_the_scalar_kernel() {
    for (name, cloud, cam, cfg) in scenes() {
        for with_depth in [false, true] {
            let exact = gradients(&cloud.cast::<f64>(), &cam, &cfg, with_depth);
            let scalar = RasterConfig {
                kernel: Kernel::Scalar,
                ..cfg
            };
            let floor = distance(&gradients(&cloud, &cam, &scalar, with_depth), &exact);
            let allowed = if name == ILL_CONDITIONED { 20.0 } else { 3.0 };
            for kernel in lane_kernels() {
                let got = gradients(&cloud, &cam, &RasterConfig { kernel, ..cfg }, with_depth);
                for ((group, d), (_, d_scalar)) in distance(&got, &exact).into_iter().zip(&floor) {
                    assert!(
                        d <= (allowed * d_scalar).max(2e-5),
                        "{name}, {kernel:?}, depth {with_depth}: {group} is {d:e} from f64 (scalar f32: {d_scalar:e})"
                    );
                }
            }
        }
    }
}

#[test]
fn every_kernel_is_bit_identical_for_one_two_and_three_threads() {
    let (_, cloud, cam, cfg) = scenes().swap_remove(0);
    let mut kernels = lane_kernels();
    kernels.push(Kernel::Scalar);
    for kernel in kernels {
        let cfg = RasterConfig { kernel, ..cfg };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let (out, _) = render(&cloud, &cam, &cfg);
                    let g = gradients(&cloud, &cam, &cfg, true);
                    let mut bits: Vec<u32> = flat(&out.color).iter().map(|v| v.to_bits()).collect();
                    for (_, v) in g.groups() {
                        bits.extend(v.iter().map(|x| x.to_bits()));
                    }
                    bits
                })
        };
        let one = run(1);
        assert_eq!(one, run(2), "{kernel:?}: 1 vs 2 threads");
        assert_eq!(one, run(3), "{kernel:?}: 1 vs 3 threads");
    }
}

#[test]
fn kernel_choice_resolves_to_what_the_cpu_runs() {
    let widest = if Kernel::Lanes8.available() {
        Kernel::Lanes8
    } else {
        Kernel::Lanes4
    };
    assert_eq!(Kernel::Auto.resolve(), widest);
    assert_eq!(Kernel::Lanes8.resolve(), widest);
    assert_eq!(Kernel::Lanes4.resolve(), Kernel::Lanes4);
    assert_eq!(Kernel::Scalar.lanes(), 1);
    // The f64 path has no lanes: it always runs the scalar kernel.
    let cloud = random_cloud(10, ColorModel::Rgb, 3);
    let cam =
        Camera::look_at(Vec3::new(0.0, 0.0, -4.0), Vec3::ZERO, Vec3::Y, 50.0, 20, 20).unwrap();
    let (_, state) = render(&cloud, &cam, &RasterConfig::default());
    assert_eq!(state.kernel(), Kernel::Scalar);
    let (_, state) = render(&cloud.cast::<f32>(), &cam, &RasterConfig::default());
    assert_eq!(state.kernel(), widest);
}

/// Pixels masked out of a loss (zero upstream gradient) are skipped by the backward pass. The
/// skip must never drop a pixel that has any gradient left: the gradients of `u` must equal
/// those of `u` plus a tiny red gradient on every pixel (so that no pixel is skipped) to within
/// that tiny change. The upstream gradients have single non-zero components on some pixels (only
/// green, only the transmittance, only the depth), so a skip that looked at the colour alone
/// drops those pixels' whole contribution and fails by far more.
#[test]
fn masked_pixels_are_skipped_and_no_others() {
    let (_, cloud, cam, cfg) = scenes().swap_remove(1);
    let n = (cam.width * cam.height) as usize;
    let upstream = |i: usize| -> ([f64; 3], f64, f64) {
        match i % 5 {
            0 => ([0.0, 0.7, 0.0], 0.0, 0.0),
            1 => ([0.0, 0.0, 0.0], -0.4, 0.0),
            2 => ([0.0, 0.0, 0.0], 0.0, 0.3),
            3 => ([0.0; 3], 0.0, 0.0),
            _ => ([0.2, -1.0, 0.5], 0.1, -0.2),
        }
    };
    fn grads<F: splat_raster::real::Real>(
        cloud: &GaussianCloud<F>,
        cam: &Camera,
        cfg: &RasterConfig,
        n: usize,
        up: impl Fn(usize) -> ([f64; 3], f64, f64),
        nudge: f64,
    ) -> Vec<f64> {
        let (_, state) = render(cloud, cam, cfg);
        let c = |v: f64| F::c(v);
        let color: Vec<[F; 3]> = (0..n)
            .map(|i| {
                let [r, g, b] = up(i).0;
                [c(r + nudge), c(g), c(b)]
            })
            .collect();
        let trans: Vec<F> = (0..n).map(|i| c(up(i).1)).collect();
        let depth: Vec<F> = (0..n).map(|i| c(up(i).2)).collect();
        let g = backward(
            cloud,
            cam,
            &state,
            PixelGrads {
                color: &color,
                transmittance: Some(&trans),
                depth: Some(&depth),
            },
        );
        g.groups()
            .iter()
            .flat_map(|(_, v)| v.iter().map(|x| x.as_f64()))
            .collect()
    }
    fn distance(a: &[f64], b: &[f64]) -> f64 {
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        for (x, y) in a.iter().zip(b) {
            diff += (x - y).powi(2);
            norm += y.powi(2);
        }
        (diff / norm).sqrt()
    }
    let c64 = cloud.cast::<f64>();
    let d = distance(
        &grads(&c64, &cam, &cfg, n, upstream, 0.0),
        &grads(&c64, &cam, &cfg, n, upstream, 1e-9),
    );
    assert!(d <= 1e-6, "f64: {d:e}");
    for kernel in lane_kernels() {
        let cfg = RasterConfig { kernel, ..cfg };
        let d = distance(
            &grads(&cloud, &cam, &cfg, n, upstream, 0.0),
            &grads(&cloud, &cam, &cfg, n, upstream, 1e-6),
        );
        assert!(d <= 1e-3, "{kernel:?}: {d:e}");
    }
}
