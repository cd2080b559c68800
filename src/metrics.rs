//! Image error metrics against a reference, in f64.
//!
//! - relMSE: `mean over pixels and channels of (x - r)^2 / (r^2 + eps)` with `eps = 0.01`,
//!   after dropping the largest 0.1% of per-pixel values (fireflies would otherwise decide it).
//! - SMAPE: `mean over pixels and channels of |x - r| / (|x| + |r| + eps)` with `eps = 0.01`:
//!   bounded by 1, so no single pixel decides it.
//! - PSNR: `10 log10(peak^2 / MSE)` with the peak stated by the caller (for HDR images, the
//!   reference's 99.9th percentile channel value is a fair choice; see [`hdr_peak`]).

use glam::Vec3;

/// The epsilon of relMSE's denominator.
pub const REL_MSE_EPSILON: f64 = 0.01;
/// Fraction of the largest per-pixel relMSE values dropped.
pub const REL_MSE_TRIM: f64 = 0.001;

/// Per-pixel relative squared error, averaged over the three channels.
pub fn rel_mse_map(image: &[Vec3], reference: &[Vec3]) -> Vec<f64> {
    assert_eq!(image.len(), reference.len(), "images differ in size");
    image
        .iter()
        .zip(reference)
        .map(|(x, r)| {
            let (x, r) = (x.as_dvec3(), r.as_dvec3());
            let e = (x - r) * (x - r) / (r * r + glam::DVec3::splat(REL_MSE_EPSILON));
            (e.x + e.y + e.z) / 3.0
        })
        .collect()
}

/// relMSE with the top [`REL_MSE_TRIM`] of pixels dropped.
pub fn rel_mse(image: &[Vec3], reference: &[Vec3]) -> f64 {
    let mut m = rel_mse_map(image, reference);
    if m.is_empty() {
        return 0.0;
    }
    let keep = m.len() - ((m.len() as f64 * REL_MSE_TRIM).floor() as usize);
    m.sort_by(|a, b| a.total_cmp(b));
    m[..keep].iter().sum::<f64>() / keep.max(1) as f64
}

/// The epsilon of SMAPE's denominator.
pub const SMAPE_EPSILON: f64 = 0.01;

/// Symmetric mean absolute percentage error (see the module docs).
pub fn smape(image: &[Vec3], reference: &[Vec3]) -> f64 {
    assert_eq!(image.len(), reference.len(), "images differ in size");
    let sum: f64 = image
        .iter()
        .zip(reference)
        .map(|(x, r)| {
            let (x, r) = (x.as_dvec3(), r.as_dvec3());
            let e = (x - r).abs() / (x.abs() + r.abs() + glam::DVec3::splat(SMAPE_EPSILON));
            e.x + e.y + e.z
        })
        .sum();
    sum / (3 * image.len()).max(1) as f64
}

/// Mean squared error over pixels and channels.
pub fn mse(image: &[Vec3], reference: &[Vec3]) -> f64 {
    assert_eq!(image.len(), reference.len(), "images differ in size");
    image
        .iter()
        .zip(reference)
        .map(|(x, r)| (x.as_dvec3() - r.as_dvec3()).length_squared() / 3.0)
        .sum::<f64>()
        / image.len().max(1) as f64
}

/// The 99.9th percentile of the reference's channel values: the PSNR peak for HDR images.
pub fn hdr_peak(reference: &[Vec3]) -> f64 {
    let mut v: Vec<f64> = reference
        .iter()
        .flat_map(|c| [c.x as f64, c.y as f64, c.z as f64])
        .collect();
    if v.is_empty() {
        return 1.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * 0.999).round() as usize].max(1e-12)
}

/// PSNR in dB for the given peak.
pub fn psnr(image: &[Vec3], reference: &[Vec3], peak: f64) -> f64 {
    10.0 * (peak * peak / mse(image, reference).max(1e-300)).log10()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smape_hand_computed() {
        let r = vec![Vec3::splat(1.0), Vec3::splat(0.0)];
        let x = vec![Vec3::splat(2.0), Vec3::splat(0.125)];
        // 1 / (2 + 1 + 0.01) and 0.125 / (0.125 + 0 + 0.01), averaged.
        let expected = 0.5 * (1.0 / 3.01 + 0.125 / 0.135);
        assert!((smape(&x, &r) - expected).abs() < 1e-12);
        assert_eq!(smape(&r, &r), 0.0);
    }

    #[test]
    fn hand_computed() {
        let r = vec![Vec3::splat(1.0), Vec3::splat(0.0)];
        // 0.125 is exact in f32, so the expected values are exact too.
        let x = vec![Vec3::splat(2.0), Vec3::splat(0.125)];
        // (1)^2/(1 + 0.01) and (0.125)^2/(0 + 0.01) = 1.5625.
        let m = rel_mse_map(&x, &r);
        assert!((m[0] - 1.0 / 1.01).abs() < 1e-12 && (m[1] - 1.5625).abs() < 1e-9);
        // MSE = (1 + 0.015625) / 2; PSNR with peak 1.
        assert!((mse(&x, &r) - 0.5078125).abs() < 1e-12);
        assert!((psnr(&x, &r, 1.0) - 10.0 * (1.0f64 / 0.5078125).log10()).abs() < 1e-9);
    }

    #[test]
    fn trimming_drops_the_top_tenth_of_a_percent() {
        let r = vec![Vec3::ONE; 2000];
        let mut x = r.clone();
        x[7] = Vec3::splat(1e6);
        x[9] = Vec3::splat(1e6);
        assert_eq!(rel_mse(&x, &r), 0.0);
        x[11] = Vec3::splat(2.0);
        assert!((rel_mse(&x, &r) - (1.0 / 1.01) / 1998.0).abs() < 1e-12);
    }
}
