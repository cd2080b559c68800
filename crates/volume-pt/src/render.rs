//! Rendering an image: progressive passes over tiles, threads from rayon, samples from the
//! counter-based streams. Pixel `(x, y)` with sample index `s` always draws the same numbers,
//! so the image is bit-identical for a seed whatever the thread count or pass split.

use crate::cache::{FrameCache, NoCache, PathHooks, TilePixel, TileRect, path_key};
use crate::film::{ExactFeatures, ExactRgb, FeatureSample, Film, Tile};
use crate::integrator::{FirstHit, PathSettings, SceneMedia, radiance_with};
use crate::sampling::SampleStream;
use rayon::prelude::*;
use render_base::Camera;
use render_base::Control;
use std::sync::atomic::{AtomicU64, Ordering};

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

/// Renders samples `samples` of every pixel of `tile` into it, reading `cache` and filing each
/// path's record in `record`. Returns the number of samples that came out NaN or infinite.
/// Cancellation is read before every sample, so a tile of very long paths (a dense medium, a
/// huge image) still stops promptly; each pixel keeps the samples it finished.
#[allow(clippy::too_many_arguments)] // one tile's job: plain references, no per-call struct
fn render_tile<C: FrameCache>(
    tile: &mut Tile,
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    samples: std::ops::Range<u32>,
    cache: &C,
    record: &mut C::TileRecord,
    control: &Control,
) -> u64 {
    let mut nonfinite = 0;
    let keep_features = !tile.features.is_empty();
    let directions = camera.ray_directions();
    for j in 0..tile.height {
        for i in 0..tile.width {
            let (x, y) = (tile.x0 + i, tile.y0 + j);
            let pixel_index = y as u64 * camera.width as u64 + x as u64;
            let in_tile = (j * tile.width + i) as usize;
            let mut sum = ExactRgb::ZERO;
            let mut features = ExactFeatures::ZERO;
            let mut taken = 0u32;
            for s in samples.clone() {
                if control.cancelled() {
                    break;
                }
                taken += 1;
                let pixel = TilePixel {
                    pixel: pixel_index,
                    in_tile,
                    key: path_key(settings.seed, pixel_index, s as u64),
                };
                let mut rng = SampleStream::new(settings.seed, pixel.pixel, s as u64);
                let (jx, jy) = rng.next_2d();
                let dir = directions.at(x as f32 + jx, y as f32 + jy);
                let mut path = cache.path(pixel);
                let sample = radiance_with(
                    scene,
                    &settings.path,
                    camera.position,
                    dir,
                    &mut rng,
                    &mut path,
                );
                if keep_features {
                    features.add(feature_sample(scene, sample.first_hit, dir));
                }
                let l = path.image_radiance(sample.radiance);
                cache.path_ended(path, pixel, record);
                // A bad sample (NaN, infinite, absurdly bright) counts as black and
                // never reaches the film.
                match ExactRgb::from_sample(l) {
                    Some(v) => sum += v,
                    None => nonfinite += 1,
                }
            }
            tile.sum[in_tile] += sum;
            tile.count[in_tile] += taken;
            if keep_features {
                let f = &mut tile.features[in_tile];
                *f = f
                    .checked_add(&features)
                    .expect("a pixel's feature sums are bounded by its u32 sample count");
            }
        }
    }
    nonfinite
}

/// The features of a sample whose camera ray (direction `dir`) met `first` first. A scattering
/// event gives its albedo (clamped to [0, 1], as Open Image Denoise requires), the extinction
/// normal (facing the camera where the field is flat) and its distance. An emitter seen
/// directly (a light, the environment) gives its radiance clamped to [0, 1] as the albedo, no
/// normal and no depth: the convention for emissive surfaces, which tells a light's disc from
/// the dark background around it (measured against 0 and 1 for misses: BENCHMARKS.md).
fn feature_sample(scene: &SceneMedia, first: Option<FirstHit>, dir: glam::Vec3) -> FeatureSample {
    match first {
        Some(FirstHit::Scattered(event)) => FeatureSample {
            albedo: event.albedo.clamp(glam::Vec3::ZERO, glam::Vec3::ONE),
            normal: scene
                .medium
                .extinction_normal(event.position, -dir)
                .clamp(-glam::Vec3::ONE, glam::Vec3::ONE),
            depth: Some(event.distance),
        },
        Some(FirstHit::Emitter(radiance)) => FeatureSample {
            albedo: radiance.clamp(glam::Vec3::ZERO, glam::Vec3::ONE),
            normal: glam::Vec3::ZERO,
            depth: None,
        },
        None => FeatureSample {
            albedo: glam::Vec3::ZERO,
            normal: glam::Vec3::ZERO,
            depth: None,
        },
    }
}

