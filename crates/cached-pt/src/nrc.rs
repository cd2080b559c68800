//! volume-pt's path tracer with the neural radiance cache (nrc-cache): the adapter and the
//! cached frame.
//!
//! A network cannot be evaluated one vertex at a time inside the path loop at any useful speed,
//! so the read is deferred, as in Müller et al. (2021): a path that stops into the cache files
//! its vertex and throughput, the frame's stops are evaluated in one batch after every path is
//! traced, and each `W * N(x)` is added to its pixel's sum (the sample was counted when its
//! path ended).
//!
//! Training paths (a fixed fraction of pixels each frame, chosen by a hash of the pixel and the
//! frame) are the NRC paper's short rendering path plus a training suffix. They make the same
//! stop decision as any path, with a stateless hash of the vertex for its random number (the
//! path's own stream must not see it, or the suffix would differ from a plain path's), but do
//! not stop: the image takes what they gathered before that vertex plus the cache's value there
//! ([`PathHooks::image_radiance`]), exactly as a path that stopped, while the whole path, traced
//! to its end by plain NEE, gives a training record at every vertex it passes. Self-training is
//! off, so every target is an unbiased sample.

use gs_cache::TerminationConfig;
use gs_cache::termination::continue_probability;
use nrc_cache::{NeuralCache, NrcConfig, Query, TrainReport, TrainingRecord};
use render_base::hash::splitmix64;
use splat_raster::Camera;
use volume_pt::{
    Control, FrameCache, PathHooks, RenderSettings, SceneMedia, TilePixel, TileRect, Vertex,
    render_frame_with,
};

use glam::Vec3;
use rayon::prelude::*;

/// Vertices of a training path that give records; deeper ones give none (paths this long carry
/// little throughput, and a fixed bound keeps a path's bookkeeping on the stack).
pub const MAX_TRAINING_VERTICES: usize = 16;

/// One frame's view of the cache: how vertices map to the cache's unit cube, who trains, when
/// paths stop.
#[derive(Debug, Clone, Copy)]
pub struct NrcFrame {
    origin: Vec3,
    inv_extent: Vec3,
    termination: TerminationConfig,
    /// Paths stop into the cache only once it has been trained.
    ready: bool,
    /// A pixel traces training paths this frame when its hash is below this.
    training_threshold: u64,
    frame_hash: u64,
}

impl NrcFrame {
    /// The frame `frame_index` of `seed` over a volume with world bounds `bounds`.
    pub fn new(
        config: &NrcConfig,
        bounds: (Vec3, Vec3),
        ready: bool,
        seed: u64,
        frame_index: u32,
    ) -> Self {
        let extent = (bounds.1 - bounds.0).max(Vec3::splat(1e-30));
        Self {
            origin: bounds.0,
            inv_extent: extent.recip(),
            termination: termination(config),
            ready,
            training_threshold: (config.training_fraction as f64 * u64::MAX as f64) as u64,
            frame_hash: splitmix64(seed ^ splitmix64(frame_index as u64 ^ 0x006e_7263)),
        }
    }

    /// Whether `pixel`'s paths are training paths this frame (traced to their end, never
    /// reading the cache).
    pub fn is_training(&self, pixel: u64) -> bool {
        splitmix64(self.frame_hash ^ pixel) < self.training_threshold
    }

