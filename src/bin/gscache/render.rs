//! `gscache render SCENE.toml`: path-trace a volume scene to EXR and PNG, optionally reading
//! and training the GSCache radiance cache.

use crate::common::{
    Global, INTERRUPTED, cancellation, finite_f32, prepare_folder, prepare_output,
};
use anyhow::{Context, Result, bail};
use cached_pt::nrc::render_nrc_frame;
use cached_pt::render_cached_frame;
use gs_cache::{CacheConfig, GsCache};
use gscache_cli::camera_path::orbit;
use gscache_cli::experiment::measure::new_nrc;
use hdr_image::{RgbImage, ToneMap};
use indicatif::ProgressBar;
use nrc_cache::NrcConfig;
use serde::Deserialize;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use volume_pt::scene::max_depth_from;
use volume_pt::scene::scene_render_key;
use volume_pt::{
    Film, IntegratorKind, PartialRender, RenderStats, Scene, Shard, load_scene, render,
    render_samples, sample_cache_points,
};

/// Path-trace a scientific volume through its transfer function (see docs/scene-format.md).
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct RenderArgs {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Samples per pixel (overrides the scene); with the cache, per frame.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    spp: Option<u32>,
    /// `uniform` (phase sampling only) or `nee` (light sampling + phase sampling, MIS).
    #[arg(long, value_enum)]
    integrator: Option<IntegratorKind>,
    /// Largest path length in real scattering vertices; -1 for unlimited.
    #[arg(long)]
    max_depth: Option<i64>,
    /// Seed of the counter-based random numbers (and of the cache's starting points).
    #[arg(long)]
    seed: Option<u64>,
    /// Image width in pixels (overrides the scene).
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels (overrides the scene).
    #[arg(long)]
    height: Option<u32>,
    /// Majorant macrocell size in voxels (a size >= the largest dim gives one global majorant).
    #[arg(long)]
    macrocell: Option<u32>,
    /// Linear EXR output (default: out/<scene>.exr).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Tone-mapped PNG output (default: next to the EXR).
    #[arg(long)]
    png: Option<PathBuf>,
    /// PNG exposure in stops (overrides the scene).
    #[arg(long, value_parser = finite_f32)]
    exposure: Option<f32>,
    /// PNG tone map (overrides the scene).
    #[arg(long, value_enum)]
    tonemap: Option<ToneMap>,
    /// Render only shard I/N of the samples (for example 0/4: the first quarter of every
    /// pixel's samples) into the partial film `--partial`; `gscache merge` joins the shards
    /// into the image one process would make, bit for bit.
    #[arg(long, requires = "partial", value_parser = parse_shard)]
    shard: Option<Shard>,
    /// Where a shard's partial film goes (written atomically).
    #[arg(long, requires = "shard")]
    partial: Option<PathBuf>,
    #[command(flatten)]
    cache: CacheRun,
}

fn parse_shard(s: &str) -> std::result::Result<Shard, String> {
    Shard::parse(s).map_err(|e| e.to_string())
}

/// The GSCache radiance cache (Bauer et al., 2025): read where paths stop, trained between
/// frames. Its settings are `--cache-KEY`, the keys of an experiment file's `cache` table.
#[derive(clap::Args, Debug)]
pub struct CacheRun {
    /// Read and train the radiance cache.
    #[arg(long, conflicts_with = "nrc")]
    cache: bool,
    /// Read and train the neural radiance cache (Müller et al., 2021: a hash grid and an MLP
    /// on burn) instead: the baseline the GSCache paper compares with.
    #[arg(long)]
    nrc: bool,
    /// A neural cache setting, `KEY=VALUE` with the keys of an experiment file's `nrc` table
    /// (for example `hidden_layers=5`); repeat for several.
    #[arg(long = "nrc-set", value_name = "KEY=VALUE", requires = "nrc")]
    nrc_set: Vec<String>,
    #[command(flatten)]
    settings: CacheConfig,
    /// Frames of `--spp` samples each, trained between them; the image is their mean.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    frames: u32,
    /// Frames rendered and trained on before the image starts accumulating.
    #[arg(long, default_value_t = 0)]
    warmup: u32,
    /// Degrees of orbit about the volume's centre over the warm-up frames, ending at the
    /// scene's camera (the experiment runner's warm-up); 0 keeps the camera still.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = finite_f32)]
    warmup_orbit: f32,
    /// Write the trained levels as 3DGS PLY files into this folder.
    #[arg(long)]
    save_cache: Option<PathBuf>,
    /// Start from levels saved by `--save-cache` instead of initialising from the volume.
    #[arg(long)]
    load_cache: Option<PathBuf>,
    /// Write each level's image as drawn for the last frame (EXR and PNG) into this folder.
    #[arg(long)]
    cache_images: Option<PathBuf>,
}

