//! cached-pt: volume-pt's path tracer with the GSCache radiance cache (Bauer et al., 2025).
//!
//! The two crates do not know each other. volume-pt offers a seam ([`volume_pt::PathHooks`] per
//! path, [`volume_pt::FrameCache`] per frame) and gs-cache offers one path's bookkeeping
//! ([`gs_cache::CachedPath`]) and per-tile training targets ([`gs_cache::TileTargets`]); this
//! crate joins them, so the plain path tracer builds and is tested without the cache, and the
//! cache stays free of volumes. It is a crate of its own rather than a cargo feature of either
//! side because the join needs both: a feature would make one of them depend on the other.
//!
//! - [`GsFrame`], [`GsPath`]: the adapter (the level index stays inside gs-cache).
//! - [`render_cached_frame`]: one frame that draws the cache, traces paths reading it, and
//!   trains it on their samples.
//! - [`nrc`] (feature `nrc`): the same for the neural radiance cache (nrc-cache), the baseline
//!   the GSCache paper compares with; its `NrcSequence` runs each frame's training step beside
//!   the next frame's path tracing.

#![forbid(unsafe_code)]

use gs_cache::{CacheFrame, CachedPath, GsCache, TerminationConfig, TileTargets};
use rayon::prelude::*;
use splat_raster::Camera;
use std::time::Instant;
use volume_pt::{
    Control, FrameCache, NoCache, PathHooks, RenderSettings, SceneMedia, TilePixel, TileRect,
    render_frame_with,
};

pub use volume_pt::sample_cache_points;

#[cfg(feature = "nrc")]
pub mod nrc;

/// One path's hooks: gs-cache's bookkeeping seen through volume-pt's seam.
#[derive(Debug, Clone)]
pub struct GsPath<'a>(pub CachedPath<'a>);

impl PathHooks for GsPath<'_> {
    fn vertex(&mut self, vertex: &volume_pt::Vertex) {
        self.0.vertex(vertex.albedo);
    }
    fn scale(&mut self, factor: glam::Vec3) {
        self.0.scale(factor);
    }
    fn radiance(&mut self, x: glam::Vec3) {
        self.0.radiance(x);
    }
    fn continue_probability(&self) -> f32 {
        self.0.continue_probability()
    }
    fn stop_into_cache(&mut self) -> glam::Vec3 {
        self.0.stop_into_cache()
    }
    fn finished(&mut self, work: u64) {
        self.0.finished(work as f32);
    }
    fn control_variate(&mut self, work: u64) -> Option<volume_pt::ControlVariate> {
        Some(match self.0.control_variate(work as f32)? {
            gs_cache::ControlVariate::Stop { cached } => volume_pt::ControlVariate::Stop { cached },
            gs_cache::ControlVariate::GoOn { cached, q } => {
                volume_pt::ControlVariate::GoOn { cached, q }
            }
        })
    }
    fn escaped(&mut self, path_radiance: glam::Vec3) -> glam::Vec3 {
        self.0.escaped(path_radiance)
    }
}

/// A drawn cache frame as volume-pt's renderer reads it; each tile's paths file their training
/// samples in a [`TileTargets`].
#[derive(Debug, Clone, Copy)]
pub struct GsFrame<'a> {
    pub frame: &'a CacheFrame,
    pub termination: TerminationConfig,
}

impl FrameCache for GsFrame<'_> {
    type Path<'b>
        = GsPath<'b>
    where
        Self: 'b;
    type TileRecord = TileTargets;

    fn tile_record(&self, t: TileRect) -> TileTargets {
        let record = TileTargets::new(self.frame.levels(), t.x0, t.y0, t.width, t.height);
        if self.termination.unbiased {
            record.with_statistics()
        } else {
            record
        }
    }
    fn path(&self, pixel: TilePixel) -> GsPath<'_> {
        GsPath(CachedPath::new(
            self.frame,
            pixel.pixel as usize,
            pixel.key,
            self.termination,
        ))
    }
    fn path_ended(&self, path: GsPath<'_>, pixel: TilePixel, record: &mut TileTargets) {
        if let Some(statistics) = path.0.statistics() {
            record.add_statistics(pixel.in_tile, &statistics);
        }
        record.add_samples(pixel.in_tile, path.0.samples());
        if self.frame.counts_paths() {
            record.add_path(pixel.in_tile, path.0.length());
        }
    }
}

