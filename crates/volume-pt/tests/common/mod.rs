//! Helpers shared by the volume-pt tests: simple media, path statistics, data paths.
#![allow(dead_code)]

use glam::{UVec3, Vec3};
use std::path::PathBuf;
use volume_pt::integrator::{PathSettings, SceneMedia, radiance};
use volume_pt::sampling::SampleStream;
use volume_pt::{Filter, Lights, Medium, Phase, ScalarGrid, TransferFunction};

/// The repository's `data/` folder.
pub fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data")
}

/// A homogeneous cube of side `size` centred on the origin: extinction `sigma`, albedo `albedo`.
pub fn homogeneous(sigma: f32, albedo: Vec3, size: f32, macrocell: u32) -> Medium {
    let grid = ScalarGrid::new(UVec3::splat(4), vec![1.0; 64]).unwrap();
    let tf = TransferFunction::from_points((0.0, 1.0), &[(0.0, albedo, 1.0)], sigma).unwrap();
    Medium::new(
        grid,
        Filter::Trilinear,
        Vec3::splat(-0.5 * size),
        Vec3::splat(size / 4.0),
        tf,
        macrocell,
    )
    .unwrap()
}

pub fn scene(medium: Medium, phase: Phase, lights: Lights) -> SceneMedia {
    SceneMedia {
        medium,
        phase,
        lights,
    }
}

/// Mean and variance of the mean (per channel, f64) of `n` paths along one ray.
pub fn path_stats(
    scene: &SceneMedia,
    settings: &PathSettings,
    origin: Vec3,
    dir: Vec3,
    n: u64,
    seed: u64,
) -> ([f64; 3], [f64; 3]) {
    let mut s = [0.0f64; 3];
    let mut s2 = [0.0f64; 3];
    for i in 0..n {
        let mut rng = SampleStream::new(seed, 0, i);
        let l = radiance(scene, settings, origin, dir, &mut rng);
        assert!(l.is_finite() && l.min_element() >= 0.0, "bad sample {l}");
        for c in 0..3 {
            s[c] += l[c] as f64;
            s2[c] += (l[c] as f64).powi(2);
        }
    }
    let nf = n as f64;
    let mean = s.map(|v| v / nf);
    let var_of_mean = [0, 1, 2].map(|c| ((s2[c] / nf - mean[c] * mean[c]).max(0.0)) / (nf - 1.0));
    (mean, var_of_mean)
}
