//! The messages between the page and the server, and how each is checked.
//!
//! The page sends JSON text messages ([`ClientMessage`]), at most [`MAX_MESSAGE_BYTES`] each;
//! the server answers with binary messages (each a JPEG frame) and JSON text ([`hello`], the
//! frame statistics, errors, saved files). An edit is checked as the scene file's settings are
//! (finite numbers, ranges, sizes); a bad one is answered with an error naming the field, and the
//! view goes on unchanged.

use glam::Vec3;
use render_base::Camera;
use render_session::CacheChoice;
use serde::Deserialize;
use volume_pt::scene::ViewDesc;
use volume_pt::{ClipBox, ClipPlane, Clipping, Colormap, Light, Lights, Scene, TransferFunction};

/// The largest message the server reads (the WebSocket closes on a larger one).
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;
/// The most control points an opacity curve may have.
pub const MAX_OPACITY_POINTS: usize = 64;
/// Bins of the value histogram sent to the page.
pub const HISTOGRAM_BINS: usize = 128;
/// The largest intensity factor a light or the environment may be given.
pub const MAX_INTENSITY: f32 = 1e4;

/// What the page may ask.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMessage {
    /// The camera; `moving` while the user drags (the view renders at a reduced size then).
    Camera {
        eye: [f32; 3],
        target: [f32; 3],
        up: [f32; 3],
        #[serde(default)]
        moving: bool,
    },
    /// The transfer function: a colour map, the data window, the density scale and the
    /// opacity curve as `[position in the window (0..1), opacity (0..1)]` points.
    Transfer {
        colormap: String,
        window: [f32; 2],
        density_scale: f32,
        opacity: Vec<[f32; 2]>,
    },
    /// Light `index`: the direction from the volume's centre towards it (a sphere light keeps
    /// its distance; a distant light shines from there) and a factor on its scene intensity.
    Light {
        index: usize,
        direction: [f32; 3],
        intensity: f32,
    },
    /// A factor on the scene's environment radiance.
    Environment { intensity: f32 },
    /// What is cut away of the medium, world units, as the scene file's `[clip]` table: keep
    /// what lies in `box` (if given) and behind every `plane` (the side a plane's normal
    /// points to is cut away). No box and no plane: nothing is cut.
    Clip {
        #[serde(default, rename = "box")]
        bounds: Option<ClipBox>,
        #[serde(default)]
        plane: Vec<ClipPlane>,
    },
    /// Where the camera ray through image point (`x`, `y`) first meets visible medium, and the
    /// data there (answered to this page alone with a `probe` message). `x` and `y` are
    /// fractions of the image's width and height from its top-left corner.
    Probe { x: f32, y: f32 },
    /// Keep the camera in force as the view `name` (replacing one of that name), or with
    /// `remove` forget that view. The views are saved with the scene (`[[view]]`).
    View {
        name: String,
        #[serde(default)]
        remove: bool,
    },
    /// `nee`, `cache` (the Gaussian cache), `cache-rt` (its ray-traced lookup), `unbiased` (the
    /// unbiased Gaussian cache) or `nrc` (the neural cache, where the program has it).
    Method { method: String },
    /// Denoise the shown image (where Open Image Denoise is installed).
    Denoise { on: bool },
    /// The split view: NEE on the left half, the method on the right, each given the same
    /// rendering time (the GSCache paper's comparison, live).
    Split { on: bool },
    /// The Gaussian cache's training on or off (what it has learnt is kept).
    Train { on: bool },
    /// Whether the camera sees the light spheres (they light the volume either way).
    ShowLights { on: bool },
    /// Show or hide channel `channel` (counting the scene's `[[channel]]` tables from 0): a
    /// hidden channel takes no part in the medium until shown again.
    Channel { channel: usize, visible: bool },
    /// Show time point `time` of a time series (a folder or pattern of files, an OME-Zarr
    /// store's time axis): the volume is read again; the view's edits are kept.
    Time { time: u32 },
    /// A fresh cache of the same method.
    ResetCache {},
    /// Each Gaussian cache level as drawn from the camera (answered with a `levels` message).
    Levels {},
    /// Write the image, the scene and the cache into the output folder (a struct variant, so
    /// that unknown fields are refused as on every other message).
    Save {},
    /// The page's view area in device pixels (sent on load and on resize): the view renders
    /// at this size times the resolution scale, within the viewer's `--max-size`.
    Viewport { width: u32, height: u32 },
    /// The resolution scale: the rendered image's size against the page's view area.
    Scale { scale: f32 },
}

