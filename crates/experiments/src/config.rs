//! The experiment file (TOML): what to render, which methods, at which budgets, against which
//! reference. Every key is documented in `docs/experiment-format.md`; relative paths are
//! resolved against the experiment file's folder.

use crate::camera_path::{Keyframe, check_keyframes};
use crate::error::{Error, Result, Within, refuse};
pub use crate::method::{CacheDesc, MethodCache, MethodSpec, NrcDesc};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use volume_pt::IntegratorKind;

/// The whole file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentFile {
    /// Names the output folder and the report; default: the file's stem.
    pub name: Option<String>,
    /// The scene file.
    pub scene: PathBuf,
    /// Image size; default: the scene's.
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Each (method, budget) is rendered once per seed: the spread gives the error bars and the
    /// bias estimate. At least 3.
    #[serde(default = "default_seeds")]
    pub seeds: Vec<u64>,
    /// Where results go; default `out/experiments/<name>` under the current folder (the
    /// committed results are written only when asked: `--results-dir docs/results`).
    pub output: Option<PathBuf>,
    #[serde(default)]
    pub reference: ReferenceDesc,
    #[serde(default)]
    pub budgets: Budgets,
    /// The method the report's gains are measured against; default `nee` when there is one.
    pub baseline: Option<String>,
    #[serde(rename = "method")]
    pub methods: Vec<MethodDesc>,
    #[serde(default, rename = "flythrough")]
    pub flythroughs: Vec<FlythroughDesc>,
    #[serde(default, rename = "ablation")]
    pub ablations: Vec<AblationDesc>,
    /// Measure every method also after Intel Open Image Denoise: one twin per entry of
    /// `denoise_guides`, its time counting the filter once per image.
    #[serde(default)]
    pub denoise: bool,
    /// The denoiser's quality (default `high`).
    pub denoise_quality: Option<denoise::Quality>,
    /// The guides of each twin (default `["none", "albedo"]`: colour alone, and with the
    /// albedo feature buffer).
    pub denoise_guides: Option<Vec<denoise::Guides>>,
}

/// How the experiment's denoised twins are made.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DenoiseSpec {
    pub quality: denoise::Quality,
    pub guides: Vec<denoise::Guides>,
}

impl DenoiseSpec {
    /// The denoiser's settings for every twin: the experiment's quality and no prefiltered
    /// guides, on purpose (one filter pass, the interactive setting the time budgets charge),
    /// where `denoise::Options::default()` prefilters them.
    pub fn options(&self) -> denoise::Options {
        denoise::Options {
            quality: self.quality,
            prefilter: false,
        }
    }
}

/// The folder experiments write into, one subfolder per experiment, when neither the file nor
/// the command line names one: beside the renders' `out/`, never over committed results.
pub const DEFAULT_OUTPUT: &str = "out/experiments";

fn default_seeds() -> Vec<u64> {
    vec![1, 2, 3]
}

/// The high-spp NEE render every image is compared with.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReferenceDesc {
    pub spp: u32,
    /// Kept here between runs, named by a hash of everything that decides the image.
    pub dir: PathBuf,
}

impl Default for ReferenceDesc {
    fn default() -> Self {
        Self {
            spp: 1024,
            dir: PathBuf::from("target/experiment-references"),
        }
    }
}

/// The budgets every method is measured at: samples per pixel, and wall-clock seconds per image.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Budgets {
    pub spp: Vec<u32>,
    pub seconds: Vec<f64>,
}

impl Default for Budgets {
    fn default() -> Self {
        Self {
            spp: vec![1, 4, 16],
            seconds: vec![],
        }
    }
}

/// One method: an integrator, optionally reading a cache: the Gaussian cache (`cache`) or the
/// neural radiance cache (`nrc`).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MethodDesc {
    pub name: String,
    pub integrator: IntegratorKind,
    pub cache: Option<CacheDesc>,
    pub nrc: Option<NrcDesc>,
}

