//! image-metrics: image error metrics against a reference, in f64 (the experiments' measures,
//! and the tests'). They are:
//!
//! - relMSE: `mean over pixels and channels of (x - r)^2 / (r^2 + eps)` with `eps = 0.01`,
//!   after dropping the largest 0.1% of per-pixel values (fireflies would otherwise decide it).
//! - SMAPE: `mean over pixels and channels of |x - r| / (|x| + |r| + eps)` with `eps = 0.01`:
//!   bounded by 1, so no single pixel decides it.
//! - PSNR: `10 log10(peak^2 / MSE)` with the peak stated by the caller (for HDR images, the
//!   reference's 99.9th percentile channel value is a fair choice; see [`hdr_peak`]). On
//!   tone-mapped 8-bit images the peak is 255 ([`psnr_8bit`]).
//! - Efficiency: `1 / (relMSE x seconds)`, so halving the error at equal time and halving the
//!   time at equal error count the same.
//! - Bias across seeds ([`SeedSpread`]): with `S` independent renders `x_s` of one pixel,
//!   `(mean - r)^2 - var / S` is an unbiased estimate of the squared bias (the variance of the
//!   mean is removed), reported relative like relMSE; and the image's mean brightness against the
//!   reference's, with its standard error over seeds.
//! - FLIP (feature `flip`, on by default): NVIDIA's perceptual difference of two tone-mapped
//!   images (LDR-FLIP, Andersson et al. 2020), mean over pixels, through the `nv-flip` bindings
//!   of its C++ reference code. Lower is better.
//! - SSIM ([`ssim`]): Wang et al. (2004)'s structural similarity of the tone-mapped images'
//!   luma, with their constants (11x11 Gaussian window, sigma 1.5, K1 = 0.01, K2 = 0.03,
//!   L = 255), averaged over the window positions inside the image. Higher is better; 1 is
//!   equal. relMSE and PSNR see every error alike; FLIP and SSIM see structure, which is where
//!   a cache's error (blur, bias in patches) and a denoiser's differ from noise.
//!
//! And two of motion, for frames of a moving view each with a reference of its own:
//!
//! - Flicker ([`flicker`]): relMSE of a frame's change from the frame before against the
//!   references' change, `(dx - dr)^2 / (r^2 + eps)` with `dx = x_t - x_{t-1}`, trimmed as relMSE.
//!   Independent noise counts twice (`Var(dx) = 2 Var(x)`); an error that stays put from frame
//!   to frame (a bias that moves with the data) counts not at all, so it tells steady from
//!   shimmering where relMSE cannot.
//! - ColorVideoVDP ([`video_jod`]): Mantiuk et al. (2024)'s perceptual video metric through the
//!   `colorvideovdp` crate (a port validated against the authors' PyTorch code), in JOD: 10 is
//!   no visible difference, one JOD less is what 75% of observers would pick against. It sees
//!   noise, blur and flicker at the frame rate the clip is shown.

#![forbid(unsafe_code)]

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
    trimmed_mean(rel_mse_map(image, reference))
}

/// Flicker: relMSE of the change from `previous` to `current` against the change from
/// `previous_reference` to `current_reference`, relative to the current reference (module docs).
pub fn flicker(
    previous: &[Vec3],
    current: &[Vec3],
    previous_reference: &[Vec3],
    current_reference: &[Vec3],
) -> f64 {
    let n = current.len();
    assert!(
        previous.len() == n && previous_reference.len() == n && current_reference.len() == n,
        "images differ in size"
    );
    // (x1 - x0) - (r1 - r0) = x1 - (x0 - r0 + r1): relMSE of x1 against that image, with r1's
    // weight.
    let map = (0..n)
        .map(|i| {
            let (x1, r1) = (current[i].as_dvec3(), current_reference[i].as_dvec3());
            let d = (x1 - previous[i].as_dvec3()) - (r1 - previous_reference[i].as_dvec3());
            let e = d * d / (r1 * r1 + glam::DVec3::splat(REL_MSE_EPSILON));
            (e.x + e.y + e.z) / 3.0
        })
        .collect();
    trimmed_mean(map)
}

