//! Counter-based random numbers and the warps built on them.
//!
//! A sample is a pure function of (seed, pixel, sample index, dimension): there is no generator
//! state to share between threads, so an image is bit-identical for a seed whatever the thread
//! count or the tile order. The mixer is the SplitMix64 finaliser (Stafford's variant 13) over a
//! Weyl sequence keyed by the hashed (seed, pixel, sample) triple.

use glam::Vec3;
use std::f32::consts::PI;

use render_base::hash::{GOLDEN_GAMMA, splitmix64_finalize};

/// The random numbers of one (seed, pixel, sample): dimension `k` is the k-th draw.
#[derive(Debug, Clone)]
pub struct SampleStream {
    key: u64,
    dim: u64,
}

impl SampleStream {
    #[inline]
    pub fn new(seed: u64, pixel: u64, sample: u64) -> Self {
        let key = splitmix64_finalize(
            splitmix64_finalize(seed.wrapping_mul(GOLDEN_GAMMA) ^ pixel)
                ^ sample.wrapping_mul(0xd6e8_feb8_6659_fd93),
        );
        Self { key, dim: 0 }
    }

    /// A uniform number in [0, 1) with 24 random bits (never 1).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        self.dim += 1;
        let h = splitmix64_finalize(self.key.wrapping_add(self.dim.wrapping_mul(GOLDEN_GAMMA)));
        (h >> 40) as f32 * (1.0 / 16_777_216.0)
    }

    /// How many numbers have been drawn: a deterministic measure of a path's work (every
    /// tracking step draws one), which a cache weighs its choices by.
    #[inline]
    pub fn draws(&self) -> u64 {
        self.dim
    }

    #[inline]
    pub fn next_2d(&mut self) -> (f32, f32) {
        (self.next_f32(), self.next_f32())
    }
}

/// An orthonormal basis around unit `n` (Duff et al. 2017, branchless).
#[inline]
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// A direction around unit `axis` with the given cosine and azimuth; `sin` is passed in so callers
/// that know `1 - cos` precisely (tiny cones) keep that precision.
#[inline]
pub fn direction_around(axis: Vec3, cos: f32, sin: f32, phi: f32) -> Vec3 {
    let (t, b) = basis(axis);
    (t * (sin * phi.cos()) + b * (sin * phi.sin()) + axis * cos).normalize()
}

/// Uniform direction on the unit sphere; pdf `1 / (4 pi)`.
#[inline]
pub fn uniform_sphere(u: (f32, f32)) -> Vec3 {
    let z = 1.0 - 2.0 * u.0;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.1;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

pub const UNIFORM_SPHERE_PDF: f32 = 1.0 / (4.0 * PI);

/// Power heuristic (beta = 2) weight of strategy `a` against `b`.
#[inline]
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2.is_infinite() {
        return 1.0;
    }
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_uniform_and_distinct() {
        // Chi-square over 64 bins of 64k draws from many streams; 63 dof, the 1e-4
        // upper quantile is about 117.
        let mut bins = [0u32; 64];
        let mut n = 0;
        for pixel in 0..256u64 {
            let mut s = SampleStream::new(7, pixel, 3);
            for _ in 0..256 {
                let u = s.next_f32();
                assert!((0.0..1.0).contains(&u));
                bins[(u * 64.0) as usize] += 1;
                n += 1;
            }
        }
        let e = n as f64 / 64.0;
        let chi2: f64 = bins.iter().map(|&b| (b as f64 - e).powi(2) / e).sum();
        assert!(chi2 < 117.0, "chi2 = {chi2}");
        let a = SampleStream::new(1, 2, 3).next_f32();
        assert_ne!(a, SampleStream::new(1, 2, 4).next_f32());
        assert_ne!(a, SampleStream::new(1, 3, 3).next_f32());
        assert_ne!(a, SampleStream::new(2, 2, 3).next_f32());
        assert_eq!(a, SampleStream::new(1, 2, 3).next_f32());
    }

    #[test]
    fn basis_is_orthonormal() {
        for i in 0..100 {
            let n = uniform_sphere(((i as f32 * 0.37).fract(), (i as f32 * 0.71).fract()));
            let (t, b) = basis(n);
            assert!(t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5 && t.dot(b).abs() < 1e-5);
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
        }
    }
}
