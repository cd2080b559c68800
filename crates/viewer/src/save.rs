//! What the page's Save writes, into the output folder only: `view-NNNN.exr` and `.png` (the
//! image as rendered at the view's size, before any denoising), `view-NNNN.toml` (the scene
//! with every edit, at the scene's own image size, which `gscache render` renders the same way) and, with the Gaussian cache, `view-NNNN-cache/`
//! (its levels as 3DGS PLY, with their manifest). `NNNN` is the first number none of them uses
//! yet, and every one of its names is created exclusively before anything is written
//! (`Reserved`): two viewers saving into one folder never share a number, and nothing already
//! there is replaced. No name or path comes from the page.

use crate::protocol::{LightSettings, SceneFacts, TransferSettings};
use hdr_image::RgbImage;
use std::path::{Path, PathBuf};
use volume_pt::Scene;
use volume_pt::scene::{
    CameraDesc, EnvironmentDesc, LightDesc, RenderDesc, SceneFile, TfPoint, TransferDesc, ViewDesc,
    VolumeDesc,
};

/// The files one save wrote.
#[derive(Debug, Clone)]
pub struct Saved {
    pub files: Vec<PathBuf>,
}

/// A `view-NNNN` name held by one save: its scene file, image files and (with the Gaussian
/// cache) cache folder, each created empty and exclusively (`create_new`, `create_dir`) before
/// anything is written, so that two viewers saving into one folder never write to, or
/// replace, the same name. Dropped without [`Reserved::keep`], it removes what it created.
struct Reserved {
    stem: String,
    /// The scene file, open: written last, through this handle.
    toml: std::fs::File,
    created: Vec<PathBuf>,
    kept: bool,
}