pub fn run(args: RenderArgs, global: &Global) -> Result<i32> {
    let load_start = std::time::Instant::now();
    let mut scene = load_scene(&args.scene)?;
    for n in &scene.notes {
        let (kind, text) = n
            .strip_prefix("warning: ")
            .map_or(("note", n.as_str()), |w| ("warning", w));
        eprintln!("{kind}: {}: {text}", scene.volume_path.display());
    }
    if let Some(s) = args.spp {
        scene.settings.spp = s;
    }
    if let Some(i) = args.integrator {
        scene.settings.path.integrator = i;
    }
    if let Some(d) = args.max_depth {
        scene.settings.path.max_depth = max_depth_from(d).map_err(anyhow::Error::msg)?;
    }
    if let Some(s) = args.seed {
        scene.settings.seed = s;
    }
    if let Some(m) = args.macrocell {
        scene.media.medium.set_macrocell_size(m);
    }
    if args.width.is_some() || args.height.is_some() {
        let c = scene.camera;
        let (w, h) = (
            args.width.unwrap_or(c.width),
            args.height.unwrap_or(c.height),
        );
        scene.camera = scene
            .camera
            .with_size(w, h)
            .map_err(|e| anyhow::anyhow!("--width/--height: {e}"))?;
    }
    check_image_memory(scene.camera.width, scene.camera.height)?;
    if let (Some(shard), Some(partial)) = (args.shard, &args.partial) {
        if args.cache.cache || args.cache.nrc {
            bail!(
                "--shard with --cache or --nrc: a cached render's frames train the cache one after the other, so they cannot be split; shard an experiment's seeds instead"
            );
        }
        return render_shard(&args.scene, &scene, shard, partial, global);
    }
    let exposure = args.exposure.unwrap_or(scene.output.exposure);
    let tonemap = args.tonemap.unwrap_or(scene.output.tonemap);
    let stem = args
        .scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "render".into());
    let exr_path = args
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from("out").join(format!("{stem}.exr")));
    let png_path = args
        .png
        .clone()
        .unwrap_or_else(|| exr_path.with_extension("png"));
    prepare_output(&exr_path)?;
    prepare_output(&png_path)?;
    for dir in [&args.cache.save_cache, &args.cache.cache_images]
        .into_iter()
        .flatten()
    {
        prepare_folder(dir)?;
    }
    if args.cache.nrc
        && (args.cache.save_cache.is_some()
            || args.cache.load_cache.is_some()
            || args.cache.cache_images.is_some())
    {
        bail!(
            "--save-cache, --load-cache and --cache-images are the Gaussian cache's: not with --nrc"
        );
    }
    if !args.cache.cache
        && !args.cache.nrc
        && (args.cache.frames != 1
            || args.cache.warmup != 0
            || args.cache.save_cache.is_some()
            || args.cache.load_cache.is_some()
            || args.cache.cache_images.is_some())
    {
        bail!("--frames, --warmup and the cache's files need a cache: add --cache (or --nrc)");
    }
    if scene.settings.spp == 0 {
        bail!("--spp 0: expected at least 1 sample per pixel");
    }
    if !exposure.is_finite() {
        bail!("exposure {exposure}: expected a finite number of stops");
    }

    let cam = scene.camera;
    let dims = scene.media.medium.grid().dims();
    let maj = scene.media.medium.majorants();
    eprintln!(
        "volume {}x{}x{} ({:.1} MB), {} macrocells of {} voxels ({:.0}% empty), loaded in {:.2} s",
        dims.x,
        dims.y,
        dims.z,
        scene.media.medium.memory_bytes() as f64 / 1e6,
        maj.cell_count(),
        maj.cell_size(),
        100.0 * maj.empty_fraction(),
        load_start.elapsed().as_secs_f64()
    );

    let cancel = cancellation()?;
    let total = scene.settings.spp as u64 * cam.width as u64 * cam.height as u64;
    let bar = global.progress(total, "samples");
    let mut film = Film::new(cam.width, cam.height);
    let stats = if args.cache.nrc {
        bar.set_length(total * args.cache.frames as u64);
        render_with_nrc(&scene, &args.cache, &mut film, &cancel, &bar)?
    } else if !args.cache.cache {
        render(
            &scene.media,
            &cam,
            &scene.settings,
            &mut film,
            &cancel,
            &|n| bar.inc(n),
        )
    } else {
        bar.set_length(total * args.cache.frames as u64);
        render_with_cache(&scene, &args.cache, &mut film, &cancel, &bar)?
    };
    bar.finish_and_clear();

    let image = film.image();
    image.write_exr(&exr_path)?;
    image.write_png(&png_path, exposure, tonemap)?;
    let depth = match scene.settings.path.max_depth {
        Some(d) => format!("max path length {d} scattering vertices"),
        None => "unlimited path length".into(),
    };
    if stats.nonfinite_samples > 0 {
        eprintln!(
            "warning: {} samples were NaN or infinite and were counted as black",
            stats.nonfinite_samples
        );
    }
    let done = if stats.cancelled {
        format!(
            "interrupted after {:.1} of {} spp",
            film.total_samples() as f64 / (cam.width as f64 * cam.height as f64),
            scene.settings.spp
        )
    } else if args.cache.cache {
        format!(
            "{} frames of {} spp with the cache ({:?} lookup)",
            args.cache.frames, scene.settings.spp, args.cache.settings.lookup
        )
    } else if args.cache.nrc {
        format!(
            "{} frames of {} spp with the neural cache",
            args.cache.frames, scene.settings.spp
        )
    } else {
        format!("{} spp", scene.settings.spp)
    };
    println!(
        "rendered {}x{} at {done} ({}, {depth}, seed {}) in {:.2} s: {:.3} M samples/s on {} threads; wrote {} and {}",
        cam.width,
        cam.height,
        scene.settings.path.integrator,
        scene.settings.seed,
        stats.seconds,
        stats.samples_per_second() / 1e6,
        rayon::current_num_threads(),
        exr_path.display(),
        png_path.display()
    );
    Ok(if stats.cancelled { INTERRUPTED } else { 0 })
}

