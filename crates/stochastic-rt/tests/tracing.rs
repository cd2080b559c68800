//! The BVH finds exactly what brute force finds; the stochastic estimator is unbiased against
//! the exact sorted composite; degenerate Gaussians never produce NaN.

use glam::Vec3;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use splat_raster::io::read_ply;
use splat_raster::{Camera, ColorModel, GaussianCloud};
use std::path::PathBuf;
use stochastic_rt::estimators::{all_hits, trace_exact, trace_stochastic};
use stochastic_rt::{DepthMode, GaussianScene};

fn random_cloud(n: usize, seed: u64) -> GaussianCloud<f32> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut c = GaussianCloud::new(ColorModel::Rgb);
    for i in 0..n {
        // Mostly small; some very thin, some huge.
        let ls = match i % 10 {
            0 => [rng.random_range(-6.0..-4.0), -1.5, -1.5],
            1 => [0.5, 0.3, 0.2],
            _ => [
                rng.random_range(-2.5..-1.0),
                rng.random_range(-2.5..-1.0),
                rng.random_range(-2.5..-1.0),
            ],
        };
        let m = [
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ];
        let q = [
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ];
        let col = [
            rng.random_range(0.0..1.5),
            rng.random_range(0.0..1.5),
            rng.random_range(0.0..1.5),
        ];
        c.push(m, ls, q, &col, rng.random_range(-2.0..1.5));
    }
    c
}

fn brute_hits(scene: &GaussianScene, o: Vec3, d: Vec3) -> Vec<(u32, u32)> {
    let g = &scene.gaussians;
    let mut v: Vec<(u32, u32)> = (0..g.len())
        .filter_map(|i| {
            g.intersect(i, o, d, 0.0, f32::INFINITY, DepthMode::Mean, Vec3::Z)
                .map(|h| (g.ids[i], h.t.to_bits()))
        })
        .collect();
    v.sort();
    v
}

fn bvh_hits(scene: &GaussianScene, o: Vec3, d: Vec3) -> Vec<(u32, u32)> {
    let g = &scene.gaussians;
    let mut v: Vec<(u32, u32)> = all_hits(scene, o, d, DepthMode::Mean, Vec3::Z)
        .into_iter()
        .map(|(t, _, i)| (g.ids[i], t.to_bits()))
        .collect();
    v.sort();
    v
}

#[test]
fn bvh_and_brute_force_report_identical_hit_sets() {
    let mut rng = StdRng::seed_from_u64(3);
    let mut clouds = vec![("random", random_cloud(400, 1))];
    let asset = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/splats/fruit_drops_minimal_inria.ply");
    clouds.push(("fruit_drops", read_ply(&asset).unwrap()));
    for (name, cloud) in clouds {
        let scene = GaussianScene::new(&cloud);
        let g = &scene.gaussians;
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for i in 0..g.len() {
            lo = lo.min(g.means[i]);
            hi = hi.max(g.means[i]);
        }
        let (mut total, mut inside) = (0, 0);
        for k in 0..3000 {
            let d = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize();
            // A third of the rays start at a Gaussian's mean: inside its bounds.
            let o = if k % 3 == 0 {
                inside += 1;
                g.means[rng.random_range(0..g.len())]
            } else {
                lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random())
                    - d * (hi - lo).length()
            };
            let a = bvh_hits(&scene, o, d);
            let b = brute_hits(&scene, o, d);
            assert_eq!(a, b, "{name}: ray {k} from {o} along {d}");
            total += a.len();
        }
        assert!(
            total > 3000 && inside > 0,
            "{name}: too few hits to test ({total})"
        );
    }
}

