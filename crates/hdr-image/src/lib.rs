//! hdr-image: the image every renderer in this project produces, and the one place it is read
//! and written.
//!
//! - [`RgbImage`]: linear RGB radiance in f32, row-major with row 0 at the top, never clamped.
//! - EXR ([`RgbImage::write_exr`], [`RgbImage::read_exr`]): lossless 32-bit float. Blocks are
//!   written in increasing order, so a file is a pure function of its pixels (a seed gives the
//!   same bytes, not only the same pixels).
//! - Feature buffers ([`FeatureImages`]: albedo, normal, depth, coverage) travel beside an
//!   image and are written as extra channels of its EXR ([`RgbImage::write_exr_with_features`]),
//!   under the names compositing tools read.
//! - PNG ([`RgbImage::write_png`]): exposure, a [`ToneMap`], sRGB encoding, 8 bits.
//! - Every write goes through [`render_base::write_atomically`]: an interrupted write never
//!   leaves a truncated image where a good one was, and nothing planted in a shared output
//!   folder can redirect it.

#![forbid(unsafe_code)]

use glam::Vec3;
use render_base::write_atomically;
use std::path::{Path, PathBuf};

/// What went wrong with which file.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{}: cannot write: {message}", path.display())]
    Write { path: PathBuf, message: String },
    #[error("{}: cannot read: {message}", path.display())]
    Read { path: PathBuf, message: String },
    #[error("image of {width}x{height} given {len} pixels: expected width x height")]
    Size { width: u32, height: u32, len: usize },
}

pub type Result<T, E = ImageError> = std::result::Result<T, E>;

/// Linear RGB radiance, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    width: u32,
    height: u32,
    pixels: Vec<Vec3>,
}

/// The largest image side [`RgbImage::read_exr`] accepts (the cameras' own limit is 32768).
pub const MAX_READ_SIDE: usize = 32_768;

impl RgbImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            pixels: vec![Vec3::ZERO; width as usize * height as usize],
        }
    }

    /// An image over `pixels`, which must hold `width * height` of them.
    pub fn from_pixels(width: u32, height: u32, pixels: Vec<Vec3>) -> Result<Self> {
        if pixels.len() as u64 != width as u64 * height as u64 {
            return Err(ImageError::Size {
                width,
                height,
                len: pixels.len(),
            });
        }
        Ok(Self {
            width,
            height,
            pixels,
        })
    }

    /// An image over RGB triples (the rasteriser's and the cache's layout).
    pub fn from_rgb(width: u32, height: u32, rgb: &[[f32; 3]]) -> Result<Self> {
        Self::from_pixels(width, height, rgb.iter().map(|c| Vec3::from(*c)).collect())
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn pixels(&self) -> &[Vec3] {
        &self.pixels
    }
    pub fn pixels_mut(&mut self) -> &mut [Vec3] {
        &mut self.pixels
    }
    pub fn into_pixels(self) -> Vec<Vec3> {
        self.pixels
    }
    /// Pixel `(x, y)`.
    pub fn get(&self, x: u32, y: u32) -> Vec3 {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// Writes a 32-bit float RGB EXR (atomically: see the crate docs).
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        use exr::prelude::*;
        let (w, h) = (self.width as usize, self.height as usize);
        let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
            let p = self.pixels[pos.y() * w + pos.x()];
            (p.x, p.y, p.z)
        });
        let mut layer = Layer::new(
            (w, h),
            LayerAttributes::default(),
            Encoding::SMALL_LOSSLESS,
            channels,
        );
        // Increasing line order makes the writer emit blocks in order even when it compresses
        // them in parallel: the same pixels give the same bytes.
        layer.encoding.line_order = LineOrder::Increasing;
        write_atomically(path, |file| {
            Image::from_layer(layer)
                .write()
                .to_buffered(file)
                .map_err(|e| e.to_string())
        })
        .map_err(ImageError::from)
    }

    /// Writes a 32-bit float EXR whose channels are this image (`R`, `G`, `B`) and its
    /// feature buffers: `albedo.R/G/B`, `N.X/N.Y/N.Z` (world-space normal), `Z` (depth; `inf`
    /// where nothing was hit, as OpenEXR's depth convention has it) and `coverage.A`. Nuke,
    /// Blender and OpenImageIO list these as layers `albedo`, `N` and `coverage`. Written
    /// atomically, blocks in order, like [`RgbImage::write_exr`].
    pub fn write_exr_with_features(&self, path: &Path, features: &FeatureImages) -> Result<()> {
        use exr::prelude::*;
        if (features.width, features.height) != (self.width, self.height) {
            return Err(ImageError::Write {
                path: path.into(),
                message: format!(
                    "feature buffers are {}x{} but the image is {}x{}: expected the same size",
                    features.width, features.height, self.width, self.height
                ),
            });
        }
        let channel =
            |name: &str, values: Vec<f32>| AnyChannel::new(name, FlatSamples::F32(values));
        let component = |px: &[Vec3], k: usize| px.iter().map(|p| p[k]).collect::<Vec<f32>>();
        let list = vec![
            channel("R", component(&self.pixels, 0)),
            channel("G", component(&self.pixels, 1)),
            channel("B", component(&self.pixels, 2)),
            channel("albedo.R", component(&features.albedo, 0)),
            channel("albedo.G", component(&features.albedo, 1)),
            channel("albedo.B", component(&features.albedo, 2)),
            channel("N.X", component(&features.normal, 0)),
            channel("N.Y", component(&features.normal, 1)),
            channel("N.Z", component(&features.normal, 2)),
            channel("Z", features.depth.clone()),
            channel("coverage.A", features.coverage.clone()),
        ];
        let mut layer = Layer::new(
            (self.width as usize, self.height as usize),
            LayerAttributes::default(),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(SmallVec::from_vec(list)),
        );
        layer.encoding.line_order = LineOrder::Increasing;
        write_atomically(path, |file| {
            Image::from_layer(layer)
                .write()
                .to_buffered(file)
                .map_err(|e| e.to_string())
        })
        .map_err(ImageError::from)
    }

    /// Reads the first RGB(A) layer of an EXR as linear RGB (alpha is dropped).
    pub fn read_exr(path: &Path) -> Result<Self> {
        use exr::prelude::read_first_rgba_layer_from_file;
        let refuse = |message: String| ImageError::Read {
            path: path.into(),
            message,
        };
        // A FIFO or a device has no end to read to; the header's size is checked before the
        // pixels are allocated for it.
        if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
            return Err(refuse(
                "is missing or not a regular file: expected an EXR image".into(),
            ));
        }
        let meta = exr::meta::MetaData::read_from_file(path, false)
            .map_err(|e| refuse(format!("not a readable RGB EXR: {e}")))?;
        if let Some(header) = meta.headers.first() {
            let size = header.layer_size;
            if size.width() > MAX_READ_SIDE || size.height() > MAX_READ_SIDE {
                return Err(refuse(format!(
                    "EXR is {}x{}: expected at most {MAX_READ_SIDE} pixels a side",
                    size.width(),
                    size.height()
                )));
            }
        }
        let image = read_first_rgba_layer_from_file(
            path,
            |res, _| (res.width(), vec![Vec3::ZERO; res.width() * res.height()]),
            |(w, px): &mut (usize, Vec<Vec3>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = Vec3::new(r, g, b);
            },
        )
        .map_err(|e| ImageError::Read {
            path: path.into(),
            message: format!("not a readable RGB EXR: {e}"),
        })?;
        let size = image.layer_data.size;
        let (_, px) = image.layer_data.channel_data.pixels;
        Self::from_pixels(size.width() as u32, size.height() as u32, px)
    }

    /// Writes a tone-mapped 8-bit sRGB PNG (atomically: see the crate docs).
    pub fn write_png(&self, path: &Path, exposure: f32, tone: ToneMap) -> Result<()> {
        let bytes = tone_map(&self.pixels, exposure, tone);
        write_atomically(path, |file| {
            image::write_buffer_with_format(
                file,
                &bytes,
                self.width,
                self.height,
                image::ExtendedColorType::Rgb8,
                image::ImageFormat::Png,
            )
            .map_err(|e| e.to_string())
        })
        .map_err(ImageError::from)
    }
}

