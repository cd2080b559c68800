//! The BVH finds exactly what brute force finds; the stochastic estimator is unbiased against
//! the exact sorted composite; degenerate Gaussians never produce NaN.

use glam::Vec3;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use splat_raster::io::read_ply;
use splat_raster::{Camera, ColorModel, GaussianCloud};
use std::path::PathBuf;
use stochastic_rt::estimators::{
    TraceRay, all_hits, k_closest_after, trace_exact, trace_kbuffer, trace_stochastic,
    trace_stochastic_pass,
};
use stochastic_rt::random::SampleKey;
use stochastic_rt::{DepthMode, GaussianScene, RandomKind};

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
    let r = TraceRay {
        o,
        d,
        mode: DepthMode::Mean,
        forward: Vec3::Z,
    };
    let mut v: Vec<(u32, u32)> = all_hits(scene, &r)
        .into_iter()
        .map(|(t, _, i)| (g.ids[i], t.to_bits()))
        .collect();
    v.sort();
    v
}

/// The box of the traceable Gaussians' means.
fn mean_bounds(g: &stochastic_rt::gaussians::TraceGaussians) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for m in &g.means {
        lo = lo.min(*m);
        hi = hi.max(*m);
    }
    (lo, hi)
}

/// A random unit direction (not uniform on the sphere; any spread of directions will do).
fn random_direction(rng: &mut StdRng) -> Vec3 {
    Vec3::new(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
    )
    .normalize()
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
        let (lo, hi) = mean_bounds(g);
        let (mut total, mut inside) = (0, 0);
        for k in 0..3000 {
            let d = random_direction(&mut rng);
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

/// Exact mean and second moment of one estimate of each estimator on a ray (channel 0).
fn moments(scene: &GaussianScene, r: &TraceRay, bg: Vec3, pass_k: Option<usize>) -> (f64, f64) {
    let g = &scene.gaussians;
    let c0 = |i: usize| g.color(i, r.o).x as f64;
    match pass_k {
        None => {
            // Closest accepted: Gaussian i wins with weight T_i alpha_i, the background with T.
            let mut hits = all_hits(scene, r);
            hits.sort_by(|a, b| a.0.total_cmp(&b.0).then(g.ids[a.2].cmp(&g.ids[b.2])));
            let (mut t, mut m1, mut m2) = (1.0f64, 0.0, 0.0);
            for (_, alpha, i) in hits {
                let w = t * alpha as f64;
                m1 += w * c0(i);
                m2 += w * c0(i) * c0(i);
                t *= 1.0 - alpha as f64;
            }
            (m1 + t * bg.x as f64, m2 + t * (bg.x as f64).powi(2))
        }
        Some(k) => {
            // Pass j is reached with probability prod of earlier T, accepted with p_j = 1 - T_j,
            // and returns L_j / p_j.
            let (mut reach, mut m1, mut m2) = (1.0f64, 0.0, 0.0);
            let mut buf = Vec::new();
            let mut after = None;
            loop {
                k_closest_after(scene, r, after, k, &mut buf);
                if buf.is_empty() {
                    break;
                }
                let (mut t, mut l) = (1.0f32, 0.0f32);
                for &(_, alpha, i) in &buf {
                    l += t * alpha * g.color(i, r.o).x;
                    t *= 1.0 - alpha;
                }
                let p = 1.0 - t as f64;
                let est = l as f64 / p;
                m1 += reach * p * est;
                m2 += reach * p * est * est;
                reach *= 1.0 - p;
                if buf.len() < k {
                    break;
                }
                let &(tl, _, i) = buf.last().unwrap();
                after = Some((tl, g.ids[i]));
            }
            (m1 + reach * bg.x as f64, m2 + reach * (bg.x as f64).powi(2))
        }
    }
}

/// Per-pixel z-scores of `n` estimates against the exact mean with the exact variance, summed
/// into a chi-square; asserts it under the 1e-5 upper quantile and every |z| under 5.5.
fn check_unbiased(
    name: &str,
    n: u32,
    per_estimate_var_scale: f64,
    pass_k: Option<usize>,
    estimate: impl Fn(&GaussianScene, &TraceRay, Vec3, u32, u32) -> Vec3,
) -> f64 {
    let cloud = random_cloud(300, 2);
    let scene = GaussianScene::new(&cloud);
    let cam =
        Camera::look_at(Vec3::new(0.2, 0.1, -4.0), Vec3::ZERO, Vec3::Y, 45.0, 24, 18).unwrap();
    let bg = Vec3::new(0.2, 0.3, 0.4);
    let (mut scores, mut mse) = (test_stats::ZScores::new(), 0.0f64);
    for p in 0..cam.width * cam.height {
        let r = TraceRay::through_pixel(&cam, p, DepthMode::Mean);
        let (m1, m2) = moments(&scene, &r, bg, pass_k);
        let var = (m2 - m1 * m1).max(0.0) * per_estimate_var_scale;
        let mean = (0..n)
            .map(|s| estimate(&scene, &r, bg, p, s).x as f64)
            .sum::<f64>()
            / n as f64;
        assert!(mean.is_finite());
        mse += (mean - m1).powi(2);
        if var < 1e-9 {
            continue;
        }
        scores.add(mean - m1, var / n as f64);
    }
    scores.assert_unbiased(name, 5.5, 200);
    mse / (cam.width * cam.height) as f64
}

#[test]
fn stochastic_estimators_are_unbiased_against_exact() {
    for kind in [RandomKind::Hash, RandomKind::Trig] {
        check_unbiased(
            &format!("stochastic ({kind:?})"),
            400,
            1.0,
            None,
            |s, r, bg, p, i| trace_stochastic(s, r, bg, &SampleKey::new(9, p, i), 1, kind),
        );
    }
    check_unbiased(
        "stochastic, 8 samples per traversal",
        100,
        1.0 / 8.0,
        None,
        |s, r, bg, p, i| trace_stochastic(s, r, bg, &SampleKey::new(9, p, i), 8, RandomKind::Hash),
    );
    check_unbiased(
        "stochastic pass, k = 4",
        400,
        1.0,
        Some(4),
        |s, r, bg, p, i| trace_stochastic_pass(s, r, bg, &SampleKey::new(9, p, i), 4),
    );
}

#[test]
fn stochastic_mse_falls_as_one_over_spp() {
    let est = |s: &GaussianScene, r: &TraceRay, bg: Vec3, p: u32, i: u32| {
        trace_stochastic(s, r, bg, &SampleKey::new(3, p, i), 1, RandomKind::Hash)
    };
    let m4 = check_unbiased("4 spp", 4, 1.0, None, est);
    let m64 = check_unbiased("64 spp", 64, 1.0, None, est);
    let r = m4 / m64;
    eprintln!("MSE 4 spp / 64 spp = {r:.2} (16 expected)");
    assert!((11.0..23.0).contains(&r), "MSE ratio {r}");
}

#[test]
fn kbuffer_equals_exact_without_its_stop() {
    let cloud = random_cloud(300, 4);
    let scene = GaussianScene::new(&cloud);
    let cam =
        Camera::look_at(Vec3::new(0.0, 0.2, -4.0), Vec3::ZERO, Vec3::Y, 45.0, 24, 18).unwrap();
    let bg = Vec3::new(0.1, 0.2, 0.3);
    let mut max_hits = 0;
    // Centre depth too: the K-th hit's depth clips the traversal, and a centre's depth can lie
    // outside its box along the ray, so the clip must leave room for it.
    for mode in [DepthMode::Mean, DepthMode::Center] {
        for p in 0..cam.width * cam.height {
            let r = TraceRay::through_pixel(&cam, p, mode);
            max_hits = max_hits.max(all_hits(&scene, &r).len());
            let e = trace_exact(&scene, &r, bg);
            for k in [1, 3, 16] {
                let kb = trace_kbuffer(&scene, &r, bg, k, 0.0);
                assert!(
                    (kb - e).abs().max_element() <= 1e-6,
                    "{mode:?} pixel {p}, k {k}: {kb} vs {e}"
                );
            }
        }
    }
    assert!(
        max_hits > 16,
        "rays must need several passes ({max_hits} hits at most)"
    );
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
    for p in 0..cam.width * cam.height {
        let r = TraceRay::through_pixel(&cam, p, DepthMode::Mean);
        assert!(trace_exact(&scene, &r, Vec3::ZERO).is_finite());
        assert!(trace_kbuffer(&scene, &r, Vec3::ZERO, 4, 0.01).is_finite());
        assert!(
            trace_stochastic(
                &scene,
                &r,
                Vec3::ZERO,
                &SampleKey::new(1, p, 0),
                4,
                RandomKind::Trig
            )
            .is_finite()
        );
        assert!(
            trace_stochastic_pass(&scene, &r, Vec3::ZERO, &SampleKey::new(1, p, 0), 4).is_finite()
        );
    }
}

/// A refitted BVH after the Gaussians moved finds exactly the hits brute force finds, and a
/// move large enough to spoil the tree (or a Gaussian fading out) makes it rebuild.
#[test]
fn a_refitted_bvh_finds_every_hit_after_the_gaussians_move() {
    let mut rng = StdRng::seed_from_u64(9);
    let mut cloud = random_cloud(400, 4);
    let mut scene = GaussianScene::new(&cloud);
    // Small moves, as a training step makes: refitted, not rebuilt.
    for m in cloud.means.iter_mut() {
        *m += rng.random_range(-0.02..0.02);
    }
    assert!(
        !scene.update(&cloud),
        "a small move must refit, not rebuild"
    );
    let g = &scene.gaussians;
    let (lo, hi) = mean_bounds(g);
    let mut total = 0;
    for k in 0..2000 {
        let d = random_direction(&mut rng);
        let o = lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random())
            - d * (hi - lo).length();
        let a = bvh_hits(&scene, o, d);
        assert_eq!(a, brute_hits(&scene, o, d), "ray {k}");
        total += a.len();
    }
    assert!(total > 2000, "too few hits to test ({total})");
    // Scatter the Gaussians far apart: the old topology is poor, so the tree is rebuilt.
    for m in cloud.means.iter_mut() {
        *m = rng.random_range(-20.0..20.0);
    }
    assert!(scene.update(&cloud), "a scattered cloud must be rebuilt");
    // A Gaussian that fades below 1/255 leaves the traceable set: rebuilt.
    cloud.opacity_logits[0] = -20.0;
    assert!(scene.update(&cloud));
}

/// The bundled 3DGS asset seen obliquely: many elongated Gaussians whose centres sit far from
/// where rays meet them, the case that broke centre-depth clipping.
fn fruit_scene() -> (GaussianScene, Camera) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/splats/fruit_drops_minimal_inria.ply");
    let cloud = read_ply(&path).unwrap();
    let n = cloud.len() as f32;
    let centre = cloud
        .means
        .chunks(3)
        .fold(Vec3::ZERO, |a, m| a + Vec3::from_slice(m))
        / n;
    let cam = Camera::look_at(
        centre + Vec3::new(0.35, -0.25, -0.5),
        centre,
        Vec3::new(0.0, -1.0, 0.0),
        70.0,
        48,
        36,
    )
    .unwrap();
    (GaussianScene::new(&cloud), cam)
}

