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

/// [`continue_probability`] at `level` (0: path length 1), with the level's coefficient: the
/// first level's `coefficient`, the deeper levels' `deep_coefficient`.
pub fn continue_probability_at(
    config: &TerminationConfig,
    level: usize,
    albedo_product: Vec3,
) -> f32 {
    if level == 0 || config.deep_coefficient == config.coefficient {
        return continue_probability(config, albedo_product);
    }
    let deeper = TerminationConfig {
        coefficient: config.deep_coefficient,
        ..*config
    };
    continue_probability(&deeper, albedo_product)
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

    #[test]
    fn the_deeper_levels_take_their_own_coefficient() {
        let c = crate::CacheConfig {
            c_deep: 1.5,
            ..Default::default()
        }
        .termination();
        let albedo = Vec3::splat(0.4);
        // Level 0: C = 0.5 gives 0.2; levels 1 and 2: C = 1.5 gives 0.6.
        assert!((continue_probability_at(&c, 0, albedo) - 0.2).abs() < 1e-6);
        assert!((continue_probability_at(&c, 1, albedo) - 0.6).abs() < 1e-6);
        assert!((continue_probability_at(&c, 2, albedo) - 0.6).abs() < 1e-6);
        // Unset, every level takes `c`.
        let same = crate::CacheConfig::default().termination();
        assert_eq!(
            continue_probability_at(&same, 2, albedo),
            continue_probability(&same, albedo)
        );
    }
}