/// Per-pixel features of a render (AOVs), row-major like [`RgbImage`]: what a denoiser reads
/// beside the colour. The renderer documents how each is estimated.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureImages {
    width: u32,
    height: u32,
    /// Albedo in [0, 1] (where rays met no medium: the emitter they saw, clamped).
    pub albedo: Vec<Vec3>,
    /// World-space normal, components in [-1, 1], not renormalised (0 where rays met no medium).
    pub normal: Vec<Vec3>,
    /// Distance to the first scattering event (infinite where nothing was hit).
    pub depth: Vec<f32>,
    /// Fraction of samples that hit anything, in [0, 1].
    pub coverage: Vec<f32>,
}

impl FeatureImages {
    /// Features of a `width` x `height` image; every buffer must hold `width * height` values.
    pub fn new(
        width: u32,
        height: u32,
        albedo: Vec<Vec3>,
        normal: Vec<Vec3>,
        depth: Vec<f32>,
        coverage: Vec<f32>,
    ) -> Result<Self> {
        let n = width as u64 * height as u64;
        for len in [albedo.len(), normal.len(), depth.len(), coverage.len()] {
            if len as u64 != n {
                return Err(ImageError::Size { width, height, len });
            }
        }
        Ok(Self {
            width,
            height,
            albedo,
            normal,
            depth,
            coverage,
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
}

impl From<render_base::WriteError> for ImageError {
    fn from(e: render_base::WriteError) -> Self {
        ImageError::Write {
            path: e.path,
            message: e.message,
        }
    }
}

/// How HDR radiance is mapped to [0, 1] for an 8-bit image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum ToneMap {
    /// Clamp to [0, 1]: what you see is the radiance, until it saturates.
    #[default]
    Clip,
    /// Narkowicz's fit of the ACES filmic curve: keeps highlights.
    Aces,
}

#[inline]
fn srgb_encode(c: f32) -> f32 {
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

#[inline]
fn aces(x: f32) -> f32 {
    ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)
}

/// Tone maps linear radiance to 8-bit sRGB: multiply by `2^exposure`, map, encode. NaN,
/// infinite and negative values map to black.
pub fn tone_map(pixels: &[Vec3], exposure: f32, tone: ToneMap) -> Vec<u8> {
    let scale = exposure.exp2();
    pixels
        .iter()
        .flat_map(|p| {
            let v = *p * scale;
            let m = |c: f32| {
                let c = if c.is_finite() { c.max(0.0) } else { 0.0 };
                let c = match tone {
                    ToneMap::Clip => c.min(1.0),
                    ToneMap::Aces => aces(c),
                };
                (srgb_encode(c) * 255.0 + 0.5) as u8
            };
            [m(v.x), m(v.y), m(v.z)]
        })
        .collect()
}