/// A camera path of `frames` frames after `warmup` frames, with scene edits on the way.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FlythroughDesc {
    pub name: String,
    pub frames: u32,
    #[serde(default)]
    pub warmup: u32,
    /// Degrees of orbit about the camera's up axis through the volume's centre over the whole
    /// run, ending at the scene camera; 0 holds the camera still (for adaptation curves).
    #[serde(default)]
    pub orbit_degrees: f32,
    /// A key-framed path instead of the orbit (frames counted from the first warm-up frame).
    #[serde(default, rename = "key")]
    pub keys: Vec<Keyframe>,
    /// Methods flown (names from `[[method]]`); default: all.
    #[serde(default)]
    pub methods: Vec<String>,
    /// Every this many frames the frame's 1-spp image is compared with a reference (made once
    /// per camera and scene state, kept on disk).
    #[serde(default = "default_error_every")]
    pub error_every: u32,
    /// Samples per pixel of those references.
    #[serde(default = "default_flythrough_reference_spp")]
    pub reference_spp: u32,
    #[serde(default, rename = "event")]
    pub events: Vec<EventDesc>,
    /// Each frame's time budget in seconds, as a user moving through the data has one: passes
    /// of one sample per pixel (tracing, and a cache's lookup and training, all charged) are
    /// added to the frame while the next fits (at least one). None: one pass a frame. Not
    /// written when unset, so older fly-throughs keep their identities.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_seconds: Option<f64>,
    /// The closing clip: this many last frames are all scored, for flicker (each frame's change
    /// against the references') and the clip's ColorVideoVDP JOD. 0 (the default, not written)
    /// scores none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub clip_frames: u32,
    /// The denoised twins' quality on this fly-through, where it differs from the experiment's
    /// `denoise_quality` (a fast filter at a short frame budget, a high one at a longer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise_quality: Option<denoise::Quality>,
}

impl FlythroughDesc {
    /// The frame rate the closing clip is shown at: what the frame budget gives, or 30 frames
    /// a second without one.
    pub fn clip_fps(&self) -> f64 {
        self.frame_seconds.map_or(30.0, |t| 1.0 / t)
    }
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

fn default_error_every() -> u32 {
    10
}

fn default_flythrough_reference_spp() -> u32 {
    256
}

/// A scene edit at a frame (counted from the first warm-up frame). A cache's learning-rate
/// schedule restarts there, as an application would do on an edit.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct EventDesc {
    pub frame: u32,
    /// Moves every light by this offset (world units).
    pub light_offset: Option<[f32; 3]>,
    /// Multiplies every light's radiance.
    pub light_scale: Option<f32>,
    /// Multiplies the transfer function's extinction (a denser or thinner medium).
    pub density_scale: Option<f32>,
    /// Replaces the scene's medium, lights and phase function by another scene file's (any
    /// transfer-function edit); the camera path is kept.
    pub scene: Option<PathBuf>,
    /// Shows time point `time` of the scene's volume (a time series, or an OME-Zarr store's
    /// time axis): the voxels read again, everything else kept.
    pub time: Option<u32>,
}

/// One parameter of a cache method swept over values; every value is measured like a method.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct AblationDesc {
    pub name: String,
    /// The `[[method]]` whose cache is varied.
    pub method: String,
    /// A key of the method's `cache` table.
    pub parameter: String,
    pub values: Vec<toml::Value>,
    /// Budgets of the sweep; default: the experiment's.
    pub budgets: Option<Budgets>,
}

/// The parsed file with its paths resolved and every method checked.
#[derive(Debug, Clone)]
pub struct Experiment {
    pub name: String,
    pub file: PathBuf,
    pub scene: PathBuf,
    pub size: Option<(u32, u32)>,
    pub seeds: Vec<u64>,
    pub output: PathBuf,
    pub reference: ReferenceDesc,
    pub budgets: Budgets,
    pub baseline: Option<String>,
    pub methods: Vec<MethodSpec>,
    pub flythroughs: Vec<FlythroughDesc>,
    pub ablations: Vec<Ablation>,
    /// The denoised twins, where the file asks for them (`denoise = true`).
    pub denoise: Option<DenoiseSpec>,
}

/// An ablation with its variants built.
#[derive(Debug, Clone)]
pub struct Ablation {
    pub name: String,
    pub parameter: String,
    pub budgets: Budgets,
    /// (value as written, the method with that value).
    pub variants: Vec<(String, MethodSpec)>,
}

/// Reads and checks an experiment file.
pub fn load_experiment(path: &Path) -> Result<Experiment> {
    let text = volume_pt::io::read_text_file(path, "an experiment file")?;
    let file: ExperimentFile = toml::from_str(&text)
        .map_err(|e| Error::file(path, format!("not a valid experiment file: {e}")))?;
    build(path, file).map_err(|e| Error::file(path, e.to_string()))
}

