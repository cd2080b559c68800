//! Rendering with the gs-cache radiance cache: the initial point cloud (the GSCache paper's section
//! 3.2, delta tracking of random rays), and frames that read the cache, gather its training samples
//! and train it.

use crate::film::Film;
use crate::integrator::SceneMedia;
use crate::render::{RenderSettings, TileCache, render_tile};
use crate::sampling::{SampleStream, uniform_sphere};
use crate::tracking::free_flight;
use glam::Vec3;
use gs_cache::{GsCache, TrainingTargets};
use rayon::prelude::*;
use splat_raster::Camera;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

/// Points where random rays first scatter in the medium, with the albedo there: `n` of them,
/// in random order. Each ray starts on a sphere around the volume and aims at a uniform point
/// of the box; rays that pass through without scattering are replaced. Gives up (returning
/// fewer points) after `64 n` rays, so an empty medium cannot hang it.
pub fn sample_cache_points(media: &SceneMedia, n: usize, seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
    let medium = &media.medium;
    let (lo, hi) = medium.bounds();
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length() * 1.01;
    const CHUNK: usize = 1024;
    let chunks = n.div_ceil(CHUNK);
    let found: Vec<Vec<(Vec3, Vec3)>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let want = CHUNK.min(n - c * CHUNK);
            let mut out = Vec::with_capacity(want);
            let mut attempt = 0u64;
            while out.len() < want && attempt < 64 * want as u64 {
                let mut rng = SampleStream::new(seed ^ 0x6a09_e667_f3bc_c908, c as u64, attempt);
                attempt += 1;
                let o = centre + radius * uniform_sphere(rng.next_2d());
                let (u, v) = rng.next_2d();
                let target = lo + (hi - lo) * Vec3::new(u, v, rng.next_f32());
                let Some(d) = (target - o).try_normalize() else {
                    continue;
                };
                let ray = medium.to_index_ray(o, d);
                if let Some(t) = free_flight(medium, &ray, 0.0, f32::INFINITY, &mut rng) {
                    out.push((o + d * t, medium.albedo(ray.at(t))));
                }
            }
            out
        })
        .collect();
    found.into_iter().flatten().unzip()
}

/// One tile's training samples: per level, per tile pixel, a sum and a count.
struct TileSamples {
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    sums: Vec<Vec3>,
    counts: Vec<u32>,
}

/// What one cached frame did.
#[derive(Debug, Clone, Copy, Default)]
pub struct CachedFrameStats {
    /// Path tracing time (the paper's PT).
    pub trace_seconds: f64,
    /// Drawing the levels (ST).
    pub lookup_seconds: f64,
    /// Training (OT).
    pub train_seconds: f64,
    pub samples: u64,
    pub nonfinite_samples: u64,
    pub cancelled: bool,
}

/// Frame `frame` of a sequence: draw the cache from `camera`, trace `settings.spp` paths per
/// pixel reading it (accumulated into `film` when one is given), then train it on the frame's
/// samples. Frame `f` draws sample indices `f * spp .. (f + 1) * spp`, so successive frames
/// have independent noise (the cache must never be trained twice on the same random paths)
/// and a film accumulated over frames is a progressive render.
pub fn render_cached_frame(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    frame_index: u32,
    film: Option<&mut Film>,
    cache: &mut GsCache,
    cancel: &AtomicBool,
) -> Result<CachedFrameStats, gs_cache::CacheError> {
    let first_sample = frame_index.saturating_mul(settings.spp);
    let termination = cache.config().termination;
    let levels = cache.levels().len();
    cache.begin_frame(camera);
    let lookup_seconds = cache.report().lookup_seconds;
    let start = Instant::now();
    let nonfinite = AtomicU64::new(0);
    let mut scratch;
    let film_ref: &mut Film = match film {
        Some(film) => film,
        None => {
            scratch = Film::new(camera.width, camera.height);
            &mut scratch
        }
    };
    let frame = cache.frame().expect("begin_frame draws the frame");
    let tile_samples: Vec<TileSamples> = film_ref
        .tiles
        .par_iter_mut()
        .filter_map(|tile| {
            if cancel.load(Ordering::Relaxed) {
                return None;
            }
            let n = (tile.width * tile.height) as usize * levels;
            let mut tc = TileCache {
                frame,
                termination,
                sums: vec![Vec3::ZERO; n],
                counts: vec![0; n],
            };
            let bad = render_tile(
                tile,
                scene,
                camera,
                settings,
                first_sample..first_sample + settings.spp,
                Some(&mut tc),
            );
            nonfinite.fetch_add(bad, Ordering::Relaxed);
            Some(TileSamples {
                x0: tile.x0,
                y0: tile.y0,
                width: tile.width,
                height: tile.height,
                sums: tc.sums,
                counts: tc.counts,
            })
        })
        .collect();
    let trace_seconds = start.elapsed().as_secs_f64();
    let mut targets = TrainingTargets::new(levels, camera.width, camera.height);
    for t in &tile_samples {
        let (x0, y0, w, h) = (t.x0, t.y0, t.width, t.height);
        let (sums, counts) = (&t.sums, &t.counts);
        let tile_px = (w * h) as usize;
        for level in 0..levels {
            for j in 0..h {
                for i in 0..w {
                    let k = level * tile_px + (j * w + i) as usize;
                    let pixel = ((y0 + j) * camera.width + x0 + i) as usize;
                    if counts[k] > 0 {
                        let mean = sums[k] / counts[k] as f32;
                        targets.add(level, pixel, mean.to_array());
                    }
                }
            }
        }
    }
    let cancelled = cancel.load(Ordering::Relaxed);
    let train_seconds = if cancelled {
        0.0
    } else {
        cache.train(&targets)?.train_seconds
    };
    let nonfinite = nonfinite.into_inner();
    film_ref.nonfinite_samples += nonfinite;
    Ok(CachedFrameStats {
        trace_seconds,
        lookup_seconds,
        train_seconds,
        samples: camera.width as u64 * camera.height as u64 * settings.spp as u64,
        nonfinite_samples: nonfinite,
        cancelled,
    })
}
