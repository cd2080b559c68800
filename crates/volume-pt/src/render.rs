//! Rendering an image: progressive passes over tiles, threads from rayon, samples from the
//! counter-based streams. Pixel `(x, y)` with sample index `s` always draws the same numbers,
//! so the image is bit-identical for a seed whatever the thread count or pass split.

use crate::film::{Film, Tile};
use crate::integrator::{PathSettings, SceneMedia, radiance_cached};
use crate::sampling::SampleStream;
use glam::{DVec3, Vec3};
use gs_cache::{CacheFrame, CachedPath, TerminationConfig};
use rayon::prelude::*;
use splat_raster::Camera;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Everything a render needs besides the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    pub spp: u32,
    pub seed: u64,
    pub path: PathSettings,
}

/// What a render did.
#[derive(Debug, Clone, Copy)]
pub struct RenderStats {
    pub samples: u64,
    pub seconds: f64,
    pub cancelled: bool,
    pub nonfinite_samples: u64,
}

impl RenderStats {
    pub fn samples_per_second(&self) -> f64 {
        self.samples as f64 / self.seconds.max(1e-9)
    }
}

/// Progressive passes of this many samples per pixel: small enough for a smooth progress bar and
/// a prompt Ctrl-C, large enough that a pass amortises scheduling.
fn pass_size(spp: u32, pixels: u64) -> u32 {
    let target_samples_per_pass = 1u64 << 20;
    ((target_samples_per_pass / pixels.max(1)) as u32).clamp(1, spp.max(1))
}

/// A cache to read during a pass, and where the pass's training samples go: per level, per
/// tile pixel, a sum and a count.
pub(crate) struct TileCache<'a> {
    pub frame: &'a CacheFrame,
    pub termination: TerminationConfig,
    pub sums: Vec<Vec3>,
    pub counts: Vec<u32>,
}

pub(crate) fn render_tile(
    tile: &mut Tile,
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    samples: std::ops::Range<u32>,
    mut cache: Option<&mut TileCache>,
) -> u64 {
    let mut nonfinite = 0;
    let tile_px = (tile.width * tile.height) as usize;
    for j in 0..tile.height {
        for i in 0..tile.width {
            let (x, y) = (tile.x0 + i, tile.y0 + j);
            let pixel = y as u64 * camera.width as u64 + x as u64;
            let k = (j * tile.width + i) as usize;
            let mut sum = DVec3::ZERO;
            for s in samples.clone() {
                let mut rng = SampleStream::new(settings.seed, pixel, s as u64);
                let (jx, jy) = rng.next_2d();
                let dir = camera.ray_direction(x as f32 + jx, y as f32 + jy);
                let l: Vec3 = match cache.as_deref_mut() {
                    None => {
                        radiance_cached(scene, &settings.path, camera.position, dir, &mut rng, None)
                    }
                    Some(tc) => {
                        let mut path = CachedPath::new(tc.frame, pixel as usize, tc.termination);
                        let l = radiance_cached(
                            scene,
                            &settings.path,
                            camera.position,
                            dir,
                            &mut rng,
                            Some(&mut path),
                        );
                        for (level, v) in path.samples() {
                            tc.sums[level * tile_px + k] += v;
                            tc.counts[level * tile_px + k] += 1;
                        }
                        l
                    }
                };
                // Written so that NaN fails: a bad sample counts as black, never reaches the film.
                if l.is_finite() && l.min_element() >= 0.0 {
                    sum += l.as_dvec3();
                } else {
                    nonfinite += 1;
                }
            }
            tile.sum[k] += sum;
            tile.count[k] += samples.len() as u32;
        }
    }
    nonfinite
}

/// Renders `settings.spp` samples per pixel into `film`, calling `progress(samples_done)` after
/// each tile. Setting `cancel` stops the render between tiles; the film keeps what it has.
pub fn render(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    film: &mut Film,
    cancel: &AtomicBool,
    progress: &(dyn Fn(u64) + Sync),
) -> RenderStats {
    let start = std::time::Instant::now();
    let before = film.total_samples();
    let pixels = camera.width as u64 * camera.height as u64;
    let step = pass_size(settings.spp, pixels);
    let nonfinite = AtomicU64::new(0);
    let mut s0 = 0;
    while s0 < settings.spp && !cancel.load(Ordering::Relaxed) {
        let s1 = (s0 + step).min(settings.spp);
        film.tiles.par_iter_mut().for_each(|tile| {
            if cancel.load(Ordering::Relaxed) {
                return;
            }
            let bad = render_tile(tile, scene, camera, settings, s0..s1, None);
            nonfinite.fetch_add(bad, Ordering::Relaxed);
            progress((tile.width * tile.height * (s1 - s0)) as u64);
        });
        s0 = s1;
    }
    let nonfinite = nonfinite.into_inner();
    film.nonfinite_samples += nonfinite;
    RenderStats {
        samples: film.total_samples() - before,
        seconds: start.elapsed().as_secs_f64(),
        cancelled: cancel.load(Ordering::Relaxed),
        nonfinite_samples: nonfinite,
    }
}
