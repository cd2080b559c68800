//! Projecting one 3D Gaussian to a 2D splat (EWA splatting), and the exact adjoint of it.
//!
//! Forward, for a Gaussian with mean `p`, scales `s = exp(log_scale)`, unit quaternion `q`:
//! camera-space mean `t = W (p - c)`; covariance `Sigma = R S S^T R^T`; perspective Jacobian `J`
//! at `t` with the 3DGS guard band (`t.x / t.z` clamped to 1.3 x the half field of view, so
//! Gaussians far off screen do not blow up); `Sigma2 = J W Sigma W^T J^T + k I` with the low-pass
//! `k` (0.3 px^2, or 0.1 px^2 with the mip-splatting opacity compensation
//! `sqrt(det(Sigma2) / det(Sigma2 + k I))`); the conic is `Sigma2^-1`. A splat is culled when it
//! is behind the near plane, degenerate, non-finite, too faint ever to reach alpha 1/255, or off
//! screen; its screen extent is the exact bounding box of the ellipse where alpha >= 1/255
//! (opacity-aware), so tiles see every pixel a brute-force compositor would.

use crate::camera::Camera;
use crate::cloud::{ColorModel, GaussianCloud};
use crate::real::*;
use crate::sh;

/// Contributions below this alpha are skipped.
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// Alpha is capped here, so no splat is fully opaque.
pub const ALPHA_MAX: f64 = 0.99;
/// Compositing stops before a splat that would take transmittance below this.
pub const T_MIN: f64 = 1e-4;
/// Guard band of the Jacobian, in units of the half field of view.
const GUARD_BAND: f64 = 1.3;

/// The 2D low-pass filter added to every projected covariance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LowPass {
    /// 3DGS: add 0.3 px^2.
    #[default]
    Classic,
    /// Mip-splatting style: add 0.1 px^2 and scale opacity by the determinant ratio.
    Mip,
}

impl LowPass {
    pub(crate) fn variance(self) -> f64 {
        match self {
            LowPass::Classic => 0.3,
            LowPass::Mip => 0.1,
        }
    }
}

/// A Gaussian projected to the image.
#[derive(Debug, Clone, Copy, Default)]
pub struct Splat<F: Real> {
    /// Centre in continuous pixel coordinates (pixel (x, y) has its centre at (x + 0.5, y + 0.5)).
    pub xy: [F; 2],
    /// Inverse 2D covariance: (a, b, c) for [[a, b], [b, c]].
    pub conic: [F; 3],
    /// Opacity after the sigmoid (and the mip compensation).
    pub opacity: F,
    pub color: [F; 3],
    /// Camera-space depth of the mean.
    pub depth: F,
    /// `-ln(255 opacity)`: below this exponent alpha is under 1/255, so `exp` need not run.
    pub power_min: F,
    /// Inclusive pixel bounds: x0, y0, x1, y1.
    pub rect: [u32; 4],
}

/// Per-frame camera quantities in the kernel's float type.
#[derive(Debug, Clone, Copy)]
pub struct CameraTerms<F: Real> {
    pub w: M3<F>,
    pub position: V3<F>,
    pub focal: F,
    pub cx: F,
    pub cy: F,
    pub lim_x: F,
    pub lim_y: F,
    pub width: u32,
    pub height: u32,
}

impl<F: Real> CameraTerms<F> {
    pub fn new(cam: &Camera) -> Self {
        let (r, d, f) = cam.axes();
        let row = |v: glam::Vec3| [F::c(v.x as f64), F::c(v.y as f64), F::c(v.z as f64)];
        let focal = cam.focal_pixels() as f64;
        let tan_y = 0.5 * cam.height as f64 / focal;
        let tan_x = 0.5 * cam.width as f64 / focal;
        Self {
            w: [row(r), row(d), row(f)],
            position: row(cam.position),
            focal: F::c(focal),
            cx: F::c(0.5 * cam.width as f64),
            cy: F::c(0.5 * cam.height as f64),
            lim_x: F::c(GUARD_BAND * tan_x),
            lim_y: F::c(GUARD_BAND * tan_y),
            width: cam.width,
            height: cam.height,
        }
    }
}

