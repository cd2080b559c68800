//! `gscache bench`: speed of the renderers, as Markdown tables.
//!
//! - `gscache bench` (or `bench pt`): the volume path tracer on the bundled and shared volumes: samples
//!   per second for `uniform` and `nee`, with the macrocell majorant grid and with one global
//!   majorant, and how time grows with spp and image size.
//! - `bench splat`: the rasteriser's forward and backward passes at 1280x720, the AdamW step,
//!   memory per Gaussian.
//! - `bench trace`: the ray tracer's estimators: rays per second, error at equal time, and the
//!   multi-sample table.
//!
//! - `bench cache`: the GSCache paper's Table 2 (per-frame path tracing, splat and
//!   optimisation times along a camera orbit) on every volume, and quality at equal spp and
//!   equal time.
//! - `bench stability`: the cache over a 1000-frame orbit on every volume, inspected for
//!   non-finite values, exploding or straying Gaussians.
//!
//! - `bench large`: the path tracer on a gigavoxel (a bundled volume tiled to 1024^3): load
//!   time, peak memory, samples per second.
//! - `bench stream`: the path tracer on an OME-Zarr store streamed within a memory budget
//!   (a procedural store it makes once): time to first image, peak memory, and streamed
//!   against read whole.
//!
//! The bundled data comes from `--data DIR` (a clone's `data/`), else `data/` in the current
//! folder, else the source tree the program was built from; inputs that live in `shared/data`
//! beside the clone are skipped, with a note, when it is absent.

mod cache_bench;
mod large_bench;
mod splat_bench;
mod stability_bench;
mod stream_bench;
mod trace_bench;

use anyhow::Result;
use std::path::{Path, PathBuf};
use volume_pt::{Film, IntegratorKind, Scene, load_scene, render};

#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: Option<Sub>,
    #[command(flatten)]
    pt: Args,
}

#[derive(clap::Subcommand, Debug)]
enum Sub {
    /// The volume path tracer (the default).
    Pt(Args),
    /// The splatting rasteriser.
    Splat(splat_bench::SplatArgs),
    /// The stochastic Gaussian ray tracer.
    Trace(trace_bench::TraceArgs),
    /// The radiance cache: the GSCache paper's Table 2 and quality at equal spp and time.
    Cache(cache_bench::CacheBenchArgs),
    /// The radiance cache over a long fly-through: no NaN, no exploding Gaussians.
    Stability(stability_bench::StabilityArgs),
    /// The path tracer on a gigavoxel volume: load time, peak memory, samples per second.
    Large(large_bench::LargeArgs),
    /// The path tracer on an OME-Zarr store streamed within a memory budget.
    Stream(stream_bench::StreamArgs),
    /// Error of EXR images against a reference EXR: relMSE and PSNR.
    Compare {
        reference: PathBuf,
        images: Vec<PathBuf>,
    },
}

/// `--data DIR`, which every bench takes.
#[derive(clap::Args, Debug, Clone)]
pub struct DataArg {
    /// The bundled data folder (a clone's `data/`; default: `data/` here, else the source
    /// tree's).
    #[arg(long)]
    pub data: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct Args {
    #[command(flatten)]
    data: DataArg,
    /// Scene files to measure (default: the bundled and shared scenes in data/scenes).
    scenes: Vec<PathBuf>,
    /// Image width and height.
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(1..=4096))]
    size: u32,
    /// Samples per pixel for the throughput table.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..))]
    spp: u32,
    /// Skip the spp / image-size scaling table.
    #[arg(long)]
    no_scaling: bool,
}

fn time_render(scene: &Scene, spp: u32, size: u32) -> (f64, f64) {
    let mut cam = scene.camera;
    cam.width = size;
    cam.height = size;
    let mut settings = scene.settings;
    settings.spp = spp;
    let mut film = Film::new(size, size);
    let stats = render(
        &scene.media,
        &cam,
        &settings,
        &mut film,
        &volume_pt::Control::none(),
    );
    (stats.seconds, stats.samples_per_second())
}

/// Where the benches' inputs are.
#[derive(Debug, Clone)]
pub struct DataDirs {
    /// The bundled data (`data/` of a clone).
    pub bundled: PathBuf,
    /// The shared data beside the clone (`../shared/data`), which may be absent.
    pub shared: PathBuf,
}

impl DataDirs {
    /// `--data`, else `data/` in the current folder, else the source tree's: the first that
    /// holds `scenes/`. An installed program run elsewhere without `--data` is told so.
    fn find(flag: Option<&Path>) -> Result<Self> {
        let is_data = |d: &Path| d.join("scenes").is_dir();
        let bundled = match flag {
            Some(d) if is_data(d) => d.to_path_buf(),
            Some(d) => anyhow::bail!(
                "--data {}: no scenes/ folder there: expected the data/ folder of a clone",
                d.display()
            ),
            None => [
                PathBuf::from("data"),
                PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data"),
            ]
            .into_iter()
            .find(|d| is_data(d))
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "the benches read the bundled data, and there is no data/ here: pass \
                     --data DIR (the data/ folder of a clone), or run from the clone's folder"
                )
            })?,
        };
        let shared = bundled.join("../../shared/data");
        Ok(Self { bundled, shared })
    }

    /// A bundled scene file by name (`default` is `scenes/default.toml`).
    pub fn scene(&self, name: &str) -> PathBuf {
        self.bundled.join("scenes").join(format!("{name}.toml"))
    }
}