    /// A uniform number in [0, 1) from the pixel, the frame and a vertex's position: the stop
    /// decision of a training path, which must not draw from the path's own stream.
    fn unit_hash(&self, pixel: u64, position: Vec3) -> f32 {
        let bits = (position.x.to_bits() as u64)
            ^ ((position.y.to_bits() as u64) << 21)
            ^ ((position.z.to_bits() as u64) << 42);
        let h = splitmix64(self.frame_hash ^ splitmix64(pixel ^ splitmix64(bits)));
        (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    fn query(&self, v: &Vertex) -> Query {
        Query {
            position: (v.position - self.origin) * self.inv_extent,
            direction: v.direction,
            albedo: v.albedo,
            value: v.value,
        }
    }
}

/// Algorithm 1 with the NRC's coefficient and threshold; no natural termination and no
/// survivor weights (neither exists in NRC).
pub fn termination(config: &NrcConfig) -> TerminationConfig {
    TerminationConfig {
        coefficient: config.c,
        deep_coefficient: config.c,
        threshold: config.threshold,
        early: true,
        natural: false,
        survivor_weights: false,
        stopper_weights: false,
        channel_weights: false,
        unbiased: false,
        min_continuation: 1.0,
    }
}

/// A training path's records: per recorded vertex, its query, the throughput since it (a
/// product, so never a division by a tiny throughput) and the radiance gathered from it on.
#[derive(Debug, Clone)]
pub struct TrainingSuffix {
    len: usize,
    queries: [Query; MAX_TRAINING_VERTICES],
    relative: [Vec3; MAX_TRAINING_VERTICES],
    sums: [Vec3; MAX_TRAINING_VERTICES],
}

impl TrainingSuffix {
    fn new() -> Self {
        Self {
            len: 0,
            queries: [Query::default(); MAX_TRAINING_VERTICES],
            relative: [Vec3::ZERO; MAX_TRAINING_VERTICES],
            sums: [Vec3::ZERO; MAX_TRAINING_VERTICES],
        }
    }
}

/// One path's bookkeeping.
#[derive(Debug, Clone)]
pub struct NrcPath<'a> {
    frame: &'a NrcFrame,
    pixel: u64,
    /// The renderer's throughput, kept from the changes it reports.
    throughput: Vec3,
    albedo_product: Vec3,
    /// The current vertex, as the cache would be queried there.
    current: Query,
    length: usize,
    /// Where the path stopped into the cache, with its throughput there.
    stop: Option<(Query, Vec3)>,
    /// Training paths only (the others never fill, so never initialise, the arrays).
    training: Option<TrainingSuffix>,
    /// A training path: the radiance gathered before the vertex where it would have stopped,
    /// which is what enters the image if it would have.
    prefix: Vec3,
}

impl PathHooks for NrcPath<'_> {
    fn vertex(&mut self, v: &Vertex) {
        self.throughput *= v.albedo;
        self.albedo_product *= v.albedo;
        self.length += 1;
        self.current = self.frame.query(v);
        if self.training.is_some() && self.stop.is_none() && self.frame.ready {
            // The stop a rendering path would make here, decided by a hash of the vertex.
            let q = continue_probability(&self.frame.termination, self.albedo_product);
            if q < 1.0 && self.frame.unit_hash(self.pixel, v.position) >= q {
                self.stop = Some((self.current, self.throughput));
            }
        }
        if let Some(t) = &mut self.training {
            for m in 0..t.len {
                t.relative[m] *= v.albedo;
            }
            if t.len < MAX_TRAINING_VERTICES {
                let m = t.len;
                t.queries[m] = self.current;
                t.relative[m] = Vec3::ONE;
                t.sums[m] = Vec3::ZERO;
                t.len += 1;
            }
        }
    }
    fn scale(&mut self, factor: Vec3) {
        self.throughput *= factor;
        if let Some(t) = &mut self.training {
            for m in 0..t.len {
                t.relative[m] *= factor;
            }
        }
    }
    fn radiance(&mut self, x: Vec3) {
        if self.stop.is_none() {
            self.prefix += self.throughput * x;
        }
        if let Some(t) = &mut self.training {
            for m in 0..t.len {
                t.sums[m] += t.relative[m] * x;
            }
        }
    }
    fn continue_probability(&self) -> f32 {
        if self.training.is_some() || !self.frame.ready || self.length == 0 {
            return 1.0;
        }
        continue_probability(&self.frame.termination, self.albedo_product)
    }
    fn stop_into_cache(&mut self) -> Vec3 {
        // The value is added after the frame's batch of queries (the read is deferred).
        self.stop = Some((self.current, self.throughput));
        Vec3::ZERO
    }
    fn image_radiance(&self, path_radiance: Vec3) -> Vec3 {
        // A training path that would have stopped: what it gathered before that vertex (the
        // cache's value there is composed later). Any other path: all it gathered, as the
        // renderer summed it.
        if self.training.is_some() && self.stop.is_some() {
            self.prefix
        } else {
            path_radiance
        }
    }
}

