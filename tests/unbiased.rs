//! The unbiased Gaussian cache (gs-cache's crate docs, "The unbiased estimator"): with the cache
//! as a control variate, a frozen cache's mean image is plain NEE's, whatever the cache holds.
//!
//! The statistic: for every pixel, the mean over frames of the paired difference between the
//! cached frame and the plain NEE frame with the same seed and sample indices (the cache's
//! decisions come from a hash of the path's key, not from its random stream, so a path that goes
//! on draws the very numbers the plain path draws, and the pair is strongly correlated). Its
//! z-score uses the frames' sample variance; the squared z-scores summed over the pixels are
//! held under chi-square's 1e-5 upper quantile, and every `|z|` under 6 (a two-sided
//! false-alarm rate of 2e-9 per pixel, about 1e-5 over an image of a few thousand pixels).
//! Beside it, the image-wide brightness: the summed difference over the summed NEE image, with
//! its standard error over frames; the test also asserts that a 0.1% bias would be seen (its
//! detection bound, 4.4 standard errors plus 1.6 for 95% power, is under 0.1%). Dropping the
//! `1 / q` (the path that goes on keeps its weight and the cache's term) must fail it.

use cached_pt::{GsFrame, GsPath, render_cached_frame};
use glam::Vec3;
use gs_cache::{CacheConfig, GsCache, Lookup, TileTargets};
use std::path::{Path, PathBuf};
use test_stats::ZScores;
use volume_pt::{
    Control, ControlVariate, Film, FrameCache, NoCache, PathHooks, Scene, TilePixel, TileRect,
    load_scene, render_frame_with, sample_cache_points,
};

/// Standard-normal quantile for a two-sided false-alarm rate of 1e-5.
const Z_TWO_SIDED_1E5: f64 = 4.42;
/// Standard-normal quantile for 95% power.
const Z_POWER_95: f64 = 1.645;

fn luminance(c: Vec3) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

fn scene_at(path: &Path, width: u32, height: u32) -> Scene {
    let mut s = load_scene(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    s.camera.width = width;
    s.camera.height = height;
    s
}

fn bundled(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("data/scenes/{name}.toml"))
}

/// A cache trained for `warmup` frames of 1 spp on `scene`'s view, then frozen.
fn trained_frozen_cache(scene: &Scene, config: CacheConfig, warmup: u32) -> GsCache {
    let config = config.for_image(scene.camera.width, scene.camera.height);
    let (p, a) = sample_cache_points(&scene.media.medium, config.points, 7);
    let mut cache = GsCache::new(&p, &a, config).unwrap();
    let mut settings = scene.settings;
    settings.spp = 1;
    settings.seed = 1_000;
    for f in 0..warmup {
        render_cached_frame(
            &scene.media,
            &scene.camera,
            &settings,
            f,
            None,
            &mut cache,
            &Control::none(),
        )
        .unwrap();
    }
    cache.frozen().unwrap()
}

/// The GsFrame's paths with the `1 / q` dropped: a path that goes on keeps its weight, and the
/// cache's `C - C / q` becomes `C - C = 0`. The estimator that is left is Algorithm 1's
/// selection (stop with `C`, or go on unweighted), which is biased.
struct WithoutInverseQ<'a>(GsFrame<'a>);
struct PathWithoutInverseQ<'a>(GsPath<'a>);

impl PathHooks for PathWithoutInverseQ<'_> {
    fn vertex(&mut self, v: &volume_pt::Vertex) {
        self.0.vertex(v)
    }
    fn scale(&mut self, f: Vec3) {
        self.0.scale(f)
    }
    fn radiance(&mut self, x: Vec3) {
        self.0.radiance(x)
    }
    fn control_variate(&mut self, work: u64) -> Option<ControlVariate> {
        match self.0.control_variate(work)? {
            ControlVariate::GoOn { cached, .. } => Some(ControlVariate::GoOn { cached, q: 1.0 }),
            stop => Some(stop),
        }
    }
}

impl FrameCache for WithoutInverseQ<'_> {
    type Path<'b>
        = PathWithoutInverseQ<'b>
    where
        Self: 'b;
    type TileRecord = TileTargets;
    fn tile_record(&self, t: TileRect) -> TileTargets {
        self.0.tile_record(t)
    }
    fn path(&self, pixel: TilePixel) -> PathWithoutInverseQ<'_> {
        PathWithoutInverseQ(self.0.path(pixel))
    }
    fn path_ended(&self, path: PathWithoutInverseQ<'_>, pixel: TilePixel, r: &mut TileTargets) {
        self.0.path_ended(path.0, pixel, r)
    }
}

