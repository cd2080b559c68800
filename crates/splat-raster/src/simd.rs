//! The per-tile kernels across pixels in SIMD lanes, and the run-time choice of the lane width.
//!
//! A tile row of 16 pixels is 2 chunks of 8 lanes (AVX2 + FMA) or 4 chunks of 4 (SSE2 on any
//! x86-64, NEON on aarch64). Each splat visits the chunks its rectangle touches; a lane outside
//! the rectangle, past the image edge, already saturated, or whose exponent is out of range is
//! masked, and a chunk with no live lane skips `exp`. The arithmetic is the scalar kernel's
//! (`raster/forward.rs`) with three differences, all within rounding: the exponent is evaluated as
//! `dx (a' dx + b' dy) + c' dy^2` (two FMAs), `exp` is [`crate::lanes::exp`] (at most
//! [`crate::lanes::EXP_MAX_REL_ERROR`] from the exact value, libm's `expf` is within 1 ulp), and
//! products are fused where the lanes have FMA. A pixel whose alpha or transmittance sits within
//! that rounding of a threshold (1/255, `T_MIN`) can take the other branch; the tests bound how
//! often and by how much.
//!
//! The backward pass reconstructs each pixel's transmittance by dividing out the same alphas the
//! forward pass multiplied in, so both passes of one frame must run the same kernel:
//! `ForwardState` records the one that ran. Per-splat sums over a tile's lanes are reduced in a
//! fixed order, so gradients stay bit-identical for any thread count.

use crate::cloud::GaussianCloud;
#[cfg(target_arch = "x86_64")]
use crate::lanes::{Avx2, Avx2Token};
use crate::lanes::{Isa, Lanes, exp};
use crate::project::{ALPHA_MAX, ALPHA_MIN, CameraTerms, LowPass, Splat, T_MIN};
use crate::project_lanes::{self, GradientBlock};
use crate::real::SplatGrad;
use crate::tile::{TILE, TileOut, TilePixels};
use std::ops::Range;

/// Which per-pixel kernel composites the tiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Kernel {
    /// The widest lanes this CPU runs.
    #[default]
    Auto,
    /// One pixel at a time, libm's `exp`: the reference the lanes are tested against, and the
    /// only kernel of the f64 path.
    Scalar,
    /// 4 lanes: SSE2 on x86-64, NEON on aarch64, plain code elsewhere. Every CPU runs it.
    Lanes4,
    /// 8 lanes with AVX2 and FMA (x86-64 only).
    Lanes8,
}

impl Kernel {
    /// Whether this CPU can run the kernel.
    pub fn available(self) -> bool {
        match self {
            Kernel::Lanes8 => Isa::avx2_fma().is_some(),
            _ => true,
        }
    }

    /// The kernel that runs when this one is asked for: `Auto` becomes the widest available,
    /// and `Lanes8` on a CPU without AVX2 + FMA becomes `Lanes4`.
    pub fn resolve(self) -> Kernel {
        match self {
            Kernel::Auto | Kernel::Lanes8 if Kernel::Lanes8.available() => Kernel::Lanes8,
            Kernel::Auto | Kernel::Lanes8 => Kernel::Lanes4,
            k => k,
        }
    }

    /// Lanes per vector (1 for the scalar kernel).
    pub fn lanes(self) -> usize {
        match self.resolve() {
            Kernel::Lanes8 => 8,
            Kernel::Lanes4 => 4,
            _ => 1,
        }
    }
}

impl std::fmt::Display for Kernel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Kernel::Auto => "auto",
            Kernel::Scalar => "scalar",
            Kernel::Lanes4 => "lanes4",
            Kernel::Lanes8 => "lanes8",
        })
    }
}

impl std::str::FromStr for Kernel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(Kernel::Auto),
            "scalar" => Ok(Kernel::Scalar),
            "lanes4" => Ok(Kernel::Lanes4),
            "lanes8" => Ok(Kernel::Lanes8),
            _ => Err(format!(
                "unknown kernel `{s}`: expected auto, scalar, lanes4 or lanes8"
            )),
        }
    }
}

