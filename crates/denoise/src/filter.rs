//! The denoiser: one OIDN CPU device and its `RT` filters (the colour's, and optionally the
//! albedo's and the normal's prefilters), built once per image size, guides and options and
//! kept for the last few of them (an interactive viewer alternates between a preview's size
//! and the full view's).
//!
//! A run can be abandoned from another thread ([`Denoiser::abort_handle`]): OIDN asks a
//! progress monitor between its steps, and the one set here answers from an atomic flag.
//!
//! Each filter reads and writes buffers it owns, so their addresses never change between
//! calls and a filter is committed once per configuration; each call copies the images in and
//! the result out (a few ms at 1280x720 against the filter's hundreds).

use crate::library::{Api, DEVICE_TYPE_CPU, ERROR_CANCELLED, ERROR_NONE, FORMAT_FLOAT3, Handle};
use crate::{DenoiseError, Result};
use glam::Vec3;
use hdr_image::RgbImage;
use std::ffi::{CStr, CString, c_void};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// How many filter configurations (size, guides, options) a [`Denoiser`] keeps built.
const KEPT_PIPELINES: usize = 4;

/// The progress monitor every filter gets: go on unless the denoiser's abort flag is set.
///
/// # Safety
/// `flag` must point to a live `AtomicBool`: it is the denoiser's abort flag, an `Arc` the
/// denoiser holds for as long as any of its filters exists (filters are released before it).
unsafe extern "C" fn keep_going(flag: *mut c_void, _progress: f64) -> bool {
    // SAFETY: see the function's contract; only atomic loads go through the pointer.
    let flag = unsafe { &*(flag as *const AtomicBool) };
    !flag.load(Ordering::Relaxed)
}

/// OIDN's quality modes (`OIDN_QUALITY_*`): `high` for final frames, `balanced` and `fast`
/// for interactive work.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    Fast,
    Balanced,
    #[default]
    High,
}

impl Quality {
    fn code(self) -> i32 {
        match self {
            Quality::Fast => 4,
            Quality::Balanced => 5,
            Quality::High => 6,
        }
    }
}

impl std::fmt::Display for Quality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Quality::Fast => "fast",
            Quality::Balanced => "balanced",
            Quality::High => "high",
        })
    }
}

/// Which of the film's feature buffers guide the filter: the one name of the guides, in the
/// program (`--denoise-guides`), the experiments (`denoise_guides`) and the reports.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Guides {
    /// Colour alone: the default. Guided by the albedo, OIDN leaves a few background pixels
    /// near a light's disc many times too bright (BENCHMARKS.md); its trimmed error is the same
    /// at 1 spp and lower from 16 spp.
    #[default]
    None,
    /// Colour and albedo.
    Albedo,
    /// Colour, albedo and normal (OIDN takes a normal only beside an albedo).
    #[cfg_attr(feature = "clap", value(name = "albedo,normal"))]
    #[serde(rename = "albedo,normal")]
    AlbedoNormal,
}

impl std::fmt::Display for Guides {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Guides::None => "none",
            Guides::Albedo => "albedo",
            Guides::AlbedoNormal => "albedo,normal",
        })
    }
}

/// The settings of one denoising call: quality, and whether noisy guides are denoised first.
/// Its [`Default`] is the one default of the program, the Python package and the viewer
/// (`high`, guides prefiltered: OIDN's advice for final frames); the experiment runner sets
/// `prefilter: false` on purpose (one filter pass, the interactive setting its time budgets
/// charge).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    pub quality: Quality,
    /// Denoise the albedo and normal on their own first, then tell the colour filter they are
    /// clean (`cleanAux`): OIDN's advice for final frames, since guides taken over few samples
    /// are noisy and the colour filter keeps the noise it sees in them. Costs two more filter
    /// passes; what it buys on volumes is in BENCHMARKS.md.
    pub prefilter: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            quality: Quality::High,
            prefilter: true,
        }
    }
}

