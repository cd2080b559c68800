//! `gscache render SCENE.toml`: path-trace a volume scene to EXR and PNG, optionally reading
//! and training the GSCache radiance cache.

use crate::cache_flags::CacheFlags;
use crate::common::{
    Global, INTERRUPTED, cancellation, finite_f32, prepare_folder, prepare_output,
};
use crate::denoising::{DenoiseArgs, write_denoised, write_image};
use anyhow::{Context, Result, bail};
use hdr_image::ToneMap;
use render_session::{Cache, CacheChoice, Control, FrameReport, Session};
use std::path::PathBuf;
use volume_pt::scene::scene_render_key;
use volume_pt::{Film, PartialRender, RenderStats, Scene, Shard, render_samples};

/// Path-trace a scientific volume through its transfer function (see docs/scene-format.md).
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct RenderArgs {
    /// Scene file (TOML), or a volume file (NIfTI, NRRD, VTK/VTI, raw) to render with a scene
    /// chosen for it: a transfer function from its histogram, a framing camera, a key light.
    scene: PathBuf,
    /// With a volume file: the colour map of the chosen transfer function.
    #[arg(long, value_enum)]
    colormap: Option<volume_pt::Colormap>,
    /// With a volume file: write the scene chosen for it as TOML here, to edit and render.
    #[arg(long)]
    save_scene: Option<PathBuf>,
    /// What the command line changes of the scene.
    #[command(flatten)]
    overrides: volume_pt::SceneOverrides,
    /// Linear EXR output (default: out/SCENE.exr, out/SCENE.cache.exr with --cache,
    /// out/SCENE.nrc.exr with --nrc). `-o NAME.png` names the PNG and puts the EXR beside it
    /// as NAME.exr.
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
    /// Keep feature buffers (albedo, normal, depth, coverage at each path's first scattering
    /// event, over the image's samples) and write them as layers of the EXR: albedo.R/G/B,
    /// N.X/N.Y/N.Z, Z and coverage.A. With --shard, the partial carries them.
    #[arg(long)]
    features: bool,
    #[command(flatten)]
    denoise: DenoiseArgs,
    #[command(flatten)]
    cache: CacheRun,
}

fn parse_shard(s: &str) -> std::result::Result<Shard, String> {
    Shard::parse(s).map_err(|e| e.to_string())
}

/// A cached render's frames, warm-up and files; the cache itself is [`CacheFlags`].
#[derive(clap::Args, Debug)]
pub struct CacheRun {
    #[command(flatten)]
    flags: CacheFlags,
    /// Frames of `--spp` samples each, trained between them; the image is their mean.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    frames: u32,
    /// Frames rendered and trained on before the image starts accumulating.
    #[arg(long, default_value_t = 0)]
    warmup: u32,
    /// Degrees of orbit about the volume's centre over the warm-up frames, ending at the
    /// scene's camera (the experiment runner's warm-up); 0 keeps the camera still.
    /// (`--warmup-orbit-degrees`, the experiment files' `warmup_orbit_degrees`; `--warmup-orbit`
    /// is kept as an alias.)
    #[arg(long, alias = "warmup-orbit", value_name = "DEG", default_value_t = 0.0, allow_negative_numbers = true, value_parser = finite_f32)]
    warmup_orbit_degrees: f32,
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
    let scene = load_scene_for_render(&args, global)?;
    // The one place the flags become a cache: everything after asks the choice.
    let choice = args.cache.choice(args.denoise.denoise)?;
    if let (Some(shard), Some(partial)) = (args.shard, &args.partial) {
        if !choice.is_none() {
            bail!(
                "--shard with --cache or --nrc: a cached render's frames train the cache one after the other, so they cannot be split; shard an experiment's seeds instead"
            );
        }
        if args.denoise.denoise {
            bail!(
                "--shard with --denoise: a shard holds part of every pixel's samples; denoise the merged image (`gscache merge --denoise`, with the shards rendered with --features)"
            );
        }
        return render_shard(&args.scene, &scene, shard, partial, args.features, global);
    }
    let exposure = args.exposure.unwrap_or(scene.output.exposure);
    let tonemap = args.tonemap.unwrap_or(scene.output.tonemap);
    let (exr_path, png_path) = output_paths(&args, &choice);
    prepare_output(&exr_path)?;
    prepare_output(&png_path)?;
    // Loaded before any work: a missing library is said now, not after the render.
    let mut denoiser = args.denoise.load()?;
    for dir in [&args.cache.save_cache, &args.cache.cache_images]
        .into_iter()
        .flatten()
    {
        prepare_folder(dir)?;
    }
    check_cache_flags(&args.cache, &choice)?;
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

