//! `render`, `render_partial` and `Partial`: a scene's image as a numpy array, or one shard of
//! it as an exact partial film that merges with the others bit for bit (volume-pt's `shard`).

use crate::run::run_polled;
use crate::volume::{Scene, settings_with};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use std::path::PathBuf;
use volume_pt::{Film, PartialRender, Shard, render_samples};

/// An image as a float32 numpy array of shape (height, width, 3).
pub(crate) fn image_array<'py>(
    py: Python<'py>,
    width: u32,
    height: u32,
    pixels: &[glam::Vec3],
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let flat: Vec<f32> = pixels.iter().flat_map(|p| p.to_array()).collect();
    PyArray1::from_vec(py, flat).reshape([height as usize, width as usize, 3])
}

/// Renders sample indices `samples` of `scene` with `settings` on `threads` threads.
fn render_range(
    py: Python<'_>,
    scene: &Scene,
    settings: &volume_pt::RenderSettings,
    samples: std::ops::Range<u32>,
    threads: Option<usize>,
    progress: Option<&Bound<'_, PyAny>>,
    features: bool,
) -> PyResult<(Film, bool)> {
    let s = &scene.scene;
    let mut film = if features {
        Film::with_features(s.camera.width, s.camera.height)
    } else {
        Film::new(s.camera.width, s.camera.height)
    };
    let total = s.camera.width as u64 * s.camera.height as u64 * samples.len() as u64;
    let outcome = run_polled(py, threads, progress, total, |control| {
        // An interrupted render's image is returned: every pixel gets its first sample.
        let control = control.keeping_every_pixel();
        render_samples(&s.media, &s.camera, settings, samples, &mut film, &control)
    })?;
    s.media
        .medium
        .grid()
        .check_streaming()
        .map_err(crate::error)?;
    Ok((film, outcome.interrupted))
}

/// A film's feature buffers as numpy arrays: albedo and normal (height, width, 3), depth and
/// coverage (height, width).
type FeatureArrays<'py> = (
    Bound<'py, PyArray3<f32>>,
    Bound<'py, PyArray3<f32>>,
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray2<f32>>,
);

fn feature_arrays<'py>(py: Python<'py>, film: &Film) -> PyResult<Option<FeatureArrays<'py>>> {
    let Some(f) = film.feature_images() else {
        return Ok(None);
    };
    let (w, h) = (f.width(), f.height());
    let plane = |v: &[f32]| PyArray1::from_vec(py, v.to_vec()).reshape([h as usize, w as usize]);
    Ok(Some((
        image_array(py, w, h, &f.albedo)?,
        image_array(py, w, h, &f.normal)?,
        plane(&f.depth)?,
        plane(&f.coverage)?,
    )))
}

/// Renders `scene`; returns (image, samples taken, interrupted, non-finite samples, feature
/// arrays or None). The Python layer (`gscache.render`) raises `Interrupted` with the partial
/// image when interrupted.
#[pyfunction]
#[pyo3(name = "_render", signature = (scene, spp=None, seed=None, integrator=None, max_depth=None, threads=None, progress=None, features=false))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)] // Python keyword arguments
pub(crate) fn render_image<'py>(
    py: Python<'py>,
    scene: &Scene,
    spp: Option<u32>,
    seed: Option<u64>,
    integrator: Option<&str>,
    max_depth: Option<i64>,
    threads: Option<usize>,
    progress: Option<Bound<'py, PyAny>>,
    features: bool,
) -> PyResult<(
    Bound<'py, PyArray3<f32>>,
    u64,
    bool,
    u64,
    Option<FeatureArrays<'py>>,
)> {
    let settings = settings_with(scene, spp, seed, integrator, max_depth)?;
    let (film, interrupted) = render_range(
        py,
        scene,
        &settings,
        0..settings.spp,
        threads,
        progress.as_ref(),
        features,
    )?;
    let c = scene.scene.camera;
    Ok((
        image_array(py, c.width, c.height, &film.mean())?,
        film.total_samples(),
        interrupted,
        film.nonfinite_samples,
        feature_arrays(py, &film)?,
    ))
}

/// A shard's render: its partial, or (interrupted) the image of its samples; and the samples.
type ShardOutcome<'py> = (Option<Partial>, Option<Bound<'py, PyArray3<f32>>>, u64);