/// Renders one shard of the scene's samples and writes its partial film.
fn render_shard(
    scene_path: &std::path::Path,
    scene: &Scene,
    shard: Shard,
    partial: &std::path::Path,
    global: &Global,
) -> Result<i32> {
    prepare_output(partial)?;
    let key = scene_render_key(scene_path, scene)?.hex();
    let cam = scene.camera;
    let spp = scene.settings.spp;
    let samples = shard.samples(spp);
    let cancel = cancellation()?;
    let bar = global.progress(
        samples.len() as u64 * cam.width as u64 * cam.height as u64,
        "samples",
    );
    let mut film = Film::new(cam.width, cam.height);
    let stats = render_samples(
        &scene.media,
        &cam,
        &scene.settings,
        samples.clone(),
        &mut film,
        &cancel,
        &|n| bar.inc(n),
    );
    bar.finish_and_clear();
    if stats.cancelled {
        eprintln!(
            "interrupted: shard {shard} not written (a partial must hold whole sample ranges); run it again"
        );
        return Ok(INTERRUPTED);
    }
    PartialRender::from_film(&film, &key, spp, samples.clone()).write(partial)?;
    println!(
        "rendered shard {shard} (samples {}..{} of {spp}) of {}x{} in {:.2} s: {:.3} M samples/s; wrote {} (render {key})",
        samples.start,
        samples.end,
        cam.width,
        cam.height,
        stats.seconds,
        stats.samples_per_second() / 1e6,
        partial.display()
    );
    Ok(0)
}

