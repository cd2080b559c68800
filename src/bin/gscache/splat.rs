//! `gscache splat render | fit | trace`: render a Gaussian cloud (3DGS PLY or .splat) with the
//! differentiable rasteriser, fit a cloud to a target EXR seen from a given camera, or ray-trace
//! it with stochastic transparency (Sun et al., 2025).

use crate::common::{
    Global, INTERRUPTED, cancellation, finite_f32, finite_vec3, positive_f32, prepare_output,
    unit_f32,
};
use anyhow::{Result, bail};
use clap::{Args as ClapArgs, Subcommand};
use glam::Vec3;
use hdr_image::{RgbImage, ToneMap};
use splat_raster::adamw::{AdamW, AdamWConfig};
use splat_raster::io::{read_cloud, write_ply};
use splat_raster::loss::Loss;
use splat_raster::stochastic::render_stochastic_with;
use splat_raster::train::train_step;
use splat_raster::{Camera, ColorModel, GaussianCloud, LowPass, RasterConfig, render};
use std::path::{Path, PathBuf};
use stochastic_rt::{DepthMode, RandomKind};
use volume_pt::Control;

#[derive(Subcommand, Debug)]
pub enum SplatCommand {
    /// Render ASSET (.ply or .splat) to EXR and PNG.
    Render(RenderArgs),
    /// Fit a cloud to TARGET.exr seen from the given camera.
    Fit(FitArgs),
    /// Ray-trace ASSET with stochastic transparency (or the exact / K-buffer baselines).
    Trace(TraceArgs),
}

/// The ray tracer's estimators.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
enum TraceMode {
    /// Every hit sorted and composited: the reference.
    Exact,
    /// The K closest hits per pass (3DGRT-style).
    Kbuffer,
    /// One traversal, each hit accepted with its opacity (Sun et al.).
    Stochastic,
    /// The stochastic pass over K-hit buffers.
    StochasticPass,
}

#[derive(ClapArgs, Debug)]
pub struct TraceArgs {
    /// The Gaussian cloud: a 3DGS `.ply` (INRIA layout) or an antimatter15 `.splat`.
    asset: PathBuf,
    #[command(flatten)]
    camera: CameraArgs,
    /// The estimator.
    #[arg(long, value_enum, default_value_t = TraceMode::Stochastic)]
    mode: TraceMode,
    /// Samples per traversal for `stochastic` (Sun et al., section 3.5).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    samples_per_traversal: u32,
    /// Hits per pass for `kbuffer` and `stochastic-pass`.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u16).range(1..=4096))]
    k: u16,
    /// `kbuffer` stops once transmittance falls below this (0: never).
    #[arg(long, default_value_t = 0.0, value_parser = unit_f32)]
    min_transmittance: f32,
    /// Estimates per pixel.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..))]
    spp: u32,
    /// Where a hit sits along the ray: `mean` (the 1D Gaussian's mean) or `center` (the
    /// rasteriser's depth).
    #[arg(long, value_enum, default_value_t = DepthMode::Mean)]
    depth: DepthMode,
    /// Acceptance numbers: `hash` (integer) or `trig` (Sun et al., Eq. 8-10, in f64: in f32 it
    /// is biased for faint Gaussians).
    #[arg(long, value_enum, default_value_t = RandomKind::Hash)]
    random: RandomKind,
    /// Seed of the acceptance numbers (images are bit-identical for a seed on any thread count).
    #[arg(long, default_value_t = 0)]
    seed: u32,
    /// Background colour `r,g,b`.
    #[arg(long, value_parser = finite_vec3, default_value = "0,0,0")]
    background: Vec3,
    /// EXR output (default: out/ASSET.trace.exr; `-o NAME.png` names the PNG, the EXR beside).
    #[arg(short = 'o', long)]
    output: Option<PathBuf>,
    /// PNG output, tone-mapped by clipping (default: beside the EXR, same name).
    #[arg(long)]
    png: Option<PathBuf>,
}

