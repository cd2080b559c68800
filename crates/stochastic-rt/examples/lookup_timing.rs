//! Times the cache's two lookups on saved levels (`gscache render --save-cache DIR`): the
//! rasteriser's image and the stochastic ray tracer's through the camera grid, alternated; the
//! tracer's arrays kept from round to round, as the cache keeps them.
//!
//! `cargo run --release --example lookup_timing -- DIR WIDTH HEIGHT [ROUNDS]`, the camera the
//! default scene's. Prints each lookup's minimum and median per round, and a checksum of the
//! ray-traced images (the same bits before and after a change that must not change them).

use glam::Vec3;
use rayon::prelude::*;
use splat_raster::{Camera, RasterConfig, render};
use std::time::Instant;
use stochastic_rt::{CameraTracer, TraceGaussians};

fn main() {
    const USAGE: &str = "usage: lookup_timing DIR WIDTH HEIGHT [ROUNDS]";
    let args: Vec<String> = std::env::args().collect();
    let number = |k: usize, default: Option<u32>| -> u32 {
        match (args.get(k), default) {
            (Some(a), _) => a.parse().expect(USAGE),
            (None, Some(d)) => d,
            (None, None) => panic!("{USAGE}"),
        }
    };
    let dir = std::path::Path::new(args.get(1).expect(USAGE));
    let (width, height) = (number(2, None), number(3, None));
    let rounds = number(4, Some(20)).max(1) as usize;
    let mut clouds = Vec::new();
    for n in 1.. {
        let path = dir.join(format!("length_{n}.ply"));
        if !path.exists() {
            break;
        }
        let cloud = splat_raster::io::read_ply(&path);
        clouds.push(cloud.unwrap_or_else(|e| panic!("{}: {e}", path.display())));
    }
    assert!(!clouds.is_empty(), "{}: no length_1.ply", dir.display());
    let camera = Camera::look_at(
        Vec3::new(60.0, 45.0, 95.0),
        Vec3::ZERO,
        Vec3::Y,
        38.0,
        width,
        height,
    )
    .expect("the default scene's camera at this size");
    let raster = RasterConfig::default();
    let (mut rt_ms, mut raster_ms) = (Vec::new(), Vec::new());
    let mut checksum = 0u64;
    // Each level's tracing arrays kept from round to round, as the cache keeps them.
    let mut tracers: Vec<(TraceGaussians, CameraTracer)> = clouds
        .iter()
        .map(|c| (TraceGaussians::new(c), CameraTracer::default()))
        .collect();
    for _ in 0..rounds {
        let start = Instant::now();
        let images: Vec<Vec<Vec3>> = clouds
            .par_iter()
            .zip(&mut tracers)
            .map(|(c, (gaussians, tracer))| {
                gaussians.prepare(c);
                tracer.trace(gaussians, &camera, 8, 1, 1, Vec3::ZERO)
            })
            .collect();
        rt_ms.push(start.elapsed().as_secs_f64() * 1e3);
        checksum = images.iter().flatten().fold(0u64, |h, v| {
            let bits = [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
            bits.iter()
                .fold(h, |h, &b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3))
        });
        let start = Instant::now();
        let drawn: Vec<_> = clouds
            .par_iter()
            .map(|c| render(c, &camera, &raster))
            .collect();
        raster_ms.push(start.elapsed().as_secs_f64() * 1e3);
        drop(drawn);
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() / 2])
    };
    let (rt_min, rt_med) = stats(&mut rt_ms);
    let (ra_min, ra_med) = stats(&mut raster_ms);
    println!(
        "{width}x{height}, {} levels: rt {rt_min:.2} / {rt_med:.2} ms, raster {ra_min:.2} / {ra_med:.2} ms (min / median), rt/raster {:.2}x (medians); checksum {checksum:016x}",
        clouds.len(),
        rt_med / ra_med
    );
}