/// Colour of Gaussian `g` seen from `cam_pos`, before the clamp at 0.
#[inline]
pub(crate) fn raw_color<F: Real>(
    cloud: &GaussianCloud<F>,
    g: usize,
    mean: V3<F>,
    cam_pos: V3<F>,
    basis: &mut [F; 16],
) -> [F; 3] {
    let stride = cloud.color_stride();
    let c = &cloud.colors[g * stride..(g + 1) * stride];
    match cloud.color_model {
        ColorModel::Rgb => [c[0], c[1], c[2]],
        ColorModel::Sh(deg) => {
            let d = sub3(mean, cam_pos);
            let inv = F::one() / dot3(d, d).sqrt();
            sh::basis(deg, [d[0] * inv, d[1] * inv, d[2] * inv], basis, None);
            let mut out = [F::c(0.5); 3];
            for (k, &y) in basis.iter().enumerate().take(sh::coeffs_for_degree(deg)) {
                for ch in 0..3 {
                    out[ch] = out[ch] + y * c[3 * k + ch];
                }
            }
            out
        }
    }
}

/// The 3D-to-2D geometry of one Gaussian that the forward pass and its adjoint share.
struct Geometry<F: Real> {
    p: V3<F>,
    /// Camera-space mean.
    t: V3<F>,
    /// Norm of the stored quaternion and the unit quaternion.
    qn: F,
    qh: [F; 4],
    /// Standard deviations, rotation, and `M = R S` (so `Sigma = M M^T`).
    s: V3<F>,
    r: M3<F>,
    m: M3<F>,
    /// Camera-space x and y after the guard-band clamp, and whether the clamp acted.
    txc: F,
    tyc: F,
    x_clamped: bool,
    y_clamped: bool,
    /// `T = J W` (2x3) and `T Sigma` (rows).
    tm: [V3<F>; 2],
    ts: [V3<F>; 2],
    /// The projected covariance before the low-pass: [[a0, b0], [b0, c0]].
    a0: F,
    b0: F,
    c0: F,
}

#[inline]
fn geometry<F: Real>(cloud: &GaussianCloud<F>, g: usize, cam: &CameraTerms<F>) -> Geometry<F> {
    let zero = F::zero();
    let p = [
        cloud.means[3 * g],
        cloud.means[3 * g + 1],
        cloud.means[3 * g + 2],
    ];
    let q = [
        cloud.rotations[4 * g],
        cloud.rotations[4 * g + 1],
        cloud.rotations[4 * g + 2],
        cloud.rotations[4 * g + 3],
    ];
    let ls = [
        cloud.log_scales[3 * g],
        cloud.log_scales[3 * g + 1],
        cloud.log_scales[3 * g + 2],
    ];
    let t = mat_vec(&cam.w, sub3(p, cam.position));
    let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let qh = [q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn];
    let s = [ls[0].exp(), ls[1].exp(), ls[2].exp()];
    let r = quat_to_mat(qh);
    let m = [
        [r[0][0] * s[0], r[0][1] * s[1], r[0][2] * s[2]],
        [r[1][0] * s[0], r[1][1] * s[1], r[1][2] * s[2]],
        [r[2][0] * s[0], r[2][1] * s[1], r[2][2] * s[2]],
    ];
    let sigma = mat_mul(&m, &transpose(&m));
    let (tx, ty, tz) = (t[0], t[1], t[2]);
    let x_clamped = !((tx / tz) >= -cam.lim_x && (tx / tz) <= cam.lim_x);
    let y_clamped = !((ty / tz) >= -cam.lim_y && (ty / tz) <= cam.lim_y);
    let txc = (tx / tz).max(-cam.lim_x).min(cam.lim_x) * tz;
    let tyc = (ty / tz).max(-cam.lim_y).min(cam.lim_y) * tz;
    let f = cam.focal;
    let j = [
        [f / tz, zero, -f * txc / (tz * tz)],
        [zero, f / tz, -f * tyc / (tz * tz)],
    ];
    let tm = [
        [
            j[0][0] * cam.w[0][0] + j[0][2] * cam.w[2][0],
            j[0][0] * cam.w[0][1] + j[0][2] * cam.w[2][1],
            j[0][0] * cam.w[0][2] + j[0][2] * cam.w[2][2],
        ],
        [
            j[1][1] * cam.w[1][0] + j[1][2] * cam.w[2][0],
            j[1][1] * cam.w[1][1] + j[1][2] * cam.w[2][1],
            j[1][1] * cam.w[1][2] + j[1][2] * cam.w[2][2],
        ],
    ];
    // Sigma is symmetric, so Sigma^T T_i = Sigma T_i.
    let ts = [mat_t_vec(&sigma, tm[0]), mat_t_vec(&sigma, tm[1])];
    Geometry {
        p,
        t,
        qn,
        qh,
        s,
        r,
        m,
        txc,
        tyc,
        x_clamped,
        y_clamped,
        a0: dot3(tm[0], ts[0]),
        b0: dot3(tm[0], ts[1]),
        c0: dot3(tm[1], ts[1]),
        tm,
        ts,
    }
}

