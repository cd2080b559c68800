//! The random numbers that decide acceptance, both stateless: an integer hash keyed on
//! (seed, pixel, sample, Gaussian id), and Sun et al.'s trigonometric hash (Eq. 8-10) of the hit
//! position, perturbed per (seed, pixel, sample) as the paper perturbs it per frame.

use glam::Vec3;
use render_base::hash::Hash32;
use splat_raster::random::{hash32, unit_f32};

/// Which generator decides acceptance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum RandomKind {
    /// xxHash32-style integer hash of (seed, pixel, sample, Gaussian id).
    #[default]
    Hash,
    /// `xi(p) = r2(p_xy + r1(p_z))` with `r1(q) = fract(b1 sin(a1 q))` and
    /// `r2(q) = fract(b2 sin(a2 . q))` (Sun et al. 2025, Eq. 8-10), at the perturbed hit position,
    /// evaluated in f64 (in f32 it is grossly biased). Slightly biased even in f64: against an independent
    /// f64 exact compositor on the fruit asset (4,096 samples a pixel over two seeds, 8 a
    /// traversal) its image mean is -0.026% (-7 standard errors), and more where transmittance
    /// is high (-0.25% at 0.9-0.999): it accepts hits of opacity 0.1-0.3 about 0.13% too
    /// rarely (`tests/random.rs` measures it). Use `hash` (the default, unbiased) for
    /// measurements.
    Trig,
}

/// The key of one estimate: what the integer hash mixes, and the trig hash's perturbation.
#[derive(Debug, Clone, Copy)]
pub struct SampleKey {
    pub seed: u32,
    pub pixel: u32,
    pub sample: u32,
    /// The integer hash's state after the key's seed and pixel, which every acceptance number
    /// of the key starts from: hashed once here rather than in each of them (a hit tests up to
    /// a number per slot).
    prefix: Hash32,
}

impl SampleKey {
    pub fn new(seed: u32, pixel: u32, sample: u32) -> Self {
        Self {
            seed,
            pixel,
            sample,
            prefix: Hash32::new(4).absorb(seed).absorb(pixel),
        }
    }

    /// The numbers of slots `0..thresholds.len()` for a walk that meets a ray's hits in depth
    /// order ([`crate::camera_grid`]), each in (0, 1]. A slot takes the hit across which the
    /// ray's transmittance falls below its number: hit k, met at transmittance `T_k` with alpha
    /// `a_k`, with probability `T_k - T_k (1 - a_k) = a_k T_k`, the probability an acceptance
    /// test per hit gives it. Slots stay independent, so the estimate has the same law as Sun
    /// et al.'s, from one number a slot instead of one a hit.
    pub fn slot_thresholds(&self, thresholds: &mut [f32]) {
        for (slot, threshold) in (0u32..).zip(thresholds.iter_mut()) {
            // `unit_f32` is in [0, 1); one less it is in (0, 1], exactly (24 bits).
            *threshold = 1.0 - unit_f32(self.slot_state(slot).absorb(THRESHOLD_WORD).finish());
        }
    }

    /// The integer hash's state for slot `slot` before a Gaussian's id.
    #[inline]
    fn slot_state(&self, slot: u32) -> Hash32 {
        self.prefix
            .absorb(self.sample.wrapping_add(slot.wrapping_mul(0x632b_e5ab)))
    }

    /// The per-(seed, pixel, sample) offset the trigonometric hash adds to hit positions:
    /// computed where that hash is used, not with every key (three hashes a key, a tenth of
    /// a camera ray's cost in the cache's lookup, which uses the integer hash).
    fn trig_offset(&self) -> Vec3 {
        let h = |k: u32| {
            unit_f32(hash32(&[
                self.seed,
                self.pixel,
                self.sample,
                0x9e37_79b9 ^ k,
            ]))
        };
        Vec3::new(h(1), h(2), h(3))
    }
}

#[inline]
fn fract(x: f64) -> f64 {
    x - x.floor()
}

