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

use crate::camera::Camera;
use crate::cloud::{CloudGradients, GaussianCloud};
use crate::project::*;
use crate::project_lanes::GradientBlock;
use crate::real::{Real, SplatGrad};
use crate::simd::{Isa, Kernel};
use rayon::prelude::*;
use std::any::Any;
use std::sync::OnceLock;

pub use crate::tile::TILE;
use crate::tile::{TILE_PIXELS, TileOut, TilePixels};

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

struct Bins<F: Real> {
    splats: Vec<Splat<F>>,
    ids: Vec<u32>,
    entries: Vec<u32>,
    tile_ranges: Vec<(u32, u32)>,
}

fn tile_span(s: &[u32; 4]) -> (u32, u32, u32, u32) {
    (s[0] / TILE, s[1] / TILE, s[2] / TILE, s[3] / TILE)
}

/// Gaussians per chunk of the parallel projection and binning: about 64 chunks, so that a
/// cache level's 5-20 thousand Gaussians still spread over many cores, but never under 1024
/// (each chunk keeps a count per tile) nor over 8192. It depends on the cloud's size alone,
/// never on the threads.
fn chunk_size(gaussians: usize) -> usize {
    (gaussians / 64).clamp(1024, 8192)
}

/// One chunk's splats binned into tiles: tile `t`'s list is `keys[offsets[t]..offsets[t + 1]]`,
/// in splat order. A key holds the splat's index within the chunk in its low 32 bits and, when the lists are to
/// be depth sorted, the f32 bits of its depth above them (positive floats order as their bits,
/// so sorting the keys sorts by depth, ties to the lower index). The keys are made here, where
/// the splats are read in order, and not by a later pass that would look every entry's splat up
/// again in scattered order.
struct ChunkBins {
    offsets: Vec<u32>,
    keys: Vec<u64>,
}

impl ChunkBins {
    /// Bins `splats` into `n_tiles` tiles of a grid `tiles_x` wide (a counting sort).
    fn new<F: Real>(splats: &[Splat<F>], tiles_x: u32, n_tiles: usize, depth_keys: bool) -> Self {
        let mut offsets = vec![0u32; n_tiles + 1];
        for s in splats {
            let (tx0, ty0, tx1, ty1) = tile_span(&s.rect);
            for ty in ty0..=ty1 {
                for tx in tx0..=tx1 {
                    offsets[(ty * tiles_x + tx) as usize + 1] += 1;
                }
            }
        }
        for t in 0..n_tiles {
            offsets[t + 1] += offsets[t];
        }
        let mut cursor = offsets.clone();
        let mut keys = vec![0u64; offsets[n_tiles] as usize];
        for (i, s) in splats.iter().enumerate() {
            let depth_bits = if depth_keys {
                ((s.depth.as_f64() as f32).to_bits() as u64) << 32
            } else {
                0
            };
            let key = depth_bits | i as u64;
            let (tx0, ty0, tx1, ty1) = tile_span(&s.rect);
            for ty in ty0..=ty1 {
                for tx in tx0..=tx1 {
                    let t = (ty * tiles_x + tx) as usize;
                    keys[cursor[t] as usize] = key;
                    cursor[t] += 1;
                }
            }
        }
        Self { offsets, keys }
    }

    fn len(&self, tile: usize) -> u32 {
        self.offsets[tile + 1] - self.offsets[tile]
    }

    fn list(&self, tile: usize) -> &[u64] {
        &self.keys[self.offsets[tile] as usize..self.offsets[tile + 1] as usize]
    }
}