/// One `RT` filter and the buffers it reads and writes.
struct Filter {
    handle: Handle,
    /// Input images: OIDN's name and the buffer.
    inputs: Vec<(&'static str, Vec<f32>)>,
    output: Vec<f32>,
}

impl Filter {
    /// An `RT` filter over packed FLOAT3 images `inputs` of `w` x `h` pixels, committed, that
    /// stops early when `abort` is set.
    #[allow(clippy::too_many_arguments)] // one filter's whole configuration
    fn build(
        api: &Api,
        device: Handle,
        (w, h): (u32, u32),
        inputs: &[&'static str],
        hdr: bool,
        clean_aux: bool,
        quality: Quality,
        abort: &Arc<AtomicBool>,
    ) -> Result<Self> {
        let floats = w as usize * h as usize * 3;
        // SAFETY: `device` is live; "RT" is a NUL-terminated filter type; null is handled.
        let handle = unsafe { (api.new_filter)(device, c_name("RT").as_ptr()) };
        if handle.is_null() {
            return Err(DenoiseError::Oidn(
                "the RT filter could not be created".into(),
            ));
        }
        let mut filter = Filter {
            handle,
            inputs: inputs.iter().map(|&n| (n, vec![0.0; floats])).collect(),
            output: vec![0.0; floats],
        };
        let set = |name: &str, buffer: &mut Vec<f32>| {
            // SAFETY: `handle` is live; the pointer and the sizes describe `buffer`, which
            // holds w*h packed FLOAT3 pixels (strides 0: packed, as OIDN documents) and stays
            // at this address for the filter's life (the Vec moves with the filter, its heap
            // allocation unchanged, and is never resized).
            unsafe {
                (api.set_shared_filter_image)(
                    handle,
                    c_name(name).as_ptr(),
                    buffer.as_mut_ptr().cast(),
                    FORMAT_FLOAT3,
                    w as usize,
                    h as usize,
                    0,
                    0,
                    0,
                )
            }
        };
        for (name, buffer) in &mut filter.inputs {
            set(name, buffer);
        }
        set("output", &mut filter.output);
        // SAFETY: `handle` is live; names are NUL-terminated.
        unsafe {
            (api.set_filter_bool)(handle, c_name("hdr").as_ptr(), hdr);
            (api.set_filter_bool)(handle, c_name("cleanAux").as_ptr(), clean_aux);
            (api.set_filter_int)(handle, c_name("quality").as_ptr(), quality.code());
            // The flag outlives the filter: the denoiser holds its Arc and releases every
            // filter before dropping it (see `keep_going`).
            (api.set_filter_progress_monitor)(
                handle,
                Some(keep_going),
                Arc::as_ptr(abort) as *mut c_void,
            );
            (api.commit_filter)(handle);
        }
        Ok(filter)
    }

    /// Copies `images` into the inputs (in the order they were named) and runs the filter.
    fn run(&mut self, api: &Api, images: &[&[Vec3]]) {
        for ((_, buffer), image) in self.inputs.iter_mut().zip(images) {
            copy_in(buffer, image);
        }
        // SAFETY: the filter was committed by `build` with images pointing into this filter's
        // own buffers, which have exactly w*h*3 floats and have not been reallocated since
        // (they are only written through `copy_in`, which keeps their length).
        unsafe { (api.execute_filter)(self.handle) };
    }

    /// The output as pixels.
    fn output(&self) -> Vec<Vec3> {
        self.output
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect()
    }

    fn release(self, api: &Api) {
        // SAFETY: the handle is live and released once (`self` is consumed).
        unsafe { (api.release_filter)(self.handle) };
    }
}

/// The filters for one size, set of guides and options: the colour filter, and the guides'
/// prefilters where asked for.
struct Pipeline {
    key: (u32, u32, Guides, Options),
    albedo: Option<Filter>,
    normal: Option<Filter>,
    color: Filter,
}

impl Pipeline {
    fn release(self, api: &Api) {
        for f in [self.albedo, self.normal].into_iter().flatten() {
            f.release(api);
        }
        self.color.release(api);
    }
}

/// One OIDN CPU device and its filters. Not `Sync`: one thread drives it at a time (OIDN
/// serialises calls on a device anyway); its own threads do the work.
pub struct Denoiser {
    api: Api,
    device: Handle,
    /// The filters built, the most recently used last.
    pipelines: Vec<Pipeline>,
    /// Set by anyone to abandon the run under way (see [`Denoiser::abort_handle`]).
    abort: Arc<AtomicBool>,
}

impl std::fmt::Debug for Denoiser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Denoiser")
            .field("library", &self.api.path)
            .finish()
    }
}