/// Projects Gaussian `g`; None when it is culled.
#[inline]
pub fn project<F: Real>(
    cloud: &GaussianCloud<F>,
    g: usize,
    cam: &CameraTerms<F>,
    low_pass: LowPass,
    near: F,
) -> Option<Splat<F>> {
    let geo = geometry(cloud, g, cam);
    let (p, t, qn) = (geo.p, geo.t, geo.qn);
    // Written so that NaN fails.
    if !(t[2] > near) || !t[0].is_finite() || !t[1].is_finite() {
        return None;
    }
    if !(qn > F::zero()) || !qn.is_finite() {
        return None;
    }
    let (tx, ty, tz) = (t[0], t[1], t[2]);
    let f = cam.focal;
    let (a0, b0, c0) = (geo.a0, geo.b0, geo.c0);
    let k = F::c(low_pass.variance());
    let (a, c) = (a0 + k, c0 + k);
    let det = a * c - b0 * b0;
    if !(det > F::zero()) || !det.is_finite() || !a.is_finite() || !c.is_finite() {
        return None;
    }
    let mut opacity = sigmoid(cloud.opacity_logits[g]);
    if low_pass == LowPass::Mip {
        let det0 = a0 * c0 - b0 * b0;
        opacity = opacity * (det0 / det).max(F::zero()).sqrt();
    }
    if !(opacity >= F::c(ALPHA_MIN)) {
        return None;
    }
    let u = f * tx / tz + cam.cx;
    let v = f * ty / tz + cam.cy;
    // alpha >= 1/255 inside the ellipse d^T conic d <= 2 ln(255 opacity); its bounding box.
    let k2 = F::c(2.0) * (F::c(255.0) * opacity).ln();
    // A hair wider than exact, so rounding can never cut a pixel whose alpha reaches 1/255.
    let ex = (k2 * a).sqrt() * F::c(1.0 + 1e-5) + F::c(1e-3);
    let ey = (k2 * c).sqrt() * F::c(1.0 + 1e-5) + F::c(1e-3);
    let half = F::c(0.5);
    let x0 = (u - ex - half).ceil().max(F::zero());
    let x1 = (u + ex - half).floor().min(F::c(cam.width as f64 - 1.0));
    let y0 = (v - ey - half).ceil().max(F::zero());
    let y1 = (v + ey - half).floor().min(F::c(cam.height as f64 - 1.0));
    if !(x0 <= x1 && y0 <= y1) {
        return None;
    }
    let mut basis = [F::zero(); 16];
    let rc = raw_color(cloud, g, p, cam.position, &mut basis);
    let color = [
        rc[0].max(F::zero()),
        rc[1].max(F::zero()),
        rc[2].max(F::zero()),
    ];
    if !(color[0].is_finite() && color[1].is_finite() && color[2].is_finite()) {
        return None;
    }
    let to_u = |x: F| x.as_f64() as u32;
    Some(Splat {
        xy: [u, v],
        conic: [c / det, -b0 / det, a / det],
        opacity,
        color,
        depth: tz,
        power_min: -(F::c(255.0) * opacity).ln(),
        rect: [to_u(x0), to_u(y0), to_u(x1), to_u(y1)],
    })
}

