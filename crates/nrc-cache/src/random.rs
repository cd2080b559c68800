//! A small counter-based generator for initialisation and shuffling: splitmix64, so every
//! draw is a pure function of the seed and the draw's index (no thread or order dependence).

// One splitmix64 step from `x`: render-base's, the one definition.
use render_base::hash::splitmix64;

/// A sequential splitmix64 stream.
#[derive(Debug, Clone)]
pub struct SplitMix {
    state: u64,
}

impl SplitMix {
    pub fn new(seed: u64) -> Self {
        Self {
            state: splitmix64(seed ^ 0x6e72_6320_6361_6368),
        }
    }
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(render_base::hash::GOLDEN_GAMMA);
        splitmix64(self.state)
    }
    /// Uniform in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}