#[test]
fn centre_depth_kbuffer_equals_exact_on_a_real_asset() {
    let (scene, cam) = fruit_scene();
    let bg = Vec3::new(0.1, 0.2, 0.3);
    let mut differ = 0;
    let mut hits = 0;
    for p in 0..cam.width * cam.height {
        let r = TraceRay::through_pixel(&cam, p, DepthMode::Center);
        hits += all_hits(&scene, &r).len();
        let e = trace_exact(&scene, &r, bg);
        for k in [1, 4] {
            let kb = trace_kbuffer(&scene, &r, bg, k, 0.0);
            if (kb - e).abs().max_element() > 1e-5 {
                differ += 1;
            }
        }
    }
    eprintln!("{hits} hits; {differ} (pixel, k) pairs differ");
    assert!(hits > 10_000, "too few hits ({hits}) to exercise the clip");
    assert_eq!(
        differ, 0,
        "k-buffer passes skipped hits that sort before their clip"
    );
}

/// Where the ray first meets Gaussian `i`'s box (the BVH culls by this).
fn box_entry(scene: &GaussianScene, i: usize, r: &TraceRay) -> f32 {
    let g = &scene.gaussians;
    let inv = r.d.recip();
    let a = (g.lower[i] - r.o) * inv;
    let b = (g.upper[i] - r.o) * inv;
    a.min(b).max_element().max(0.0)
}