/// The camera: explicit (`--eye`, `--target`) or an orbit around the cloud.
#[derive(ClapArgs, Clone, Debug)]
struct CameraArgs {
    /// Camera position `x,y,z` (with --target; otherwise an orbit around the cloud).
    #[arg(long, value_parser = finite_vec3)]
    eye: Option<Vec3>,
    /// Point at the image centre `x,y,z` (default: the cloud's median).
    #[arg(long, value_parser = finite_vec3)]
    target: Option<Vec3>,
    /// Image up direction `x,y,z`; 3DGS captures made with COLMAP are usually `0,-1,0`.
    #[arg(long, value_parser = finite_vec3, default_value = "0,-1,0", allow_hyphen_values = true)]
    up: Vec3,
    /// Orbit azimuth in degrees (orbit preset: around the cloud's median, at --distance).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = finite_f32)]
    orbit: f32,
    /// Orbit elevation in degrees.
    #[arg(long, default_value_t = 20.0, allow_hyphen_values = true, value_parser = finite_f32)]
    elevation: f32,
    /// Orbit distance in units of the cloud's extent.
    #[arg(long, default_value_t = 1.6, value_parser = positive_f32)]
    distance: f32,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 50.0, value_parser = positive_f32)]
    fov: f32,
    /// Image width in pixels.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 720)]
    height: u32,
}

#[derive(ClapArgs, Debug)]
pub struct RenderArgs {
    /// The Gaussian cloud: a 3DGS `.ply` (INRIA layout) or an antimatter15 `.splat`.
    asset: PathBuf,
    #[command(flatten)]
    camera: CameraArgs,
    /// Background colour `r,g,b`.
    #[arg(long, value_parser = finite_vec3, default_value = "0,0,0")]
    background: Vec3,
    /// Mip-splatting low-pass (0.1 px^2 with opacity compensation) instead of 0.3 px^2.
    #[arg(long)]
    mip: bool,
    /// Stochastic splatting with this many samples per pixel instead of sorted compositing.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    stochastic: Option<u32>,
    /// Per-pixel kernel of sorted compositing: `auto` (the widest SIMD lanes this CPU runs),
    /// `lanes8` (AVX2 + FMA), `lanes4` (SSE2 / NEON) or `scalar` (the reference).
    #[arg(long, default_value = "auto")]
    kernel: splat_raster::Kernel,
    /// EXR output (default: out/ASSET.exr; `-o NAME.png` names the PNG, the EXR beside).
    #[arg(short = 'o', long)]
    output: Option<PathBuf>,
    /// PNG output, tone-mapped by clipping (default: beside the EXR, same name).
    #[arg(long)]
    png: Option<PathBuf>,
}

#[derive(ClapArgs, Debug)]
pub struct FitArgs {
    /// The image to fit (EXR, linear RGB).
    #[arg(value_name = "TARGET.exr")]
    target_image: PathBuf,
    #[command(flatten)]
    camera: CameraArgs,
    /// Start from this cloud (else random Gaussians in the camera's view).
    #[arg(long)]
    init: Option<PathBuf>,
    /// Random Gaussians to start from when there is no --init.
    #[arg(long, default_value_t = 20_000, value_parser = clap::value_parser!(u32).range(1..=16_777_216))]
    points: u32,
    /// Optimisation steps.
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u32).range(1..))]
    iterations: u32,
    /// `hdr` (the GSCache paper's Eq. 4), `l1` or `l2`.
    #[arg(long, value_enum, default_value_t = Loss::L1)]
    loss: Loss,
    /// The fitted cloud (3DGS `.ply`).
    #[arg(short = 'o', long, default_value = "out/fitted.ply")]
    output: PathBuf,
}

/// Reads a cloud and says how many of its Gaussians no renderer can use (they are skipped).
fn load_cloud(path: &std::path::Path) -> Result<GaussianCloud<f32>> {
    let cloud = read_cloud(path)?;
    let unusable = cloud.count_unusable();
    if unusable > 0 {
        eprintln!(
            "warning: {}: {unusable} of {} Gaussians have a non-finite parameter or a zero \
             quaternion and are skipped (and left out of what a fit writes)",
            path.display(),
            cloud.len()
        );
    }
    Ok(cloud)
}

