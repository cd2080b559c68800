//! Scene files (TOML): what to render and how. Every key is documented in `docs/scene-format.md`.
//! Relative paths are resolved against the scene file's folder.

use crate::clip::{ClipBox, ClipPlane, Clipping};
use crate::error::{Error, Result};
use crate::grid::Filter;
use crate::integrator::{IntegratorKind, PathSettings, SceneMedia};
use crate::io::{ByteOrder, DType, Format, RawLayout, ReadHints, read_volume};
use crate::lights::{DistantLight, Light, Lights, SphereLight};
use crate::medium::{DEFAULT_MACROCELL, Medium};
use crate::phase::Phase;
use crate::render::RenderSettings;
use crate::transfer::{PiecewiseLinear, TransferFunction, read_paraview_preset};
use glam::{UVec3, Vec3};
use hdr_image::ToneMap;
use render_base::Camera;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Which kind of emitter a `[[light]]` table describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    #[default]
    Sphere,
    Distant,
}

impl LightKind {
    pub fn name(self) -> &'static str {
        match self {
            LightKind::Sphere => "sphere",
            LightKind::Distant => "distant",
        }
    }
}

/// A `[[light]]` table as written: `type` (sphere when left out) and the keys of that kind.
/// Kept flat so that a missing or misplaced key is named with the light's kind.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    #[serde(rename = "type", default)]
    pub kind: LightKind,
    /// Sphere: centre and radius.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub center: Option<[f32; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f32>,
    /// Sphere: emitted radiance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radiance: Option<[f32; 3]>,
    /// Distant: the direction the light travels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f32; 3]>,
    /// Distant: irradiance on a surface facing the light.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<[f32; 3]>,
}

impl LightDesc {
    /// The `[[light]]` table that describes `light`.
    pub fn from_light(light: &Light) -> Self {
        match *light {
            Light::Sphere(s) => Self {
                kind: LightKind::Sphere,
                center: Some(s.center.to_array()),
                radius: Some(s.radius),
                radiance: Some(s.radiance.to_array()),
                ..Self::default()
            },
            Light::Distant(d) => Self {
                kind: LightKind::Distant,
                direction: Some(d.direction.to_array()),
                irradiance: Some(d.irradiance.to_array()),
                ..Self::default()
            },
        }
    }

    /// The emitter this table describes (not yet validated); names a missing key, or one that
    /// belongs to another kind of light.
    pub fn to_light(&self) -> std::result::Result<Light, String> {
        let need = |v: Option<[f32; 3]>, key: &str, what: &str| {
            v.map(Vec3::from_array)
                .ok_or_else(|| format!("missing `{key}`: expected {what}"))
        };
        let refuse = |present: bool, key: &str| {
            if present {
                Err(format!(
                    "`{key}` is not a key of a {} light (set `type` to the kind you mean)",
                    self.kind.name()
                ))
            } else {
                Ok(())
            }
        };
        match self.kind {
            LightKind::Sphere => {
                refuse(self.direction.is_some(), "direction")?;
                refuse(self.irradiance.is_some(), "irradiance")?;
                Ok(Light::Sphere(SphereLight {
                    center: need(self.center, "center", "[x, y, z]")?,
                    radius: self
                        .radius
                        .ok_or("missing `radius`: expected a radius > 0")?,
                    radiance: need(self.radiance, "radiance", "[r, g, b]")?,
                }))
            }
            LightKind::Distant => {
                refuse(self.center.is_some(), "center")?;
                refuse(self.radius.is_some(), "radius")?;
                refuse(self.radiance.is_some(), "radiance")?;
                Ok(Light::Distant(DistantLight {
                    direction: need(
                        self.direction,
                        "direction",
                        "[x, y, z], the way the light travels",
                    )?,
                    irradiance: need(self.irradiance, "irradiance", "[r, g, b]")?,
                }))
            }
        }
    }
}

