//! Tracking against closed forms: Beer-Lambert through homogeneous and graded media, from very
//! thin (sigma L = 1e-4) to very dense (sigma L = 1e3), with both free-flight and ratio tracking.

mod common;

use common::*;
use glam::{UVec3, Vec3};
use volume_pt::integrator::{IntegratorKind, PathSettings};
use volume_pt::sampling::SampleStream;
use volume_pt::tracking::{free_flight, ratio_transmittance, transmittance};
use volume_pt::{Filter, Lights, Medium, Phase, ScalarGrid, TransferFunction};

const Z: f64 = 5.0; // two-sided false-alarm rate 5.7e-7 per check

fn lights_env(v: f32) -> Lights {
    Lights {
        lights: vec![],
        environment: Vec3::splat(v),
    }
}

/// Pixel = exp(-sigma L) for an absorbing box under a unit environment, both integrators.
#[test]
fn beer_lambert_pixel_through_absorbing_box() {
    for &tau in &[1e-4f32, 1.0, 30.0, 1e3] {
        let medium = homogeneous(tau, Vec3::ZERO, 1.0, 8);
        let scene = scene(medium, Phase::Isotropic, lights_env(1.0));
        let p = (-(tau as f64)).exp();
        for integrator in [IntegratorKind::Uniform, IntegratorKind::Nee] {
            let settings = PathSettings {
                integrator,
                max_depth: None,
                ..PathSettings::default()
            };
            let n = 1_000_000;
            let (mean, _) = path_stats(
                &scene,
                &settings,
                Vec3::new(0.1, -0.2, -5.0),
                Vec3::Z,
                n,
                11,
            );
            // The estimator is Bernoulli(p): its standard error is sqrt(p (1 - p) / n).
            let se = (p * (1.0 - p) / n as f64).sqrt();
            assert!(
                (mean[0] - p).abs() <= Z * se + 1e-12,
                "tau={tau} {integrator}: {} vs {p} (se {se})",
                mean[0]
            );
        }
    }
}

