//! Emitters: the light types a scene's `[[light]]` tables name, and the constant environment.
//!
//! - [`SphereLight`] (`type = "sphere"`, the default): an opaque sphere of constant radiance,
//!   sampled by solid angle.
//! - [`DistantLight`] (`type = "distant"`): parallel light from one direction, a delta light.
//! - The environment: constant radiance from every direction no light sphere blocks.
//!
//! [`Light`] is the one type the renderer sees: selection weight, sampling, pdf, intersection
//! and validation live in it, each arm delegating to its type. A new light type is a file here,
//! a variant of [`Light`] and its arms: nothing outside this module changes.
//!
//! Next-event estimation picks among the lights and the environment in proportion to the
//! unoccluded power each sends to the point ([`Lights::selection_probability`]).

mod distant;
mod sphere;

pub use distant::DistantLight;
pub use sphere::SphereLight;

use crate::sampling::{UNIFORM_SPHERE_PDF, uniform_sphere};
use glam::Vec3;

pub use render_base::MAX_COORDINATE;

/// Checks an RGB quantity: finite and >= 0 in every channel.
fn check_rgb(name: &str, c: Vec3) -> Result<(), String> {
    if !(c.is_finite() && c.min_element() >= 0.0) {
        return Err(format!("{name} {c} invalid: expected finite values >= 0"));
    }
    Ok(())
}

/// Rec. 709 luminance: the weight of a radiance in light selection.
#[inline]
fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// A direction towards an emitter, with what NEE needs to use it.
#[derive(Debug, Clone, Copy)]
pub struct LightSample {
    pub direction: Vec3,
    /// Distance to the emitting surface (infinite for the environment and a distant light).
    pub distance: f32,
    /// Radiance arriving along the direction (for a delta light: its irradiance).
    pub radiance: Vec3,
    /// Solid-angle pdf of the direction (selection included once returned by
    /// [`Lights::sample`]); for a delta light, the delta's weight (1, times the selection).
    pub pdf: f32,
    /// A delta light: no other strategy can find it, so MIS gives this sample all the weight.
    pub delta: bool,
    /// The light sampled (its index in [`Lights::lights`]), or None for the environment.
    pub light: Option<usize>,
}

/// One emitter of a scene.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Light {
    Sphere(SphereLight),
    Distant(DistantLight),
}

impl Light {
    /// Its weight in NEE's choice at `p`: the unoccluded power it sends there, up to a factor
    /// common to every light.
    #[inline]
    fn selection_weight(&self, p: Vec3) -> f32 {
        match self {
            Light::Sphere(s) => s.selection_weight(p),
            Light::Distant(d) => d.selection_weight(),
        }
    }

    /// A direction towards it from `p` (None where it cannot light `p`, as from inside a
    /// sphere).
    #[inline]
    fn sample(&self, p: Vec3, u: (f32, f32)) -> Option<LightSample> {
        match self {
            Light::Sphere(s) => s.sample(p, u),
            Light::Distant(d) => Some(d.sample()),
        }
    }

    /// Solid-angle pdf with which [`Light::sample`] gives a direction from `p` that reaches it
    /// (0 for a delta light, which no ray reaches).
    #[inline]
    fn pdf(&self, p: Vec3) -> f32 {
        match self {
            Light::Sphere(s) => s.pdf(p),
            Light::Distant(_) => 0.0,
        }
    }

    /// Distance from `o` along unit `d` to where the ray meets it after `t_min`, for lights a
    /// ray can meet (a distant light is at infinity and meets none).
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, t_min: f32) -> Option<f32> {
        match self {
            Light::Sphere(s) => s.intersect(o, d, t_min),
            Light::Distant(_) => None,
        }
    }

    /// The radiance a ray that reaches it sees.
    #[inline]
    fn radiance(&self) -> Vec3 {
        match self {
            Light::Sphere(s) => s.radiance,
            Light::Distant(d) => d.irradiance,
        }
    }

    /// Checks it (and normalises what needs it) for a scene; the message names the fault and
    /// what was expected.
    pub fn validate(&mut self) -> Result<(), String> {
        match self {
            Light::Sphere(s) => s.validate(),
            Light::Distant(d) => d.validate(),
        }
    }

    /// Moves it by `offset` (a distant light, at infinity, does not move).
    pub fn translate(&mut self, offset: Vec3) {
        if let Light::Sphere(s) = self {
            s.center += offset;
        }
    }

    /// Scales its emission by `factor`.
    pub fn scale(&mut self, factor: f32) {
        match self {
            Light::Sphere(s) => s.radiance *= factor,
            Light::Distant(d) => d.irradiance *= factor,
        }
    }
}