/// Bytes a rendered pixel takes: the film's exact sums and count (52), the f32 image (12) and
/// the PNG's bytes (4), plus slack for the tiles' bookkeeping.
const IMAGE_BYTES_PER_PIXEL: u64 = 80;

/// Refuses an image whose buffers would not fit in the memory available, before any is made.
fn check_image_memory(width: u32, height: u32) -> Result<()> {
    let need = u64::from(width) * u64::from(height) * IMAGE_BYTES_PER_PIXEL;
    let available = volume_pt::io::available_memory();
    if need > available {
        bail!(
            "a {width}x{height} image needs about {} of memory, but {} is available: render a \
             smaller image",
            volume_pt::io::human_bytes(need),
            volume_pt::io::human_bytes(available)
        );
    }
    Ok(())
}

/// Initialises (or loads) the cache, renders the warm-up and the accumulated frames, prints
/// the per-frame costs, and saves the cache when asked.
/// The neural cache's settings from `--nrc-set KEY=VALUE` arguments, read as the keys of an
/// experiment file's `nrc` table (so unknown keys and bad values get the same messages).
fn nrc_config(sets: &[String]) -> Result<NrcConfig> {
    let mut table = toml::Table::new();
    for s in sets {
        let Some((key, value)) = s.split_once('=') else {
            bail!("--nrc-set {s}: expected KEY=VALUE (for example hidden_layers=5)");
        };
        let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {value}"))
            .ok()
            .and_then(|mut t| t.remove("v"))
            .with_context(|| {
                format!("--nrc-set {s}: `{value}` is not a number, true/false or a quoted string")
            })?;
        table.insert(key.trim().to_string(), value);
    }
    let config = NrcConfig::deserialize(toml::Value::Table(table))
        .map_err(|e| anyhow::anyhow!("--nrc-set: {e}"))?;
    config.validate()?;
    Ok(config)
}

/// `--nrc`: warm-up frames (along the orbit) and then `--frames` frames with the neural cache.
fn render_with_nrc(
    scene: &Scene,
    a: &CacheRun,
    film: &mut Film,
    cancel: &AtomicBool,
    bar: &ProgressBar,
) -> Result<RenderStats> {
    // The experiment runner's construction, so its "one frame of it" commands reproduce it.
    let (mut cache, _) = new_nrc(nrc_config(&a.nrc_set)?, scene.settings.seed)?;
    eprintln!(
        "neural cache: {} levels of 2^{} entries, {} hidden layers of {} ({:.1} MB of parameters and optimiser state)",
        cache.config().grid_levels,
        cache.config().grid_log2_table,
        cache.config().hidden_layers,
        cache.config().hidden_width,
        cache.parameter_bytes() as f64 / 1e6
    );
    cached_frames(
        scene,
        a,
        film,
        cancel,
        bar,
        "inference and composition",
        |camera, f, film| {
            let s = render_nrc_frame(
                &scene.media,
                camera,
                &scene.settings,
                f,
                film,
                &mut cache,
                cancel,
            );
            Ok(FrameCosts {
                samples: s.samples,
                seconds: [s.trace_seconds, s.inference_seconds, s.train_seconds],
                nonfinite_samples: s.nonfinite_samples,
            })
        },
    )
}

/// One cached frame's figures, for [`cached_frames`].
struct FrameCosts {
    samples: u64,
    /// Path tracing, reading the cache, training.
    seconds: [f64; 3],
    nonfinite_samples: u64,
}