/// Renders shard `shard = (i, n)` of `scene`'s samples into a `Partial`; when interrupted, no
/// partial (it must hold whole sample ranges) but the image of the samples it has and their
/// count, which the Python layer raises with `Interrupted`.
#[pyfunction]
#[pyo3(name = "_render_partial", signature = (scene, shard, spp=None, seed=None, integrator=None, max_depth=None, threads=None, progress=None))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments
pub(crate) fn render_partial<'py>(
    py: Python<'py>,
    scene: &Scene,
    shard: (u32, u32),
    spp: Option<u32>,
    seed: Option<u64>,
    integrator: Option<&str>,
    max_depth: Option<i64>,
    threads: Option<usize>,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<ShardOutcome<'py>> {
    let shard = Shard::new(shard.0, shard.1).map_err(crate::error)?;
    let settings = settings_with(scene, spp, seed, integrator, max_depth)?;
    let samples = shard.samples(settings.spp);
    let (film, interrupted) = render_range(
        py,
        scene,
        &settings,
        samples.clone(),
        threads,
        progress.as_ref(),
        false,
    )?;
    if interrupted {
        let c = scene.scene.camera;
        let image = image_array(py, c.width, c.height, &film.mean())?;
        return Ok((None, Some(image), film.total_samples()));
    }
    let partial = Partial {
        inner: PartialRender::from_film(&film, &scene.key(&settings), settings.spp, samples),
    };
    Ok((Some(partial), None, film.total_samples()))
}

/// The exact film of some sample ranges of one render: merge the shards, then take the image.
/// Pickles as its file's bytes, so it travels between Dask workers unchanged.
#[pyclass(frozen, module = "gscache._gscache")]
#[derive(Clone)]
pub struct Partial {
    pub(crate) inner: PartialRender,
}

#[pymethods]
impl Partial {
    /// This partial and `other` merged (a new partial); refused when they belong to different
    /// renders or hold the same samples.
    fn merge(&self, other: &Partial) -> PyResult<Partial> {
        let mut m = self.inner.clone();
        m.merge(&other.inner).map_err(crate::error)?;
        Ok(Partial { inner: m })
    }

    /// Every partial in `parts` merged; the order does not change a bit of the result.
    #[staticmethod]
    fn merge_all(parts: Vec<PyRef<'_, Partial>>) -> PyResult<Partial> {
        let inner = PartialRender::merge_all(parts.iter().map(|p| p.inner.clone()))
            .map_err(crate::error)?;
        Ok(Partial { inner })
    }

    /// Each pixel's mean: float32 (height, width, 3). Refused while samples are missing,
    /// unless `allow_incomplete`.
    #[pyo3(signature = (allow_incomplete=false))]
    fn image<'py>(
        &self,
        py: Python<'py>,
        allow_incomplete: bool,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        if !self.inner.is_complete() && !allow_incomplete {
            return Err(crate::error(format!(
                "the partial holds samples {} of 0..{}: some shards are missing (merge them, or pass allow_incomplete=True)",
                self.ranges_text(),
                self.inner.spp()
            )));
        }
        let img = self.inner.image();
        image_array(py, img.width(), img.height(), img.pixels())
    }

    /// Samples per pixel, uint32 (height, width).
    fn counts<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u32>>> {
        PyArray1::from_slice(py, self.inner.counts())
            .reshape([self.inner.height() as usize, self.inner.width() as usize])
    }

    #[getter]
    fn key(&self) -> String {
        self.inner.key().to_string()
    }
    #[getter]
    fn spp(&self) -> u32 {
        self.inner.spp()
    }
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width()
    }
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height()
    }
    /// The sample ranges held, as (start, end) pairs.
    #[getter]
    fn ranges(&self) -> Vec<(u32, u32)> {
        self.inner
            .ranges()
            .iter()
            .map(|r| (r.start, r.end))
            .collect()
    }
    #[getter]
    fn is_complete(&self) -> bool {
        self.inner.is_complete()
    }
    #[getter]
    fn nonfinite_samples(&self) -> u64 {
        self.inner.nonfinite_samples()
    }

    /// Writes the partial file (the program's format: `gscache merge` reads it), atomically.
    fn write(&self, path: PathBuf) -> PyResult<()> {
        self.inner.write(&path).map_err(crate::error)
    }

    #[staticmethod]
    fn read(path: PathBuf) -> PyResult<Partial> {
        Ok(Partial {
            inner: PartialRender::read(&path).map_err(crate::error)?,
        })
    }

    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.inner.to_bytes())
    }

    #[staticmethod]
    fn from_bytes(data: &[u8]) -> PyResult<Partial> {
        let inner = PartialRender::from_bytes(data, std::path::Path::new("<bytes>"))
            .map_err(crate::error)?;
        Ok(Partial { inner })
    }

    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyBytes>,))> {
        let from_bytes = slf.get_type().getattr("from_bytes")?;
        Ok((from_bytes, (slf.get().to_bytes(py),)))
    }

    fn __repr__(&self) -> String {
        format!(
            "Partial(render {}, {}x{}, samples {} of {})",
            self.inner.key(),
            self.inner.width(),
            self.inner.height(),
            self.ranges_text(),
            self.inner.spp()
        )
    }
}

impl Partial {
    fn ranges_text(&self) -> String {
        let r: Vec<String> = self
            .inner
            .ranges()
            .iter()
            .map(|r| format!("{}..{}", r.start, r.end))
            .collect();
        if r.is_empty() {
            "none".into()
        } else {
            r.join(", ")
        }
    }
}