fn median_and_extent(cloud: &GaussianCloud<f32>) -> (Vec3, f32) {
    if cloud.is_empty() {
        return (Vec3::ZERO, 1.0);
    }
    let mut axes: [Vec<f32>; 3] = Default::default();
    for m in cloud.means.chunks(3) {
        for a in 0..3 {
            if m[a].is_finite() {
                axes[a].push(m[a]);
            }
        }
    }
    let mut med = [0.0; 3];
    let mut ext = 0.0f32;
    for a in 0..3 {
        let v = &mut axes[a];
        v.sort_by(f32::total_cmp);
        if v.is_empty() {
            continue;
        }
        med[a] = v[v.len() / 2];
        // 2nd to 98th percentile: robust to floaters.
        ext = ext.max(v[v.len() * 98 / 100] - v[v.len() * 2 / 100]);
    }
    (Vec3::from_array(med), ext.max(1e-3))
}

fn make_camera(c: &CameraArgs, cloud: Option<&GaussianCloud<f32>>) -> Result<Camera> {
    let (centre, extent) = cloud.map(median_and_extent).unwrap_or((Vec3::ZERO, 1.0));
    let target = c.target.unwrap_or(centre);
    let eye = match c.eye {
        Some(e) => e,
        None => {
            let (az, el) = (c.orbit.to_radians(), c.elevation.to_radians());
            // Orbit in the plane perpendicular to `up`.
            let up = c.up.normalize();
            let side = if up.cross(Vec3::Z).length() > 0.1 {
                up.cross(Vec3::Z).normalize()
            } else {
                up.cross(Vec3::X).normalize()
            };
            let fwd = side.cross(up);
            target
                + c.distance
                    * extent
                    * (el.cos() * (az.cos() * fwd + az.sin() * side) + el.sin() * up)
        }
    };
    Ok(Camera::look_at(
        eye, target, c.up, c.fov, c.width, c.height,
    )?)
}

pub fn run(command: SplatCommand, global: &Global) -> Result<i32> {
    // True when a long render (stochastic splatting, ray tracing) was interrupted and wrote
    // what it had: the exit status is then 130.
    let interrupted = match command {
        SplatCommand::Render(a) => render_splats(a, global)?,
        SplatCommand::Fit(a) => {
            fit(a)?;
            false
        }
        SplatCommand::Trace(a) => trace(a, global)?,
    };
    Ok(if interrupted { INTERRUPTED } else { 0 })
}