/// What one tile's paths leave: their stops (pixel in the tile, throughput, query) and the
/// training records of its training paths.
#[derive(Debug, Clone, Default)]
pub struct NrcTile {
    pub stops: Vec<(u32, Vec3, Query)>,
    pub records: Vec<TrainingRecord>,
}

impl FrameCache for NrcFrame {
    type Path<'b> = NrcPath<'b>;
    type TileRecord = NrcTile;

    fn tile_record(&self, tile: TileRect) -> NrcTile {
        let pixels = (tile.width * tile.height) as usize;
        NrcTile {
            stops: Vec::with_capacity(pixels),
            records: Vec::new(),
        }
    }
    fn path(&self, pixel: TilePixel) -> NrcPath<'_> {
        NrcPath {
            frame: self,
            pixel: pixel.pixel,
            prefix: Vec3::ZERO,
            throughput: Vec3::ONE,
            albedo_product: Vec3::ONE,
            current: Query::default(),
            length: 0,
            stop: None,
            training: self.is_training(pixel.pixel).then(TrainingSuffix::new),
        }
    }
    fn path_ended(&self, path: NrcPath<'_>, pixel: TilePixel, record: &mut NrcTile) {
        if let Some((query, throughput)) = path.stop {
            record.stops.push((pixel.in_tile as u32, throughput, query));
        }
        if let Some(t) = &path.training {
            for m in 0..t.len {
                record.records.push(TrainingRecord {
                    query: t.queries[m],
                    target: t.sums[m],
                });
            }
        }
    }
}

/// The neural cache as a sequence of frames drives it, with the last frame's training step
/// still to take.
///
/// A frame's training step needs only that frame's records, and the next frame's path tracing
/// needs nothing of the cache but whether it has been trained at all (its stops are read after
/// tracing, in one batch). So frame `N`'s step runs beside frame `N + 1`'s path tracing, whose
/// thousands of tiles keep every core busy through the step's small kernels, and frame
/// `N + 1`'s inference then reads the cache with that step taken (issue 31). The images are
/// the same bits as when each frame takes its step at its end: the cache each inference reads
/// and each frame's stop decisions are the same (tested).
#[derive(Debug)]
pub struct NrcSequence {
    cache: NeuralCache,
    pending: Option<PendingStep>,
}

/// A frame's training step, not yet taken: its training paths' records, by tile, and the seed
/// that draws its batches.
struct PendingStep {
    tiles: Vec<Vec<TrainingRecord>>,
    shuffle: u64,
}

impl std::fmt::Debug for PendingStep {
    /// The number of records, not the records (a frame files about a hundred thousand).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PendingStep")
            .field("records", &self.tiles.iter().map(Vec::len).sum::<usize>())
            .field("shuffle", &self.shuffle)
            .finish()
    }
}

impl PendingStep {
    /// Takes the step on `cache`: what `NeuralCache::train` does with the frame's records.
    fn take(self, cache: &mut NeuralCache) -> TrainReport {
        let records: Vec<TrainingRecord> = self.tiles.into_iter().flatten().collect();
        cache.train(&records, self.shuffle)
    }

    /// [`PendingStep::take`], and the seconds it took.
    fn take_timed(self, cache: &mut NeuralCache) -> (TrainReport, f64) {
        let start = std::time::Instant::now();
        let report = self.take(cache);
        (report, start.elapsed().as_secs_f64())
    }
}

