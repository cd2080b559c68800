//! The tiled rasteriser: project, bin into 16x16 tiles, sort each tile by depth, composite front
//! to back; and the backward pass over the same lists.
//!
//! Compositing per pixel (3DGS): `alpha_i = min(0.99, opacity_i exp(-d^T K_i d / 2))`, skipped
//! below 1/255; `C = sum_i c_i alpha_i T_i + T_final * background`, `T_{i+1} = T_i (1 - alpha_i)`;
//! the splat that would take `T` below 1e-4 and every splat after it are left out. Colour is
//! HDR: nothing is clamped above.
//!
//! Kernels: a tile is composited by one of two kernels with the same equations. The scalar
//! kernel here visits one pixel at a time (generic over f32/f64: the f64 path is the reference of
//! the gradient tests); the lane kernels of [`crate::simd`] take a row's pixels 8 or 4 at a time
//! (f32 only). [`RasterConfig::kernel`] chooses; the default is the widest this CPU runs.
//!
//! Where the time goes (2 cores, 300k Gaussians at 1280x720, lane kernel, 36-40 ms): the tile
//! kernels 60%, projection and binning (one pass over fixed chunks of the cloud, projected in
//! lanes) a sixth, the per-tile lists and their radix depth sort a sixth, the rest the output
//! images. The backward pass is about 1.4x that: its tile kernels, then each Gaussian's records
//! summed in tile order and its projection's adjoint in lanes (`BENCHMARKS.md`).
//!
//! Determinism: the backward pass writes one gradient record per (tile, splat) entry up to the
//! tile's last contributor, each tile's pixels in a fixed order, and sums every Gaussian's
//! records in tile order; no atomics, so gradients are bit-identical for any thread count.
//!
//! - [`binning`]: projection and binning into tiles, each tile's list sorted by depth
//!   ([`crate::depth_sort`], the radix sort the stochastic ray tracer uses too).
//! - [`forward`]: compositing a tile (the scalar kernel) and [`render`], the forward pass.
//! - [`backward`]: [`backward`], the gradients over the same lists.

use crate::camera::Camera;
use crate::cloud::{CloudGradients, GaussianCloud};
use crate::lanes::Isa;
use crate::project::*;
use crate::project_lanes::GradientBlock;
use crate::real::{Real, SplatGrad};
use crate::simd::Kernel;
use rayon::prelude::*;
use std::any::Any;
use std::sync::OnceLock;

pub use crate::tile::TILE;
use crate::tile::{TILE_PIXELS, TileOut, TilePixels};

mod backward;
mod binning;
mod forward;

pub use backward::{PixelGrads, backward};
use binning::*;
pub(crate) use binning::{bin_for_stochastic, tile_pixels};
use forward::*;
pub use forward::{render, splat_alpha};

/// Rasteriser settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterConfig {
    pub low_pass: LowPass,
    /// Gaussians whose camera-space depth is not beyond this are culled (world units).
    pub near: f32,
    pub background: [f32; 3],
    /// Also output the accumulated depth `sum_i z_i alpha_i T_i`.
    pub depth: bool,
    /// The per-pixel kernel (f32 only: the f64 path is always scalar).
    pub kernel: Kernel,
}

impl Default for RasterConfig {
    fn default() -> Self {
        Self {
            low_pass: LowPass::Classic,
            near: 0.01,
            background: [0.0; 3],
            depth: false,
            kernel: Kernel::Auto,
        }
    }
}

/// Rendered images, row-major, row 0 at the top.
#[derive(Debug, Clone)]
pub struct RenderOutput<F: Real> {
    pub width: u32,
    pub height: u32,
    pub color: Vec<[F; 3]>,
    pub transmittance: Vec<F>,
    /// Accumulated depth, when asked for.
    pub depth: Option<Vec<F>>,
}

/// What the backward pass needs from the forward pass.
#[derive(Debug, Clone)]
pub struct ForwardState<F: Real> {
    splats: Vec<Splat<F>>,
    /// Index of each splat's Gaussian.
    ids: Vec<u32>,
    /// Splat indices, tile-major, each tile sorted by depth.
    entries: Vec<u32>,
    /// Per tile, its range in `entries`.
    tile_ranges: Vec<(u32, u32)>,
    /// Per pixel, entries processed in its tile list (the last contributor + 1), tile-major.
    n_contrib: Vec<u32>,
    /// Per tile, the range of its live entries' gradient records: one record for each entry up
    /// to the tile's last contributor, tiles end to end. The entries after it (most of them
    /// where tiles saturate: 70% for 300k dense Gaussians) reach no pixel, so the backward
    /// pass neither writes nor sums records for them.
    live_ranges: Vec<(u32, u32)>,
    /// Per pixel final transmittance, tile-major.
    final_t: Vec<F>,
    tiles_x: u32,
    /// Pixel evaluations the kernel ran (lanes of the vectors it computed, live or not).
    lane_evaluations: u64,
    /// The settings of the forward pass, with the kernel that ran (never `Auto`): the backward
    /// pass must divide out the very alphas the forward pass multiplied in.
    config: RasterConfig,
    /// Where each splat's records lie, built by the first backward pass and kept for the next
    /// ones over this state (the cache's warm start runs three).
    index: OnceLock<SplatIndex>,
}

