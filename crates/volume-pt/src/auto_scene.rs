//! A scene for a bare volume file: `gscache render VOLUME` with no TOML.
//!
//! What it chooses, and why:
//! - **Transfer function.** The window is the 0.5th to 99.5th percentile of the voxels (a
//!   sample of at most about a million of them), so a few outliers do not squeeze the data into
//!   a corner of it. What is made visible is what lies above Otsu's threshold on that window's
//!   histogram: the split between the two classes of values that best separates them, which on
//!   CT and MRI is air against the body and on simulations empty space against the structure.
//!   Opacity ramps from 0 at the threshold to 1 at the window's top; colour follows a
//!   [`Colormap`] over the same range.
//! - **Density.** At opacity 1 a ray crossing the box's mean side meets an optical depth of
//!   [`OPTICAL_DEPTH_ACROSS`], the order of the bundled scenes (neghip: 38).
//! - **Camera.** A three-quarter view of the box's centre, at the distance where its bounding
//!   sphere fills the vertical field of view; up is +z for NIfTI (the head-foot axis of
//!   RAS-oriented scans), +y otherwise.
//! - **Light.** A distant key light from above, behind the camera's left shoulder (a distant
//!   light is never seen by the camera, so no light disc sits in the image) and a dim grey
//!   environment as fill and background.
//!
//! The choice is a [`SceneFile`] written as TOML text, so it is printed, saved
//! (`--save-scene`) and edited like any scene, and loaded by the same code.

use crate::clip::Clipping;
use crate::colormap::Colormap;
use crate::error::Result;
use crate::grid::ScalarGrid;
use crate::integrator::IntegratorKind;
use crate::io::{Format, LoadedVolume, ReadHints, read_volume};
use crate::lights::{DistantLight, Light};
use crate::phase::Phase;
use crate::scene::{
    CameraDesc, EnvironmentDesc, LightDesc, OutputDesc, RenderDesc, Scene, SceneFile, TfPoint,
    TransferDesc, VolumeDesc, build_scene_with_volume,
};
use glam::Vec3;
use hdr_image::ToneMap;
use std::path::{Path, PathBuf};

/// Optical depth at opacity 1 across the box's mean side.
pub const OPTICAL_DEPTH_ACROSS: f32 = 40.0;

/// Bins of the histogram Otsu's threshold is taken on.
const BINS: usize = 256;

/// What the automatic scene found in the volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeStats {
    /// The 0.5th and 99.5th percentiles of the sampled voxels.
    pub window: (f32, f32),
    /// Otsu's threshold on the window, as a fraction of it (0..1).
    pub threshold: f32,
}

/// The percentiles and Otsu's threshold of `grid`'s values (see the module docs).
pub fn volume_stats(grid: &ScalarGrid) -> VolumeStats {
    // About a million voxels, spread over the box (a streamed grid's come from its survey;
    // one it cannot give leaves the default window).
    let mut values = grid
        .strided_values(crate::grid::histogram_stride(grid.dims()))
        .unwrap_or_default();
    values.retain(|v| v.is_finite());
    if values.is_empty() {
        return VolumeStats {
            window: (0.0, 1.0),
            threshold: 0.5,
        };
    }
    values.sort_by(f32::total_cmp);
    let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
    let (lo, mut hi) = (at(0.005), at(0.995));
    if !(hi > lo) {
        // A (nearly) constant volume: widen the window so that it is not empty.
        hi = values[values.len() - 1].max(lo + 1.0);
    }
    let mut histogram = [0u64; BINS];
    for &v in &values {
        let u = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
        histogram[((u * BINS as f32) as usize).min(BINS - 1)] += 1;
    }
    VolumeStats {
        window: (lo, hi),
        threshold: otsu(&histogram),
    }
}

/// Otsu's threshold of a histogram, as a fraction of its range: the split that maximises the
/// variance between the classes below and above it.
pub fn otsu(histogram: &[u64]) -> f32 {
    let total: f64 = histogram.iter().map(|&c| c as f64).sum();
    let sum_all: f64 = histogram
        .iter()
        .enumerate()
        .map(|(i, &c)| i as f64 * c as f64)
        .sum();
    let (mut w0, mut sum0) = (0.0f64, 0.0f64);
    let (mut best, mut best_split) = (-1.0f64, histogram.len() / 2);
    for (i, &c) in histogram.iter().enumerate().take(histogram.len() - 1) {
        w0 += c as f64;
        sum0 += i as f64 * c as f64;
        let w1 = total - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let (m0, m1) = (sum0 / w0, (sum_all - sum0) / w1);
        let between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if between > best {
            best = between;
            best_split = i + 1;
        }
    }
    best_split as f32 / histogram.len() as f32
}