/// Projects the cloud and bins its splats into tiles; each tile's list is sorted by (depth,
/// Gaussian id) when `sort`.
///
/// In parallel, and as a serial pass would: fixed chunks of Gaussians are projected and binned
/// on their own, each while its splats are still in cache; then the splats are laid end to end
/// in Gaussian order and each tile concatenates its chunks' lists, every key moved by its
/// chunk's first splat. The chunks depend on the cloud's size alone, so the lists do not depend
/// on the thread count. (Serial, the binning was a sixth of a 300k-Gaussian frame at 2 threads
/// and bound the lookup's scaling: issue 31.)
fn project_and_bin<F: Real>(
    cloud: &GaussianCloud<F>,
    cam: &CameraTerms<F>,
    config: &RasterConfig,
    sort: bool,
) -> Bins<F> {
    let near = F::c(config.near as f64);
    let near_f32 = config.near;
    let tiles_x = cam.width.div_ceil(TILE);
    let n_tiles = (tiles_x * cam.height.div_ceil(TILE)) as usize;
    let chunk = chunk_size(cloud.len());
    // The lane kernels' instruction set projects f32 clouds in lanes too.
    let isa = Isa::of(resolved_kernel::<F>(config.kernel));
    let lanes = (isa, as_f32(cloud), as_f32(cam));
    let chunks: Vec<(Vec<Splat<F>>, Vec<u32>, ChunkBins)> = (0..cloud.len().div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let gaussians = c * chunk..((c + 1) * chunk).min(cloud.len());
            let mut splats = Vec::with_capacity(gaussians.len());
            let mut ids = Vec::with_capacity(gaussians.len());
            match (lanes, as_f32_mut(&mut splats)) {
                ((Some(isa), Some(cloud), Some(cam)), Some(splats)) => isa.project_range(
                    cloud,
                    gaussians,
                    cam,
                    config.low_pass,
                    near_f32,
                    splats,
                    &mut ids,
                ),
                _ => {
                    for g in gaussians {
                        if let Some(s) = project(cloud, g, cam, config.low_pass, near) {
                            splats.push(s);
                            ids.push(g as u32);
                        }
                    }
                }
            }
            let bins = ChunkBins::new(&splats, tiles_x, n_tiles, sort);
            (splats, ids, bins)
        })
        .collect();
    // Each chunk's first splat, and the splats and their Gaussians end to end.
    let mut firsts = Vec::with_capacity(chunks.len());
    let mut n_splats = 0u64;
    for (splats, _, _) in &chunks {
        firsts.push(n_splats);
        n_splats += splats.len() as u64;
    }
    let mut splats = vec![Splat::<F>::default(); n_splats as usize];
    let mut ids = vec![0u32; n_splats as usize];
    {
        let mut splat_parts = Vec::with_capacity(chunks.len());
        let mut id_parts = Vec::with_capacity(chunks.len());
        let (mut splat_rest, mut id_rest) = (&mut splats[..], &mut ids[..]);
        for (part, _, _) in &chunks {
            let (head, tail) = splat_rest.split_at_mut(part.len());
            splat_parts.push(head);
            splat_rest = tail;
            let (head, tail) = id_rest.split_at_mut(part.len());
            id_parts.push(head);
            id_rest = tail;
        }
        (splat_parts, id_parts, &chunks).into_par_iter().for_each(
            |(splat_out, id_out, (part, part_ids, _))| {
                splat_out.copy_from_slice(part);
                id_out.copy_from_slice(part_ids);
            },
        );
    }
    let sizes: Vec<u32> = (0..n_tiles)
        .into_par_iter()
        .map(|t| chunks.iter().map(|(_, _, c)| c.len(t)).sum())
        .collect();
    let mut tile_ranges = Vec::with_capacity(n_tiles);
    let mut end = 0u32;
    for &n in &sizes {
        tile_ranges.push((end, end + n));
        end += n;
    }
    let mut keys = vec![0u64; end as usize];
    let mut entries = vec![0u32; end as usize];
    let exact_f32 = std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>();
    let key_lists = split_by_tile(&mut keys, &tile_ranges);
    let lists = split_by_tile(&mut entries, &tile_ranges);
    (key_lists, lists)
        .into_par_iter()
        .enumerate()
        .for_each_init(Vec::new, |scratch, (t, (keys, list))| {
            let mut k = 0;
            for ((_, _, c), &first) in chunks.iter().zip(&firsts) {
                let part = c.list(t);
                for (out, &key) in keys[k..k + part.len()].iter_mut().zip(part) {
                    *out = key + first;
                }
                k += part.len();
            }
            if sort {
                depth_order(keys, scratch, list);
            } else {
                for (e, k) in list.iter_mut().zip(keys.iter()) {
                    *e = *k as u32;
                }
            }
            if sort && !exact_f32 {
                // Wider floats: order by the exact depth (the f32 keys have put it nearly there).
                list.sort_by(|&x, &y| {
                    let (sx, sy) = (&splats[x as usize], &splats[y as usize]);
                    sx.depth
                        .partial_cmp(&sy.depth)
                        .unwrap_or(std::cmp::Ordering::Equal)
                        .then(ids[x as usize].cmp(&ids[y as usize]))
                });
            }
        });
    Bins {
        splats,
        ids,
        entries,
        tile_ranges,
    }
}

/// Lists shorter than this are sorted by comparison; longer ones by radix.
const RADIX_MIN: usize = 96;