/// Per splat, the positions of its live records in tile order (a counting sort of the live
/// entries: its records are `slots[starts[s]..starts[s + 1]]`), and per Gaussian its splat
/// (`u32::MAX`: culled). It depends on the forward pass alone, not on the gradients.
#[derive(Debug, Clone)]
struct SplatIndex {
    starts: Vec<u32>,
    slots: Vec<u32>,
    splat_of: Vec<u32>,
}

impl SplatIndex {
    /// Splat `si`'s records summed in tile order (the same order on any thread count).
    fn total<F: Real>(&self, si: usize, records: &[SplatGrad<F>]) -> SplatGrad<F> {
        let mut total = SplatGrad::<F>::default();
        for &pos in &self.slots[self.starts[si] as usize..self.starts[si + 1] as usize] {
            total.add(&records[pos as usize]);
        }
        total
    }

    fn build(
        entries: &[u32],
        tile_ranges: &[(u32, u32)],
        live_ranges: &[(u32, u32)],
        ids: &[u32],
        n_splats: usize,
        gaussians: usize,
    ) -> Self {
        // The live entries of each tile, with their record positions.
        let live = || {
            tile_ranges
                .iter()
                .zip(live_ranges)
                .flat_map(|(&(a, _), &(la, lb))| {
                    let list = &entries[a as usize..(a + lb - la) as usize];
                    list.iter().zip(la..lb)
                })
        };
        let mut starts = vec![0u32; n_splats + 1];
        for (&e, _) in live() {
            starts[e as usize + 1] += 1;
        }
        for i in 0..n_splats {
            starts[i + 1] += starts[i];
        }
        let mut slots = vec![0u32; starts[n_splats] as usize];
        let mut cursor = starts.clone();
        for (&e, pos) in live() {
            slots[cursor[e as usize] as usize] = pos;
            cursor[e as usize] += 1;
        }
        let mut splat_of = vec![u32::MAX; gaussians];
        for (si, &g) in ids.iter().enumerate() {
            splat_of[g as usize] = si as u32;
        }
        Self {
            starts,
            slots,
            splat_of,
        }
    }
}

impl<F: Real> ForwardState<F> {
    /// The per-pixel kernel that composited the frame.
    pub fn kernel(&self) -> Kernel {
        self.config.kernel
    }
    /// Per pixel final transmittance, row-major: the forward pass's
    /// [`RenderOutput::transmittance`] again, for a caller that kept the state but not the output.
    pub fn transmittance(&self, camera: &Camera) -> Vec<F> {
        tile_major_to_rows(&self.final_t, camera.width, camera.height)
    }
    /// Number of (tile, splat) pairs.
    pub fn entry_count(&self) -> usize {
        self.entries.len()
    }
    /// Number of splats that survived culling.
    pub fn visible_count(&self) -> usize {
        self.splats.len()
    }
    /// Pixel evaluations the forward pass ran: lanes of every vector whose alpha it computed
    /// (masked lanes included), or pixels for the scalar kernel. With a kernel's operation count
    /// per lane, the measure of how close it runs to the core's arithmetic peak.
    pub fn lane_evaluations(&self) -> u64 {
        self.lane_evaluations
    }
    /// Splat-pixel pairs in each splat's rectangle within its tiles, whether or not the pixel
    /// was saturated by then: the work a kernel without early termination would do.
    pub fn evaluations(&self) -> u64 {
        (0..self.tile_ranges.len())
            .into_par_iter()
            .map(|ti| {
                let (a, b) = self.tile_ranges[ti];
                let (x0, y0) = (
                    (ti as u32 % self.tiles_x) * TILE,
                    (ti as u32 / self.tiles_x) * TILE,
                );
                let mut n = 0u64;
                for &e in &self.entries[a as usize..b as usize] {
                    let s = &self.splats[e as usize];
                    let [ax, ay, bx, by] = rect_in_tile(s, [x0, y0]);
                    if ax <= bx && ay <= by {
                        n += ((bx - ax + 1) * (by - ay + 1)) as u64;
                    }
                }
                n
            })
            .sum()
    }
}
