//! Fly-throughs: F frames (after W warm-up frames) along an orbit, a key-framed path or with a
//! still camera, with scene edits at given frames. A frame is one pass of 1 spp, or with
//! `frame_seconds` as many passes as its time budget holds (a cache's lookup and training
//! charged to it, as a user in motion pays them). Every frame's time is recorded (tracing,
//! splatting, training); every `error_every` frames, and on the frames around an edit, the
//! frame's own image is compared with a reference of that view and scene state. With a still
//! camera and an edit this is the adaptation curve: how many frames the cache takes to learn
//! the new scene.

use super::config::{EventDesc, FlythroughDesc, MethodSpec};
use super::measure::method_session;
use super::reference::reference;
use crate::camera_path::{keyframed, orbit};
use crate::error::{Result, Within, refuse};
use glam::Vec3;
use image_metrics::rel_mse;
use render_session::{Accumulation, Control, Edit};
use std::path::Path;
use volume_pt::{Scene, load_scene};

/// One frame of one method.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct FrameRecord {
    pub flythrough: String,
    pub method: String,
    pub frame: u32,
    pub warmup: bool,
    /// Passes of 1 spp the frame holds (1 without a time budget).
    #[serde(default = "one_pass")]
    pub passes: u32,
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

fn one_pass() -> u32 {
    1
}

/// The session edit `event` makes to `scene`, and a description of it for the reference key
/// and the report.
pub fn event_edit(scene: &Scene, event: &EventDesc) -> Result<(Edit, String)> {
    let lights = &scene.media.lights;
    if let Some(o) = event.light_offset {
        let o = Vec3::from_array(o);
        let mut moved = lights.clone();
        moved.lights.iter_mut().for_each(|l| l.translate(o));
        return Ok((Edit::Lights(moved), format!("lights moved by {o}")));
    }
    if let Some(s) = event.light_scale {
        let mut scaled = lights.clone();
        scaled.lights.iter_mut().for_each(|l| l.scale(s));
        scaled.environment *= s;
        return Ok((Edit::Lights(scaled), format!("lights x{s}")));
    }
    if let Some(s) = event.density_scale {
        let tf = scene.media.medium.transfer_function();
        let edited = tf.with_density_scale(tf.density_scale() * s)?;
        return Ok((Edit::TransferFunction(edited), format!("density x{s}")));
    }
    if let Some(path) = &event.scene {
        let other = load_scene(path)?;
        let edit = Edit::Volume {
            media: Box::new(other.media),
            path: other.volume_path,
        };
        return Ok((edit, format!("scene {}", path.display())));
    }
    refuse!("event at frame {} changes nothing", event.frame)
}

/// Flies `fly` with each method (one seed), returning every frame's record.
pub fn fly(
    scene: &Scene,
    scene_file: &Path,
    fly: &FlythroughDesc,
    methods: &[&MethodSpec],
    seed: u64,
    reference_dir: &Path,
    progress: &dyn Fn(&str),
) -> Result<Vec<FrameRecord>> {
    let (lo, hi) = scene.media.medium.bounds();
    let centre = 0.5 * (lo + hi);
    let total = fly.warmup + fly.frames;
    let mut out = Vec::new();
    for method in methods {
        // Each frame is an image of its own: an interactive view in motion. With a budget, a
        // frame's passes are averaged (the image is emptied at each frame).
        let accumulation = match fly.frame_seconds {
            Some(_) => Accumulation::Progressive,
            None => Accumulation::PerFrame,
        };
        let mut session = method_session(scene, method, seed)?.with_accumulation(accumulation);
        let mut state = String::new();
        let edit_frames: Vec<u32> = fly.events.iter().map(|e| e.frame).collect();
        for f in 0..total {
            for e in fly.events.iter().filter(|e| e.frame == f) {
                let (edit, what) = event_edit(session.scene(), e)
                    .within(|| format!("flythrough `{}`", fly.name))?;
                session.edit(edit)?;
                state.push_str(&format!("{f}:{what};"));
            }
            let cam = if fly.keys.is_empty() {
                orbit(&scene.camera, centre, fly.orbit_degrees, f, total)
            } else {
                keyframed(&scene.camera, &fly.keys, f)
                    .within(|| format!("flythrough `{}`", fly.name))?
            };
            session.edit(Edit::Camera(cam))?;
            let pass = frame_passes(&mut session, fly.frame_seconds)?;
            let (mut trace, splat, train) = (pass.trace, pass.splat, pass.train);
            let total_s = pass.seconds;
            if !method.has_cache() {
                trace = total_s;
            }
            let level_mse = pass.level_mse;
            // Evaluated: every `error_every` frames, the last, and the few frames right after
            // an edit (where the curve moves fastest).
            let near_edit = edit_frames.iter().any(|&e| f >= e && f < e + 4);
            let evaluate = f % fly.error_every == 0 || f + 1 == total || near_edit;
            let rel = if evaluate {
                // The reference is the scene as edited, rendered with the scene file's own
                // settings (not the method's), so every method shares it.
                let mut edited = session.scene().clone();
                edited.settings = scene.settings;
                let r = reference(
                    reference_dir,
                    scene_file,
                    &state,
                    &edited,
                    &cam,
                    fly.reference_spp,
                    None,
                )?;
                if !r.reused {
                    progress(&format!(
                        "flythrough `{}`: reference of frame {f} ({} spp, {:.1} s)",
                        fly.name, r.spp, r.seconds
                    ));
                }
                Some(rel_mse(&session.mean(), &r.image))
            } else {
                None
            };
            out.push(FrameRecord {
                flythrough: fly.name.clone(),
                method: method.name.clone(),
                frame: f,
                warmup: f < fly.warmup,
                passes: pass.passes,
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

/// What one fly-through frame's passes took.
struct FramePasses {
    passes: u32,
    trace: f64,
    splat: f64,
    train: f64,
    seconds: f64,
    /// The last pass's per-level training loss.
    level_mse: Vec<Option<f64>>,
}

/// Renders one frame: one pass, or with `budget` passes into an emptied image while the next
/// (taken to cost what the passes so far cost on average, by the wall clock) fits in it. Its
/// `seconds` are the passes' own (the frame reports'), as a frame without a budget records.
fn frame_passes(session: &mut render_session::Session, budget: Option<f64>) -> Result<FramePasses> {
    if budget.is_some() {
        session.clear_image();
    }
    let start = std::time::Instant::now();
    let mut out = FramePasses {
        passes: 0,
        trace: 0.0,
        splat: 0.0,
        train: 0.0,
        seconds: 0.0,
        level_mse: Vec::new(),
    };
    loop {
        let r = session.next_frame(&Control::none())?;
        out.passes += 1;
        out.trace += r.trace_seconds;
        out.splat += r.lookup_seconds;
        out.train += r.train_seconds;
        out.seconds += r.seconds;
        out.level_mse = r.loss;
        let spent = start.elapsed().as_secs_f64();
        let next = spent / f64::from(out.passes);
        match budget {
            Some(b) if spent + next <= b => {}
            _ => return Ok(out),
        }
    }
}