/// The mean of `m` without its top [`REL_MSE_TRIM`].
fn trimmed_mean(mut m: Vec<f64>) -> f64 {
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

/// PSNR in dB of two 8-bit images (tone-mapped), peak 255.
pub fn psnr_8bit(image: &[u8], reference: &[u8]) -> f64 {
    assert_eq!(image.len(), reference.len(), "images differ in size");
    let sum: f64 = image
        .iter()
        .zip(reference)
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum();
    let mse = sum / image.len().max(1) as f64;
    10.0 * (255.0 * 255.0 / mse.max(1e-300)).log10()
}

/// `1 / (relMSE x seconds)`: higher is better.
pub fn efficiency(rel_mse: f64, seconds: f64) -> f64 {
    1.0 / (rel_mse * seconds).max(1e-300)
}

/// SSIM's window: 11 taps of a Gaussian with sigma 1.5, normalised.
fn ssim_window() -> [f64; 11] {
    let mut w = [0.0; 11];
    for (i, v) in w.iter_mut().enumerate() {
        let x = i as f64 - 5.0;
        *v = (-x * x / (2.0 * 1.5 * 1.5)).exp();
    }
    let sum: f64 = w.iter().sum();
    w.map(|v| v / sum)
}

/// Separable filtering of a `width x height` plane with `w`, keeping only the positions where
/// the window lies inside the image ("valid"): `(width - 10) x (height - 10)` values.
fn filter_valid(plane: &[f64], width: usize, height: usize, w: &[f64; 11]) -> Vec<f64> {
    let (ow, oh) = (width - 10, height - 10);
    let mut rows = vec![0.0; ow * height];
    for y in 0..height {
        for x in 0..ow {
            rows[y * ow + x] = (0..11).map(|k| w[k] * plane[y * width + x + k]).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|k| w[k] * rows[(y + k) * ow + x]).sum();
        }
    }
    out
}

/// Mean SSIM of two tone-mapped 8-bit sRGB images (`width x height x 3` bytes) on their luma
/// (Rec. 601 weights), as in the module docs; `None` for an image under 11 pixels a side.
pub fn ssim(image: &[u8], reference: &[u8], width: u32, height: u32) -> Option<f64> {
    let (w, h) = (width as usize, height as usize);
    assert_eq!(image.len(), w * h * 3, "image size");
    assert_eq!(reference.len(), w * h * 3, "reference size");
    if w < 11 || h < 11 {
        return None;
    }
    let luma = |px: &[u8]| -> Vec<f64> {
        px.chunks_exact(3)
            .map(|c| 0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64)
            .collect()
    };
    let (a, b) = (luma(image), luma(reference));
    let win = ssim_window();
    let blur = |p: &[f64]| filter_valid(p, w, h, &win);
    let product = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).collect::<Vec<_>>();
    let (mu_a, mu_b) = (blur(&a), blur(&b));
    let (aa, bb, ab) = (
        blur(&product(&a, &a)),
        blur(&product(&b, &b)),
        blur(&product(&a, &b)),
    );
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let n = mu_a.len();
    let sum: f64 = (0..n)
        .map(|i| {
            let (ma, mb) = (mu_a[i], mu_b[i]);
            let (va, vb, cov) = (aa[i] - ma * ma, bb[i] - mb * mb, ab[i] - ma * mb);
            ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
        })
        .sum();
    Some(sum / n as f64)
}