pub fn run(cli: BenchArgs) -> Result<i32> {
    if let Some(Sub::Compare { reference, images }) = &cli.command {
        compare(reference, images)?;
        return Ok(0);
    }
    let flag = match &cli.command {
        Some(Sub::Splat(a)) => &a.data,
        Some(Sub::Trace(a)) => &a.data,
        Some(Sub::Cache(a)) => &a.data,
        Some(Sub::Stability(a)) => &a.data,
        Some(Sub::Large(a)) => &a.data,
        Some(Sub::Stream(a)) => &a.data,
        Some(Sub::Pt(a)) => &a.data,
        Some(Sub::Compare { .. }) | None => &cli.pt.data,
    };
    let data = DataDirs::find(flag.data.as_deref())?;
    match cli.command {
        Some(Sub::Splat(a)) => splat_bench::run(&a, &data),
        Some(Sub::Trace(a)) => trace_bench::run(&a, &data),
        Some(Sub::Cache(a)) => cache_bench::run(&a, &data),
        Some(Sub::Stability(a)) => stability_bench::run(&a, &data),
        Some(Sub::Large(a)) => large_bench::run(&a, &data),
        Some(Sub::Stream(a)) => stream_bench::run(&a, &data),
        Some(Sub::Pt(a)) => run_pt(a, &data),
        Some(Sub::Compare { .. }) => Ok(()),
        None => run_pt(cli.pt, &data),
    }?;
    Ok(0)
}

fn compare(reference: &std::path::Path, images: &[PathBuf]) -> Result<()> {
    use image_metrics::{hdr_peak, psnr, rel_mse, smape};
    let r = hdr_image::RgbImage::read_exr(reference)?.into_pixels();
    let peak = hdr_peak(&r);
    println!("| image | relMSE | SMAPE | PSNR (dB, peak {peak:.3}) |");
    println!("|---|---|---|---|");
    for p in images {
        let x = hdr_image::RgbImage::read_exr(p)?.into_pixels();
        if x.len() != r.len() {
            anyhow::bail!("{}: size differs from the reference", p.display());
        }
        println!(
            "| {} | {:.4e} | {:.4} | {:.2} |",
            p.display(),
            rel_mse(&x, &r),
            smape(&x, &r),
            psnr(&x, &r, peak)
        );
    }
    Ok(())
}

fn run_pt(args: Args, data: &DataDirs) -> Result<()> {
    let scenes = if args.scenes.is_empty() {
        ["default", "hydrogen", "headsq", "chest_ct", "embryo"]
            .iter()
            .map(|s| data.scene(s))
            .collect()
    } else {
        args.scenes.clone()
    };
    println!(
        "threads: {}, image {}x{}, {} spp, max path length from each scene (64)\n",
        rayon::current_num_threads(),
        args.size,
        args.size,
        args.spp
    );
    println!(
        "| scene | volume | integrator | M samples/s (macrocells of 8) | M samples/s (one global majorant) | grid speed-up |"
    );
    println!("|---|---|---|---|---|---|");
    let mut loaded = Vec::new();
    for path in &scenes {
        let mut scene = match load_scene(path) {
            Ok(s) => s,
            Err(e) => {
                if path.to_string_lossy().contains("chest")
                    || path.to_string_lossy().contains("embryo")
                {
                    eprintln!(
                        "note: skipping {}: {e} (is ../shared/data present?)",
                        path.display()
                    );
                    continue;
                }
                return Err(e.into());
            }
        };
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let d = scene.media.medium.grid().dims();
        // Warm-up: page in the volume and the code.
        time_render(&scene, 1, 64);
        for integrator in [IntegratorKind::Uniform, IntegratorKind::Nee] {
            scene.settings.path.integrator = integrator;
            scene.media.medium.set_macrocell_size(8)?;
            let (_, grid) = time_render(&scene, args.spp, args.size);
            scene.media.medium.set_macrocell_size(1 << 20)?;
            let (_, global) = time_render(&scene, args.spp, args.size);
            println!(
                "| {name} | {}x{}x{} | {integrator} | {:.3} | {:.3} | {:.2}x |",
                d.x,
                d.y,
                d.z,
                grid / 1e6,
                global / 1e6,
                grid / global
            );
        }
        scene.media.medium.set_macrocell_size(8)?;
        scene.settings.path.integrator = IntegratorKind::Nee;
        loaded.push((name, scene));
    }
    if args.no_scaling || loaded.is_empty() {
        return Ok(());
    }
    let (name, scene) = &loaded[0];
    println!("\nScaling ({name}, nee): seconds per render\n");
    println!("| image | 4 spp | 16 spp | 64 spp | time per sample (64 spp) |");
    println!("|---|---|---|---|---|");
    for size in [128, 256, 512] {
        let t: Vec<f64> = [4, 16, 64]
            .iter()
            .map(|&s| time_render(scene, s, size).0)
            .collect();
        println!(
            "| {size}x{size} | {:.3} | {:.3} | {:.3} | {:.1} ns |",
            t[0],
            t[1],
            t[2],
            t[2] / (64.0 * (size * size) as f64) * 1e9
        );
    }
    Ok(())
}
