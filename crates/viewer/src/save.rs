//! What the page's Save writes, into the output folder only: `view-NNNN.exr` and `.png` (the
//! image as shown, before any denoising), `view-NNNN.toml` (the scene with every edit, which
//! `gscache render` renders the same way) and, with the Gaussian cache, `view-NNNN-cache/`
//! (its levels as 3DGS PLY). `NNNN` is the first number none of them uses yet, so nothing
//! already there is replaced. No name or path comes from the page.

use crate::protocol::{LightSettings, SceneFacts, TransferSettings};
use glam::Vec3;
use hdr_image::RgbImage;
use std::path::{Path, PathBuf};
use volume_pt::{Light, Scene};

/// The files one save wrote.
#[derive(Debug, Clone)]
pub struct Saved {
    pub files: Vec<PathBuf>,
}

/// The first `view-NNNN` stem in `dir` that no file or folder uses.
fn free_stem(dir: &Path) -> std::io::Result<String> {
    for n in 1..100_000u32 {
        let stem = format!("view-{n:04}");
        let taken = ["exr", "png", "toml"]
            .iter()
            .any(|e| dir.join(format!("{stem}.{e}")).exists())
            || dir.join(format!("{stem}-cache")).exists();
        if !taken {
            return Ok(stem);
        }
    }
    Err(std::io::Error::other(format!(
        "{}: every name view-0001 to view-99999 is taken",
        dir.display()
    )))
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
}

/// Writes the image, the scene and the cache (see the module docs).
pub fn save(r: SaveRequest) -> Result<Saved, String> {
    std::fs::create_dir_all(r.dir).map_err(|e| format!("{}: {e}", r.dir.display()))?;
    let stem = free_stem(r.dir).map_err(|e| e.to_string())?;
    let mut files = Vec::new();
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
    let toml_path = r.dir.join(format!("{stem}.toml"));
    let text = scene_toml(&r)?;
    write_new(&toml_path, text.as_bytes())?;
    files.push(toml_path);
    if r.session.cache().gaussian().is_some() {
        let dir = r.dir.join(format!("{stem}-cache"));
        r.session
            .save_cache(&dir)
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        files.push(dir);
    }
    Ok(Saved { files })
}

/// Writes `bytes` to `path`, which must not exist yet.
fn write_new(path: &Path, bytes: &[u8]) -> Result<(), String> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    f.write_all(bytes)
        .map_err(|e| format!("{}: {e}", path.display()))
}

fn array(v: Vec3) -> toml::Value {
    toml::Value::Array(vec![
        toml::Value::Float(v.x as f64),
        toml::Value::Float(v.y as f64),
        toml::Value::Float(v.z as f64),
    ])
}

/// The scene file with the view's camera, transfer function, lights and environment, and the
/// volume's path made absolute (the file is written elsewhere than the scene it came from).
pub fn scene_toml(r: &SaveRequest) -> Result<String, String> {
    let mut table: toml::Table =
        toml::from_str(r.scene_text).map_err(|e| format!("{}: {e}", r.scene_file.display()))?;
    let anchor = r.scene_file.parent().unwrap_or(Path::new("."));
    // A scene made from tables in Python has no file: its volume is named as it was given.
    if !table.contains_key("volume") {
        let mut volume = toml::Table::new();
        volume.insert(
            "file".into(),
            toml::Value::String(r.scene.volume_path.display().to_string()),
        );
        table.insert("volume".into(), toml::Value::Table(volume));
    }
    if let Some(toml::Value::Table(volume)) = table.get_mut("volume")
        && let Some(toml::Value::String(file)) = volume.get("file")
    {
        let path = Path::new(file);
        let absolute = if path.is_absolute() {
            path.to_path_buf()
        } else {
            std::path::absolute(anchor.join(path)).unwrap_or_else(|_| anchor.join(path))
        };
        volume.insert(
            "file".into(),
            toml::Value::String(absolute.display().to_string()),
        );
    }
    let camera = r.scene.camera;
    let (_, down, forward) = camera.axes();
    let target =
        camera.position + forward * (r.facts.centre - camera.position).dot(forward).max(1e-3);
    let mut cam = toml::Table::new();
    cam.insert("eye".into(), array(camera.position));
    cam.insert("target".into(), array(target));
    cam.insert("up".into(), array(-down));
    cam.insert(
        "fov_y".into(),
        toml::Value::Float(camera.fov_y_degrees as f64),
    );
    cam.insert("width".into(), toml::Value::Integer(r.facts.width as i64));
    cam.insert("height".into(), toml::Value::Integer(r.facts.height as i64));
    table.insert("camera".into(), toml::Value::Table(cam));
    let mut transfer = toml::Table::new();
    transfer.insert(
        "window".into(),
        toml::Value::Array(vec![
            toml::Value::Float(r.transfer.window[0] as f64),
            toml::Value::Float(r.transfer.window[1] as f64),
        ]),
    );
    transfer.insert(
        "density_scale".into(),
        toml::Value::Float(r.transfer.density_scale as f64),
    );
    let points = r
        .transfer
        .points(&r.facts.transfer)
        .into_iter()
        .map(|(u, colour, opacity)| {
            let mut p = toml::Table::new();
            p.insert("value".into(), toml::Value::Float(u as f64));
            p.insert("color".into(), array(colour));
            p.insert("opacity".into(), toml::Value::Float(opacity as f64));
            toml::Value::Table(p)
        })
        .collect();
    transfer.insert("points".into(), toml::Value::Array(points));
    table.insert("transfer".into(), toml::Value::Table(transfer));
    let lights = r.lights.lights(r.facts);
    let light_tables = lights
        .lights
        .iter()
        .map(|l| {
            let mut t = toml::Table::new();
            match l {
                Light::Sphere(s) => {
                    t.insert("center".into(), array(s.center));
                    t.insert("radius".into(), toml::Value::Float(s.radius as f64));
                    t.insert("radiance".into(), array(s.radiance));
                }
                Light::Distant(d) => {
                    t.insert("type".into(), toml::Value::String("distant".into()));
                    t.insert("direction".into(), array(d.direction));
                    t.insert("irradiance".into(), array(d.irradiance));
                }
            }
            toml::Value::Table(t)
        })
        .collect();
    table.insert("light".into(), toml::Value::Array(light_tables));
    let mut env = toml::Table::new();
    env.insert("radiance".into(), array(lights.environment));
    table.insert("environment".into(), toml::Value::Table(env));
    let render = table
        .entry("render")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let toml::Value::Table(render) = render {
        render.insert("spp".into(), toml::Value::Integer(r.spp.max(1) as i64));
        render.insert(
            "show_lights".into(),
            toml::Value::Boolean(r.scene.settings.path.show_lights),
        );
    }
    let body = toml::to_string(&table).map_err(|e| e.to_string())?;
    Ok(format!(
        "# Saved by `gscache view` from {}: render it with `gscache render` as any scene.\n{body}",
        r.scene_file.display()
    ))
}