/// Writes the splat indices of a tile's `keys` to `list` in depth order, ties in index order.
/// A key is a depth's f32 bits (positive, so ordered as the depths) above a 32-bit index;
/// `list` has one entry a key. The stochastic ray tracer's camera grid orders its Gaussians
/// with it too.
///
/// The keys arrive in index order (the chunks' lists concatenated), so a stable sort on the
/// depth bits alone gives the order of sorting the whole keys. Long lists take a least
/// significant digit radix sort over the depth's four bytes, skipping a byte that all keys
/// share (the exponent byte usually is) and scattering the last pass straight into `list`:
/// at the 300-odd entries of a 300k-Gaussian frame's tile it is about twice as fast as
/// comparison sorting them, with no branch to mispredict.
pub fn depth_order(keys: &mut [u64], scratch: &mut Vec<u64>, list: &mut [u32]) {
    if keys.len() < RADIX_MIN {
        keys.sort_unstable();
        for (e, k) in list.iter_mut().zip(keys.iter()) {
            *e = *k as u32;
        }
        return;
    }
    let digit = |key: u64, byte: usize| ((key >> (32 + 8 * byte)) & 0xff) as usize;
    let mut counts = [[0u32; 256]; 4];
    for &key in keys.iter() {
        for (byte, count) in counts.iter_mut().enumerate() {
            count[digit(key, byte)] += 1;
        }
    }
    let n = keys.len() as u32;
    let mut passes = [0usize; 4];
    let mut n_passes = 0;
    for byte in 0..4 {
        if counts[byte][digit(keys[0], byte)] != n {
            passes[n_passes] = byte;
            n_passes += 1;
        }
    }
    scratch.resize(keys.len(), 0);
    let (mut from, mut to) = (keys, &mut scratch[..]);
    for (i, &byte) in passes[..n_passes].iter().enumerate() {
        let mut offsets = [0u32; 256];
        let mut sum = 0;
        for (offset, &count) in offsets.iter_mut().zip(&counts[byte]) {
            *offset = sum;
            sum += count;
        }
        if i + 1 == n_passes {
            for &key in from.iter() {
                let slot = &mut offsets[digit(key, byte)];
                list[*slot as usize] = key as u32;
                *slot += 1;
            }
            return;
        }
        for &key in from.iter() {
            let slot = &mut offsets[digit(key, byte)];
            to[*slot as usize] = key;
            *slot += 1;
        }
        std::mem::swap(&mut from, &mut to);
    }
    // Every key at one depth: index order already.
    for (e, k) in list.iter_mut().zip(from.iter()) {
        *e = *k as u32;
    }
}

/// `values` (tile-major, like the entries) cut into each tile's slice.
fn split_by_tile<'a, T>(values: &'a mut [T], tile_ranges: &[(u32, u32)]) -> Vec<&'a mut [T]> {
    let mut slices = Vec::with_capacity(tile_ranges.len());
    let mut rest = values;
    for &(a, b) in tile_ranges {
        let (head, tail) = rest.split_at_mut((b - a) as usize);
        slices.push(head);
        rest = tail;
    }
    slices
}

/// Projected splats binned into tiles without sorting (for stochastic splatting): the splats,
/// their Gaussian ids, the tile-major entries, each tile's range, and the tiles per row.
#[allow(clippy::type_complexity)]
pub(crate) fn bin_for_stochastic(
    cloud: &GaussianCloud<f32>,
    camera: &Camera,
    config: &RasterConfig,
) -> (Vec<Splat<f32>>, Vec<u32>, Vec<u32>, Vec<(u32, u32)>, u32) {
    let cam = CameraTerms::<f32>::new(camera);
    let b = project_and_bin(cloud, &cam, config, false);
    (
        b.splats,
        b.ids,
        b.entries,
        b.tile_ranges,
        camera.width.div_ceil(TILE),
    )
}

/// The pixels of tile `ti` inside the image: (x, y, index within the tile).
pub(crate) fn tile_pixels(
    ti: usize,
    tiles_x: u32,
    w: u32,
    h: u32,
) -> impl Iterator<Item = (u32, u32, usize)> {
    let (x0, y0) = ((ti as u32 % tiles_x) * TILE, (ti as u32 / tiles_x) * TILE);
    (0..TILE * TILE).filter_map(move |k| {
        let (x, y) = (x0 + k % TILE, y0 + k / TILE);
        (x < w && y < h).then_some((x, y, k as usize))
    })
}