/// Sun et al.'s trigonometric hash of a position, in [0, 1).
///
/// Evaluated in f64. In f32, as a shader computes it, `43758.5 sin(.)` is a number of up to
/// 43758 whose fraction keeps only 8 or 9 bits: the numbers fall on a grid of 1/256, so a hit of
/// opacity 1/255 is accepted with probability 0 or 2/255 and the image is biased (23 standard
/// errors at 256 spp on the bundled asset; `tests/random.rs` measures the grid directly).
#[inline]
pub fn trig_hash(p: Vec3) -> f32 {
    let p = p.as_dvec3();
    let r1 = fract(47_453.547 * (91.3458 * p.z).sin());
    let (x, y) = (p.x + r1, p.y + r1);
    // Both components of r2 use the same coefficients; one is enough.
    (fract(43_758.547 * (12.9898 * x + 78.233 * y).sin()) as f32).min(0.999_999_94)
}

/// The acceptance number for Gaussian `id` hit at position `p`, for slot `slot` of a
/// multi-sample traversal.
#[inline]
pub fn acceptance(kind: RandomKind, key: &SampleKey, id: u32, slot: u32, p: Vec3) -> f32 {
    match kind {
        // `hash32(&[seed, pixel, sample + slot * 0x632be5ab, id])`, from the key's prefix.
        RandomKind::Hash => unit_f32(key.slot_state(slot).absorb(id).finish()),
        RandomKind::Trig => trig_hash(
            p + key.trig_offset() + slot as f32 * Vec3::new(0.618_034, 0.414_213_57, 0.732_050_8),
        ),
    }
}

/// The last word of a slot's threshold key ([`SampleKey::slot_thresholds`]), where an
/// acceptance number's key has a Gaussian's id.
const THRESHOLD_WORD: u32 = u32::MAX;

#[cfg(test)]
mod tests {
    use super::*;

    /// The integer hash's acceptance number, started from the key's kept prefix, is the hash of
    /// the whole key (seed, pixel, sample and slot, Gaussian id), bit for bit.
    #[test]
    fn acceptance_from_the_prefix_is_the_whole_key_hashed() {
        for (seed, pixel, sample) in [(0u32, 0u32, 0u32), (1, 57_599, 3), (u32::MAX, 12_345, 1023)]
        {
            let key = SampleKey::new(seed, pixel, sample);
            for slot in [0u32, 1, 7, 63] {
                for id in [0, 1, 4_095, u32::MAX] {
                    let whole = hash32(&[
                        seed,
                        pixel,
                        sample.wrapping_add(slot.wrapping_mul(0x632b_e5ab)),
                        id,
                    ]);
                    let got = acceptance(RandomKind::Hash, &key, id, slot, Vec3::ZERO);
                    assert_eq!(got.to_bits(), unit_f32(whole).to_bits());
                }
            }
        }
    }

    /// A slot's threshold is one less the hash of its key with [`THRESHOLD_WORD`] for the
    /// Gaussian's id, in (0, 1]: the same numbers as hashed one by one.
    #[test]
    fn slot_thresholds_are_the_hashed_keys() {
        for (seed, pixel, sample) in [(0u32, 0u32, 0u32), (1, 57_599, 3), (u32::MAX, 12_345, 1023)]
        {
            let key = SampleKey::new(seed, pixel, sample);
            for slots in [1usize, 8, 64] {
                let mut got = vec![0.0f32; slots];
                key.slot_thresholds(&mut got);
                let want: Vec<f32> = (0..slots as u32)
                    .map(|slot| {
                        let word = sample.wrapping_add(slot.wrapping_mul(0x632b_e5ab));
                        1.0 - unit_f32(hash32(&[seed, pixel, word, THRESHOLD_WORD]))
                    })
                    .collect();
                assert_eq!(got, want);
                assert!(got.iter().all(|&t| t > 0.0 && t <= 1.0));
            }
        }
    }
}
