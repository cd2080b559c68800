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
        if !(len > 1e-12 && len.is_finite()) {
            return Err(format!(
                "direction {} invalid: expected a finite, non-zero vector (the way the light travels)",
                self.direction
            ));
        }
        self.direction /= len;
        super::check_rgb("irradiance", self.irradiance)
    }
}