/// Pixels where centre-depth clipping can go wrong, most sensitive first: some hit `i` sorts
/// before another `j` (smaller centre depth), yet the ray meets `i`'s box only after `j`'s depth,
/// so a clip at an accepted `j` would skip `i`. A pixel's sensitivity is the largest
/// `alpha_i alpha_j |c_i - c_j|` (channel 0) over such pairs: how much the skip moves its mean.
fn clip_sensitive_pixels(scene: &GaussianScene, cam: &Camera) -> Vec<u32> {
    let g = &scene.gaussians;
    let mut ranked: Vec<(f32, u32)> = (0..cam.width * cam.height)
        .filter_map(|p| {
            let r = TraceRay::through_pixel(cam, p, DepthMode::Center);
            let hits = all_hits(scene, &r);
            let mut worst = 0.0f32;
            for &(ti, ai, i) in &hits {
                let entry = box_entry(scene, i, &r);
                for &(tj, aj, j) in &hits {
                    if ti < tj && entry > tj {
                        let dc = (g.color(i, r.o).x - g.color(j, r.o).x).abs();
                        worst = worst.max(ai * aj * dc);
                    }
                }
            }
            (worst > 0.0).then_some((worst, p))
        })
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    ranked.into_iter().map(|(_, p)| p).collect()
}