/// The frames of a cached render, for either cache: `--warmup` frames along the warm-up orbit
/// (none in the image), then `--frames` frames at the scene camera accumulated into `film`;
/// prints the mean per-frame costs, `read` naming the cache's read. `frame(camera, index,
/// film)` renders and trains one frame.
fn cached_frames(
    scene: &Scene,
    a: &CacheRun,
    film: &mut Film,
    cancel: &AtomicBool,
    bar: &ProgressBar,
    read: &str,
    mut frame: impl FnMut(&splat_raster::Camera, u32, Option<&mut Film>) -> Result<FrameCosts>,
) -> Result<RenderStats> {
    let start = std::time::Instant::now();
    let (mut sums, mut samples, mut nonfinite) = ([0.0f64; 3], 0u64, 0u64);
    let mut counted = 0u32;
    let (lo, hi) = scene.media.medium.bounds();
    let centre = 0.5 * (lo + hi);
    for f in 0..a.warmup + a.frames {
        if cancel.load(Ordering::Relaxed) {
            break;
        }
        let accumulate = f >= a.warmup;
        let camera = if accumulate || a.warmup_orbit == 0.0 {
            scene.camera
        } else {
            orbit(&scene.camera, centre, a.warmup_orbit, f, a.warmup + 1)
        };
        let s = frame(&camera, f, accumulate.then_some(&mut *film))?;
        nonfinite += s.nonfinite_samples;
        if accumulate {
            bar.inc(s.samples);
            samples += s.samples;
            for (sum, x) in sums.iter_mut().zip(s.seconds) {
                *sum += x;
            }
            counted += 1;
        }
    }
    if counted > 0 {
        let n = counted as f64 * 1e-3;
        eprintln!(
            "per frame: path tracing {:.1} ms, {read} {:.1} ms, training {:.1} ms",
            sums[0] / n,
            sums[1] / n,
            sums[2] / n
        );
    }
    Ok(RenderStats {
        samples,
        seconds: start.elapsed().as_secs_f64(),
        cancelled: cancel.load(Ordering::Relaxed),
        nonfinite_samples: nonfinite,
    })
}

fn render_with_cache(
    scene: &Scene,
    a: &CacheRun,
    film: &mut Film,
    cancel: &AtomicBool,
    bar: &ProgressBar,
) -> Result<RenderStats> {
    let config = a
        .settings
        .for_image(scene.camera.width, scene.camera.height);
    config.validate()?;
    let t0 = std::time::Instant::now();
    let mut cache = match &a.load_cache {
        Some(dir) => GsCache::load(dir, config)?,
        None => {
            let (points, albedo) =
                sample_cache_points(&scene.media.medium, config.points, scene.settings.seed);
            if points.len() < config.points {
                bail!(
                    "{}: only {} of {} cache points found: the transfer function leaves the volume almost empty",
                    scene.volume_path.display(),
                    points.len(),
                    config.points
                );
            }
            GsCache::new(&points, &albedo, config)?
        }
    };
    eprintln!(
        "cache: {} Gaussians in {} levels ({:.1} MB of parameters), {} in {:.0} ms",
        cache.gaussian_count(),
        cache.levels().len(),
        cache.parameter_bytes() as f64 / 1e6,
        if a.load_cache.is_some() {
            "loaded"
        } else {
            "initialised"
        },
        t0.elapsed().as_secs_f64() * 1e3
    );
    let mut dropped = 0u64;
    let stats = cached_frames(
        scene,
        a,
        film,
        cancel,
        bar,
        "cache lookup",
        |camera, f, film| {
            if f == a.warmup {
                cache.start_image();
            }
            let s = render_cached_frame(
                &scene.media,
                camera,
                &scene.settings,
                f,
                film,
                &mut cache,
                cancel,
            )?;
            dropped += s.dropped_training_samples;
            Ok(FrameCosts {
                samples: s.samples,
                seconds: [s.trace_seconds, s.lookup_seconds, s.train_seconds],
                nonfinite_samples: s.nonfinite_samples,
            })
        },
    )?;
    if dropped > 0 {
        eprintln!(
            "warning: the cache refused {dropped} training samples that were negative or not finite"
        );
    }
    if let Some(dir) = &a.cache_images {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create folder", dir.display()))?;
        let cam = scene.camera;
        let frame = cache.begin_frame(&cam);
        for level in 0..frame.levels() {
            let img = RgbImage::from_rgb(cam.width, cam.height, frame.image(level))?;
            let stem = dir.join(format!("length_{}", level + 1));
            img.write_exr(&stem.with_extension("exr"))?;
            img.write_png(&stem.with_extension("png"), 0.0, ToneMap::Aces)?;
        }
        eprintln!("cache: wrote the level images to {}", dir.display());
    }
    if let Some(dir) = &a.save_cache {
        cache.save(dir)?;
        eprintln!(
            "cache: wrote {} levels to {}",
            cache.levels().len(),
            dir.display()
        );
    }
    Ok(stats)
}