    let frames = if choice.is_none() {
        1
    } else {
        args.cache.frames
    };
    let spp = scene.settings.spp;
    let mut session =
        Session::new(scene, choice)?.with_features(args.features || args.denoise.needs_features());
    describe_cache(&session, args.cache.load_cache.is_some());
    if let (Some(dir), Cache::Gaussian(c)) = (&args.cache.load_cache, session.cache())
        && c.levels().len() != args.cache.flags.settings.levels
    {
        // The saved folder's manifest fixes the levels; a differing --cache-levels (or its
        // default) is said, not silently overridden.
        eprintln!(
            "note: {} holds {} levels (its manifest): the loaded cache has those, not the {} of --cache-levels",
            dir.display(),
            c.levels().len(),
            args.cache.flags.settings.levels
        );
    }
    // Frame counts from the user are checked before any work: they cannot wrap.
    let all_frames = args.cache.warmup.checked_add(frames).with_context(|| {
        format!(
            "--warmup {} and --frames {frames}: more than 2^32 frames in all",
            args.cache.warmup
        )
    })?;
    session.check_frames(all_frames)?;

    let cancel = cancellation()?;
    // The bar counts the warm-up's samples too: it once sat at 0% through the warm-up.
    let total = spp as u64 * cam.width as u64 * cam.height as u64 * all_frames as u64;
    let bar = global.progress(total, "samples");
    let report_progress = |n| bar.inc(n);
    // An interrupted render is kept: every pixel gets its first sample before it may stop.
    let control = Control::new(&cancel, &report_progress).keeping_every_pixel();
    let start = std::time::Instant::now();
    let warm = session.warm_up(args.cache.warmup, args.cache.warmup_orbit_degrees, &control)?;
    let mut accumulated = Vec::with_capacity(frames as usize);
    for _ in 0..frames {
        if control.cancelled() {
            break;
        }
        accumulated.push(session.next_frame(&control)?);
    }
    bar.finish_and_clear();
    let stats = RenderStats {
        samples: session.film().total_samples(),
        seconds: start.elapsed().as_secs_f64(),
        cancelled: control.cancelled(),
        nonfinite_samples: warm
            .iter()
            .chain(&accumulated)
            .map(|r| r.nonfinite_samples)
            .sum(),
    };
    print_frame_costs(&session, "per warm-up frame", &warm);
    print_frame_costs(&session, "per frame", &accumulated);
    print_grown_cache(&session);
    print_control_summary(&session);
    let dropped: u64 = warm
        .iter()
        .chain(&accumulated)
        .map(|r| r.dropped_training_samples)
        .sum();
    if dropped > 0 {
        eprintln!(
            "warning: the cache refused {dropped} training samples that were negative or not finite"
        );
    }
    if session.film().total_samples() == 0 {
        // Interrupted before the first frame reached the image (during the warm-up, say): an
        // empty film would be a black image written over whatever the output held.
        eprintln!(
            "interrupted before any frame reached the image: nothing written ({} left as it was)",
            exr_path.display()
        );
        return Ok(INTERRUPTED);
    }
    write_outputs(
        &mut session,
        &args,
        denoiser.as_mut(),
        &exr_path,
        &png_path,
        (exposure, tonemap),
    )?;
    print_summary(&session, &stats, frames, &exr_path, &png_path);
    Ok(if stats.cancelled { INTERRUPTED } else { 0 })
}

