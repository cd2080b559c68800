//! The path integrators: `uniform` (phase sampling only) and `nee` (next-event estimation with
//! multiple importance sampling against phase sampling, power heuristic).
//!
//! Path length is the number of real scattering vertices (docs/architecture.md, Path length): a camera ray that leaves
//! the volume has length 0; NEE from the n-th vertex, and a phase-sampled ray from it that reaches
//! an emitter, both make paths of length n. With `max_depth = D`, vertices 1..=D are created and
//! may connect to emitters; a collision that would create vertex D+1 ends the path. Both
//! integrators estimate exactly this truncated sum, so they converge to the same image.
//!
//! Russian roulette at volume vertices from `rr_start_depth` on: continue with probability
//! `max(throughput)`, dividing the throughput by it.

use crate::cache::{ControlVariate, PathHooks, Vertex};
use crate::lights::Lights;
use crate::medium::Medium;
use crate::phase::Phase;
use crate::sampling::{SampleStream, power_heuristic};
use crate::tracking::{Collision, free_flight, transmittance};
use glam::Vec3;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum IntegratorKind {
    /// Phase-function sampling only: emitters are found by chance.
    Uniform,
    /// Light sampling and phase sampling combined by MIS.
    #[default]
    Nee,
}

impl std::fmt::Display for IntegratorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            IntegratorKind::Uniform => "uniform",
            IntegratorKind::Nee => "nee",
        })
    }
}

/// Settings of one path: which estimator, how long, when roulette starts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSettings {
    pub integrator: IntegratorKind,
    /// Largest number of real scattering vertices; None is unlimited (roulette ends paths).
    pub max_depth: Option<u32>,
    /// First vertex at which Russian roulette may end a path.
    pub rr_start_depth: u32,
    /// Whether camera rays see the light spheres (they light the volume either way). A
    /// scientific view usually hides them (`show_lights = false` in the scene's `[render]`).
    pub show_lights: bool,
}

impl Default for PathSettings {
    fn default() -> Self {
        Self {
            integrator: IntegratorKind::Nee,
            max_depth: Some(64),
            rr_start_depth: 3,
            show_lights: true,
        }
    }
}

/// What light transport sees: medium, phase function and emitters.
#[derive(Debug, Clone)]
pub struct SceneMedia {
    pub medium: Medium,
    pub phase: Phase,
    pub lights: Lights,
}

/// Where a camera path first scattered: what the feature buffers record (see
/// [`crate::film::ExactFeatures`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirstEvent {
    /// World distance along the camera ray.
    pub distance: f32,
    /// World position.
    pub position: Vec3,
    /// Transfer-function colour times single-scattering albedo there.
    pub albedo: Vec3,
}

/// What the camera ray met first: a real scattering event, or an emitter (a light or the
/// environment) it reached without one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FirstHit {
    Scattered(FirstEvent),
    /// The radiance of the emitter the camera ray reached, seen through the volume unscattered.
    Emitter(Vec3),
}

/// One path's estimate and what its camera ray met first (`None` only for a path ended by
/// cancellation of the hooks before either, which the integrator never does today).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSample {
    pub radiance: Vec3,
    pub first_hit: Option<FirstHit>,
}

/// Radiance arriving at `origin` from direction `-dir` (`dir` is the unit direction of the ray
/// leaving the camera), one path.
pub fn radiance(
    scene: &SceneMedia,
    settings: &PathSettings,
    origin: Vec3,
    dir: Vec3,
    rng: &mut SampleStream,
) -> Vec3 {
    radiance_with(scene, settings, origin, dir, rng, &mut ()).radiance
}