/// `gscache splat render`: the sorted rasteriser, or stochastic splatting with `--stochastic`.
/// Returns whether it was interrupted.
fn render_splats(a: RenderArgs, global: &Global) -> Result<bool> {
    let mut interrupted = false;
    let (exr_path, png_path) =
        prepared_outputs(&a.asset, a.output.as_deref(), a.png.as_deref(), "")?;
    let cloud = load_cloud(&a.asset)?;
    let cam = make_camera(&a.camera, Some(&cloud))?;
    let cfg = RasterConfig {
        low_pass: if a.mip {
            LowPass::Mip
        } else {
            LowPass::Classic
        },
        background: a.background.to_array(),
        kernel: a.kernel,
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    let (img, info) = match a.stochastic {
        Some(n) => {
            // Many samples per pixel take long: Ctrl-C keeps what each pixel has.
            let cancel = cancellation()?;
            let total = n as u64 * cam.width as u64 * cam.height as u64;
            let bar = global.progress(total, "samples");
            let report = |k| bar.inc(k);
            let (img, stopped) =
                render_stochastic_with(&cloud, &cam, &cfg, n, 0, &Control::new(&cancel, &report));
            bar.finish_and_clear();
            interrupted = stopped;
            let info = if stopped {
                format!("stochastic, interrupted before {n} samples per pixel")
            } else {
                format!("stochastic, {n} samples per pixel")
            };
            (img, info)
        }
        None => {
            let (img, state) = render(&cloud, &cam, &cfg);
            let info = format!(
                "sorted ({} kernel), {} visible, {} tile entries, {:.1} splat evaluations per pixel",
                state.kernel(),
                state.visible_count(),
                state.entry_count(),
                state.lane_evaluations() as f64 / (cam.width * cam.height) as f64
            );
            (img, info)
        }
    };
    let secs = t0.elapsed().as_secs_f64();
    let image = RgbImage::from_rgb(cam.width, cam.height, &img.color)?;
    image.write_exr(&exr_path)?;
    image.write_png(&png_path, 0.0, ToneMap::Clip)?;
    println!(
        "rendered {} Gaussians at {}x{} in {:.1} ms ({info}); wrote {} and {}",
        cloud.len(),
        cam.width,
        cam.height,
        secs * 1e3,
        exr_path.display(),
        png_path.display()
    );
    Ok(interrupted)
}

/// The EXR and PNG a render of `asset` writes (`-o` and `--png`, else `out/ASSET{suffix}.exr`),
/// checked before any work.
fn prepared_outputs(
    asset: &Path,
    output: Option<&Path>,
    png: Option<&Path>,
    suffix: &str,
) -> Result<(PathBuf, PathBuf)> {
    let (exr_path, png_path) =
        crate::common::output_paths(output, png, &default_output(asset, suffix));
    prepare_output(&exr_path)?;
    prepare_output(&png_path)?;
    Ok((exr_path, png_path))
}

/// `gscache splat fit`: a cloud fitted to a target image by gradient descent.
fn fit(a: FitArgs) -> Result<()> {
    prepare_output(&a.output)?;
    let target = RgbImage::read_exr(&a.target_image)?;
    let (w, h) = (target.width(), target.height());
    let target = target.into_pixels();
    if let Some(i) = target.iter().position(|p| !p.is_finite()) {
        bail!(
            "{}: pixel ({}, {}) is {}: a target must be finite everywhere",
            a.target_image.display(),
            i as u32 % w,
            i as u32 / w,
            target[i]
        );
    }
    if (w, h) != (a.camera.width, a.camera.height) {
        bail!(
            "{}: the target is {w}x{h} but the camera is {}x{}: pass --width {w} --height {h}",
            a.target_image.display(),
            a.camera.width,
            a.camera.height
        );
    }
    let loss = a.loss;
    // The fit writes its cloud back: an unusable row would be written back as it was
    // (NaN in the output), so the start drops them (load_cloud's warning counts them).
    let init = a
        .init
        .as_deref()
        .map(load_cloud)
        .transpose()?
        .map(|c| c.without_unusable());
    let cam = make_camera(&a.camera, init.as_ref())?;
    let mut cloud = match init {
        Some(c) => c,
        None => {
            // Spread the start around the target's depth.
            let dist = match (a.camera.eye, a.camera.target) {
                (Some(e), Some(t)) => (t - e).length(),
                _ => a.camera.distance,
            };
            random_in_view(&cam, a.points as usize, 0.7 * dist, 1.3 * dist)
        }
    };
    let target: Vec<[f32; 3]> = target.iter().map(|v| v.to_array()).collect();
    let cfg = RasterConfig::default();
    let mut opt = AdamW::new(AdamWConfig::default(), &cloud);
    let t0 = std::time::Instant::now();
    for it in 0..a.iterations {
        let l = train_step(&mut cloud, &cam, &cfg, &target, None, loss, &mut opt, 1.0);
        if it % 25 == 0 || it + 1 == a.iterations {
            println!("iteration {it:5}: loss {l:.5e}");
        }
    }
    write_ply(&a.output, &cloud)?;
    let (img, _) = render(&cloud, &cam, &cfg);
    let png = a.output.with_extension("png");
    RgbImage::from_rgb(w, h, &img.color)?.write_png(&png, 0.0, ToneMap::Clip)?;
    println!(
        "fitted {} Gaussians in {:.1} s; wrote {} and {}",
        cloud.len(),
        t0.elapsed().as_secs_f64(),
        a.output.display(),
        png.display()
    );
    Ok(())
}

/// `gscache splat trace`: stochastic ray tracing of transparent Gaussians (or the exact and
/// K-buffer baselines). Returns whether it was interrupted.
fn trace(a: TraceArgs, global: &Global) -> Result<bool> {
    let (exr_path, png_path) =
        prepared_outputs(&a.asset, a.output.as_deref(), a.png.as_deref(), ".trace")?;
    use stochastic_rt::{Estimator, GaussianScene, TraceSettings, trace_image_with};
    let cloud = load_cloud(&a.asset)?;
    let cam = make_camera(&a.camera, Some(&cloud))?;
    let estimator = match a.mode {
        TraceMode::Exact => Estimator::Exact,
        TraceMode::Kbuffer => Estimator::KBuffer {
            k: a.k.into(),
            min_transmittance: a.min_transmittance,
        },
        TraceMode::Stochastic => Estimator::Stochastic {
            samples_per_traversal: a.samples_per_traversal,
        },
        TraceMode::StochasticPass => Estimator::StochasticPass { k: a.k.into() },
    };
    let (depth_mode, random) = (a.depth, a.random);
    let t0 = std::time::Instant::now();
    let scene = GaussianScene::new(&cloud);
    let build = t0.elapsed().as_secs_f64();
    let settings = TraceSettings {
        estimator,
        depth_mode,
        spp: a.spp,
        seed: a.seed,
        background: a.background,
        random,
    };
    let t1 = std::time::Instant::now();
    let cancel = cancellation()?;
    let per_pixel = match estimator {
        Estimator::Exact | Estimator::KBuffer { .. } => 1,
        _ => settings.spp.max(1),
    };
    let bar = global.progress(
        per_pixel as u64 * cam.width as u64 * cam.height as u64,
        "rays",
    );
    let report = |k| bar.inc(k);
    let (img, stopped) = trace_image_with(&scene, &cam, &settings, &Control::new(&cancel, &report));
    bar.finish_and_clear();
    if stopped {
        eprintln!("interrupted: each pixel is the mean of the estimates it finished; writing them");
    }
    let secs = t1.elapsed().as_secs_f64();
    let image = RgbImage::from_pixels(cam.width, cam.height, img)?;
    image.write_exr(&exr_path)?;
    image.write_png(&png_path, 0.0, ToneMap::Clip)?;
    let rays = match estimator {
        Estimator::Exact | Estimator::KBuffer { .. } => 1,
        _ => settings.spp,
    } as f64
        * (cam.width * cam.height) as f64;
    println!(
        "traced {} Gaussians ({} traceable; BVH built in {:.0} ms) at {}x{}, {} in {:.2} s: {:.3} M rays/s on {} threads; wrote {} and {}",
        cloud.len(),
        scene.gaussians.len(),
        build * 1e3,
        cam.width,
        cam.height,
        clap::ValueEnum::to_possible_value(&a.mode)
            .expect("every mode has a name")
            .get_name(),
        secs,
        rays / secs / 1e6,
        rayon::current_num_threads(),
        exr_path.display(),
        png_path.display()
    );
    Ok(stopped)
}

/// Random small Gaussians spread through the camera's view between two depths (a hash-based
/// sequence, so fits are reproducible).
fn random_in_view(cam: &Camera, n: usize, near: f32, far: f32) -> GaussianCloud<f32> {
    use splat_raster::random::{hash32, unit_f32};
    let mut c = GaussianCloud::new(ColorModel::Rgb);
    for i in 0..n as u32 {
        let r = |k: u32| unit_f32(hash32(&[99, i, k]));
        let d = cam.ray_direction(r(0) * cam.width as f32, r(1) * cam.height as f32);
        let depth = near + (far - near) * r(2);
        let p = cam.position + d * depth;
        // About two pixels wide at its depth.
        let size = (2.0 * depth / cam.focal_pixels()).ln();
        c.push(
            p.to_array(),
            [size; 3],
            [1.0, 0.0, 0.0, 0.0],
            &[0.5, 0.5, 0.5],
            -1.0,
        );
    }
    c
}

/// `out/<asset stem><suffix>.exr`: each asset (and the ray tracer) gets its own default name,
/// so renders of two assets do not overwrite each other.
fn default_output(asset: &Path, suffix: &str) -> PathBuf {
    let stem = asset
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "splat".into());
    PathBuf::from("out").join(format!("{stem}{suffix}.exr"))
}
