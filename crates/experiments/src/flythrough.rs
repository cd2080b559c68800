//! Fly-throughs: F frames (after W warm-up frames) along an orbit, a key-framed path or with a
//! still camera, with scene edits at given frames. A frame is one pass of 1 spp, or with
//! `frame_seconds` as many passes as its time budget holds (a cache's lookup and training
//! charged to it, as a user in motion pays them). Every frame's time is recorded (tracing,
//! splatting, training); every `error_every` frames, and on the frames around an edit, the
//! frame's own image is compared with a reference of that view and scene state. With a still
//! camera and an edit this is the adaptation curve: how many frames the cache takes to learn
//! the new scene.
//!
//! With the experiment's denoised twins, each method flies again per guides, every frame
//! denoised and the denoiser's time charged to it (a time budget renders in what the denoiser
//! leaves). The closing `clip_frames` frames are all scored: their flicker (each frame's change
//! against the references' change) and the clip's ColorVideoVDP JOD, shown at the frame rate
//! the budget gives, say whether a method's motion is steady as well as close.

use super::config::{DenoiseSpec, EventDesc, FlythroughDesc, MethodSpec};
use super::denoised::Denoisers;
use super::measure::method_session;
use super::reference::reference;
use crate::camera_path::{keyframed, orbit};
use crate::error::{Error, Result, Within, refuse};
use denoise::Guides;
use glam::Vec3;
use hdr_image::{RgbImage, tone_map};
use image_metrics::{flicker, flip, rel_mse, video_jod};
use render_session::{Accumulation, Control, Edit, ImageBudget};
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
    /// The denoiser's time on this frame (a denoised twin's), part of `total_ms`.
    #[serde(default)]
    pub denoise_ms: f64,
    /// Wall-clock time of the whole frame.
    pub total_ms: f64,
    /// relMSE of this frame's image, on scored frames.
    pub rel_mse: Option<f64>,
    /// FLIP of this frame's tone-mapped image, on scored frames (with the `flip` feature).
    #[serde(default)]
    pub flip: Option<f64>,
    /// Flicker (image-metrics' definition) from the frame before, when both are scored.
    #[serde(default)]
    pub flicker: Option<f64>,
    /// On the last frame: ColorVideoVDP's JOD of the closing clip (`clip_frames` frames).
    #[serde(default)]
    pub jod: Option<f64>,
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
    if let Some(t) = event.time {
        let hints = volume_pt::io::ReadHints {
            zarr: volume_pt::io::ZarrSelection {
                time: t,
                ..Default::default()
            },
            ..Default::default()
        };
        let loaded = volume_pt::io::read_volume(&scene.volume_path, &hints)?;
        let mut media = scene.media.clone();
        media.medium.replace_grid(loaded.grid)?;
        let edit = Edit::Volume {
            media: Box::new(media),
            path: scene.volume_path.clone(),
        };
        return Ok((edit, format!("time {t}")));
    }
    refuse!("event at frame {} changes nothing", event.frame)
}

/// What every flight of one fly-through shares: the scene, where references are kept, the seed
/// and the experiment's denoised twins.
pub struct FlightSetup<'a> {
    pub scene: &'a Scene,
    pub scene_file: &'a Path,
    pub seed: u64,
    pub reference_dir: &'a Path,
    /// With denoised twins, each method flies once more per guides, every frame denoised.
    pub denoise: Option<&'a DenoiseSpec>,
}

/// Flies `fly` with each method (one seed), and with each method's denoised twins, returning
/// every frame's record.
pub fn fly(
    setup: &FlightSetup<'_>,
    fly: &FlythroughDesc,
    methods: &[&MethodSpec],
    denoisers: &mut Denoisers,
    progress: &dyn Fn(&str),
) -> Result<Vec<FrameRecord>> {
    let denoise = setup.denoise.map(|spec| DenoiseSpec {
        quality: fly.denoise_quality.unwrap_or(spec.quality),
        ..spec.clone()
    });
    let mut out = Vec::new();
    for method in methods {
        out.extend(flight(setup, fly, method, None, denoisers, progress)?);
        if let Some(spec) = &denoise {
            for &guides in &spec.guides {
                let twin = Some((spec, guides));
                out.extend(flight(setup, fly, method, twin, denoisers, progress)?);
            }
        }
    }
    Ok(out)
}

/// The frames of `fly` scored against references: every `error_every`, the last, the few
/// right after an edit (where an adaptation curve moves fastest) and the closing clip.
fn scored(fly: &FlythroughDesc, frame: u32) -> bool {
    let total = fly.warmup + fly.frames;
    let near_edit = fly
        .events
        .iter()
        .any(|e| frame >= e.frame && frame < e.frame + 4);
    frame.is_multiple_of(fly.error_every)
        || frame + 1 == total
        || near_edit
        || frame + fly.clip_frames >= total
}

/// A scored frame's images, kept for the next frame's flicker and the clip's JOD.
struct Scored {
    frame: u32,
    image: Vec<Vec3>,
    reference: Vec<Vec3>,
}

