//! `bench cache`: the GSCache paper's Table 2 on this machine, and image quality at equal spp and
//! at equal time. Every volume is rendered along a camera orbit (`warmup + frames` frames ending at
//! the scene's own camera) by `uniform`, `nee`, and `nee` with the cache (raster and ray-traced
//! lookups); per-frame times are averaged over the frames after the warm-up, and the last frame (1
//! spp, at the scene camera) is compared with a high-spp `nee` reference made once and kept on
//! disk.

use crate::bench::DataDirs;
use anyhow::Result;
pub use experiments::camera_path::orbit;
use glam::Vec3;
use gs_cache::{CacheConfig, Lookup};
use image_metrics::{hdr_peak, psnr, rel_mse};
use render_session::{Accumulation, CacheChoice, Control, Edit, Session};
use std::path::{Path, PathBuf};
use volume_pt::{IntegratorKind, Scene, load_scene};

#[derive(clap::Args, Debug, Clone)]
pub struct CacheBenchArgs {
    #[command(flatten)]
    pub data: crate::bench::DataArg,
    /// Scene files (default: every scene in data/scenes; those reading ../shared/data are
    /// skipped with a note when it is absent).
    pub scenes: Vec<PathBuf>,
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Frames measured after the warm-up.
    #[arg(long, default_value_t = 200)]
    pub frames: u32,
    #[arg(long, default_value_t = 40)]
    pub warmup: u32,
    /// Degrees the camera orbits (about its up axis through the volume's centre) over the run.
    #[arg(long, default_value_t = 60.0, value_parser = crate::common::finite_f32)]
    pub orbit_degrees: f32,
    /// The cache's settings (`--cache-KEY`, as for `gscache render`); its lookup is measured
    /// both ways unless `--no-rt`.
    #[command(flatten)]
    pub cache: CacheConfig,
    /// Samples per pixel of the `nee` reference.
    #[arg(long, default_value_t = 256)]
    pub reference_spp: u32,
    /// Where references are kept between runs.
    #[arg(long, default_value = "target/experiment-references")]
    pub references: PathBuf,
    /// Skip the ray-traced lookup.
    #[arg(long)]
    pub no_rt: bool,
}

/// The scenes measured by default: every volume the project renders.
pub fn default_scenes(data: &DataDirs) -> Vec<PathBuf> {
    [
        "default", "ironprot", "hydrogen", "headsq", "chest_ct", "embryo",
    ]
    .iter()
    .map(|s| data.scene(s))
    .collect()
}

/// Loads a scene at the benchmark's image size, or `None` (with a note) when it reads from an
/// absent `../shared/data`.
pub fn load_sized(path: &Path, width: u32, height: u32) -> Result<Option<(String, Scene)>> {
    let mut scene = match load_scene(path) {
        Ok(s) => s,
        Err(e) if e.to_string().contains("shared/data") => {
            eprintln!(
                "note: skipping {}: {e} (../shared/data is absent)",
                path.display()
            );
            return Ok(None);
        }
        Err(e) => return Err(e.into()),
    };
    scene.camera = scene.camera.with_size(width, height)?;
    let name = path.file_stem().unwrap().to_string_lossy().into_owned();
    Ok(Some((name, scene)))
}

/// A plain `kind` render of `spp` samples per pixel at the scene camera: the image and the
/// seconds it took.
fn plain(scene: &Scene, kind: IntegratorKind, spp: u32) -> Result<(Vec<Vec3>, f64)> {
    let mut scene = scene.clone();
    scene.settings.spp = spp;
    scene.settings.path.integrator = kind;
    let mut session = Session::new(scene, CacheChoice::None)?;
    let r = session.next_frame(&Control::none())?;
    Ok((session.mean(), r.seconds))
}

/// The high-spp `nee` reference at the scene camera: the experiment runner's, kept on disk under
/// the same key (scene file, volume file, camera, size, spp), so either program reuses the
/// other's.
fn reference(path: &Path, scene: &Scene, args: &CacheBenchArgs) -> Result<Vec<Vec3>> {
    let name = path.file_stem().unwrap().to_string_lossy();
    let r = experiments::reference::reference(
        &args.references,
        path,
        "",
        scene,
        &scene.camera,
        args.reference_spp,
        Some(&|line: &str| eprintln!("{name}: {line}")),
    )?;
    if r.reused {
        eprintln!("{name}: reference {}", r.file.display());
    } else {
        eprintln!(
            "{name}: rendered the reference ({} spp) in {:.1} s: {}",
            r.spp,
            r.seconds,
            r.file.display()
        );
    }
    Ok(r.image)
}

/// Mean per-frame times (ms) of a fly-through and its last frame.
struct Run {
    pt: f64,
    st: f64,
    ot: f64,
    image: Vec<Vec3>,
    nonfinite: u64,
}

impl Run {
    fn total(&self) -> f64 {
        self.pt + self.st + self.ot
    }
}