/// The automatic scene's description (see the module docs) and the comment that opens its
/// file. `volume_file` is written as given; `size` is the box in world units.
pub fn scene_description(
    volume_file: &Path,
    format: Option<Format>,
    size: Vec3,
    stats: VolumeStats,
    colormap: Colormap,
) -> (SceneFile, String) {
    let (lo, hi) = stats.window;
    let nifti = matches!(format, Some(Format::Nifti));
    let mean_side = (size.x + size.y + size.z) / 3.0;
    let u0 = stats.threshold.clamp(0.0, 0.95);
    const STEPS: usize = 8;
    let ramp = (0..=STEPS).filter_map(|k| {
        let s = k as f32 / STEPS as f32;
        let u = u0 + (1.0 - u0) * s;
        (u > 0.0).then(|| TfPoint {
            value: u,
            color: rgb(colormap.at(s)),
            opacity: s,
        })
    });
    let points = std::iter::once(TfPoint {
        value: 0.0,
        color: rgb(colormap.at(0.0)),
        opacity: 0.0,
    })
    .chain(ramp)
    .collect();
    // A key light from above and behind the camera's left, travelling down into the volume.
    let up = if nifti { Vec3::Z } else { Vec3::Y };
    let view = view_direction(up);
    let right = view.cross(up).normalize();
    let toward_light = (up * 1.2 + view * 0.8 - right * 0.6).normalize();
    let fov = 30.0f32;
    let radius = 0.5 * size.length();
    // The bounding sphere of a box is loose (its corners are seldom filled): 0.85 of the
    // distance at which the sphere just fits frames the data, not the empty corners.
    let distance = 0.85 * radius / (0.5 * fov.to_radians()).sin();
    let description = SceneFile {
        volume: VolumeDesc::file(volume_file.display().to_string()),
        transfer: TransferDesc {
            window: Some([lo, hi]),
            density_scale: OPTICAL_DEPTH_ACROSS / mean_side.max(1e-6),
            points: Some(points),
            preset: None,
            preset_name: None,
            opacity: None,
        },
        lights: vec![LightDesc::from_light(&Light::Distant(DistantLight {
            direction: -toward_light,
            irradiance: Vec3::new(4.0, 3.9, 3.7),
        }))],
        environment: EnvironmentDesc {
            radiance: [0.30, 0.31, 0.34],
        },
        phase: Phase::HenyeyGreenstein { g: 0.2 },
        camera: CameraDesc {
            eye: (view * distance).to_array(),
            target: [0.0; 3],
            up: up.to_array(),
            fov_y: fov,
            width: 512,
            height: 512,
        },
        render: RenderDesc {
            spp: 64,
            max_depth: 64,
            integrator: IntegratorKind::Nee,
            seed: 1,
            ..RenderDesc::default()
        },
        output: OutputDesc {
            exposure: 0.0,
            tonemap: ToneMap::Aces,
        },
        clip: Clipping::default(),
        views: Vec::new(),
        channels: Vec::new(),
    };
    let comment = format!(
        "Made by `gscache render` for {} (colour map {colormap}): edit and render it as any \
         scene (docs/scene-format.md).\n\
         density_scale: an optical depth of {OPTICAL_DEPTH_ACROSS} across the box at opacity 1.\n\
         Opacity 0 below Otsu's threshold ({:.3} of the window), rising to 1 at its top.",
        volume_file.display(),
        stats.threshold
    );
    (description, comment)
}

/// From the volume's centre toward the camera: a three-quarter view, a little from above.
fn view_direction(up: Vec3) -> Vec3 {
    if up == Vec3::Z {
        // RAS: +y is anterior. From the front right, a little above.
        Vec3::new(0.55, 1.0, 0.35).normalize()
    } else {
        Vec3::new(0.6, 0.45, 1.0).normalize()
    }
}

/// A colour to three decimals, as the scene's text shows it (and as it was read back when the
/// scene was written by hand: through f64, so the renders stay the same bits).
fn rgb(c: Vec3) -> [f32; 3] {
    c.to_array()
        .map(|x| format!("{x:.3}").parse::<f64>().map_or(x, |v| v as f32))
}

/// The colours channels are composited in, as microscopists' viewers give them: green,
/// magenta, cyan, yellow, red, blue.
pub const CHANNEL_COLOURS: [[f32; 3]; 6] = [
    [0.1, 0.9, 0.2],
    [0.9, 0.1, 0.9],
    [0.1, 0.8, 0.9],
    [0.9, 0.8, 0.1],
    [0.9, 0.15, 0.1],
    [0.2, 0.3, 0.95],
];