/// Evaluates alpha of splat `s` at pixel centre `(px, py)`; None when it is skipped.
#[inline(always)]
pub fn splat_alpha<F: Real>(s: &Splat<F>, px: F, py: F) -> Option<(F, F, F, F)> {
    let dx = px - s.xy[0];
    let dy = py - s.xy[1];
    let power = -F::c(0.5) * (s.conic[0] * dx * dx + s.conic[2] * dy * dy) - s.conic[1] * dx * dy;
    // Most evaluations are pixels a splat does not reach: reject them before `exp`.
    if power > F::zero() || power < s.power_min {
        return None;
    }
    let gauss = power.exp();
    let alpha = (s.opacity * gauss).min(F::c(ALPHA_MAX));
    if alpha < F::c(ALPHA_MIN) {
        return None;
    }
    Some((alpha, gauss, dx, dy))
}

/// Splat `s`'s pixel rectangle clipped to the tile at `origin`: inclusive x0, y0, x1, y1 (empty
/// when x0 > x1 or y0 > y1).
fn rect_in_tile<F: Real>(s: &Splat<F>, origin: [u32; 2]) -> [u32; 4] {
    let [x0, y0] = origin;
    [
        s.rect[0].max(x0),
        s.rect[1].max(y0),
        s.rect[2].min(x0 + TILE - 1),
        s.rect[3].min(y0 + TILE - 1),
    ]
}

/// The kernel that runs for float type `F`: lanes only exist for f32.
fn resolved_kernel<F: Real>(asked: Kernel) -> Kernel {
    if std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>() {
        asked.resolve()
    } else {
        Kernel::Scalar
    }
}

/// `x` as its f32 instance, when `F` is f32 (generic code hands f32 data to the lane kernels
/// without `unsafe`).
fn as_f32<T: Any, U: Any>(x: &T) -> Option<&U> {
    (x as &dyn Any).downcast_ref()
}

fn as_f32_mut<T: Any, U: Any>(x: &mut T) -> Option<&mut U> {
    (x as &mut dyn Any).downcast_mut()
}

/// Front-to-back compositing of one tile, one pixel at a time: the reference kernel.
///
/// Splat-major: each splat visits only the tile pixels inside its rectangle, in depth order, so
/// every pixel still sees its splats front to back with the same arithmetic as a per-pixel loop.
fn forward_tile_scalar<F: Real>(
    splats: &[Splat<F>],
    list: &[u32],
    origin: [u32; 2],
    size: [u32; 2],
    want_depth: bool,
    out: &mut TileOut<F>,
) {
    let ([x0, y0], [w, h]) = (origin, size);
    let t_min = F::c(T_MIN);
    let mut done = [false; TILE_PIXELS];
    let mut active = 0usize;
    for j in 0..TILE {
        for i in 0..TILE {
            if x0 + i >= w || y0 + j >= h {
                done[(j * TILE + i) as usize] = true;
            } else {
                active += 1;
            }
        }
    }
    // Pixel-centre coordinates of the tile's columns and rows, converted once.
    let cx: [F; TILE as usize] = std::array::from_fn(|i| F::c((x0 + i as u32) as f64 + 0.5));
    let cy: [F; TILE as usize] = std::array::from_fn(|j| F::c((y0 + j as u32) as f64 + 0.5));
    for (k, &si) in list.iter().enumerate() {
        if active == 0 {
            break;
        }
        let s = &splats[si as usize];
        let [ax, ay, bx, by] = rect_in_tile(s, [x0, y0]);
        for y in ay..=by {
            let py = cy[(y - y0) as usize];
            for x in ax..=bx {
                let p = ((y - y0) * TILE + (x - x0)) as usize;
                if done[p] {
                    continue;
                }
                out.lane_evaluations += 1;
                let Some((alpha, _, _, _)) = splat_alpha(s, cx[(x - x0) as usize], py) else {
                    continue;
                };
                let t = out.t[p];
                let next_t = t * (F::one() - alpha);
                if next_t < t_min {
                    done[p] = true;
                    active -= 1;
                    continue;
                }
                let wgt = alpha * t;
                let c = &mut out.color[p];
                for ch in 0..3 {
                    c[ch] = c[ch] + wgt * s.color[ch];
                }
                if want_depth {
                    out.depth[p] = out.depth[p] + wgt * s.depth;
                }
                out.t[p] = next_t;
                out.n[p] = k as u32 + 1;
            }
        }
    }
}