/// The scene `args` name with its overrides: a scene file, or a bare volume's automatic scene
/// (printed, or saved with `--save-scene`); its notes are printed and its image's memory
/// checked.
fn load_scene_for_render(args: &RenderArgs, global: &Global) -> Result<Scene> {
    let from_volume = !volume_pt::scene::is_scene_file(&args.scene);
    if !from_volume && (args.colormap.is_some() || args.save_scene.is_some()) {
        bail!(
            "--colormap and --save-scene are for a volume file: {} is a scene already (edit its [transfer] table)",
            args.scene.display()
        );
    }
    if from_volume && args.shard.is_some() {
        bail!(
            "--shard needs a scene file (its text keys the shards): write one with --save-scene and render that"
        );
    }
    if let Some(path) = &args.save_scene {
        // The scene must not replace the volume it describes (a slip of the tab key).
        let target = path.canonicalize().ok();
        if target.is_some() && target == args.scene.canonicalize().ok() {
            bail!(
                "--save-scene {}: that is the volume being rendered; name a new .toml file",
                path.display()
            );
        }
        prepare_output(path)?;
    }
    let opened = volume_pt::open_scene(&args.scene, args.colormap.unwrap_or_default())?;
    if opened.automatic {
        let text = &opened.text;
        match &args.save_scene {
            Some(path) => {
                render_base::write_atomically(path, |f| {
                    std::io::Write::write_all(f, text.as_bytes()).map_err(|e| e.to_string())
                })?;
                eprintln!(
                    "the scene chosen for {} is in {}",
                    args.scene.display(),
                    path.display()
                );
            }
            None if !global.quiet => eprintln!(
                "the scene chosen for {} (--save-scene FILE writes it for editing):\n{text}",
                args.scene.display()
            ),
            None => {}
        }
    }
    finish_scene(
        opened.scene,
        &args.overrides,
        args.features || args.denoise.needs_features(),
    )
}

/// A loaded scene made ready to render: its notes printed, the command line's overrides
/// applied, its image's memory (with feature buffers if `features`) checked.
pub fn finish_scene(
    mut scene: Scene,
    overrides: &volume_pt::SceneOverrides,
    features: bool,
) -> Result<Scene> {
    for n in &scene.notes {
        let (kind, text) = n
            .strip_prefix("warning: ")
            .map_or(("note", n.as_str()), |w| ("warning", w));
        eprintln!("{kind}: {}: {text}", scene.volume_path.display());
    }
    overrides.apply(&mut scene)?;
    check_image_memory(scene.camera.width, scene.camera.height, features)?;
    Ok(scene)
}

/// The cache flags that make sense only together: refused before any work.
fn check_cache_flags(cache: &CacheRun, choice: &CacheChoice) -> Result<()> {
    if matches!(choice, CacheChoice::Neural(_))
        && (cache.save_cache.is_some()
            || cache.load_cache.is_some()
            || cache.cache_images.is_some())
    {
        bail!(
            "--save-cache, --load-cache and --cache-images are the Gaussian cache's: not with --nrc"
        );
    }
    if choice.is_none()
        && (cache.frames != 1
            || cache.warmup != 0
            || cache.save_cache.is_some()
            || cache.load_cache.is_some()
            || cache.cache_images.is_some())
    {
        bail!("--frames, --warmup and the cache's files need a cache: add --cache (or --nrc)");
    }
    Ok(())
}

/// The EXR and PNG a render writes: `-o` and `--png`, else `out/NAME[.cache|.nrc].exr`.
fn output_paths(args: &RenderArgs, choice: &CacheChoice) -> (PathBuf, PathBuf) {
    // The name up to its first dot: `neghip.nii.gz` renders to out/neghip.exr.
    let stem = args
        .scene
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .and_then(|n| n.split('.').next().map(str::to_string))
        .filter(|n| !n.is_empty())
        .unwrap_or_else(|| "render".into());
    // Cached renders are named apart from the plain one, so that neither overwrites the other.
    let method = match choice {
        CacheChoice::None => "",
        CacheChoice::Gaussian { .. } => ".cache",
        CacheChoice::Neural(_) => ".nrc",
    };
    crate::common::output_paths(
        args.output.as_deref(),
        args.png.as_deref(),
        &PathBuf::from("out").join(format!("{stem}{method}.exr")),
    )
}

/// Writes what the render made: the image (first: a cache that cannot be saved must not cost
/// it), its denoised twin, the cache's level images and the cache itself.
fn write_outputs(
    session: &mut Session,
    args: &RenderArgs,
    denoiser: Option<&mut denoise::Denoiser>,
    exr_path: &std::path::Path,
    png_path: &std::path::Path,
    (exposure, tonemap): (f32, ToneMap),
) -> Result<()> {
    // The image first: it is what the user waited for, and a cache that cannot be saved (a
    // full disk) must not cost it.
    let image = session.image();
    let features = session.feature_images();
    let layers = features.as_ref().filter(|_| args.features);
    write_image(&image, layers, exr_path, png_path, exposure, tonemap)?;
    if let Some(denoiser) = denoiser {
        let (path, seconds) = write_denoised(
            denoiser,
            &args.denoise,
            &image,
            features.as_ref(),
            exr_path,
            exposure,
            tonemap,
        )?;
        eprintln!(
            "denoised ({} quality, guided by {}) in {:.0} ms: wrote {} and its PNG",
            args.denoise.denoise_quality,
            args.denoise.denoise_guides,
            seconds * 1e3,
            path.display()
        );
    }
    if let Some(dir) = &args.cache.cache_images
        && let Some(levels) = session.level_images()
    {
        for (level, img) in levels?.iter().enumerate() {
            let stem = dir.join(format!("length_{}", level + 1));
            img.write_exr(&stem.with_extension("exr"))?;
            img.write_png(&stem.with_extension("png"), 0.0, ToneMap::Aces)?;
        }
        eprintln!("cache: wrote the level images to {}", dir.display());
    }
    if let Some(dir) = &args.cache.save_cache {
        let levels = session.save_cache(dir)?;
        eprintln!("cache: wrote {levels} levels to {}", dir.display());
    }
    Ok(())
}

