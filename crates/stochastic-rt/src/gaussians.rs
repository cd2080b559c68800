//! Gaussians prepared for tracing, and their response along a ray.
//!
//! In canonical space `y = S^-1 R^T (x - mu)` a Gaussian is `exp(-|y|^2 / 2)`; along the ray
//! `o + t d` the response is a 1D Gaussian whose mean `t*` (the point of maximum response) is
//! where the ray is shaded (`mean` depth mode). Alpha there is `min(0.99, opacity G)`, and
//! intersections with alpha below 1/255 are negligible, as in splat-raster; so each Gaussian is
//! bounded by the ellipsoid `|y|^2 <= 2 ln(255 opacity)` and its exact axis-aligned box: the
//! BVH sees exactly the intersections that a brute-force loop accepts.

use crate::isa::{Baseline, Isa};
use glam::Vec3;
use rayon::prelude::*;
#[cfg(target_arch = "x86_64")]
use splat_raster::lanes::{Avx2, Avx2Token};
use splat_raster::lanes::{EXP_MAX, EXP_MIN, Lanes, exp, ln, rotation};
use splat_raster::project::{ALPHA_MAX, ALPHA_MIN};
use splat_raster::sh;
use splat_raster::{ColorModel, GaussianCloud};
use std::ops::Range;

/// Where along the ray an intersection is placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum DepthMode {
    /// The mean of the 1D Gaussian along the ray (Sun et al.'s "OursMean").
    #[default]
    Mean,
    /// The Gaussian's centre projected onto the camera's forward axis, as a rasteriser sorts
    /// (Sun et al., section 4.1, "OursCenter").
    Center,
}

/// The Gaussians of a cloud that can be seen, in tracing form (structure of arrays).
#[derive(Debug, Clone)]
pub struct TraceGaussians {
    /// Index in the source cloud.
    pub ids: Vec<u32>,
    pub means: Vec<Vec3>,
    /// Rows of `S^-1 R^T`, world offset to canonical space.
    pub canonical: Vec<[Vec3; 3]>,
    pub opacity: Vec<f32>,
    /// Squared canonical radius of the alpha >= 1/255 ellipsoid: `2 ln(255 opacity)`.
    pub cutoff: Vec<f32>,
    pub lower: Vec<Vec3>,
    pub upper: Vec<Vec3>,
    /// The largest half-diagonal of any Gaussian's box: how far a centre can be from any point
    /// of its box, which bounds how far `Center` depth can lie outside the box along a ray.
    pub max_half_diagonal: f32,
    /// `3 * coefficients` per Gaussian, `[coefficient][channel]`, as in the cloud.
    pub colors: Vec<f32>,
    pub color_model: ColorModel,
}

/// An accepted ray-Gaussian intersection: where, and with what alpha.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intersection {
    pub t: f32,
    pub alpha: f32,
}

/// What [`TraceGaussians::intersect`] computes from a ray's origin and a Gaussian alone
/// ([`TraceGaussians::origin_terms`]).
#[derive(Debug, Clone, Copy)]
pub struct OriginTerms {
    /// The origin less the Gaussian's mean.
    off: Vec3,
    /// `off` in the Gaussian's canonical frame.
    canonical: Vec3,
}

/// No Gaussians (RGB colours): arrays for [`TraceGaussians::prepare`] to fill.
impl Default for TraceGaussians {
    fn default() -> Self {
        TraceGaussians {
            ids: Vec::new(),
            means: Vec::new(),
            canonical: Vec::new(),
            opacity: Vec::new(),
            cutoff: Vec::new(),
            lower: Vec::new(),
            upper: Vec::new(),
            max_half_diagonal: 0.0,
            colors: Vec::new(),
            color_model: ColorModel::Rgb,
        }
    }
}

impl TraceGaussians {
    /// Prepares every Gaussian that can contribute ([`TraceGaussians::prepare`]).
    pub fn new(cloud: &GaussianCloud<f32>) -> Self {
        let mut out = Self::default();
        out.prepare(cloud);
        out
    }

