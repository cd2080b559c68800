//! `bench trace`: the stochastic ray tracer's estimators on a 3DGS asset at 1280x960.

use anyhow::Result;
use glam::Vec3;
use splat_raster::Camera;
use splat_raster::io::read_cloud;
use std::time::Instant;
use stochastic_rt::{Estimator, GaussianScene, RandomKind, TraceSettings, trace_image};

#[derive(clap::Args, Debug)]
pub struct TraceArgs {
    #[command(flatten)]
    pub data: crate::bench::DataArg,
    /// Image width (height is 3/4 of it).
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Samples per pixel for the stochastic estimators in the throughput table.
    #[arg(long, default_value_t = 4)]
    spp: u32,
    /// Total samples per pixel for the multi-sample table (Sun et al., Tables 4-5 use 1024).
    #[arg(long, default_value_t = 64)]
    multi_total: u32,
    /// Image width for the multi-sample table (default: --width); 1024 spp at 1280x960 with
    /// n = 1 takes about a quarter of an hour on two cores.
    #[arg(long)]
    multi_width: Option<u32>,
    /// Measure only the multi-sample table.
    #[arg(long)]
    multi_only: bool,
    /// Gaussians in the volume-density cloud (0 to skip it).
    #[arg(long, default_value_t = 1_000_000)]
    volume_gaussians: usize,
}

/// Stochastic with each acceptance generator, and exact, on a cloud and camera (2 threads).
fn hash_table(name: &str, scene: &GaussianScene, cam: &Camera, spp: u32) {
    let exact_t = Instant::now();
    let exact = trace_image(
        scene,
        cam,
        &TraceSettings {
            estimator: Estimator::Exact,
            ..Default::default()
        },
    );
    let exact_s = exact_t.elapsed().as_secs_f64();
    let rays = (cam.width * cam.height) as f64;
    println!(
        "| {name} | exact | 1 | {exact_s:.2} | {:.3} | 0 |",
        rays / exact_s / 1e6
    );
    for (label, random) in [
        ("integer hash", RandomKind::Hash),
        ("trig hash (Eq. 8-10)", RandomKind::Trig),
    ] {
        let settings = TraceSettings {
            estimator: Estimator::Stochastic {
                samples_per_traversal: 1,
            },
            spp,
            random,
            ..Default::default()
        };
        let t = Instant::now();
        let img = trace_image(scene, cam, &settings);
        let secs = t.elapsed().as_secs_f64();
        println!(
            "| {name} | stochastic, {label} | {spp} | {secs:.2} | {:.3} | {:.3e} |",
            rays * spp as f64 / secs / 1e6,
            mse(&img, &exact)
        );
    }
}

fn mse(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).as_dvec3().length_squared() / 3.0)
        .sum::<f64>()
        / a.len() as f64
}