// SAFETY: the device and filter handles are owned by this struct alone, and OIDN's API is
// thread-safe ("All API calls are thread-safe", oidn's API documentation), so moving the
// struct to another thread is sound. It is not `Sync`: `denoise` takes `&mut self`.
unsafe impl Send for Denoiser {}

fn c_name(name: &str) -> CString {
    CString::new(name).expect("parameter names have no NUL")
}

impl Denoiser {
    /// Finds the library (see [`crate::library`]) and creates a CPU device running on
    /// `threads` threads (0: OIDN's default, every core).
    pub fn load(threads: usize) -> Result<Self> {
        Self::with_api(Api::find()?, threads)
    }

    /// [`Denoiser::load`] from the library at `path`.
    pub fn from_library(path: &std::path::Path, threads: usize) -> Result<Self> {
        Self::with_api(Api::open(path)?, threads)
    }

    fn with_api(api: Api, threads: usize) -> Result<Self> {
        // SAFETY: `new_device` has oidn.h's signature (see `Api::open`); a null result is
        // handled below and never used as a device.
        let device = unsafe { (api.new_device)(DEVICE_TYPE_CPU) };
        if device.is_null() {
            return Err(DenoiseError::Load {
                path: api.path.clone(),
                message: "it could not create a CPU device (an unsupported CPU?)".into(),
            });
        }
        let denoiser = Self {
            api,
            device,
            pipelines: Vec::new(),
            abort: Arc::new(AtomicBool::new(false)),
        };
        // SAFETY: `device` is a live device handle owned by `denoiser`; the names are
        // NUL-terminated strings that outlive the calls.
        unsafe {
            if threads > 0 {
                let n = i32::try_from(threads).unwrap_or(i32::MAX);
                (denoiser.api.set_device_int)(device, c_name("numThreads").as_ptr(), n);
            }
            (denoiser.api.commit_device)(device);
        }
        denoiser.check()?;
        // SAFETY: as above.
        let version = unsafe { (denoiser.api.get_device_int)(device, c_name("version").as_ptr()) };
        if !(20000..30000).contains(&version) {
            return Err(DenoiseError::Load {
                path: denoiser.api.path.clone(),
                message: format!(
                    "it is version {}.{}.{}: expected 2.x",
                    version / 10000,
                    version / 100 % 100,
                    version % 100
                ),
            });
        }
        Ok(denoiser)
    }