    /// Replaces these Gaussians with `cloud`'s that can contribute, in the memory these hold:
    /// a cache traces its clouds every frame, and fresh arrays cost more in page faults than
    /// the preparation itself. Non-finite, degenerate (zero quaternion, a log-scale outside
    /// [`EXP_MIN`, `EXP_MAX`], that is a scale below 1.6e-38 or above 1.6e38) and too faint
    /// (opacity below 1/255) ones are left out.
    ///
    /// [`PREPARE_BLOCK`] Gaussians a task, in parallel, each block in SIMD lanes (the
    /// exponentials, the rotation and the box were nine tenths of a scalar preparation's
    /// 750 instructions) and written to its own part of the arrays; then the blocks' kept
    /// Gaussians are moved together in order: the same arrays on any thread count. The lanes'
    /// `exp` and `ln` round differently from libm (within 3e-7 relative), and AVX2's fused
    /// multiply-adds from the baseline's, so the terms can differ between processors in their
    /// last bits; every test and every bound here holds for either.
    pub fn prepare(&mut self, cloud: &GaussianCloud<f32>) {
        self.prepare_in(Isa::detect(), cloud);
    }

    /// [`TraceGaussians::prepare`] in `isa`'s lanes.
    fn prepare_in(&mut self, isa: Isa, cloud: &GaussianCloud<f32>) {
        let (n, stride) = (cloud.len(), cloud.color_stride());
        self.color_model = cloud.color_model;
        // Each array `n` long: every value is overwritten, so only a longer array's new tail
        // is filled (the memory is kept, and not rewritten twice each frame).
        fn sized<T: Clone>(v: &mut Vec<T>, n: usize, fill: T) {
            v.resize(n, fill);
        }
        sized(&mut self.ids, n, 0);
        sized(&mut self.means, n, Vec3::ZERO);
        sized(&mut self.canonical, n, [Vec3::ZERO; 3]);
        sized(&mut self.opacity, n, 0.0);
        sized(&mut self.cutoff, n, 0.0);
        sized(&mut self.lower, n, Vec3::ZERO);
        sized(&mut self.upper, n, Vec3::ZERO);
        sized(&mut self.colors, n * stride, 0.0);
        let chunks = (
            self.ids.par_chunks_mut(PREPARE_BLOCK),
            self.means.par_chunks_mut(PREPARE_BLOCK),
            self.canonical.par_chunks_mut(PREPARE_BLOCK),
            self.opacity.par_chunks_mut(PREPARE_BLOCK),
            self.cutoff.par_chunks_mut(PREPARE_BLOCK),
            self.lower.par_chunks_mut(PREPARE_BLOCK),
            self.upper.par_chunks_mut(PREPARE_BLOCK),
            self.colors.par_chunks_mut(PREPARE_BLOCK * stride),
        );
        let blocks: Vec<(usize, f32)> = chunks
            .into_par_iter()
            .enumerate()
            .map(
                |(b, (ids, means, canonical, opacity, cutoff, lower, upper, colors))| {
                    let range = b * PREPARE_BLOCK..((b + 1) * PREPARE_BLOCK).min(n);
                    let mut block = Block {
                        ids,
                        means,
                        canonical,
                        opacity,
                        cutoff,
                        lower,
                        upper,
                        colors,
                        stride,
                        kept: 0,
                        largest_half_diagonal: 0.0,
                    };
                    prepare_on(isa, cloud, range, &mut block);
                    (block.kept, block.largest_half_diagonal)
                },
            )
            .collect();
        // Each block's kept Gaussians lie at its start: move them after the previous
        // blocks' (nothing moves until a Gaussian is left out).
        let mut end = 0;
        self.max_half_diagonal = 0.0;
        for (b, &(kept, largest)) in blocks.iter().enumerate() {
            let start = b * PREPARE_BLOCK;
            if start != end {
                let from = start..start + kept;
                self.ids.copy_within(from.clone(), end);
                self.means.copy_within(from.clone(), end);
                self.canonical.copy_within(from.clone(), end);
                self.opacity.copy_within(from.clone(), end);
                self.cutoff.copy_within(from.clone(), end);
                self.lower.copy_within(from.clone(), end);
                self.upper.copy_within(from, end);
                let colors = start * stride..(start + kept) * stride;
                self.colors.copy_within(colors, end * stride);
            }
            end += kept;
            self.max_half_diagonal = self.max_half_diagonal.max(largest);
        }
        self.ids.truncate(end);
        self.means.truncate(end);
        self.canonical.truncate(end);
        self.opacity.truncate(end);
        self.cutoff.truncate(end);
        self.lower.truncate(end);
        self.upper.truncate(end);
        self.colors.truncate(end * stride);
    }

    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The intersection of the ray `o + t d` (t in `(t_min, t_max)`) with Gaussian `i`, if
    /// its alpha reaches 1/255. `forward` is the camera's forward axis (for `Center` depth).
    #[inline]
    #[allow(clippy::too_many_arguments)] // the hot path: plain values, no per-call struct
    pub fn intersect(
        &self,
        i: usize,
        o: Vec3,
        d: Vec3,
        t_min: f32,
        t_max: f32,
        mode: DepthMode,
        forward: Vec3,
    ) -> Option<Intersection> {
        self.intersect_from(i, &self.origin_terms(i, o), d, t_min, t_max, mode, forward)
    }