/// The lane kernels' dispatch on the instruction set ([`Isa`], `lanes.rs`).
impl Isa {
    /// The instruction set of a resolved lane kernel; None for the scalar one.
    pub(crate) fn of(kernel: Kernel) -> Option<Isa> {
        match kernel.resolve() {
            Kernel::Lanes8 => Isa::avx2_fma(),
            Kernel::Lanes4 => Some(Isa::Baseline),
            _ => None,
        }
    }

    /// Composites one tile front to back.
    pub(crate) fn forward_tile(
        self,
        splats: &[Splat<f32>],
        list: &[u32],
        origin: [u32; 2],
        size: [u32; 2],
        depth: bool,
        out: &mut TileOut<f32>,
    ) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `forward_avx2_fma` needs AVX2 and FMA, which the token proves this CPU has.
            Isa::Avx2Fma(token) => unsafe {
                forward_avx2_fma(token, splats, list, origin, size, depth, out)
            },
            Isa::Baseline => forward_baseline(splats, list, origin, size, depth, out),
        }
    }

    /// Projects Gaussians `range` of `cloud` in lanes (`project_lanes`), appending each
    /// survivor's splat and index in order.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn project_range(
        self,
        cloud: &GaussianCloud<f32>,
        range: Range<usize>,
        cam: &CameraTerms<f32>,
        low_pass: LowPass,
        near: f32,
        splats: &mut Vec<Splat<f32>>,
        ids: &mut Vec<u32>,
    ) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `forward_tile`, the token proves AVX2 and FMA are there.
            Isa::Avx2Fma(token) => unsafe {
                project_avx2_fma(token, cloud, range, cam, low_pass, near, splats, ids)
            },
            Isa::Baseline => project_lanes::project_range::<BaselineLanes>(
                (),
                cloud,
                range,
                cam,
                low_pass,
                near,
                splats,
                ids,
            ),
        }
    }

    /// Back-propagates the summed splat gradients of Gaussians `first..first + totals.len()`
    /// to their parameters in lanes (`project_lanes`), added into `out`.
    pub(crate) fn project_backward_range(
        self,
        cloud: &GaussianCloud<f32>,
        first: usize,
        totals: &[Option<SplatGrad<f32>>],
        cam: &CameraTerms<f32>,
        low_pass: LowPass,
        out: GradientBlock<'_>,
    ) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `forward_tile`, the token proves AVX2 and FMA are there.
            Isa::Avx2Fma(token) => unsafe {
                project_backward_avx2_fma(token, cloud, first, totals, cam, low_pass, out)
            },
            Isa::Baseline => project_lanes::project_backward_range::<BaselineLanes>(
                (),
                cloud,
                first,
                totals,
                cam,
                low_pass,
                out,
            ),
        }
    }

    /// Back-propagates one tile, back to front; one record per splat of the tile's list.
    pub(crate) fn backward_tile(
        self,
        splats: &[Splat<f32>],
        list: &[u32],
        input: &TilePixels<f32>,
        records: &mut [SplatGrad<f32>],
    ) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `forward_tile`, the token proves AVX2 and FMA are there.
            Isa::Avx2Fma(token) => unsafe {
                backward_avx2_fma(token, splats, list, input, records)
            },
            Isa::Baseline => backward_baseline(splats, list, input, records),
        }
    }
}