/// Every emitter of a scene.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Lights {
    pub lights: Vec<Light>,
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

    /// Number of strategies NEE chooses among (the lights, plus the environment if it emits).
    pub fn count(&self) -> usize {
        self.lights.len() + self.has_environment() as usize
    }

    /// The nearest light a ray meets after `t_min`: (index, distance).
    #[inline]
    pub fn nearest(&self, o: Vec3, d: Vec3, t_min: f32) -> Option<(usize, f32)> {
        let mut best: Option<(usize, f32)> = None;
        for (i, l) in self.lights.iter().enumerate() {
            if let Some(t) = l.intersect(o, d, t_min)
                && best.is_none_or(|b| t < b.1)
            {
                best = Some((i, t));
            }
        }
        best
    }

    /// The environment's selection weight, on the lights' scale: luminance times 4 pi.
    fn environment_weight(&self) -> f32 {
        if self.has_environment() {
            luminance(self.environment) * 2.0 * std::f32::consts::TAU
        } else {
            0.0
        }
    }

    /// The weight of strategy `light` (a light's index, or None for the environment).
    #[inline]
    fn weight(&self, p: Vec3, light: Option<usize>) -> f32 {
        match light {
            Some(i) => self.lights[i].selection_weight(p),
            None => self.environment_weight(),
        }
    }

    /// The strategies in order: each light, then the environment if it emits.
    fn strategies(&self) -> impl Iterator<Item = Option<usize>> + '_ {
        (0..self.lights.len())
            .map(Some)
            .chain(self.has_environment().then_some(None))
    }

    /// The probability that NEE at `p` picks strategy `light` (a light's index, or None for
    /// the environment): proportional to the unoccluded power each sends to `p`, so the bright,
    /// near and large lights get the samples (uniform selection spends a third of them on a dim
    /// environment in the bundled scenes). Falls back to uniform when every weight is 0 or not
    /// finite, so no light that can contribute is ever left out.
    #[inline]
    pub fn selection_probability(&self, p: Vec3, light: Option<usize>) -> f32 {
        let total = self.total_weight(p);
        let n = self.count();
        if !(total > 0.0 && total.is_finite()) {
            return 1.0 / n.max(1) as f32;
        }
        self.weight(p, light) / total
    }

    #[inline]
    fn total_weight(&self, p: Vec3) -> f32 {
        self.lights
            .iter()
            .map(|l| l.selection_weight(p))
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
        let (chosen, pick) = if total > 0.0 && total.is_finite() {
            // Walk the cumulative weights; the last strategy with weight takes any rounding.
            let target = u_pick * total;
            let mut acc = 0.0f32;
            let mut chosen = None;
            for k in self.strategies() {
                let w = self.weight(p, k);
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
            (self.strategies().nth(k)?, 1.0 / n as f32)
        };
        let mut s = match chosen {
            Some(i) => LightSample {
                light: Some(i),
                ..self.lights[i].sample(p, u)?
            },
            None => LightSample {
                direction: uniform_sphere(u),
                distance: f32::INFINITY,
                radiance: self.environment,
                pdf: UNIFORM_SPHERE_PDF,
                delta: false,
                light: None,
            },
        };
        s.pdf *= pick;
        Some(s)
    }

    /// Whether a shadow ray towards sample `s` whose first light met is `blocker` (from
    /// [`Lights::nearest`]) reaches the emitter sampled: a light a ray can meet must be the
    /// first one; one at infinity (the environment, a distant light) must meet none.
    #[inline]
    pub fn unblocked(&self, s: &LightSample, blocker: Option<(usize, f32)>) -> bool {
        match (s.light.filter(|&i| self.lights[i].is_reachable()), blocker) {
            (Some(i), Some((j, _))) => i == j,
            (Some(_), None) => false,
            (None, blocker) => blocker.is_none(),
        }
    }

    /// Emission seen along a ray from `p` that reached light `hit` (or escaped to the
    /// environment when `hit` is None), with the NEE pdf for MIS.
    #[inline]
    pub fn emission(&self, p: Vec3, hit: Option<usize>) -> Emission {
        match hit {
            Some(i) => {
                let l = &self.lights[i];
                Emission {
                    radiance: l.radiance(),
                    nee_pdf: l.pdf(p) * self.selection_probability(p, Some(i)),
                }
            }
            None => Emission {
                radiance: self.environment,
                nee_pdf: if self.has_environment() {
                    UNIFORM_SPHERE_PDF * self.selection_probability(p, None)
                } else {
                    0.0
                },
            },
        }
    }
}

