//! Emitters: spherical area lights sampled by solid angle, and a constant environment.
//!
//! Light spheres are opaque emitters of constant radiance: a ray that reaches one stops there.
//! Intersections and cone geometry run in f64 so that tiny lights (radius 1e-4 at distance 10,
//! a cone of 1e-10 steradians) keep their precision; `1 - cos(theta_max)` is computed as
//! `sin^2 / (1 + cos)` and never as a difference of nearly equal numbers.

use crate::sampling::{UNIFORM_SPHERE_PDF, direction_around, uniform_sphere};
use glam::{DVec3, Vec3};
use std::f64::consts::PI;

#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct SphereLight {
    pub center: Vec3,
    pub radius: f32,
    /// Emitted radiance (RGB, linear), the same in every direction from every surface point.
    pub radiance: Vec3,
}

/// A direction towards a light, with what NEE needs to use it.
#[derive(Debug, Clone, Copy)]
pub struct LightSample {
    pub direction: Vec3,
    /// Distance to the emitting surface (infinite for the environment).
    pub distance: f32,
    pub radiance: Vec3,
    /// Solid-angle pdf of the direction (selection included once returned by [`Lights::sample`]).
    pub pdf: f32,
    /// The sphere sampled, or None for the environment.
    pub sphere: Option<usize>,
}

/// Rec. 709 luminance: the weight of a radiance in light selection.
#[inline]
fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
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
    fn selection_weight(&self, p: Vec3) -> f32 {
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
            sphere: None,
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
}

/// Every emitter of a scene. NEE picks one of them uniformly.
#[derive(Debug, Clone, Default)]
pub struct Lights {
    pub spheres: Vec<SphereLight>,
    /// Radiance arriving from every direction not blocked by the volume or a light sphere.
    pub environment: Vec3,
}

/// What a ray that left the medium sees.
#[derive(Debug, Clone, Copy)]
pub struct Emission {
    pub radiance: Vec3,
    /// Solid-angle pdf with which NEE would have chosen this direction (selection included).
    pub nee_pdf: f32,
}

impl Lights {
    fn has_environment(&self) -> bool {
        self.environment.max_element() > 0.0
    }

    /// Number of strategies NEE chooses among (spheres, plus the environment if it emits).
    pub fn count(&self) -> usize {
        self.spheres.len() + self.has_environment() as usize
    }

    /// Nearest light sphere along the ray after `t_min`: (index, distance).
    #[inline]
    pub fn nearest_sphere(&self, o: Vec3, d: Vec3, t_min: f32) -> Option<(usize, f32)> {
        let mut best: Option<(usize, f32)> = None;
        for (i, s) in self.spheres.iter().enumerate() {
            if let Some(t) = s.intersect(o, d, t_min)
                && best.is_none_or(|b| t < b.1)
            {
                best = Some((i, t));
            }
        }
        best
    }

    /// The environment's selection weight, on the spheres' scale: luminance times 4 pi.
    fn environment_weight(&self) -> f32 {
        if self.has_environment() {
            luminance(self.environment) * 2.0 * std::f32::consts::TAU
        } else {
            0.0
        }
    }

    /// The probability that NEE at `p` picks strategy `i` (sphere `i`, or the environment at
    /// `i = spheres.len()`): proportional to the unoccluded power each sends to `p`, so the
    /// bright, near and large lights get the samples (uniform selection spends a third of them
    /// on a dim environment in the bundled scenes). Falls back to uniform when every weight is 0
    /// or not finite, so no light that can contribute is ever left out.
    #[inline]
    pub fn selection_probability(&self, p: Vec3, i: usize) -> f32 {
        let total = self.total_weight(p);
        let n = self.count();
        if !(total > 0.0 && total.is_finite()) {
            return 1.0 / n.max(1) as f32;
        }
        let w = if i < self.spheres.len() {
            self.spheres[i].selection_weight(p)
        } else {
            self.environment_weight()
        };
        w / total
    }

    #[inline]
    fn total_weight(&self, p: Vec3) -> f32 {
        self.spheres
            .iter()
            .map(|s| s.selection_weight(p))
            .sum::<f32>()
            + self.environment_weight()
    }

