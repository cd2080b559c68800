//! The distant (directional) light: parallel light of constant irradiance from one direction,
//! the sun of a scientific visualisation (pbrt-v4's `DistantLight`).
//!
//! It is a delta light: it lights a point from exactly one direction, so next-event estimation
//! is the only way to find it (a phase-sampled direction hits it with probability 0). Its
//! sample's pdf is the delta's weight 1 and MIS gives it all the weight; a ray that leaves the
//! medium never sees it. Its shadow ray runs to infinity, blocked by the medium and by light
//! spheres, as the environment's does.

use super::{LightSample, luminance};
use glam::Vec3;

/// `type = "distant"` in a scene file's `[[light]]`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct DistantLight {
    /// The direction the light travels (from the light into the scene); any length, normalised
    /// when the scene is built.
    pub direction: Vec3,
    /// Irradiance on a surface facing the light, per RGB channel (linear).
    pub irradiance: Vec3,
}

impl DistantLight {
    /// The direction towards the light.
    #[inline]
    fn towards(&self) -> Vec3 {
        -self.direction
    }

    /// Irradiance luminance: on the spheres' scale (their radiance times solid angle), the
    /// unoccluded power this light sends to any point.
    #[inline]
    pub(super) fn selection_weight(&self) -> f32 {
        luminance(self.irradiance)
    }

    /// The one direction it lights a point from; its weight is the delta's (pdf 1).
    #[inline]
    pub fn sample(&self) -> LightSample {
        LightSample {
            direction: self.towards(),
            distance: f32::INFINITY,
            radiance: self.irradiance,
            pdf: 1.0,
            delta: true,
            light: None,
        }
    }

    /// What a scene may hold: a finite, non-zero direction (normalised here) and finite
    /// irradiance >= 0.
    pub fn validate(&mut self) -> Result<(), String> {
        let len = self.direction.length();
        if len > 1e-12 && len.is_finite() {
            self.direction /= len;
        } else {
            // A length f32 cannot hold (a tiny or huge vector, whose square under- or
            // overflows): normalised in f64, where any finite non-zero vector has one.
            let wide = self.direction.as_dvec3();
            let wide_len = wide.length();
            if !(wide_len > 0.0 && wide_len.is_finite()) {
                let [x, y, z] = self.direction.to_array();
                return Err(format!(
                    "direction [{x:?}, {y:?}, {z:?}] invalid: expected a finite, non-zero vector (the way the light travels)"
                ));
            }
            self.direction = (wide / wide_len).as_vec3();
        }
        super::check_rgb("irradiance", self.irradiance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn validated(direction: Vec3) -> Result<Vec3, String> {
        let mut light = DistantLight {
            direction,
            irradiance: Vec3::ONE,
        };
        light.validate().map(|()| light.direction)
    }

    /// Issue 48, item 11: a tiny or huge direction was refused as "[0, 0, 0]" (its f32 length
    /// under- or overflowed). Any finite, non-zero vector is a direction; the message names
    /// what was given, digit for digit.
    #[test]
    fn tiny_and_huge_directions_are_directions_and_zero_is_named_as_given() {
        for (given, expected) in [
            (Vec3::new(1e-30, 0.0, 0.0), Vec3::X),
            (Vec3::new(0.0, -1e30, 0.0), Vec3::NEG_Y),
            (
                Vec3::new(1e-45, 1e-45, 0.0),
                Vec3::new(1.0, 1.0, 0.0).normalize(),
            ),
            (Vec3::new(3e38, 3e38, 3e38), Vec3::ONE.normalize()),
        ] {
            let got = validated(given).unwrap();
            assert!((got - expected).length() < 1e-6, "{given:?} -> {got:?}");
        }
        // The common case is normalised in f32 as before (the same bits as every scene had).
        let d = Vec3::new(0.3, -1.0, 0.2);
        assert_eq!(validated(d).unwrap(), d / d.length());
        for bad in [
            Vec3::ZERO,
            Vec3::new(f32::NAN, 1.0, 0.0),
            Vec3::new(f32::INFINITY, 0.0, 0.0),
        ] {
            let err = validated(bad).unwrap_err();
            assert!(err.contains("expected a finite, non-zero vector"), "{err}");
        }
        let err = validated(Vec3::new(0.0, -0.0, 0.0)).unwrap_err();
        assert!(err.contains("[0.0, -0.0, 0.0]"), "{err}");
    }
}
