//! `Denoiser`: Intel Open Image Denoise on numpy images, through the project's `denoise`
//! crate (the Python layer's `gscache.denoise` keeps one and finds pyoidn's library for it).

use crate::images::to_image;
use crate::render::image_array;
use denoise::{Options, Quality};
use numpy::{PyArray3, PyReadonlyArray3};
use pyo3::prelude::*;
use std::path::PathBuf;

/// One OIDN CPU device and its filters (reused while the image size and guides stay). The
/// mutex makes the class shareable between Python threads: one call drives the device at a
/// time, as OIDN serialises them anyway.
#[pyclass(module = "gscache._gscache")]
pub struct Denoiser {
    inner: std::sync::Mutex<denoise::Denoiser>,
}

/// A guide image as pixels: (height, width, 3) float32 of the colour's size.
fn guide(array: Option<PyReadonlyArray3<'_, f32>>) -> PyResult<Option<Vec<glam::Vec3>>> {
    array
        .map(|a| to_image(a).map(|img| img.into_pixels()))
        .transpose()
}

impl Denoiser {
    /// The device, even after a panic in another call (the device holds no state a panic
    /// could leave half-changed: each call sets every input it reads).
    fn lock(&self) -> std::sync::MutexGuard<'_, denoise::Denoiser> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[pymethods]
impl Denoiser {
    /// Loads the library at `library` (a file or folder), or finds it as the program does
    /// (GSCACHE_OIDN, the system loader, pyoidn through python3); `threads` 0 uses every core.
    #[new]
    #[pyo3(signature = (library=None, threads=0))]
    fn new(library: Option<PathBuf>, threads: usize) -> PyResult<Self> {
        let inner = match library {
            Some(path) => {
                let file = if path.is_dir() {
                    path.join("libOpenImageDenoise.so.2")
                } else {
                    path
                };
                denoise::Denoiser::from_library(&file, threads)
            }
            None => denoise::Denoiser::load(threads),
        }
        .map_err(crate::error)?;
        Ok(Self {
            inner: std::sync::Mutex::new(inner),
        })
    }

    /// The library in use.
    #[getter]
    fn library(&self) -> String {
        self.lock().library().to_string()
    }

    /// Denoises `image`; see `gscache.denoise`.
    /// `quality` and `prefilter` left out are `denoise::Options::default()`'s, the program's.
    #[pyo3(signature = (image, albedo=None, normal=None, quality=None, prefilter=None))]
    fn denoise<'py>(
        &self,
        py: Python<'py>,
        image: PyReadonlyArray3<'py, f32>,
        albedo: Option<PyReadonlyArray3<'py, f32>>,
        normal: Option<PyReadonlyArray3<'py, f32>>,
        quality: Option<&str>,
        prefilter: Option<bool>,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let defaults = Options::default();
        let quality: Quality = match quality {
            None => defaults.quality,
            Some(q) => clap::ValueEnum::from_str(q, true).map_err(|_| {
                crate::error(format!(
                    "quality `{q}`: expected \"fast\", \"balanced\" or \"high\""
                ))
            })?,
        };
        let prefilter = prefilter.unwrap_or(defaults.prefilter);
        let color = to_image(image)?;
        let (albedo, normal) = (guide(albedo)?, guide(normal)?);
        let out = py
            .detach(|| {
                self.lock().denoise(
                    &color,
                    albedo.as_deref(),
                    normal.as_deref(),
                    Options { quality, prefilter },
                )
            })
            .map_err(crate::error)?;
        image_array(py, out.width(), out.height(), out.pixels())
    }
}
