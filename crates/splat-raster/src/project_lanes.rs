//! The forward projection of [`crate::project`], 8 or 4 Gaussians at a time in SIMD lanes (f32).
//!
//! Why: projected one at a time, a Gaussian costs about 70 ns a core (three `exp` for its
//! scales, one for its opacity, one `ln`, three square roots and a dozen divisions, none of
//! them in lanes): a quarter of a 300k-Gaussian frame at 2 threads (issue 31).
//!
//! The equations are `project::project`'s, term for term. The lanes' `exp` and `ln`
//! ([`crate::lanes`]) round differently from libm, within `EXP_MAX_REL_ERROR` and
//! `LN_MAX_ERROR`, so a splat can differ from the scalar projection's in its last bits; its
//! screen rectangle keeps the scalar one's margin (1e-5 relative and 1e-3 px), thousands of
//! times those bits, so it still holds every pixel whose alpha reaches 1/255. Culling runs in
//! the lanes as masks. Each surviving Gaussian's rectangle (floor and ceiling) and colour (RGB
//! or spherical harmonics) are then finished one at a time, as the scalar code does them.
//!
//! The lane count divides the chunks of `raster::project_and_bin` except for a tail of fewer
//! than N Gaussians, which the scalar projection takes; both depend on the cloud's size alone,
//! so the splats are the same on any number of threads.

