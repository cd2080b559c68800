//! Running one method progressively: 1-spp passes (or cached frames) accumulated into a film,
//! with a snapshot each time a budget is reached. Budgets in spp and in seconds share one run,
//! so a method's images at 1, 4 and 16 spp are the prefixes of one progressive render, as a
//! user watching it would see them. Times are wall-clock around each pass.

use super::config::Method;
use super::config::NrcDesc;
use crate::camera_path::orbit;
use anyhow::Result;
use cached_pt::nrc::render_nrc_frame;
use cached_pt::render_cached_frame;
use glam::Vec3;
use gs_cache::{CacheConfig, GsCache};
use nrc_cache::{NeuralCache, NrcConfig};
use splat_raster::Camera;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use volume_pt::{Film, Scene, render, sample_cache_points};

/// A budget: samples per pixel, or wall-clock seconds per image.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", content = "value", rename_all = "lowercase")]
pub enum Budget {
    Spp(u32),
    Seconds(f64),
}

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Budget::Spp(s) => write!(f, "{s} spp"),
            Budget::Seconds(s) => write!(f, "{s} s"),
        }
    }
}

/// The image a progressive run had when it reached a budget.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Snapshot {
    pub budget: Budget,
    /// Passes (samples per pixel) in the image.
    pub spp: u32,
    /// Wall-clock seconds of those passes (for a cache: tracing, lookup and training).
    pub seconds: f64,
    #[serde(with = "super::shard::image_bits")]
    pub image: Vec<Vec3>,
}

/// What a cached run leaves besides its snapshots.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct CacheRecord {
    pub init_seconds: f64,
    pub warmup_seconds: f64,
    /// Per frame (warm-up, then measured): per level, the MSE before the step (the neural
    /// cache: one entry, its steps' mean relative L2 loss).
    pub level_mse: Vec<Vec<Option<f64>>>,
    /// Per measured frame that used the cache: seconds of path tracing, lookup (splatting, or
    /// the neural cache's inference and composition) and training. Frames after the handoff (plain path tracing) are counted in `handed_off`
    /// instead, so the cache's per-frame cost is that of the frames that pay it.
    pub frame_seconds: Vec<[f64; 3]>,
    /// Measured frames traced without the cache after its handoff.
    pub handed_off: u32,
    /// The levels as last drawn, at the scene camera.
    #[serde(with = "super::shard::image_bits::many")]
    pub level_images: Vec<Vec<Vec3>>,
    pub parameter_bytes: usize,
    pub nonfinite_samples: u64,
}