/// A row-major `w` x `h` image from tile-major values (each tile's 16x16 pixels in a run,
/// tiles row by row), a row at a time in parallel, each tile's stretch of the row copied whole.
fn tile_major_to_rows<T: Copy + Default + Send + Sync>(tile_major: &[T], w: u32, h: u32) -> Vec<T> {
    let tile = TILE as usize;
    let tiles_x = w.div_ceil(TILE) as usize;
    let mut img = vec![T::default(); (w * h) as usize];
    img.par_chunks_mut(w as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let (ty, py) = (y / tile, y % tile);
            for (tx, run) in row.chunks_mut(tile).enumerate() {
                let from = (ty * tiles_x + tx) * TILE_PIXELS + py * tile;
                run.copy_from_slice(&tile_major[from..from + run.len()]);
            }
        });
    img
}

/// Renders the cloud; returns the images and the state the backward pass needs.
pub fn render<F: Real>(
    cloud: &GaussianCloud<F>,
    camera: &Camera,
    config: &RasterConfig,
) -> (RenderOutput<F>, ForwardState<F>) {
    let cam = CameraTerms::<F>::new(camera);
    let (w, h) = (camera.width, camera.height);
    let tiles_x = w.div_ceil(TILE);
    let tiles_y = h.div_ceil(TILE);
    let bins = project_and_bin(cloud, &cam, config, true);
    let bg = config.background.map(|v| F::c(v as f64));
    let tile_px = TILE_PIXELS;
    let n_tiles = (tiles_x * tiles_y) as usize;

    let kernel = resolved_kernel::<F>(config.kernel);
    let isa = Isa::of(kernel);
    let splats_f32 = as_f32::<_, Vec<Splat<f32>>>(&bins.splats);
    // Tile-major outputs, written in parallel one tile each; the backward pass reads the counts
    // and final transmittances in this order.
    let tile_major = n_tiles * tile_px;
    let mut color_tm = vec![[F::zero(); 3]; tile_major];
    let mut final_t = vec![F::one(); tile_major];
    let mut n_contrib = vec![0u32; tile_major];
    let mut depth_tm = vec![F::zero(); if config.depth { tile_major } else { 0 }];
    let mut depth_chunks: Vec<Option<&mut [F]>> = if config.depth {
        depth_tm.chunks_mut(tile_px).map(Some).collect()
    } else {
        (0..n_tiles).map(|_| None).collect()
    };
    let lane_evaluations = (
        color_tm.par_chunks_mut(tile_px),
        final_t.par_chunks_mut(tile_px),
        n_contrib.par_chunks_mut(tile_px),
        depth_chunks.par_iter_mut(),
    )
        .into_par_iter()
        .enumerate()
        .map(|(ti, (color, t, n, depth))| {
            let (a, b) = bins.tile_ranges[ti];
            let list = &bins.entries[a as usize..b as usize];
            let origin = [(ti as u32 % tiles_x) * TILE, (ti as u32 / tiles_x) * TILE];
            let mut out = TileOut::new();
            match (isa, splats_f32, as_f32_mut(&mut out)) {
                (Some(isa), Some(splats), Some(out)) => {
                    isa.forward_tile(splats, list, origin, [w, h], config.depth, out)
                }
                _ => {
                    forward_tile_scalar(&bins.splats, list, origin, [w, h], config.depth, &mut out)
                }
            }
            for p in 0..tile_px {
                let (tp, c) = (out.t[p], out.color[p]);
                color[p] = [c[0] + tp * bg[0], c[1] + tp * bg[1], c[2] + tp * bg[2]];
            }
            t.copy_from_slice(&out.t);
            n.copy_from_slice(&out.n);
            if let Some(d) = depth {
                d.copy_from_slice(&out.depth);
            }
            out.lane_evaluations
        })
        .sum();

    // Each tile's live entries: up to its last contributor.
    let live_counts: Vec<u32> = n_contrib
        .par_chunks(tile_px)
        .map(|n| n.iter().copied().max().unwrap_or(0))
        .collect();
    let mut live_ranges = Vec::with_capacity(n_tiles);
    let mut live_end = 0u32;
    for &n in &live_counts {
        live_ranges.push((live_end, live_end + n));
        live_end += n;
    }
    let color = tile_major_to_rows(&color_tm, w, h);
    let transmittance = tile_major_to_rows(&final_t, w, h);
    let depth = config.depth.then(|| tile_major_to_rows(&depth_tm, w, h));
    let state = ForwardState {
        splats: bins.splats,
        ids: bins.ids,
        entries: bins.entries,
        tile_ranges: bins.tile_ranges,
        n_contrib,
        live_ranges,
        final_t,
        tiles_x,
        lane_evaluations,
        config: RasterConfig { kernel, ..*config },
        index: OnceLock::new(),
    };
    (
        RenderOutput {
            width: w,
            height: h,
            color,
            transmittance,
            depth,
        },
        state,
    )
}