use crate::cloud::GaussianCloud;
use crate::lanes::{self, Lanes};
use crate::project::{ALPHA_MIN, CameraTerms, LowPass, Splat, project, raw_color};
use std::ops::Range;

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
    // No lane value passes through a generic helper here (`array::map`, iterators): those are
    // compiled without the caller's AVX2, so a closure over lanes inside them would become a
    // call per element.
    let n = L::N;
    let s = |v: f32| L::splat(token, v);
    let zero = s(0.0);
    // Written so that NaN and infinities fail.
    let (lowest, highest) = (s(f32::MIN), s(f32::MAX));
    let finite = |x: L| x.ge(lowest) & x.le(highest);
    let cw = cam.w;
    let w = [
        [s(cw[0][0]), s(cw[0][1]), s(cw[0][2])],
        [s(cw[1][0]), s(cw[1][1]), s(cw[1][2])],
        [s(cw[2][0]), s(cw[2][1]), s(cw[2][2])],
    ];
    let position = [s(cam.position[0]), s(cam.position[1]), s(cam.position[2])];
    let focal = s(cam.focal);
    let variance = s(low_pass.variance() as f32);
    let (one, two) = (s(1.0), s(2.0));
    let dot = |a: &[L; 3], b: &[L; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut g0 = range.start;
    while g0 + n <= range.end {
        // One field's component `k` of Gaussians g0..g0 + N, as lanes.
        let field = |values: &[f32], stride: usize, k: usize| {
            let mut lane = [0.0f32; 16];
            for i in 0..n {
                lane[i] = values[(g0 + i) * stride + k];
            }
            L::load(token, &lane)
        };
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
        let logit = field(&cloud.opacity_logits, 1, 0);

        // Camera-space mean: t = W (p - c).
        let d = [p[0] - position[0], p[1] - position[1], p[2] - position[2]];
        let t = [dot(&w[0], &d), dot(&w[1], &d), dot(&w[2], &d)];
        // Sigma = M M^T with M = R(q / |q|) S.
        let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        let (qw, qx, qy, qz) = (q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn);
        let r = [
            [
                one - two * (qy * qy + qz * qz),
                two * (qx * qy - qw * qz),
                two * (qx * qz + qw * qy),
            ],
            [
                two * (qx * qy + qw * qz),
                one - two * (qx * qx + qz * qz),
                two * (qy * qz - qw * qx),
            ],
            [
                two * (qx * qz - qw * qy),
                two * (qy * qz + qw * qx),
                one - two * (qx * qx + qy * qy),
            ],
        ];
        let m = [
            [r[0][0] * scale[0], r[0][1] * scale[1], r[0][2] * scale[2]],
            [r[1][0] * scale[0], r[1][1] * scale[1], r[1][2] * scale[2]],
            [r[2][0] * scale[0], r[2][1] * scale[1], r[2][2] * scale[2]],
        ];
        let (s00, s01, s02) = (dot(&m[0], &m[0]), dot(&m[0], &m[1]), dot(&m[0], &m[2]));
        let (s11, s12, s22) = (dot(&m[1], &m[1]), dot(&m[1], &m[2]), dot(&m[2], &m[2]));
        // The perspective Jacobian at the guard-band-clamped mean, and T = J W.
        let (tx, ty, tz) = (t[0], t[1], t[2]);
        let (lim_x, lim_y) = (s(cam.lim_x), s(cam.lim_y));
        let txc = (tx / tz).max(zero - lim_x).min(lim_x) * tz;
        let tyc = (ty / tz).max(zero - lim_y).min(lim_y) * tz;
        let (j_diag, tz2) = (focal / tz, tz * tz);
        let (j02, j12) = (zero - focal * txc / tz2, zero - focal * tyc / tz2);
        let tm0 = [
            j_diag * w[0][0] + j02 * w[2][0],
            j_diag * w[0][1] + j02 * w[2][1],
            j_diag * w[0][2] + j02 * w[2][2],
        ];
        let tm1 = [
            j_diag * w[1][0] + j12 * w[2][0],
            j_diag * w[1][1] + j12 * w[2][1],
            j_diag * w[1][2] + j12 * w[2][2],
        ];
        // Sigma T_i, in the scalar code's order (Sigma^T T_i: Sigma is symmetric).
        let ts0 = [
            s00 * tm0[0] + s01 * tm0[1] + s02 * tm0[2],
            s01 * tm0[0] + s11 * tm0[1] + s12 * tm0[2],
            s02 * tm0[0] + s12 * tm0[1] + s22 * tm0[2],
        ];
        let ts1 = [
            s00 * tm1[0] + s01 * tm1[1] + s02 * tm1[2],
            s01 * tm1[0] + s11 * tm1[1] + s12 * tm1[2],
            s02 * tm1[0] + s12 * tm1[1] + s22 * tm1[2],
        ];
        let (a0, b0, c0) = (dot(&tm0, &ts0), dot(&tm0, &ts1), dot(&tm1, &ts1));
        let (a, c) = (a0 + variance, c0 + variance);
        let det = a * c - b0 * b0;
        // The sigmoid as the scalar code takes it: 1 / (1 + e^-x) for x >= 0, e^x / (1 + e^x)
        // below, both from e = e^-|x|.
        let positive = logit.ge(zero);
        let e = lanes::exp(token, L::select(positive, zero - logit, logit));
        let mut opacity = L::select(positive, one / (one + e), e / (one + e));
        if low_pass == LowPass::Mip {
            let det0 = a0 * c0 - b0 * b0;
            opacity = opacity * (det0 / det).max(zero).sqrt();
        }
        let alive = t[2].gt(s(near))
            & finite(tx)
            & finite(ty)
            & qn.gt(zero)
            & finite(qn)
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
    /// off screen and in the guard band, with zero and non-finite quaternions, tiny and huge
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
            // Anisotropic up to e^3; kind 3 nearly round but up to e^10 across (anisotropy of
            // e^14 would leave f32 nothing of the projected covariance to compare).
            let log_scale = if kind == 3 {
                let size = -4.0 + 14.0 * r(g, 4);
                [4, 5, 6].map(|k| size + 0.5 * r(g, k + 1))
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

    /// The lanes keep the same Gaussians as the scalar projection and make the same splats:
    /// the same rectangles and colours, and the same geometry within the lanes' `exp` and `ln`
    /// error (`EXP_MAX_REL_ERROR`, `LN_MAX_ERROR`) carried through a few roundings.
    fn check<L: Lanes>(token: L::Token, name: &str) {
        let camera = Camera::look_at(
            Vec3::new(0.3, -0.2, -4.0),
            Vec3::ZERO,
            Vec3::Y,
            50.0,
            320,
            180,
        )
        .unwrap();
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

    #[test]
    fn portable_projection_matches_the_scalar_one() {
        check::<crate::lanes::Portable>((), "portable");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sse2_projection_matches_the_scalar_one() {
        check::<crate::lanes::Sse2>((), "sse2");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_projection_matches_the_scalar_one() {
        let Some(token) = crate::lanes::Avx2Token::detect() else {
            eprintln!("note: this CPU has no AVX2 + FMA; the 8-lane check is skipped");
            return;
        };
        check::<crate::lanes::Avx2>(token, "avx2");
    }
}
