//! The sphere light: an opaque sphere of constant radiance, sampled by the solid angle it
//! subtends. A ray that reaches one stops there.
//!
//! Intersections and cone geometry run in f64 so that tiny lights (radius 1e-4 at distance 10,
//! a cone of 1e-10 steradians) keep their precision; `1 - cos(theta_max)` is computed as
//! `sin^2 / (1 + cos)` and never as a difference of nearly equal numbers.

use super::{LightSample, luminance};
use crate::sampling::direction_around;
use glam::{DVec3, Vec3};
use std::f64::consts::PI;

/// `type = "sphere"` (the default) in a scene file's `[[light]]`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SphereLight {
    pub center: Vec3,
    pub radius: f32,
    /// Emitted radiance (RGB, linear), the same in every direction from every surface point.
    pub radiance: Vec3,
}

impl SphereLight {
    /// `1 - cos(theta_max)` of the cone the sphere subtends from `p`, or None inside the sphere.
    fn cone(&self, p: Vec3) -> Option<(DVec3, f64, f64)> {
        let to = self.center.as_dvec3() - p.as_dvec3();
        let d2 = to.length_squared();
        let r = self.radius as f64;
        if !(d2 > r * r) {
            return None;
        }
        let sin2 = r * r / d2;
        let cos_max = (1.0 - sin2).max(0.0).sqrt();
        let one_minus_cos_max = sin2 / (1.0 + cos_max);
        Some((to / d2.sqrt(), d2.sqrt(), one_minus_cos_max))
    }

    /// The unoccluded power this light sends to `p`, up to a common factor: luminance times the
    /// solid angle it subtends (0 from inside it, where it cannot be sampled).
    #[inline]
    pub(super) fn selection_weight(&self, p: Vec3) -> f32 {
        // In f32: a weight only sets how often the light is picked, and sample and emission
        // compute it the same way, so their pdfs agree exactly.
        let d2 = (self.center - p).length_squared();
        let r2 = self.radius * self.radius;
        if !(d2 > r2) {
            return 0.0;
        }
        let sin2 = r2 / d2;
        let one_minus_cos = sin2 / (1.0 + (1.0 - sin2).sqrt());
        luminance(self.radiance) * std::f32::consts::TAU * one_minus_cos
    }

    /// Samples a direction uniformly inside the cone the sphere subtends from `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, u: (f32, f32)) -> Option<LightSample> {
        let (axis, dist, omc_max) = self.cone(p)?;
        let omc = u.0 as f64 * omc_max;
        let cos = 1.0 - omc;
        let sin = (omc * (2.0 - omc)).max(0.0).sqrt();
        let direction = direction_around(
            axis.as_vec3(),
            cos as f32,
            sin as f32,
            2.0 * std::f32::consts::PI * u.1,
        );
        // Distance along the sampled direction to the near side of the sphere.
        let r = self.radius as f64;
        let b = dist * cos;
        let h2 = (r * r - dist * dist * sin * sin).max(0.0);
        let distance = (b - h2.sqrt()).max(0.0);
        Some(LightSample {
            direction,
            distance: distance as f32,
            radiance: self.radiance,
            pdf: (1.0 / (2.0 * PI * omc_max)) as f32,
            delta: false,
            light: None,
        })
    }

    /// Solid-angle pdf of `sample` for a direction that hits the sphere from `p`.
    #[inline]
    pub fn pdf(&self, p: Vec3) -> f32 {
        match self.cone(p) {
            Some((_, _, omc)) => (1.0 / (2.0 * PI * omc)) as f32,
            None => 0.0,
        }
    }

    /// Distance from `o` along unit `d` to the sphere's surface, if the ray reaches it after `t_min`.
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, t_min: f32) -> Option<f32> {
        let oc = o.as_dvec3() - self.center.as_dvec3();
        let d = d.as_dvec3();
        let b = oc.dot(d);
        let r = self.radius as f64;
        // c - b^2 computed as |oc - b d|^2 (distance of the closest approach): no cancellation.
        let closest = oc - b * d;
        let h2 = r * r - closest.length_squared();
        if h2 < 0.0 {
            return None;
        }
        let h = h2.sqrt();
        let t0 = -b - h;
        let t1 = -b + h;
        let t = if t0 > t_min as f64 {
            t0
        } else if t1 > t_min as f64 {
            t1
        } else {
            return None;
        };
        Some(t as f32)
    }

    /// Power emitted by the sphere, summed over RGB (for reports).
    pub fn power(&self) -> f32 {
        let a = 4.0 * std::f32::consts::PI * self.radius * self.radius;
        std::f32::consts::PI * a * (self.radiance.x + self.radiance.y + self.radiance.z)
    }

    /// What a scene may hold: a finite centre, a finite radius > 0 and finite radiance >= 0,
    /// all within [`super::MAX_COORDINATE`].
    pub fn validate(&self) -> Result<(), String> {
        if !(self.center.is_finite() && self.center.abs().max_element() <= super::MAX_COORDINATE) {
            return Err(format!(
                "center {} invalid: expected finite coordinates within +-{:e}",
                self.center,
                super::MAX_COORDINATE
            ));
        }
        if !(self.radius > 0.0 && self.radius <= super::MAX_COORDINATE) {
            return Err(format!(
                "radius {} invalid: expected a finite radius > 0 and at most {:e}",
                self.radius,
                super::MAX_COORDINATE
            ));
        }
        super::check_rgb("radiance", self.radiance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::SampleStream;

    #[test]
    fn tiny_light_irradiance_by_solid_angle_sampling() {
        // E = L * pi * sin^2(theta_max) for a sphere seen head-on; estimate the cosine-weighted
        // integral by cone sampling. Relative standard error of the mean is below 1e-4 here.
        let light = SphereLight {
            center: Vec3::new(0.0, 0.0, 10.0),
            radius: 1e-4,
            radiance: Vec3::splat(1.0),
        };
        let p = Vec3::ZERO;
        let mut s = SampleStream::new(1, 0, 0);
        let n = 10_000;
        let mut e = 0.0f64;
        for _ in 0..n {
            let ls = light.sample(p, s.next_2d()).unwrap();
            assert!((ls.distance - (10.0 - 1e-4)).abs() < 1e-4);
            e += (ls.direction.z / ls.pdf) as f64;
            let t = light.intersect(p, ls.direction, 0.0);
            assert!(t.is_some(), "sampled direction misses the light");
        }
        e /= n as f64;
        let exact = std::f64::consts::PI * 1e-8 / 100.0;
        assert!((e / exact - 1.0).abs() < 1e-4, "{e} vs {exact}");
    }

    #[test]
    fn intersection_agrees_with_geometry() {
        let s = SphereLight {
            center: Vec3::new(1.0, 2.0, 3.0),
            radius: 0.5,
            radiance: Vec3::ONE,
        };
        let o = Vec3::new(1.0, 2.0, -2.0);
        assert!((s.intersect(o, Vec3::Z, 0.0).unwrap() - 4.5).abs() < 1e-5);
        assert!(s.intersect(o, -Vec3::Z, 0.0).is_none());
        assert!(s.intersect(o, Vec3::X, 0.0).is_none());
        assert!(s.sample(Vec3::new(1.0, 2.0, 3.1), (0.5, 0.5)).is_none());
    }
}