/// [`radiance`] with a radiance cache's hooks: the path tells `hooks` every vertex, re-weighting
/// and radiance it adds, stops into the cache where it is told to, and reads it when it leaves
/// the volume (the GSCache estimator is written out in the gs-cache crate docs). With the no-op
/// hooks `()` this is exactly [`radiance`], random numbers included. The first scattering
/// event is reported for the feature buffers; recording it draws no random numbers.
pub fn radiance_with<H: PathHooks>(
    scene: &SceneMedia,
    settings: &PathSettings,
    origin: Vec3,
    dir: Vec3,
    rng: &mut SampleStream,
    hooks: &mut H,
) -> PathSample {
    let SceneMedia {
        medium,
        phase,
        lights,
    } = scene;
    let nee = settings.integrator == IntegratorKind::Nee;
    let max_depth = settings.max_depth.unwrap_or(u32::MAX);
    let mut l = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    let mut depth = 0u32;
    let (mut o, mut d) = (origin, dir);
    let mut phase_pdf = 0.0f32;
    let mut first_hit = None;
    loop {
        // A camera ray passes through hidden light spheres (and sees what lies behind them).
        let hit = if depth == 0 && !settings.show_lights {
            None
        } else {
            lights.nearest(o, d, 0.0)
        };
        let t_end = hit.map_or(f32::INFINITY, |h| h.1);
        let ray = medium.to_index_ray(o, d);
        let Some(Collision { t, value }) = free_flight(medium, &ray, 0.0, t_end, rng) else {
            // The ray reached a light sphere or the environment.
            let em = lights.emission(o, hit.map(|h| h.0));
            if depth == 0 {
                first_hit = Some(FirstHit::Emitter(em.radiance));
            }
            let w = if depth == 0 || !nee {
                1.0
            } else {
                power_heuristic(phase_pdf, em.nee_pdf)
            };
            let x = em.radiance * w;
            l += beta * x;
            hooks.radiance(x);
            let cached = hooks.escaped(l);
            if cached != Vec3::ZERO {
                l += beta * cached;
            }
            break;
        };
        if depth == 0 {
            first_hit = Some(FirstHit::Scattered(FirstEvent {
                distance: t,
                position: o + d * t,
                albedo: medium.albedo_with(value, ray.at(t)),
            }));
        }
        if depth >= max_depth {
            break;
        }
        let x = o + d * t;
        let tf = medium.transfer_function();
        let albedo = medium.albedo_with(value, ray.at(t));
        beta *= albedo;
        depth += 1;
        if !(beta.max_element() > 0.0) {
            break;
        }
        hooks.vertex(&Vertex {
            position: x,
            direction: d,
            albedo,
            value: tf.normalise(value),
        });
        let q = hooks.continue_probability();
        if q < 1.0 && rng.next_f32() >= q {
            l += beta * hooks.stop_into_cache();
            break;
        }

        if nee && let Some(ls) = lights.sample(x, rng.next_f32(), rng.next_2d()) {
            // The sampled emitter must be the first one along the shadow ray.
            let blocker = lights.nearest(x, ls.direction, 0.0);
            if lights.unblocked(&ls, blocker) && ls.pdf > 0.0 {
                let f = phase.eval(d, ls.direction);
                let shadow = medium.to_index_ray(x, ls.direction);
                let tr = transmittance(medium, &shadow, 0.0, ls.distance, rng);
                if tr > 0.0 {
                    // A delta light has no other strategy to share the weight with.
                    let w = if ls.delta {
                        1.0
                    } else {
                        power_heuristic(ls.pdf, f)
                    };
                    let x = ls.radiance * (f * tr * w / ls.pdf);
                    l += beta * x;
                    hooks.radiance(x);
                }
            }
        }

        // An unbiased cache's control variate (the gs-cache crate docs), after the vertex's
        // next-event estimation: the cache stands for what the path gathers from its next
        // direction on. The cache has made the decision and kept its own books; the path only
        // applies it.
        match hooks.control_variate(rng.draws()) {
            Some(ControlVariate::Stop { cached }) => {
                l += beta * cached;
                break;
            }
            Some(ControlVariate::GoOn { cached, q }) => {
                l += beta * (cached - cached / q);
                beta /= q;
            }
            None => {}
        }

        if depth >= settings.rr_start_depth {
            let survive = beta.max_element().min(1.0);
            if rng.next_f32() >= survive {
                break;
            }
            beta /= survive;
            hooks.scale(Vec3::splat(1.0 / survive));
        }

        let (d_new, pdf) = phase.sample(d, rng.next_2d());
        o = x;
        d = d_new;
        phase_pdf = pdf;
    }
    hooks.finished(rng.draws());
    PathSample {
        radiance: l,
        first_hit,
    }
}