/// Back-propagates a splat's 2D gradients to Gaussian `g`'s parameters, adding into `grads`
/// (a cloud-shaped buffer whose slices for `g` are given). The chain, step by step: the
/// opacity, the screen covariance ([`screen_covariance_backward`]), the projection to the
/// camera-space mean ([`projection_backward`]), the mean, the scales and rotation
/// ([`scale_rotation_backward`]), the quaternion, the colour.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn project_backward<F: Real>(
    cloud: &GaussianCloud<F>,
    g: usize,
    cam: &CameraTerms<F>,
    low_pass: LowPass,
    dg: &SplatGrad<F>,
    d_mean: &mut [F],
    d_log_scale: &mut [F],
    d_rotation: &mut [F],
    d_color: &mut [F],
    d_opacity_logit: &mut F,
) {
    let zero = F::zero();
    let geo = geometry(cloud, g, cam);
    let (a0, b0, c0) = (geo.a0, geo.b0, geo.c0);
    let k = F::c(low_pass.variance());
    let (a, c) = (a0 + k, c0 + k);
    let det = a * c - b0 * b0;

    // Opacity: alpha0 = sigmoid(l) * comp.
    let sg = sigmoid(cloud.opacity_logits[g]);
    let det0 = a0 * c0 - b0 * b0;
    let comp = if low_pass == LowPass::Mip {
        (det0 / det).max(zero).sqrt()
    } else {
        F::one()
    };
    *d_opacity_logit = *d_opacity_logit + dg.opacity * comp * sg * (F::one() - sg);

    let g2 = screen_covariance_backward(&geo, k, low_pass, dg, sg, comp);
    let (d_sigma, d_tcam) = projection_backward(&geo, cam, &g2, dg);
    let dp = mat_t_vec(&cam.w, d_tcam);
    for i in 0..3 {
        d_mean[i] = d_mean[i] + dp[i];
    }
    let (d_r, ds) = scale_rotation_backward(&geo, &d_sigma);
    for jx in 0..3 {
        d_log_scale[jx] = d_log_scale[jx] + ds[jx];
    }
    let (qh, qn) = (geo.qh, geo.qn);
    let dqh = quat_to_mat_backward(qh, &d_r);
    let proj = dqh[0] * qh[0] + dqh[1] * qh[1] + dqh[2] * qh[2] + dqh[3] * qh[3];
    for i in 0..4 {
        d_rotation[i] = d_rotation[i] + (dqh[i] - qh[i] * proj) / qn;
    }

    color_backward(cloud, g, cam, dg.color, d_mean, d_color);
}

