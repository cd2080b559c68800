//! What a movie is: its frames, rate, camera path, per-frame budget, warm-up, denoising and
//! references. Written into the folder's manifest, so a resume can check it is the same movie.

use crate::error::{MovieError, Result};
use render_base::Camera;
use render_session::camera_path::{Keyframe, check_keyframes, keyframed, turntable};
use serde::{Deserialize, Serialize};
use volume_pt::Scene;

/// The most frames a movie may have (the frame numbers' width in file names stays 6 digits).
pub const MAX_FRAMES: u32 = 999_999;

/// A movie's settings; [`MovieSpec::check`] refuses what cannot be made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MovieSpec {
    /// Frames in the movie.
    pub frames: u32,
    /// Frames a second the video plays at (and ColorVideoVDP shows the movie at).
    pub fps: f64,
    pub path: MoviePath,
    pub budget: FrameBudget,
    /// Frames rendered before the movie, only to train the cache: the path's first frames (a
    /// cache then starts the movie warm, as the experiments' fly-throughs do). Not for NEE.
    pub warmup: u32,
    pub denoise: Option<DenoiseSpec>,
    /// With references: each frame's NEE reference at this many samples per pixel, for the
    /// frames' error, flicker and the movie's JOD.
    pub reference_spp: Option<u32>,
}

/// The camera's way through the movie.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MoviePath {
    /// A turn of `degrees` about the scene's up through the volume's centre, starting at the
    /// scene's camera; 360 loops.
    Turntable { degrees: f32 },
    /// Eye and target through key frames (Catmull-Rom; still before the first and after the
    /// last), frames counted from the movie's first.
    Keys { keys: Vec<Keyframe> },
}

/// What each frame may take.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameBudget {
    /// Samples per pixel (passes of one sample, so a cache reads and trains between them as in
    /// `gscache render --frames`).
    Spp(u32),
    /// Seconds: passes of one sample while the next fits, the denoiser's time charged.
    Seconds(f64),
}

/// Each frame denoised by Intel Open Image Denoise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DenoiseSpec {
    pub quality: denoise::Quality,
    pub guides: denoise::Guides,
    /// Denoise the guides first (OIDN's advice for final frames; two more filter passes).
    pub prefilter: bool,
}

impl DenoiseSpec {
    pub fn options(&self) -> denoise::Options {
        denoise::Options {
            quality: self.quality,
            prefilter: self.prefilter,
        }
    }
}

impl MovieSpec {
    /// Refuses a movie that cannot be made, naming the setting; `has_cache` says whether the
    /// method trains a cache (a warm-up needs one).
    pub fn check(&self, has_cache: bool) -> Result<()> {
        let invalid = |m: String| Err(MovieError::Invalid(m));
        if self.frames == 0 || self.frames > MAX_FRAMES {
            return invalid(format!(
                "{} frames: expected 1 to {MAX_FRAMES}",
                self.frames
            ));
        }
        if !(self.fps > 0.0 && self.fps <= 1000.0) {
            return invalid(format!(
                "{} frames a second: expected more than 0 and at most 1000",
                self.fps
            ));
        }
        match self.budget {
            FrameBudget::Spp(0) => return invalid("0 samples a frame: expected at least 1".into()),
            FrameBudget::Seconds(t) if !(t > 0.0 && t.is_finite()) => {
                return invalid(format!(
                    "{t} seconds a frame: expected a finite time above 0"
                ));
            }
            _ => {}
        }
        if self.warmup > 0 && !has_cache {
            return invalid(format!(
                "a warm-up of {} frames without a cache: there is nothing to train (add a cache, \
                 or leave the warm-up out)",
                self.warmup
            ));
        }
        if self.reference_spp == Some(0) {
            return invalid("references of 0 samples a pixel: expected at least 1".into());
        }
        match &self.path {
            MoviePath::Turntable { degrees } if !degrees.is_finite() => invalid(format!(
                "a turntable of {degrees} degrees: expected a finite angle"
            )),
            MoviePath::Keys { keys } => Ok(check_keyframes(keys)?),
            MoviePath::Turntable { .. } => Ok(()),
        }
    }

    /// The camera of frame `f` (warm-up frames are the path's first frames).
    pub fn camera(&self, scene: &Scene, f: u32) -> Result<Camera> {
        Ok(match &self.path {
            MoviePath::Turntable { degrees } => {
                let (lo, hi) = scene.media.medium.bounds();
                let centre = 0.5 * (lo + hi);
                turntable(&scene.camera, centre, scene.up, *degrees, f, self.frames)
            }
            MoviePath::Keys { keys } => keyframed(&scene.camera, keys, f)?,
        })
    }
}