/// Ratio tracking is an unbiased transmittance estimate, including with its Russian roulette.
#[test]
fn ratio_tracking_matches_beer_lambert() {
    for &tau in &[1e-4f32, 0.5, 3.0, 30.0, 1e3] {
        let medium = homogeneous(tau, Vec3::ONE, 1.0, 8);
        let ray = medium.to_index_ray(Vec3::new(0.0, 0.0, -3.0), Vec3::Z);
        let n = 400_000u64;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for i in 0..n {
            let mut rng = SampleStream::new(5, 1, i);
            let t = transmittance(&medium, &ray, 0.0, f32::INFINITY, &mut rng) as f64;
            assert!((0.0..=1.0).contains(&t), "tau={tau}: transmittance {t}");
            s += t;
            s2 += t * t;
        }
        let mean = s / n as f64;
        let se = ((s2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt();
        let p = (-(tau as f64)).exp();
        // Where the estimator is almost always 0 or exactly p, its sample error can be 0: allow
        // the f32 resolution of p on top.
        assert!(
            (mean - p).abs() <= Z * se + 1e-6 * p + 1e-12,
            "tau={tau}: {mean} vs {p} (se {se})"
        );
    }
}

/// A graded medium: the scalar rises linearly along z and the opacity ramp is linear, so the
/// extinction is piecewise linear in z (flat beyond the first and last voxel centres). The
/// optical depth is integrated in f64 from the stated conventions, independently of the tracker.
#[test]
fn graded_medium_optical_depth_matches_convention() {
    let dims = UVec3::new(3, 3, 8);
    let mut values = Vec::new();
    for z in 0..8 {
        for _ in 0..9 {
            values.push(z as f32);
        }
    }
    let grid = ScalarGrid::new(dims, values).unwrap();
    let scale = 0.8f32;
    let tf = TransferFunction::from_points(
        (0.0, 7.0),
        &[(0.0, Vec3::ZERO, 0.0), (1.0, Vec3::ZERO, 1.0)],
        scale,
    )
    .unwrap();
    // Spacing 0.5 along z: the box spans z in [0, 4].
    let spacing = Vec3::new(1.0, 1.0, 0.5);
    for macrocell in [2, 1000] {
        let medium = Medium::new(
            grid.clone(),
            Filter::Trilinear,
            Vec3::ZERO,
            spacing,
            tf.clone(),
            macrocell,
        )
        .unwrap();
        // Analytic: value(z) = clamp(z / 0.5 - 0.5, 0, 7); sigma = scale * value / 7.
        let steps = 200_000;
        let tau: f64 = (0..steps)
            .map(|i| {
                let z = (i as f64 + 0.5) * 4.0 / steps as f64;
                let v = (z / 0.5 - 0.5).clamp(0.0, 7.0);
                scale as f64 * v / 7.0 * 4.0 / steps as f64
            })
            .sum();
        let p = (-tau).exp();
        let ray = medium.to_index_ray(Vec3::new(1.5, 1.5, -1.0), Vec3::Z);
        let n = 1_000_000u64;
        let mut escaped = 0u64;
        for i in 0..n {
            let mut rng = SampleStream::new(9, macrocell as u64, i);
            if free_flight(&medium, &ray, 0.0, f32::INFINITY, &mut rng).is_none() {
                escaped += 1;
            }
        }
        let mean = escaped as f64 / n as f64;
        let se = (p * (1.0 - p) / n as f64).sqrt();
        assert!(
            (mean - p).abs() <= Z * se,
            "macrocell {macrocell}: {mean} vs {p} (tau {tau})"
        );
    }
}

/// Rays that graze a face or run inside a face plane, and rays that start inside the box.
#[test]
fn grazing_and_inside_rays_are_finite_and_correct() {
    let medium = homogeneous(2.0, Vec3::ZERO, 1.0, 8);
    let n = 200_000u64;
    // Along the face plane x = 0.5 (inside the closed box), from outside.
    for (o, d, len) in [
        (Vec3::new(0.5, 0.0, -3.0), Vec3::Z, 1.0f64),
        (Vec3::new(0.0, 0.0, 0.0), Vec3::Z, 0.5),
        (
            Vec3::new(-0.5, -0.5, -0.5),
            Vec3::new(1.0, 1.0, 1.0).normalize(),
            3f64.sqrt(),
        ),
    ] {
        let ray = medium.to_index_ray(o, d);
        let mut escaped = 0u64;
        for i in 0..n {
            let mut rng = SampleStream::new(2, 0, i);
            if free_flight(&medium, &ray, 0.0, f32::INFINITY, &mut rng).is_none() {
                escaped += 1;
            }
        }
        let p = (-2.0 * len).exp();
        let mean = escaped as f64 / n as f64;
        let se = (p * (1.0 - p) / n as f64).sqrt();
        assert!((mean - p).abs() <= Z * se, "{o} {d}: {mean} vs {p}");
    }
    // Parallel to a face but outside the box: no medium at all.
    let ray = medium.to_index_ray(Vec3::new(0.5001, 0.0, -3.0), Vec3::Z);
    let mut rng = SampleStream::new(2, 0, 0);
    assert!(free_flight(&medium, &ray, 0.0, f32::INFINITY, &mut rng).is_none());
}

/// Ratio tracking with a loose (global) majorant on a graded medium: the null ratios vary along
/// the ray and the estimate often falls below the roulette threshold, so a biased roulette shows.
#[test]
fn ratio_tracking_with_loose_majorant_matches_beer_lambert() {
    let dims = UVec3::new(2, 2, 16);
    let values: Vec<f32> = (0..64).map(|i| (i / 4) as f32).collect();
    let grid = ScalarGrid::new(dims, values).unwrap();
    let tf = TransferFunction::from_points(
        (0.0, 15.0),
        &[(0.0, Vec3::ZERO, 0.0), (1.0, Vec3::ZERO, 1.0)],
        1.0,
    )
    .unwrap();
    for macrocell in [4, 1000] {
        let medium = Medium::new(
            grid.clone(),
            Filter::Nearest,
            Vec3::ZERO,
            Vec3::new(1.0, 1.0, 0.25),
            tf.clone(),
            macrocell,
        )
        .unwrap();
        // Nearest filter: sigma is piecewise constant, voxel k covers z in [k/4, (k+1)/4).
        let tau: f64 = (0..16).map(|k| k as f64 / 15.0 * 0.25).sum();
        let p = (-tau).exp();
        let ray = medium.to_index_ray(Vec3::new(1.0, 1.0, -1.0), Vec3::Z);
        let n = 1_000_000u64;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for i in 0..n {
            let mut rng = SampleStream::new(10, macrocell as u64, i);
            let t = transmittance(&medium, &ray, 0.0, f32::INFINITY, &mut rng) as f64;
            s += t;
            s2 += t * t;
        }
        let mean = s / n as f64;
        let se = ((s2 / n as f64 - mean * mean) / n as f64).sqrt();
        assert!(
            (mean - p).abs() <= Z * se,
            "macrocell {macrocell}: {mean} vs {p} (se {se})"
        );
    }
}

/// The majorant bounds the extinction everywhere, for random grids and random transfer
/// functions (steps included), with trilinear and nearest reconstruction, before and after a
/// transfer-function change rebuilt from the stored value ranges.
#[test]
fn majorants_bound_extinction_everywhere() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(42);
    for case in 0..20 {
        let dims = UVec3::new(
            rng.random_range(1..20),
            rng.random_range(1..20),
            rng.random_range(1..20),
        );
        let n = (dims.x * dims.y * dims.z) as usize;
        // Sparse spikes make the halo matter.
        let values: Vec<f32> = (0..n)
            .map(|_| {
                if rng.random::<f32>() < 0.1 {
                    rng.random_range(0.0..100.0)
                } else {
                    0.0
                }
            })
            .collect();
        let grid = ScalarGrid::new(dims, values).unwrap();
        let random_tf = |rng: &mut rand::rngs::StdRng| {
            let mut xs: Vec<f32> = (0..rng.random_range(1..6))
                .map(|_| rng.random::<f32>())
                .collect();
            xs.sort_by(f32::total_cmp);
            if xs.len() > 2 {
                xs[1] = xs[0]; // a step
            }
            let pts: Vec<(f32, Vec3, f32)> = xs
                .iter()
                .map(|&x| (x, Vec3::ONE, rng.random::<f32>()))
                .collect();
            TransferFunction::from_points(
                (rng.random_range(-10.0..20.0), rng.random_range(30.0..120.0)),
                &pts,
                rng.random_range(0.1..10.0),
            )
            .unwrap()
        };
        let filter = if case % 2 == 0 {
            Filter::Trilinear
        } else {
            Filter::Nearest
        };
        let cell = rng.random_range(1..6);
        let mut medium = Medium::new(
            grid,
            filter,
            Vec3::ZERO,
            Vec3::ONE,
            random_tf(&mut rng),
            cell,
        )
        .unwrap();
        for pass in 0..2 {
            if pass == 1 {
                medium.set_transfer_function(random_tf(&mut rng));
            }
            let maj = medium.majorants();
            for _ in 0..20_000 {
                let u = Vec3::new(
                    rng.random::<f32>() * dims.x as f32,
                    rng.random::<f32>() * dims.y as f32,
                    rng.random::<f32>() * dims.z as f32,
                );
                let sigma = medium.extinction(u);
                // The majorant of u's cell, found by walking a tiny segment through u.
                let seg = maj.segments(u, Vec3::X, 0.0, 1e-6).next().unwrap();
                assert!(
                    sigma <= seg.majorant,
                    "case {case} pass {pass}: sigma {sigma} > majorant {} at {u}",
                    seg.majorant
                );
                // And residual ratio tracking's control bounds it from below.
                assert!(
                    seg.control <= sigma && seg.control >= 0.0,
                    "case {case} pass {pass}: control {} > sigma {sigma} at {u}",
                    seg.control
                );
            }
        }
    }
}

/// Residual ratio tracking agrees with plain ratio tracking on random heterogeneous media
/// (sparse spikes through random transfer functions with steps; trilinear and nearest; several
/// macrocell sizes), ray by ray. Statistic: per ray the z of the difference of the two means of
/// 20000 independent estimates each; chi-square over all rays under its 1e-5 quantile, and every
/// |z| < 5.5. Also reports the two estimators' variance.
#[test]
fn residual_ratio_tracking_is_unbiased_against_ratio_tracking() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let mut scores = test_stats::ZScores::new();
    let (mut var_ratio, mut var_residual) = (0.0f64, 0.0f64);
    for case in 0..12u64 {
        let dims = UVec3::new(
            rng.random_range(4..16),
            rng.random_range(4..16),
            rng.random_range(4..16),
        );
        let n = (dims.x * dims.y * dims.z) as usize;
        let values: Vec<f32> = (0..n)
            .map(|_| 20.0 + rng.random_range(0.0..60.0) * (rng.random::<f32>() < 0.3) as u8 as f32)
            .collect();
        let grid = ScalarGrid::new(dims, values).unwrap();
        let tf = TransferFunction::from_points(
            (0.0, 100.0),
            &[
                (0.0, Vec3::ONE, 0.1),
                (0.5, Vec3::ONE, rng.random_range(0.1..1.0)),
                (0.5, Vec3::ONE, rng.random_range(0.1..1.0)),
                (1.0, Vec3::ONE, 1.0),
            ],
            rng.random_range(0.05..0.6),
        )
        .unwrap();
        let filter = if case % 2 == 0 {
            Filter::Trilinear
        } else {
            Filter::Nearest
        };
        let medium =
            Medium::new(grid, filter, Vec3::ZERO, Vec3::ONE, tf, 1 + case as u32 % 4).unwrap();
        for r in 0..8u64 {
            let o = Vec3::new(
                rng.random::<f32>() * dims.x as f32,
                rng.random::<f32>() * dims.y as f32,
                -1.0,
            );
            let d = Vec3::new(
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                1.0,
            )
            .normalize();
            let ray = medium.to_index_ray(o, d);
            let m = 20_000u64;
            let stats = |f: &dyn Fn(&mut SampleStream) -> f32, stream: u64| {
                let (mut s, mut s2) = (0.0f64, 0.0f64);
                for i in 0..m {
                    let mut g = SampleStream::new(stream, case * 100 + r, i);
                    let t = f(&mut g) as f64;
                    s += t;
                    s2 += t * t;
                }
                let mean = s / m as f64;
                (mean, (s2 / m as f64 - mean * mean).max(0.0))
            };
            let (m1, v1) = stats(&|g| transmittance(&medium, &ray, 0.0, f32::INFINITY, g), 1);
            let (m2, v2) = stats(
                &|g| ratio_transmittance(&medium, &ray, 0.0, f32::INFINITY, g),
                2,
            );
            var_residual += v1;
            var_ratio += v2;
            let var = (v1 + v2) / m as f64;
            if var > 1e-14 {
                scores.add(m1 - m2, var);
            }
        }
    }
    eprintln!("summed variance: residual {var_residual:.4e}, ratio {var_ratio:.4e}");
    scores.assert_unbiased("residual vs ratio tracking", 5.5, 80);
}