/// Upstream gradients per pixel, row-major.
#[derive(Debug, Clone, Copy)]
pub struct PixelGrads<'a, F: Real> {
    pub color: &'a [[F; 3]],
    /// Gradient with respect to the final transmittance (alpha = 1 - T), if the loss uses it.
    pub transmittance: Option<&'a [F]>,
    /// Gradient with respect to the accumulated depth, if the loss uses it.
    pub depth: Option<&'a [F]>,
}

/// Gradients of the loss with respect to every parameter of `cloud`.
pub fn backward<F: Real>(
    cloud: &GaussianCloud<F>,
    camera: &Camera,
    state: &ForwardState<F>,
    grads: PixelGrads<'_, F>,
) -> CloudGradients<F> {
    let cam = CameraTerms::<F>::new(camera);
    let (w, h) = (camera.width, camera.height);
    let bg = state.config.background.map(|v| F::c(v as f64));
    let zero = F::zero();

    let isa = Isa::of(state.config.kernel);
    let splats_f32 = as_f32::<_, Vec<Splat<f32>>>(&state.splats);
    // One record per live entry (tile-major, like `entries`), written tile by tile.
    let live_records = state.live_ranges.last().map_or(0, |r| r.1) as usize;
    // Zeroed in parallel: a serial fill is a fixed cost that no number of threads shortens.
    let mut records = Vec::with_capacity(live_records);
    records.par_extend(
        (0..live_records)
            .into_par_iter()
            .map(|_| SplatGrad::<F>::default()),
    );
    let per_tile = split_by_tile(&mut records, &state.live_ranges);
    per_tile.into_par_iter().enumerate().for_each(|(ti, rec)| {
        let a = state.tile_ranges[ti].0 as usize;
        let list = &state.entries[a..a + rec.len()];
        if list.is_empty() {
            return;
        }
        let origin = [
            (ti as u32 % state.tiles_x) * TILE,
            (ti as u32 / state.tiles_x) * TILE,
        ];
        let mut input = TilePixels {
            origin,
            contributors: [0; TILE_PIXELS],
            dl_dc: [[zero; 3]; TILE_PIXELS],
            dl_dd: [zero; TILE_PIXELS],
            bg_dot: [zero; TILE_PIXELS],
            t_final: [zero; TILE_PIXELS],
            depth: grads.depth.is_some(),
        };
        for (x, y, p) in tile_pixels(ti, state.tiles_x, w, h) {
            let q = (y * w + x) as usize;
            let dl_dc = grads.color[q];
            let dl_dt = grads.transmittance.map_or(zero, |g| g[q]);
            let dl_dd = grads.depth.map_or(zero, |g| g[q]);
            let bg_dot = dl_dc[0] * bg[0] + dl_dc[1] * bg[1] + dl_dc[2] * bg[2] + dl_dt;
            // A pixel with no upstream gradient (masked out of the loss) adds exactly nothing
            // to any splat: give it no contributors, so the kernels skip it.
            let silent = dl_dc == [zero; 3] && dl_dd == zero && bg_dot == zero;
            input.contributors[p] = if silent {
                0
            } else {
                state.n_contrib[ti * TILE_PIXELS + p]
            };
            input.dl_dc[p] = dl_dc;
            input.dl_dd[p] = dl_dd;
            input.bg_dot[p] = bg_dot;
            input.t_final[p] = state.final_t[ti * TILE_PIXELS + p];
        }
        if let (Some(isa), Some(splats), Some(input)) = (isa, splats_f32, as_f32(&input))
            && let Some(rec) = F::grads_as_f32(rec)
        {
            isa.backward_tile(splats, list, input, rec)
        } else {
            backward_tile_scalar(&state.splats, list, &input, rec)
        }
    });

    // For each splat, its records in tile order; for each Gaussian, its splat.
    let index = state.index.get_or_init(|| {
        SplatIndex::build(
            &state.entries,
            &state.tile_ranges,
            &state.live_ranges,
            &state.ids,
            state.splats.len(),
            cloud.len(),
        )
    });
    assert_eq!(
        index.splat_of.len(),
        cloud.len(),
        "backward over a cloud other than the one drawn"
    );
    let mut out = cloud.zeros_like();
    let lanes = (
        isa,
        as_f32::<_, GaussianCloud<f32>>(cloud),
        as_f32::<_, CameraTerms<f32>>(&cam),
        as_f32::<_, Vec<SplatGrad<f32>>>(&records),
    );
    if let ((Some(isa), Some(cloud), Some(cam), Some(records)), Some(out)) =
        (lanes, as_f32_mut::<_, GaussianCloud<f32>>(&mut out))
    {
        gradients_in_lanes(isa, cloud, cam, state.config.low_pass, records, index, out);
        sanitize(out);
    } else {
        let stride = cloud.color_stride();
        let GaussianCloud {
            means,
            log_scales,
            rotations,
            colors,
            opacity_logits,
            ..
        } = &mut out;
        // The scalar kernel and the f64 path: per Gaussian, in parallel, sum its splat's
        // records and back-propagate them into its parameters, written in place.
        (
            means.par_chunks_mut(3),
            log_scales.par_chunks_mut(3),
            rotations.par_chunks_mut(4),
            colors.par_chunks_mut(stride),
            opacity_logits.par_iter_mut(),
        )
            .into_par_iter()
            .with_min_len(256)
            .enumerate()
            .for_each(|(g, (dm, ds, dr, dc, dl))| {
                let si = index.splat_of[g] as usize;
                if si == u32::MAX as usize {
                    return; // culled: no gradient
                }
                let total = index.total(si, &records);
                project_backward(
                    cloud,
                    g,
                    &cam,
                    state.config.low_pass,
                    &total,
                    dm,
                    ds,
                    dr,
                    dc,
                    dl,
                );
            });
        sanitize(&mut out);
    }
    out
}