/// A distinct stream of random numbers for pass `pass` of seed `seed` (splitmix64 finaliser).
pub fn pass_seed(seed: u64, pass: u64) -> u64 {
    let mut z = seed
        .wrapping_mul(0x9e37_79b9_7f4a_7c15)
        .wrapping_add(pass.wrapping_add(1).wrapping_mul(0xbf58_476d_1ce4_e5b9));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Calls `pass(k, film)` for k = 0, 1, ... (each adds 1 spp to the film and returns its
/// seconds) until every budget is reached, snapshotting the film at each. A time budget is
/// reached by the first pass that ends at or past it (its image includes that pass).
pub fn progressive(
    budgets: &[Budget],
    width: u32,
    height: u32,
    mut pass: impl FnMut(u32, &mut Film) -> Result<f64>,
) -> Result<Vec<Snapshot>> {
    let mut film = Film::new(width, height);
    let mut pending: Vec<Budget> = budgets.to_vec();
    let mut out = Vec::new();
    let (mut k, mut seconds) = (0u32, 0.0);
    while !pending.is_empty() {
        seconds += pass(k, &mut film)?;
        k += 1;
        pending.retain(|b| {
            let reached = match *b {
                Budget::Spp(s) => k >= s,
                Budget::Seconds(t) => seconds >= t,
            };
            if reached {
                out.push(Snapshot {
                    budget: *b,
                    spp: k,
                    seconds,
                    image: film.mean(),
                });
            }
            !reached
        });
    }
    Ok(out)
}

/// A new cache for `scene`, its points found with `seed`, and the seconds it took.
pub fn new_cache(scene: &Scene, config: CacheConfig, seed: u64) -> Result<(GsCache, f64)> {
    let start = Instant::now();
    let config = config.for_image(scene.camera.width, scene.camera.height);
    let (points, albedo) = sample_cache_points(&scene.media.medium, config.points, seed);
    let cache = GsCache::new(&points, &albedo, config)?;
    Ok((cache, start.elapsed().as_secs_f64()))
}

/// `method` at the scene camera with `seed`, snapshotted at every budget.
pub fn run_method(
    scene: &Scene,
    method: &Method,
    seed: u64,
    budgets: &[Budget],
    centre: Vec3,
) -> Result<(Vec<Snapshot>, Option<CacheRecord>)> {
    let cam = scene.camera;
    let mut settings = scene.settings;
    settings.spp = 1;
    settings.path.integrator = method.integrator;
    let cancel = AtomicBool::new(false);
    if let Some(desc) = &method.nrc {
        settings.seed = seed;
        return run_nrc(scene, desc, &settings, budgets, centre);
    }
    let Some(desc) = &method.cache else {
        let snaps = progressive(budgets, cam.width, cam.height, |k, film| {
            let s = volume_pt::RenderSettings {
                seed: pass_seed(seed, k as u64),
                ..settings
            };
            let start = Instant::now();
            render(&scene.media, &cam, &s, film, &cancel, &|_| {});
            Ok(start.elapsed().as_secs_f64())
        })?;
        return Ok((snaps, None));
    };
    settings.seed = seed;
    let (mut cache, init_seconds) = new_cache(scene, desc.config()?, seed)?;
    let mut record = CacheRecord {
        init_seconds,
        parameter_bytes: cache.parameter_bytes(),
        ..Default::default()
    };
    let warmup = desc.warmup;
    let snaps = cached_run(
        scene,
        (warmup, desc.warmup_orbit_degrees),
        budgets,
        centre,
        &mut record,
        |view, f, film| {
            if f == warmup {
                cache.start_image();
            }
            let s =
                render_cached_frame(&scene.media, view, &settings, f, film, &mut cache, &cancel)?;
            Ok(FrameReport {
                costs: [s.trace_seconds, s.lookup_seconds, s.train_seconds],
                loss: cache.report().mse.clone(),
                handed_off: cache.report().handed_off,
                nonfinite_samples: s.nonfinite_samples,
            })
        },
    )?;
    if let Some(frame) = cache.frame() {
        record.level_images = (0..frame.levels())
            .map(|l| {
                frame
                    .image(l)
                    .iter()
                    .map(|&c| Vec3::from_array(c))
                    .collect()
            })
            .collect();
    }
    Ok((snaps, Some(record)))
}

/// What one frame of a cached run files in its [`CacheRecord`].
struct FrameReport {
    /// Seconds of path tracing, reading the cache, and training.
    costs: [f64; 3],
    /// Per level, the loss before the step (the neural cache: one entry).
    loss: Vec<Option<f64>>,
    /// The frame was plain path tracing after the cache's handoff.
    handed_off: bool,
    nonfinite_samples: u64,
}

/// A cached run, for either cache: `warmup.0` frames along an orbit of `warmup.1` degrees
/// ending at the scene camera (no film; their time is the record's warm-up), then measured
/// frames at the camera, accumulated progressively until every budget is reached.
/// `frame(camera, index, film)` renders and trains one frame.
fn cached_run(
    scene: &Scene,
    warmup: (u32, f32),
    budgets: &[Budget],
    centre: Vec3,
    record: &mut CacheRecord,
    mut frame: impl FnMut(&Camera, u32, Option<&mut Film>) -> Result<FrameReport>,
) -> Result<Vec<Snapshot>> {
    let cam = scene.camera;
    let (frames, degrees) = warmup;
    let start = Instant::now();
    for f in 0..frames {
        let view = orbit(&cam, centre, degrees, f, frames + 1);
        let r = frame(&view, f, None)?;
        record.nonfinite_samples += r.nonfinite_samples;
        record.level_mse.push(r.loss);
    }
    record.warmup_seconds = start.elapsed().as_secs_f64();
    progressive(budgets, cam.width, cam.height, |k, film| {
        let start = Instant::now();
        let r = frame(&cam, frames + k, Some(film))?;
        let secs = start.elapsed().as_secs_f64();
        record.nonfinite_samples += r.nonfinite_samples;
        record.level_mse.push(r.loss);
        if r.handed_off {
            record.handed_off += 1;
        } else {
            record.frame_seconds.push(r.costs);
        }
        Ok(secs)
    })
}

/// A new neural cache for `scene` with `seed` (its weights' seed mixed with the run's), and
/// the seconds it took.
pub fn new_nrc(config: NrcConfig, seed: u64) -> Result<(NeuralCache, f64)> {
    let start = Instant::now();
    let config = NrcConfig {
        seed: config.seed ^ pass_seed(seed, u64::MAX),
        ..config
    };
    let cache = NeuralCache::new(config)?;
    Ok((cache, start.elapsed().as_secs_f64()))
}

/// A neural cache frame's training loss, where the record keeps a level's MSE (none when the
/// frame took no step).
pub fn nrc_loss(s: &cached_pt::nrc::NrcFrameStats) -> Option<f64> {
    (s.train.steps > 0).then_some(s.train.mean_loss)
}

/// The neural cache's run, as the Gaussian cache's: its per-frame costs are (trace, inference
/// and composition, training), its loss the training steps' relative L2.
fn run_nrc(
    scene: &Scene,
    desc: &NrcDesc,
    settings: &volume_pt::RenderSettings,
    budgets: &[Budget],
    centre: Vec3,
) -> Result<(Vec<Snapshot>, Option<CacheRecord>)> {
    let cancel = AtomicBool::new(false);
    let (mut cache, init_seconds) = new_nrc(desc.config()?, settings.seed)?;
    let mut record = CacheRecord {
        init_seconds,
        parameter_bytes: cache.parameter_bytes(),
        ..Default::default()
    };
    let snaps = cached_run(
        scene,
        (desc.warmup, desc.warmup_orbit_degrees),
        budgets,
        centre,
        &mut record,
        |view, f, film| {
            let s = render_nrc_frame(&scene.media, view, settings, f, film, &mut cache, &cancel);
            Ok(FrameReport {
                costs: [s.trace_seconds, s.inference_seconds, s.train_seconds],
                loss: vec![nrc_loss(&s)],
                handed_off: false,
                nonfinite_samples: s.nonfinite_samples,
            })
        },
    )?;
    Ok((snaps, Some(record)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progressive_snapshots_every_budget_once_in_order_reached() {
        let budgets = [Budget::Spp(3), Budget::Seconds(0.25), Budget::Spp(1)];
        let snaps = progressive(&budgets, 1, 1, |_, _| Ok(0.1)).unwrap();
        let got: Vec<(Budget, u32)> = snaps.iter().map(|s| (s.budget, s.spp)).collect();
        // 0.25 s is first reached by the third pass (0.3 s).
        assert_eq!(
            got,
            vec![
                (Budget::Spp(1), 1),
                (Budget::Spp(3), 3),
                (Budget::Seconds(0.25), 3)
            ]
        );
        assert!((snaps[2].seconds - 0.3).abs() < 1e-12);
    }

    #[test]
    fn pass_seeds_differ() {
        let a: std::collections::HashSet<u64> = (0..1000)
            .flat_map(|p| [pass_seed(1, p), pass_seed(2, p)])
            .collect();
        assert_eq!(a.len(), 2000);
    }
}