/// Clipping (`volume_pt::clip`) against the closed form: an absorbing unit cube (optical depth
/// `tau` across) seen along +z under a unit environment, cut by planes and a box, renders
/// `exp(-tau L)` with `L` the length of the ray inside the kept region, with both integrators;
/// and the transmittance of a shadow ray through it (residual ratio tracking, exact in a
/// homogeneous cell) is the same closed form to 0.05% (measured 0.015% off, the unclipped
/// cube's f32 arithmetic; a kept length off by 0.01, a hundredth of the cube, changes it by 2%).
#[test]
fn clipping_cuts_the_medium_exactly() {
    use volume_pt::{ClipBox, ClipPlane, Clipping};
    let tau = 2.0f32;
    let plane = |point: [f32; 3], normal: [f32; 3]| ClipPlane { point, normal };
    let slab = |lo: f32, hi: f32| ClipBox {
        min: [-1.0, -1.0, lo],
        max: [1.0, 1.0, hi],
    };
    // The ray runs along +z through (0.1, -0.2): the cube spans z in [-0.5, 0.5].
    let cases = [
        (
            "plane cutting z > 0.25",
            None,
            vec![plane([0.0, 0.0, 0.25], [0.0, 0.0, 1.0])],
            0.75,
        ),
        (
            "plane cutting z < 0.25",
            None,
            vec![plane([0.0, 0.0, 0.25], [0.0, 0.0, -2.0])],
            0.25,
        ),
        ("box z in [-0.2, 0.3]", Some(slab(-0.2, 0.3)), vec![], 0.5),
        // x + z > 0 cut: at x = 0.1 the kept part ends at z = -0.1.
        (
            "box z >= -0.3 and a tilted plane",
            Some(slab(-0.3, 1.0)),
            vec![plane([0.0; 3], [1.0, 0.0, 1.0])],
            0.2,
        ),
        ("everything cut", Some(slab(0.6, 0.7)), vec![], 0.0),
    ];
    let (origin, dir) = (Vec3::new(0.1, -0.2, -5.0), Vec3::Z);
    for (name, bounds, planes, length) in cases {
        let mut medium = homogeneous(tau, Vec3::ZERO, 1.0, 8);
        medium.set_clipping(Clipping { bounds, planes }).unwrap();
        let p = (-(tau as f64) * length).exp();
        let ray = medium.to_index_ray(origin, dir);
        let mut rng = SampleStream::new(3, 0, 0);
        let t = transmittance(&medium, &ray, 0.0, f32::INFINITY, &mut rng) as f64;
        assert!(
            (t - p).abs() <= 5e-4 * p + 1e-12,
            "{name}: transmittance {t} against {p}"
        );
        let scene = scene(medium, Phase::Isotropic, lights_env(1.0));
        for integrator in [IntegratorKind::Uniform, IntegratorKind::Nee] {
            let settings = PathSettings {
                integrator,
                max_depth: None,
                ..PathSettings::default()
            };
            let n = 200_000;
            let (mean, _) = path_stats(&scene, &settings, origin, dir, n, 17);
            // Bernoulli(p): standard error sqrt(p (1 - p) / n).
            let se = (p * (1.0 - p) / n as f64).sqrt();
            assert!(
                (mean[0] - p).abs() <= Z * se + 1e-12,
                "{name}, {integrator}: {} against {p} (se {se})",
                mean[0]
            );
        }
    }
}

