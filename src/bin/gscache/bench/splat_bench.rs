//! `bench splat`: forward and backward of the rasteriser, every kernel side by side: a cache
//! level at 320x180, volume-density clouds and the plant asset at 1280x720.

use crate::bench::DataDirs;
use anyhow::Result;
use glam::Vec3;
use splat_raster::adamw::{AdamW, AdamWConfig};
use splat_raster::io::read_cloud;
use splat_raster::random::{hash32, unit_f32};
use splat_raster::raster::backward;
use splat_raster::{Camera, ColorModel, GaussianCloud, Kernel, PixelGrads, RasterConfig, render};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct SplatArgs {
    #[command(flatten)]
    pub data: crate::bench::DataArg,
    /// Repetitions per measurement (the median is reported).
    #[arg(long, default_value_t = 5)]
    reps: usize,
    /// Largest synthetic cloud.
    #[arg(long, default_value_t = 1_000_000)]
    max_gaussians: usize,
    /// Skip the scalar reference kernel (it is 3-5x slower).
    #[arg(long)]
    no_scalar: bool,
}

/// The kernels measured side by side, widest first.
fn kernels(with_scalar: bool) -> Vec<Kernel> {
    let mut k = vec![];
    if Kernel::Lanes8.available() {
        k.push(Kernel::Lanes8);
    }
    k.push(Kernel::Lanes4);
    if with_scalar {
        k.push(Kernel::Scalar);
    }
    k
}

/// Gaussians spread through the default scene's volume where its transfer function is opaque,
/// sized like the cache's initialisation (half the mean spacing), seen by its camera: the
/// density the radiance cache will have.
pub fn volume_cloud(n: usize, data: &DataDirs) -> Result<(GaussianCloud<f32>, Camera)> {
    let scene = volume_pt::load_scene(&data.scene("default"))?;
    let m = &scene.media.medium;
    let (lo, hi) = m.bounds();
    let size = hi - lo;
    let mut cloud = GaussianCloud::new(ColorModel::Rgb);
    let mut k = 0u32;
    let spacing = (size.x * size.y * size.z * 0.3 / n as f32).cbrt();
    let s = (0.5 * spacing).ln();
    let threshold = 0.05 * m.majorants().global_max();
    while cloud.len() < n {
        k += 1;
        let r = |j: u32| unit_f32(hash32(&[5, k, j]));
        let p = lo + size * Vec3::new(r(0), r(1), r(2));
        let u = m.to_index_ray(p, Vec3::X).o;
        if m.extinction(u) <= threshold {
            continue;
        }
        let a = m.albedo(u);
        cloud.push(
            p.to_array(),
            [s; 3],
            [1.0, 0.0, 0.0, 0.0],
            &a.to_array(),
            0.0,
        );
    }
    let mut cam = scene.camera;
    cam.width = 1280;
    cam.height = 720;
    Ok((cloud, cam))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Forward ms, backward ms and evaluations per kernel: each repetition runs every kernel in turn
/// (A B A B), so a slow spell of this shared machine touches them alike.
fn measure(
    cloud: &GaussianCloud<f32>,
    cam: &Camera,
    reps: usize,
    threads: usize,
    kernels: &[Kernel],
) -> Vec<(f64, f64, u64)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let up = vec![[1.0f32, 0.5, 0.25]; (cam.width * cam.height) as usize];
        let mut times = vec![(Vec::new(), Vec::new(), 0); kernels.len()];
        for _ in 0..reps {
            for (kernel, (f, b, evals)) in kernels.iter().zip(times.iter_mut()) {
                let cfg = RasterConfig {
                    kernel: *kernel,
                    ..Default::default()
                };
                let t0 = Instant::now();
                let (_, state) = render(cloud, cam, &cfg);
                f.push(t0.elapsed().as_secs_f64());
                *evals = state.lane_evaluations();
                let t1 = Instant::now();
                let g = backward(
                    cloud,
                    cam,
                    &state,
                    PixelGrads {
                        color: &up,
                        transmittance: None,
                        depth: None,
                    },
                );
                b.push(t1.elapsed().as_secs_f64());
                std::hint::black_box(g);
            }
        }
        times
            .into_iter()
            .map(|(f, b, e)| (median(f), median(b), e))
            .collect()
    })
}

/// f32 operations per pixel evaluation of the forward lane kernel (depth off): the exponent
/// (5), `exp` (22: the range reduction and Horner's seven FMAs), alpha (1), transmittance (2),
/// the weight (1) and the colour (6). Compares, selects and the clamps of `exp` are not counted.
const FLOPS_PER_EVALUATION: f64 = 37.0;
/// f32 operations per cycle of one core at its FMA peak with 8-lane vectors: two 256-bit FMA
/// pipes (AMD Zen 4, this machine; Intel since Haswell has the same).
const PEAK_FLOPS_PER_CYCLE: f64 = 32.0;