/// A message checked and turned into what the render thread does.
#[derive(Debug, Clone)]
pub enum Change {
    Camera { camera: Camera, moving: bool },
    Transfer(TransferFunction, TransferSettings),
    Lights(Lights, Vec<(Vec3, f32)>, f32),
    Clip(Clipping),
    Probe { x: f32, y: f32 },
    View { name: String, remove: bool },
    Method(Method),
    Denoise(bool),
    Split(bool),
    Train(bool),
    ShowLights(bool),
    Channel { channel: usize, visible: bool },
    Time(u32),
    ResetCache,
    Levels,
    Save,
    Viewport { width: u32, height: u32 },
    Scale(f32),
}

/// The largest view area a page may report, per side in device pixels (an 8K display's).
pub const MAX_VIEWPORT: u32 = 8192;
/// The resolution scales a page may ask for.
pub const SCALES: std::ops::RangeInclusive<f32> = 0.1..=2.0;

/// The transfer function as the page edits it (kept to write the scene file back).
#[derive(Debug, Clone, PartialEq)]
pub struct TransferSettings {
    /// A preset, or `None` for the scene's own colours.
    pub colormap: Option<Colormap>,
    pub window: [f32; 2],
    pub density_scale: f32,
    pub opacity: Vec<[f32; 2]>,
}

/// The methods the page offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    Nee,
    Cache,
    CacheRt,
    Unbiased,
    Nrc,
}

impl Method {
    /// Every method, in the page's order.
    pub const ALL: [Method; 5] = [
        Method::Nee,
        Method::Cache,
        Method::CacheRt,
        Method::Unbiased,
        Method::Nrc,
    ];

    /// The name the page and the command line use.
    pub fn name(self) -> &'static str {
        match self {
            Method::Nee => "nee",
            Method::Cache => "cache",
            Method::CacheRt => "cache-rt",
            Method::Unbiased => "unbiased",
            Method::Nrc => "nrc",
        }
    }

    /// Whether this build has the method (the neural cache is a feature).
    fn is_built(self) -> bool {
        self != Method::Nrc || cfg!(feature = "nrc")
    }

    fn parse(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.is_built() && m.name() == s)
            .ok_or_else(|| {
                format!(
                    "method `{s}`: expected one of {}",
                    Self::available().join(", ")
                )
            })
    }

    /// The names this build offers.
    pub fn available() -> Vec<&'static str> {
        Self::ALL
            .into_iter()
            .filter(|m| m.is_built())
            .map(Method::name)
            .collect()
    }

    /// The session's cache for this method; one whose image will be `denoised` reads its
    /// levels only where they have earned trust ([`gs_cache::CacheConfig::for_denoiser`]).
    pub fn cache_choice(self, denoised: bool) -> CacheChoice {
        use gs_cache::{CacheConfig, Lookup};
        let algorithm_1 = |config: CacheConfig| {
            CacheChoice::gaussian(if denoised {
                config.for_denoiser()
            } else {
                config
            })
        };
        match self {
            Method::Nee => CacheChoice::None,
            Method::Cache => algorithm_1(CacheConfig::default()),
            Method::CacheRt => algorithm_1(CacheConfig {
                lookup: Lookup::Rt,
                ..Default::default()
            }),
            Method::Unbiased => CacheChoice::gaussian(CacheConfig {
                unbiased: true,
                ..Default::default()
            }),
            #[cfg(feature = "nrc")]
            Method::Nrc => CacheChoice::Neural(nrc_cache::NrcConfig::default()),
            #[cfg(not(feature = "nrc"))]
            Method::Nrc => CacheChoice::None,
        }
    }
}