/// Mean FLIP error of two tone-mapped 8-bit sRGB images (`width x height x 3` bytes), at FLIP's
/// default viewing distance (67 pixels per degree). `None` without the `flip` feature.
pub fn flip(image: &[u8], reference: &[u8], width: u32, height: u32) -> Option<f64> {
    assert_eq!(image.len(), reference.len(), "images differ in size");
    #[cfg(feature = "flip")]
    {
        let r = nv_flip::FlipImageRgb8::with_data(width, height, reference);
        let t = nv_flip::FlipImageRgb8::with_data(width, height, image);
        let map = nv_flip::flip(r, t, nv_flip::DEFAULT_PIXELS_PER_DEGREE);
        Some(nv_flip::FlipPool::from_image(&map).mean() as f64)
    }
    #[cfg(not(feature = "flip"))]
    {
        let _ = (width, height);
        None
    }
}

/// The display ColorVideoVDP assumes: a 24-inch Full HD monitor of 200 cd/m², seen from 0.6 m
/// in office light (the reference implementation's `standard_fhd`). A clip is shown at its own
/// pixel size on it, as a viewer's window would be.
pub const VIDEO_DISPLAY: &str = "standard_fhd";

/// ColorVideoVDP's quality of `test` against `reference`, in JOD: clips of tone-mapped 8-bit
/// sRGB frames (`width x height x 3` bytes each), shown at `fps` on [`VIDEO_DISPLAY`]. One frame
/// is an image. Errors: clips of different lengths or sizes, an empty clip, frames under 4x4 or
/// a frame rate outside (0, 16384].
pub fn video_jod(
    test: &[&[u8]],
    reference: &[&[u8]],
    width: u32,
    height: u32,
    fps: f64,
) -> Result<f64, colorvideovdp::Error> {
    use colorvideovdp::{Color, Cvvdp, DisplayModel, Image, Options};
    let frames = |clip: &[&[u8]]| -> Result<Vec<Image>, colorvideovdp::Error> {
        clip.iter()
            .map(|f| {
                let data = f.iter().map(|&b| f32::from(b) / 255.0).collect();
                Image::new(width as usize, height as usize, 3, data)
            })
            .collect()
    };
    let (t, r) = (frames(test)?, frames(reference)?);
    let metric = Cvvdp::new(DisplayModel::from_name(VIDEO_DISPLAY)?, Options::default())?;
    // A one-frame clip takes the metric's image path.
    let p = metric.predict_video(&t, &r, fps as f32, Color::Srgb)?;
    Ok(f64::from(p.jod))
}

/// Per-pixel sums over seeds of one method at one budget: the bias estimates of the module docs.
#[derive(Debug, Clone)]
pub struct SeedSpread {
    sum: Vec<glam::DVec3>,
    sum_sq: Vec<glam::DVec3>,
    /// Each seed's mean channel value (brightness).
    means: Vec<f64>,
}

/// Bias of a method, estimated from its renders with different seeds.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BiasEstimate {
    pub seeds: usize,
    /// Relative squared bias: `mean over pixels and channels of ((m - r)^2 - var/S) / (r^2 +
    /// eps)`; comparable with relMSE (relMSE ~ this + the variance part). Can be slightly
    /// negative from noise.
    pub rel_bias_sq: f64,
    /// Mean brightness over the reference's, minus 1 (mean over seeds).
    pub brightness: f64,
    /// Standard error of `brightness` over seeds.
    pub brightness_se: f64,
}

impl SeedSpread {
    pub fn new(pixels: usize) -> Self {
        Self {
            sum: vec![glam::DVec3::ZERO; pixels],
            sum_sq: vec![glam::DVec3::ZERO; pixels],
            means: Vec::new(),
        }
    }

    /// Adds one seed's image.
    pub fn add(&mut self, image: &[Vec3]) {
        assert_eq!(image.len(), self.sum.len(), "images differ in size");
        let mut total = 0.0;
        for ((s, q), x) in self.sum.iter_mut().zip(&mut self.sum_sq).zip(image) {
            let x = x.as_dvec3();
            *s += x;
            *q += x * x;
            total += x.x + x.y + x.z;
        }
        self.means.push(total / (3 * image.len()).max(1) as f64);
    }