/// A scene file's tables, as read and as written ([`SceneFile::to_toml`]): the one description
/// of the format in code, so a new key is added here and nowhere else.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub volume: VolumeDesc,
    pub transfer: TransferDesc,
    /// `[[light]]` tables: `type = "sphere"` (the default when `type` is left out) or
    /// `"distant"`.
    #[serde(default, rename = "light")]
    pub lights: Vec<LightDesc>,
    #[serde(default)]
    pub environment: EnvironmentDesc,
    #[serde(default)]
    pub phase: Phase,
    pub camera: CameraDesc,
    #[serde(default)]
    pub render: RenderDesc,
    #[serde(default)]
    pub output: OutputDesc,
    /// `[clip]`: a box and planes that cut the medium away (see [`crate::clip`]).
    #[serde(default, skip_serializing_if = "Clipping::is_empty")]
    pub clip: Clipping,
    /// `[[view]]` tables: named camera positions (the viewer's bookmarks; `--view NAME`).
    #[serde(default, rename = "view", skip_serializing_if = "Vec::is_empty")]
    pub views: Vec<ViewDesc>,
    /// `[[channel]]` tables: more channels rendered together with the volume's own (see
    /// [`crate::medium`]).
    #[serde(default, rename = "channel", skip_serializing_if = "Vec::is_empty")]
    pub channels: Vec<ChannelDesc>,
}

/// The most `[[channel]]` tables a scene may hold.
pub const MAX_CHANNELS: usize = 15;

/// A channel rendered together with the volume's own, classified as microscopists' viewers
/// do: a window, a colour and an opacity (rising linearly across the window from 0 to
/// `opacity`). Extinctions add; the colour is the extinction-weighted mix.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelDesc {
    /// The channel's index on the image's channel axis (an OME-Zarr store's `c`); 0 for a file
    /// of one channel.
    pub index: u32,
    /// A file of its own (the same dims as the volume); default: the volume's file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    /// Data values mapped to no opacity and to `opacity`.
    pub window: [f32; 2],
    /// The channel's colour (single-scattering albedo), each component in [0, 1].
    pub color: [f32; 3],
    /// The opacity at the window's top.
    #[serde(default = "full_opacity")]
    pub opacity: f32,
    /// Extinction per world unit at opacity 1; default: `[transfer]`'s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density_scale: Option<f32>,
}

fn full_opacity() -> f32 {
    1.0
}

impl ChannelDesc {
    /// The channel's transfer function (`density_scale` where the table gives none).
    pub fn transfer_function(&self, density_scale: f32) -> Result<TransferFunction> {
        let c = Vec3::from_array(self.color);
        TransferFunction::from_points(
            (self.window[0], self.window[1]),
            &[(0.0, c, 0.0), (1.0, c, self.opacity)],
            self.density_scale.unwrap_or(density_scale),
        )
    }
}

/// The most `[[view]]` tables a scene may hold.
pub const MAX_VIEWS: usize = 64;
/// The longest view name, in characters.
pub const MAX_VIEW_NAME: usize = 64;

/// A named camera position: where the camera is, what it looks at and its up (the field of
/// view and the image size are the scene's).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ViewDesc {
    pub name: String,
    pub eye: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
}

impl ViewDesc {
    /// The scene's camera moved to this view (its field of view and size kept); an error
    /// names the view and the fault.
    pub fn camera(&self, scene_camera: &Camera) -> std::result::Result<Camera, String> {
        Camera::look_at(
            vec3(self.eye),
            vec3(self.target),
            vec3(self.up),
            scene_camera.fov_y_degrees,
            scene_camera.width,
            scene_camera.height,
        )
        .map_err(|e| format!("view \"{}\": {e}", self.name))
    }