/// What one cached frame did. The parts add up to the frame: a caller's wall time less their
/// sum is only the bookkeeping between them (issue 31 found a third of a frame in no part).
#[derive(Debug, Clone, Copy, Default)]
pub struct CachedFrameStats {
    /// Path tracing time (the GSCache paper's PT).
    pub trace_seconds: f64,
    /// Drawing the levels (ST): the whole of [`GsCache::begin_frame`].
    pub lookup_seconds: f64,
    /// Gathering the tiles' training samples into the frame's targets.
    pub targets_seconds: f64,
    /// Training (OT): the whole of [`GsCache::train`].
    pub train_seconds: f64,
    /// Making a film for a frame that keeps none (a warm-up frame's scratch film).
    pub film_seconds: f64,
    pub samples: u64,
    pub nonfinite_samples: u64,
    /// Training samples the cache refused (negative or not finite).
    pub dropped_training_samples: u64,
    pub cancelled: bool,
}

/// Frame `frame_index` of a sequence: draw the cache from `camera`, trace `settings.spp` paths
/// per pixel reading it (accumulated into `film` when one is given), then train it on the
/// frame's samples (unless cancelled); a frame after a still view's handoff
/// ([`gs_cache::CacheConfig::handoff_frames`]) is the plain tracer's, without the cache's
/// bookkeeping. Frame `f` draws sample indices `f * spp .. (f + 1) * spp` (see
/// [`render_frame_with`]).
pub fn render_cached_frame(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    frame_index: u32,
    film: Option<&mut volume_pt::Film>,
    cache: &mut GsCache,
    control: &Control,
) -> Result<CachedFrameStats, gs_cache::CacheError> {
    let termination = cache.config().termination();
    let clock = Instant::now();
    let handed_off = cache.begin_frame(camera).handed_off();
    let lookup_seconds = clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let mut scratch;
    let film = match film {
        Some(film) => film,
        None => {
            scratch = volume_pt::Film::new(camera.width, camera.height);
            &mut scratch
        }
    };
    let film_seconds = clock.elapsed().as_secs_f64();
    let samples = camera.width as u64 * camera.height as u64 * settings.spp as u64;
    if handed_off {
        // After the still view's handoff the cache neither reads nor trains, so its per-path
        // bookkeeping (each vertex's samples filed into training targets) would be work for
        // nothing: 12% of a pass on hydrogen, measured on issue 53's stills. The plain tracer
        // draws the frame the hooked one would, bit for bit (a path that never stops into the
        // cache runs the plain tracer's samples: `a_still_view_is_handed_back_to_plain_path_tracing`
        // in cached-pt's tests).
        let traced = render_frame_with(
            scene,
            camera,
            settings,
            frame_index,
            film,
            &NoCache,
            control,
        );
        return Ok(CachedFrameStats {
            trace_seconds: traced.trace_seconds,
            lookup_seconds,
            film_seconds,
            samples,
            nonfinite_samples: traced.nonfinite_samples,
            cancelled: traced.cancelled || control.cancelled(),
            ..Default::default()
        });
    }
    let clock = Instant::now();
    let mut targets = cache
        .take_training_targets()
        .expect("begin_frame draws the frame");
    let mut targets_seconds = clock.elapsed().as_secs_f64();
    let frame = cache.frame().expect("begin_frame draws the frame");
    let gs_frame = GsFrame { frame, termination };
    let traced = render_frame_with(
        scene,
        camera,
        settings,
        frame_index,
        film,
        &gs_frame,
        control,
    );
    let (trace_seconds, nonfinite_samples) = (traced.trace_seconds, traced.nonfinite_samples);
    let cancelled = traced.cancelled || control.cancelled();
    let clock = Instant::now();
    let tiles: Vec<&TileTargets> = traced.records.iter().map(|(_, tile)| tile).collect();
    targets.add_tiles(&tiles);
    drop(tiles);
    // Thousands of tile records, each allocated by the thread that traced the tile: freed one
    // after another they cost a millisecond or more a frame that no number of threads shortens.
    traced.records.into_par_iter().for_each(drop);
    targets_seconds += clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    if !cancelled {
        cache.train(&targets)?;
    }
    let train_seconds = clock.elapsed().as_secs_f64();
    let dropped_training_samples = targets.dropped();
    cache.recycle_training_targets(targets);
    Ok(CachedFrameStats {
        trace_seconds,
        lookup_seconds,
        targets_seconds,
        train_seconds,
        film_seconds,
        samples,
        nonfinite_samples,
        dropped_training_samples,
        cancelled,
    })
}