    /// The part of [`TraceGaussians::intersect`] that depends on the ray's origin and not its
    /// direction: rays that leave one point (a camera's) share it, computed once per Gaussian.
    #[inline]
    pub fn origin_terms(&self, i: usize, o: Vec3) -> OriginTerms {
        let a = &self.canonical[i];
        let off = o - self.means[i];
        OriginTerms {
            off,
            canonical: Vec3::new(a[0].dot(off), a[1].dot(off), a[2].dot(off)),
        }
    }

    /// [`TraceGaussians::intersect`] from the origin's [`OriginTerms`] for Gaussian `i`: the
    /// same result, bit for bit.
    #[inline]
    #[allow(clippy::too_many_arguments)] // the hot path: plain values, no per-call struct
    pub fn intersect_from(
        &self,
        i: usize,
        origin: &OriginTerms,
        d: Vec3,
        t_min: f32,
        t_max: f32,
        mode: DepthMode,
        forward: Vec3,
    ) -> Option<Intersection> {
        let (t_star, q) = self.closest_point(i, origin, d);
        let alpha = self.alpha(i, q)?;
        let t = match mode {
            DepthMode::Mean => t_star,
            DepthMode::Center => {
                let fd = forward.dot(d);
                if !(fd > 0.0) {
                    return None;
                }
                // `means - o`, exactly: IEEE subtraction is antisymmetric.
                (-origin.off).dot(forward) / fd
            }
        };
        (t > t_min && t < t_max).then_some(Intersection { t, alpha })
    }

    /// The ray's closest point to Gaussian `i`: its distance along the ray (direction `d`),
    /// and its squared canonical distance (NaN where `d` is zero in the Gaussian's frame).
    #[inline(always)]
    pub fn closest_point(&self, i: usize, origin: &OriginTerms, d: Vec3) -> (f32, f32) {
        let a = &self.canonical[i];
        let oc = origin.canonical;
        let dc = Vec3::new(a[0].dot(d), a[1].dot(d), a[2].dot(d));
        let dd = dc.length_squared();
        let t_star = -oc.dot(dc) / dd;
        // Squared canonical distance at the closest point, computed from the point itself (no
        // cancellation for rays far from the Gaussian).
        let q = (oc + t_star * dc).length_squared();
        (t_star, if dd > 0.0 { q } else { f32::NAN })
    }