impl Light {
    /// Whether a ray can meet it (a sphere), rather than it lying at infinity.
    #[inline]
    fn is_reachable(&self) -> bool {
        matches!(self, Light::Sphere(_))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::SampleStream;

    /// The pdf a light sample reports is the one `emission` gives for the same direction from
    /// the same point (MIS needs both), the selection probabilities sum to 1, and a light that
    /// sends more power to a point is picked more often, in proportion.
    #[test]
    fn selection_is_consistent_and_follows_power() {
        let lights = Lights {
            lights: vec![
                Light::Sphere(SphereLight {
                    center: Vec3::new(10.0, 0.0, 0.0),
                    radius: 1.0,
                    radiance: Vec3::splat(100.0),
                }),
                Light::Sphere(SphereLight {
                    center: Vec3::new(0.0, -20.0, 3.0),
                    radius: 4.0,
                    radiance: Vec3::new(0.5, 1.0, 3.0),
                }),
                Light::Distant(DistantLight {
                    direction: Vec3::new(0.0, -1.0, 0.0),
                    irradiance: Vec3::new(0.3, 0.3, 0.2),
                }),
            ],
            environment: Vec3::splat(0.05),
        };
        let strategies = [Some(0), Some(1), Some(2), None];
        let mut rng = SampleStream::new(4, 0, 0);
        for k in 0..200 {
            let p = Vec3::new(k as f32 * 0.05 - 5.0, (k % 7) as f32, (k % 3) as f32 - 1.0);
            let total: f32 = strategies
                .iter()
                .map(|&s| lights.selection_probability(p, s))
                .sum();
            assert!((total - 1.0).abs() < 1e-5, "{total}");
            let ls = lights.sample(p, rng.next_f32(), rng.next_2d()).unwrap();
            if ls.delta {
                // Nothing meets a delta light: its pdf is the selection's alone.
                let q = lights.selection_probability(p, ls.light);
                assert_eq!(ls.pdf, q);
                continue;
            }
            let em = lights.emission(p, ls.light);
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
        let mut counts = [0u32; 4];
        for _ in 0..n {
            let ls = lights.sample(p, rng.next_f32(), rng.next_2d()).unwrap();
            counts[ls.light.unwrap_or(3)] += 1;
        }
        for (i, &c) in counts.iter().enumerate() {
            let q = lights.selection_probability(p, strategies[i]) as f64;
            let z = (c as f64 - n as f64 * q) / (n as f64 * q * (1.0 - q)).sqrt();
            assert!(
                z.abs() < 5.0,
                "strategy {i}: {c} picks, expected {}",
                n as f64 * q
            );
        }
        // The bright sphere (100 x 0.0314 sr) outweighs the dim environment (0.05 x 4 pi).
        assert!(lights.selection_probability(p, Some(0)) > lights.selection_probability(p, None));
    }

    /// A distant light is sampled from its one direction with the delta's weight, is never met
    /// by a ray, and is shadowed by a sphere in front of it (but not by one behind).
    #[test]
    fn a_distant_light_is_a_delta_at_infinity() {
        let sun = Light::Distant(DistantLight {
            direction: Vec3::new(0.0, 0.0, -1.0),
            irradiance: Vec3::splat(2.0),
        });
        let front = Light::Sphere(SphereLight {
            center: Vec3::new(0.0, 0.0, 5.0),
            radius: 1.0,
            radiance: Vec3::ZERO,
        });
        let lights = Lights {
            lights: vec![sun, front],
            environment: Vec3::ZERO,
        };
        let p = Vec3::ZERO;
        // Only the sun has weight (the sphere is black): it is always the pick.
        let s = lights.sample(p, 0.7, (0.3, 0.9)).unwrap();
        assert!(s.delta && s.light == Some(0) && s.direction == Vec3::Z && s.pdf == 1.0);
        assert!(sun.intersect(p, Vec3::Z, 0.0).is_none());
        let blocker = lights.nearest(p, s.direction, 0.0);
        assert_eq!(blocker.map(|b| b.0), Some(1));
        assert!(!lights.unblocked(&s, blocker));
        assert!(lights.unblocked(&s, lights.nearest(Vec3::new(0.0, 0.0, 7.0), Vec3::Z, 0.0)));
        // Validation normalises the direction and refuses a zero one.
        let mut d = DistantLight {
            direction: Vec3::new(0.0, 3.0, 4.0),
            irradiance: Vec3::ONE,
        };
        d.validate().unwrap();
        assert!((d.direction.length() - 1.0).abs() < 1e-6);
        d.direction = Vec3::ZERO;
        assert!(d.validate().unwrap_err().contains("non-zero"));
        d.direction = Vec3::X;
        d.irradiance = Vec3::new(1.0, -1.0, 0.0);
        assert!(d.validate().unwrap_err().contains("irradiance"));
    }
}