#[test]
fn stochastic_estimate_is_unbiased_against_exact() {
    let cloud = random_cloud(300, 2);
    let scene = GaussianScene::new(&cloud);
    let cam =
        Camera::look_at(Vec3::new(0.2, 0.1, -4.0), Vec3::ZERO, Vec3::Y, 45.0, 32, 24).unwrap();
    let (_, _, fwd) = cam.axes();
    let bg = Vec3::new(0.2, 0.3, 0.4);
    let n = 400u32;
    let (mut chi2, mut k, mut worst) = (0.0f64, 0usize, 0.0f64);
    let mut mse = [0.0f64; 3];
    for p in 0..cam.width * cam.height {
        let d = cam.ray_direction((p % cam.width) as f32 + 0.5, (p / cam.width) as f32 + 0.5);
        let exact = trace_exact(&scene, cam.position, d, DepthMode::Mean, fwd, bg);
        // Exact variance of one estimate: the composite of squared colours minus the square.
        let mut hits = all_hits(&scene, cam.position, d, DepthMode::Mean, fwd);
        hits.sort_by(|a, b| {
            a.0.total_cmp(&b.0)
                .then(scene.gaussians.ids[a.2].cmp(&scene.gaussians.ids[b.2]))
        });
        let (mut t, mut second) = (1.0f64, 0.0f64);
        for (_, alpha, i) in &hits {
            second +=
                t * *alpha as f64 * (scene.gaussians.color(*i, cam.position).x as f64).powi(2);
            t *= 1.0 - *alpha as f64;
        }
        second += t * (bg.x as f64).powi(2);
        let var = (second - (exact.x as f64).powi(2)).max(0.0);
        let mut sums = [0.0f64; 3];
        for s in 0..n {
            let e = trace_stochastic(&scene, cam.position, d, DepthMode::Mean, fwd, bg, 9, p, s).x
                as f64;
            assert!(e.is_finite());
            sums[0] += e;
            if s < 4 {
                sums[1] += e;
            }
            if s < 64 {
                sums[2] += e;
            }
        }
        let means = [sums[0] / n as f64, sums[1] / 4.0, sums[2] / 64.0];
        for (j, m) in means.iter().enumerate() {
            mse[j] += (m - exact.x as f64).powi(2);
        }
        if var < 1e-9 {
            continue;
        }
        let z = (means[0] - exact.x as f64) / (var / n as f64).sqrt();
        chi2 += z * z;
        worst = worst.max(z.abs());
        k += 1;
    }
    let a = 2.0 / (9.0 * k as f64);
    let limit = k as f64 * (1.0 - a + 4.265 * a.sqrt()).powi(3);
    eprintln!(
        "stochastic vs exact: chi2 {chi2:.1} over {k} pixels (limit {limit:.1}, false alarm 1e-5), max |z| {worst:.2}; MSE at 4/64/400 spp {:.3e} {:.3e} {:.3e}",
        mse[1], mse[2], mse[0]
    );
    assert!(k > 300, "too few noisy pixels: {k}");
    assert!(
        chi2 < limit && worst < 5.5,
        "chi2 {chi2} (limit {limit}), max |z| {worst}"
    );
    // MSE falls as 1/spp: from 4 to 64 samples by about 16x.
    let r = mse[1] / mse[2];
    assert!((10.0..25.0).contains(&r), "MSE ratio 4 -> 64 spp: {r}");
}

#[test]
fn degenerate_gaussians_never_produce_nan() {
    let mut cloud = random_cloud(50, 5);
    let col = [0.5f32; 3];
    for (m, s, q, o) in [
        (
            [f32::NAN, 0.0, 0.0],
            [-1.0f32; 3],
            [1.0f32, 0.0, 0.0, 0.0],
            0.0f32,
        ),
        ([0.0; 3], [f32::NEG_INFINITY; 3], [1.0, 0.0, 0.0, 0.0], 0.0),
        ([0.0; 3], [40.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0),
        ([0.0; 3], [-1.0; 3], [0.0; 4], 0.0),
        ([0.0; 3], [-1.0, -30.0, -1.0], [0.3, 0.2, 0.1, 0.9], 2.0),
        ([0.0; 3], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], f32::NAN),
    ] {
        cloud.push(m, s, q, &col, o);
    }
    let scene = GaussianScene::new(&cloud);
    let cam =
        Camera::look_at(Vec3::new(0.0, 0.0, -4.0), Vec3::ZERO, Vec3::Y, 45.0, 24, 16).unwrap();
    let (_, _, fwd) = cam.axes();
    for p in 0..cam.width * cam.height {
        let d = cam.ray_direction((p % cam.width) as f32 + 0.5, (p / cam.width) as f32 + 0.5);
        assert!(trace_exact(&scene, cam.position, d, DepthMode::Mean, fwd, Vec3::ZERO).is_finite());
        assert!(
            trace_stochastic(
                &scene,
                cam.position,
                d,
                DepthMode::Mean,
                fwd,
                Vec3::ZERO,
                1,
                p,
                0
            )
            .is_finite()
        );
    }
}