/// The clock the peak is taken at: the first `cpu MHz` of /proc/cpuinfo (the nominal clock in a
/// VM), or 2.6 GHz.
fn clock_ghz() -> f64 {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("cpu MHz"))
                .and_then(|l| l.split(':').nth(1))
                .and_then(|v| v.trim().parse::<f64>().ok())
        })
        .map_or(2.6, |mhz| mhz / 1000.0)
}

pub fn run(a: &SplatArgs, data: &DataDirs) -> Result<()> {
    let ghz = clock_ghz();
    println!(
        "Median of {} runs, kernels alternated within each run. Lane evaluations: pixels of every \
         vector whose alpha the forward pass computed (masked lanes included; one per pixel for \
         the scalar kernel). GFLOP/s: {FLOPS_PER_EVALUATION} f32 operations per evaluation; peak: \
         {PEAK_FLOPS_PER_CYCLE} per cycle at {ghz:.2} GHz = {:.1} GFLOP/s per core.\n",
        a.reps,
        PEAK_FLOPS_PER_CYCLE * ghz
    );
    let kernels = kernels(!a.no_scalar);
    println!(
        "| cloud | size | Gaussians | threads | kernel | forward ms | backward ms | backward / forward | forward speed-up over scalar | M lane evaluations / s / core | GFLOP/s / core (of peak) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut clouds: Vec<(String, GaussianCloud<f32>, Camera)> = Vec::new();
    // A level of the radiance cache as the experiments draw it: 20k Gaussians at 320x180.
    let (c, mut cam) = volume_cloud(20_000, data)?;
    (cam.width, cam.height) = (320, 180);
    clouds.push(("cache level (neghip) 20k".into(), c, cam));
    for n in [10_000, 100_000, 300_000, 1_000_000] {
        if n > a.max_gaussians {
            continue;
        }
        let (c, cam) = volume_cloud(n, data)?;
        clouds.push((format!("volume-density (neghip) {}k", n / 1000), c, cam));
    }
    let plant = data.shared.join("splats/plant_inria_sh0.ply");
    match read_cloud(&plant) {
        Ok(mut c) => {
            // The asset carries zero SH bands; render it as what it is, degree 0.
            c = c.sh_truncated(0);
            let cam = Camera::look_at(
                Vec3::new(0.9, -0.6, -1.0),
                Vec3::new(0.0, 0.1, 0.0),
                Vec3::new(0.0, -1.0, 0.0),
                50.0,
                1280,
                720,
            )?;
            clouds.push(("plant (3DGS asset)".into(), c, cam));
        }
        Err(e) => eprintln!("note: skipping the plant asset ({e}); is ../shared/data present?"),
    }
    let peak = PEAK_FLOPS_PER_CYCLE * ghz;
    // 1 and 2 threads (the issues' figures), and all of the pool's threads where it has more.
    let mut thread_counts = vec![1, 2];
    if rayon::current_num_threads() > 2 {
        thread_counts.push(rayon::current_num_threads());
    }
    for (name, cloud, cam) in &clouds {
        for &threads in &thread_counts {
            let rows = measure(cloud, cam, a.reps, threads, &kernels);
            let scalar = kernels.iter().position(|k| *k == Kernel::Scalar);
            for (kernel, &(f, b, evals)) in kernels.iter().zip(&rows) {
                let speedup = scalar.map_or("-".to_string(), |s| format!("{:.2}x", rows[s].0 / f));
                let per_core = evals as f64 / f / threads as f64;
                let gflops = per_core * FLOPS_PER_EVALUATION / 1e9;
                println!(
                    "| {name} | {}x{} | {} | {threads} | {kernel:?} | {:.1} | {:.1} | {:.2} | {speedup} | {:.0} | {:.1} ({:.0}%) |",
                    cam.width,
                    cam.height,
                    cloud.len(),
                    f * 1e3,
                    b * 1e3,
                    b / f,
                    per_core / 1e6,
                    gflops,
                    100.0 * gflops / peak
                );
            }
        }
    }
    // AdamW step over 300k Gaussians (14 floats each, RGB colour).
    let (cloud, _) = volume_cloud(300_000, data)?;
    let mut params = cloud.clone();
    let grads = cloud.clone();
    let mut opt = AdamW::new(AdamWConfig::default(), &cloud);
    let mut times = Vec::new();
    for _ in 0..20 {
        let t0 = Instant::now();
        opt.step(&mut params, &grads, 1.0);
        times.push(t0.elapsed().as_secs_f64());
    }
    println!(
        "\nAdamW step, 300k Gaussians x 14 floats, {} threads: median of 20 = {:.2} ms",
        rayon::current_num_threads(),
        median(times) * 1e3
    );
    println!(
        "Memory per Gaussian: parameters {} B (RGB) / {} B (SH degree 3); AdamW moments twice that.",
        cloud.bytes_per_gaussian(),
        GaussianCloud::<f32>::new(ColorModel::Sh(3)).bytes_per_gaussian()
    );
    Ok(())
}