    /// The estimates against `reference`; `None` with fewer than 2 seeds.
    pub fn estimate(&self, reference: &[Vec3]) -> Option<BiasEstimate> {
        let n = self.means.len();
        if n < 2 {
            return None;
        }
        let nf = n as f64;
        let eps = glam::DVec3::splat(REL_MSE_EPSILON);
        let mut acc = 0.0;
        let mut ref_total = 0.0;
        for ((s, q), r) in self.sum.iter().zip(&self.sum_sq).zip(reference) {
            let r = r.as_dvec3();
            let m = *s / nf;
            let var = ((*q - *s * m) / (nf - 1.0)).max(glam::DVec3::ZERO);
            let e = ((m - r) * (m - r) - var / nf) / (r * r + eps);
            acc += e.x + e.y + e.z;
            ref_total += r.x + r.y + r.z;
        }
        let ref_mean = ref_total / (3 * reference.len()).max(1) as f64;
        let ratios: Vec<f64> = self.means.iter().map(|m| m / ref_mean - 1.0).collect();
        let mean = ratios.iter().sum::<f64>() / nf;
        let var = ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (nf - 1.0);
        Some(BiasEstimate {
            seeds: n,
            rel_bias_sq: acc / (3 * reference.len()).max(1) as f64,
            brightness: mean,
            brightness_se: (var / nf).sqrt(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_8bit_and_efficiency_hand_computed() {
        // One channel off by 5 in six: MSE = 25 / 6.
        let r = [10u8, 20, 30, 40, 50, 60];
        let x = [10u8, 25, 30, 40, 50, 60];
        let expected = 10.0 * (255.0f64 * 255.0 * 6.0 / 25.0).log10();
        assert!((psnr_8bit(&x, &r) - expected).abs() < 1e-9);
        assert!((efficiency(0.25, 2.0) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn seed_spread_hand_computed() {
        // One pixel, reference 1 (grey); seeds 1.5 and 2.5: mean 2, sample variance 0.5.
        // Squared bias estimate: (2 - 1)^2 - 0.5 / 2 = 0.75, over 1 + 0.01.
        let r = [Vec3::ONE];
        let mut s = SeedSpread::new(1);
        assert!(s.estimate(&r).is_none());
        s.add(&[Vec3::splat(1.5)]);
        s.add(&[Vec3::splat(2.5)]);
        let b = s.estimate(&r).unwrap();
        assert_eq!(b.seeds, 2);
        assert!((b.rel_bias_sq - 0.75 / 1.01).abs() < 1e-12, "{b:?}");
        // Brightness ratios 0.5 and 1.5: mean 1.0, sd 0.7071, se 0.5.
        assert!((b.brightness - 1.0).abs() < 1e-12 && (b.brightness_se - 0.5).abs() < 1e-12);
        // An unbiased pair around the reference estimates a negative-or-zero squared bias.
        let mut u = SeedSpread::new(1);
        u.add(&[Vec3::splat(0.5)]);
        u.add(&[Vec3::splat(1.5)]);
        let b = u.estimate(&r).unwrap();
        assert!((b.rel_bias_sq - (0.0 - 0.5 / 2.0) / 1.01).abs() < 1e-12);
        assert!(b.brightness.abs() < 1e-12);
    }

    #[test]
    fn flicker_hand_computed_and_blind_to_a_steady_error() {
        // One pixel: the references go 1 -> 2; the frames 1.5 -> 2.5 (the same +0.5 error both
        // times) flicker not at all; 1 -> 3 changes by 2 where the references change by 1:
        // (2 - 1)^2 / (2^2 + 0.01) per channel.
        let (r0, r1) = ([Vec3::ONE], [Vec3::splat(2.0)]);
        assert_eq!(
            flicker(&[Vec3::splat(1.5)], &[Vec3::splat(2.5)], &r0, &r1),
            0.0
        );
        let f = flicker(&[Vec3::ONE], &[Vec3::splat(3.0)], &r0, &r1);
        assert!((f - 1.0 / 4.01).abs() < 1e-12, "{f}");
        // A steady error still counts in relMSE: the two measures see different things.
        assert!(rel_mse(&[Vec3::splat(2.5)], &r1) > 0.06);
    }

    #[test]
    fn video_jod_is_ten_for_equal_clips_and_falls_with_noise_and_flicker() {
        let (w, h) = (32u32, 24u32);
        let n = (w * h * 3) as usize;
        let grey: Vec<u8> = (0..n).map(|i| 100 + (i % 7) as u8).collect();
        let clip = [grey.as_slice(); 4];
        let same = video_jod(&clip, &clip, w, h, 10.0).unwrap();
        assert!((same - 10.0).abs() < 1e-3, "{same}");
        // Noise of +-20 levels on every other pixel, and the same noise on alternate frames
        // only (flicker): both visible, each well under 10.
        let noisy: Vec<u8> = grey
            .iter()
            .enumerate()
            .map(|(i, &v)| if (i / 3) % 2 == 0 { v + 20 } else { v - 20 })
            .collect();
        let still = video_jod(&[noisy.as_slice(); 4], &clip, w, h, 10.0).unwrap();
        let flickering = [&noisy[..], &grey, &noisy, &grey];
        let flick = video_jod(&flickering, &clip, w, h, 10.0).unwrap();
        assert!(still < 9.5 && flick < 9.5, "{still} {flick}");
        // Wrong shapes are errors, not panics.
        assert!(video_jod(&clip[..2], &clip, w, h, 10.0).is_err());
        assert!(video_jod(&clip, &clip, w, h, 0.0).is_err());
    }

    #[cfg(feature = "flip")]
    #[test]
    fn flip_is_zero_on_equal_images_and_positive_otherwise() {
        let a = vec![128u8; 16 * 16 * 3];
        let mut b = a.clone();
        assert_eq!(flip(&a, &b, 16, 16), Some(0.0));
        b.iter_mut().step_by(2).for_each(|v| *v = 255);
        assert!(flip(&b, &a, 16, 16).unwrap() > 0.1);
    }

    #[test]
    fn ssim_of_flat_images_is_its_closed_form() {
        // Flat images have no variance and no covariance: SSIM reduces to the luminance term
        // (2 a b + C1) / (a^2 + b^2 + C1), and equals 1 for equal images.
        let (w, h) = (24u32, 17u32);
        let flat = |v: u8| vec![v; (w * h * 3) as usize];
        assert!((ssim(&flat(90), &flat(90), w, h).unwrap() - 1.0).abs() < 1e-12);
        let (a, b) = (90.0f64, 130.0f64);
        let c1 = (0.01f64 * 255.0).powi(2);
        let expected = (2.0 * a * b + c1) / (a * a + b * b + c1);
        let got = ssim(&flat(90), &flat(130), w, h).unwrap();
        assert!((got - expected).abs() < 1e-9, "{got} against {expected}");
        // Too small for the window.
        assert_eq!(
            ssim(&flat(1)[..10 * 10 * 3], &flat(1)[..10 * 10 * 3], 10, 10),
            None
        );
    }

    #[test]
    fn ssim_sees_structure_that_mse_ranks_alike() {
        // A checkerboard's contrast reversed and a uniform shift by the same amount have equal
        // MSE; SSIM, which weighs structure, scores the reversal far lower.
        let (w, h) = (32u32, 32u32);
        let board: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let v = if (i % w + i / w) % 2 == 0 { 100 } else { 140 };
                [v; 3]
            })
            .collect();
        let reversed: Vec<u8> = board.iter().map(|&v| 240 - v).collect();
        let shifted: Vec<u8> = board.iter().map(|&v| v + 40).collect();
        let (rev, shift) = (
            ssim(&reversed, &board, w, h).unwrap(),
            ssim(&shifted, &board, w, h).unwrap(),
        );
        assert!(rev < 0.0 && shift > 0.9, "reversed {rev}, shifted {shift}");
    }

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