/// The render's last line (what was rendered, how, how fast, where it went) and its warnings.
fn print_summary(
    session: &Session,
    stats: &RenderStats,
    frames: u32,
    exr_path: &std::path::Path,
    png_path: &std::path::Path,
) {
    let scene = session.scene();
    let film = session.film();
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
    let (w, h) = (scene.camera.width, scene.camera.height);
    let done = if stats.cancelled {
        let counts = film.counts();
        let (fewest, most) = counts
            .iter()
            .fold((u32::MAX, 0), |(lo, hi), &c| (lo.min(c), hi.max(c)));
        format!(
            "interrupted after {:.1} of {} spp: kept {w}x{h}, each pixel the mean of its own {fewest} to {most} samples",
            film.total_samples() as f64 / (w as f64 * h as f64),
            scene.settings.spp as u64 * frames as u64
        )
    } else {
        match session.cache_choice() {
            CacheChoice::Gaussian { config, .. } => format!(
                "rendered {w}x{h} at {frames} frames of {} spp with the cache ({} lookup)",
                scene.settings.spp,
                format!("{:?}", config.lookup).to_lowercase()
            ),
            CacheChoice::Neural(_) => format!(
                "rendered {w}x{h} at {frames} frames of {} spp with the neural cache",
                scene.settings.spp
            ),
            CacheChoice::None => format!("rendered {w}x{h} at {} spp", scene.settings.spp),
        }
    };
    println!(
        "{done} ({}, {depth}, seed {}) in {:.2} s: {:.3} M samples/s on {} threads; wrote {} and {}",
        scene.settings.path.integrator,
        scene.settings.seed,
        stats.seconds,
        stats.samples_per_second() / 1e6,
        rayon::current_num_threads(),
        exr_path.display(),
        png_path.display()
    );
}

