//! The stateless hashes, defined once: a random decision anywhere in the project is a pure
//! function of its key (seed, pixel, sample, Gaussian id...), so images do not depend on thread
//! count or order.
//!
//! - [`splitmix64_finalize`] / [`splitmix64`]: 64-bit keys (the path tracer's sample streams,
//!   the neural cache's shuffles and seeds).
//! - [`hash32`] / [`unit_f32`]: several 32-bit words to one (per-fragment decisions of the
//!   rasteriser and the ray tracer); [`Hash32`] is the same hash a word at a time, for keys
//!   that share a prefix.
//! - [`fnv1a64`]: byte strings to the keys of renders, references and experiments.

/// The FNV-1a offset basis: the 64-bit FNV-1a hash of nothing.
pub const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// 64-bit FNV-1a of `bytes`, continuing from `state` ([`FNV_OFFSET`] to start): the keys that
/// name renders, references and experiments. Not cryptographic: it guards against mistakes.
#[inline]
pub fn fnv1a64(bytes: &[u8], mut state: u64) -> u64 {
    for &b in bytes {
        state = (state ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
    }
    state
}

/// 2^64 / golden ratio, odd: the splitmix64 increment.
pub const GOLDEN_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// The splitmix64 output function (Stafford's "Mix13"): a bijection of u64 whose every output
/// bit depends on every input bit.
#[inline]
pub const fn splitmix64_finalize(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// One splitmix64 step from state `x`: the finaliser of `x + GOLDEN_GAMMA`.
#[inline]
pub const fn splitmix64(x: u64) -> u64 {
    splitmix64_finalize(x.wrapping_add(GOLDEN_GAMMA))
}

/// The xxHash32 finaliser applied to a running combination of 32-bit words (PCG-style avalanche
/// in, xxHash32 avalanche out).
#[inline]
pub fn hash32(words: &[u32]) -> u32 {
    words
        .iter()
        .fold(Hash32::new(words.len()), |h, &w| h.absorb(w))
        .finish()
}

/// [`hash32`] a word at a time, for keys that share their first words: the state after a
/// common prefix is kept and continued with each key's last words (the ray tracer hashes a
/// sample's seed and pixel once for all its acceptance numbers). `Hash32::new(n)`, `absorb`
/// the key's `n` words in order, then `finish`, is `hash32` of those words, bit for bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Hash32(u32);

impl Hash32 {
    const P2: u32 = 0x85eb_ca77;
    const P3: u32 = 0xc2b2_ae3d;
    const P4: u32 = 0x27d4_eb2f;
    const P5: u32 = 0x1656_67b1;

    /// The state before the first word of a key of `words` words.
    #[inline]
    pub const fn new(words: usize) -> Self {
        Self(Self::P5.wrapping_add(4 * words as u32))
    }

    /// The state after the next word `w`.
    #[inline]
    pub const fn absorb(self, w: u32) -> Self {
        let h = self.0.wrapping_add(w.wrapping_mul(Self::P3));
        Self(h.rotate_left(17).wrapping_mul(Self::P4))
    }

    /// The hash of the words absorbed.
    #[inline]
    pub const fn finish(self) -> u32 {
        let mut h = self.0;
        h ^= h >> 15;
        h = h.wrapping_mul(Self::P2);
        h ^= h >> 13;
        h = h.wrapping_mul(Self::P3);
        h ^ (h >> 16)
    }
}

/// A uniform number in [0, 1) from a hash (24 bits).
#[inline]
pub fn unit_f32(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `hash32`'s values are fixed (images depend on them): a change to the word-at-a-time form
    /// must not move them. The expected values were printed by the one-function form before it
    /// was split into `Hash32`.
    #[test]
    fn hash32_keeps_its_values() {
        assert_eq!(hash32(&[]), 0x02cc_5d05);
        assert_eq!(hash32(&[0]), 0x08d6_d969);
        assert_eq!(hash32(&[1, 2, 3, 4]), 0x623c_12cf);
        assert_eq!(hash32(&[u32::MAX, 7, 0x9e37_79b9]), 0xb079_d391);
    }

    #[test]
    fn fnv1a_matches_its_published_vectors() {
        assert_eq!(fnv1a64(b"", FNV_OFFSET), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a", FNV_OFFSET), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar", FNV_OFFSET), 0x8594_4171_f739_67e8);
        // Continuing from a state is hashing the concatenation.
        assert_eq!(
            fnv1a64(b"bar", fnv1a64(b"foo", FNV_OFFSET)),
            fnv1a64(b"foobar", FNV_OFFSET)
        );
    }

    #[test]
    fn matches_the_reference_sequence() {
        // The first outputs of Vigna's splitmix64.c seeded with 0 (state advanced by the gamma
        // before mixing, as `splitmix64` does).
        assert_eq!(splitmix64(0), 0xe220_a839_7b1d_cdaf);
        assert_eq!(splitmix64(GOLDEN_GAMMA), 0x6e78_9e6a_a1b9_65f4);
    }

    #[test]
    fn hash_is_uniform_over_keys() {
        // Chi-square over 64 bins; 63 degrees of freedom, the 1e-4 upper quantile is about 117.
        let mut bins = [0u32; 64];
        let mut n = 0;
        for a in 0..64u32 {
            for b in 0..1024u32 {
                bins[(unit_f32(hash32(&[7, a, b])) * 64.0) as usize] += 1;
                n += 1;
            }
        }
        let e = n as f64 / 64.0;
        let chi2: f64 = bins.iter().map(|&b| (b as f64 - e).powi(2) / e).sum();
        assert!(chi2 < 117.0, "chi2 {chi2}");
    }
}
