//! The splitmix64 finaliser, defined once: every stateless hash in the project (sample streams,
//! the neural cache's shuffles and seeds, stochastic acceptance) mixes its counter through it.

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_reference_sequence() {
        // The first outputs of Vigna's splitmix64.c seeded with 0 (state advanced by the gamma
        // before mixing, as `splitmix64` does).
        assert_eq!(splitmix64(0), 0xe220_a839_7b1d_cdaf);
        assert_eq!(splitmix64(GOLDEN_GAMMA), 0x6e78_9e6a_a1b9_65f4);
    }
}