/// The stochastic estimator with centre depth converges to the exact composite in centre-depth
/// order, on the 16 pixels where the traversal clip could most change the mean. Statistic: per
/// pixel z of the mean of 50000 estimates against the exact mean and variance (channel 0);
/// chi-square under its 1e-5 quantile and |z| < 5.5 (false alarm about 1e-5 overall). Without
/// the clip margin this fails (chi-square 199 over 16 when it was written).
#[test]
fn centre_depth_stochastic_is_unbiased_where_the_clip_matters() {
    let (scene, cam) = fruit_scene();
    let bg = Vec3::new(0.1, 0.2, 0.3);
    let pixels = clip_sensitive_pixels(&scene, &cam);
    assert!(pixels.len() >= 16, "only {} sensitive pixels", pixels.len());
    let n = 50_000u32;
    let mut scores = test_stats::ZScores::new();
    for &p in pixels.iter().take(16) {
        let r = TraceRay::through_pixel(&cam, p, DepthMode::Center);
        let (m1, m2) = moments(&scene, &r, bg, None);
        let var = (m2 - m1 * m1).max(0.0);
        let mean = (0..n)
            .map(|s| {
                trace_stochastic(
                    &scene,
                    &r,
                    bg,
                    &SampleKey::new(5, p, s),
                    1,
                    RandomKind::Hash,
                )
                .x as f64
            })
            .sum::<f64>()
            / n as f64;
        if var > 1e-9 {
            scores.add(mean - m1, var / n as f64);
        }
    }
    scores.assert_unbiased("stochastic, centre depth, clip-sensitive pixels", 5.5, 12);
}

