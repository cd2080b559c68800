//! The neural radiance cache inside the volume path tracer (cached-pt's `nrc` adapter), on the
//! bundled neghip scene at a small size: an untrained cache changes nothing, bit for bit;
//! training paths put in the image what stopped paths do; a warm cache lowers the error at
//! 1 spp.

use cached_pt::nrc::render_nrc_frame;
use glam::Vec3;
use gscache_cli::metrics::rel_mse;
use nrc_cache::{NeuralCache, NrcConfig};
use std::path::PathBuf;
use volume_pt::Control;
use volume_pt::{Film, NoCache, Scene, load_scene, render, render_frame_with};

const SIZE: u32 = 64;

fn scene() -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/scenes/default.toml");
    let mut s = load_scene(&path).unwrap();
    s.camera.width = SIZE;
    s.camera.height = SIZE;
    s.settings.spp = 1;
    s
}

fn small_config() -> NrcConfig {
    NrcConfig {
        grid_levels: 8,
        grid_log2_table: 14,
        grid_finest_resolution: 128,
        batch_size: 1024,
        training_fraction: 0.25,
        ..Default::default()
    }
}

/// Frame `f` with the neural cache; returns the frame's image.
fn nrc_frame(s: &Scene, cache: &mut NeuralCache, seed: u64, f: u32) -> Vec<Vec3> {
    let mut settings = s.settings;
    settings.seed = seed;
    let mut film = Film::new(SIZE, SIZE);
    let stats = render_nrc_frame(
        &s.media,
        &s.camera,
        &settings,
        f,
        Some(&mut film),
        cache,
        &Control::none(),
    );
    assert_eq!(stats.nonfinite_samples, 0);
    film.mean()
}

/// Frame `f` of plain NEE: the same sample indices a cached frame `f` draws.
fn plain_frame(s: &Scene, seed: u64, f: u32) -> Vec<Vec3> {
    let mut settings = s.settings;
    settings.seed = seed;
    let mut film = Film::new(SIZE, SIZE);
    render_frame_with(
        &s.media,
        &s.camera,
        &settings,
        f,
        &mut film,
        &NoCache,
        &Control::none(),
    );
    film.mean()
}

/// Before its first training step the cache is never read and no random number is drawn for
/// it: frame 0 is bit-identical to plain NEE's, whatever the fraction of training paths; the
/// frame's training paths then train it.
#[test]
fn an_untrained_cache_is_plain_nee() {
    let s = scene();
    for fraction in [1.0, 0.25] {
        let mut cache = NeuralCache::new(NrcConfig {
            training_fraction: fraction,
            ..small_config()
        })
        .unwrap();
        assert_eq!(
            nrc_frame(&s, &mut cache, 4, 0),
            plain_frame(&s, 4, 0),
            "training fraction {fraction}"
        );
        assert!(cache.steps() > 0, "the frame trained the cache");
    }
}

/// Training paths put in the image what a path that stopped would (their prefix and the
/// cache's value where they would have stopped), while they go on to train it: with a trained,
/// frozen cache, the images with every path a training path and with none have the same mean.
/// Per pixel, z = difference of the 128-frame means over its standard error; the chi-square of
/// all pixels' z against its 1e-5 quantile (test-stats). A training path that put its whole
/// path in the image as well as the cache's value (too bright), or dropped the radiance
/// gathered before its stop, fails it.
#[test]
fn training_paths_read_the_cache_as_stopped_paths_do() {
    let s = scene();
    let mut cache = NeuralCache::new(small_config()).unwrap();
    for f in 0..20 {
        nrc_frame(&s, &mut cache, 8, f);
    }
    let frames = 128u32;
    let steps_before = cache.steps();
    let mut moments = |fraction: f32, seed: u64| -> Vec<(f64, f64)> {
        cache.set_training(fraction, 0).unwrap();
        let mut m = vec![(0.0f64, 0.0f64); (SIZE * SIZE) as usize];
        for f in 0..frames {
            for (acc, v) in m.iter_mut().zip(nrc_frame(&s, &mut cache, seed, 100 + f)) {
                let x = v.element_sum() as f64;
                acc.0 += x;
                acc.1 += x * x;
            }
        }
        m
    };
    let all = moments(1.0, 21);
    let none = moments(0.0, 22);
    assert_eq!(cache.steps(), steps_before, "a frozen cache takes no step");
    let n = frames as f64;
    let mut z = test_stats::ZScores::new();
    let (mut mean_all, mut mean_none) = (0.0, 0.0);
    for (a, b) in all.iter().zip(&none) {
        let (ma, mb) = (a.0 / n, b.0 / n);
        let va = (a.1 / n - ma * ma).max(0.0) * n / (n - 1.0);
        let vb = (b.1 / n - mb * mb).max(0.0) * n / (n - 1.0);
        mean_all += ma;
        mean_none += mb;
        if va + vb > 0.0 {
            z.add(ma - mb, (va + vb) / n);
        }
    }
    eprintln!("mean brightness: every path training {mean_all:.3}, none {mean_none:.3}");
    z.assert_unbiased("training paths against stopped paths", 5.5, 1000);
}

/// After 60 frames a warm cache's 1-spp images have lower relMSE than NEE's against a 256-spp
/// reference (8 seeds each; measured ratio about 0.4, asserted below 0.8).
#[test]
fn warm_nrc_beats_nee_at_one_spp() {
    let s = scene();
    let mut settings = s.settings;
    settings.spp = 256;
    settings.seed = 1000;
    let mut film = Film::new(SIZE, SIZE);
    render(&s.media, &s.camera, &settings, &mut film, &Control::none());
    let reference = film.mean();
    let mut cache = NeuralCache::new(NrcConfig {
        training_fraction: 0.1,
        ..small_config()
    })
    .unwrap();
    for f in 0..60 {
        nrc_frame(&s, &mut cache, 500, f);
    }
    let (mut e_nrc, mut e_nee) = (0.0, 0.0);
    for k in 0..8 {
        e_nrc += rel_mse(&nrc_frame(&s, &mut cache, 900 + k, 60), &reference);
        e_nee += rel_mse(&plain_frame(&s, 900 + k, 60), &reference);
    }
    eprintln!(
        "relMSE at 1 spp: nrc {:.4}, nee {:.4}",
        e_nrc / 8.0,
        e_nee / 8.0
    );
    assert!(e_nrc < 0.8 * e_nee, "nrc {e_nrc} vs nee {e_nee}");
}
