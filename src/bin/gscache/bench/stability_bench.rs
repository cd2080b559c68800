//! `bench stability`: the cache over a long fly-through on every volume (the GSCache paper's claim
//! that training stays stable): a full orbit of `frames` frames, training after every one, with the
//! cache's parameters inspected at intervals. It fails (non-zero exit) if a parameter, a cache
//! value or a sample is ever non-finite, or a Gaussian grows or strays past the stated bounds.

use crate::bench::cache_bench::{default_scenes, load_sized, orbit};
use anyhow::{Result, bail};
use gs_cache::GsCache;
use render_session::{Accumulation, CacheChoice, Control, Edit, Session};
use std::path::PathBuf;
use volume_pt::IntegratorKind;

#[derive(clap::Args, Debug, Clone)]
pub struct StabilityArgs {
    #[command(flatten)]
    pub data: crate::bench::DataArg,
    /// Scene files (default: every scene in data/scenes).
    pub scenes: Vec<PathBuf>,
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    #[arg(long, default_value_t = 180)]
    pub height: u32,
    #[arg(long, default_value_t = 1000)]
    pub frames: u32,
    /// Frames between inspections.
    #[arg(long, default_value_t = 250)]
    pub every: u32,
    /// The cache's settings (`--cache-KEY`, as for `gscache render`).
    #[command(flatten)]
    pub cache: gs_cache::CacheConfig,
    /// Largest Gaussian allowed, as a fraction of the volume's diagonal.
    #[arg(long, default_value_t = 0.5, value_parser = crate::common::positive_f32)]
    pub max_scale: f32,
    /// How far outside the volume's box a Gaussian centre may stray, as a fraction of the
    /// diagonal.
    #[arg(long, default_value_t = 0.25, value_parser = crate::common::positive_f32)]
    pub max_stray: f32,
}

/// What an inspection found, over every level.
#[derive(Debug, Default)]
struct Inspection {
    nonfinite_parameters: usize,
    largest_scale: f32,
    farthest_stray: f32,
    opacity_range: (f32, f32),
    largest_cache_value: f32,
    nonfinite_cache_values: usize,
}

fn inspect(cache: &GsCache, lo: glam::Vec3, hi: glam::Vec3) -> Inspection {
    let mut r = Inspection {
        opacity_range: (1.0, 0.0),
        ..Default::default()
    };
    for level in cache.levels() {
        let c = &level.cloud;
        for (_, values) in c.groups() {
            r.nonfinite_parameters += values.iter().filter(|v| !v.is_finite()).count();
        }
        for s in &c.log_scales {
            r.largest_scale = r.largest_scale.max(s.exp());
        }
        for m in c.means.chunks_exact(3) {
            let p = glam::Vec3::from_slice(m);
            let outside = (lo - p).max(p - hi).max(glam::Vec3::ZERO).length();
            r.farthest_stray = r.farthest_stray.max(outside);
        }
        for &o in &c.opacity_logits {
            let a = 1.0 / (1.0 + (-o).exp());
            r.opacity_range = (r.opacity_range.0.min(a), r.opacity_range.1.max(a));
        }
    }
    if let Some(frame) = cache.frame() {
        for level in 0..frame.levels() {
            for px in frame.image(level) {
                for &v in px {
                    if v.is_finite() {
                        r.largest_cache_value = r.largest_cache_value.max(v);
                    } else {
                        r.nonfinite_cache_values += 1;
                    }
                }
            }
        }
    }
    r
}

pub fn run(args: &StabilityArgs, data: &crate::bench::DataDirs) -> Result<()> {
    let scenes = if args.scenes.is_empty() {
        default_scenes(data)
    } else {
        args.scenes.clone()
    };
    println!(
        "threads {}, {}x{}, 1 spp per frame, {} frames on a full orbit, cache N = {}, learning rates x {}, scale rate {}\n",
        rayon::current_num_threads(),
        args.width,
        args.height,
        args.frames,
        args.cache.points,
        args.cache.lr_multiplier,
        args.cache.lr_scales
    );
    println!(
        "| volume | frame | non-finite parameters / cache values / samples | largest scale / diagonal | farthest stray / diagonal | opacity range | largest cache value | length-1 MSE | ms per frame |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut failures = Vec::new();
    for path in &scenes {
        let Some((name, mut scene)) = load_sized(path, args.width, args.height)? else {
            continue;
        };
        scene.settings.spp = 1;
        scene.settings.path.integrator = IntegratorKind::Nee;
        let camera = scene.camera;
        let (lo, hi) = scene.media.medium.bounds();
        let diagonal = (hi - lo).length();
        let centre = 0.5 * (lo + hi);
        let mut session = Session::new(scene, CacheChoice::gaussian(args.cache))?
            .with_accumulation(Accumulation::PerFrame);
        session.check_frames(args.frames)?;
        let (mut nonfinite_samples, mut seconds, mut counted) = (0u64, 0.0, 0u32);
        for f in 0..args.frames {
            session.edit(Edit::Camera(orbit(&camera, centre, 360.0, f, args.frames)))?;
            let s = session.next_frame(&Control::none())?;
            nonfinite_samples += s.nonfinite_samples;
            seconds += s.trace_seconds + s.lookup_seconds + s.train_seconds;
            counted += 1;
            if (f + 1) % args.every == 0 || f + 1 == args.frames {
                let cache = session
                    .cache()
                    .gaussian()
                    .expect("a Gaussian cache session");
                let i = inspect(cache, lo, hi);
                let mse = cache.report().mse.first().copied().flatten();
                println!(
                    "| {name} | {} | {} / {} / {nonfinite_samples} | {:.4} | {:.4} | {:.3}-{:.3} | {:.3} | {} | {:.0} |",
                    f + 1,
                    i.nonfinite_parameters,
                    i.nonfinite_cache_values,
                    i.largest_scale / diagonal,
                    i.farthest_stray / diagonal,
                    i.opacity_range.0,
                    i.opacity_range.1,
                    i.largest_cache_value,
                    mse.map_or("-".into(), |m| format!("{m:.4}")),
                    seconds / counted as f64 * 1e3
                );
                let bad = i.nonfinite_parameters > 0
                    || i.nonfinite_cache_values > 0
                    || nonfinite_samples > 0
                    || !(i.largest_scale <= args.max_scale * diagonal)
                    || !(i.farthest_stray <= args.max_stray * diagonal);
                if bad {
                    failures.push(format!("{name} at frame {}: {i:?}", f + 1));
                }
                (seconds, counted) = (0.0, 0);
            }
        }
    }
    if !failures.is_empty() {
        bail!("unstable:\n{}", failures.join("\n"));
    }
    println!("\nevery inspection passed");
    Ok(())
}