/// dL/dSigma2, the gradient of the screen covariance before the low-pass filter (variance
/// `k` added): through the conic K = (Sigma2 + k)^-1, and with Mip through the opacity's
/// compensation `comp` (`sg`: the opacity logit's sigmoid).
#[inline]
fn screen_covariance_backward<F: Real>(
    geo: &Geometry<F>,
    k: F,
    low_pass: LowPass,
    dg: &SplatGrad<F>,
    sg: F,
    comp: F,
) -> [[F; 2]; 2] {
    let (zero, two) = (F::zero(), F::c(2.0));
    let (a0, b0, c0) = (geo.a0, geo.b0, geo.c0);
    let (a, c) = (a0 + k, c0 + k);
    let det = a * c - b0 * b0;
    let det0 = a0 * c0 - b0 * b0;
    // Conic K = Sigma2^-1: dL/dSigma2 = -K G K with G the symmetric gradient (b split in two).
    let kk = [[c / det, -b0 / det], [-b0 / det, a / det]];
    let gk = [
        [dg.conic[0], dg.conic[1] / two],
        [dg.conic[1] / two, dg.conic[2]],
    ];
    let mut g2 = [[zero; 2]; 2];
    for i in 0..2 {
        for jx in 0..2 {
            let mut acc = zero;
            for a_ in 0..2 {
                for b_ in 0..2 {
                    acc = acc + kk[i][a_] * gk[a_][b_] * kk[b_][jx];
                }
            }
            g2[i][jx] = -acc;
        }
    }
    if low_pass == LowPass::Mip && det0 > zero {
        // comp = sqrt(det0 / det1): d comp / d Sigma2_raw entries (b0 split over both off-diagonals).
        let dcomp = dg.opacity * sg;
        let half = F::c(0.5) * comp;
        g2[0][0] = g2[0][0] + dcomp * half * (c0 / det0 - c / det);
        g2[1][1] = g2[1][1] + dcomp * half * (a0 / det0 - a / det);
        let off = dcomp * half * (-b0 / det0 + b0 / det);
        g2[0][1] = g2[0][1] + off;
        g2[1][0] = g2[1][0] + off;
    }
    g2
}

/// Through Sigma2 = T Sigma T^T and T = J W (J: the perspective Jacobian at the camera-space
/// mean, clamped to the guard band): dL/dSigma, and dL/d(camera-space mean) with the screen
/// position's and depth's gradients added.
#[inline]
fn projection_backward<F: Real>(
    geo: &Geometry<F>,
    cam: &CameraTerms<F>,
    g2: &[[F; 2]; 2],
    dg: &SplatGrad<F>,
) -> (M3<F>, V3<F>) {
    let (zero, two) = (F::zero(), F::c(2.0));
    let (tm, ts) = (&geo.tm, &geo.ts);
    let (tx, ty, tz) = (geo.t[0], geo.t[1], geo.t[2]);
    let f = cam.focal;
    // dL/dSigma = T^T G2 T, dL/dT = 2 G2 T Sigma.
    let mut d_sigma = [[zero; 3]; 3];
    for i in 0..3 {
        for jx in 0..3 {
            let mut acc = zero;
            for a_ in 0..2 {
                for b_ in 0..2 {
                    acc = acc + tm[a_][i] * g2[a_][b_] * tm[b_][jx];
                }
            }
            d_sigma[i][jx] = acc;
        }
    }
    let mut d_t = [[zero; 3]; 2];
    for a_ in 0..2 {
        for i in 0..3 {
            d_t[a_][i] = two * (g2[a_][0] * ts[0][i] + g2[a_][1] * ts[1][i]);
        }
    }
    // T = J W: dL/dJ = dL/dT W^T (only the non-zero entries of J matter).
    let d_j00 = dot3(d_t[0], cam.w[0]);
    let d_j02 = dot3(d_t[0], cam.w[2]);
    let d_j11 = dot3(d_t[1], cam.w[1]);
    let d_j12 = dot3(d_t[1], cam.w[2]);
    let tz2 = tz * tz;
    let tz3 = tz2 * tz;
    let mut d_tcam = [zero; 3];
    d_tcam[2] = d_tcam[2] - (d_j00 + d_j11) * f / tz2;
    if geo.x_clamped {
        d_tcam[2] = d_tcam[2] + d_j02 * f * geo.txc / tz3;
    } else {
        d_tcam[0] = d_tcam[0] - d_j02 * f / tz2;
        d_tcam[2] = d_tcam[2] + d_j02 * two * f * tx / tz3;
    }
    if geo.y_clamped {
        d_tcam[2] = d_tcam[2] + d_j12 * f * geo.tyc / tz3;
    } else {
        d_tcam[1] = d_tcam[1] - d_j12 * f / tz2;
        d_tcam[2] = d_tcam[2] + d_j12 * two * f * ty / tz3;
    }
    // Screen position and depth.
    d_tcam[0] = d_tcam[0] + dg.xy[0] * f / tz;
    d_tcam[1] = d_tcam[1] + dg.xy[1] * f / tz;
    d_tcam[2] = d_tcam[2] - (dg.xy[0] * f * tx + dg.xy[1] * f * ty) / tz2 + dg.depth;
    (d_sigma, d_tcam)
}