    /// The flag that abandons a run: set it (from any thread) and the run under way stops at
    /// OIDN's next progress check, returning [`DenoiseError::Cancelled`]; so does every run
    /// started while it is set. Whoever sets it clears it for the next run.
    pub fn abort_handle(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.abort)
    }

    /// The library in use (its path as loaded).
    pub fn library(&self) -> &str {
        &self.api.path
    }

    /// The device's pending error, if any, as an error naming it.
    fn check(&self) -> Result<()> {
        let mut message: *const std::ffi::c_char = std::ptr::null();
        // SAFETY: `device` is live; OIDN writes a pointer to a NUL-terminated string it owns
        // (valid until the next call on the device) or leaves it null.
        let code = unsafe { (self.api.get_device_error)(self.device, &mut message) };
        if code == ERROR_NONE {
            return Ok(());
        }
        if code == ERROR_CANCELLED {
            return Err(DenoiseError::Cancelled);
        }
        let text = if message.is_null() {
            String::new()
        } else {
            // SAFETY: non-null and NUL-terminated, per the comment above; copied at once.
            unsafe { CStr::from_ptr(message) }
                .to_string_lossy()
                .into_owned()
        };
        Err(DenoiseError::Oidn(format!("error {code}: {text}")))
    }

    /// Denoises `color` guided by the feature buffers `guides` names, taken from `features`
    /// (none taken without them): the one place a render's feature buffers become the filter's
    /// guides, for the program, the experiments, the movies and the viewer.
    pub fn denoise_guided(
        &mut self,
        color: &RgbImage,
        features: Option<&hdr_image::FeatureImages>,
        guides: Guides,
        options: Options,
    ) -> Result<RgbImage> {
        let albedo = features
            .filter(|_| guides != Guides::None)
            .map(|f| f.albedo.as_slice());
        let normal = features
            .filter(|_| guides == Guides::AlbedoNormal)
            .map(|f| f.normal.as_slice());
        self.denoise(color, albedo, normal, options)
    }

    /// Denoises `color` (linear HDR radiance), guided by `albedo` and `normal` where given.
    ///
    /// `albedo` values must lie in [0, 1] and `normal` components in [-1, 1] (OIDN's ranges);
    /// a normal needs an albedo. Colour must be finite. Each is checked, and an image or a
    /// buffer of the wrong size is refused, before anything is copied. Negative colour channels
    /// (an unbiased estimator with a control variate makes them at low sample counts: see
    /// gs-cache's crate docs) are clamped to 0, as the filter takes only non-negative radiance.
    pub fn denoise(
        &mut self,
        color: &RgbImage,
        albedo: Option<&[Vec3]>,
        normal: Option<&[Vec3]>,
        options: Options,
    ) -> Result<RgbImage> {
        let (w, h) = (color.width(), color.height());
        let aux = check_inputs(color, albedo, normal)?;
        if self.abort.load(Ordering::Relaxed) {
            return Err(DenoiseError::Cancelled);
        }
        self.prepare((w, h, aux, options))?;
        let api = &self.api;
        let pipeline = self.pipelines.last_mut().expect("prepared above");
        let mut guides: Vec<Vec<Vec3>> = Vec::new();
        for (filter, guide) in [
            (&mut pipeline.albedo, albedo),
            (&mut pipeline.normal, normal),
        ] {
            if let (Some(filter), Some(guide)) = (filter, guide) {
                filter.run(api, &[guide]);
                guides.push(filter.output());
            } else if let Some(guide) = guide {
                guides.push(guide.to_vec());
            }
        }
        let clamped: Vec<Vec3>;
        let colour = if color.pixels().iter().any(|p| p.min_element() < 0.0) {
            clamped = color.pixels().iter().map(|p| p.max(Vec3::ZERO)).collect();
            clamped.as_slice()
        } else {
            color.pixels()
        };
        let mut images: Vec<&[Vec3]> = vec![colour];
        images.extend(guides.iter().map(|g| g.as_slice()));
        pipeline.color.run(api, &images);
        self.check()?;
        let out = self
            .pipelines
            .last()
            .expect("prepared above")
            .color
            .output();
        RgbImage::from_pixels(w, h, out).map_err(|e| DenoiseError::Oidn(e.to_string()))
    }

    /// Makes the filters for `key` (size, guides, options) the last of the pipelines, reusing
    /// built ones where they fit (building a filter costs far more than running it) and
    /// releasing the least recently used beyond [`KEPT_PIPELINES`].
    fn prepare(&mut self, key: (u32, u32, Guides, Options)) -> Result<()> {
        if let Some(at) = self.pipelines.iter().position(|p| p.key == key) {
            let p = self.pipelines.remove(at);
            self.pipelines.push(p);
            return Ok(());
        }
        if self.pipelines.len() >= KEPT_PIPELINES {
            let oldest = self.pipelines.remove(0);
            oldest.release(&self.api);
        }
        let (w, h, aux, options) = key;
        let (api, device, q, abort) = (&self.api, self.device, options.quality, &self.abort);
        let prefilter = |name: &'static str| -> Result<Option<Filter>> {
            let wanted = options.prefilter
                && match name {
                    "albedo" => aux != Guides::None,
                    _ => aux == Guides::AlbedoNormal,
                };
            wanted
                .then(|| Filter::build(api, device, (w, h), &[name], false, false, q, abort))
                .transpose()
        };
        let albedo = prefilter("albedo")?;
        let normal = prefilter("normal")?;
        let inputs: &[&'static str] = match aux {
            Guides::None => &["color"],
            Guides::Albedo => &["color", "albedo"],
            Guides::AlbedoNormal => &["color", "albedo", "normal"],
        };
        let clean = options.prefilter && aux != Guides::None;
        let color = Filter::build(api, device, (w, h), inputs, true, clean, q, abort)?;
        self.pipelines.push(Pipeline {
            key,
            albedo,
            normal,
            color,
        });
        self.check()
    }

    fn release_pipelines(&mut self) {
        for p in std::mem::take(&mut self.pipelines) {
            p.release(&self.api);
        }
    }
}

