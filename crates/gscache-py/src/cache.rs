//! `Cache`: the GSCache radiance cache (Bauer et al., 2025) read and trained by the path tracer
//! frame after frame, as `gscache render --cache` runs it.

use crate::render::image_array;
use crate::run::run_polled;
use crate::volume::{Scene, settings_with};
use gs_cache::{CacheConfig, GsCache};
use numpy::PyArray3;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use volume_pt::{Film, sample_cache_points};

/// A radiance cache for one scene. Frames keep counting across calls, so no two frames draw
/// the same random paths.
#[pyclass(module = "gscache._gscache")]
pub struct Cache {
    cache: GsCache,
    scene: Py<Scene>,
    /// The next frame's index.
    frame: u32,
    /// Summed per accumulated frame: path tracing, lookup (splatting), training, in seconds.
    costs: [f64; 3],
    counted: u32,
}

fn config_from(scene: &Scene, config_json: Option<&str>) -> PyResult<CacheConfig> {
    let c: CacheConfig = match config_json {
        Some(j) => {
            serde_json::from_str(j).map_err(|e| crate::error(format!("cache config: {e}")))?
        }
        None => CacheConfig::default(),
    };
    let c = c.for_image(scene.scene.camera.width, scene.scene.camera.height);
    c.validate().map_err(crate::error)?;
    Ok(c)
}

#[pymethods]
impl Cache {
    /// A cache initialised from the volume (Eq. 2); `config_json` holds an experiment file's
    /// `cache` keys (the Python layer passes a dict as JSON).
    #[new]
    #[pyo3(signature = (scene, config_json=None))]
    fn new(py: Python<'_>, scene: Py<Scene>, config_json: Option<&str>) -> PyResult<Self> {
        let s = scene.get();
        let config = config_from(s, config_json)?;
        let media = &s.scene.media;
        let seed = s.scene.settings.seed;
        let cache = py
            .detach(|| {
                let (points, albedo) = sample_cache_points(&media.medium, config.points, seed);
                if points.len() < config.points {
                    return Err(format!(
                        "{}: only {} of {} cache points found: the transfer function leaves the volume almost empty",
                        s.scene.volume_path.display(),
                        points.len(),
                        config.points
                    ));
                }
                GsCache::new(&points, &albedo, config).map_err(|e| e.to_string())
            })
            .map_err(crate::error)?;
        Ok(Self {
            cache,
            scene,
            frame: 0,
            costs: [0.0; 3],
            counted: 0,
        })
    }

    /// A cache saved by `save` (or `gscache render --save-cache`).
    #[staticmethod]
    #[pyo3(signature = (scene, folder, config_json=None))]
    fn load(scene: Py<Scene>, folder: PathBuf, config_json: Option<&str>) -> PyResult<Self> {
        let config = config_from(scene.get(), config_json)?;
        let cache = GsCache::load(&folder, config).map_err(crate::error)?;
        Ok(Self {
            cache,
            scene,
            frame: 0,
            costs: [0.0; 3],
            counted: 0,
        })
    }

    /// Renders `warmup` frames (trained on, not kept), then `frames` frames of `spp` samples
    /// whose mean is returned: float32 (height, width, 3). Returns (image, interrupted).
    #[pyo3(name = "_render", signature = (frames=1, warmup=0, spp=1, threads=None, progress=None))]
    fn render<'py>(
        &mut self,
        py: Python<'py>,
        frames: u32,
        warmup: u32,
        spp: u32,
        threads: Option<usize>,
        progress: Option<Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyArray3<f32>>, bool)> {
        if frames == 0 {
            return Err(crate::error("frames = 0: expected at least 1 frame"));
        }
        let scene = self.scene.get();
        let settings = settings_with(scene, Some(spp), None, None, None)?;
        let s = &scene.scene;
        let mut film = Film::new(s.camera.width, s.camera.height);
        let (cache, first) = (&mut self.cache, self.frame);
        let outcome = run_polled(py, threads, progress.as_ref(), |cancel, done| {
            let mut costs = [0.0f64; 3];
            let mut counted = 0;
            for f in 0..warmup + frames {
                if cancel.load(Ordering::Relaxed) {
                    break;
                }
                let accumulate = f >= warmup;
                if f == warmup {
                    cache.start_image();
                }
                let r = cached_pt::render_cached_frame(
                    &s.media,
                    &s.camera,
                    &settings,
                    first + f,
                    accumulate.then_some(&mut film),
                    cache,
                    cancel,
                )
                .map_err(|e| e.to_string())?;
                done.fetch_add(r.samples, Ordering::Relaxed);
                if accumulate && !r.cancelled {
                    costs[0] += r.trace_seconds;
                    costs[1] += r.lookup_seconds;
                    costs[2] += r.train_seconds;
                    counted += 1;
                }
            }
            Ok::<_, String>((costs, counted))
        })?;
        self.frame = first + warmup + frames;
        let (costs, counted) = outcome.value.map_err(crate::error)?;
        for (a, b) in self.costs.iter_mut().zip(costs) {
            *a += b;
        }
        self.counted += counted;
        Ok((
            image_array(py, s.camera.width, s.camera.height, &film.mean())?,
            outcome.interrupted,
        ))
    }

    /// Each level drawn from the scene's camera: a list of float32 (height, width, 3) arrays,
    /// level 0 first (paths of length 1).
    fn level_images<'py>(&mut self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray3<f32>>>> {
        let cam = self.scene.get().scene.camera;
        let frame = self.cache.begin_frame(&cam);
        (0..frame.levels())
            .map(|l| {
                let px: Vec<glam::Vec3> = frame
                    .image(l)
                    .iter()
                    .map(|c| glam::Vec3::from_array(*c))
                    .collect();
                if px.len() != (cam.width * cam.height) as usize {
                    return Err(crate::error(
                        "a level image does not match the camera's size",
                    ));
                }
                image_array(py, cam.width, cam.height, &px)
            })
            .collect()
    }

    /// Writes the levels as 3DGS PLY files `length_N.ply` into `folder`.
    fn save(&self, folder: PathBuf) -> PyResult<()> {
        self.cache.save(&folder).map_err(crate::error)
    }

    /// Mean per accumulated frame so far, in milliseconds: `trace` (path tracing), `lookup`
    /// (drawing the levels), `train`.
    #[getter]
    fn costs_ms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let n = self.counted.max(1) as f64 / 1e3;
        for (name, v) in ["trace", "lookup", "train"].iter().zip(self.costs) {
            d.set_item(name, v / n)?;
        }
        Ok(d)
    }

    #[getter]
    fn gaussian_count(&self) -> usize {
        self.cache.gaussian_count()
    }
    #[getter]
    fn levels(&self) -> usize {
        self.cache.levels().len()
    }
    /// Frames rendered so far (warm-up included).
    #[getter]
    fn frames(&self) -> u32 {
        self.frame
    }

    fn __repr__(&self) -> String {
        format!(
            "Cache({} Gaussians in {} levels, {} frames)",
            self.cache.gaussian_count(),
            self.cache.levels().len(),
            self.frame
        )
    }
}