/// What the page is told of the scene when it connects, and what an edit is checked against:
/// the scene as loaded.
#[derive(Debug, Clone)]
pub struct SceneFacts {
    /// The volume's box centre: cameras orbit it and lights move about it.
    pub centre: Vec3,
    /// The volume's box, world units (the page places clip boxes and planes in it).
    pub bounds: [Vec3; 2],
    /// The data range.
    pub range: [f32; 2],
    /// The scene's own lights and environment (intensity factors are relative to these).
    pub lights: Lights,
    /// The value histogram over the data range, [`HISTOGRAM_BINS`] bins.
    pub histogram: Vec<u64>,
    /// The scene's transfer function (its colours stay available as a colour map).
    pub transfer: TransferFunction,
    pub width: u32,
    pub height: u32,
    pub fov_y: f32,
    /// The scene's up (its camera table's `up`): the page orbits about it.
    pub up: Vec3,
    /// What the page's data panel shows: the volume's file, size, spacing, type and memory.
    pub data: DataFacts,
    /// The channels rendered with the first (the scene's `[[channel]]` tables), as the scene
    /// classified them.
    pub channels: Vec<ChannelFacts>,
    /// The volume's time points (1 for most volumes).
    pub time_points: u32,
}

/// A channel rendered with the first, as the scene gave it.
#[derive(Debug, Clone)]
pub struct ChannelFacts {
    /// Its index on the image's channel axis.
    pub index: u32,
    /// Its colour (the top of its window).
    pub color: [f32; 3],
    /// Its classification when shown.
    pub transfer: TransferFunction,
}

/// The volume as the page's data panel shows it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DataFacts {
    /// The volume file's name (not its folder: the page is no place for the machine's paths).
    pub file: String,
    pub dims: [u32; 3],
    /// World size of a voxel (the scene's units, as the file or the scene gave them).
    pub spacing: [f32; 3],
    /// Their unit, where the scene or the file names one.
    pub units: Option<String>,
    /// How the voxels are stored: `uint8`, `int8`, `uint16`, `int16` or `float32`.
    pub dtype: &'static str,
    /// Bytes the voxels take, and the whole medium with its majorants.
    pub voxel_bytes: usize,
    pub medium_bytes: usize,
}

impl SceneFacts {
    pub fn of(scene: &Scene) -> Self {
        let medium = &scene.media.medium;
        let (lo, hi) = medium.bounds();
        let grid = medium.grid();
        let (min, max) = grid.range();
        Self {
            data: DataFacts {
                file: scene
                    .volume_path
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                dims: grid.dims().to_array(),
                spacing: medium.spacing().to_array(),
                units: scene.units.clone(),
                dtype: grid.type_name(),
                voxel_bytes: grid.bytes(),
                medium_bytes: medium.memory_bytes(),
            },
            centre: 0.5 * (lo + hi),
            bounds: [lo, hi],
            range: [min, max],
            lights: scene.media.lights.clone(),
            histogram: histogram(grid, min, max),
            transfer: medium.transfer_function().clone(),
            width: scene.camera.width,
            height: scene.camera.height,
            fov_y: scene.camera.fov_y_degrees,
            up: scene.up,
            time_points: scene.time_points.max(1),
            channels: medium
                .channels()
                .iter()
                .map(|c| ChannelFacts {
                    index: c.index,
                    color: c.transfer_function().albedo_at(1.0).to_array(),
                    transfer: c.transfer_function().clone(),
                })
                .collect(),
        }
    }
}