    /// Gaussian `i`'s alpha where a ray passes at squared canonical distance `q` (from
    /// [`TraceGaussians::closest_point`]): `None` outside its cut-off or below 1/255.
    #[inline]
    pub fn alpha(&self, i: usize, q: f32) -> Option<f32> {
        if !(q <= self.cutoff[i]) {
            return None;
        }
        let alpha = (self.opacity[i] * (-0.5 * q).exp()).min(ALPHA_MAX as f32);
        (alpha >= ALPHA_MIN as f32).then_some(alpha)
    }

    /// How far past the depth of a hit the traversal must still look (and how far before it,
    /// when starting after a hit) so that no intersection that sorts before it is skipped.
    ///
    /// The BVH culls by where a ray meets each Gaussian's box. `Mean` depth lies inside the box
    /// (the point of maximum response is inside the cut-off ellipsoid), so clipping the ray at a
    /// hit's depth is exact: 0. `Center` depth is the centre's depth along the camera's forward
    /// axis `f`; a ray point `p` in the box is within the box's half-diagonal `h` of the centre,
    /// so the two depths differ by at most `h / (d . f)` along the ray. Clipping that much further
    /// out keeps the estimator's expectation the exact composite in centre-depth order.
    #[inline]
    pub fn traversal_margin(&self, mode: DepthMode, d: Vec3, forward: Vec3) -> f32 {
        match mode {
            DepthMode::Mean => 0.0,
            DepthMode::Center => {
                let fd = forward.dot(d);
                // Written so that NaN gives the safe answer: traverse everything.
                if fd > 0.0 {
                    self.max_half_diagonal / fd
                } else {
                    f32::INFINITY
                }
            }
        }
    }

    /// Colour of Gaussian `i` seen from `eye` (3DGS convention for SH: view direction from the
    /// eye to the mean; clamped at 0, never above).
    #[inline]
    pub fn color(&self, i: usize, eye: Vec3) -> Vec3 {
        match self.color_model {
            ColorModel::Rgb => Vec3::from_slice(&self.colors[3 * i..3 * i + 3]).max(Vec3::ZERO),
            // Degree 0 does not depend on the direction: its one basis function is a constant,
            // so the direction and the basis's call are skipped (the cache's clouds are degree
            // 0, and its lookup takes a colour per slot of every ray). The same bits as below.
            ColorModel::Sh(0) => {
                let c = &self.colors[3 * i..3 * i + 3];
                (Vec3::splat(0.5) + sh0_basis() * Vec3::new(c[0], c[1], c[2])).max(Vec3::ZERO)
            }
            ColorModel::Sh(deg) => {
                let n = sh::coeffs_for_degree(deg);
                let c = &self.colors[3 * n * i..3 * n * (i + 1)];
                let dir = (self.means[i] - eye).normalize_or_zero();
                let mut basis = [0.0f32; 16];
                sh::basis(deg, dir.to_array(), &mut basis, None);
                let mut out = Vec3::splat(0.5);
                for k in 0..n {
                    out += basis[k] * Vec3::new(c[3 * k], c[3 * k + 1], c[3 * k + 2]);
                }
                out.max(Vec3::ZERO)
            }
        }
    }
}

/// The degree-0 spherical harmonic's value, as `sh::basis` gives it (computed once).
#[inline]
fn sh0_basis() -> f32 {
    static VALUE: std::sync::LazyLock<f32> = std::sync::LazyLock::new(|| {
        let mut basis = [0.0f32; 1];
        sh::basis(0, [0.0; 3], &mut basis, None);
        basis[0]
    });
    *VALUE
}

/// Gaussians a task of [`TraceGaussians::new`] prepares: a whole number of lanes, enough to
/// hide a task's cost, few enough that a cache's clouds (thousands) spread over the cores.
const PREPARE_BLOCK: usize = 1024;

/// One task's part of [`TraceGaussians::prepare`]'s arrays: its kept Gaussians are written
/// from the start, in order.
struct Block<'a> {
    ids: &'a mut [u32],
    means: &'a mut [Vec3],
    canonical: &'a mut [[Vec3; 3]],
    opacity: &'a mut [f32],
    cutoff: &'a mut [f32],
    lower: &'a mut [Vec3],
    upper: &'a mut [Vec3],
    colors: &'a mut [f32],
    stride: usize,
    /// Gaussians written so far.
    kept: usize,
    largest_half_diagonal: f32,
}