    /// Checks `views`: at most [`MAX_VIEWS`], each named (at most [`MAX_VIEW_NAME`]
    /// characters, no two alike) and a camera that can be built.
    pub fn validate_all(
        views: &[ViewDesc],
        scene_camera: &Camera,
    ) -> std::result::Result<(), String> {
        if views.len() > MAX_VIEWS {
            return Err(format!(
                "{} views: expected at most {MAX_VIEWS}",
                views.len()
            ));
        }
        for (i, v) in views.iter().enumerate() {
            let chars = v.name.chars().count();
            if chars == 0 || chars > MAX_VIEW_NAME || v.name.chars().any(char::is_control) {
                return Err(format!(
                    "view {i}: name {:?}: expected 1 to {MAX_VIEW_NAME} characters, none a control character",
                    v.name
                ));
            }
            if views[..i].iter().any(|w| w.name == v.name) {
                return Err(format!("view {i}: a second view named {:?}", v.name));
            }
            v.camera(scene_camera)?;
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeDesc {
    pub file: PathBuf,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub format: Option<Format>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dims: Option<[u32; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dtype: Option<DType>,
    #[serde(default, skip_serializing_if = "is_default")]
    pub byte_order: ByteOrder,
    #[serde(default, skip_serializing_if = "is_default")]
    pub header_bytes: u64,
    /// OME-Zarr: the resolution level (0, the finest, by default), channel and time point.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub level: Option<u32>,
    #[serde(default, skip_serializing_if = "is_default")]
    pub channel: u32,
    #[serde(default, skip_serializing_if = "is_default")]
    pub time: u32,
    /// World size of a voxel; overrides the file's spacing; default the file's, else 1.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spacing: Option<[f32; 3]>,
    /// The unit of the spacing (and so of every world coordinate), shown by the viewer's
    /// scale bar and data panel; default the file's (NRRD `space units`, NIfTI `xyzt_units`)
    /// when the spacing is the file's too.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<String>,
    /// World position of the box's minimum corner; default: the box is centred on the origin.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub origin: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "is_default")]
    pub filter: Filter,
    /// Macrocell size of the majorant grid in voxels (a size >= the largest dim = one majorant).
    #[serde(
        default = "default_macrocell",
        skip_serializing_if = "is_default_macrocell"
    )]
    pub macrocell: u32,
}

impl VolumeDesc {
    /// The file at `file`, read as its name says, placed and filtered by default.
    pub fn file(file: impl Into<PathBuf>) -> Self {
        Self {
            file: file.into(),
            format: None,
            dims: None,
            dtype: None,
            byte_order: ByteOrder::default(),
            header_bytes: 0,
            level: None,
            channel: 0,
            time: 0,
            spacing: None,
            units: None,
            origin: None,
            filter: Filter::default(),
            macrocell: DEFAULT_MACROCELL,
        }
    }
}

impl SceneFile {
    /// The scene file's text: what [`load_scene`] reads back to the same tables (tested on
    /// every bundled scene). `comment` opens the file, each of its lines as a `#` line.
    pub fn to_toml(&self, comment: &str) -> Result<String> {
        let body = toml::to_string(self)
            .map_err(|e| Error::Invalid(format!("the scene cannot be written as TOML: {e}")))?;
        let mut text = String::with_capacity(body.len() + comment.len() + 16);
        for line in comment.lines() {
            text.push_str("# ");
            text.push_str(line);
            text.push('\n');
        }
        text.push_str(&body);
        Ok(text)
    }
}

fn default_macrocell() -> u32 {
    DEFAULT_MACROCELL
}

fn is_default_macrocell(cells: &u32) -> bool {
    *cells == DEFAULT_MACROCELL
}

/// Keys at their default are left out of a written file, which then reads as a person wrote it.
fn is_default<T: Default + PartialEq>(value: &T) -> bool {
    *value == T::default()
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TfPoint {
    pub value: f32,
    pub color: [f32; 3],
    pub opacity: f32,
}

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TransferDesc {
    /// Data values mapped to normalised 0 and 1; default: the data's range.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub window: Option<[f32; 2]>,
    /// Extinction per world unit at opacity 1.
    pub density_scale: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub points: Option<Vec<TfPoint>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preset: Option<PathBuf>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preset_name: Option<String>,
    /// `[[value, opacity], ...]`: opacity points used with a preset (replacing its `Points`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub opacity: Option<Vec<[f32; 2]>>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentDesc {
    #[serde(default)]
    pub radiance: [f32; 3],
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov_y: f32,
    pub width: u32,
    pub height: u32,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

impl CameraDesc {
    /// The description of `camera`, aimed at a target `target_distance` ahead of it (a camera
    /// holds only its direction; where along it the target sat is the writer's choice).
    pub fn from_camera(camera: &Camera, target_distance: f32) -> Self {
        let (_, down, forward) = camera.axes();
        Self {
            eye: camera.position.to_array(),
            target: (camera.position + forward * target_distance).to_array(),
            up: (-down).to_array(),
            fov_y: camera.fov_y_degrees,
            width: camera.width,
            height: camera.height,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderDesc {
    pub spp: u32,
    /// Largest number of real scattering vertices; -1 for unlimited.
    pub max_depth: i64,
    pub integrator: IntegratorKind,
    pub seed: u64,
    pub rr_start_depth: u32,
    /// Whether camera rays see the light spheres (default true: they are part of the scene's
    /// radiance, and the committed results were measured with them; false for the look
    /// scientific viewers have, with the volume lit by lights that are not in the picture).
    pub show_lights: bool,
}

impl Default for RenderDesc {
    fn default() -> Self {
        Self {
            spp: 16,
            max_depth: 64,
            integrator: IntegratorKind::Nee,
            seed: 0,
            rr_start_depth: 3,
            show_lights: true,
        }
    }
}

impl RenderDesc {
    /// The `[render]` table that gives `settings`.
    pub fn from_settings(settings: &RenderSettings) -> Self {
        Self {
            spp: settings.spp,
            max_depth: settings.path.max_depth.map_or(-1, i64::from),
            integrator: settings.path.integrator,
            seed: settings.seed,
            rr_start_depth: settings.path.rr_start_depth,
            show_lights: settings.path.show_lights,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputDesc {
    /// PNG exposure in stops.
    pub exposure: f32,
    pub tonemap: ToneMap,
}

/// A scene ready to render.
#[derive(Debug, Clone)]
pub struct Scene {
    pub media: SceneMedia,
    pub camera: Camera,
    /// The scene's up: its camera table's `up`, normalised (the camera keeps only the image's
    /// up, which tilts with the view). Turntables turn about it.
    pub up: Vec3,
    pub settings: RenderSettings,
    pub output: OutputDesc,
    /// What the readers reported but the renderer does not use, and warnings (prefixed
    /// `warning: `) about settings that are legal but likely mistakes.
    pub notes: Vec<String>,
    pub volume_path: PathBuf,
    /// The scene's named views (`[[view]]`).
    pub views: Vec<ViewDesc>,
    /// The unit of world coordinates, where the scene or the volume file names one.
    pub units: Option<String>,
    /// The `[[channel]]` tables the medium's channels were made from (a channel's own file
    /// made absolute), as a saved scene writes them back.
    pub channels: Vec<ChannelDesc>,
    /// The time point shown (`[volume] time`) and how many the volume has (a series' files,
    /// an OME-Zarr store's time axis; 1 for most volumes).
    pub time: u32,
    pub time_points: u32,
}

/// Max depth from the scene-file convention (-1 = unlimited).
pub fn max_depth_from(v: i64) -> std::result::Result<Option<u32>, String> {
    match v {
        -1 => Ok(None),
        0..=0xffff_fffe => Ok(Some(v as u32)),
        _ => Err(format!(
            "max_depth {v} is invalid: expected -1 (unlimited) or a count of scattering vertices >= 0"
        )),
    }
}

fn vec3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

/// Optical depths across a whole volume (the box's diagonal at the densest majorant) beyond this
/// draw a warning. The bundled scenes reach 66 to 177; this is over 100 times the densest.
pub const MAX_PLAUSIBLE_OPTICAL_DEPTH: f64 = 2e4;

/// Reads and builds the scene at `path`.
pub fn load_scene(path: &Path) -> Result<Scene> {
    let text = crate::io::read_text_file(path, "a scene file")?;
    scene_from_text(path, &text)
}

/// The scene in `text`, the contents of the scene file at `path`.
fn scene_from_text(path: &Path, text: &str) -> Result<Scene> {
    let desc: SceneFile = toml::from_str(text).map_err(|e| Error::Scene {
        path: path.into(),
        message: e.to_string(),
    })?;
    build_scene(path, desc)
}

/// A scene opened from a path that names either a scene file or a bare volume
/// ([`open_scene`]).
#[derive(Debug, Clone)]
pub struct OpenedScene {
    pub scene: Scene,
    /// The scene's TOML text: the file's, or the automatic scene's.
    pub text: String,
    /// The file the text is, or would be saved as: the scene file itself, or `VOLUME.auto.toml`
    /// beside a bare volume (its relative paths resolve there).
    pub file: PathBuf,
    /// Whether the scene was chosen for a bare volume ([`crate::auto_scene`]).
    pub automatic: bool,
}

/// Whether `path` names a scene file (`.toml`, or a name no volume reader claims) rather than
/// a volume file.
pub fn is_scene_file(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
        || Format::from_path(path).is_none()
}

/// Opens `path` as `gscache render` and `gscache view` do: a scene file, or a bare volume with
/// the automatic scene in `colormap`.
pub fn open_scene(path: &Path, colormap: crate::Colormap) -> Result<OpenedScene> {
    if is_scene_file(path) {
        let text = crate::io::read_text_file(path, "a scene file")?;
        Ok(OpenedScene {
            scene: scene_from_text(path, &text)?,
            text,
            file: path.to_path_buf(),
            automatic: false,
        })
    } else {
        let (scene, text) = crate::auto_scene::scene_for_volume(path, colormap)?;
        Ok(OpenedScene {
            scene,
            text,
            file: path.with_extension("auto.toml"),
            automatic: true,
        })
    }
}

/// What a command line or a Python call changes of a loaded scene: one type for `gscache
/// render`, `gscache view` and the Python package, so that an override means the same
/// everywhere. Each field left `None` keeps the scene's value.
#[derive(Debug, Clone, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SceneOverrides {
    /// Samples per pixel (overrides the scene); with a cache, per frame.
    #[cfg_attr(feature = "clap", arg(long, value_parser = clap::value_parser!(u32).range(1..)))]
    pub spp: Option<u32>,
    /// `uniform` (phase sampling only) or `nee` (light sampling + phase sampling, MIS).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub integrator: Option<IntegratorKind>,
    /// Largest path length in real scattering vertices; -1 for unlimited.
    #[cfg_attr(feature = "clap", arg(long))]
    pub max_depth: Option<i64>,
    /// Seed of the counter-based random numbers (and of the cache's starting points).
    #[cfg_attr(feature = "clap", arg(long))]
    pub seed: Option<u64>,
    /// Image width in pixels (overrides the scene).
    #[cfg_attr(feature = "clap", arg(long))]
    pub width: Option<u32>,
    /// Image height in pixels (overrides the scene).
    #[cfg_attr(feature = "clap", arg(long))]
    pub height: Option<u32>,
    /// Majorant macrocell size in voxels (a size >= the largest dim gives one global majorant).
    #[cfg_attr(feature = "clap", arg(long))]
    pub macrocell: Option<u32>,
    /// Keep only the medium inside this box, world units: `MINX,MINY,MINZ,MAXX,MAXY,MAXZ`
    /// (replaces the scene's clip box).
    #[cfg_attr(feature = "clap", arg(long, value_name = "MIN,MAX", value_parser = parse_clip_box))]
    pub clip_box: Option<ClipBox>,
    /// Cut away the medium on the side a plane's normal points to: `PX,PY,PZ,NX,NY,NZ` (a
    /// point on the plane, then the normal), repeatable (replaces the scene's planes).
    #[cfg_attr(feature = "clap", arg(long, value_name = "POINT,NORMAL", value_parser = parse_clip_plane))]
    pub clip_plane: Vec<ClipPlane>,
    /// Render from the scene's view of this name (a `[[view]]` table: the viewer's bookmarks).
    #[cfg_attr(feature = "clap", arg(long, value_name = "NAME"))]
    pub view: Option<String>,
}

/// Six comma-separated numbers, named in errors as `what`.
fn six_numbers(text: &str, what: &str) -> std::result::Result<[f32; 6], String> {
    let numbers: Vec<f32> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| format!("{what} `{text}`: {e}"))?;
    <[f32; 6]>::try_from(numbers.as_slice())
        .map_err(|_| format!("{what} `{text}`: expected 6 comma-separated numbers"))
}

/// `--clip-box`'s value.
pub fn parse_clip_box(text: &str) -> std::result::Result<ClipBox, String> {
    let v = six_numbers(text, "clip box")?;
    Ok(ClipBox {
        min: [v[0], v[1], v[2]],
        max: [v[3], v[4], v[5]],
    })
}

/// `--clip-plane`'s value.
pub fn parse_clip_plane(text: &str) -> std::result::Result<ClipPlane, String> {
    let v = six_numbers(text, "clip plane")?;
    Ok(ClipPlane {
        point: [v[0], v[1], v[2]],
        normal: [v[3], v[4], v[5]],
    })
}

impl SceneOverrides {
    /// `settings` with the overridden samples, integrator, depth and seed.
    pub fn settings(&self, mut settings: RenderSettings) -> Result<RenderSettings> {
        if let Some(spp) = self.spp {
            if spp == 0 {
                return Err(Error::Invalid(
                    "spp = 0: expected at least 1 sample per pixel".into(),
                ));
            }
            settings.spp = spp;
        }
        if let Some(integrator) = self.integrator {
            settings.path.integrator = integrator;
        }
        if let Some(depth) = self.max_depth {
            settings.path.max_depth = max_depth_from(depth).map_err(Error::Invalid)?;
        }
        if let Some(seed) = self.seed {
            settings.seed = seed;
        }
        Ok(settings)
    }

    /// Applies every override to `scene`: its settings, its macrocells (the majorants are
    /// rebuilt), its clipping and its image size.
    pub fn apply(&self, scene: &mut Scene) -> Result<()> {
        scene.settings = self.settings(scene.settings)?;
        if let Some(cells) = self.macrocell {
            scene.media.medium.set_macrocell_size(cells)?;
        }
        if self.clip_box.is_some() || !self.clip_plane.is_empty() {
            let mut clipping = scene.media.medium.clipping().clone();
            if let Some(b) = self.clip_box {
                clipping.bounds = Some(b);
            }
            if !self.clip_plane.is_empty() {
                clipping.planes = self.clip_plane.clone();
            }
            scene.media.medium.set_clipping(clipping)?;
        }
        if let Some(name) = &self.view {
            let view = scene
                .views
                .iter()
                .find(|v| &v.name == name)
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "--view {name:?}: the scene has {}",
                        if scene.views.is_empty() {
                            "no [[view]] tables".to_string()
                        } else {
                            format!(
                                "the views {}",
                                scene
                                    .views
                                    .iter()
                                    .map(|v| format!("{:?}", v.name))
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            )
                        }
                    ))
                })?;
            scene.camera = view.camera(&scene.camera).map_err(Error::Invalid)?;
        }
        if self.width.is_some() || self.height.is_some() {
            let camera = scene.camera;
            scene.camera = camera
                .with_size(
                    self.width.unwrap_or(camera.width),
                    self.height.unwrap_or(camera.height),
                )
                .map_err(|e| Error::Invalid(format!("width/height: {e}")))?;
        }
        Ok(())
    }
}

/// The key of a render of `scene`, loaded from the file at `path` with any overrides applied
/// (see [`crate::shard::RenderKey`]): [`scene_file_key`] and [`settings_fingerprint`].
pub fn scene_render_key(path: &Path, scene: &Scene) -> Result<crate::shard::RenderKey> {
    Ok(scene_file_key(path, scene)?
        .part(settings_fingerprint(&scene.settings, &scene.camera, &scene.media.medium).as_bytes()))
}

/// The part of a render's key that comes from files: the scene file's text and the volume
/// file's path and size. A volume edited in place at the same size is not told apart (hashing
/// a gigavoxel for every shard would cost more than it guards).
pub fn scene_file_key(path: &Path, scene: &Scene) -> Result<crate::shard::RenderKey> {
    let text = crate::io::read_text_file(path, "a scene file")?;
    let volume_bytes = std::fs::metadata(&scene.volume_path)
        .map_err(|e| Error::io(&scene.volume_path, e))?
        .len();
    Ok(crate::shard::RenderKey::new()
        .part(text.as_bytes())
        .part(scene.volume_path.to_string_lossy().as_bytes())
        .part(&volume_bytes.to_le_bytes()))
}

/// The settings that decide a render's pixels besides the media (samples, seed, path
/// settings, camera, macrocells, clipping), as text for a key.
pub fn settings_fingerprint(settings: &RenderSettings, camera: &Camera, medium: &Medium) -> String {
    let mut text = format!(
        "{settings:?}|{camera:?}|macrocell {}",
        medium.majorants().cell_size()
    );
    // Clipping given on the command line or from Python is not in the scene file's text; an
    // unclipped render keeps the key it had before clipping existed.
    if !medium.clipping().is_empty() {
        text.push_str(&format!("|clip {:?}", medium.clipping()));
    }
    // Likewise channels (a Python scene's are not in a file's text).
    for c in medium.channels() {
        text.push_str(&format!("|channel {} {:?}", c.index, c.transfer_function()));
    }
    text
}

/// Builds a scene from its parsed description; `path` names the file in errors and anchors
/// relative paths.
pub fn build_scene(path: &Path, desc: SceneFile) -> Result<Scene> {
    let base = path.parent().unwrap_or(Path::new("."));
    let v = &desc.volume;
    let volume_path = base.join(&v.file);
    let loaded = read_volume(&volume_path, &read_hints(v, v.channel))?;
    build_scene_with_volume(path, desc, loaded, volume_path)
}

/// How the `[volume]` table `v` says its file is read, at channel `channel`.
fn read_hints(v: &VolumeDesc, channel: u32) -> ReadHints {
    ReadHints {
        memory_budget: None,
        format: v.format,
        raw: RawLayout {
            dims: v.dims.map(UVec3::from_array),
            dtype: v.dtype,
            byte_order: v.byte_order,
            header_bytes: v.header_bytes,
        },
        zarr: crate::io::ZarrSelection {
            level: v.level,
            channel,
            time: v.time,
        },
    }
}

/// Builds a scene from its description around a volume already in memory (a program's own
/// array: the Python package's `Volume.from_array`); the description's `volume.file` and its
/// reading hints are not used, its placement (spacing, origin, filter, macrocell) is.
/// `volume_path` names the volume in messages.
pub fn build_scene_with_volume(
    path: &Path,
    desc: SceneFile,
    loaded: crate::io::LoadedVolume,
    volume_path: PathBuf,
) -> Result<Scene> {
    let scene_err = |m: String| Error::Scene {
        path: path.into(),
        message: m,
    };
    let base = path.parent().unwrap_or(Path::new("."));
    let v = &desc.volume;
    let grid = loaded.grid;
    let spacing = v.spacing.map(vec3).or(loaded.spacing).unwrap_or(Vec3::ONE);
    // The file's unit goes with the file's spacing: a scene that sets its own spacing names
    // its unit too, or has none.
    let units = v
        .units
        .clone()
        .or(loaded.units.filter(|_| v.spacing.is_none()));
    if let Some(u) = &units
        && (u.is_empty() || u.chars().count() > 16 || u.chars().any(char::is_control))
    {
        return Err(scene_err(format!(
            "[volume] units {u:?}: expected 1 to 16 characters, none a control character"
        )));
    }
    let size = grid.dims().as_vec3() * spacing;
    let origin = v.origin.map(vec3).unwrap_or(-0.5 * size);

    let t = &desc.transfer;
    let window = match t.window {
        Some([lo, hi]) => (lo, hi),
        None => {
            let (lo, hi) = grid.range();
            if hi > lo { (lo, hi) } else { (lo, lo + 1.0) }
        }
    };
    let tf_err = |e: Error| scene_err(e.to_string());
    let tf = match (&t.points, &t.preset) {
        (Some(points), None) => {
            let pts: Vec<(f32, Vec3, f32)> = points
                .iter()
                .map(|p| (p.value, vec3(p.color), p.opacity))
                .collect();
            TransferFunction::from_points(window, &pts, t.density_scale).map_err(tf_err)?
        }
        (None, Some(preset)) => {
            let (colour, preset_opacity) =
                read_paraview_preset(&base.join(preset), t.preset_name.as_deref())?;
            let opacity = match (&t.opacity, preset_opacity) {
                (Some(o), _) => {
                    PiecewiseLinear::new(o.iter().map(|p| (p[0], p[1])).collect(), "opacity")
                        .map_err(tf_err)?
                }
                (None, Some(o)) => o,
                (None, None) => {
                    return Err(scene_err(
                        "transfer preset has no opacity `Points`: give `opacity = [[value, opacity], ...]`"
                            .into(),
                    ));
                }
            };
            TransferFunction::new(window, colour, opacity, t.density_scale).map_err(tf_err)?
        }
        (Some(_), Some(_)) => {
            return Err(scene_err(
                "[transfer] has both `points` and `preset`: give one of them".into(),
            ));
        }
        (None, None) => {
            return Err(scene_err(
                "[transfer] needs `points = [{ value, color, opacity }, ...]` or `preset = \"file.json\"`"
                    .into(),
            ));
        }
    };
    desc.phase.validate().map_err(scene_err)?;
    let mut lights = Vec::with_capacity(desc.lights.len());
    for (i, l) in desc.lights.iter().enumerate() {
        let light = l
            .to_light()
            .and_then(|mut light| light.validate().map(|()| light))
            .map_err(|e| scene_err(format!("light {i} ({}): {e}", l.kind.name())))?;
        lights.push(light);
    }
    let env = vec3(desc.environment.radiance);
    if !(env.is_finite() && env.min_element() >= 0.0) {
        return Err(scene_err(format!(
            "environment radiance {env} invalid: expected finite values >= 0"
        )));
    }
    let tf_density_scale = tf.density_scale();
    // A streamed volume's default macrocells grow with it (see `bricks::streamed_macrocell`).
    let macrocell = match grid.bricks() {
        Some(_) if v.macrocell == DEFAULT_MACROCELL => {
            crate::bricks::streamed_macrocell(grid.dims(), DEFAULT_MACROCELL)
        }
        _ => v.macrocell,
    };
    let mut medium = Medium::new(grid, v.filter, origin, spacing, tf, macrocell)
        .map_err(|e| scene_err(e.to_string()))?;
    medium
        .set_clipping(desc.clip.clone())
        .map_err(|e| scene_err(format!("[clip]: {e}")))?;
    let c = &desc.camera;
    let camera = Camera::look_at(
        vec3(c.eye),
        vec3(c.target),
        vec3(c.up),
        c.fov_y,
        c.width,
        c.height,
    )
    .map_err(|e| scene_err(format!("camera: {e}")))?;
    ViewDesc::validate_all(&desc.views, &camera).map_err(scene_err)?;
    if desc.channels.len() > MAX_CHANNELS {
        return Err(scene_err(format!(
            "{} [[channel]] tables: expected at most {MAX_CHANNELS}",
            desc.channels.len()
        )));
    }
    // A volume from a program's array (Python's `Volume.from_array`) has no file to count in.
    let time_points = if volume_path.exists() || crate::io::is_series(&volume_path) {
        crate::io::time_points(&volume_path, &read_hints(v, v.channel))
            .map_err(|e| scene_err(e.to_string()))?
    } else {
        1
    };
    let mut channels = Vec::with_capacity(desc.channels.len());
    for (k, c) in desc.channels.iter().enumerate() {
        let what = format!("[[channel]] {k} (index {})", c.index);
        let tf = c
            .transfer_function(tf_density_scale)
            .map_err(|e| scene_err(format!("{what}: {e}")))?;
        let file = match &c.file {
            Some(f) => base.join(f),
            None if volume_path.exists() => volume_path.clone(),
            None => {
                return Err(scene_err(format!(
                    "{what}: the volume is not a file ({}): expected `file = ...` in the table",
                    volume_path.display()
                )));
            }
        };
        let index = if c.file.is_some()
            && !crate::io::Format::from_path(&file).is_some_and(|f| f == crate::io::Format::OmeZarr)
        {
            0
        } else {
            c.index
        };
        let mut hints = read_hints(v, index);
        if c.file.is_some() {
            // The channel's own file says its format (its extension).
            hints.format = None;
        }
        let grid = read_volume(&file, &hints)?.grid;
        medium
            .add_channel(c.index, grid, tf)
            .map_err(|e| scene_err(format!("{what}: {e}")))?;
        channels.push(ChannelDesc {
            file: c
                .file
                .as_ref()
                .map(|_| std::path::absolute(&file).unwrap_or(file.clone())),
            ..c.clone()
        });
    }
    let r = &desc.render;
    let max_depth = max_depth_from(r.max_depth).map_err(scene_err)?;
    if r.spp == 0 {
        return Err(scene_err(
            "[render] spp = 0: expected at least 1 sample per pixel".into(),
        ));
    }
    if !desc.output.exposure.is_finite() {
        return Err(scene_err(format!(
            "[output] exposure = {}: expected a finite number of stops",
            desc.output.exposure
        )));
    }
    let mut notes = loaded.notes;
    // The densest path across the box: a huge optical depth is almost always a units mistake
    // (a density scale per voxel given per world unit, a spacing in micrometres read as metres),
    // and it makes every path a random walk of millions of steps.
    let (lo, hi) = medium.bounds();
    let optical_depth = medium.majorants().global_max() as f64 * (hi - lo).length() as f64;
    if optical_depth > MAX_PLAUSIBLE_OPTICAL_DEPTH {
        notes.push(format!(
            "warning: the optical depth across the volume reaches {optical_depth:.3e} (density_scale \
             {} per world unit x a box {:.3e} units across): paths will take millions of steps; \
             check density_scale and the voxel spacing",
            tf_density_scale,
            (hi - lo).length()
        ));
    }
    if desc.lights.is_empty() && env.max_element() == 0.0 {
        notes.push("the scene has no light: the image will be black".into());
    }
    Ok(Scene {
        media: SceneMedia {
            medium,
            phase: desc.phase,
            lights: Lights {
                lights,
                environment: env,
            },
        },
        camera,
        up: vec3(c.up).normalize_or(Vec3::Y),
        settings: RenderSettings {
            spp: r.spp,
            seed: r.seed,
            path: PathSettings {
                integrator: r.integrator,
                max_depth,
                rr_start_depth: r.rr_start_depth,
                show_lights: r.show_lights,
            },
        },
        output: desc.output,
        notes,
        volume_path,
        views: desc.views,
        units,
        channels,
        time: v.time,
        time_points,
    })
}