impl Reserved {
    /// Reserves the first `view-NNNN` in `dir` whose names are all free (`cache`: the cache
    /// folder's too).
    fn first_free(dir: &Path, cache: bool) -> Result<Self, String> {
        for n in 1..100_000u32 {
            let stem = format!("view-{n:04}");
            let names = [
                dir.join(format!("{stem}.toml")),
                dir.join(format!("{stem}.exr")),
                dir.join(format!("{stem}.png")),
                dir.join(format!("{stem}-cache")),
            ];
            if names.iter().any(|p| std::fs::symlink_metadata(p).is_ok()) {
                continue;
            }
            let mut created = Vec::new();
            let mut toml = None;
            let mut taken = false;
            for (i, path) in names.iter().enumerate() {
                let made = match i {
                    3 if !cache => continue,
                    3 => std::fs::create_dir(path).map(|()| None),
                    _ => std::fs::OpenOptions::new()
                        .write(true)
                        .create_new(true)
                        .open(path)
                        .map(Some),
                };
                match made {
                    Ok(file) => {
                        created.push(path.clone());
                        if i == 0 {
                            toml = file;
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                        taken = true;
                        break;
                    }
                    Err(e) => {
                        remove_created(&created);
                        return Err(format!("{}: {e}", path.display()));
                    }
                }
            }
            match (taken, toml) {
                (false, Some(toml)) => {
                    return Ok(Self {
                        stem,
                        toml,
                        created,
                        kept: false,
                    });
                }
                // Another save took one of the names between the look and the creation.
                _ => remove_created(&created),
            }
        }
        Err(format!(
            "{}: every name view-0001 to view-99999 is taken",
            dir.display()
        ))
    }

    fn keep(mut self) {
        self.kept = true;
    }
}

impl Drop for Reserved {
    fn drop(&mut self) {
        if !self.kept {
            remove_created(&self.created);
        }
    }
}

/// Removes what a reservation created (empty files, or a cache folder the failed save had
/// begun): nothing else is touched.
fn remove_created(created: &[PathBuf]) {
    for path in created {
        if path.is_dir() {
            let _ = std::fs::remove_dir_all(path);
        } else {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Checks, when the viewer starts, that Save will be able to write into `dir` (a bad folder is
/// said now, not at the first Save), without creating anything: `dir` is a folder that can be
/// written, or does not exist yet and its nearest existing ancestor is one.
pub fn check_output_folder(dir: &Path) -> crate::Result<()> {
    let fail = |message: String| crate::ViewerError::Output {
        path: dir.to_path_buf(),
        message,
    };
    let existing = dir
        .ancestors()
        .map(|d| {
            if d.as_os_str().is_empty() {
                Path::new(".")
            } else {
                d
            }
        })
        .find(|d| std::fs::symlink_metadata(d).is_ok())
        .ok_or_else(|| fail("no part of the path exists".into()))?;
    if !existing.is_dir() {
        return Err(fail(format!(
            "{} is not a folder: expected a folder for the saved images",
            existing.display()
        )));
    }
    render_base::check_output(&existing.join("view-0001.exr")).map_err(|e| fail(e.message))?;
    render_base::check_writable(existing).map_err(|e| {
        fail(format!(
            "cannot write into {}: {}",
            existing.display(),
            e.message
        ))
    })
}

/// What a save needs of the viewer's state.
pub struct SaveRequest<'a> {
    pub dir: &'a Path,
    pub image: &'a RgbImage,
    pub scene: &'a Scene,
    /// The scene file's text as loaded, and the file its relative paths resolve against.
    pub scene_text: &'a str,
    pub scene_file: &'a Path,
    pub facts: &'a SceneFacts,
    pub transfer: &'a TransferSettings,
    pub lights: &'a LightSettings,
    pub spp: u32,
    pub session: &'a render_session::Session,
    /// The named views (bookmarks) the page keeps.
    pub views: &'a [ViewDesc],
    /// The time point shown.
    pub time: u32,
}

/// Writes the image, the scene and the cache (see the module docs): into names reserved
/// first, the scene file last (a save whose scene file is empty did not finish).
pub fn save(r: SaveRequest) -> Result<Saved, String> {
    std::fs::create_dir_all(r.dir).map_err(|e| format!("{}: {e}", r.dir.display()))?;
    let cache = matches!(r.session.cache(), render_session::Cache::Gaussian(_));
    let mut reserved = Reserved::first_free(r.dir, cache)?;
    let stem = reserved.stem.clone();
    let mut files = Vec::new();
    // The image files replace this save's own empty placeholders (atomically: complete or
    // empty), never another save's file.
    let exr = r.dir.join(format!("{stem}.exr"));
    r.image
        .write_exr(&exr)
        .map_err(|e| format!("{}: {e}", exr.display()))?;
    files.push(exr);
    let png = r.dir.join(format!("{stem}.png"));
    r.image
        .write_png(&png, r.scene.output.exposure, r.scene.output.tonemap)
        .map_err(|e| format!("{}: {e}", png.display()))?;
    files.push(png);
    if cache {
        let dir = r.dir.join(format!("{stem}-cache"));
        r.session
            .save_cache(&dir)
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        files.push(dir);
    }
    let toml_path = r.dir.join(format!("{stem}.toml"));
    let text = scene_toml(&r)?;
    std::io::Write::write_all(&mut reserved.toml, text.as_bytes())
        .and_then(|()| reserved.toml.sync_all())
        .map_err(|e| format!("{}: {e}", toml_path.display()))?;
    files.insert(2, toml_path);
    reserved.keep();
    Ok(Saved { files })
}

/// The scene file with the view's camera, transfer function, lights, environment and samples,
/// and the volume's path made absolute (the file is written elsewhere than the scene it came
/// from). The volume's other keys (format, spacing, filter...) are kept as the file gave them.
pub fn scene_toml(r: &SaveRequest) -> Result<String, String> {
    // A scene made from tables in Python has no file: its volume is named as it was given.
    let mut volume = if r.scene_text.trim().is_empty() {
        VolumeDesc::file(&r.scene.volume_path)
    } else {
        toml::from_str::<SceneFile>(r.scene_text)
            .map_err(|e| format!("{}: {e}", r.scene_file.display()))?
            .volume
    };
    volume.time = r.time;
    if volume.file.is_relative() {
        let anchor = r.scene_file.parent().unwrap_or(Path::new("."));
        let joined = anchor.join(&volume.file);
        volume.file = std::path::absolute(&joined).unwrap_or(joined);
    }
    let camera = &r.scene.camera;
    let (_, _, forward) = camera.axes();
    let target_distance = (r.facts.centre - camera.position).dot(forward).max(1e-3);
    let points = r
        .transfer
        .points(&r.facts.transfer)
        .into_iter()
        .map(|(value, colour, opacity)| TfPoint {
            value,
            color: colour.to_array(),
            opacity,
        })
        .collect();
    let lights = r.lights.lights(r.facts);
    let description = SceneFile {
        volume,
        transfer: TransferDesc {
            window: Some(r.transfer.window),
            density_scale: r.transfer.density_scale,
            points: Some(points),
            preset: None,
            preset_name: None,
            opacity: None,
        },
        lights: lights.lights.iter().map(LightDesc::from_light).collect(),
        environment: EnvironmentDesc {
            radiance: lights.environment.to_array(),
        },
        phase: r.scene.media.phase,
        // The scene's own size, whatever the page's view area made the view render at: a
        // saved scene renders as the scene did (the image saved beside it is the view's).
        camera: CameraDesc {
            width: r.facts.width,
            height: r.facts.height,
            ..CameraDesc::from_camera(camera, target_distance)
        },
        render: RenderDesc {
            spp: r.spp.max(1),
            ..RenderDesc::from_settings(&r.scene.settings)
        },
        output: r.scene.output,
        clip: r.scene.media.medium.clipping().clone(),
        views: r.views.to_vec(),
        channels: r.scene.channels.clone(),
    };
    description
        .to_toml(&format!(
            "Saved by `gscache view` from {}: render it with `gscache render` as any scene.",
            r.scene_file.display()
        ))
        .map_err(|e| e.to_string())
}