/// A histogram of about a million voxels spread over the box (every voxel of a smaller one;
/// a streamed volume's from its survey).
fn histogram(grid: &volume_pt::ScalarGrid, min: f32, max: f32) -> Vec<u64> {
    let mut bins = vec![0u64; HISTOGRAM_BINS];
    let width = (max - min).max(f32::MIN_POSITIVE);
    let values = grid
        .strided_values(volume_pt::grid::histogram_stride(grid.dims()))
        .unwrap_or_default();
    for v in values {
        if v.is_finite() {
            let u = ((v - min) / width).clamp(0.0, 1.0);
            bins[((u * HISTOGRAM_BINS as f32) as usize).min(HISTOGRAM_BINS - 1)] += 1;
        }
    }
    bins
}

fn finite3(name: &str, v: [f32; 3]) -> Result<Vec3, String> {
    let v = Vec3::from_array(v);
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{name} {v}: expected finite numbers"))
    }
}

fn intensity(name: &str, k: f32) -> Result<f32, String> {
    if (0.0..=MAX_INTENSITY).contains(&k) {
        Ok(k)
    } else {
        Err(format!(
            "{name} intensity {k}: expected 0 to {MAX_INTENSITY}"
        ))
    }
}

/// The colour-map name that keeps the scene's own colours.
pub const SCENE_COLOURS: &str = "scene";

/// The transfer function the page described, checked. `scene` gives the colours for the
/// colour map [`SCENE_COLOURS`].
pub fn transfer_function(
    colormap: &str,
    window: [f32; 2],
    density_scale: f32,
    opacity: &[[f32; 2]],
    scene: &TransferFunction,
) -> Result<(TransferFunction, TransferSettings), String> {
    let colormap: Option<Colormap> = if colormap == SCENE_COLOURS {
        None
    } else {
        Some(
            colormap
                .parse()
                .map_err(|e| format!("{e}, or {SCENE_COLOURS}"))?,
        )
    };
    let [lo, hi] = window;
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Err(format!(
            "window [{lo}, {hi}]: expected two finite values, the first below the second"
        ));
    }
    if !(density_scale > 0.0 && density_scale <= 1e6) {
        return Err(format!(
            "density scale {density_scale}: expected a value above 0 and at most 1e6"
        ));
    }
    if opacity.len() < 2 || opacity.len() > MAX_OPACITY_POINTS {
        return Err(format!(
            "{} opacity points: expected 2 to {MAX_OPACITY_POINTS}",
            opacity.len()
        ));
    }
    let mut last = f32::NEG_INFINITY;
    for (i, &[u, o]) in opacity.iter().enumerate() {
        if !((0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&o)) {
            return Err(format!(
                "opacity point {i} ({u}, {o}): expected a position and an opacity in [0, 1]"
            ));
        }
        if !(u > last) {
            return Err(format!(
                "opacity point {i} at {u}: expected positions in increasing order"
            ));
        }
        last = u;
    }
    let settings = TransferSettings {
        colormap,
        window,
        density_scale,
        opacity: opacity.to_vec(),
    };
    let points = settings.points(scene);
    let tf = TransferFunction::from_points((lo, hi), &points, density_scale)
        .map_err(|e| e.to_string())?;
    Ok((tf, settings))
}

impl TransferSettings {
    /// The control points `(position, colour, opacity)` of the function: the colour follows the
    /// map (or the scene's colours) along the window, the opacity the curve; both are sampled at
    /// the curve's points and at 16 steps between, so the map's colours are kept.
    pub fn points(&self, scene: &TransferFunction) -> Vec<(f32, Vec3, f32)> {
        let opacity = &self.opacity;
        let mut positions: Vec<f32> = opacity.iter().map(|p| p[0]).collect();
        positions.extend((0..=16).map(|k| k as f32 / 16.0));
        positions.sort_by(f32::total_cmp);
        positions.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
        let opacity_at = |u: f32| -> f32 {
            let i = opacity.partition_point(|p| p[0] <= u);
            if i == 0 {
                opacity[0][1]
            } else if i == opacity.len() {
                opacity[opacity.len() - 1][1]
            } else {
                let ([u0, o0], [u1, o1]) = (opacity[i - 1], opacity[i]);
                o0 + (o1 - o0) * (u - u0) / (u1 - u0)
            }
        };
        positions
            .iter()
            .map(|&u| {
                let colour = match self.colormap {
                    Some(map) => map.at(u),
                    None => scene.albedo_at(u),
                };
                (u, colour, opacity_at(u))
            })
            .collect()
    }
}

