//! The projection of [`crate::project`] and its adjoint, 8 or 4 Gaussians at a time in SIMD
//! lanes (f32).
//!
//! Why: one at a time, a Gaussian's projection costs about 70 ns a core (three `exp` for its
//! scales, one for its opacity, one `ln`, three square roots and a dozen divisions) and its
//! adjoint about twice that: a quarter of a 300k-Gaussian frame at 2 threads, and a third of
//! its backward pass (issue 31).
//!
//! The equations are `project::project`'s and `project::project_backward`'s, term for term,
//! on the same geometry ([`LaneGeometry`]). The lanes' `exp` and `ln` ([`crate::lanes`]) round
//! differently from libm, within `EXP_MAX_REL_ERROR` and `LN_MAX_ERROR`, so a splat can differ
//! from the scalar projection's in its last bits; its screen rectangle keeps the scalar one's
//! margin (1e-5 relative and 1e-3 px), thousands of times those bits, so it still holds every
//! pixel whose alpha reaches 1/255. Culling runs in the lanes as masks. Each surviving
//! Gaussian's rectangle (floor and ceiling) and colour (RGB or spherical harmonics), and each
//! colour gradient, are finished one at a time by the scalar code.
//!
//! The lane count divides the chunks of `raster::project_and_bin` and the gradient blocks of
//! `raster::backward` except for a tail of fewer than N Gaussians, which the scalar code takes;
//! both depend on the cloud's size alone, so the results are the same on any number of threads.

use crate::cloud::GaussianCloud;
use crate::lanes::{self, Lanes};
use crate::project::{
    ALPHA_MIN, CameraTerms, LowPass, Splat, color_backward, project, project_backward, raw_color,
};
use crate::real::SplatGrad;
use std::ops::Range;

// No lane value in this module passes through a generic helper (`array::map`, iterators):
// those are compiled without the caller's AVX2, so a closure over lanes inside them would
// become a call per element. Hence the spelled-out arrays.

/// The camera's terms as lanes, made once per range.
struct LaneCamera<L: Lanes> {
    w: [[L; 3]; 3],
    position: [L; 3],
    focal: L,
    lim_x: L,
    lim_y: L,
    variance: L,
}

impl<L: Lanes> LaneCamera<L> {
    #[inline(always)]
    fn new(token: L::Token, cam: &CameraTerms<f32>, low_pass: LowPass) -> Self {
        let s = |v: f32| L::splat(token, v);
        let w = cam.w;
        Self {
            w: [
                [s(w[0][0]), s(w[0][1]), s(w[0][2])],
                [s(w[1][0]), s(w[1][1]), s(w[1][2])],
                [s(w[2][0]), s(w[2][1]), s(w[2][2])],
            ],
            position: [s(cam.position[0]), s(cam.position[1]), s(cam.position[2])],
            focal: s(cam.focal),
            lim_x: s(cam.lim_x),
            lim_y: s(cam.lim_y),
            variance: s(low_pass.variance() as f32),
        }
    }
}

/// Component `k` of a field with `stride` values per Gaussian, for Gaussians `g0..g0 + N`.
#[inline(always)]
fn gather<L: Lanes>(token: L::Token, values: &[f32], stride: usize, k: usize, g0: usize) -> L {
    let mut lane = [0.0f32; 16];
    for i in 0..L::N {
        lane[i] = values[(g0 + i) * stride + k];
    }
    L::load(token, &lane)
}