/// One method (or its twin denoised with the given guides) along `fly`. A twin's frame renders
/// in the frame's budget less the denoiser's measured cost (at least one pass), then is
/// denoised; the denoiser's time is the frame's too.
fn flight(
    setup: &FlightSetup<'_>,
    fly: &FlythroughDesc,
    method: &MethodSpec,
    twin: Option<(&DenoiseSpec, Guides)>,
    denoisers: &mut Denoisers,
    progress: &dyn Fn(&str),
) -> Result<Vec<FrameRecord>> {
    let scene = setup.scene;
    let (w, h) = (scene.camera.width, scene.camera.height);
    let (lo, hi) = scene.media.medium.bounds();
    let centre = 0.5 * (lo + hi);
    let total = fly.warmup + fly.frames;
    let name = match twin {
        Some((_, guides)) => method.denoised_twin(guides).name,
        None => method.name.clone(),
    };
    // What the denoiser will take of the next frame: its cost measured before the run, then
    // the mean of its actual times on this flight's frames after the first (which may rebuild
    // the filter), as an interactive application's governor would track it. The cost measured
    // on a flat image ran up to twice the actual time at OIDN's high quality.
    let mut denoise_estimate = match twin {
        Some((spec, guides)) => denoisers.cost(w, h, guides, spec)?,
        None => 0.0,
    };
    let (mut denoise_sum, mut denoise_count) = (0.0, 0u32);
    // Each frame is an image of its own: an interactive view in motion. With a budget, a
    // frame's passes are averaged (the image is emptied at each frame).
    let accumulation = match fly.frame_seconds {
        Some(_) => Accumulation::Progressive,
        None => Accumulation::PerFrame,
    };
    let wants_features = matches!(twin, Some((_, g)) if g != Guides::None);
    let mut session = method_session(scene, method, setup.seed)?
        .with_accumulation(accumulation)
        .with_features(wants_features);
    let mut state = String::new();
    let mut out = Vec::new();
    let mut last_scored: Option<Scored> = None;
    let mut clip: Vec<(Vec<u8>, Vec<u8>)> = Vec::new();
    let ldr = |img: &[Vec3]| tone_map(img, scene.output.exposure, scene.output.tonemap);
    for f in 0..total {
        for e in fly.events.iter().filter(|e| e.frame == f) {
            let (edit, what) =
                event_edit(session.scene(), e).within(|| format!("flythrough `{}`", fly.name))?;
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
        let budget = match fly.frame_seconds {
            Some(t) => ImageBudget::Seconds((t - denoise_estimate).max(0.0)),
            None => ImageBudget::Passes(1),
        };
        let image_report = session.render_image(budget, &Control::none())?;
        let pass = &image_report.report;
        let (image, denoise_seconds) = match twin {
            Some((spec, guides)) => {
                let noisy = RgbImage::from_pixels(w, h, session.mean())?;
                let features = session.feature_images();
                let (d, s) = denoisers.run(&noisy, features.as_ref(), guides, spec)?;
                (d.into_pixels(), s)
            }
            None => (session.mean(), 0.0),
        };
        if twin.is_some() && f > 0 {
            denoise_sum += denoise_seconds;
            denoise_count += 1;
            denoise_estimate = denoise_sum / f64::from(denoise_count);
        }
        let mut record = FrameRecord {
            flythrough: fly.name.clone(),
            method: name.clone(),
            frame: f,
            warmup: f < fly.warmup,
            passes: image_report.passes,
            trace_ms: if method.has_cache() {
                pass.trace_seconds
            } else {
                pass.seconds
            } * 1e3,
            splat_ms: pass.lookup_seconds * 1e3,
            train_ms: pass.train_seconds * 1e3,
            denoise_ms: denoise_seconds * 1e3,
            total_ms: (pass.seconds + denoise_seconds) * 1e3,
            rel_mse: None,
            flip: None,
            flicker: None,
            jod: None,
            level_mse: pass.loss.clone(),
        };
        if scored(fly, f) {
            // The reference is the scene as edited, rendered with the scene file's own
            // settings (not the method's), so every method shares it.
            let mut edited = session.scene().clone();
            edited.settings = scene.settings;
            let r = reference(
                setup.reference_dir,
                setup.scene_file,
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
            let (tm, tm_ref) = (ldr(&image), ldr(&r.image));
            record.rel_mse = Some(rel_mse(&image, &r.image));
            record.flip = flip(&tm, &tm_ref, w, h);
            if let Some(prev) = last_scored.as_ref().filter(|p| p.frame + 1 == f) {
                record.flicker = Some(flicker(&prev.image, &image, &prev.reference, &r.image));
            }
            if f + fly.clip_frames >= total {
                clip.push((tm, tm_ref));
            }
            last_scored = Some(Scored {
                frame: f,
                image,
                reference: r.image,
            });
        }
        if f + 1 == total && !clip.is_empty() {
            record.jod = Some(clip_jod(&clip, w, h, fly.clip_fps())?);
        }
        out.push(record);
    }
    progress(&format!("flythrough `{}`: {name} done", fly.name));
    Ok(out)
}

/// ColorVideoVDP's JOD of a clip of (frame, reference) pairs, tone-mapped.
fn clip_jod(clip: &[(Vec<u8>, Vec<u8>)], width: u32, height: u32, fps: f64) -> Result<f64> {
    let test: Vec<&[u8]> = clip.iter().map(|c| c.0.as_slice()).collect();
    let reference: Vec<&[u8]> = clip.iter().map(|c| c.1.as_slice()).collect();
    video_jod(&test, &reference, width, height, fps)
        .map_err(|e| Error::Invalid(format!("ColorVideoVDP refused the clip: {e}")))
}