/// Channels (OME-Zarr's `c` axis, rendered together): extinctions add and the colour is the
/// extinction-weighted mix, as the closed forms say; every channel's majorant and control bound
/// the summed extinction in every macrocell a ray crosses.
#[test]
fn channels_add_their_extinctions_and_mix_their_colours() {
    let constant = |v: f32| ScalarGrid::new(UVec3::splat(4), vec![v; 64]).unwrap();
    let flat = |colour: Vec3, sigma: f32| {
        TransferFunction::from_points((0.0, 1.0), &[(0.0, colour, 1.0)], sigma).unwrap()
    };
    // Absorbing (black) channels of extinction 1.2 and 0.8 in a unit cube: exp(-2) through it.
    let mut medium = homogeneous(1.2, Vec3::ZERO, 1.0, 8);
    medium
        .add_channel(1, constant(1.0), flat(Vec3::ZERO, 0.8))
        .unwrap();
    let (origin, dir) = (Vec3::new(0.1, -0.2, -5.0), Vec3::Z);
    let p = (-2.0f64).exp();
    let ray = medium.to_index_ray(origin, dir);
    let t = transmittance(
        &medium,
        &ray,
        0.0,
        f32::INFINITY,
        &mut SampleStream::new(1, 0, 0),
    );
    assert!(
        (t as f64 - p).abs() <= 5e-4 * p,
        "transmittance {t} against {p}"
    );
    let scene = scene(medium.clone(), Phase::Isotropic, lights_env(1.0));
    for integrator in [IntegratorKind::Uniform, IntegratorKind::Nee] {
        let settings = PathSettings {
            integrator,
            max_depth: None,
            ..PathSettings::default()
        };
        let n = 200_000;
        let (mean, _) = path_stats(&scene, &settings, origin, dir, n, 29);
        // Bernoulli(p): standard error sqrt(p (1 - p) / n); one channel alone would give
        // exp(-1.2) = 0.30 against 0.135, hundreds of standard errors away.
        let se = (p * (1.0 - p) / n as f64).sqrt();
        assert!(
            (mean[0] - p).abs() <= Z * se,
            "{integrator}: {} against {p} (se {se})",
            mean[0]
        );
    }

    // Colours: red at 1.2 and blue at 0.8 mix to (0.6, 0, 0.4).
    let mut medium = homogeneous(1.2, Vec3::X, 1.0, 8);
    medium
        .add_channel(4, constant(1.0), flat(Vec3::Z, 0.8))
        .unwrap();
    let u = Vec3::splat(2.0);
    assert!((medium.extinction(u) - 2.0).abs() < 1e-6);
    let a = medium.albedo(u);
    assert!(
        (a - Vec3::new(0.6, 0.0, 0.4)).abs().max_element() < 1e-6,
        "{a}"
    );
    assert_eq!(medium.channels()[0].index, 4);
    // A channel of other dims is refused by name.
    let e = medium
        .add_channel(
            5,
            ScalarGrid::new(UVec3::splat(2), vec![0.0; 8]).unwrap(),
            flat(Vec3::ONE, 1.0),
        )
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("channel 5") && e.contains("expected the first channel's"),
        "{e}"
    );

    // Heterogeneous channels: the summed extinction lies between every crossed cell's control
    // and majorant.
    let hash = |i: u32, k: u32| render_base::hash::unit_f32(render_base::hash::hash32(&[k, i]));
    let noisy = |k: u32| {
        ScalarGrid::new(UVec3::splat(12), (0..1728).map(|i| hash(i, k)).collect()).unwrap()
    };
    let ramp = |colour: Vec3, sigma: f32, lo: f32| {
        TransferFunction::from_points((lo, 1.0), &[(0.0, colour, 0.0), (1.0, colour, 1.0)], sigma)
            .unwrap()
    };
    let mut medium = Medium::new(
        noisy(1),
        Filter::Trilinear,
        Vec3::splat(-0.5),
        Vec3::splat(1.0 / 12.0),
        ramp(Vec3::X, 3.0, 0.2),
        4,
    )
    .unwrap();
    medium
        .add_channel(1, noisy(2), ramp(Vec3::Y, 2.0, 0.5))
        .unwrap();
    medium
        .add_channel(2, noisy(3), ramp(Vec3::Z, 5.0, 0.7))
        .unwrap();
    let mut checked = 0;
    for k in 0..2000u32 {
        let o = Vec3::new(hash(k, 10) - 0.5, hash(k, 11) - 0.5, -2.0);
        let d = (Vec3::new(hash(k, 12) - 0.5, hash(k, 13) - 0.5, 0.0) - o).normalize();
        let ray = medium.to_index_ray(o, d);
        let Some((t0, t1)) = medium.clip(&ray, 0.0, f32::INFINITY) else {
            continue;
        };
        for seg in medium.segments(&ray, t0, t1) {
            for j in 0..8 {
                let t = seg.t0 + (seg.t1 - seg.t0) * (j as f32 + 0.5) / 8.0;
                let sigma = medium.extinction(ray.at(t));
                assert!(
                    sigma <= seg.majorant && sigma >= seg.control,
                    "extinction {sigma} outside [{}, {}]",
                    seg.control,
                    seg.majorant
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 10_000, "{checked} points checked");
}