/// Both acceptance generators converge to the exact composite on a real asset, where most hits
/// are faint: the trigonometric hash in f32 put its numbers on a 1/256 grid and failed this
/// (chi-square 1657 over 1318 pixels when it was written). Statistic: per-pixel z of 2048 estimates against the exact mean and
/// variance (channel 0), chi-square under its 1e-5 quantile, |z| < 5.5.
#[test]
fn both_generators_are_unbiased_on_a_real_asset() {
    let (scene, cam) = fruit_scene();
    let bg = Vec3::new(0.1, 0.2, 0.3);
    let n = 2048u32;
    for kind in [RandomKind::Hash, RandomKind::Trig] {
        let mut scores = test_stats::ZScores::new();
        for p in 0..cam.width * cam.height {
            let r = TraceRay::through_pixel(&cam, p, DepthMode::Mean);
            let (m1, m2) = moments(&scene, &r, bg, None);
            let var = (m2 - m1 * m1).max(0.0);
            if var < 1e-9 {
                continue;
            }
            let mean = (0..n)
                .map(|s| {
                    trace_stochastic(&scene, &r, bg, &SampleKey::new(11, p, s), 1, kind).x as f64
                })
                .sum::<f64>()
                / n as f64;
            scores.add(mean - m1, var / n as f64);
        }
        scores.assert_unbiased(&format!("{kind:?} on the fruit asset"), 5.5, 500);
    }
}

/// The cache's lookup traces its camera's rays a row at a time through the Gaussians'
/// depth-sorted silhouettes (`camera_grid`): its image must be its definition's
/// (`camera_grid::reference_image`: every Gaussian, in depth order, on every pixel's ray) bit
/// for bit: the same hits, found through the bands and chords, in the same order, filling the
/// same slots. For 1, 8 and 64 slots, more than one estimate per pixel, and cameras from outside
/// the cloud looking at it, at an angle, and from its edge (boxes reaching behind the camera).
/// Also through one `CameraTracer` and one `TraceGaussians` kept across all of them (as the
/// cache keeps them), first filled from a larger cloud of large Gaussians, whose lists reach
/// every row: what an earlier call left in their memory must not reach an image.
#[test]
fn the_camera_grid_is_its_definition_bit_for_bit() {
    use stochastic_rt::camera_grid::reference_image;
    use stochastic_rt::{CameraTracer, TraceGaussians, trace_camera_image};
    let cloud = random_cloud(1500, 11);
    let scene = GaussianScene::new(&cloud);
    let mut large = random_cloud(3000, 12);
    large
        .log_scales
        .iter_mut()
        .for_each(|s| *s = s.max(-1.0) + 1.0);
    let mut kept = TraceGaussians::new(&large);
    let mut tracer = CameraTracer::default();
    let wide = Camera::look_at(Vec3::new(0.0, 0.0, -3.0), Vec3::ZERO, Vec3::Y, 60.0, 90, 70);
    tracer.trace(&kept, &wide.unwrap(), 8, 1, 5, Vec3::ZERO);
    kept.prepare(&cloud);
    let g = &scene.gaussians;
    assert_eq!(
        (&kept.ids, &kept.means, &kept.canonical),
        (&g.ids, &g.means, &g.canonical)
    );
    assert_eq!(
        (&kept.opacity, &kept.cutoff, &kept.colors),
        (&g.opacity, &g.cutoff, &g.colors)
    );
    assert_eq!((&kept.lower, &kept.upper), (&g.lower, &g.upper));
    assert_eq!(kept.max_half_diagonal, g.max_half_diagonal);
    let cameras = [
        (Vec3::new(0.3, -0.2, -4.0), Vec3::ZERO, 57, 41),
        (Vec3::new(3.0, 2.0, 2.5), Vec3::new(0.2, 0.0, 0.1), 48, 48),
        (Vec3::new(0.0, 0.0, -2.2), Vec3::new(0.5, 0.5, 0.0), 40, 23),
    ];
    let background = Vec3::new(0.1, 0.2, 0.3);
    let mut compared = 0;
    for (eye, target, w, h) in cameras {
        let camera = Camera::look_at(eye, target, Vec3::Y, 45.0, w, h).unwrap();
        for (slots, spp) in [(1, 1), (8, 2), (64, 1)] {
            let want = reference_image(&scene.gaussians, &camera, slots, spp, 5, background);
            let got = trace_camera_image(&scene.gaussians, &camera, slots, spp, 5, background);
            let again = tracer.trace(&kept, &camera, slots, spp, 5, background);
            for (image, how) in [(got, "fresh"), (again, "kept")] {
                let differ = want.iter().zip(&image).filter(|(a, b)| a != b).count();
                assert_eq!(
                    differ,
                    0,
                    "camera at {eye}, {slots} slots, {spp} spp, {how} memory: {differ} of {} \
                     pixels differ",
                    want.len()
                );
            }
            // The images must show the cloud, not only the background.
            assert!(want.iter().filter(|c| **c != background).count() > want.len() / 4);
            compared += 1;
        }
    }
    assert_eq!(compared, 9);
}