impl NrcSequence {
    pub fn new(cache: NeuralCache) -> Self {
        Self {
            cache,
            pending: None,
        }
    }

    /// The cache as its steps so far left it: the last frame's step may still be to take (see
    /// [`NrcSequence::finish`]).
    pub fn cache(&self) -> &NeuralCache {
        &self.cache
    }

    /// Takes the last frame's training step, if it is still to take, and reports it: after
    /// this the cache has learned from every frame rendered.
    pub fn finish(&mut self) -> TrainReport {
        match self.pending.take() {
            Some(step) => step.take(&mut self.cache),
            None => TrainReport::default(),
        }
    }

    /// The cache with every frame's step taken, to change or read directly.
    pub fn cache_mut(&mut self) -> &mut NeuralCache {
        self.finish();
        &mut self.cache
    }

    /// The cache with every frame's step taken.
    pub fn into_cache(mut self) -> NeuralCache {
        self.finish();
        self.cache
    }
}

/// What one frame with the neural cache did.
#[derive(Debug, Clone, Copy, Default)]
pub struct NrcFrameStats {
    /// Path tracing (the GSCache paper's PT), the previous frame's training step beside it.
    pub trace_seconds: f64,
    /// Inference and composition (IT).
    pub inference_seconds: f64,
    /// Training's part of the frame (OT): the time the frame waited on the previous frame's
    /// step after its own tracing ended, and filing its own records for the next frame (and
    /// freeing its tiles). The parts add up to the frame.
    pub train_seconds: f64,
    /// The training step's own duration, the overlap with path tracing included.
    pub train_step_seconds: f64,
    /// Making a film for a frame that keeps none (a warm-up frame's scratch film).
    pub film_seconds: f64,
    /// Paths that stopped into the cache.
    pub queries: usize,
    pub samples: u64,
    pub nonfinite_samples: u64,
    /// The training step taken during this frame: the previous frame's records.
    pub train: TrainReport,
    pub cancelled: bool,
}

/// Frame `frame_index`: trace `settings.spp` paths per pixel (accumulated into `film` when one
/// is given) while the previous frame's training step runs, read the cache at the paths' stops
/// in one batch and compose the values into the film, then file the frame's training records
/// for the next frame's step (unless cancelled). Without a film (warm-up frames) nothing is
/// read: the stops' values would go nowhere.
pub fn render_nrc_frame(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    frame_index: u32,
    film: Option<&mut volume_pt::Film>,
    sequence: &mut NrcSequence,
    control: &Control,
) -> NrcFrameStats {
    let timed = |f: &mut dyn FnMut()| {
        let start = std::time::Instant::now();
        f();
        start.elapsed().as_secs_f64()
    };
    let NrcSequence { cache, pending } = sequence;
    let mut report = TrainReport::default();
    let mut first_step_seconds = 0.0;
    if cache.steps() == 0 {
        // Whether paths may stop depends on whether the cache has taken a step, which only
        // taking it tells (a step whose loss is not finite is skipped): an untrained cache's
        // pending step runs before the tracing, not beside it.
        if let Some(step) = pending.take() {
            (report, first_step_seconds) = step.take_timed(cache);
        }
    }
    let frame = NrcFrame::new(
        cache.config(),
        scene.medium.bounds(),
        cache.steps() > 0,
        settings.seed,
        frame_index,
    );
    let clock = std::time::Instant::now();
    let mut scratch;
    let has_film = film.is_some();
    let film = match film {
        Some(film) => film,
        None => {
            scratch = volume_pt::Film::new(camera.width, camera.height);
            &mut scratch
        }
    };
    let film_seconds = clock.elapsed().as_secs_f64();
    let nonfinite_before = film.nonfinite_samples;
    let clock = std::time::Instant::now();
    let step = pending.take();
    let mut step_seconds = first_step_seconds;
    let mut traced = {
        let film = &mut *film;
        let cache = &mut *cache;
        let (traced, step) = rayon::join(
            || render_frame_with(scene, camera, settings, frame_index, film, &frame, control),
            || step.map(|step| step.take_timed(cache)),
        );
        if let Some((step_report, seconds)) = step {
            report = step_report;
            step_seconds += seconds;
        }
        traced
    };
    let waited = (clock.elapsed().as_secs_f64() - traced.trace_seconds).max(0.0);
    let mut stats = NrcFrameStats {
        trace_seconds: traced.trace_seconds,
        film_seconds,
        samples: camera.width as u64 * camera.height as u64 * settings.spp as u64,
        train_step_seconds: step_seconds,
        train: report,
        ..Default::default()
    };
    stats.queries = traced.records.iter().map(|(_, t)| t.stops.len()).sum();
    stats.cancelled = traced.cancelled || control.cancelled();
    if has_film && stats.queries > 0 {
        stats.inference_seconds =
            timed(&mut || compose(&traced.records, &|q| cache.predict(q), film));
    }
    let clock = std::time::Instant::now();
    if !stats.cancelled {
        *pending = Some(PendingStep {
            tiles: traced
                .records
                .iter_mut()
                .map(|(_, t)| std::mem::take(&mut t.records))
                .collect(),
            shuffle: splitmix64(settings.seed ^ splitmix64(frame_index as u64 ^ 0x0074_7261_696e)),
        });
    }
    // Thousands of tiles' stops, each allocated by the thread that traced the tile: freed one
    // after another they cost a millisecond or more a frame that no number of threads shortens.
    traced.records.into_par_iter().for_each(drop);
    let filing = clock.elapsed().as_secs_f64();
    stats.train_seconds = first_step_seconds + waited + filing;
    // The traced samples and the composed values that were refused.
    stats.nonfinite_samples = film.nonfinite_samples - nonfinite_before;
    stats
}

