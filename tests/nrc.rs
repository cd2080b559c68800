//! The neural radiance cache inside the volume path tracer (cached-pt's `nrc` adapter), on the
//! bundled neghip scene at a small size: training paths are plain NEE paths, bit for bit, even
//! once the cache is trained and read by the other pixels; a warm cache lowers the error at
//! 1 spp.

use cached_pt::nrc::{NrcFrame, render_nrc_frame};
use glam::Vec3;
use gscache_cli::metrics::rel_mse;
use nrc_cache::{NeuralCache, NrcConfig};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
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
        &AtomicBool::new(false),
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
        &AtomicBool::new(false),
    );
    film.mean()
}

/// With every path a training path, the cache is never read and no random number is drawn
/// for it: the image is bit-identical to plain NEE's, and the frame yields training records.
#[test]
fn all_training_paths_is_plain_nee() {
    let s = scene();
    let mut cache = NeuralCache::new(NrcConfig {
        training_fraction: 1.0,
        ..small_config()
    })
    .unwrap();
    for f in 0..3 {
        assert_eq!(
            nrc_frame(&s, &mut cache, 4, f),
            plain_frame(&s, 4, f),
            "frame {f}"
        );
    }
    assert!(cache.steps() > 0, "the frames trained the cache");
}

/// Once the cache is trained and read, the pixels whose paths train it this frame are still
/// plain NEE samples, bit for bit (so the image is unbiased where the cache is not used), and
/// the other pixels read the cache (over a quarter of them differ from NEE's; about 28% do,
/// the rest see only the background or paths that never stopped).
#[test]
fn a_trained_cache_leaves_training_pixels_unbiased() {
    let s = scene();
    let mut cache = NeuralCache::new(small_config()).unwrap();
    for f in 0..20 {
        nrc_frame(&s, &mut cache, 8, f);
    }
    let f = 20;
    let img = nrc_frame(&s, &mut cache, 8, f);
    let reference = plain_frame(&s, 8, f);
    let frame = NrcFrame::new(cache.config(), s.media.medium.bounds(), true, 8, f);
    let (mut training, mut read, mut differ) = (0, 0, 0);
    for (k, (a, b)) in img.iter().zip(&reference).enumerate() {
        if frame.is_training(k as u64) {
            training += 1;
            assert_eq!(a, b, "training pixel {k}");
        } else {
            read += 1;
            differ += (a != b) as usize;
        }
    }
    let n = (SIZE * SIZE) as f64;
    assert!(
        (training as f64 / n - 0.25).abs() < 0.03,
        "{training} of {n} pixels trained (expected 25%)"
    );
    assert!(
        differ as f64 > 0.2 * read as f64,
        "only {differ} of {read} pixels read the cache"
    );
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
    render(
        &s.media,
        &s.camera,
        &settings,
        &mut film,
        &AtomicBool::new(false),
        &|_| {},
    );
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
