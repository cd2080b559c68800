//! Real spherical harmonics up to degree 3 in the 3DGS convention: colour is
//! `0.5 + sum_k coef_k * Y_k(d)` for the unit view direction `d` (camera to Gaussian), with the
//! basis ordered by degree and the same signs as the reference 3DGS implementation, so trained
//! 3DGS assets render with their intended colours. The gradient of the basis with respect to `d`
//! is written out too: it carries colour gradients into the means.

use crate::real::Real;

/// Number of coefficients per channel for a degree.
pub const fn coeffs_for_degree(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

const C0: f64 = 0.282_094_791_773_878_14;
const C1: f64 = 0.488_602_511_902_919_9;
const C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
const C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// The basis values at direction `d` (unit), and optionally their gradients with respect to `d`.
pub fn basis<F: Real>(degree: u32, d: [F; 3], out: &mut [F], grad: Option<&mut [[F; 3]]>) {
    let c = F::c;
    let [x, y, z] = d;
    let z0 = F::zero();
    let mut g_local = [[z0; 3]; 16];
    let g = &mut g_local;
    out[0] = c(C0);
    if degree >= 1 {
        out[1] = -c(C1) * y;
        out[2] = c(C1) * z;
        out[3] = -c(C1) * x;
        g[1] = [z0, -c(C1), z0];
        g[2] = [z0, z0, c(C1)];
        g[3] = [-c(C1), z0, z0];
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        out[4] = c(C2[0]) * x * y;
        out[5] = c(C2[1]) * y * z;
        out[6] = c(C2[2]) * (c(2.0) * zz - xx - yy);
        out[7] = c(C2[3]) * x * z;
        out[8] = c(C2[4]) * (xx - yy);
        g[4] = [c(C2[0]) * y, c(C2[0]) * x, z0];
        g[5] = [z0, c(C2[1]) * z, c(C2[1]) * y];
        g[6] = [-c(2.0 * C2[2]) * x, -c(2.0 * C2[2]) * y, c(4.0 * C2[2]) * z];
        g[7] = [c(C2[3]) * z, z0, c(C2[3]) * x];
        g[8] = [c(2.0 * C2[4]) * x, -c(2.0 * C2[4]) * y, z0];
        if degree >= 3 {
            out[9] = c(C3[0]) * y * (c(3.0) * xx - yy);
            out[10] = c(C3[1]) * x * y * z;
            out[11] = c(C3[2]) * y * (c(4.0) * zz - xx - yy);
            out[12] = c(C3[3]) * z * (c(2.0) * zz - c(3.0) * xx - c(3.0) * yy);
            out[13] = c(C3[4]) * x * (c(4.0) * zz - xx - yy);
            out[14] = c(C3[5]) * z * (xx - yy);
            out[15] = c(C3[6]) * x * (xx - c(3.0) * yy);
            g[9] = [
                c(6.0 * C3[0]) * x * y,
                c(C3[0]) * (c(3.0) * xx - c(3.0) * yy),
                z0,
            ];
            g[10] = [c(C3[1]) * y * z, c(C3[1]) * x * z, c(C3[1]) * x * y];
            g[11] = [
                -c(2.0 * C3[2]) * x * y,
                c(C3[2]) * (c(4.0) * zz - xx - c(3.0) * yy),
                c(8.0 * C3[2]) * y * z,
            ];
            g[12] = [
                -c(6.0 * C3[3]) * x * z,
                -c(6.0 * C3[3]) * y * z,
                c(C3[3]) * (c(6.0) * zz - c(3.0) * xx - c(3.0) * yy),
            ];
            g[13] = [
                c(C3[4]) * (c(4.0) * zz - c(3.0) * xx - yy),
                -c(2.0 * C3[4]) * x * y,
                c(8.0 * C3[4]) * x * z,
            ];
            g[14] = [
                c(2.0 * C3[5]) * x * z,
                -c(2.0 * C3[5]) * y * z,
                c(C3[5]) * (xx - yy),
            ];
            g[15] = [
                c(C3[6]) * (c(3.0) * xx - c(3.0) * yy),
                -c(6.0 * C3[6]) * x * y,
                z0,
            ];
        }
    }
    if let Some(grad) = grad {
        let n = coeffs_for_degree(degree);
        grad[..n].copy_from_slice(&g[..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_gradients_match_finite_differences() {
        let d = [0.3f64, -0.5, 0.81];
        let mut v = [0.0; 16];
        let mut g = [[0.0; 3]; 16];
        basis(3, d, &mut v, Some(&mut g));
        for a in 0..3 {
            let h = 1e-6;
            let (mut p, mut m) = (d, d);
            p[a] += h;
            m[a] -= h;
            let (mut vp, mut vm) = ([0.0; 16], [0.0; 16]);
            basis(3, p, &mut vp, None);
            basis(3, m, &mut vm, None);
            for k in 0..16 {
                let fd = (vp[k] - vm[k]) / (2.0 * h);
                assert!(
                    (fd - g[k][a]).abs() < 1e-8,
                    "k={k} a={a}: {fd} vs {}",
                    g[k][a]
                );
            }
        }
    }

    #[test]
    fn basis_is_orthonormal_on_the_sphere() {
        // Monte Carlo-free check: a fine quadrature of Y_i Y_j over the sphere gives the identity.
        let n = 400;
        let mut gram = [[0.0f64; 16]; 16];
        for i in 0..n {
            let z = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
            for j in 0..2 * n {
                let phi = (j as f64 + 0.5) * std::f64::consts::PI / n as f64;
                let r = (1.0 - z * z).sqrt();
                let mut v = [0.0; 16];
                basis(3, [r * phi.cos(), r * phi.sin(), z], &mut v, None);
                let w = 4.0 * std::f64::consts::PI / (2 * n * n) as f64;
                for a in 0..16 {
                    for b in 0..16 {
                        gram[a][b] += w * v[a] * v[b];
                    }
                }
            }
        }
        for a in 0..16 {
            for b in 0..16 {
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((gram[a][b] - want).abs() < 1e-3, "{a},{b}: {}", gram[a][b]);
            }
        }
    }
}