pub fn run(a: &TraceArgs, data: &crate::bench::DataDirs) -> Result<()> {
    let path = data.shared.join("splats/plant_inria_sh0.ply");
    let cloud = match read_cloud(&path) {
        Ok(c) => c.sh_truncated(0),
        Err(e) => {
            println!("note: skipping: {e} (is ../shared/data present?)");
            return Ok(());
        }
    };
    let (w, h) = (a.width, a.width * 3 / 4);
    let cam = Camera::look_at(
        Vec3::new(0.9, -0.6, -1.0),
        Vec3::new(0.0, 0.1, 0.0),
        Vec3::new(0.0, -1.0, 0.0),
        50.0,
        w,
        h,
    )?;
    let t0 = Instant::now();
    let scene = GaussianScene::new(&cloud);
    println!(
        "plant: {} Gaussians; bounds in {:.0} ms, BVH (obvhs Bvh2, medium build) in {:.0} ms ({:.0} ms total), {:.1} MB\n",
        scene.gaussians.len(),
        scene.prepare_seconds * 1e3,
        scene.build_seconds * 1e3,
        t0.elapsed().as_secs_f64() * 1e3,
        scene.bvh_bytes() as f64 / 1e6
    );
    if a.multi_only {
        return multi_table(a, &scene, &cam);
    }
    let exact = trace_image(
        &scene,
        &cam,
        &TraceSettings {
            estimator: Estimator::Exact,
            ..Default::default()
        },
    );
    println!("{w}x{h}; a ray is one estimate of one pixel; MSE against `exact` (linear RGB)\n");
    println!(
        "| estimator | threads | M rays/s | M rays/s/core | MSE at this spp | MSE x seconds |"
    );
    println!("|---|---|---|---|---|---|");
    let estimators = [
        ("exact", Estimator::Exact, 1),
        (
            "kbuffer k=16",
            Estimator::KBuffer {
                k: 16,
                min_transmittance: 0.0,
            },
            1,
        ),
        (
            "kbuffer k=16, stop T<1e-3",
            Estimator::KBuffer {
                k: 16,
                min_transmittance: 1e-3,
            },
            1,
        ),
        (
            "stochastic",
            Estimator::Stochastic {
                samples_per_traversal: 1,
            },
            a.spp,
        ),
        (
            "stochastic, 4 per traversal",
            Estimator::Stochastic {
                samples_per_traversal: 4,
            },
            a.spp,
        ),
        (
            "stochastic-pass k=16",
            Estimator::StochasticPass { k: 16 },
            a.spp,
        ),
    ];
    for (name, est, spp) in estimators {
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()?;
            let settings = TraceSettings {
                estimator: est,
                spp,
                ..Default::default()
            };
            let t = Instant::now();
            let img = pool.install(|| trace_image(&scene, &cam, &settings));
            let secs = t.elapsed().as_secs_f64();
            let rays = (w * h * spp) as f64;
            let e = mse(&img, &exact);
            println!(
                "| {name} | {threads} | {:.3} | {:.3} | {:.3e} | {:.3e} |",
                rays / secs / 1e6,
                rays / secs / 1e6 / threads as f64,
                e,
                e * secs
            );
        }
    }
    println!("\nAcceptance generators, and a volume-density cloud (2 threads, {w}x{h})\n");
    println!("| cloud | estimator | spp | seconds | M rays/s | MSE vs exact |");
    println!("|---|---|---|---|---|---|");
    hash_table("plant", &scene, &cam, a.spp);
    if a.volume_gaussians > 0 {
        let (vcloud, mut vcam) = crate::bench::splat_bench::volume_cloud(a.volume_gaussians, data)?;
        vcam.width = w;
        vcam.height = h;
        let t = Instant::now();
        let vscene = GaussianScene::new(&vcloud);
        let build = t.elapsed().as_secs_f64();
        let name = format!(
            "volume-density {}k (BVH {:.0} ms)",
            vcloud.len() / 1000,
            build * 1e3
        );
        hash_table(&name, &vscene, &vcam, a.spp);
    }
    multi_table(a, &scene, &cam)
}

/// Sun et al., Tables 4-5: the same total samples per pixel as m traversals of n samples each.
fn multi_table(a: &TraceArgs, scene: &GaussianScene, cam: &Camera) -> Result<()> {
    let mut cam = *cam;
    if let Some(mw) = a.multi_width {
        cam.width = mw;
        cam.height = mw * 3 / 4;
    }
    let (w, h) = (cam.width, cam.height);
    let exact = trace_image(
        scene,
        &cam,
        &TraceSettings {
            estimator: Estimator::Exact,
            ..Default::default()
        },
    );
    println!(
        "\nMulti-sample (Sun et al., Tables 4-5): {} samples per pixel as m traversals x n samples, {w}x{h}, 2 threads\n",
        a.multi_total
    );
    println!("| n per traversal | m traversals | seconds | speed-up over n = 1 | MSE |");
    println!("|---|---|---|---|---|");
    let mut base = 0.0;
    let mut n = 1;
    while n <= a.multi_total.min(64) {
        let m = a.multi_total / n;
        let settings = TraceSettings {
            estimator: Estimator::Stochastic {
                samples_per_traversal: n,
            },
            spp: m,
            ..Default::default()
        };
        let t = Instant::now();
        let img = trace_image(scene, &cam, &settings);
        let secs = t.elapsed().as_secs_f64();
        if n == 1 {
            base = secs;
        }
        println!(
            "| {n} | {m} | {secs:.2} | {:.2}x | {:.3e} |",
            base / secs,
            mse(&img, &exact)
        );
        n *= 2;
    }
    Ok(())
}