    /// Picks a strategy by [`Lights::selection_probability`] and samples a direction towards
    /// it. The returned pdf includes the selection probability.
    #[inline]
    pub fn sample(&self, p: Vec3, u_pick: f32, u: (f32, f32)) -> Option<LightSample> {
        let n = self.count();
        if n == 0 {
            return None;
        }
        let total = self.total_weight(p);
        let (i, pick) = if total > 0.0 && total.is_finite() {
            // Walk the cumulative weights; the last strategy with weight takes any rounding.
            let target = u_pick * total;
            let mut acc = 0.0f32;
            let mut chosen = None;
            for k in 0..n {
                let w = if k < self.spheres.len() {
                    self.spheres[k].selection_weight(p)
                } else {
                    self.environment_weight()
                };
                if w > 0.0 {
                    chosen = Some((k, w / total));
                    acc += w;
                    if target < acc {
                        break;
                    }
                }
            }
            chosen?
        } else {
            let k = ((u_pick * n as f32) as usize).min(n - 1);
            (k, 1.0 / n as f32)
        };
        let mut s = if i < self.spheres.len() {
            LightSample {
                sphere: Some(i),
                ..self.spheres[i].sample(p, u)?
            }
        } else {
            LightSample {
                direction: uniform_sphere(u),
                distance: f32::INFINITY,
                radiance: self.environment,
                pdf: UNIFORM_SPHERE_PDF,
                sphere: None,
            }
        };
        s.pdf *= pick;
        Some(s)
    }

    /// Emission seen along a ray from `p` in direction `d` that reached sphere `hit` (or escaped
    /// to the environment when `hit` is None), with the NEE pdf for MIS.
    #[inline]
    pub fn emission(&self, p: Vec3, hit: Option<usize>) -> Emission {
        match hit {
            Some(i) => {
                let s = &self.spheres[i];
                Emission {
                    radiance: s.radiance,
                    nee_pdf: s.pdf(p) * self.selection_probability(p, i),
                }
            }
            None => Emission {
                radiance: self.environment,
                nee_pdf: if self.has_environment() {
                    UNIFORM_SPHERE_PDF * self.selection_probability(p, self.spheres.len())
                } else {
                    0.0
                },
            },
        }
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

    /// The pdf a light sample reports is the one `emission` gives for the same direction from
    /// the same point (MIS needs both), the selection probabilities sum to 1, and a light that
    /// sends more power to a point is picked more often, in proportion.
    #[test]
    fn selection_is_consistent_and_follows_power() {
        let lights = Lights {
            spheres: vec![
                SphereLight {
                    center: Vec3::new(10.0, 0.0, 0.0),
                    radius: 1.0,
                    radiance: Vec3::splat(100.0),
                },
                SphereLight {
                    center: Vec3::new(0.0, -20.0, 3.0),
                    radius: 4.0,
                    radiance: Vec3::new(0.5, 1.0, 3.0),
                },
            ],
            environment: Vec3::splat(0.05),
        };
        let mut rng = SampleStream::new(4, 0, 0);
        for k in 0..200 {
            let p = Vec3::new(k as f32 * 0.05 - 5.0, (k % 7) as f32, (k % 3) as f32 - 1.0);
            let total: f32 = (0..3).map(|i| lights.selection_probability(p, i)).sum();
            assert!((total - 1.0).abs() < 1e-5, "{total}");
            let ls = lights.sample(p, rng.next_f32(), rng.next_2d()).unwrap();
            let em = lights.emission(p, ls.sphere);
            assert!(
                (ls.pdf - em.nee_pdf).abs() <= 1e-4 * ls.pdf,
                "{} vs {}",
                ls.pdf,
                em.nee_pdf
            );
        }
        // Picks follow the probabilities: binomial z < 5 over 200000 picks at one point.
        let p = Vec3::ZERO;
        let n = 200_000;
        let mut counts = [0u32; 3];
        for _ in 0..n {
            let ls = lights.sample(p, rng.next_f32(), rng.next_2d()).unwrap();
            counts[ls.sphere.unwrap_or(2)] += 1;
        }
        for (i, &c) in counts.iter().enumerate() {
            let q = lights.selection_probability(p, i) as f64;
            let z = (c as f64 - n as f64 * q) / (n as f64 * q * (1.0 - q)).sqrt();
            assert!(
                z.abs() < 5.0,
                "strategy {i}: {c} picks, expected {}",
                n as f64 * q
            );
        }
        // The bright sphere (100 x 0.0314 sr) outweighs the dim environment (0.05 x 4 pi).
        assert!(lights.selection_probability(p, 0) > lights.selection_probability(p, 2));
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