/// The state of the lights the page has set: per scene light its direction from the centre and
/// intensity factor, and the environment's factor.
#[derive(Debug, Clone, PartialEq)]
pub struct LightSettings {
    pub lights: Vec<(Vec3, f32)>,
    pub environment: f32,
}

impl LightSettings {
    pub fn of(facts: &SceneFacts) -> Self {
        Self {
            lights: facts
                .lights
                .lights
                .iter()
                .map(|l| (light_direction(l, facts.centre), 1.0))
                .collect(),
            environment: 1.0,
        }
    }

    /// The scene's lights with these settings applied. A light whose direction is the scene's
    /// own stays where the scene put it, bit for bit (rebuilt from its direction it moved by
    /// roundings: an intensity edit once saved [70, 80, 60] as [69.81, 80.20, 59.96]).
    pub fn lights(&self, facts: &SceneFacts) -> Lights {
        let mut out = facts.lights.clone();
        for (light, &(dir, k)) in out.lights.iter_mut().zip(&self.lights) {
            let moved = dir != light_direction(light, facts.centre);
            match light {
                Light::Sphere(s) => {
                    if moved {
                        let distance = (s.center - facts.centre).length();
                        s.center = facts.centre + dir * distance;
                    }
                    s.radiance *= k;
                }
                Light::Distant(d) => {
                    if moved {
                        d.direction = -dir;
                    }
                    d.irradiance *= k;
                }
            }
        }
        out.environment *= self.environment;
        out
    }
}

/// The unit direction from `centre` towards `light`.
pub fn light_direction(light: &Light, centre: Vec3) -> Vec3 {
    match light {
        Light::Sphere(s) => (s.center - centre).try_normalize().unwrap_or(Vec3::Y),
        Light::Distant(d) => (-d.direction).try_normalize().unwrap_or(Vec3::Y),
    }
}