/// Renders one shard of the scene's samples and writes its partial film.
fn render_shard(
    scene_path: &std::path::Path,
    scene: &Scene,
    shard: Shard,
    partial: &std::path::Path,
    features: bool,
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
    let mut film = if features {
        Film::with_features(cam.width, cam.height)
    } else {
        Film::new(cam.width, cam.height)
    };
    let stats = render_samples(
        &scene.media,
        &cam,
        &scene.settings,
        samples.clone(),
        &mut film,
        &Control::new(&cancel, &|n| bar.inc(n)),
    );
    bar.finish_and_clear();
    scene.media.medium.grid().check_streaming()?;
    if stats.cancelled {
        eprintln!(
            "interrupted: shard {shard} not written (a partial must hold whole sample ranges); run it again"
        );
        return Ok(INTERRUPTED);
    }
    PartialRender::from_film(&film, &key, spp, samples.clone())
        .with_output(scene.output.exposure, scene.output.tonemap)
        .write(partial)?;
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
/// Bytes the feature buffers add: the film's exact sums (68), the f32 images (32) and the
/// denoiser's copies (36), with slack.
const FEATURE_BYTES_PER_PIXEL: u64 = 150;

/// Refuses an image whose buffers would not fit in the memory available, before any is made.
fn check_image_memory(width: u32, height: u32, features: bool) -> Result<()> {
    let per_pixel = IMAGE_BYTES_PER_PIXEL + if features { FEATURE_BYTES_PER_PIXEL } else { 0 };
    let need = u64::from(width) * u64::from(height) * per_pixel;
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

impl RenderArgs {
    /// Notes which cache settings the command line named ([`CacheFlags::note_named`]).
    pub fn note_named(&mut self, matches: &clap::ArgMatches) {
        self.cache.flags.note_named(matches);
    }
}

impl CacheRun {
    /// The cache these flags ask for.
    fn choice(&self, denoised: bool) -> Result<CacheChoice> {
        self.flags.choice(self.load_cache.clone(), denoised)
    }
}

/// Prints what the session's cache is and what it took to build.
fn describe_cache(session: &Session, loaded: bool) {
    let ms = session.cache_seconds() * 1e3;
    match session.cache() {
        Cache::None => {}
        Cache::Gaussian(c) => eprintln!(
            "cache: {} Gaussians in {} levels ({:.1} MB of parameters), {} in {ms:.0} ms",
            c.gaussian_count(),
            c.levels().len(),
            c.parameter_bytes() as f64 / 1e6,
            if loaded { "loaded" } else { "initialised" },
        ),
        Cache::Neural(c) => {
            let c = c.cache();
            eprintln!(
                "neural cache: {} levels of 2^{} entries, {} hidden layers of {} ({:.1} MB of parameters and optimiser state)",
                c.config().grid_levels,
                c.config().grid_log2_table,
                c.config().hidden_layers,
                c.config().hidden_width,
                c.parameter_bytes() as f64 / 1e6
            )
        }
    }
}

/// With adaptive density on, prints what the levels grew to (each level's Gaussians).
fn print_grown_cache(session: &Session) {
    if let Cache::Gaussian(c) = session.cache()
        && c.config().densify_every > 0
    {
        let sizes: Vec<String> = c
            .levels()
            .iter()
            .map(|l| l.cloud.len().to_string())
            .collect();
        eprintln!(
            "cache after adaptive density: {} Gaussians ({} per level)",
            c.gaussian_count(),
            sizes.join(" / ")
        );
    }
}

/// Prints a cached render's mean per-frame costs over `frames` (`what`: which frames): every
/// part of the frame's wall time, the remainder ("other", the session's bookkeeping) included.
fn print_frame_costs(session: &Session, what: &str, frames: &[FrameReport]) {
    let (read, beside) = match session.cache() {
        Cache::None => return,
        Cache::Gaussian(_) => ("cache lookup", "cache lookup"),
        // The previous frame's step runs beside this frame's path tracing.
        Cache::Neural(_) => ("inference and composition", "path tracing"),
    };
    if frames.is_empty() {
        return;
    }
    let n = frames.len() as f64 * 1e-3;
    let mean = |f: &dyn Fn(&FrameReport) -> f64| frames.iter().map(f).sum::<f64>() / n;
    let mut parts = vec![
        ("path tracing", mean(&|r| r.trace_seconds)),
        (read, mean(&|r| r.lookup_seconds)),
        ("gathering targets", mean(&|r| r.targets_seconds)),
        ("training", mean(&|r| r.train_seconds)),
        ("scratch film", mean(&|r| r.film_seconds)),
    ];
    // The neural cache gathers inside its training; a frame that keeps its film makes none.
    parts.retain(|&(name, ms)| ms > 0.0 || name == "training");
    parts.push(("other", mean(&|r| r.other_seconds())));
    let parts: Vec<String> = parts
        .iter()
        .map(|(name, ms)| format!("{name} {} ms", milliseconds(*ms)))
        .collect();
    let step = mean(&|r| r.train_step_seconds);
    let beside = if step > mean(&|r| r.train_seconds) + 0.05 {
        format!(" (the training step, {step:.1} ms, runs beside the {beside})")
    } else {
        String::new()
    };
    eprintln!(
        "{what}: {:.1} ms = {}{beside}",
        mean(&|r| r.seconds),
        parts.join(" + ")
    );
}

/// A part of a frame's time in milliseconds to three significant figures at most (a
/// lookup at a small size takes well under a millisecond; one decimal hid its changes).
fn milliseconds(ms: f64) -> String {
    match ms {
        ms if ms < 1.0 => format!("{ms:.3}"),
        ms if ms < 10.0 => format!("{ms:.2}"),
        ms => format!("{ms:.1}"),
    }
}

/// Prints the unbiased cache's choice of continuation per level and the bound on its gain.
fn print_control_summary(session: &Session) {
    if let Cache::Gaussian(c) = session.cache() {
        for (l, s) in c.control_summary().iter().enumerate() {
            eprintln!(
                "unbiased cache, level {}: mean q {:.2}; the tail holds {:.0}% of the variance and {:.0}% of the work: no q can gain more than {:.2}x over plain path tracing",
                l + 1,
                s.mean_q,
                100.0 * s.variance_share,
                100.0 * s.cost_share,
                s.best_gain
            );
        }
    }
}