/// [`prepare`] in `isa`'s lanes.
fn prepare_on(isa: Isa, cloud: &GaussianCloud<f32>, range: Range<usize>, out: &mut Block) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: an `Avx2Token` exists only where the processor runs AVX2 and FMA
        // (`Avx2Token::detect`), which is all `prepare_avx2_fma` requires.
        Isa::Avx2Fma(token) => unsafe { prepare_avx2_fma(token, cloud, range, out) },
        Isa::Baseline => prepare::<Baseline>((), cloud, range, out),
    }
}

/// [`prepare`] compiled for AVX2 and FMA, in their lanes.
///
/// # Safety
/// The processor must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn prepare_avx2_fma(
    token: Avx2Token,
    cloud: &GaussianCloud<f32>,
    range: Range<usize>,
    out: &mut Block,
) {
    prepare::<Avx2>(token, cloud, range, out)
}

/// Gaussians `range` of `cloud` in tracing form, written to `out` in order, `L::N` at a
/// time (the last lanes of the last group past the range are masked out).
///
/// Per Gaussian: the unit quaternion's rotation `R`, the scales `s = e^log_scale`, the
/// canonical rows `S^-1 R^T` (the columns of `R` over `s`), the opacity (the logit's
/// sigmoid), the cut-off `2 ln(255 opacity)`, and the exact box of the cut-off ellipsoid:
/// half-extent `i` is `sqrt(cutoff) |row i of R S|`, a hair wider against rounding.
#[inline(always)]
fn prepare<L: Lanes>(
    token: L::Token,
    cloud: &GaussianCloud<f32>,
    range: Range<usize>,
    out: &mut Block,
) {
    let c = |v: f32| L::splat(token, v);
    let (zero, one, two) = (c(0.0), c(1.0), c(2.0));
    // Written so that NaN and infinities fail.
    let finite = |x: L| x.ge(c(f32::MIN)) & x.le(c(f32::MAX));
    let stride = out.stride;
    for g0 in range.clone().step_by(L::N) {
        let lanes = (range.end - g0).min(L::N);
        let field = |values: &[f32], width: usize, k: usize| {
            gather::<L>(token, values, width, k, g0, lanes)
        };
        let (means, rotations, log_scales) = (&cloud.means, &cloud.rotations, &cloud.log_scales);
        let p = [field(means, 3, 0), field(means, 3, 1), field(means, 3, 2)];
        let q = [
            field(rotations, 4, 0),
            field(rotations, 4, 1),
            field(rotations, 4, 2),
            field(rotations, 4, 3),
        ];
        let ls = [
            field(log_scales, 3, 0),
            field(log_scales, 3, 1),
            field(log_scales, 3, 2),
        ];
        let logit = field(&cloud.opacity_logits, 1, 0);
        // The lanes' `exp` clamps its input: a log-scale outside its range is refused.
        let in_range = |x: L| x.ge(c(EXP_MIN)) & x.le(c(EXP_MAX));
        let scale = [exp(token, ls[0]), exp(token, ls[1]), exp(token, ls[2])];
        let opacity = one / (one + exp(token, zero - logit));
        let cutoff = (two * ln(token, c(255.0) * opacity)).max(zero);
        let (qn, _, r) = rotation(token, q);
        // Row k of S^-1 R^T: column k of R over s_k. (Lanes are spelled out, not mapped over
        // arrays: core's generic helpers are not compiled with the caller's AVX2.)
        let inverse = [one / scale[0], one / scale[1], one / scale[2]];
        let canonical = [
            [
                r[0][0] * inverse[0],
                r[1][0] * inverse[0],
                r[2][0] * inverse[0],
            ],
            [
                r[0][1] * inverse[1],
                r[1][1] * inverse[1],
                r[2][1] * inverse[1],
            ],
            [
                r[0][2] * inverse[2],
                r[1][2] * inverse[2],
                r[2][2] * inverse[2],
            ],
        ];
        // |row i of R S|: the box's half-extents for a unit cut-off.
        let reach = |i: usize| length(r[i][0] * scale[0], r[i][1] * scale[1], r[i][2] * scale[2]);
        let magnitude = p[0]
            .max(zero - p[0])
            .max(p[1].max(zero - p[1]))
            .max(p[2].max(zero - p[2]));
        let (radius, margin) = (cutoff.sqrt() * c(1.0 + 1e-5), c(1e-6) * (one + magnitude));
        let half = [
            reach(0) * radius + margin,
            reach(1) * radius + margin,
            reach(2) * radius + margin,
        ];
        let mut keep = qn.gt(zero)
            & finite(qn)
            & finite(logit)
            & opacity.ge(c(ALPHA_MIN as f32))
            & in_range(ls[0])
            & in_range(ls[1])
            & in_range(ls[2]);
        for k in 0..3 {
            keep = keep & finite(p[k]) & finite(half[k]);
            for i in 0..3 {
                keep = keep & finite(canonical[k][i]);
            }
        }
        let diagonal = length(half[0], half[1], half[2]);
        let largest = L::keep(keep, diagonal).reduce_max();
        out.largest_half_diagonal = out.largest_half_diagonal.max(largest);

        // Out of the lanes (`write_kept`), less the Gaussians whose colour is not finite.
        let all = (1u32 << lanes) - 1;
        let mut keep = L::bits(keep) & all;
        let colors = &cloud.colors[g0 * stride..(g0 + lanes) * stride];
        // Branch-free over the group's colours (the common case: all finite).
        if !colors.iter().fold(true, |ok, c| ok & c.is_finite()) {
            for (i, color) in colors.chunks_exact(stride).enumerate() {
                if !color.iter().all(|c| c.is_finite()) {
                    keep &= !(1 << i);
                }
            }
        }
        let mut lanes_of = [[0.0f32; 16]; 17];
        let values = [p[0], p[1], p[2], half[0], half[1], half[2], opacity, cutoff];
        for (k, v) in values.into_iter().enumerate() {
            v.store(&mut lanes_of[k]);
        }
        for k in 0..3 {
            for i in 0..3 {
                canonical[k][i].store(&mut lanes_of[8 + 3 * k + i]);
            }
        }
        write_kept(out, &lanes_of, colors, g0, lanes, keep);
    }
}

