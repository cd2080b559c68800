//! A movie's temporal quality: a NEE reference of every frame (kept in `reference/`, so a
//! resume reuses them), each frame's relMSE and flicker against them, and the movie's
//! ColorVideoVDP JOD. The frame compared is the frame shown: the denoised one when denoising.

use crate::error::{MovieError, Result};
use crate::folder::MovieFolder;
use glam::Vec3;
use hdr_image::{RgbImage, tone_map};
use render_base::{Camera, Control};
use render_session::{CacheChoice, ImageBudget, Session};
use std::path::PathBuf;
use volume_pt::Scene;

/// The references' seed is the scene's with this added: their samples are not the movie's.
const REFERENCE_SEED_OFFSET: u64 = 0x9e37_79b9_7f4a_7c15;

/// ColorVideoVDP scores the movie in clips of at most this many frames (its memory grows with
/// the clip); the movie's JOD is their mean.
pub const JOD_CLIP_FRAMES: usize = 30;

/// The reference of a frame: its file, and whether it was rendered now (with the seconds).
pub struct Reference {
    pub image: RgbImage,
    pub rendered_seconds: Option<f64>,
}

/// The reference of frame `f` at `camera`: read from the folder if made before, else rendered
/// with NEE at `spp` samples a pixel (the scene's settings otherwise) and written there.
pub fn reference(
    folder: &MovieFolder,
    scene: &Scene,
    camera: &Camera,
    f: u32,
    spp: u32,
) -> Result<Reference> {
    let path = reference_path(folder, f);
    if path.is_file() {
        return Ok(Reference {
            image: RgbImage::read_exr(&path)?,
            rendered_seconds: None,
        });
    }
    let start = std::time::Instant::now();
    let mut s = scene.clone();
    s.camera = *camera;
    s.settings.spp = spp;
    s.settings.seed = s.settings.seed.wrapping_add(REFERENCE_SEED_OFFSET);
    let mut session = Session::new(s, CacheChoice::None)?;
    session.render_image(ImageBudget::Passes(1), &Control::none())?;
    let image = session.image();
    let dir = folder.reference_dir();
    std::fs::create_dir_all(&dir)
        .map_err(|e| MovieError::file(&dir, format!("cannot create the folder: {e}")))?;
    image.write_exr(&path)?;
    Ok(Reference {
        image,
        rendered_seconds: Some(start.elapsed().as_secs_f64()),
    })
}

fn reference_path(folder: &MovieFolder, f: u32) -> PathBuf {
    folder.reference_dir().join(format!("frame_{f:06}.exr"))
}

/// The movie's JOD over its frames `frames`, shown at `fps`: the mean over clips of
/// [`JOD_CLIP_FRAMES`], each frame tone-mapped as the PNGs are, against its reference.
pub fn movie_jod(
    folder: &MovieFolder,
    scene: &Scene,
    frames: std::ops::Range<u32>,
    fps: f64,
) -> Result<f64> {
    let ldr = |img: &[Vec3]| tone_map(img, scene.output.exposure, scene.output.tonemap);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut scores = Vec::new();
    let all: Vec<u32> = frames.collect();
    for clip in all.chunks(JOD_CLIP_FRAMES) {
        let mut test = Vec::with_capacity(clip.len());
        let mut refs = Vec::with_capacity(clip.len());
        for &f in clip {
            test.push(ldr(RgbImage::read_exr(&folder.shown_exr(f))?.pixels()));
            refs.push(ldr(RgbImage::read_exr(&reference_path(folder, f))?.pixels()));
        }
        let t: Vec<&[u8]> = test.iter().map(Vec::as_slice).collect();
        let r: Vec<&[u8]> = refs.iter().map(Vec::as_slice).collect();
        let jod = image_metrics::video_jod(&t, &r, w, h, fps)
            .map_err(|e| MovieError::Invalid(format!("ColorVideoVDP refused the movie: {e}")))?;
        scores.push(jod);
    }
    Ok(scores.iter().sum::<f64>() / scores.len().max(1) as f64)
}
