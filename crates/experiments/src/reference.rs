//! References: high-spp NEE renders, made once and kept on disk. A reference's file name is a
//! hash of everything that decides its pixels (the scene file's bytes, the volume file's name
//! and length, the scene state after edits, the camera, the size and the spp), so a changed
//! input makes a new one and an unchanged one is reused. A JSON file beside each EXR says what
//! it is.

use crate::error::{Error, Result};
use glam::Vec3;
use hdr_image::RgbImage;
use splat_raster::Camera;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volume_pt::{Control, Film, IntegratorKind, Scene, render_samples};

/// FNV-1a, 64 bits (render-base's, the one definition), and its offset basis.
use render_base::hash::{FNV_OFFSET, fnv1a64};

/// A reference image and where it lives.
#[derive(Debug, Clone)]
pub struct Reference {
    pub image: Vec<Vec3>,
    pub file: PathBuf,
    /// Found on disk rather than rendered by this run.
    pub reused: bool,
    /// Seconds it took to render (0 when reused).
    pub seconds: f64,
    pub spp: u32,
}

/// The seed of every reference: fixed, and far from the seeds experiments use.
const REFERENCE_SEED: u64 = 0x005e_ed0f_5eed;

/// The reference of `scene` seen from `camera` at `spp`, from `dir` or rendered into it.
/// `scene_file` and `state` (a description of the edits applied to the scene) enter the key.
pub fn reference(
    dir: &Path,
    scene_file: &Path,
    state: &str,
    scene: &Scene,
    camera: &Camera,
    spp: u32,
    progress: Option<&dyn Fn(&str)>,
) -> Result<Reference> {
    let scene_bytes = std::fs::read(scene_file)
        .map_err(|e| Error::io(scene_file, "cannot read the scene file", e))?;
    let volume_len = std::fs::metadata(&scene.volume_path)
        .map(|m| m.len())
        .unwrap_or(0);
    let mut h = fnv1a64(&scene_bytes, FNV_OFFSET);
    let key = format!(
        "{}|{volume_len}|{state}|{camera:?}|{spp}|{:?}",
        scene.volume_path.display(),
        scene.settings.path
    );
    h = fnv1a64(key.as_bytes(), h);
    let stem = scene_file
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let file = dir.join(format!(
        "{stem}_{}x{}_{spp}spp_{h:016x}.exr",
        camera.width, camera.height
    ));
    if file.exists() {
        let image = RgbImage::read_exr(&file)?;
        // A kept reference is a cache of a render, checked as the render would be: a damaged
        // or edited one (NaN, infinite or negative pixels) is rendered again, never reused (a
        // NaN reference once gave relMSE NaN, PSNR 2760 dB and an efficiency of 1e300).
        let sound = image
            .pixels()
            .iter()
            .all(|p| p.is_finite() && p.min_element() >= 0.0);
        if !sound {
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "warning: {}: the kept reference has non-finite or negative pixels; rendering it again",
                file.display()
            );
        }
        if sound && (image.width(), image.height()) == (camera.width, camera.height) {
            return Ok(Reference {
                image: image.into_pixels(),
                file,
                reused: true,
                seconds: 0.0,
                spp,
            });
        }
    }
    let mut settings = scene.settings;
    settings.spp = spp;
    settings.seed = REFERENCE_SEED;
    settings.path.integrator = IntegratorKind::Nee;
    let mut film = Film::new(camera.width, camera.height);
    let start = Instant::now();
    // In ten passes of sample indices, reporting after each: a reference can take minutes,
    // and it once printed nothing for 102 s (issue 33). The exact film makes the passes' sum
    // the one render's, bit for bit.
    let passes = if progress.is_some() { spp.min(10) } else { 1 };
    if let Some(say) = progress {
        say(&format!(
            "reference: rendering {spp} spp at {}x{} (none kept for this scene and view)",
            camera.width, camera.height
        ));
    }
    for pass in 0..passes {
        let samples = spp * pass / passes..spp * (pass + 1) / passes;
        render_samples(
            &scene.media,
            camera,
            &settings,
            samples,
            &mut film,
            &Control::none(),
        );
        if let Some(say) = progress.filter(|_| pass + 1 < passes) {
            let done = (pass + 1) as f64 / passes as f64;
            let elapsed = start.elapsed().as_secs_f64();
            say(&format!(
                "reference: {:.0}% in {elapsed:.0} s, about {:.0} s left",
                100.0 * done,
                elapsed * (1.0 - done) / done
            ));
        }
    }
    scene.media.medium.grid().check_streaming()?;
    let seconds = start.elapsed().as_secs_f64();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, "cannot create", e))?;
    // Written atomically, so an interrupted run leaves no half file that a later run would take
    // for a reference.
    let image = film.image();
    image.write_exr(&file)?;
    let image = image.into_pixels();
    let about = serde_json::json!({
        "scene_file": scene_file.display().to_string(),
        "volume": scene.volume_path.display().to_string(),
        "state": state,
        "camera": format!("{camera:?}"),
        "spp": spp,
        "seed": REFERENCE_SEED,
        "integrator": "nee",
        "seconds": seconds,
    });
    crate::write_text(
        &file.with_extension("json"),
        &serde_json::to_string_pretty(&about)?,
    )?;
    Ok(Reference {
        image,
        file,
        reused: false,
        seconds,
        spp,
    })
}