/// `warmup + frames` frames of 1 spp along the orbit with `kind` and `cache`, each an image of
/// its own; the times are means over the frames after the warm-up, the image the last frame's
/// (at the scene camera). Returns the run and the cache's size and build time.
fn fly(
    scene: &Scene,
    kind: IntegratorKind,
    cache: CacheChoice,
    args: &CacheBenchArgs,
) -> Result<(Run, usize, f64)> {
    let mut scene = scene.clone();
    scene.settings.spp = 1;
    scene.settings.path.integrator = kind;
    let camera = scene.camera;
    let (lo, hi) = scene.media.medium.bounds();
    let centre = 0.5 * (lo + hi);
    let mut session = Session::new(scene, cache)?.with_accumulation(Accumulation::PerFrame);
    let total = args.warmup + args.frames;
    session.check_frames(total)?;
    let (mut pt, mut st, mut ot, mut nonfinite) = (0.0, 0.0, 0.0, 0);
    for f in 0..total {
        session.edit(Edit::Camera(orbit(
            &camera,
            centre,
            args.orbit_degrees,
            f,
            total,
        )))?;
        let r = session.next_frame(&Control::none())?;
        nonfinite += r.nonfinite_samples;
        if f >= args.warmup {
            pt += r.trace_seconds;
            st += r.lookup_seconds;
            ot += r.train_seconds;
        }
    }
    let n = args.frames.max(1) as f64 / 1e3;
    let run = Run {
        pt: pt / n,
        st: st / n,
        ot: ot / n,
        image: session.mean(),
        nonfinite,
    };
    Ok((
        run,
        session.cache().parameter_bytes(),
        session.cache_seconds(),
    ))
}

pub fn run(args: &CacheBenchArgs, data: &DataDirs) -> Result<()> {
    let scenes = if args.scenes.is_empty() {
        default_scenes(data)
    } else {
        args.scenes.clone()
    };
    println!(
        "threads {}, {}x{}, 1 spp per frame, {} frames after {} warm-up on a {}-degree orbit ending at the scene camera; cache N = {}, C = {}, learning rates x {}\n",
        rayon::current_num_threads(),
        args.width,
        args.height,
        args.frames,
        args.warmup,
        args.orbit_degrees,
        args.cache.points,
        args.cache.c,
        args.cache.lr_multiplier
    );
    let mut table2 = vec![
        "| volume | uniform PT | nee PT | nee + cache PT | ST (raster) | OT | (ST + OT) / PT | ST (rt) | OT (rt) | cache MB (+ AdamW moments) | init ms |".to_string(),
        "|---|---|---|---|---|---|---|---|---|---|---|".to_string(),
    ];
    let mut quality = vec![
        "| volume | method | spp | ms per frame | relMSE | PSNR (dB) | nee relMSE at equal time / this |".to_string(),
        "|---|---|---|---|---|---|---|".to_string(),
    ];
    for path in &scenes {
        let Some((name, scene)) = load_sized(path, args.width, args.height)? else {
            continue;
        };
        let reference = reference(path, &scene, args)?;
        let peak = hdr_peak(&reference);
        let (uniform, ..) = fly(&scene, IntegratorKind::Uniform, CacheChoice::None, args)?;
        let (nee, ..) = fly(&scene, IntegratorKind::Nee, CacheChoice::None, args)?;
        let with_lookup = |lookup| {
            CacheChoice::gaussian(CacheConfig {
                lookup,
                ..args.cache
            })
        };
        let (raster, bytes, init) = fly(
            &scene,
            IntegratorKind::Nee,
            with_lookup(Lookup::Raster),
            args,
        )?;
        let mb = bytes as f64 / 1e6;
        let rt = if args.no_rt {
            None
        } else {
            Some(fly(&scene, IntegratorKind::Nee, with_lookup(Lookup::Rt), args)?.0)
        };
        let fmt_opt = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.1}"));
        table2.push(format!(
            "| {name} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.2}x | {} | {} | {mb:.1} ({:.1}) | {:.0} |",
            uniform.pt,
            nee.pt,
            raster.pt,
            raster.st,
            raster.ot,
            (raster.st + raster.ot) / raster.pt,
            fmt_opt(rt.as_ref().map(|r| r.st)),
            fmt_opt(rt.as_ref().map(|r| r.ot)),
            3.0 * mb,
            init * 1e3
        ));
        // Equal time: nee with as many spp as fit in a cached frame's time.
        let nee_at_time = |time_ms: f64| -> Result<(u32, f64, Vec<Vec3>)> {
            let spp = ((time_ms / nee.pt).round() as u32).max(1);
            let (img, secs) = plain(&scene, IntegratorKind::Nee, spp)?;
            Ok((spp, secs * 1e3, img))
        };
        let row = |method: &str, spp: u32, ms: f64, img: &[Vec3], nee_equal: Option<f64>| {
            let e = rel_mse(img, &reference);
            format!(
                "| {name} | {method} | {spp} | {ms:.1} | {e:.4} | {:.2} | {} |",
                psnr(img, &reference, peak),
                nee_equal.map_or(String::new(), |n| format!("{:.2}x", n / e))
            )
        };
        quality.push(row("uniform", 1, uniform.pt, &uniform.image, None));
        quality.push(row("nee", 1, nee.pt, &nee.image, None));
        for (label, run) in [
            ("nee + cache (raster)", Some(&raster)),
            ("nee + cache (rt)", rt.as_ref()),
        ] {
            let Some(run) = run else { continue };
            let (spp, ms, img) = nee_at_time(run.total())?;
            let e_equal = rel_mse(&img, &reference);
            quality.push(row(label, 1, run.total(), &run.image, Some(e_equal)));
            quality.push(row(
                &format!("nee at the time of {label}"),
                spp,
                ms,
                &img,
                None,
            ));
            if run.nonfinite > 0 {
                eprintln!("{name}: {label}: {} non-finite samples", run.nonfinite);
            }
        }
        eprintln!("{name}: done");
    }
    println!(
        "Per-frame times in ms (the GSCache paper's Table 2: PT path tracing, ST splatting, OT optimisation)\n"
    );
    println!("{}\n", table2.join("\n"));
    println!(
        "Quality of the last frame (1 spp unless stated) against the {}-spp nee reference; relMSE with epsilon 0.01 and the top 0.1% trimmed; PSNR on HDR with the reference's 99.9th percentile as peak\n",
        args.reference_spp
    );
    println!("{}", quality.join("\n"));
    Ok(())
}