/// Writes the kept Gaussians of one group (`keep`: a bit per lane) from their lanes
/// (`lanes_of`: mean, half-extent, opacity, cut-off, canonical rows) and `colors` into `out`:
/// a group kept whole at once, otherwise one at a time.
#[inline(always)]
fn write_kept(
    out: &mut Block,
    lanes_of: &[[f32; 16]; 17],
    colors: &[f32],
    g0: usize,
    lanes: usize,
    mut keep: u32,
) {
    let all = (1u32 << lanes) - 1;
    let at = |k: usize, i: usize| Vec3::new(lanes_of[k][i], lanes_of[k + 1][i], lanes_of[k + 2][i]);
    let (mean, half) = (|i| at(0, i), |i| at(3, i));
    let (k, stride) = (out.kept, out.stride);
    if keep == all {
        // Whole: each array's part written in one pass.
        let part = k..k + lanes;
        for (i, id) in out.ids[part.clone()].iter_mut().enumerate() {
            *id = (g0 + i) as u32;
        }
        for (i, m) in out.means[part.clone()].iter_mut().enumerate() {
            *m = mean(i);
        }
        for (i, l) in out.lower[part.clone()].iter_mut().enumerate() {
            *l = mean(i) - half(i);
        }
        for (i, u) in out.upper[part.clone()].iter_mut().enumerate() {
            *u = mean(i) + half(i);
        }
        out.opacity[part.clone()].copy_from_slice(&lanes_of[6][..lanes]);
        out.cutoff[part.clone()].copy_from_slice(&lanes_of[7][..lanes]);
        for (i, c) in out.canonical[part].iter_mut().enumerate() {
            *c = [at(8, i), at(11, i), at(14, i)];
        }
        out.colors[k * stride..(k + lanes) * stride].copy_from_slice(colors);
        out.kept += lanes;
        return;
    }
    while keep != 0 {
        let i = keep.trailing_zeros() as usize;
        keep &= keep - 1;
        let k = out.kept;
        out.ids[k] = (g0 + i) as u32;
        out.means[k] = mean(i);
        out.lower[k] = mean(i) - half(i);
        out.upper[k] = mean(i) + half(i);
        out.opacity[k] = lanes_of[6][i];
        out.cutoff[k] = lanes_of[7][i];
        out.canonical[k] = [at(8, i), at(11, i), at(14, i)];
        out.colors[k * stride..(k + 1) * stride]
            .copy_from_slice(&colors[i * stride..(i + 1) * stride]);
        out.kept += 1;
    }
}

