//! Phase functions. Directions are propagation directions: `d_in` is where the light travelled
//! before the scattering event, `d_out` where it travels after; the angle between them is the
//! scattering angle, so `g > 0` scatters forwards.

use crate::sampling::{UNIFORM_SPHERE_PDF, direction_around, uniform_sphere};
use glam::Vec3;
use std::f32::consts::PI;

#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Phase {
    #[default]
    Isotropic,
    /// Henyey-Greenstein with mean cosine `g` in (-1, 1).
    #[serde(alias = "hg")]
    HenyeyGreenstein { g: f32 },
}

/// Below this |g| Henyey-Greenstein is sampled as isotropic (its inversion loses precision).
const HG_ISOTROPIC_EPS: f32 = 1e-3;

impl Phase {
    /// Checks `g` is usable: finite and within (-0.99, 0.99).
    pub fn validate(&self) -> Result<(), String> {
        match *self {
            Phase::Isotropic => Ok(()),
            Phase::HenyeyGreenstein { g } if g.abs() <= 0.99 => Ok(()),
            Phase::HenyeyGreenstein { g } => Err(format!(
                "Henyey-Greenstein g = {g} is invalid: expected a value in [-0.99, 0.99]"
            )),
        }
    }

    /// Value (= pdf, both phase functions are sampled exactly) for the pair of directions.
    #[inline]
    pub fn eval(&self, d_in: Vec3, d_out: Vec3) -> f32 {
        match *self {
            Phase::Isotropic => UNIFORM_SPHERE_PDF,
            Phase::HenyeyGreenstein { g } => {
                let cos = d_in.dot(d_out);
                let denom = (1.0 + g * g - 2.0 * g * cos).max(1e-12);
                (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
            }
        }
    }

    /// Samples `d_out` proportionally to the phase function; the weight value/pdf is exactly 1.
    #[inline]
    pub fn sample(&self, d_in: Vec3, u: (f32, f32)) -> (Vec3, f32) {
        match *self {
            Phase::Isotropic => (uniform_sphere(u), UNIFORM_SPHERE_PDF),
            Phase::HenyeyGreenstein { g } => {
                let cos = if g.abs() < HG_ISOTROPIC_EPS {
                    1.0 - 2.0 * u.0
                } else {
                    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.0);
                    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
                };
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let d = direction_around(d_in, cos, sin, 2.0 * PI * u.1);
                (d, self.eval(d_in, d))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::SampleStream;

    #[test]
    fn hg_integrates_to_one_and_has_mean_cosine_g() {
        for &g in &[-0.7f32, 0.0, 0.3, 0.9] {
            let p = Phase::HenyeyGreenstein { g };
            // Midpoint rule over cos in [-1, 1]: integral of 2 pi p(cos) dcos.
            let n = 200_000;
            let (mut total, mut mean) = (0.0f64, 0.0f64);
            for i in 0..n {
                let c = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
                let d = Vec3::new((1.0 - c * c).sqrt() as f32, 0.0, c as f32);
                let v = p.eval(Vec3::Z, d) as f64 * 2.0 * std::f64::consts::PI * 2.0 / n as f64;
                total += v;
                mean += v * c;
            }
            assert!((total - 1.0).abs() < 1e-3, "g={g}: {total}");
            assert!((mean - g as f64).abs() < 1e-3, "g={g}: {mean}");
        }
    }

    #[test]
    fn hg_sampling_matches_its_mean_cosine() {
        // Sample mean of cos over 200k draws; its standard error is below 0.0015, the bound is 4
        // standard errors (false-alarm rate about 6e-5).
        for &g in &[-0.5f32, 0.0005, 0.6] {
            let p = Phase::HenyeyGreenstein { g };
            let d_in = Vec3::new(0.3, -0.5, 0.8).normalize();
            let mut s = SampleStream::new(3, 0, 0);
            let n = 200_000;
            let mut mean = 0.0f64;
            for _ in 0..n {
                let (d, pdf) = p.sample(d_in, s.next_2d());
                assert!((pdf - p.eval(d_in, d)).abs() <= 1e-4 * pdf);
                mean += d.dot(d_in) as f64;
            }
            mean /= n as f64;
            assert!((mean - g as f64).abs() < 0.006, "g={g}: {mean}");
        }
    }
}
