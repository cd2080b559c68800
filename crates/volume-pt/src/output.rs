//! Writing images: EXR (linear RGB f32, lossless) and PNG (exposure, tone mapping, sRGB).

use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// How HDR radiance is mapped to [0, 1] for PNG.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ToneMap {
    /// Clamp to [0, 1]: what you see is the radiance, until it saturates.
    #[default]
    Clip,
    /// Narkowicz's fit of the ACES filmic curve: keeps highlights.
    Aces,
}

impl std::str::FromStr for ToneMap {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "clip" => Ok(ToneMap::Clip),
            "aces" => Ok(ToneMap::Aces),
            _ => Err(format!("unknown tone map `{s}`: expected `clip` or `aces`")),
        }
    }
}

/// Writes linear RGB as a 32-bit float EXR, row 0 at the top.
pub fn write_exr(path: &Path, width: u32, height: u32, pixels: &[Vec3]) -> Result<()> {
    assert_eq!(pixels.len(), (width * height) as usize);
    exr::prelude::write_rgb_file(path, width as usize, height as usize, |x, y| {
        let p = pixels[y * width as usize + x];
        (p.x, p.y, p.z)
    })
    .map_err(|e| Error::Output {
        path: path.into(),
        message: e.to_string(),
    })
}

/// Reads an RGB(A) EXR back as linear RGB, row 0 at the top.
pub fn read_exr(path: &Path) -> Result<(u32, u32, Vec<Vec3>)> {
    use exr::prelude::read_first_rgba_layer_from_file;
    let image = read_first_rgba_layer_from_file(
        path,
        |res, _| (res.width(), vec![Vec3::ZERO; res.width() * res.height()]),
        |(w, px): &mut (usize, Vec<Vec3>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.y() * *w + pos.x()] = Vec3::new(r, g, b);
        },
    )
    .map_err(|e| Error::format(path, format!("cannot read EXR: {e}")))?;
    let size = image.layer_data.size;
    let (_, px) = image.layer_data.channel_data.pixels;
    Ok((size.width() as u32, size.height() as u32, px))
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

/// Tone maps linear radiance to 8-bit sRGB: multiply by `2^exposure`, map, encode.
pub fn tone_map(pixels: &[Vec3], exposure: f32, tone: ToneMap) -> Vec<u8> {
    let scale = exposure.exp2();
    pixels
        .iter()
        .flat_map(|p| {
            let v = *p * scale;
            let m = |c: f32| {
                // NaN maps to 0 through clamp's NaN-propagation guard below.
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

/// Writes a tone-mapped 8-bit sRGB PNG.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[Vec3],
    exposure: f32,
    tone: ToneMap,
) -> Result<()> {
    let bytes = tone_map(pixels, exposure, tone);
    image::save_buffer(path, &bytes, width, height, image::ExtendedColorType::Rgb8).map_err(|e| {
        Error::Output {
            path: path.into(),
            message: e.to_string(),
        }
    })
}