/// Checks `message` against the scene and the current light settings.
pub fn check(
    message: ClientMessage,
    facts: &SceneFacts,
    lights: &LightSettings,
) -> Result<Change, String> {
    match message {
        ClientMessage::Camera {
            eye,
            target,
            up,
            moving,
        } => {
            let (eye, target, up) = (
                finite3("eye", eye)?,
                finite3("target", target)?,
                finite3("up", up)?,
            );
            if eye.abs().max_element() > render_base::MAX_COORDINATE
                || target.abs().max_element() > render_base::MAX_COORDINATE
            {
                return Err(format!(
                    "camera at {eye} looking at {target}: expected coordinates within {}",
                    render_base::MAX_COORDINATE
                ));
            }
            let camera = Camera::look_at(eye, target, up, facts.fov_y, facts.width, facts.height)
                .map_err(|e| format!("camera: {e}"))?;
            Ok(Change::Camera { camera, moving })
        }
        ClientMessage::Transfer {
            colormap,
            window,
            density_scale,
            opacity,
        } => {
            let (tf, settings) =
                transfer_function(&colormap, window, density_scale, &opacity, &facts.transfer)?;
            Ok(Change::Transfer(tf, settings))
        }
        ClientMessage::Light {
            index,
            direction,
            intensity: k,
        } => {
            let n = lights.lights.len();
            if index >= n {
                return Err(format!(
                    "light {index}: the scene has {n} light{}",
                    if n == 1 { "" } else { "s" }
                ));
            }
            let dir = finite3("light direction", direction)?
                .try_normalize()
                .ok_or("light direction [0, 0, 0]: expected a direction")?;
            let k = intensity("light", k)?;
            let mut next = lights.clone();
            // The direction the page sent back unchanged (an intensity edit) is the one in
            // force, bit for bit: normalising it again could move it by a rounding.
            let current = lights.lights[index].0;
            let dir = if dir.abs_diff_eq(current, 1e-6) {
                current
            } else {
                dir
            };
            next.lights[index] = (dir, k);
            Ok(Change::Lights(
                next.lights(facts),
                next.lights,
                next.environment,
            ))
        }
        ClientMessage::Environment { intensity: k } => {
            let k = intensity("environment", k)?;
            let next = LightSettings {
                environment: k,
                ..lights.clone()
            };
            Ok(Change::Lights(
                next.lights(facts),
                next.lights,
                next.environment,
            ))
        }
        ClientMessage::Clip { bounds, plane } => {
            let clipping = Clipping {
                bounds,
                planes: plane,
            };
            clipping.validate()?;
            Ok(Change::Clip(clipping))
        }
        ClientMessage::Probe { x, y } => {
            // Written so that NaN fails.
            if !((0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y)) {
                return Err(format!(
                    "probe at ({x}, {y}): expected fractions of the image in [0, 1]"
                ));
            }
            Ok(Change::Probe { x, y })
        }
        ClientMessage::View { name, remove } => Ok(Change::View { name, remove }),
        ClientMessage::Method { method } => Ok(Change::Method(Method::parse(&method)?)),
        ClientMessage::Denoise { on } => Ok(Change::Denoise(on)),
        ClientMessage::Split { on } => Ok(Change::Split(on)),
        ClientMessage::Train { on } => Ok(Change::Train(on)),
        ClientMessage::ShowLights { on } => Ok(Change::ShowLights(on)),
        ClientMessage::Channel { channel, visible } => {
            let n = facts.channels.len();
            if channel >= n {
                return Err(format!(
                    "channel {channel}: the scene has {n} [[channel]] table{}",
                    if n == 1 { "" } else { "s" }
                ));
            }
            Ok(Change::Channel { channel, visible })
        }
        ClientMessage::Time { time } => {
            if time >= facts.time_points {
                return Err(format!(
                    "time {time}: the volume has {} time point{} (0 to {})",
                    facts.time_points,
                    if facts.time_points == 1 { "" } else { "s" },
                    facts.time_points - 1
                ));
            }
            Ok(Change::Time(time))
        }
        ClientMessage::ResetCache {} => Ok(Change::ResetCache),
        ClientMessage::Levels {} => Ok(Change::Levels),
        ClientMessage::Save {} => Ok(Change::Save),
        ClientMessage::Viewport { width, height } => {
            if !(1..=MAX_VIEWPORT).contains(&width) || !(1..=MAX_VIEWPORT).contains(&height) {
                return Err(format!(
                    "viewport {width}x{height}: expected 1 to {MAX_VIEWPORT} device pixels a side"
                ));
            }
            Ok(Change::Viewport { width, height })
        }
        ClientMessage::Scale { scale } => {
            // Written so that NaN is refused.
            if !SCALES.contains(&scale) {
                return Err(format!(
                    "resolution scale {scale}: expected {} to {}",
                    SCALES.start(),
                    SCALES.end()
                ));
            }
            Ok(Change::Scale(scale))
        }
    }
}

/// Parses a text message, naming what is wrong with it.
pub fn parse(text: &str) -> Result<ClientMessage, String> {
    if text.len() > MAX_MESSAGE_BYTES {
        return Err(format!(
            "a message of {} bytes: expected at most {MAX_MESSAGE_BYTES}",
            text.len()
        ));
    }
    serde_json::from_str(text).map_err(|e| format!("message not understood: {e}"))
}

/// What the page is told of the view: everything it shows, so that a page that reloads or
/// reconnects shows the server's whole state.
#[derive(Debug, Clone, Copy)]
pub struct ViewState<'a> {
    pub camera: &'a Camera,
    pub transfer: &'a TransferSettings,
    pub lights: &'a LightSettings,
    /// What is cut away of the medium.
    pub clip: &'a Clipping,
    /// The named views (bookmarks).
    pub views: &'a [ViewDesc],
    /// The transfer function in force (its colours make the page's colour bar).
    pub tf: &'a TransferFunction,
    pub method: Method,
    pub show_lights: bool,
    /// The split view is on.
    pub split: bool,
    /// Denoising is on.
    pub denoise: bool,
    /// Whether the denoiser is offered (its library was found).
    pub denoiser: bool,
    /// Per `[[channel]]` table, whether it is shown.
    pub channels_visible: &'a [bool],
    /// The time point shown.
    pub time: u32,
    /// The resolution scale, and the size the view renders at.
    pub scale: f32,
    pub size: (u32, u32),
}

