//! Stochastic splatting (the Vulkan Gaussian-splatting sample's stochastic modes, section 1, after
//! Kheradmand et al. 2025): no depth sort. Per
//! pixel sample, every splat whose alpha reaches 1/255 is accepted with probability alpha (a
//! hash of seed, pixel, sample and Gaussian id) and written as opaque if it is nearer than what
//! the pixel holds (the depth test). The pixel's colour is the nearest accepted splat's, or the
//! background. Its expectation is the sorted composite without the early stop at T < 1e-4:
//! splat i wins with probability `alpha_i prod_{nearer j} (1 - alpha_j)`.

use crate::camera::Camera;
use crate::cloud::GaussianCloud;
use crate::random::{hash32, unit_f32};
use crate::raster::{
    RasterConfig, RenderOutput, TILE, bin_for_stochastic, splat_alpha, tile_pixels,
};
use rayon::prelude::*;
use render_base::Control;

/// Renders `samples` stochastic samples per pixel and returns their mean (transmittance is the
/// fraction of samples that accepted nothing).
pub fn render_stochastic(
    cloud: &GaussianCloud<f32>,
    camera: &Camera,
    config: &RasterConfig,
    samples: u32,
    seed: u32,
) -> RenderOutput<f32> {
    render_stochastic_with(cloud, camera, config, samples, seed, &Control::none()).0
}

/// [`render_stochastic`] that stops when `control` is cancelled (read before every sample),
/// each pixel keeping the mean of the samples it finished (a pixel that finished none is the
/// background); reports each pixel's samples to it. Also returns whether it was cancelled.
/// Uncancelled, the image is [`render_stochastic`]'s bit for bit.
pub fn render_stochastic_with(
    cloud: &GaussianCloud<f32>,
    camera: &Camera,
    config: &RasterConfig,
    samples: u32,
    seed: u32,
    control: &Control,
) -> (RenderOutput<f32>, bool) {
    let (w, h) = (camera.width, camera.height);
    let (splats, ids, entries, tile_ranges, tiles_x) = bin_for_stochastic(cloud, camera, config);
    let tile_px = (TILE * TILE) as usize;
    let bg = config.background;
    let tiles: Vec<(Vec<[f32; 3]>, Vec<f32>)> = tile_ranges
        .par_iter()
        .enumerate()
        .map(|(ti, &(a, b))| {
            let list = &entries[a as usize..b as usize];
            let tx = ti as u32 % tiles_x;
            let ty = ti as u32 / tiles_x;
            let mut col = vec![[0.0f32; 3]; tile_px];
            let mut tr = vec![1.0f32; tile_px];
            for j in 0..TILE {
                for i in 0..TILE {
                    let (x, y) = (tx * TILE + i, ty * TILE + j);
                    if x >= w || y >= h {
                        continue;
                    }
                    let pixel = y * w + x;
                    let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                    let mut sum = [0.0f64; 3];
                    let mut empty = 0u32;
                    let mut taken = 0u32;
                    for s in 0..samples {
                        if control.cancelled() {
                            break;
                        }
                        taken += 1;
                        let mut best_depth = f32::INFINITY;
                        let mut best = bg;
                        for &e in list {
                            let sp = &splats[e as usize];
                            if !(sp.depth < best_depth) {
                                continue;
                            }
                            let Some((alpha, ..)) = splat_alpha(sp, px, py) else {
                                continue;
                            };
                            if unit_f32(hash32(&[seed, pixel, s, ids[e as usize]])) < alpha {
                                best_depth = sp.depth;
                                best = sp.color;
                            }
                        }
                        if best_depth == f32::INFINITY {
                            empty += 1;
                        }
                        for c in 0..3 {
                            sum[c] += best[c] as f64;
                        }
                    }
                    let p = (j * TILE + i) as usize;
                    control.progress(taken as u64);
                    if taken == 0 {
                        col[p] = bg;
                        tr[p] = 1.0;
                        continue;
                    }
                    col[p] = sum.map(|v| (v / taken as f64) as f32);
                    tr[p] = empty as f32 / taken as f32;
                }
            }
            (col, tr)
        })
        .collect();
    let mut out = RenderOutput {
        width: w,
        height: h,
        color: vec![[0.0; 3]; (w * h) as usize],
        transmittance: vec![1.0; (w * h) as usize],
        depth: None,
    };
    for (ti, (col, tr)) in tiles.iter().enumerate() {
        for (x, y, p) in tile_pixels(ti, tiles_x, w, h) {
            let q = (y * w + x) as usize;
            out.color[q] = col[p];
            out.transmittance[q] = tr[p];
        }
    }
    (out, control.cancelled())
}