fn build(path: &Path, f: ExperimentFile) -> Result<Experiment> {
    let base = path.parent().unwrap_or(Path::new("."));
    let name = f.name.clone().unwrap_or_else(|| {
        path.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "experiment".into())
    });
    check_seeds(&f.seeds)?;
    check_budgets(&f.budgets, "[budgets]")?;
    if f.reference.spp == 0 {
        refuse!("[reference] spp = 0: expected at least 1 (and far more than any budget)");
    }
    let methods = build_methods(&f.methods)?;
    let baseline = match &f.baseline {
        Some(b) => Some(find_method(&methods, b, "baseline")?.name.clone()),
        None => methods
            .iter()
            .find(|m| m.name == "nee")
            .map(|m| m.name.clone()),
    };
    for fly in &f.flythroughs {
        check_flythrough(fly, &methods)?;
        if fly.denoise_quality.is_some() && !f.denoise {
            refuse!(
                "flythrough `{}`: denoise_quality without denoised twins: set `denoise = true` \
                 at the top of the file, or remove it",
                fly.name
            );
        }
    }
    let mut flythroughs = f.flythroughs.clone();
    for fly in &mut flythroughs {
        for e in &mut fly.events {
            if let Some(s) = &e.scene {
                e.scene = Some(base.join(s));
            }
        }
    }
    let ablations = f
        .ablations
        .iter()
        .map(|a| build_ablation(a, &methods, &f.budgets))
        .collect::<Result<Vec<_>>>()?;
    let size = image_size(f.width, f.height)?;
    let denoise = denoise_spec(&f, &methods)?;
    Ok(Experiment {
        denoise,
        output: f
            .output
            .map(|o| base.join(o))
            .unwrap_or_else(|| PathBuf::from(DEFAULT_OUTPUT).join(&name)),
        reference: f.reference,
        name,
        file: path.to_path_buf(),
        scene: base.join(&f.scene),
        size,
        seeds: f.seeds,
        budgets: f.budgets,
        baseline,
        methods,
        flythroughs,
        ablations,
    })
}

/// At least three seeds, each once.
fn check_seeds(seeds: &[u64]) -> Result<()> {
    if seeds.len() < 3 {
        refuse!(
            "seeds = {seeds:?}: expected at least 3 (the spread across seeds gives the error bars and the bias estimate)"
        );
    }
    let mut seen = std::collections::HashSet::new();
    for s in seeds {
        if !seen.insert(s) {
            refuse!("seed {s} is listed twice: each seed must be distinct");
        }
    }
    Ok(())
}

/// The file's `[[method]]` tables as methods, each checked, each name once.
fn build_methods(descs: &[MethodDesc]) -> Result<Vec<MethodSpec>> {
    if descs.is_empty() {
        refuse!(
            "no [[method]]: expected at least one (e.g. `name = \"nee\"`, `integrator = \"nee\"`)"
        );
    }
    let mut methods = Vec::new();
    for m in descs {
        if methods.iter().any(|x: &MethodSpec| x.name == m.name) {
            refuse!("method `{}` is defined twice", m.name);
        }
        let cache = MethodCache::from_tables(m.cache.clone(), m.nrc.clone())
            .within(|| format!("method `{}`", m.name))?;
        methods.push(MethodSpec::new(m.name.clone(), m.integrator, cache)?);
    }
    Ok(methods)
}