/// What one frame read through a cache left: each tile's record, and how long it took.
#[derive(Debug)]
pub struct CachedFrame<R> {
    /// One record per tile, in the film's tile order; a tile skipped by cancellation has none.
    pub records: Vec<(TileRect, R)>,
    pub trace_seconds: f64,
    pub nonfinite_samples: u64,
    pub cancelled: bool,
}

/// Frame `frame_index` of a sequence read through `cache`: `settings.spp` paths per pixel,
/// accumulated into `film`. Frame `f` draws sample indices `f * spp .. (f + 1) * spp`, so
/// successive frames have independent noise (a cache must never be trained twice on the same
/// random paths) and a film accumulated over frames is a progressive render. Cancelling
/// `control` stops it before the next sample; each tile reports its samples to it.
pub fn render_frame_with<C: FrameCache>(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    frame_index: u32,
    film: &mut Film,
    cache: &C,
    control: &Control,
) -> CachedFrame<C::TileRecord> {
    let first_sample = frame_index.saturating_mul(settings.spp);
    let start = std::time::Instant::now();
    let nonfinite = AtomicU64::new(0);
    let records = film
        .tiles
        .par_iter_mut()
        .filter_map(|tile| {
            if control.cancelled() {
                return None;
            }
            let mut record = cache.tile_record(tile.rect());
            let bad = render_tile(
                tile,
                scene,
                camera,
                settings,
                first_sample..first_sample + settings.spp,
                cache,
                &mut record,
                control,
            );
            nonfinite.fetch_add(bad, Ordering::Relaxed);
            control.progress(tile.width as u64 * tile.height as u64 * settings.spp as u64);
            Some((tile.rect(), record))
        })
        .collect();
    let nonfinite = nonfinite.into_inner();
    film.nonfinite_samples += nonfinite;
    CachedFrame {
        records,
        trace_seconds: start.elapsed().as_secs_f64(),
        nonfinite_samples: nonfinite,
        cancelled: control.cancelled(),
    }
}

/// Renders `settings.spp` samples per pixel into `film`, reporting each tile's samples to
/// `control`. Cancelling it stops the render before the next sample; the film keeps what it has.
pub fn render(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    film: &mut Film,
    control: &Control,
) -> RenderStats {
    render_samples(scene, camera, settings, 0..settings.spp, film, control)
}

/// Renders sample indices `samples` of every pixel into `film` (a shard of a render: see
/// [`crate::shard`]); [`render`] is `render_samples(0..spp)`. Films of disjoint ranges merge
/// into the whole render's film bit for bit.
///
/// Passes grow from one sample per pixel, doubling up to [`pass_size`]'s. Where `control`
/// [keeps every pixel](Control::keeping_every_pixel), the first pass is not cancelled, so an
/// image interrupted at any time has at least one sample in every pixel (a first pass of 256
/// samples tile by tile, interrupted after 3 s, once left 1096 of 4096 pixels black). Sums are
/// exact, so the split does not change a bit.
pub fn render_samples(
    scene: &SceneMedia,
    camera: &Camera,
    settings: &RenderSettings,
    samples: std::ops::Range<u32>,
    film: &mut Film,
    control: &Control,
) -> RenderStats {
    let start = std::time::Instant::now();
    let before = film.total_samples();
    let pixels = camera.width as u64 * camera.height as u64;
    let step = pass_size(samples.len() as u32, pixels);
    let nonfinite = AtomicU64::new(0);
    let mut s0 = samples.start;
    let mut this_pass = 1u32;
    let whole_first_pass = control.keeps_every_pixel();
    let first_pass = control.uncancellable();
    while s0 < samples.end && ((whole_first_pass && s0 == samples.start) || !control.cancelled()) {
        let s1 = s0.saturating_add(this_pass).min(samples.end);
        let control = if whole_first_pass && s0 == samples.start {
            &first_pass
        } else {
            control
        };
        film.tiles.par_iter_mut().for_each(|tile| {
            if control.cancelled() {
                return;
            }
            let bad = render_tile(
                tile,
                scene,
                camera,
                settings,
                s0..s1,
                &NoCache,
                &mut (),
                control,
            );
            nonfinite.fetch_add(bad, Ordering::Relaxed);
            control.progress((tile.width * tile.height * (s1 - s0)) as u64);
        });
        s0 = s1;
        this_pass = this_pass.saturating_mul(2).min(step);
    }
    let nonfinite = nonfinite.into_inner();
    film.nonfinite_samples += nonfinite;
    RenderStats {
        samples: film.total_samples() - before,
        seconds: start.elapsed().as_secs_f64(),
        cancelled: control.cancelled(),
        nonfinite_samples: nonfinite,
    }
}