/// Checks the inputs of [`Denoiser::denoise`] and says which guides they are.
fn check_inputs(
    color: &RgbImage,
    albedo: Option<&[Vec3]>,
    normal: Option<&[Vec3]>,
) -> Result<Guides> {
    let (w, h) = (color.width(), color.height());
    let n = w as usize * h as usize;
    let input = |what: &str, message: String| DenoiseError::Input {
        what: what.into(),
        message,
    };
    let aux = match (albedo, normal) {
        (None, None) => Guides::None,
        (Some(_), None) => Guides::Albedo,
        (Some(_), Some(_)) => Guides::AlbedoNormal,
        (None, Some(_)) => {
            return Err(input(
                "normal",
                "given without an albedo: Open Image Denoise takes a normal only beside an albedo"
                    .into(),
            ));
        }
    };
    if let Some(bad) = color.pixels().iter().position(|p| {
        // Written so that NaN is refused.
        !p.is_finite()
    }) {
        return Err(input(
            "image",
            format!(
                "pixel ({}, {}) is {}: expected finite radiance",
                bad % w as usize,
                bad / w as usize,
                color.pixels()[bad]
            ),
        ));
    }
    for (what, buffer, lo) in [("albedo", albedo, 0.0f32), ("normal", normal, -1.0)] {
        let Some(buffer) = buffer else { continue };
        if buffer.len() != n {
            return Err(input(
                what,
                format!("{} values for a {w}x{h} image: expected {n}", buffer.len()),
            ));
        }
        if let Some(bad) = buffer
            .iter()
            .position(|v| !(v.cmpge(Vec3::splat(lo)).all() && v.cmple(Vec3::ONE).all()))
        {
            return Err(input(
                what,
                format!(
                    "value {} at pixel ({}, {}): expected components in [{lo}, 1]",
                    buffer[bad],
                    bad % w as usize,
                    bad / w as usize
                ),
            ));
        }
    }
    Ok(aux)
}

impl Drop for Denoiser {
    fn drop(&mut self) {
        self.release_pipelines();
        // SAFETY: the device is live, its filter released above, and it is released once.
        unsafe { (self.api.release_device)(self.device) };
    }
}

fn copy_in(buffer: &mut [f32], pixels: &[Vec3]) {
    for (b, p) in buffer.chunks_exact_mut(3).zip(pixels) {
        b.copy_from_slice(&p.to_array());
    }
}