/// Through Sigma = M M^T, M = R S: dL/dR, and dL/d(log s) (what the scales' gradient adds).
#[inline]
fn scale_rotation_backward<F: Real>(geo: &Geometry<F>, d_sigma: &M3<F>) -> (M3<F>, V3<F>) {
    let (zero, two) = (F::zero(), F::c(2.0));
    let (m, r, s) = (&geo.m, &geo.r, &geo.s);
    // dL/dM = 2 dL/dSigma M.
    let d_m = {
        let mut out = [[zero; 3]; 3];
        for i in 0..3 {
            for jx in 0..3 {
                out[i][jx] = two
                    * (d_sigma[i][0] * m[0][jx]
                        + d_sigma[i][1] * m[1][jx]
                        + d_sigma[i][2] * m[2][jx]);
            }
        }
        out
    };
    let mut d_r = [[zero; 3]; 3];
    let mut d_log_scale = [zero; 3];
    for jx in 0..3 {
        let mut ds = zero;
        for i in 0..3 {
            ds = ds + d_m[i][jx] * r[i][jx];
            d_r[i][jx] = d_m[i][jx] * s[jx];
        }
        d_log_scale[jx] = ds * s[jx];
    }
    (d_r, d_log_scale)
}

/// The colour part of [`project_backward`]: through the clamp at 0, and for SH through the
/// view direction into the mean (added into `d_mean`). The lanes' adjoint
/// (`project_lanes.rs`) calls it per Gaussian, so both share one colour code.
#[inline]
pub(crate) fn color_backward<F: Real>(
    cloud: &GaussianCloud<F>,
    g: usize,
    cam: &CameraTerms<F>,
    dg_color: [F; 3],
    d_mean: &mut [F],
    d_color: &mut [F],
) {
    let zero = F::zero();
    let p = [
        cloud.means[3 * g],
        cloud.means[3 * g + 1],
        cloud.means[3 * g + 2],
    ];
    let mut basis = [zero; 16];
    let rc = raw_color(cloud, g, p, cam.position, &mut basis);
    let dc = [0, 1, 2].map(|ch| if rc[ch] > zero { dg_color[ch] } else { zero });
    match cloud.color_model {
        ColorModel::Rgb => {
            for ch in 0..3 {
                d_color[ch] = d_color[ch] + dc[ch];
            }
        }
        ColorModel::Sh(deg) => {
            let n = sh::coeffs_for_degree(deg);
            let d = sub3(p, cam.position);
            let len = dot3(d, d).sqrt();
            let dir = [d[0] / len, d[1] / len, d[2] / len];
            let mut grad = [[zero; 3]; 16];
            sh::basis(deg, dir, &mut basis, Some(&mut grad));
            let coef = &cloud.colors[g * 3 * n..(g + 1) * 3 * n];
            let mut d_dir = [zero; 3];
            for kx in 0..n {
                for ch in 0..3 {
                    d_color[3 * kx + ch] = d_color[3 * kx + ch] + dc[ch] * basis[kx];
                    let w = dc[ch] * coef[3 * kx + ch];
                    for ax in 0..3 {
                        d_dir[ax] = d_dir[ax] + w * grad[kx][ax];
                    }
                }
            }
            let along = dot3(d_dir, dir);
            for ax in 0..3 {
                d_mean[ax] = d_mean[ax] + (d_dir[ax] - dir[ax] * along) / len;
            }
        }
    }
}
