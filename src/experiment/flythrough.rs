//! Fly-throughs: F frames (after W warm-up frames) of 1 spp each along an orbit, a key-framed
//! path or with a still camera, with scene edits at given frames. Every frame's time is recorded (tracing, splatting,
//! training); every `error_every` frames, and on the frames around an edit, the frame's own
//! image is compared with a reference of that view and scene state. With a still camera and an
//! edit this is the adaptation curve: how many frames the cache takes to learn the new scene.

use super::config::{EventDesc, FlythroughDesc, Method};
use super::measure::{new_cache, new_nrc, nrc_loss, pass_seed};
use super::reference::reference;
use crate::camera_path::{keyframed, orbit};
use crate::metrics::rel_mse;
use anyhow::{Context, Result};
use cached_pt::nrc::render_nrc_frame;
use cached_pt::render_cached_frame;
use glam::Vec3;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use volume_pt::{Film, Scene, load_scene, render};

/// One frame of one method.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct FrameRecord {
    pub flythrough: String,
    pub method: String,
    pub frame: u32,
    pub warmup: bool,
    pub trace_ms: f64,
    pub splat_ms: f64,
    pub train_ms: f64,
    /// Wall-clock time of the whole frame.
    pub total_ms: f64,
    /// relMSE of this frame's 1-spp image, on evaluated frames.
    pub rel_mse: Option<f64>,
    /// Per cache level: MSE against the frame's samples before the step.
    pub level_mse: Vec<Option<f64>>,
}

/// Applies `event` to `scene`; returns a description for the reference key and the report.
pub fn apply_event(scene: &mut Scene, event: &EventDesc) -> Result<String> {
    let lights = &mut scene.media.lights;
    if let Some(o) = event.light_offset {
        let o = Vec3::from_array(o);
        lights.spheres.iter_mut().for_each(|l| l.center += o);
        return Ok(format!("lights moved by {o}"));
    }
    if let Some(s) = event.light_scale {
        lights.spheres.iter_mut().for_each(|l| l.radiance *= s);
        lights.environment *= s;
        return Ok(format!("lights x{s}"));
    }
    if let Some(s) = event.density_scale {
        let tf = scene.media.medium.transfer_function();
        let edited = tf.with_density_scale(tf.density_scale() * s)?;
        scene.media.medium.set_transfer_function(edited);
        return Ok(format!("density x{s}"));
    }
    if let Some(path) = &event.scene {
        let other = load_scene(path)?;
        scene.media = other.media;
        scene.volume_path = other.volume_path;
        return Ok(format!("scene {}", path.display()));
    }
    anyhow::bail!("event at frame {} changes nothing", event.frame)
}

/// Flies `fly` with each method (one seed), returning every frame's record.
pub fn fly(
    scene: &Scene,
    scene_file: &Path,
    fly: &FlythroughDesc,
    methods: &[&Method],
    seed: u64,
    reference_dir: &Path,
    progress: &dyn Fn(&str),
) -> Result<Vec<FrameRecord>> {
    let (lo, hi) = scene.media.medium.bounds();
    let centre = 0.5 * (lo + hi);
    let total = fly.warmup + fly.frames;
    let mut out = Vec::new();
    let cancel = AtomicBool::new(false);
    for method in methods {
        let mut scene = scene.clone();
        let mut state = String::new();
        let mut settings = scene.settings;
        settings.spp = 1;
        settings.seed = seed;
        settings.path.integrator = method.integrator;
        let mut cache = match &method.cache {
            Some(desc) => Some(new_cache(&scene, desc.config()?, seed)?.0),
            None => None,
        };
        let mut nrc = match &method.nrc {
            Some(desc) => Some(new_nrc(desc.config()?, seed)?.0),
            None => None,
        };
        let edit_frames: Vec<u32> = fly.events.iter().map(|e| e.frame).collect();
        for f in 0..total {
            for e in fly.events.iter().filter(|e| e.frame == f) {
                let what = apply_event(&mut scene, e)
                    .with_context(|| format!("flythrough `{}`", fly.name))?;
                state.push_str(&format!("{f}:{what};"));
                if let Some(c) = &mut cache {
                    c.reset_schedule();
                }
            }
            let cam = if fly.keys.is_empty() {
                orbit(&scene.camera, centre, fly.orbit_degrees, f, total)
            } else {
                keyframed(&scene.camera, &fly.keys, f)
                    .with_context(|| format!("flythrough `{}`", fly.name))?
            };
            let mut film = Film::new(cam.width, cam.height);
            let start = Instant::now();
            let (mut trace, mut splat, mut train, mut level_mse) = (0.0, 0.0, 0.0, Vec::new());
            match (&mut cache, &mut nrc) {
                (None, Some(n)) => {
                    let s = render_nrc_frame(
                        &scene.media,
                        &cam,
                        &settings,
                        f,
                        Some(&mut film),
                        n,
                        &cancel,
                    );
                    (trace, splat, train) = (s.trace_seconds, s.inference_seconds, s.train_seconds);
                    level_mse = vec![nrc_loss(&s)];
                }
                (None, None) => {
                    let s = volume_pt::RenderSettings {
                        seed: pass_seed(seed, f as u64),
                        ..settings
                    };
                    render(&scene.media, &cam, &s, &mut film, &cancel, &|_| {});
                }
                (Some(c), _) => {
                    let s = render_cached_frame(
                        &scene.media,
                        &cam,
                        &settings,
                        f,
                        Some(&mut film),
                        c,
                        &cancel,
                    )?;
                    (trace, splat, train) = (s.trace_seconds, s.lookup_seconds, s.train_seconds);
                    level_mse = c.report().mse.clone();
                }
            }
            let total_s = start.elapsed().as_secs_f64();
            if !method.has_cache() {
                trace = total_s;
            }
            // Evaluated: every `error_every` frames, the last, and the few frames right after
            // an edit (where the curve moves fastest).
            let near_edit = edit_frames.iter().any(|&e| f >= e && f < e + 4);
            let evaluate = f % fly.error_every == 0 || f + 1 == total || near_edit;
            let rel = if evaluate {
                let r = reference(
                    reference_dir,
                    scene_file,
                    &state,
                    &scene,
                    &cam,
                    fly.reference_spp,
                )?;
                if !r.reused {
                    progress(&format!(
                        "flythrough `{}`: reference of frame {f} ({} spp, {:.1} s)",
                        fly.name, r.spp, r.seconds
                    ));
                }
                Some(rel_mse(&film.mean(), &r.image))
            } else {
                None
            };
            out.push(FrameRecord {
                flythrough: fly.name.clone(),
                method: method.name.clone(),
                frame: f,
                warmup: f < fly.warmup,
                trace_ms: trace * 1e3,
                splat_ms: splat * 1e3,
                train_ms: train * 1e3,
                total_ms: total_s * 1e3,
                rel_mse: rel,
                level_mse,
            });
        }
        progress(&format!("flythrough `{}`: {} done", fly.name, method.name));
    }
    Ok(out)
}