/// The camera grid draws its slots from one threshold each, not a number per hit: its estimate
/// must still converge to the exact composite in centre-depth order, computed here
/// independently (every Gaussian's `intersect`, in f64, no grid and no BVH). Statistic: per
/// pixel, z of the mean of `n` estimates against the exact mean, with the exact variance over
/// the slots (channel 0); chi-square under its 1e-5 quantile and every |z| < 5.5; and the image
/// mean's pooled z under 4.9 (two-sided false alarm 1e-6), whose standard error is required to
/// be under 0.025% of the mean, so that a bias of 0.1% fails it. For 1 and 8 slots, with the
/// camera outside the cloud and at its edge.
#[test]
fn the_camera_grid_is_unbiased_against_the_exact_composite() {
    use stochastic_rt::trace_camera_image;
    let cloud = random_cloud(300, 2);
    let scene = GaussianScene::new(&cloud);
    let g = &scene.gaussians;
    let bg = Vec3::new(0.2, 0.3, 0.4);
    for (eye, slots, n) in [
        (Vec3::new(0.2, 0.1, -4.0), 8u32, 4096u32),
        (Vec3::new(0.2, 0.1, -4.0), 1, 16384),
        (Vec3::new(0.0, 0.3, -2.0), 8, 4096),
    ] {
        let cam = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 45.0, 24, 18).unwrap();
        let image = trace_camera_image(g, &cam, slots, n, 7, bg);
        let (mut scores, mut diff_sum, mut var_sum, mut mean_sum) =
            (test_stats::ZScores::new(), 0.0f64, 0.0f64, 0.0f64);
        for p in 0..cam.width * cam.height {
            let r = TraceRay::through_pixel(&cam, p, DepthMode::Center);
            // Every hit on the pixel's line in front of the camera, in centre-depth order.
            let mut hits: Vec<(f32, f32, usize)> = (0..g.len())
                .filter_map(|i| {
                    let h = g.intersect(i, r.o, r.d, 0.0, f32::INFINITY, r.mode, r.forward)?;
                    Some((h.t, h.alpha, i))
                })
                .collect();
            hits.sort_by(|a, b| a.0.total_cmp(&b.0).then(g.ids[a.2].cmp(&g.ids[b.2])));
            let (mut t, mut m1, mut m2) = (1.0f64, 0.0f64, 0.0f64);
            for (_, alpha, i) in hits {
                let c = g.color(i, r.o).x as f64;
                m1 += t * alpha as f64 * c;
                m2 += t * alpha as f64 * c * c;
                t *= 1.0 - alpha as f64;
            }
            let b = bg.x as f64;
            let (m1, m2) = (m1 + t * b, m2 + t * b * b);
            // One estimate is the mean of `slots` independent slots.
            let var = (m2 - m1 * m1).max(0.0) / slots as f64 / n as f64;
            let diff = image[p as usize].x as f64 - m1;
            mean_sum += m1;
            if var > 1e-12 {
                scores.add(diff, var);
                diff_sum += diff;
                var_sum += var;
            }
        }
        let what = format!("camera grid, {slots} slots, camera at {eye}");
        scores.assert_unbiased(&what, 5.5, 200);
        let (pooled_z, relative_se) = (diff_sum / var_sum.sqrt(), var_sum.sqrt() / mean_sum);
        eprintln!("{what}: pooled z {pooled_z:.2}, image mean's standard error {relative_se:.2e}");
        assert!(
            relative_se < 2.5e-4,
            "{what}: too few samples to see a 0.1% bias"
        );
        assert!(pooled_z.abs() < 4.9, "{what}: pooled z {pooled_z}");
    }
}
