//! The acceptance numbers themselves: uniform (so a hit of opacity alpha is accepted with
//! probability alpha, down to the faintest alpha of 1/255) and independent (between the samples
//! of a pixel, and between hits along one ray). Both generators are held to the same tests.
//!
//! Statistics: a histogram's chi-square against its expected counts, held under the 1e-5 upper
//! quantile; an acceptance rate's binomial z, held under 5 (false alarm 6e-7 each).

use glam::Vec3;
use splat_raster::random::{hash32, unit_f32};
use stochastic_rt::RandomKind;
use stochastic_rt::random::{SampleKey, acceptance};
use test_stats::{Z_FALSE_ALARM_1E5, chi2_upper};

/// A point in [-2, 2)^3 from a counter (where the hits of a small scene lie).
fn point(i: u32) -> Vec3 {
    let u = |k: u32| unit_f32(hash32(&[0xfeed, i, k]));
    Vec3::new(u(0), u(1), u(2)) * 4.0 - 2.0
}

const KINDS: [RandomKind; 2] = [RandomKind::Hash, RandomKind::Trig];

/// The number for hit `i` (Gaussian `i`, at `point(i)`) of sample `sample` in pixel `pixel`.
fn number(kind: RandomKind, pixel: u32, sample: u32, i: u32, p: Vec3) -> f32 {
    acceptance(kind, &SampleKey::new(7, pixel, sample), i, 0, p)
}

fn assert_histogram(what: &str, counts: &[u64], expected_each: f64) {
    let chi2: f64 = counts
        .iter()
        .map(|&c| (c as f64 - expected_each).powi(2) / expected_each)
        .sum();
    let limit = chi2_upper((counts.len() - 1) as f64, Z_FALSE_ALARM_1E5);
    eprintln!(
        "{what}: chi2 {chi2:.1} over {} bins (limit {limit:.1})",
        counts.len()
    );
    assert!(chi2 < limit, "{what}: chi2 {chi2} (limit {limit})");
}

#[test]
fn acceptance_numbers_are_uniform_down_to_the_faintest_alpha() {
    let n = 1u32 << 21;
    for kind in KINDS {
        let mut bins = vec![0u64; 1024];
        // Acceptance at the alphas that matter: 1/255 is the faintest hit traced.
        let alphas = [1.0 / 255.0, 0.01, 0.1, 0.5];
        let mut below = [0u64; 4];
        for i in 0..n {
            let x = number(kind, i % 4096, i / 4096, i, point(i));
            assert!((0.0..1.0).contains(&x), "{kind:?}: {x}");
            bins[(x * 1024.0) as usize] += 1;
            for (b, &a) in below.iter_mut().zip(&alphas) {
                *b += (x < a) as u64;
            }
        }
        assert_histogram(&format!("{kind:?} 1024 bins"), &bins, n as f64 / 1024.0);
        for (&b, &a) in below.iter().zip(&alphas) {
            let expected = n as f64 * a as f64;
            let z = (b as f64 - expected) / (expected * (1.0 - a as f64)).sqrt();
            eprintln!(
                "{kind:?}: P(x < {a:.4}) = {:.6} (z {z:.2})",
                b as f64 / n as f64
            );
            assert!(z.abs() < 5.0, "{kind:?}: acceptance at alpha {a}: z = {z}");
        }
    }
}

/// 2D histogram (16 x 16) of pairs: independent numbers fill it evenly.
fn assert_pairs_independent(what: &str, pairs: impl Iterator<Item = (f32, f32)>) {
    let mut bins = vec![0u64; 256];
    let mut n = 0u64;
    for (a, b) in pairs {
        bins[(a * 16.0) as usize * 16 + (b * 16.0) as usize] += 1;
        n += 1;
    }
    assert_histogram(what, &bins, n as f64 / 256.0);
}

#[test]
fn acceptance_numbers_are_independent_between_samples_and_along_a_ray() {
    let n = 1u32 << 19;
    for kind in KINDS {
        // The same hit in two samples of one pixel: a pixel's mean converges only if these are
        // independent.
        assert_pairs_independent(
            &format!("{kind:?}, one hit, samples s and s + 1"),
            (0..n).map(|i| {
                let p = point(i);
                (
                    number(kind, i % 64, 2 * i, i, p),
                    number(kind, i % 64, 2 * i + 1, i, p),
                )
            }),
        );
        // Two hits close together along one ray, in one sample: which is accepted first must
        // not depend on the other.
        assert_pairs_independent(
            &format!("{kind:?}, hits 0.01 apart on a ray"),
            (0..n).map(|i| {
                let p = point(i);
                let d = (point(i ^ 0x5555_5555) - p).normalize_or(Vec3::X);
                (
                    number(kind, i, 0, 2 * i, p),
                    number(kind, i, 0, 2 * i + 1, p + 0.01 * d),
                )
            }),
        );
    }
}

/// The trigonometric hash's remaining bias, measured (issue 32): even in f64, `fract(43758.5
/// sin(.))` is not uniform (the sine's values crowd near +-1), and a hit of opacity 0.1-0.3 is
/// accepted about 0.13% too rarely. That is what darkens its images (-0.026% on the fruit
/// asset) and why `hash` is the default and the help says so. 2^27 draws an opacity: standard
/// error 2.6e-5 at 0.1 and 4.0e-5 at 0.3. The integer hash, drawn the same way, is held to
/// |z| < 5 (false alarm 6e-7 each); the trigonometric hash must show its bias (z below -3;
/// measured -0.139% at 0.1, z -5.4, and -0.130% at 0.3, z -9.9, with these fixed draws) and no
/// more than 0.5% of it. Should the hash ever be made unbiased, this test fails and the help
/// and README must change with it.
#[test]
fn the_trigonometric_hash_accepts_faint_hits_slightly_too_rarely() {
    use rayon::prelude::*;
    let alphas = [0.1f32, 0.3];
    let chunks = 128u32;
    let per_chunk = 1u32 << 20;
    let n = chunks as f64 * per_chunk as f64;
    for kind in KINDS {
        let counts: Vec<[u64; 2]> = (0..chunks)
            .into_par_iter()
            .map(|c| {
                let mut counts = [0u64; 2];
                for i in 0..per_chunk {
                    let u = acceptance(
                        kind,
                        &SampleKey::new(11, c, i),
                        i,
                        0,
                        point(c ^ i.rotate_left(7)),
                    );
                    for (k, a) in alphas.iter().enumerate() {
                        counts[k] += (u < *a) as u64;
                    }
                }
                counts
            })
            .collect();
        for (k, &a) in alphas.iter().enumerate() {
            let hits: u64 = counts.iter().map(|c| c[k]).sum();
            let a = a as f64;
            let f = hits as f64 / n;
            let z = (f - a) / (a * (1.0 - a) / n).sqrt();
            eprintln!(
                "{kind:?} at opacity {a}: accepted {f:.6} ({:+.3}%, z {z:+.1})",
                (f / a - 1.0) * 100.0
            );
            match kind {
                RandomKind::Hash => assert!(z.abs() < 5.0, "hash at {a}: z {z}"),
                RandomKind::Trig => assert!(
                    z < -3.0 && (f / a - 1.0).abs() < 5e-3,
                    "trig at {a}: {f} (z {z}): the documented bias is gone or grown"
                ),
            }
        }
    }
}
