//! Images: EXR in and out (linear f32), PNG out (tone-mapped), through hdr-image, the one
//! place the project reads and writes images.

use crate::render::image_array;
use hdr_image::{RgbImage, ToneMap};
use numpy::{PyArray3, PyReadonlyArray3};
use pyo3::prelude::*;
use std::path::PathBuf;

pub(crate) fn to_image(array: PyReadonlyArray3<'_, f32>) -> PyResult<RgbImage> {
    let v = array.as_array();
    let s = v.shape();
    if s[2] != 3 {
        return Err(crate::error(format!(
            "an image of shape {s:?}: expected (height, width, 3)"
        )));
    }
    let (h, w) = (
        u32::try_from(s[0]).map_err(crate::error)?,
        u32::try_from(s[1]).map_err(crate::error)?,
    );
    let flat: Vec<f32> = v.iter().copied().collect();
    let px = flat
        .chunks_exact(3)
        .map(|c| glam::Vec3::new(c[0], c[1], c[2]))
        .collect();
    RgbImage::from_pixels(w, h, px).map_err(crate::error)
}

/// Reads a linear RGB EXR: float32 (height, width, 3).
#[pyfunction]
pub(crate) fn read_exr(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyArray3<f32>>> {
    let img = RgbImage::read_exr(&path).map_err(crate::error)?;
    image_array(py, img.width(), img.height(), img.pixels())
}

/// Writes float32 (height, width, 3) as a 32-bit float EXR, atomically.
#[pyfunction]
pub(crate) fn write_exr(path: PathBuf, image: PyReadonlyArray3<'_, f32>) -> PyResult<()> {
    to_image(image)?.write_exr(&path).map_err(crate::error)
}

/// Writes float32 (height, width, 3) as a tone-mapped 8-bit sRGB PNG, atomically.
#[pyfunction]
#[pyo3(signature = (path, image, exposure=0.0, tonemap="clip"))]
pub(crate) fn write_png(
    path: PathBuf,
    image: PyReadonlyArray3<'_, f32>,
    exposure: f32,
    tonemap: &str,
) -> PyResult<()> {
    let tone = <ToneMap as clap::ValueEnum>::from_str(tonemap, true)
        .map_err(|_| crate::error(format!("tonemap `{tonemap}`: expected `clip` or `aces`")))?;
    if !exposure.is_finite() {
        return Err(crate::error(format!(
            "exposure {exposure}: expected a finite number of stops"
        )));
    }
    to_image(image)?
        .write_png(&path, exposure, tone)
        .map_err(crate::error)
}