#[inline(always)]
fn dot<L: Lanes>(a: &[L; 3], b: &[L; 3]) -> L {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `project::geometry` for Gaussians `g0..g0 + N`: what the projection and its adjoint share.
struct LaneGeometry<L: Lanes> {
    /// Camera-space mean.
    t: [L; 3],
    /// Norm of the stored quaternion, and the unit quaternion (w, x, y, z).
    qn: L,
    qh: [L; 4],
    /// Standard deviations, rotation, and `M = R S`.
    scale: [L; 3],
    r: [[L; 3]; 3],
    m: [[L; 3]; 3],
    /// Camera-space x and y after the guard-band clamp, and where the clamp did not act.
    txc: L,
    tyc: L,
    x_inside: L::Mask,
    y_inside: L::Mask,
    /// `T = J W` (rows) and `Sigma T_i`.
    tm: [[L; 3]; 2],
    ts: [[L; 3]; 2],
    /// The projected covariance before the low-pass: [[a0, b0], [b0, c0]].
    a0: L,
    b0: L,
    c0: L,
}

#[inline(always)]
fn geometry<L: Lanes>(
    token: L::Token,
    cloud: &GaussianCloud<f32>,
    g0: usize,
    cam: &LaneCamera<L>,
) -> LaneGeometry<L> {
    let s = |v: f32| L::splat(token, v);
    let zero = s(0.0);
    let field = |values: &[f32], stride: usize, k: usize| gather::<L>(token, values, stride, k, g0);
    let means = &cloud.means;
    let p = [field(means, 3, 0), field(means, 3, 1), field(means, 3, 2)];
    let rot = &cloud.rotations;
    let q = [
        field(rot, 4, 0),
        field(rot, 4, 1),
        field(rot, 4, 2),
        field(rot, 4, 3),
    ];
    let ls = &cloud.log_scales;
    let scale = [
        lanes::exp(token, field(ls, 3, 0)),
        lanes::exp(token, field(ls, 3, 1)),
        lanes::exp(token, field(ls, 3, 2)),
    ];
    let w = &cam.w;
    // Camera-space mean: t = W (p - c).
    let d = [
        p[0] - cam.position[0],
        p[1] - cam.position[1],
        p[2] - cam.position[2],
    ];
    let t = [dot(&w[0], &d), dot(&w[1], &d), dot(&w[2], &d)];
    // Sigma = M M^T with M = R(q / |q|) S.
    let (qn, qh, r) = lanes::rotation(token, q);
    let m = [
        [r[0][0] * scale[0], r[0][1] * scale[1], r[0][2] * scale[2]],
        [r[1][0] * scale[0], r[1][1] * scale[1], r[1][2] * scale[2]],
        [r[2][0] * scale[0], r[2][1] * scale[1], r[2][2] * scale[2]],
    ];
    let (s00, s01, s02) = (dot(&m[0], &m[0]), dot(&m[0], &m[1]), dot(&m[0], &m[2]));
    let (s11, s12, s22) = (dot(&m[1], &m[1]), dot(&m[1], &m[2]), dot(&m[2], &m[2]));
    // The perspective Jacobian at the guard-band-clamped mean, and T = J W.
    let (tx, ty, tz) = (t[0], t[1], t[2]);
    let (rx, ry) = (tx / tz, ty / tz);
    let x_inside = rx.ge(zero - cam.lim_x) & rx.le(cam.lim_x);
    let y_inside = ry.ge(zero - cam.lim_y) & ry.le(cam.lim_y);
    let txc = rx.max(zero - cam.lim_x).min(cam.lim_x) * tz;
    let tyc = ry.max(zero - cam.lim_y).min(cam.lim_y) * tz;
    let f = cam.focal;
    let (j_diag, tz2) = (f / tz, tz * tz);
    let (j02, j12) = (zero - f * txc / tz2, zero - f * tyc / tz2);
    let tm = [
        [
            j_diag * w[0][0] + j02 * w[2][0],
            j_diag * w[0][1] + j02 * w[2][1],
            j_diag * w[0][2] + j02 * w[2][2],
        ],
        [
            j_diag * w[1][0] + j12 * w[2][0],
            j_diag * w[1][1] + j12 * w[2][1],
            j_diag * w[1][2] + j12 * w[2][2],
        ],
    ];
    // Sigma T_i, in the scalar code's order (Sigma^T T_i: Sigma is symmetric).
    let sigma_t = |v: &[L; 3]| {
        [
            s00 * v[0] + s01 * v[1] + s02 * v[2],
            s01 * v[0] + s11 * v[1] + s12 * v[2],
            s02 * v[0] + s12 * v[1] + s22 * v[2],
        ]
    };
    let ts = [sigma_t(&tm[0]), sigma_t(&tm[1])];
    LaneGeometry {
        t,
        qn,
        qh,
        scale,
        r,
        m,
        txc,
        tyc,
        x_inside,
        y_inside,
        a0: dot(&tm[0], &ts[0]),
        b0: dot(&tm[0], &ts[1]),
        c0: dot(&tm[1], &ts[1]),
        tm,
        ts,
    }
}

/// The sigmoid as `project::sigmoid` takes it: 1 / (1 + e^-x) for x >= 0, e^x / (1 + e^x)
/// below, both from e = e^-|x|.
#[inline(always)]
fn sigmoid<L: Lanes>(token: L::Token, x: L) -> L {
    let (zero, one) = (L::splat(token, 0.0), L::splat(token, 1.0));
    let positive = x.ge(zero);
    let e = lanes::exp(token, L::select(positive, zero - x, x));
    L::select(positive, one / (one + e), e / (one + e))
}

/// Projects Gaussians `range` of `cloud`, appending each survivor's splat and index in order.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn project_range<L: Lanes>(
    token: L::Token,
    cloud: &GaussianCloud<f32>,
    range: Range<usize>,
    cam: &CameraTerms<f32>,
    low_pass: LowPass,
    near: f32,
    splats: &mut Vec<Splat<f32>>,
    ids: &mut Vec<u32>,
) {
    let n = L::N;
    let s = |v: f32| L::splat(token, v);
    let (zero, two) = (s(0.0), s(2.0));
    // Written so that NaN and infinities fail.
    let (lowest, highest) = (s(f32::MIN), s(f32::MAX));
    let finite = |x: L| x.ge(lowest) & x.le(highest);
    let lane_cam = LaneCamera::<L>::new(token, cam, low_pass);
    let focal = lane_cam.focal;
    let mut g0 = range.start;
    while g0 + n <= range.end {
        let geo = geometry(token, cloud, g0, &lane_cam);
        let [tx, ty, tz] = geo.t;
        let (a0, b0, c0) = (geo.a0, geo.b0, geo.c0);
        let (a, c) = (a0 + lane_cam.variance, c0 + lane_cam.variance);
        let det = a * c - b0 * b0;
        let logit = gather::<L>(token, &cloud.opacity_logits, 1, 0, g0);
        let mut opacity = sigmoid(token, logit);
        if low_pass == LowPass::Mip {
            let det0 = a0 * c0 - b0 * b0;
            opacity = opacity * (det0 / det).max(zero).sqrt();
        }
        let alive = tz.gt(s(near))
            & finite(tx)
            & finite(ty)
            & geo.qn.gt(zero)
            & finite(geo.qn)
            & det.gt(zero)
            & finite(det)
            & finite(a)
            & finite(c)
            & opacity.ge(s(ALPHA_MIN as f32));
        if L::any(alive) {
            let u = focal * tx / tz + s(cam.cx);
            let v = focal * ty / tz + s(cam.cy);
            // alpha >= 1/255 inside the ellipse d^T conic d <= 2 ln(255 opacity).
            let log_reach = lanes::ln(token, s(255.0) * opacity);
            let k2 = two * log_reach;
            let ex = (k2 * a).sqrt() * s(1.0 + 1e-5) + s(1e-3);
            let ey = (k2 * c).sqrt() * s(1.0 + 1e-5) + s(1e-3);
            let mut out = [[0.0f32; 16]; 10];
            u.store(&mut out[0]);
            v.store(&mut out[1]);
            ex.store(&mut out[2]);
            ey.store(&mut out[3]);
            (c / det).store(&mut out[4]);
            (zero - b0 / det).store(&mut out[5]);
            (a / det).store(&mut out[6]);
            opacity.store(&mut out[7]);
            tz.store(&mut out[8]);
            (zero - log_reach).store(&mut out[9]);
            let mut alive_bits = [0u32; 16];
            L::select(alive, s(1.0), zero).store_bits(&mut alive_bits);
            for i in 0..n {
                if alive_bits[i] == 0 {
                    continue;
                }
                let [u, v, ex, ey, ca, cb, cc, opacity, depth, power_min] = out.map(|o| o[i]);
                if let Some(splat) = finish(
                    cloud,
                    g0 + i,
                    cam,
                    [u, v],
                    [ex, ey],
                    [ca, cb, cc],
                    opacity,
                    depth,
                    power_min,
                ) {
                    splats.push(splat);
                    ids.push((g0 + i) as u32);
                }
            }
        }
        g0 += n;
    }
    for g in g0..range.end {
        if let Some(splat) = project(cloud, g, cam, low_pass, near) {
            splats.push(splat);
            ids.push(g as u32);
        }
    }
}

