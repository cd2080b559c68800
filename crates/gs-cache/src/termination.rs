//! The GSCache paper's Algorithm 1: the probability that a path goes on past a vertex instead of
//! stopping into the cache.

use crate::config::TerminationConfig;
use glam::Vec3;

/// Rec. 709 luminance of linear RGB.
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// The continuation probability at a vertex whose path has gathered the albedo product
/// `albedo_product` (the vertex's own albedo included): 1 when early termination is off or the
/// product is bright enough, else `clamp(C * luminance, 0, 1)`. NaN gives 0 (the path stops).
pub fn continue_probability(config: &TerminationConfig, albedo_product: Vec3) -> f32 {
    if !config.early {
        return 1.0;
    }
    let tr = config.coefficient * luminance(albedo_product);
    // Written so that NaN stops the path rather than continuing it with a NaN weight.
    let tr = if tr > 0.0 { tr.min(1.0) } else { 0.0 };
    if tr >= config.threshold { 1.0 } else { tr }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn algorithm_one() {
        let c = crate::CacheConfig::default().termination();
        // C = 0.5, grey albedo 0.8: Tr = 0.4 < 0.9.
        assert!((continue_probability(&c, Vec3::splat(0.8)) - 0.4).abs() < 1e-6);
        // Above the threshold every path continues.
        let c2 = TerminationConfig {
            coefficient: 2.0,
            ..c
        };
        assert_eq!(continue_probability(&c2, Vec3::splat(0.5)), 1.0);
        assert_eq!(continue_probability(&c, Vec3::splat(f32::NAN)), 0.0);
        let off = TerminationConfig { early: false, ..c };
        assert_eq!(continue_probability(&off, Vec3::ZERO), 1.0);
    }
}