/// Component `k` of a field with `width` values a Gaussian, for the `lanes` Gaussians from
/// `g0` (0 in the lanes past them). A whole group reads a slice of known length: no bounds
/// check a value.
#[inline(always)]
fn gather<L: Lanes>(
    token: L::Token,
    values: &[f32],
    width: usize,
    k: usize,
    g0: usize,
    lanes: usize,
) -> L {
    let mut lane = [0.0f32; 16];
    if lanes == L::N {
        let group = &values[g0 * width..][..L::N * width];
        for i in 0..L::N {
            lane[i] = group[i * width + k];
        }
    } else {
        for (i, v) in lane[..lanes].iter_mut().enumerate() {
            *v = values[(g0 + i) * width + k];
        }
    }
    L::load(token, &lane)
}

/// The length of the vector `(a, b, c)`, lane by lane.
#[inline(always)]
fn length<L: Lanes>(a: L, b: L, c: L) -> L {
    (a * a + b * b + c * c).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat3, DQuat, DVec3};
    use render_base::hash::{hash32, unit_f32};

    /// The terms `prepare` makes in lanes are the cloud's, computed here one Gaussian at a
    /// time in f64: the same Gaussians kept (in order, across blocks and a last group short
    /// of the lanes), the means exact, the canonical rows, opacity and cut-off within 2e-6
    /// relative (the lanes' `exp` and `ln` are within 3e-7, each product adds a rounding), the
    /// box never smaller than the ellipsoid's exact box and at most 1e-4 larger beyond the
    /// margin, and the largest half-diagonal the boxes' own. For the baseline's lanes and
    /// AVX2's, into arrays a larger cloud filled first. A wrong row, scale or sigmoid moves a
    /// term by far more than 2e-6.
    #[test]
    fn prepared_terms_are_the_clouds_in_f64() {
        let r = |k: u32, i: u32| unit_f32(hash32(&[k, i]));
        let mut cloud = GaussianCloud::new(ColorModel::Rgb);
        let n = 2 * PREPARE_BLOCK as u32 + 452; // three blocks, the last ending 4 past a group
        let mut dropped = Vec::new();
        for i in 0..n {
            let mut mean = [0, 1, 2].map(|k| 20.0 * r(k, i) - 10.0);
            let mut log_scale = [3, 4, 5].map(|k| 6.0 * r(k, i) - 4.0);
            let mut rotation = [6, 7, 8, 9].map(|k| r(k, i) - 0.5);
            let mut color = [0.5f32, 0.25, 0.75];
            let mut logit = 8.0 * r(10, i) - 4.0;
            match i % 97 {
                1 => rotation = [0.0; 4],
                2 => mean[1] = f32::NAN,
                3 => log_scale[2] = 95.0,
                4 => log_scale[0] = -90.0,
                5 => logit = -6.0, // opacity 0.0025, below 1/255
                6 => color[1] = f32::INFINITY,
                7 => logit = f32::NAN,
                _ => {}
            }
            if (1..=7).contains(&(i % 97)) {
                dropped.push(i);
            }
            cloud.push(mean, log_scale, rotation, &color, logit);
        }
        let mut more = cloud.clone();
        for i in 0..3 * n {
            more.push(
                [i as f32; 3],
                [0.0; 3],
                [1.0, 0.0, 0.0, 0.0],
                &[1.0; 3],
                1.0,
            );
        }
        let mut widths = vec![("baseline", Isa::Baseline)];
        #[cfg(target_arch = "x86_64")]
        if let Some(token) = Avx2Token::detect() {
            widths.push(("avx2", Isa::Avx2Fma(token)));
        }
        for (name, isa) in widths {
            // Twice into the same arrays: what a first, larger cloud left is overwritten.
            let mut g = TraceGaussians::new(&more);
            g.prepare_in(isa, &cloud);
            let want: Vec<u32> = (0..n).filter(|i| !dropped.contains(i)).collect();
            assert_eq!(g.ids, want, "{name}: the Gaussians kept");
            let close = |got: f32, want: f64, what: &str, i: u32| {
                let error = (got as f64 - want).abs() / want.abs().max(1e-30);
                assert!(
                    error < 2e-6,
                    "{name}, Gaussian {i}: {what} {got} against {want}"
                );
            };
            let mut largest = 0.0f64;
            for (k, &i) in g.ids.iter().enumerate() {
                let at = |v: &[f32], j: usize, w: usize| v[i as usize * w + j] as f64;
                let mean = DVec3::new(
                    at(&cloud.means, 0, 3),
                    at(&cloud.means, 1, 3),
                    at(&cloud.means, 2, 3),
                );
                assert_eq!(g.means[k].as_dvec3(), mean, "{name}, Gaussian {i}: mean");
                let q = [0, 1, 2, 3].map(|j| at(&cloud.rotations, j, 4));
                let rotation =
                    DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize());
                let scale = DVec3::new(
                    at(&cloud.log_scales, 0, 3),
                    at(&cloud.log_scales, 1, 3),
                    at(&cloud.log_scales, 2, 3),
                )
                .exp();
                let opacity = 1.0 / (1.0 + (-at(&cloud.opacity_logits, 0, 1)).exp());
                let cutoff = 2.0 * (255.0 * opacity).ln();
                close(g.opacity[k], opacity, "opacity", i);
                close(g.cutoff[k], cutoff, "cut-off", i);
                for row in 0..3 {
                    let want = rotation.col(row) / scale[row];
                    for j in 0..3 {
                        let got = g.canonical[k][row][j] as f64;
                        let error = (got - want[j]).abs() / want.length();
                        assert!(error < 2e-6, "{name}, Gaussian {i}: canonical row {row}");
                    }
                }
                // The cut-off ellipsoid's exact box: sqrt(cutoff) |row j of R S|.
                let m = rotation * DMat3::from_diagonal(scale);
                let margin = 1e-6 * (1.0 + mean.abs().max_element());
                let half = (g.upper[k] - g.lower[k]).as_dvec3() * 0.5;
                for j in 0..3 {
                    let exact = cutoff.sqrt() * m.row(j).length();
                    assert!(
                        half[j] >= exact && half[j] <= exact * (1.0 + 1e-4) + 2.0 * margin,
                        "{name}, Gaussian {i}: half-extent {j} {} against {exact}",
                        half[j]
                    );
                }
                let centre = (g.upper[k] + g.lower[k]).as_dvec3() * 0.5;
                assert!(
                    (centre - mean).abs().max_element() <= 1e-5 * (1.0 + mean.abs().max_element())
                );
                largest = largest.max(((g.upper[k] - g.lower[k]) * 0.5).length() as f64);
            }
            close(g.max_half_diagonal, largest, "largest half-diagonal", 0);
            assert_eq!(g.colors.len(), 3 * g.len());
        }
    }
}