/// What the comparison found.
struct Comparison {
    scores: ZScores,
    /// Image-wide relative brightness difference and its standard error.
    relative_bias: f64,
    standard_error: f64,
    frames: usize,
    /// Fraction of pixel frames that differ from NEE's (so the test is seen to exercise the
    /// cache).
    differing_fraction: f64,
}

/// Up to `frames` frames of `spp` paths per pixel, cached (frozen `cache`, or with the `1 / q`
/// dropped) against plain NEE with the same seeds. With `enough`, it stops (at a multiple of
/// 256 frames) once the image-wide standard error is small enough to see a 0.1% bias: the rule
/// looks at the spread only, never at the difference itself, so it leaves the false-alarm rate
/// as stated.
fn compare(
    scene: &Scene,
    cache: &mut GsCache,
    frames: u32,
    spp: u32,
    drop_q: bool,
    enough: bool,
) -> Comparison {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let n = (w * h) as usize;
    let mut settings = scene.settings;
    settings.spp = spp;
    settings.seed = 42;
    let (mut sum, mut sum2) = (vec![0.0f64; n], vec![0.0f64; n]);
    let (mut frame_diffs, mut nee_total) = (Vec::new(), 0.0f64);
    let mut differing = 0u64;
    for f in 0..frames {
        let mut nee = Film::new(w, h);
        render_frame_with(
            &scene.media,
            &scene.camera,
            &settings,
            f,
            &mut nee,
            &NoCache,
            &Control::none(),
        );
        cache.begin_frame(&scene.camera);
        let frame = cache.frame().unwrap();
        let gs = GsFrame {
            frame,
            termination: cache.config().termination(),
        };
        let mut film = Film::new(w, h);
        let records = if drop_q {
            let wrapped = WithoutInverseQ(gs);
            render_frame_with(
                &scene.media,
                &scene.camera,
                &settings,
                f,
                &mut film,
                &wrapped,
                &Control::none(),
            )
            .records
        } else {
            render_frame_with(
                &scene.media,
                &scene.camera,
                &settings,
                f,
                &mut film,
                &gs,
                &Control::none(),
            )
            .records
        };
        // A frozen cache does not train, but its statistics still set `q` (from past frames
        // only, so the estimator stays unbiased).
        let mut targets = frame.training_targets();
        for (_, r) in &records {
            targets.add_tile(r);
        }
        cache.train(&targets).unwrap();
        let (a, b) = (film.mean(), nee.mean());
        let mut d_total = 0.0;
        for i in 0..n {
            let d = luminance(a[i]) - luminance(b[i]);
            sum[i] += d;
            sum2[i] += d * d;
            d_total += d;
            nee_total += luminance(b[i]);
            if d != 0.0 {
                differing += 1;
            }
        }
        frame_diffs.push(d_total);
        if enough && (f + 1) % 256 == 0 {
            let m = frame_diffs.len() as f64;
            let mean = frame_diffs.iter().sum::<f64>() / m;
            let var = frame_diffs.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (m - 1.0);
            let se = (var / m).sqrt() / (nee_total / m);
            if (Z_TWO_SIDED_1E5 + Z_POWER_95) * se < 0.8e-3 {
                break;
            }
        }
    }
    let m = frame_diffs.len() as f64;
    let mut scores = ZScores::new();
    for i in 0..n {
        let mean = sum[i] / m;
        let var = (sum2[i] / m - mean * mean).max(0.0) * m / (m - 1.0);
        if var > 0.0 {
            scores.add(mean, var / m);
        }
    }
    let mean_diff = frame_diffs.iter().sum::<f64>() / m;
    let var_diff = frame_diffs
        .iter()
        .map(|d| (d - mean_diff).powi(2))
        .sum::<f64>()
        / (m - 1.0);
    let mean_nee = nee_total / m;
    Comparison {
        frames: frame_diffs.len(),
        scores,
        relative_bias: mean_diff / mean_nee,
        standard_error: (var_diff / m).sqrt() / mean_nee,
        differing_fraction: differing as f64 / (n as f64 * m),
    }
}

/// The unbiased estimator with `q = 0.5 luminance(W)` (floored at 0.05): on the bundled
/// volumes the rule lets every path go on (no `q` gains there: BENCHMARKS.md), which would test
/// nothing; a fixed `kappa` makes most paths stop into the cache.
fn unbiased_config(lookup: Lookup) -> CacheConfig {
    CacheConfig {
        unbiased: true,
        continuation_scale: 0.5,
        lookup,
        ..Default::default()
    }
}

