//! Gaussians prepared for tracing, and their response along a ray.
//!
//! In canonical space `y = S^-1 R^T (x - mu)` a Gaussian is `exp(-|y|^2 / 2)`; along the ray
//! `o + t d` the response is a 1D Gaussian whose mean `t*` (the point of maximum response) is
//! where the ray is shaded (`mean` depth mode). Alpha there is `min(0.99, opacity G)`, and
//! intersections with alpha below 1/255 are negligible, as in splat-raster; so each Gaussian is
//! bounded by the ellipsoid `|y|^2 <= 2 ln(255 opacity)` and its exact axis-aligned box: the
//! BVH sees exactly the intersections that a brute-force loop accepts.

use glam::Vec3;
use rayon::prelude::*;
use splat_raster::project::{ALPHA_MAX, ALPHA_MIN};
use splat_raster::sh;
use splat_raster::{ColorModel, GaussianCloud};

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

impl TraceGaussians {
    /// Prepares every Gaussian that can contribute; non-finite, degenerate (zero quaternion,
    /// zero or infinite scale) and too faint (opacity below 1/255) ones are left out.
    pub fn new(cloud: &GaussianCloud<f32>) -> Self {
        let stride = cloud.color_stride();
        // Room for every Gaussian from the start: the arrays are filled without regrowing.
        let n = cloud.len();
        let mut out = TraceGaussians {
            ids: Vec::with_capacity(n),
            means: Vec::with_capacity(n),
            canonical: Vec::with_capacity(n),
            opacity: Vec::with_capacity(n),
            cutoff: Vec::with_capacity(n),
            lower: Vec::with_capacity(n),
            upper: Vec::with_capacity(n),
            max_half_diagonal: 0.0,
            colors: Vec::with_capacity(n * stride),
            color_model: cloud.color_model,
        };
        // Each Gaussian's terms in parallel (the exponentials and the rotation are most of the
        // cost), then gathered in Gaussian order: the same arrays on any thread count.
        let prepared: Vec<Option<Prepared>> = (0..cloud.len())
            .into_par_iter()
            .with_min_len(1024)
            .map(|g| prepare(cloud, g, stride))
            .collect();
        for (g, p) in prepared.into_iter().enumerate() {
            let Some(p) = p else { continue };
            out.ids.push(g as u32);
            out.means.push(p.mean);
            out.canonical.push(p.canonical);
            out.opacity.push(p.opacity);
            out.cutoff.push(p.cutoff);
            out.lower.push(p.mean - p.half);
            out.upper.push(p.mean + p.half);
            out.max_half_diagonal = out.max_half_diagonal.max(p.half.length());
            out.colors
                .extend_from_slice(&cloud.colors[g * stride..(g + 1) * stride]);
        }
        out
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

/// One Gaussian's tracing terms ([`TraceGaussians::new`]).
struct Prepared {
    mean: Vec3,
    canonical: [Vec3; 3],
    opacity: f32,
    cutoff: f32,
    /// Half-extents of its box.
    half: Vec3,
}

/// Gaussian `g`'s tracing terms; `None` when it is degenerate, not finite or below 1/255.
fn prepare(cloud: &GaussianCloud<f32>, g: usize, stride: usize) -> Option<Prepared> {
    let mean = Vec3::from_slice(&cloud.means[3 * g..3 * g + 3]);
    let q = &cloud.rotations[4 * g..4 * g + 4];
    let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let s = Vec3::from_slice(&cloud.log_scales[3 * g..3 * g + 3]).exp();
    let opacity = 1.0 / (1.0 + (-cloud.opacity_logits[g]).exp());
    let color = &cloud.colors[g * stride..(g + 1) * stride];
    // Written so that NaN fails.
    let finite =
        qn > 0.0 && qn.is_finite() && mean.is_finite() && s.is_finite() && s.min_element() > 0.0;
    let visible = opacity >= ALPHA_MIN as f32 && color.iter().all(|c| c.is_finite());
    if !(finite && visible) {
        return None;
    }
    let r = glam::Mat3::from_quat(glam::Quat::from_xyzw(
        q[1] / qn,
        q[2] / qn,
        q[3] / qn,
        q[0] / qn,
    ));
    let inv_s = 1.0 / s;
    // Rows of S^-1 R^T are the columns of R scaled by 1/s.
    let canonical = [r.x_axis * inv_s.x, r.y_axis * inv_s.y, r.z_axis * inv_s.z];
    if !canonical.iter().all(|v| v.is_finite()) {
        return None;
    }
    let cutoff = 2.0 * (255.0 * opacity).ln();
    // Exact box of the ellipsoid |S^-1 R^T (x - mu)| <= sqrt(cutoff): half-extent along
    // world axis i is sqrt(cutoff) * |row i of R S|; a hair wider against rounding.
    let m = glam::Mat3::from_cols(r.x_axis * s.x, r.y_axis * s.y, r.z_axis * s.z);
    let rows = [m.row(0), m.row(1), m.row(2)];
    let half = Vec3::new(rows[0].length(), rows[1].length(), rows[2].length())
        * cutoff.sqrt()
        * (1.0 + 1e-5)
        + 1e-6 * (1.0 + mean.abs().max_element());
    half.is_finite().then_some(Prepared {
        mean,
        canonical,
        opacity,
        cutoff,
        half,
    })
}