/// Samples of the colour bar: the transfer function's colour (its scattering albedo) at
/// [`COLOUR_BAR_SAMPLES`] evenly spaced points of its window.
pub fn colour_bar(tf: &TransferFunction) -> Vec<[f32; 3]> {
    (0..COLOUR_BAR_SAMPLES)
        .map(|k| {
            tf.albedo_at(k as f32 / (COLOUR_BAR_SAMPLES - 1) as f32)
                .to_array()
        })
        .collect()
}

/// How many colours the page's colour bar is drawn from.
pub const COLOUR_BAR_SAMPLES: usize = 64;

/// The greeting a page gets on connecting: the scene's facts and the view's whole state.
pub fn hello(facts: &SceneFacts, view: &ViewState<'_>) -> serde_json::Value {
    let ViewState {
        camera,
        transfer,
        lights,
        clip,
        views,
        tf,
        method,
        show_lights,
        split,
        denoise,
        denoiser,
        channels_visible,
        time,
        scale,
        size,
    } = *view;
    let (_, down, forward) = camera.axes();
    // The page orbits its target: the point in front of the camera nearest the volume's centre.
    let target =
        camera.position + forward * (facts.centre - camera.position).dot(forward).max(1e-3);
    // About the scene's up (the image's up tilts with the view: orbiting about it turned the
    // volume about a slanted axis), unless the view looks along it.
    let up = if facts.up.dot(forward).abs() < 0.999 {
        facts.up
    } else {
        -down
    };
    serde_json::json!({
        "type": "hello",
        "width": facts.width,
        "height": facts.height,
        "centre": facts.centre.to_array(),
        "bounds": [facts.bounds[0].to_array(), facts.bounds[1].to_array()],
        "camera": {
            "eye": camera.position.to_array(),
            "target": target.to_array(),
            "up": up.to_array(),
            "fov_y": facts.fov_y,
        },
        "range": facts.range,
        "histogram": facts.histogram,
        "colormaps": std::iter::once(SCENE_COLOURS.to_string())
            .chain(Colormap::ALL.iter().map(|c| c.to_string()))
            .collect::<Vec<_>>(),
        "transfer": {
            "colormap": transfer.colormap.map_or(SCENE_COLOURS.to_string(), |c| c.to_string()),
            "window": transfer.window,
            "density_scale": transfer.density_scale,
            "opacity": transfer.opacity,
        },
        "lights": lights.lights.iter().zip(&facts.lights.lights).map(|((d, k), l)| serde_json::json!({
            "kind": match l { Light::Sphere(_) => "sphere", Light::Distant(_) => "distant" },
            "direction": d.to_array(),
            "intensity": k,
        })).collect::<Vec<_>>(),
        "environment": lights.environment,
        "clip": clip,
        "views": views,
        "colours": colour_bar(tf),
        "data": facts.data,
        "channels": facts.channels.iter().zip(channels_visible).map(|(c, v)| serde_json::json!({
            "index": c.index,
            "color": c.color,
            "visible": v,
        })).collect::<Vec<_>>(),
        "time": time,
        "time_points": facts.time_points,
        "show_lights": show_lights,
        "methods": Method::available(),
        "method": method.name(),
        "denoiser": denoiser,
        "split": split,
        "denoise": denoise,
        "scale": scale,
        "view_width": size.0,
        "view_height": size.1,
        "max_message_bytes": MAX_MESSAGE_BYTES,
    })
}