/// Reads the cache at every stop of the frame's tiles (`predict`) and composes each value,
/// times its path's throughput, into `film`. Gathered and composed by tile in parallel (a
/// serial pass over the stops does not scale with the cores, issue 31); the film's sums are
/// exact, so the order does not show in the image.
fn compose(
    tiles: &[(TileRect, NrcTile)],
    predict: &(dyn Fn(&[Query]) -> Vec<Vec3> + Sync),
    film: &mut volume_pt::Film,
) {
    let mut first = Vec::with_capacity(tiles.len());
    let mut next = 0;
    for (_, tile) in tiles {
        first.push(next);
        next += tile.stops.len();
    }
    // The stops' queries in tile order, each tile copying its own into place: collected from
    // a flattened iterator they were concatenated on one thread (1.4 ms a frame at 1280x720).
    let mut queries = Vec::with_capacity(next);
    queries.par_extend((0..next).into_par_iter().map(|_| Query::default()));
    let mut rest = queries.as_mut_slice();
    let mut per_tile = Vec::with_capacity(tiles.len());
    for (_, tile) in tiles {
        let (mine, others) = rest.split_at_mut(tile.stops.len());
        per_tile.push(mine);
        rest = others;
    }
    per_tile
        .into_par_iter()
        .zip(tiles.par_iter())
        .for_each(|(mine, (_, tile))| {
            for (q, stop) in mine.iter_mut().zip(&tile.stops) {
                *q = stop.2;
            }
        });
    let values = predict(&queries);
    let by_corner: std::collections::HashMap<(u32, u32), usize> = tiles
        .iter()
        .enumerate()
        .map(|(i, (rect, _))| ((rect.x0, rect.y0), i))
        .collect();
    let (values, first) = (&values, &first);
    film.add_deferred_by_tile(|rect| {
        let i = by_corner.get(&(rect.x0, rect.y0)).copied();
        i.into_iter().flat_map(move |i| {
            let (_, tile) = &tiles[i];
            tile.stops
                .iter()
                .zip(&values[first[i]..])
                .map(|(&(in_tile, throughput, _), &v)| (in_tile as usize, throughput * v))
        })
    });
}