/// A block of Gaussians' parameter gradients: slices of a cloud-shaped buffer that start at
/// the block's first Gaussian.
pub(crate) struct GradientBlock<'a> {
    pub means: &'a mut [f32],
    pub log_scales: &'a mut [f32],
    pub rotations: &'a mut [f32],
    pub colors: &'a mut [f32],
    pub opacity_logits: &'a mut [f32],
}

/// `project::project_backward` for Gaussians `first..first + totals.len()`, N at a time:
/// `totals[i]` is Gaussian `first + i`'s summed splat gradient (None: culled, no gradient),
/// added into `out`. The same equations, term for term; the colour part (a clamp, or spherical
/// harmonics) runs per Gaussian in `project::color_backward`. A tail of fewer than N Gaussians
/// takes the scalar adjoint; blocks are fixed by the cloud's size, so the gradients are the
/// same on any number of threads.
#[inline(always)]
pub(crate) fn project_backward_range<L: Lanes>(
    token: L::Token,
    cloud: &GaussianCloud<f32>,
    first: usize,
    totals: &[Option<SplatGrad<f32>>],
    cam: &CameraTerms<f32>,
    low_pass: LowPass,
    out: GradientBlock<'_>,
) {
    let n = L::N;
    let s = |v: f32| L::splat(token, v);
    let (zero, one, two, half) = (s(0.0), s(1.0), s(2.0), s(0.5));
    let lane_cam = LaneCamera::<L>::new(token, cam, low_pass);
    let (f, w) = (lane_cam.focal, &lane_cam.w);
    let stride = cloud.color_stride();
    let mut j = 0;
    while j + n <= totals.len() {
        let group = &totals[j..j + n];
        if group.iter().all(|t| t.is_none()) {
            j += n;
            continue;
        }
        // The summed splat gradients as lanes (culled lanes hold zeros and are not written).
        let mut dg = [[0.0f32; 16]; 8];
        for (i, total) in group.iter().enumerate() {
            if let Some(t) = total {
                let fields = [
                    t.xy[0], t.xy[1], t.conic[0], t.conic[1], t.conic[2], t.opacity, t.depth, 0.0,
                ];
                for (lane, v) in dg.iter_mut().zip(fields) {
                    lane[i] = v;
                }
            }
        }
        let dg_xy = [L::load(token, &dg[0]), L::load(token, &dg[1])];
        let dg_conic = [
            L::load(token, &dg[2]),
            L::load(token, &dg[3]),
            L::load(token, &dg[4]),
        ];
        let (dg_opacity, dg_depth) = (L::load(token, &dg[5]), L::load(token, &dg[6]));

        let g0 = first + j;
        let geo = geometry(token, cloud, g0, &lane_cam);
        let [tx, ty, tz] = geo.t;
        let (a0, b0, c0, tm, ts) = (geo.a0, geo.b0, geo.c0, &geo.tm, &geo.ts);
        let (a, c) = (a0 + lane_cam.variance, c0 + lane_cam.variance);
        let det = a * c - b0 * b0;

        // Opacity: alpha0 = sigmoid(l) * comp.
        let sg = sigmoid(token, gather::<L>(token, &cloud.opacity_logits, 1, 0, g0));
        let det0 = a0 * c0 - b0 * b0;
        let comp = if low_pass == LowPass::Mip {
            (det0 / det).max(zero).sqrt()
        } else {
            one
        };
        let d_logit = dg_opacity * comp * sg * (one - sg);

        // Conic K = Sigma2^-1: dL/dSigma2 = -K G K with G the symmetric gradient.
        let (k01, gk01) = (zero - b0 / det, dg_conic[1] / two);
        let kk = [[c / det, k01], [k01, a / det]];
        let gk = [[dg_conic[0], gk01], [gk01, dg_conic[2]]];
        let kgk = |i: usize, jx: usize| {
            let mut acc = zero;
            for a_ in 0..2 {
                for b_ in 0..2 {
                    acc = acc + kk[i][a_] * gk[a_][b_] * kk[b_][jx];
                }
            }
            zero - acc
        };
        let mut g2 = [[kgk(0, 0), kgk(0, 1)], [kgk(1, 0), kgk(1, 1)]];
        if low_pass == LowPass::Mip {
            // comp = sqrt(det0 / det1), where det0 > 0.
            let positive = det0.gt(zero);
            let dcomp = dg_opacity * sg;
            let hc = half * comp;
            let d00 = dcomp * hc * (c0 / det0 - c / det);
            let d11 = dcomp * hc * (a0 / det0 - a / det);
            let off = dcomp * hc * (zero - b0 / det0 + b0 / det);
            g2[0][0] = L::select(positive, g2[0][0] + d00, g2[0][0]);
            g2[1][1] = L::select(positive, g2[1][1] + d11, g2[1][1]);
            g2[0][1] = L::select(positive, g2[0][1] + off, g2[0][1]);
            g2[1][0] = L::select(positive, g2[1][0] + off, g2[1][0]);
        }

        // Sigma2 = T Sigma T^T: dL/dSigma = T^T G2 T, dL/dT = 2 G2 T Sigma.
        let d_sigma_entry = |i: usize, jx: usize| {
            let mut acc = zero;
            for a_ in 0..2 {
                for b_ in 0..2 {
                    acc = acc + tm[a_][i] * g2[a_][b_] * tm[b_][jx];
                }
            }
            acc
        };
        let mut d_sigma = [[zero; 3]; 3];
        for i in 0..3 {
            for jx in 0..3 {
                d_sigma[i][jx] = d_sigma_entry(i, jx);
            }
        }
        let d_t_entry = |a_: usize, i: usize| two * (g2[a_][0] * ts[0][i] + g2[a_][1] * ts[1][i]);
        let d_t = [
            [d_t_entry(0, 0), d_t_entry(0, 1), d_t_entry(0, 2)],
            [d_t_entry(1, 0), d_t_entry(1, 1), d_t_entry(1, 2)],
        ];
        // T = J W: dL/dJ = dL/dT W^T (only the non-zero entries of J matter).
        let d_j00 = dot(&d_t[0], &w[0]);
        let d_j02 = dot(&d_t[0], &w[2]);
        let d_j11 = dot(&d_t[1], &w[1]);
        let d_j12 = dot(&d_t[1], &w[2]);
        let tz2 = tz * tz;
        let tz3 = tz2 * tz;
        let mut d2 = zero - (d_j00 + d_j11) * f / tz2;
        let d0 = L::select(geo.x_inside, zero - d_j02 * f / tz2, zero);
        d2 = L::select(
            geo.x_inside,
            d2 + d_j02 * two * f * tx / tz3,
            d2 + d_j02 * f * geo.txc / tz3,
        );
        let d1 = L::select(geo.y_inside, zero - d_j12 * f / tz2, zero);
        d2 = L::select(
            geo.y_inside,
            d2 + d_j12 * two * f * ty / tz3,
            d2 + d_j12 * f * geo.tyc / tz3,
        );
        // Screen position and depth.
        let d0 = d0 + dg_xy[0] * f / tz;
        let d1 = d1 + dg_xy[1] * f / tz;
        let d2 = d2 - (dg_xy[0] * f * tx + dg_xy[1] * f * ty) / tz2 + dg_depth;
        let dp = [
            w[0][0] * d0 + w[1][0] * d1 + w[2][0] * d2,
            w[0][1] * d0 + w[1][1] * d1 + w[2][1] * d2,
            w[0][2] * d0 + w[1][2] * d1 + w[2][2] * d2,
        ];

        // Sigma = M M^T, M = R S: dL/dM = 2 dL/dSigma M.
        let (m, r, scale) = (&geo.m, &geo.r, &geo.scale);
        let d_m_entry = |i: usize, jx: usize| {
            two * (d_sigma[i][0] * m[0][jx] + d_sigma[i][1] * m[1][jx] + d_sigma[i][2] * m[2][jx])
        };
        let mut d_r = [[zero; 3]; 3];
        let mut d_log_scale = [zero; 3];
        for jx in 0..3 {
            let mut ds = zero;
            for i in 0..3 {
                let d_m = d_m_entry(i, jx);
                ds = ds + d_m * r[i][jx];
                d_r[i][jx] = d_m * scale[jx];
            }
            d_log_scale[jx] = ds * scale[jx];
        }
        // `real::quat_to_mat_backward`, and the unit quaternion's projection.
        let [qw, qx, qy, qz] = geo.qh;
        let g = &d_r;
        let dqh = [
            two * (zero - qz * g[0][1] + qy * g[0][2] + qz * g[1][0] - qx * g[1][2] - qy * g[2][0]
                + qx * g[2][1]),
            two * (qy * g[0][1] + qz * g[0][2] + qy * g[1][0] - two * qx * g[1][1] - qw * g[1][2]
                + qz * g[2][0]
                + qw * g[2][1]
                - two * qx * g[2][2]),
            two * (zero - two * qy * g[0][0]
                + qx * g[0][1]
                + qw * g[0][2]
                + qx * g[1][0]
                + qz * g[1][2]
                - qw * g[2][0]
                + qz * g[2][1]
                - two * qy * g[2][2]),
            two * (zero - two * qz * g[0][0] - qw * g[0][1] + qx * g[0][2] + qw * g[1][0]
                - two * qz * g[1][1]
                + qy * g[1][2]
                + qx * g[2][0]
                + qy * g[2][1]),
        ];
        let proj = dqh[0] * qw + dqh[1] * qx + dqh[2] * qy + dqh[3] * qz;
        let qh = [qw, qx, qy, qz];

        // Out of the lanes, into each live Gaussian's slices.
        let mut lanes_out = [[0.0f32; 16]; 11];
        for k in 0..3 {
            dp[k].store(&mut lanes_out[k]);
            d_log_scale[k].store(&mut lanes_out[3 + k]);
        }
        for k in 0..4 {
            ((dqh[k] - qh[k] * proj) / geo.qn).store(&mut lanes_out[6 + k]);
        }
        d_logit.store(&mut lanes_out[10]);
        for (i, total) in group.iter().enumerate() {
            let Some(total) = total else { continue };
            let g = j + i;
            let d_mean = &mut out.means[3 * g..3 * g + 3];
            for k in 0..3 {
                d_mean[k] += lanes_out[k][i];
                out.log_scales[3 * g + k] += lanes_out[3 + k][i];
            }
            for k in 0..4 {
                out.rotations[4 * g + k] += lanes_out[6 + k][i];
            }
            out.opacity_logits[g] += lanes_out[10][i];
            let d_color = &mut out.colors[stride * g..stride * (g + 1)];
            color_backward(cloud, first + g, cam, total.color, d_mean, d_color);
        }
        j += n;
    }
    for (g, total) in totals.iter().enumerate().skip(j) {
        let Some(total) = total else { continue };
        project_backward(
            cloud,
            first + g,
            cam,
            low_pass,
            total,
            &mut out.means[3 * g..3 * g + 3],
            &mut out.log_scales[3 * g..3 * g + 3],
            &mut out.rotations[4 * g..4 * g + 4],
            &mut out.colors[stride * g..stride * (g + 1)],
            &mut out.opacity_logits[g],
        );
    }
}