/// Gaussians per block of the lanes' parameter gradients: a block's summed splat gradients sit
/// on the stack, and the blocks are fixed by the cloud's size, never by the threads.
const GRADIENT_BLOCK: usize = 256;

/// Per block of Gaussians, in parallel: sum each Gaussian's splat records in tile order, then
/// back-propagate them into its parameters in lanes (`project_lanes`), written in place.
fn gradients_in_lanes(
    isa: Isa,
    cloud: &GaussianCloud<f32>,
    cam: &CameraTerms<f32>,
    low_pass: LowPass,
    records: &[SplatGrad<f32>],
    index: &SplatIndex,
    out: &mut GaussianCloud<f32>,
) {
    let stride = cloud.color_stride();
    let GaussianCloud {
        means,
        log_scales,
        rotations,
        colors,
        opacity_logits,
        ..
    } = out;
    (
        means.par_chunks_mut(3 * GRADIENT_BLOCK),
        log_scales.par_chunks_mut(3 * GRADIENT_BLOCK),
        rotations.par_chunks_mut(4 * GRADIENT_BLOCK),
        colors.par_chunks_mut(stride * GRADIENT_BLOCK),
        opacity_logits.par_chunks_mut(GRADIENT_BLOCK),
    )
        .into_par_iter()
        .enumerate()
        .for_each(
            |(block, (means, log_scales, rotations, colors, opacity_logits))| {
                let first = block * GRADIENT_BLOCK;
                let mut totals = [None; GRADIENT_BLOCK];
                let totals = &mut totals[..opacity_logits.len()];
                for (i, total) in totals.iter_mut().enumerate() {
                    let si = index.splat_of[first + i] as usize;
                    if si == u32::MAX as usize {
                        continue; // culled: no gradient
                    }
                    *total = Some(index.total(si, records));
                }
                let out = GradientBlock {
                    means,
                    log_scales,
                    rotations,
                    colors,
                    opacity_logits,
                };
                isa.project_backward_range(cloud, first, totals, cam, low_pass, out);
            },
        );
}