/// The automatic scene for the volume at `path`: the scene, and its TOML text (what
/// `--save-scene` writes). The volume is read once. A store of several channels (up to six)
/// shows them composited: each in its colour of [`CHANNEL_COLOURS`], opaque from its own
/// Otsu threshold to its 99.5th percentile (the first through `[transfer]`, the others as
/// `[[channel]]` tables).
pub fn scene_for_volume(path: &Path, colormap: Colormap) -> Result<(Scene, String)> {
    let loaded: LoadedVolume = read_volume(path, &ReadHints::default())?;
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let channels = crate::io::channels(path, &ReadHints::default())?;
    if channels <= 1 {
        return scene_for_loaded(loaded, &absolute, Format::from_path(path), colormap);
    }
    let count = (channels as usize).min(CHANNEL_COLOURS.len());
    let stats = volume_stats(&loaded.grid);
    let spacing = loaded.spacing.unwrap_or(Vec3::ONE);
    let size = loaded.grid.dims().as_vec3() * spacing;
    let (mut desc, comment) =
        scene_description(&absolute, Format::from_path(path), size, stats, colormap);
    // The first channel in its colour, the ramp kept.
    if let Some(points) = desc.transfer.points.as_mut() {
        for p in points {
            p.color = CHANNEL_COLOURS[0];
        }
    }
    for (k, colour) in CHANNEL_COLOURS.iter().enumerate().take(count).skip(1) {
        let hints = ReadHints {
            zarr: crate::io::ZarrSelection {
                channel: k as u32,
                ..Default::default()
            },
            ..Default::default()
        };
        let s = volume_stats(&read_volume(path, &hints)?.grid);
        let (lo, hi) = s.window;
        desc.channels.push(crate::scene::ChannelDesc {
            index: k as u32,
            file: None,
            window: [lo + s.threshold.clamp(0.0, 0.95) * (hi - lo), hi],
            color: *colour,
            opacity: 1.0,
            density_scale: None,
        });
    }
    let comment = format!(
        "{comment}\nChannels 0 to {} composited in green, magenta, cyan, yellow, red, blue.",
        count - 1
    );
    let text = desc.to_toml(&comment)?;
    let anchor: PathBuf = absolute.with_extension("auto.toml");
    let scene = build_scene_with_volume(&anchor, desc, loaded, absolute.clone())?;
    Ok((scene, text))
}

/// [`scene_for_volume`] for a volume already in memory (a Python array); `name` is written as
/// the scene's `volume.file` and anchors its relative paths, `format` decides the up axis
/// (NIfTI: +z).
pub fn scene_for_loaded(
    loaded: LoadedVolume,
    name: &Path,
    format: Option<Format>,
    colormap: Colormap,
) -> Result<(Scene, String)> {
    let stats = volume_stats(&loaded.grid);
    let spacing = loaded.spacing.unwrap_or(Vec3::ONE);
    let size = loaded.grid.dims().as_vec3() * spacing;
    let (desc, comment) = scene_description(name, format, size, stats, colormap);
    let text = desc.to_toml(&comment)?;
    // Relative paths of the scene resolve against the volume's folder, where a saved scene
    // would sit by default.
    let anchor: PathBuf = name.with_extension("auto.toml");
    let scene = build_scene_with_volume(&anchor, desc, loaded, name.to_path_buf())?;
    Ok((scene, text))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn otsu_splits_two_separated_classes_between_them() {
        let mut h = [0u64; 256];
        for (i, c) in h.iter_mut().enumerate() {
            // Two bumps, at 40 and 200.
            let d0 = (i as f64 - 40.0) / 10.0;
            let d1 = (i as f64 - 200.0) / 10.0;
            *c = (1000.0 * (-d0 * d0).exp() + 300.0 * (-d1 * d1).exp()) as u64;
        }
        // Any split between the bumps' tails (about 60 and 180) separates them; the tails
        // decide where exactly.
        let t = otsu(&h) * 256.0;
        assert!(t > 55.0 && t < 185.0, "threshold at bin {t}");
    }

    #[test]
    fn a_sparse_volume_is_windowed_and_thresholded_above_its_empty_space() {
        // 90% zeros (empty space), 10% a structure at values 150-250.
        let dims = glam::UVec3::splat(20);
        let values: Vec<f32> = (0..8000u32)
            .map(|i| {
                if i % 10 == 0 {
                    150.0 + (i % 100) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let grid = ScalarGrid::new(dims, values).unwrap();
        let s = volume_stats(&grid);
        assert_eq!(s.window.0, 0.0);
        assert!(s.window.1 >= 240.0, "{:?}", s.window);
        // The threshold falls between the empty space (0) and the structure (150 and up).
        let t = s.window.0 + s.threshold * (s.window.1 - s.window.0);
        assert!(t > 0.0 && t < 150.0, "threshold {t}");
    }
}