/// The page's transfer-function settings for the scene's own function: its colours, and its
/// opacity curve sampled at `steps + 1` points.
pub fn transfer_settings_of(tf: &TransferFunction, steps: usize) -> TransferSettings {
    let (lo, hi) = tf.window();
    // The function's own control points where the page can edit them (inside the window, few
    // enough); a curve defined beyond the window (a preset's) is sampled instead.
    let own: Vec<[f32; 2]> = tf.opacity_points().map(|(u, o)| [u, o]).collect();
    let editable = (2..=MAX_OPACITY_POINTS).contains(&own.len())
        && own.first().is_some_and(|p| p[0] == 0.0)
        && own.last().is_some_and(|p| p[0] == 1.0)
        && own.windows(2).all(|w| w[0][0] < w[1][0])
        && own.iter().all(|p| (0.0..=1.0).contains(&p[1]));
    if editable {
        return TransferSettings {
            colormap: None,
            window: [lo, hi],
            density_scale: tf.density_scale(),
            opacity: own,
        };
    }
    let opacity = (0..=steps)
        .map(|k| {
            let u = k as f32 / steps as f32;
            [u, tf.opacity_at(u).clamp(0.0, 1.0)]
        })
        .collect();
    TransferSettings {
        colormap: None,
        window: [lo, hi],
        density_scale: tf.density_scale(),
        opacity,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_transfer_functions_are_named() {
        let ok = [[0.0, 0.0], [1.0, 1.0]];
        let scene = TransferFunction::from_points(
            (0.0, 1.0),
            &[(0.0, Vec3::ZERO, 0.0), (1.0, Vec3::ONE, 1.0)],
            1.0,
        )
        .unwrap();
        assert!(transfer_function("viridis", [0.0, 1.0], 1.0, &ok, &scene).is_ok());
        let (tf, _) = transfer_function(SCENE_COLOURS, [0.0, 1.0], 1.0, &ok, &scene).unwrap();
        assert_eq!(tf.albedo_at(0.5), Vec3::splat(0.5));
        /// Colour map, window, density scale, opacity points, and what the error names.
        type Case = (&'static str, [f32; 2], f32, Vec<[f32; 2]>, &'static str);
        let cases: [Case; 7] = [
            ("nope", [0.0, 1.0], 1.0, ok.to_vec(), "colour map"),
            ("viridis", [1.0, 0.0], 1.0, ok.to_vec(), "window"),
            ("viridis", [f32::NAN, 1.0], 1.0, ok.to_vec(), "window"),
            (
                "viridis",
                [0.0, 1.0],
                f32::NAN,
                ok.to_vec(),
                "density scale",
            ),
            (
                "viridis",
                [0.0, 1.0],
                1.0,
                vec![[0.0, 0.0]],
                "opacity points",
            ),
            (
                "viridis",
                [0.0, 1.0],
                1.0,
                vec![[0.5, 0.0], [0.2, 1.0]],
                "increasing",
            ),
            (
                "viridis",
                [0.0, 1.0],
                1.0,
                vec![[0.0, 0.0], [1.0, 2.0]],
                "in [0, 1]",
            ),
        ];
        for (map, window, scale, opacity, expected) in cases {
            let e = transfer_function(map, window, scale, &opacity, &scene).unwrap_err();
            assert!(e.contains(expected), "{e}");
        }
    }

    #[test]
    fn messages_parse_and_garbage_is_named() {
        assert_eq!(
            parse(r#"{"type":"denoise","on":true}"#).unwrap(),
            ClientMessage::Denoise { on: true }
        );
        for bad in [
            "",
            "{",
            "[]",
            r#"{"type":"fly"}"#,
            r#"{"type":"save","x":1}"#,
        ] {
            assert!(parse(bad).unwrap_err().contains("not understood"), "{bad}");
        }
        let huge = format!(
            r#"{{"type":"save","pad":"{}"}}"#,
            "x".repeat(MAX_MESSAGE_BYTES)
        );
        assert!(parse(&huge).unwrap_err().contains("at most"));
    }
}