/// Back-to-front gradients of one tile, one pixel at a time: the reference kernel. One record
/// per splat of the tile's list.
fn backward_tile_scalar<F: Real>(
    splats: &[Splat<F>],
    list: &[u32],
    input: &TilePixels<F>,
    records: &mut [SplatGrad<F>],
) {
    let zero = F::zero();
    let [x0, y0] = input.origin;
    // Per-pixel state of the back-to-front walk.
    #[derive(Clone, Copy)]
    struct Px<F> {
        t: F,
        accum: [F; 3],
        accum_d: F,
        last_alpha: F,
        last_color: [F; 3],
        last_depth: F,
    }
    let mut px: [Px<F>; TILE_PIXELS] = std::array::from_fn(|p| Px {
        t: input.t_final[p],
        accum: [zero; 3],
        accum_d: zero,
        last_alpha: zero,
        last_color: [zero; 3],
        last_depth: zero,
    });
    let cx: [F; TILE as usize] = std::array::from_fn(|i| F::c((x0 + i as u32) as f64 + 0.5));
    let cy: [F; TILE as usize] = std::array::from_fn(|j| F::c((y0 + j as u32) as f64 + 0.5));
    // Entries past every pixel's last contributor add nothing: start at the last one.
    let last = input.contributors.iter().copied().max().unwrap_or(0) as usize;
    for k in (0..last.min(list.len())).rev() {
        let s = &splats[list[k] as usize];
        let r = &mut records[k];
        let [ax, ay, bx, by] = rect_in_tile(s, [x0, y0]);
        for y in ay..=by {
            let py = cy[(y - y0) as usize];
            for x in ax..=bx {
                let p = ((y - y0) * TILE + (x - x0)) as usize;
                // Pixels outside the image have no contributors.
                if k as u32 >= input.contributors[p] {
                    continue;
                }
                let Some((alpha, gauss, dx, dy)) = splat_alpha(s, cx[(x - x0) as usize], py) else {
                    continue;
                };
                let st = &mut px[p];
                let (dl_dc, dl_dd) = (input.dl_dc[p], input.dl_dd[p]);
                st.t = st.t / (F::one() - alpha);
                let wgt = alpha * st.t;
                for ch in 0..3 {
                    r.color[ch] = r.color[ch] + wgt * dl_dc[ch];
                }
                r.depth = r.depth + wgt * dl_dd;
                let mut dl_dalpha = zero;
                for ch in 0..3 {
                    st.accum[ch] = st.last_alpha * st.last_color[ch]
                        + (F::one() - st.last_alpha) * st.accum[ch];
                    dl_dalpha = dl_dalpha + (s.color[ch] - st.accum[ch]) * dl_dc[ch];
                }
                st.accum_d =
                    st.last_alpha * st.last_depth + (F::one() - st.last_alpha) * st.accum_d;
                dl_dalpha = dl_dalpha + (s.depth - st.accum_d) * dl_dd;
                dl_dalpha = dl_dalpha * st.t;
                st.last_alpha = alpha;
                st.last_color = s.color;
                st.last_depth = s.depth;
                dl_dalpha = dl_dalpha - input.t_final[p] / (F::one() - alpha) * input.bg_dot[p];
                // alpha = min(0.99, opacity * G): no gradient through the cap.
                if s.opacity * gauss > F::c(ALPHA_MAX) {
                    continue;
                }
                r.opacity = r.opacity + gauss * dl_dalpha;
                let dl_dpower = alpha * dl_dalpha;
                r.xy[0] = r.xy[0] + dl_dpower * (s.conic[0] * dx + s.conic[1] * dy);
                r.xy[1] = r.xy[1] + dl_dpower * (s.conic[1] * dx + s.conic[2] * dy);
                r.conic[0] = r.conic[0] - F::c(0.5) * dx * dx * dl_dpower;
                r.conic[1] = r.conic[1] - dx * dy * dl_dpower;
                r.conic[2] = r.conic[2] - F::c(0.5) * dy * dy * dl_dpower;
            }
        }
    }
}

/// Replaces non-finite gradient values by 0: a NaN never reaches a parameter.
fn sanitize<F: Real>(g: &mut CloudGradients<F>) {
    for group in g.groups_mut() {
        group.par_chunks_mut(1 << 14).for_each(|chunk| {
            for v in chunk {
                if !v.is_finite() {
                    *v = F::zero();
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::hash32;

    /// The radix depth order is the comparison sort's order of the whole keys, ties in index
    /// order included, on lists of every length around the switch between the two, with
    /// depths drawn from a few values (many ties), from one exponent (a skipped byte), and
    /// from all at once (no byte skipped).
    #[test]
    fn depth_order_is_the_order_of_the_sorted_keys() {
        let mut scratch = Vec::new();
        for len in [0, 1, 2, RADIX_MIN - 1, RADIX_MIN, RADIX_MIN + 1, 350, 4000] {
            for spread in 0..3 {
                let keys: Vec<u64> = (0..len as u32)
                    .map(|i| {
                        let h = hash32(&[i, len as u32, spread]);
                        let depth = match spread {
                            0 => 1.0 + (h % 5) as f32,
                            1 => 1.0 + (h >> 9) as f32 / 8_388_608.0,
                            _ => f32::from_bits(h >> 2).max(f32::MIN_POSITIVE),
                        };
                        (depth.to_bits() as u64) << 32 | i as u64
                    })
                    .collect();
                let mut want = keys.clone();
                want.sort_unstable();
                let want: Vec<u32> = want.iter().map(|&k| k as u32).collect();
                let mut got = vec![u32::MAX; len];
                depth_order(&mut keys.clone(), &mut scratch, &mut got);
                assert_eq!(got, want, "{len} keys, spread {spread}");
            }
        }
    }
}