/// The baseline lanes of this target.
#[cfg(target_arch = "x86_64")]
type BaselineLanes = crate::lanes::Sse2;
#[cfg(not(target_arch = "x86_64"))]
type BaselineLanes = crate::lanes::Portable;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn forward_avx2_fma(
    token: Avx2Token,
    splats: &[Splat<f32>],
    list: &[u32],
    origin: [u32; 2],
    size: [u32; 2],
    depth: bool,
    out: &mut TileOut<f32>,
) {
    if depth {
        forward::<Avx2, true>(token, splats, list, origin, size, out)
    } else {
        forward::<Avx2, false>(token, splats, list, origin, size, out)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_avx2_fma(
    token: Avx2Token,
    splats: &[Splat<f32>],
    list: &[u32],
    input: &TilePixels<f32>,
    records: &mut [SplatGrad<f32>],
) {
    if input.depth {
        backward::<Avx2, true>(token, splats, list, input, records)
    } else {
        backward::<Avx2, false>(token, splats, list, input, records)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
fn project_avx2_fma(
    token: Avx2Token,
    cloud: &GaussianCloud<f32>,
    range: Range<usize>,
    cam: &CameraTerms<f32>,
    low_pass: LowPass,
    near: f32,
    splats: &mut Vec<Splat<f32>>,
    ids: &mut Vec<u32>,
) {
    project_lanes::project_range::<Avx2>(token, cloud, range, cam, low_pass, near, splats, ids)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_backward_avx2_fma(
    token: Avx2Token,
    cloud: &GaussianCloud<f32>,
    first: usize,
    totals: &[Option<SplatGrad<f32>>],
    cam: &CameraTerms<f32>,
    low_pass: LowPass,
    out: GradientBlock<'_>,
) {
    project_lanes::project_backward_range::<Avx2>(token, cloud, first, totals, cam, low_pass, out)
}

fn forward_baseline(
    splats: &[Splat<f32>],
    list: &[u32],
    origin: [u32; 2],
    size: [u32; 2],
    depth: bool,
    out: &mut TileOut<f32>,
) {
    if depth {
        forward::<BaselineLanes, true>((), splats, list, origin, size, out)
    } else {
        forward::<BaselineLanes, false>((), splats, list, origin, size, out)
    }
}

fn backward_baseline(
    splats: &[Splat<f32>],
    list: &[u32],
    input: &TilePixels<f32>,
    records: &mut [SplatGrad<f32>],
) {
    if input.depth {
        backward::<BaselineLanes, true>((), splats, list, input, records)
    } else {
        backward::<BaselineLanes, false>((), splats, list, input, records)
    }
}

const T: usize = TILE as usize;
/// Chunks per tile at the narrowest width; arrays are sized for it and use `T * T / N`.
const MAX_CHUNKS: usize = T * T / 4;
/// Chunks per row at the narrowest width.
const MAX_ROW_CHUNKS: usize = T / 4;

/// The splats of a tile's list, copied a block at a time: the list is in depth order, so its
/// splats are scattered through memory, and a copy loop lets the CPU fetch a block's cache lines
/// at once instead of stalling on each splat in turn.
struct Block {
    splats: [Splat<f32>; BLOCK],
    /// The list position of `splats[0]`, or `usize::MAX` before the first copy.
    start: usize,
}

/// Splats per copied block.
const BLOCK: usize = 32;

impl Default for Block {
    fn default() -> Self {
        Self {
            splats: [Splat::default(); BLOCK],
            start: usize::MAX,
        }
    }
}

impl Block {
    /// The splat at list position `k`, copying its block first when it is not the current one
    /// (blocks are aligned to `BLOCK`, so a walk in either direction copies each one once).
    #[inline(always)]
    fn get(&mut self, splats: &[Splat<f32>], list: &[u32], k: usize) -> &Splat<f32> {
        let start = k - k % BLOCK;
        if start != self.start {
            let end = (start + BLOCK).min(list.len());
            for (dst, &i) in self.splats.iter_mut().zip(&list[start..end]) {
                *dst = splats[i as usize];
            }
            self.start = start;
        }
        &self.splats[k - start]
    }
}

/// What one splat's lanes share: its exponent as `dx (a dx + b dy) + c dy^2`, and its bounds.
struct SplatLanes<L: Lanes> {
    centre_x: L,
    centre_y: f32,
    a: L,
    b: f32,
    c: f32,
    power_min: L,
    opacity: L,
    /// Tile-local inclusive pixel bounds, and the column bounds as lanes.
    x: [u32; 2],
    y: [u32; 2],
    x_lanes: [L; 2],
}

impl<L: Lanes> SplatLanes<L> {
    #[inline(always)]
    fn new(token: L::Token, s: &Splat<f32>, origin: [u32; 2]) -> Self {
        let [x0, y0] = origin;
        let last = TILE - 1;
        let x = [s.rect[0].max(x0) - x0, (s.rect[2] - x0).min(last)];
        let sp = |v: f32| L::splat(token, v);
        Self {
            centre_x: sp(s.xy[0]),
            centre_y: s.xy[1],
            a: sp(-0.5 * s.conic[0]),
            b: -s.conic[1],
            c: -0.5 * s.conic[2],
            power_min: sp(s.power_min),
            opacity: sp(s.opacity),
            x,
            y: [s.rect[1].max(y0) - y0, (s.rect[3] - y0).min(last)],
            x_lanes: [sp(x[0] as f32), sp(x[1] as f32)],
        }
    }

    /// The row's `dy`, `b dy` and `c dy^2`, for pixel row `row` of the tile.
    #[inline(always)]
    fn row(&self, token: L::Token, origin: [u32; 2], row: u32) -> (f32, L, L) {
        let dy = (origin[1] + row) as f32 + 0.5 - self.centre_y;
        (
            dy,
            L::splat(token, self.b * dy),
            L::splat(token, self.c * dy * dy),
        )
    }

    /// The lanes of a chunk inside the splat's columns.
    #[inline(always)]
    fn in_columns(&self, columns: L) -> L::Mask {
        columns.ge(self.x_lanes[0]) & columns.le(self.x_lanes[1])
    }
}

/// Pixel-centre x of each lane of each chunk of a row, and each lane's tile-local column.
#[inline(always)]
fn lane_columns<L: Lanes>(token: L::Token, x0: u32) -> ([L; MAX_ROW_CHUNKS], [L; MAX_ROW_CHUNKS]) {
    let mut centres = [L::splat(token, 0.0); MAX_ROW_CHUNKS];
    let mut columns = [L::splat(token, 0.0); MAX_ROW_CHUNKS];
    let mut buf = [0.0f32; T];
    for (i, v) in buf.iter_mut().enumerate() {
        *v = (x0 + i as u32) as f32 + 0.5;
    }
    for c in 0..T / L::N {
        centres[c] = L::load(token, &buf[c * L::N..]);
    }
    for (i, v) in buf.iter_mut().enumerate() {
        *v = i as f32;
    }
    for c in 0..T / L::N {
        columns[c] = L::load(token, &buf[c * L::N..]);
    }
    (centres, columns)
}

/// Front-to-back compositing of one tile (`raster/forward.rs` has the scalar twin, `raster` the equations).
#[inline(always)]
fn forward<L: Lanes, const DEPTH: bool>(
    token: L::Token,
    splats: &[Splat<f32>],
    list: &[u32],
    origin: [u32; 2],
    size: [u32; 2],
    out: &mut TileOut<f32>,
) {
    let n = L::N;
    let chunks_per_row = T / n;
    let chunks = T * T / n;
    let sp = |v: f32| L::splat(token, v);
    let (zero, one) = (sp(0.0), sp(1.0));
    let mut trans = [one; MAX_CHUNKS];
    let mut rgb = [[zero; MAX_CHUNKS]; 3];
    let mut depth = [zero; MAX_CHUNKS];
    // The number of entries each pixel processed, as integer bits.
    let mut contributors = [zero; MAX_CHUNKS];
    let mut live = [L::no_lanes(token); MAX_CHUNKS];
    let mut active = 0;
    for (i, m) in live.iter_mut().enumerate().take(chunks) {
        let (row, c) = ((i / chunks_per_row) as u32, i % chunks_per_row);
        *m = L::mask_from_fn(token, |l| {
            (origin[0] + (c * n + l) as u32) < size[0] && origin[1] + row < size[1]
        });
        active += L::count(*m);
    }
    let (centres, columns) = lane_columns::<L>(token, origin[0]);
    let (alpha_max, alpha_min, t_min) =
        (sp(ALPHA_MAX as f32), sp(ALPHA_MIN as f32), sp(T_MIN as f32));
    let mut block = Block::default();
    let mut evaluated = 0u64;
    for k in 0..list.len() {
        if active == 0 {
            break;
        }
        let s = block.get(splats, list, k);
        let sl = SplatLanes::<L>::new(token, s, origin);
        let color = s.color.map(sp);
        let splat_depth = sp(s.depth);
        // Integer bits in float lanes: only moved and compared as integers, never computed on.
        let index = L::splat(token, f32::from_bits(k as u32 + 1));
        let (c0, c1) = (sl.x[0] as usize / n, sl.x[1] as usize / n);
        for row in sl.y[0]..=sl.y[1] {
            let (_, rb, rc) = sl.row(token, origin, row);
            for c in c0..=c1 {
                let i = row as usize * chunks_per_row + c;
                let mut m = live[i] & sl.in_columns(columns[c]);
                if !L::any(m) {
                    continue;
                }
                evaluated += 1;
                let dx = centres[c] - sl.centre_x;
                let power = sl.a.mul_add(dx, rb).mul_add(dx, rc);
                m = m & power.le(zero) & power.ge(sl.power_min);
                if !L::any(m) {
                    continue;
                }
                let alpha = (sl.opacity * exp(token, power)).min(alpha_max);
                m = m & alpha.ge(alpha_min);
                let t = trans[i];
                let next_t = t * (one - alpha);
                let saturated = m & next_t.lt(t_min);
                if L::any(saturated) {
                    live[i] = L::and_not(live[i], saturated);
                    active -= L::count(saturated);
                    m = L::and_not(m, saturated);
                }
                let weight = L::keep(m, alpha * t);
                for ch in 0..3 {
                    rgb[ch][i] = weight.mul_add(color[ch], rgb[ch][i]);
                }
                if DEPTH {
                    depth[i] = weight.mul_add(splat_depth, depth[i]);
                }
                trans[i] = L::select(m, next_t, t);
                contributors[i] = L::select(m, index, contributors[i]);
            }
        }
    }
    out.lane_evaluations = evaluated * n as u64;
    let mut lanes = [[0.0f32; 16]; 3];
    for i in 0..chunks {
        let p = i * n;
        trans[i].store(&mut out.t[p..]);
        contributors[i].store_bits(&mut out.n[p..]);
        if DEPTH {
            depth[i].store(&mut out.depth[p..]);
        }
        for ch in 0..3 {
            rgb[ch][i].store(&mut lanes[ch]);
        }
        for l in 0..n {
            out.color[p + l] = [lanes[0][l], lanes[1][l], lanes[2][l]];
        }
    }
}

/// Back-to-front gradients of one tile (`raster/backward.rs` has the scalar twin, `raster` the equations).
#[inline(always)]
fn backward<L: Lanes, const DEPTH: bool>(
    token: L::Token,
    splats: &[Splat<f32>],
    list: &[u32],
    input: &TilePixels<f32>,
    records: &mut [SplatGrad<f32>],
) {
    let n = L::N;
    let chunks_per_row = T / n;
    let chunks = T * T / n;
    let origin = input.origin;
    let sp = |v: f32| L::splat(token, v);
    let (zero, one) = (sp(0.0), sp(1.0));
    // Per-pixel inputs and state of the walk, in chunks.
    let mut contributors = [zero; MAX_CHUNKS];
    let mut dl_dc = [[zero; MAX_CHUNKS]; 3];
    let mut dl_dd = [zero; MAX_CHUNKS];
    let mut bg_dot = [zero; MAX_CHUNKS];
    let mut t_final = [zero; MAX_CHUNKS];
    let mut accum = [[zero; MAX_CHUNKS]; 3];
    let mut accum_d = [zero; MAX_CHUNKS];
    let mut last_alpha = [zero; MAX_CHUNKS];
    let mut last_color = [[zero; MAX_CHUNKS]; 3];
    let mut last_depth = [zero; MAX_CHUNKS];
    let mut lanes = [[0.0f32; 16]; 3];
    for i in 0..chunks {
        let p = i * n;
        contributors[i] = L::load_bits(token, &input.contributors[p..]);
        if DEPTH {
            dl_dd[i] = L::load(token, &input.dl_dd[p..]);
        }
        bg_dot[i] = L::load(token, &input.bg_dot[p..]);
        t_final[i] = L::load(token, &input.t_final[p..]);
        for l in 0..n {
            for ch in 0..3 {
                lanes[ch][l] = input.dl_dc[p + l][ch];
            }
        }
        for ch in 0..3 {
            dl_dc[ch][i] = L::load(token, &lanes[ch]);
        }
    }
    let mut trans = t_final;
    let (centres, columns) = lane_columns::<L>(token, origin[0]);
    let (alpha_max, alpha_min) = (sp(ALPHA_MAX as f32), sp(ALPHA_MIN as f32));
    let half = sp(0.5);
    // Entries past every pixel's last contributor add nothing: start at the last one.
    let last = input.contributors.iter().copied().max().unwrap_or(0) as usize;
    let mut block = Block::default();
    for k in (0..last.min(list.len())).rev() {
        let s = block.get(splats, list, k);
        let sl = SplatLanes::<L>::new(token, s, origin);
        let color = s.color.map(sp);
        let splat_depth = sp(s.depth);
        let conic = s.conic.map(sp);
        let index = L::splat(token, f32::from_bits(k as u32));
        // This splat's sums over the tile's pixels, lane by lane.
        let mut g_color = [zero; 3];
        let (mut g_depth, mut g_opacity) = (zero, zero);
        let (mut g_xy, mut g_conic) = ([zero; 2], [zero; 3]);
        let mut touched = false;
        let (c0, c1) = (sl.x[0] as usize / n, sl.x[1] as usize / n);
        for row in sl.y[0]..=sl.y[1] {
            let (dy, rb, rc) = sl.row(token, origin, row);
            let dy = sp(dy);
            for c in c0..=c1 {
                let i = row as usize * chunks_per_row + c;
                let mut m = index.bits_lt(contributors[i]) & sl.in_columns(columns[c]);
                if !L::any(m) {
                    continue;
                }
                let dx = centres[c] - sl.centre_x;
                let power = sl.a.mul_add(dx, rb).mul_add(dx, rc);
                m = m & power.le(zero) & power.ge(sl.power_min);
                if !L::any(m) {
                    continue;
                }
                let gauss = exp(token, power);
                let raw_alpha = sl.opacity * gauss;
                let alpha = raw_alpha.min(alpha_max);
                m = m & alpha.ge(alpha_min);
                if !L::any(m) {
                    continue;
                }
                touched = true;
                // One division for both uses; masked lanes keep their state, and dividing there
                // is harmless (1 - alpha >= 0.01).
                let inv_one_minus = one / (one - alpha);
                let t = L::select(m, trans[i] * inv_one_minus, trans[i]);
                trans[i] = t;
                let weight = L::keep(m, alpha * t);
                let la = last_alpha[i];
                let mut dl_dalpha = zero;
                for ch in 0..3 {
                    g_color[ch] = weight.mul_add(dl_dc[ch][i], g_color[ch]);
                    let acc = la.mul_add(last_color[ch][i], (one - la) * accum[ch][i]);
                    accum[ch][i] = L::select(m, acc, accum[ch][i]);
                    dl_dalpha = (color[ch] - accum[ch][i]).mul_add(dl_dc[ch][i], dl_dalpha);
                    last_color[ch][i] = L::select(m, color[ch], last_color[ch][i]);
                }
                if DEPTH {
                    g_depth = weight.mul_add(dl_dd[i], g_depth);
                    let acc = la.mul_add(last_depth[i], (one - la) * accum_d[i]);
                    accum_d[i] = L::select(m, acc, accum_d[i]);
                    dl_dalpha = (splat_depth - accum_d[i]).mul_add(dl_dd[i], dl_dalpha);
                    last_depth[i] = L::select(m, splat_depth, last_depth[i]);
                }
                last_alpha[i] = L::select(m, alpha, la);
                let dl_dalpha = dl_dalpha * t - t_final[i] * inv_one_minus * bg_dot[i];
                // alpha = min(0.99, opacity G): no gradient through the cap.
                let through = L::and_not(m, raw_alpha.gt(alpha_max));
                let dl_dalpha = L::keep(through, dl_dalpha);
                g_opacity = gauss.mul_add(dl_dalpha, g_opacity);
                let dl_dpower = alpha * dl_dalpha;
                let gx = conic[0].mul_add(dx, conic[1] * dy);
                let gy = conic[1].mul_add(dx, conic[2] * dy);
                g_xy[0] = dl_dpower.mul_add(gx, g_xy[0]);
                g_xy[1] = dl_dpower.mul_add(gy, g_xy[1]);
                let hp = half * dl_dpower;
                g_conic[0] = g_conic[0] - hp * dx * dx;
                g_conic[1] = g_conic[1] - dl_dpower * dx * dy;
                g_conic[2] = g_conic[2] - hp * dy * dy;
            }
        }
        if !touched {
            continue; // the record stays zero
        }
        let sums = L::reduce8([
            g_color[0], g_color[1], g_color[2], g_opacity, g_xy[0], g_xy[1], g_conic[0], g_conic[1],
        ]);
        let r = &mut records[k];
        r.color = [sums[0], sums[1], sums[2]];
        r.opacity = sums[3];
        r.xy = [sums[4], sums[5]];
        r.conic = [sums[6], sums[7], g_conic[2].reduce_sum()];
        r.depth = if DEPTH { g_depth.reduce_sum() } else { 0.0 };
    }
}