/// The method `name`, which `what` (a baseline, a fly-through, an ablation) names.
fn find_method<'m>(methods: &'m [MethodSpec], name: &str, what: &str) -> Result<&'m MethodSpec> {
    methods.iter().find(|m| m.name == name).ok_or_else(|| {
        Error::Invalid(format!(
            "{what} names method `{name}`, which is not a [[method]] (known: {})",
            methods
                .iter()
                .map(|m| m.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })
}

/// A fly-through's frames, methods, camera path and events, checked.
fn check_flythrough(fly: &FlythroughDesc, methods: &[MethodSpec]) -> Result<()> {
    if fly.frames == 0 {
        refuse!("flythrough `{}`: frames = 0: expected at least 1", fly.name);
    }
    if fly.error_every == 0 || fly.reference_spp == 0 {
        refuse!(
            "flythrough `{}`: error_every and reference_spp must be at least 1",
            fly.name
        );
    }
    for m in &fly.methods {
        find_method(methods, m, &format!("flythrough `{}`", fly.name))?;
    }
    if let Some(s) = fly.frame_seconds
        && !(s > 0.0 && s.is_finite())
    {
        refuse!(
            "flythrough `{}`: frame_seconds = {s}: expected a finite budget > 0",
            fly.name
        );
    }
    if fly.clip_frames > fly.frames {
        refuse!(
            "flythrough `{}`: clip_frames = {}: expected at most the {} measured frames",
            fly.name,
            fly.clip_frames,
            fly.frames
        );
    }
    if fly.clip_frames > 0 && fly.clip_fps() > 16384.0 {
        refuse!(
            "flythrough `{}`: a clip shown at {:.0} frames a second (frame_seconds = {:?}): \
             ColorVideoVDP takes at most 16384",
            fly.name,
            fly.clip_fps(),
            fly.frame_seconds
        );
    }
    if !fly.orbit_degrees.is_finite() {
        refuse!(
            "flythrough `{}`: orbit_degrees = {}: expected a finite angle",
            fly.name,
            fly.orbit_degrees
        );
    }
    let last_frame = fly.warmup.saturating_add(fly.frames);
    for e in &fly.events {
        check_event(e, &fly.name)?;
        if e.frame >= last_frame {
            refuse!(
                "flythrough `{}`: the event at frame {} is past the last frame ({} warm-up + \
                 {} frames, counted from 0): it would never happen",
                fly.name,
                e.frame,
                fly.warmup,
                fly.frames
            );
        }
    }
    if !fly.keys.is_empty() {
        check_keyframes(&fly.keys).within(|| format!("flythrough `{}`", fly.name))?;
        if fly.orbit_degrees != 0.0 {
            refuse!(
                "flythrough `{}`: both orbit_degrees and [[flythrough.key]]: expected one camera path",
                fly.name
            );
        }
    }
    Ok(())
}

/// An ablation's variants: its method with one key of its Gaussian cache's table set to each
/// value (budgets: the ablation's, else the experiment's).
fn build_ablation(a: &AblationDesc, methods: &[MethodSpec], budgets: &Budgets) -> Result<Ablation> {
    let m = find_method(methods, &a.method, &format!("ablation `{}`", a.name))?;
    let Some(cache) = m.cache.gaussian() else {
        refuse!(
            "ablation `{}` varies method `{}`, which has no Gaussian cache (ablations vary a `cache` table's keys; to compare neural cache settings, give each its own [[method]])",
            a.name,
            a.method
        );
    };
    let budgets = a.budgets.clone().unwrap_or_else(|| budgets.clone());
    check_budgets(&budgets, &format!("ablation `{}` budgets", a.name))?;
    if a.values.is_empty() {
        refuse!("ablation `{}` has no values", a.name);
    }
    let mut variants = Vec::new();
    for v in &a.values {
        let varied =
            with_parameter(cache, &a.parameter, v).within(|| format!("ablation `{}`", a.name))?;
        let label = value_label(v);
        let name = format!("{} [{}={}]", m.name, a.parameter, label);
        let varied = MethodSpec::new(name, m.integrator, MethodCache::Gaussian(varied))?;
        variants.push((label, varied));
    }
    Ok(Ablation {
        name: a.name.clone(),
        parameter: a.parameter.clone(),
        budgets,
        variants,
    })
}

/// `width` and `height`: both or neither (the scene's size).
fn image_size(width: Option<u32>, height: Option<u32>) -> Result<Option<(u32, u32)>> {
    match (width, height) {
        (Some(w), Some(h)) if w > 0 && h > 0 => {
            let most = splat_raster::camera::MAX_IMAGE_SIDE;
            if w > most || h > most {
                refuse!("width and height {w}x{h}: expected at most {most} pixels a side");
            }
            Ok(Some((w, h)))
        }
        (None, None) => Ok(None),
        _ => refuse!("width and height: give both, each at least 1, or neither"),
    }
}

/// The denoised twins the file asks for: their guides listed once each, no twin's name taken
/// by a method.
fn denoise_spec(f: &ExperimentFile, methods: &[MethodSpec]) -> Result<Option<DenoiseSpec>> {
    if !f.denoise {
        if f.denoise_quality.is_some() || f.denoise_guides.is_some() {
            refuse!(
                "denoise_quality and denoise_guides set the denoised twins: add `denoise = true`"
            );
        }
        return Ok(None);
    }
    let guides = f
        .denoise_guides
        .clone()
        .unwrap_or_else(|| vec![denoise::Guides::None, denoise::Guides::Albedo]);
    if guides.is_empty() {
        refuse!(
            "denoise_guides = []: expected at least one of \"none\", \"albedo\", \"albedo,normal\""
        );
    }
    for (i, g) in guides.iter().enumerate() {
        if guides[..i].contains(g) {
            refuse!("denoise_guides lists \"{g}\" twice");
        }
    }
    for m in methods {
        for &g in &guides {
            let twin = m.denoised_twin(g).name;
            if methods.iter().any(|x| x.name == twin) {
                refuse!(
                    "method `{twin}` clashes with the name of `{}`'s denoised twin: rename it",
                    m.name
                );
            }
        }
    }
    Ok(Some(DenoiseSpec {
        quality: f.denoise_quality.unwrap_or_default(),
        guides,
    }))
}

fn check_budgets(b: &Budgets, what: &str) -> Result<()> {
    if b.spp.is_empty() && b.seconds.is_empty() {
        refuse!("{what}: no budget: give `spp = [...]` and/or `seconds = [...]`");
    }
    if b.spp.contains(&0) {
        refuse!("{what}: spp = {:?}: every budget must be at least 1", b.spp);
    }
    if b.seconds.iter().any(|&s| !(s > 0.0 && s.is_finite())) {
        refuse!(
            "{what}: seconds = {:?}: every budget must be finite and > 0",
            b.seconds
        );
    }
    Ok(())
}

fn check_event(e: &EventDesc, fly: &str) -> Result<()> {
    let n = [
        e.light_offset.is_some(),
        e.light_scale.is_some(),
        e.density_scale.is_some(),
        e.scene.is_some(),
        e.time.is_some(),
    ]
    .iter()
    .filter(|&&b| b)
    .count();
    if n != 1 {
        refuse!(
            "flythrough `{fly}`: the event at frame {} must have exactly one of light_offset, light_scale, density_scale, scene, time",
            e.frame
        );
    }
    if let Some(o) = e.light_offset
        && !o.iter().all(|v| v.is_finite())
    {
        refuse!(
            "flythrough `{fly}`: event at frame {}: light_offset = {o:?}: expected finite values",
            e.frame
        );
    }
    for (what, v) in [
        ("light_scale", e.light_scale),
        ("density_scale", e.density_scale),
    ] {
        if let Some(v) = v
            && !(v >= 0.0 && v.is_finite())
        {
            refuse!(
                "flythrough `{fly}`: event at frame {}: {what} = {v}: expected a finite value >= 0",
                e.frame
            );
        }
    }
    Ok(())
}

/// `cache` with one key replaced, through its TOML form so the key is checked by serde.
fn with_parameter(cache: &CacheDesc, key: &str, value: &toml::Value) -> Result<CacheDesc> {
    let mut table = toml::Table::try_from(cache)
        .map_err(|e| Error::Invalid(format!("cache settings as TOML: {e}")))?;
    if !table.contains_key(key) {
        refuse!(
            "parameter `{key}` is not a cache setting (known: {})",
            table.keys().cloned().collect::<Vec<_>>().join(", ")
        );
    }
    table.insert(key.to_string(), value.clone());
    toml::Value::Table(table).try_into().map_err(|e| {
        Error::Invalid(format!(
            "`{key} = {value}` is not a valid value for `{key}`: {e}"
        ))
    })
}

fn value_label(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gs_cache::Optimizer;

    fn parse(text: &str) -> Result<Experiment> {
        let f: ExperimentFile = toml::from_str(text).map_err(|e| Error::Invalid(e.to_string()))?;
        build(Path::new("x/e.toml"), f)
    }

    const METHODS: &str = r#"
        scene = "s.toml"
        [[method]]
        name = "nee"
        integrator = "nee"
        [[method]]
        name = "cache"
        integrator = "nee"
        cache = { points = 1000, c = 0.5 }
    "#;

    #[test]
    fn sweeps_build_one_checked_variant_per_value() {
        let e = parse(&format!(
            "{METHODS}\n[[ablation]]\nname = \"size\"\nmethod = \"cache\"\nparameter = \"points\"\nvalues = [100, 2000]\n\
             [[ablation]]\nname = \"opt\"\nmethod = \"cache\"\nparameter = \"optimizer\"\nvalues = [\"adamw\", \"adam\"]\n"
        ))
        .unwrap();
        assert_eq!(e.scene, Path::new("x/s.toml"));
        assert_eq!(e.baseline.as_deref(), Some("nee"));
        let size = &e.ablations[0];
        assert_eq!(size.variants.len(), 2);
        assert_eq!(
            size.variants[1].1.cache.gaussian().unwrap().settings.points,
            2000
        );
        assert_eq!(size.variants[1].1.cache.gaussian().unwrap().settings.c, 0.5);
        assert_eq!(size.variants[0].1.name, "cache [points=100]");
        let opt = &e.ablations[1];
        assert_eq!(
            opt.variants[1]
                .1
                .cache
                .gaussian()
                .unwrap()
                .settings
                .optimizer,
            Optimizer::Adam
        );
    }

    #[test]
    fn bad_files_name_their_fault() {
        let err = |t: &str| format!("{:#}", parse(t).unwrap_err());
        assert!(err(&format!("seeds = [1, 2]\n{METHODS}")).contains("at least 3"));
        assert!(err(&format!("{METHODS}\n[budgets]\nspp = [0]")).contains("at least 1"));
        let e = err(&format!(
            "{METHODS}\n[[ablation]]\nname = \"a\"\nmethod = \"cache\"\nparameter = \"pionts\"\nvalues = [1]"
        ));
        assert!(e.contains("`pionts` is not a cache setting"), "{e}");
        // A misspelt key in a method's cache table is refused, naming it.
        let e = err(&METHODS.replace("c = 0.5", "cc = 0.5"));
        assert!(e.contains("cc"), "{e}");
        let e = err(&format!(
            "{METHODS}\n[[ablation]]\nname = \"a\"\nmethod = \"cache\"\nparameter = \"points\"\nvalues = [\"many\"]"
        ));
        assert!(e.contains("not a valid value"), "{e}");
        // Too few points for three levels is caught when the variant is built.
        let e = err(&format!(
            "{METHODS}\n[[ablation]]\nname = \"a\"\nmethod = \"cache\"\nparameter = \"points\"\nvalues = [5]"
        ));
        assert!(e.contains("too few"), "{e}");
        let e = err(&format!(
            "{METHODS}\n[[flythrough]]\nname = \"f\"\nframes = 3\nmethods = [\"nope\"]"
        ));
        assert!(e.contains("`nope`"), "{e}");
        let e = err(&format!(
            "{METHODS}\n[[flythrough]]\nname = \"f\"\nframes = 3\n[[flythrough.event]]\nframe = 1"
        ));
        assert!(e.contains("exactly one"), "{e}");
        let key = |frame: u32| {
            format!(
                "[[flythrough.key]]\nframe = {frame}\neye = [0.0, 0.0, 9.0]\ntarget = [0.0, 0.0, 0.0]\n"
            )
        };
        let fly = "[[flythrough]]\nname = \"f\"\nframes = 3\n";
        let e = err(&format!("{METHODS}\n{fly}{}{}", key(2), key(1)));
        assert!(e.contains("increasing order"), "{e}");
        let e = err(&format!("{METHODS}\n{fly}orbit_degrees = 30.0\n{}", key(0)));
        assert!(e.contains("one camera path"), "{e}");
        assert!(parse(&format!("{METHODS}\n{fly}{}{}", key(0), key(2))).is_ok());
    }

    #[test]
    fn events_and_angles_that_could_never_apply_are_refused() {
        let err = |t: &str| format!("{:#}", parse(t).unwrap_err());
        let fly = "[[flythrough]]\nname = \"f\"\nframes = 3\nwarmup = 2\n";
        let event = |body: &str| format!("{METHODS}\n{fly}[[flythrough.event]]\n{body}");
        // Frames 0..5 exist (2 warm-up + 3); an event at 5 would never happen.
        let e = err(&event("frame = 5\nlight_scale = 2.0"));
        assert!(e.contains("past the last frame"), "{e}");
        assert!(parse(&event("frame = 4\nlight_scale = 2.0")).is_ok());
        let e = err(&event("frame = 1\nlight_offset = [nan, 0.0, 0.0]"));
        assert!(e.contains("light_offset") && e.contains("finite"), "{e}");
        let e = err(&format!("{METHODS}\n{fly}orbit_degrees = nan"));
        assert!(e.contains("orbit_degrees"), "{e}");
        let e = err(&format!(
            "{METHODS}\n[[method]]\nname = \"w\"\ncache = {{ warmup_orbit_degrees = inf }}"
        ));
        assert!(e.contains("finite angle"), "{e}");
    }
}
