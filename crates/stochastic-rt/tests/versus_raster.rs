//! The `center` depth mode traced against splat-raster's image of the same asset and camera.
//! The two differ by design (the ray tracer evaluates each 3D Gaussian at its maximum along the
//! ray, the rasteriser its 2D projection), so the test holds the PSNR above a floor and checks
//! that `center` is closer to the rasteriser than `mean` is.

use glam::Vec3;
use splat_raster::io::read_ply;
use splat_raster::{Camera, RasterConfig, render};
use std::path::PathBuf;
use stochastic_rt::{DepthMode, Estimator, GaussianScene, TraceSettings, trace_image};

fn psnr(a: &[Vec3], b: &[[f32; 3]]) -> f64 {
    let mse: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            (0..3)
                .map(|c| (x[c].clamp(0.0, 1.0) as f64 - y[c].clamp(0.0, 1.0) as f64).powi(2))
                .sum::<f64>()
        })
        .sum::<f64>()
        / (3 * a.len()) as f64;
    10.0 * (1.0 / mse).log10()
}

#[test]
fn center_depth_matches_the_rasteriser() {
    let asset = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/splats/fruit_drops_minimal_inria.ply");
    let cloud = read_ply(&asset).unwrap();
    let cam = Camera::look_at(
        Vec3::new(0.74, -0.25, -2.75),
        Vec3::new(0.74, 0.12, -2.13),
        Vec3::new(0.0, -1.0, 0.0),
        50.0,
        160,
        120,
    )
    .unwrap();
    let (raster, _) = render(&cloud, &cam, &RasterConfig::default());
    let scene = GaussianScene::new(&cloud);
    let mut results = Vec::new();
    for mode in [DepthMode::Center, DepthMode::Mean] {
        let img = trace_image(
            &scene,
            &cam,
            &TraceSettings {
                estimator: Estimator::Exact,
                depth_mode: mode,
                ..Default::default()
            },
        );
        let p = psnr(&img, &raster.color);
        eprintln!("{mode:?} depth vs rasteriser: PSNR {p:.2} dB");
        results.push(p);
    }
    assert!(
        results[0] >= 25.0,
        "center-depth PSNR {:.2} dB is below the 25 dB floor",
        results[0]
    );
    assert!(
        results[0] > results[1],
        "center depth should be closer to the rasteriser than mean depth"
    );
}