/// Asserts `scene`'s frozen unbiased cache matches NEE, and that the test could see a bias of
/// `detect` (relative brightness).
fn assert_matches_nee(
    name: &str,
    scene: &Scene,
    lookup: Lookup,
    (frames, spp): (u32, u32),
    detect: f64,
) {
    let mut cache = trained_frozen_cache(scene, unbiased_config(lookup), 24);
    let c = compare(scene, &mut cache, frames, spp, false, true);
    eprintln!(
        "{name}: {} frames, brightness {:+.4}% (se {:.4}%), {:.0}% of pixels differ from NEE's",
        c.frames,
        100.0 * c.relative_bias,
        100.0 * c.standard_error,
        100.0 * c.differing_fraction
    );
    c.scores.assert_unbiased(name, 6.0, 200);
    assert!(
        c.relative_bias.abs() < Z_TWO_SIDED_1E5 * c.standard_error,
        "{name}: brightness {:+.4}% against NEE, {:.1} standard errors",
        100.0 * c.relative_bias,
        c.relative_bias.abs() / c.standard_error
    );
    let detectable = (Z_TWO_SIDED_1E5 + Z_POWER_95) * c.standard_error;
    assert!(
        detectable < detect,
        "{name}: the test would see only a bias above {:.3}% (wanted {:.3}%): more frames needed",
        100.0 * detectable,
        100.0 * detect
    );
    assert!(
        c.differing_fraction > 0.05,
        "{name}: only {:.0}% of pixels read the cache: the test exercises too little",
        100.0 * c.differing_fraction
    );
}

/// The default tier's short form of the tests below: hydrogen (the volume where the cache
/// takes the most paths), small, with enough frames to see a 0.5% bias in about a second;
/// the 0.1% tests are the long tier's.
#[test]
fn frozen_unbiased_cache_matches_nee_short() {
    let scene = scene_at(&bundled("hydrogen"), 48, 27);
    assert_matches_nee("hydrogen, short", &scene, Lookup::Raster, (512, 1), 5e-3);
}

#[test]
#[ignore = "long (about a minute and a half on 2 cores): the 0.1%-bias test; CI runs it with --ignored"]
fn frozen_unbiased_cache_matches_nee_on_the_bundled_scenes() {
    for name in ["default", "headsq", "hydrogen", "ironprot"] {
        let scene = scene_at(&bundled(name), 96, 54);
        // Up to 6144 frames: the default scene, its light sphere hidden from the camera, needs
        // about 4400 to see a 0.1% bias (the sphere's exact, bright pixels had lowered the
        // image's relative error).
        assert_matches_nee(name, &scene, Lookup::Raster, (6144, 1), 1e-3);
    }
}

#[test]
#[ignore = "long (about half a minute on 2 cores): the 0.1%-bias test; CI runs it with --ignored"]
fn frozen_unbiased_cache_matches_nee_with_the_ray_traced_lookup() {
    let scene = scene_at(&bundled("default"), 96, 54);
    assert_matches_nee("default, rt lookup", &scene, Lookup::Rt, (6144, 1), 1e-3);
}

#[test]
#[ignore = "needs the chest CT and embryo volumes in ../shared/data (CI runs it with --ignored)"]
fn frozen_unbiased_cache_matches_nee_on_the_shared_volumes() {
    for name in ["chest_ct", "embryo"] {
        let scene = scene_at(&bundled(name), 96, 54);
        // Up to 6144 frames, as for the bundled scenes (embryo hides its light sphere too).
        assert_matches_nee(name, &scene, Lookup::Raster, (6144, 1), 1e-3);
    }
}

/// The test has teeth: dropping the `1 / q` leaves Algorithm 1's selection estimator, whose
/// bias on hydrogen (today's worst volume) the same statistic must see.
#[test]
fn dropping_the_inverse_probability_fails_the_test() {
    let scene = scene_at(&bundled("hydrogen"), 48, 27);
    let mut cache = trained_frozen_cache(&scene, unbiased_config(Lookup::Raster), 24);
    let c = compare(&scene, &mut cache, 192, 1, true, false);
    let limit = test_stats::chi2_upper(c.scores.k as f64, test_stats::Z_FALSE_ALARM_1E5);
    eprintln!(
        "without 1/q: chi2 {:.1} over {} (limit {limit:.1}), brightness {:+.3}% (se {:.3}%)",
        c.scores.chi2,
        c.scores.k,
        100.0 * c.relative_bias,
        100.0 * c.standard_error
    );
    assert!(
        c.scores.chi2 > limit || c.relative_bias.abs() > Z_TWO_SIDED_1E5 * c.standard_error,
        "the biased estimator passed"
    );
}