/// A survivor's splat: its pixel rectangle (None when off screen) and its colour (None when
/// not finite), as `project::project` makes them.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn finish(
    cloud: &GaussianCloud<f32>,
    g: usize,
    cam: &CameraTerms<f32>,
    xy: [f32; 2],
    extent: [f32; 2],
    conic: [f32; 3],
    opacity: f32,
    depth: f32,
    power_min: f32,
) -> Option<Splat<f32>> {
    let ([u, v], [ex, ey]) = (xy, extent);
    let x0 = (u - ex - 0.5).ceil().max(0.0);
    let x1 = (u + ex - 0.5).floor().min(cam.width as f32 - 1.0);
    let y0 = (v - ey - 0.5).ceil().max(0.0);
    let y1 = (v + ey - 0.5).floor().min(cam.height as f32 - 1.0);
    if !(x0 <= x1 && y0 <= y1) {
        return None;
    }
    let mean = [
        cloud.means[3 * g],
        cloud.means[3 * g + 1],
        cloud.means[3 * g + 2],
    ];
    let mut basis = [0.0f32; 16];
    let color = raw_color(cloud, g, mean, cam.position, &mut basis).map(|c| c.max(0.0));
    if !color.iter().all(|c| c.is_finite()) {
        return None;
    }
    Some(Splat {
        xy,
        conic,
        opacity,
        color,
        depth,
        power_min,
        rect: [x0 as u32, y0 as u32, x1 as u32, y1 as u32],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::cloud::ColorModel;
    use crate::random::{hash32, unit_f32};
    use glam::Vec3;

    /// A cloud that exercises every cull: Gaussians behind the camera and on its near plane,
    /// off screen and beyond the guard band (some reaching the screen), with zero and non-finite quaternions, tiny and huge
    /// scales, opacities from far below 1/255 to the cap, and the rest ordinary.
    fn hard_cloud(n: usize, model: ColorModel) -> GaussianCloud<f32> {
        let mut cloud = GaussianCloud::<f32>::new(model);
        let r = |g: usize, k: u32| unit_f32(hash32(&[g as u32, k, 0x9e37]));
        for g in 0..n {
            let kind = g % 10;
            let spread = if kind == 1 { 12.0 } else { 1.5 };
            let mut mean = [0, 1, 2].map(|k| (r(g, k) - 0.5) * 2.0 * spread);
            if kind == 2 {
                mean[2] = -4.0 + 0.01 * (r(g, 3) - 0.5); // on the camera's near plane
            }
            // Beyond the guard band (1.3x the half field of view: at 4 units' depth, y past
            // 2.4, x past 4.3) but wide enough to reach the screen: the clamped Jacobian.
            let side = if r(g, 13) < 0.5 { -1.0 } else { 1.0 };
            match kind {
                6 => mean[1] = side * (2.7 + r(g, 3)),
                7 => mean[0] = side * (4.6 + r(g, 3)),
                _ => {}
            }
            // Anisotropic up to e^3; kind 3 nearly round but up to e^10 across (anisotropy of
            // e^14 would leave f32 nothing of the projected covariance to compare).
            let log_scale = if kind == 3 {
                let size = -4.0 + 14.0 * r(g, 4);
                [4, 5, 6].map(|k| size + 0.5 * r(g, k + 1))
            } else if kind == 6 || kind == 7 {
                [4, 5, 6].map(|k| 0.3 + 0.7 * r(g, k))
            } else {
                [4, 5, 6].map(|k| -4.0 + 3.0 * r(g, k))
            };
            let mut rotation = [7, 8, 9, 10].map(|k| r(g, k) - 0.5);
            match kind {
                4 => rotation = [0.0; 4],
                5 if g % 20 == 5 => rotation[1] = f32::NAN,
                _ => {}
            }
            let logit = -9.0 + 16.0 * r(g, 11);
            let color: Vec<f32> = (0..cloud.color_stride())
                .map(|i| (r(g, 12 + i as u32) - 0.3) * if i < 3 { 2.0 } else { 0.4 })
                .collect();
            cloud.push(mean, log_scale, rotation, &color, logit);
        }
        cloud
    }

    /// The camera both checks look through: the hard cloud's kinds are placed for it.
    fn test_camera() -> Camera {
        Camera::look_at(
            Vec3::new(0.3, -0.2, -4.0),
            Vec3::ZERO,
            Vec3::Y,
            50.0,
            320,
            180,
        )
        .unwrap()
    }

    /// The lanes keep the same Gaussians as the scalar projection and make the same splats:
    /// the same rectangles and colours, and the same geometry within the lanes' `exp` and `ln`
    /// error (`EXP_MAX_REL_ERROR`, `LN_MAX_ERROR`) carried through a few roundings.
    fn check<L: Lanes>(token: L::Token, name: &str) {
        let camera = test_camera();
        let cam = CameraTerms::<f32>::new(&camera);
        for model in [ColorModel::Rgb, ColorModel::Sh(2)] {
            for low_pass in [LowPass::Classic, LowPass::Mip] {
                // 4003 Gaussians: not a multiple of the lanes, so the scalar tail runs too.
                let cloud = hard_cloud(4003, model);
                let (mut splats, mut ids) = (Vec::new(), Vec::new());
                project_range::<L>(
                    token,
                    &cloud,
                    0..cloud.len(),
                    &cam,
                    low_pass,
                    0.01,
                    &mut splats,
                    &mut ids,
                );
                let want: Vec<(u32, Splat<f32>)> = (0..cloud.len())
                    .filter_map(|g| project(&cloud, g, &cam, low_pass, 0.01).map(|s| (g as u32, s)))
                    .collect();
                let case = format!("{name}, {model:?}, {low_pass:?}");
                assert!(
                    want.len() > 1000 && want.len() < cloud.len() * 3 / 4,
                    "{case}: {} survive",
                    want.len()
                );
                let want_ids: Vec<u32> = want.iter().map(|w| w.0).collect();
                assert_eq!(ids, want_ids, "{case}: the survivors differ");
                for ((got, (g, want)), _) in splats.iter().zip(&want).zip(&ids) {
                    assert_eq!(got.rect, want.rect, "{case}: Gaussian {g}");
                    assert_eq!(got.color, want.color, "{case}: Gaussian {g}");
                    // Pixel positions against the image's scale (they cancel near its
                    // left and top edges); the reach exponent `-ln(255 opacity)` absolutely
                    // (it crosses 0 where the opacity is 1/255); the rest relatively.
                    let checks = [
                        ("x", got.xy[0], want.xy[0], cam.cx),
                        ("y", got.xy[1], want.xy[1], cam.cy),
                        ("depth", got.depth, want.depth, want.depth.abs()),
                        ("opacity", got.opacity, want.opacity, want.opacity),
                        ("power_min", got.power_min, want.power_min, 1.0),
                    ];
                    for (field, a, b, scale) in checks {
                        assert!(
                            (a - b).abs() <= 4e-6 * scale.max(b.abs()),
                            "{case}: Gaussian {g}'s {field}: {a} vs {b}"
                        );
                    }
                    // The conic divides by a determinant `a c - b^2` that cancels for splats
                    // seen edge on: compare it against its scale times that cancellation,
                    // `a c / (a c - b^2)` (1 for a round splat).
                    let [ca, cb, cc] = want.conic.map(|v| v as f64);
                    let cancellation = ca * cc / (ca * cc - cb * cb);
                    let scale = ca.abs().max(cc.abs()) * cancellation;
                    for (a, b) in got.conic.iter().zip(&want.conic) {
                        assert!(
                            ((a - b).abs() as f64) <= 1e-5 * scale,
                            "{case}: Gaussian {g}'s conic: {a} vs {b} (cancellation {cancellation})"
                        );
                    }
                }
            }
        }
    }

    /// The lanes' adjoint is as accurate as the scalar f32 one: against the f64 adjoint, each
    /// gradient entry's error is at most 4x the scalar f32 error plus 1e-4 of its parameter
    /// group's largest entry (mean, scales, rotation, colour, opacity of that Gaussian), for
    /// random splat gradients; culled Gaussians get none. A wrong term or sign is off by the
    /// size of the term itself, far beyond the bound. The Gaussians on the near plane and the
    /// huge ones (`hard_cloud`'s kinds 2 and 3) are held to 1e-2 instead: their chains subtract
    /// nearly equal terms, so both f32 adjoints are off by up to 1e-3 of the group, and which
    /// of the two lands nearer the f64 value is chance.
    fn check_adjoint<L: Lanes>(token: L::Token, name: &str) {
        let camera = test_camera();
        let cam = CameraTerms::<f32>::new(&camera);
        let r = |g: usize, k: u32| unit_f32(hash32(&[g as u32, k, 0x5eed])) * 2.0 - 1.0;
        for model in [ColorModel::Rgb, ColorModel::Sh(2)] {
            for low_pass in [LowPass::Classic, LowPass::Mip] {
                let cloud = hard_cloud(4003, model);
                let totals: Vec<Option<SplatGrad<f32>>> = (0..cloud.len())
                    .map(|g| {
                        project(&cloud, g, &cam, low_pass, 0.01).map(|_| SplatGrad {
                            xy: [r(g, 0), r(g, 1)],
                            conic: [r(g, 2) * 50.0, r(g, 3) * 50.0, r(g, 4) * 50.0],
                            opacity: r(g, 5),
                            color: [r(g, 6), r(g, 7), r(g, 8)],
                            depth: r(g, 9),
                        })
                    })
                    .collect();
                let mut lanes = cloud.zeros_like();
                {
                    let GaussianCloud {
                        means,
                        log_scales,
                        rotations,
                        colors,
                        opacity_logits,
                        ..
                    } = &mut lanes;
                    let block = GradientBlock {
                        means,
                        log_scales,
                        rotations,
                        colors,
                        opacity_logits,
                    };
                    project_backward_range::<L>(token, &cloud, 0, &totals, &cam, low_pass, block);
                }
                let stride = cloud.color_stride();
                // The scalar adjoint on f32 and on f64, Gaussian by Gaussian.
                fn scalar_adjoint<F: crate::real::Real>(
                    cloud: &GaussianCloud<F>,
                    cam: &CameraTerms<F>,
                    low_pass: LowPass,
                    totals: &[Option<SplatGrad<f32>>],
                ) -> GaussianCloud<F> {
                    let mut out = cloud.zeros_like();
                    let stride = cloud.color_stride();
                    let c = |v: f32| F::c(v as f64);
                    for (g, total) in totals.iter().enumerate() {
                        let Some(t) = total else { continue };
                        let t = SplatGrad {
                            xy: t.xy.map(c),
                            conic: t.conic.map(c),
                            opacity: c(t.opacity),
                            color: t.color.map(c),
                            depth: c(t.depth),
                        };
                        project_backward(
                            cloud,
                            g,
                            cam,
                            low_pass,
                            &t,
                            &mut out.means[3 * g..3 * g + 3],
                            &mut out.log_scales[3 * g..3 * g + 3],
                            &mut out.rotations[4 * g..4 * g + 4],
                            &mut out.colors[stride * g..stride * (g + 1)],
                            &mut out.opacity_logits[g],
                        );
                    }
                    out
                }
                let scalar = scalar_adjoint(&cloud, &cam, low_pass, &totals);
                let exact = scalar_adjoint(
                    &cloud.cast::<f64>(),
                    &CameraTerms::<f64>::new(&camera),
                    low_pass,
                    &totals,
                );
                let case = format!("{name}, {model:?}, {low_pass:?}");
                let live = totals.iter().filter(|t| t.is_some()).count();
                assert!(live > 1000, "{case}");
                let groups = [
                    ("mean", &lanes.means, &scalar.means, &exact.means, 3),
                    (
                        "log scale",
                        &lanes.log_scales,
                        &scalar.log_scales,
                        &exact.log_scales,
                        3,
                    ),
                    (
                        "rotation",
                        &lanes.rotations,
                        &scalar.rotations,
                        &exact.rotations,
                        4,
                    ),
                    (
                        "colour",
                        &lanes.colors,
                        &scalar.colors,
                        &exact.colors,
                        stride,
                    ),
                    (
                        "opacity",
                        &lanes.opacity_logits,
                        &scalar.opacity_logits,
                        &exact.opacity_logits,
                        1,
                    ),
                ];
                for (group, got, f32_scalar, exact, width) in groups {
                    for (g, total) in totals.iter().enumerate() {
                        let span = width * g..width * (g + 1);
                        let (got, f32_scalar, exact) =
                            (&got[span.clone()], &f32_scalar[span.clone()], &exact[span]);
                        if total.is_none() {
                            assert!(got.iter().all(|&v| v == 0.0), "{case}: culled {g}");
                            continue;
                        }
                        let scale = exact.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                        let floor = if matches!(g % 10, 2 | 3) { 1e-2 } else { 1e-4 };
                        for ((&a, &b), &e) in got.iter().zip(f32_scalar).zip(exact) {
                            let (lane_err, scalar_err) =
                                ((a as f64 - e).abs(), (b as f64 - e).abs());
                            assert!(
                                lane_err <= 4.0 * scalar_err + floor * scale,
                                "{case}: Gaussian {g}'s {group}: lanes {a}, scalar {b}, f64 {e}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn portable_lanes_match_the_scalar_projection_and_adjoint() {
        check::<crate::lanes::Portable>((), "portable");
        check_adjoint::<crate::lanes::Portable>((), "portable");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sse2_lanes_match_the_scalar_projection_and_adjoint() {
        check::<crate::lanes::Sse2>((), "sse2");
        check_adjoint::<crate::lanes::Sse2>((), "sse2");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_lanes_match_the_scalar_projection_and_adjoint() {
        let Some(token) = crate::lanes::Avx2Token::detect() else {
            eprintln!("note: this CPU has no AVX2 + FMA; the 8-lane check is skipped");
            return;
        };
        check::<crate::lanes::Avx2>(token, "avx2");
        check_adjoint::<crate::lanes::Avx2>(token, "avx2");
    }
}
