//! `Cache`: the GSCache radiance cache (Bauer et al., 2025) read and trained by the path tracer
//! frame after frame, as `gscache render --cache` runs it.

use crate::render::image_array;
use crate::run::run_polled;
use crate::volume::Scene;
use gs_cache::CacheConfig;
use numpy::PyArray3;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use render_session::{CacheChoice, Edit, Session};
use std::path::PathBuf;

/// A radiance cache for one scene: a render session (render-session) holding the scene and the
/// cache. Frames keep counting across calls (the sampling rule's frame index), so no two frames
/// draw the same random paths.
#[pyclass(module = "gscache._gscache")]
pub struct Cache {
    session: Session,
    /// Summed per accumulated frame: path tracing, lookup (splatting), training, in seconds.
    costs: [f64; 3],
    counted: u32,
}

fn config_from(config_json: Option<&str>) -> PyResult<CacheConfig> {
    let c: CacheConfig = match config_json {
        Some(j) => {
            serde_json::from_str(j).map_err(|e| crate::error(format!("cache config: {e}")))?
        }
        None => CacheConfig::default(),
    };
    c.validate().map_err(crate::error)?;
    Ok(c)
}

impl Cache {
    fn with_choice(py: Python<'_>, scene: &Scene, choice: CacheChoice) -> PyResult<Self> {
        let scene = scene.scene.clone();
        let session = py
            .detach(|| Session::new(scene, choice))
            .map_err(crate::error)?;
        Ok(Self {
            session,
            costs: [0.0; 3],
            counted: 0,
        })
    }

    fn gaussian(&self) -> &gs_cache::GsCache {
        self.session
            .cache()
            .gaussian()
            .expect("a Python Cache holds the Gaussian cache")
    }
}

#[pymethods]
impl Cache {
    /// A cache initialised from the volume (Eq. 2); `config_json` holds an experiment file's
    /// `cache` keys (the Python layer passes a dict as JSON).
    #[new]
    #[pyo3(signature = (scene, config_json=None))]
    fn new(py: Python<'_>, scene: Py<Scene>, config_json: Option<&str>) -> PyResult<Self> {
        let config = config_from(config_json)?;
        Self::with_choice(py, scene.get(), CacheChoice::gaussian(config))
    }

    /// A cache saved by `save` (or `gscache render --save-cache`).
    #[staticmethod]
    #[pyo3(signature = (scene, folder, config_json=None))]
    fn load(
        py: Python<'_>,
        scene: Py<Scene>,
        folder: PathBuf,
        config_json: Option<&str>,
    ) -> PyResult<Self> {
        let config = config_from(config_json)?;
        let choice = CacheChoice::Gaussian {
            config,
            load: Some(folder),
        };
        Self::with_choice(py, scene.get(), choice)
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
        let session = &mut self.session;
        session.edit(Edit::Spp(spp)).map_err(crate::error)?;
        // Counts from Python are checked before any work: they cannot wrap.
        session
            .check_frames(warmup.checked_add(frames).ok_or_else(|| {
                crate::error(format!(
                    "warmup = {warmup} and frames = {frames}: together more than 2^32 frames"
                ))
            })?)
            .map_err(crate::error)?;
        let camera = *session.camera();
        let total = camera.width as u64
            * camera.height as u64
            * spp as u64
            * (warmup as u64 + frames as u64);
        let outcome = run_polled(py, threads, progress.as_ref(), total, |control| {
            let mut costs = [0.0f64; 3];
            let mut counted = 0;
            session.warm_up(warmup, 0.0, control)?;
            for _ in 0..frames {
                if control.cancelled() {
                    break;
                }
                let r = session.next_frame(control)?;
                if !r.cancelled {
                    costs[0] += r.trace_seconds;
                    costs[1] += r.lookup_seconds;
                    costs[2] += r.train_seconds;
                    counted += 1;
                }
            }
            Ok::<_, render_session::SessionError>((costs, counted))
        })?;
        let (costs, counted) = outcome.value.map_err(crate::error)?;
        for (a, b) in self.costs.iter_mut().zip(costs) {
            *a += b;
        }
        self.counted += counted;
        let cam = *self.session.camera();
        Ok((
            image_array(py, cam.width, cam.height, &self.session.mean())?,
            outcome.interrupted,
        ))
    }

    /// Each level drawn from the scene's camera: a list of float32 (height, width, 3) arrays,
    /// level 0 first (paths of length 1).
    fn level_images<'py>(&mut self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray3<f32>>>> {
        let cam = *self.session.camera();
        let levels = self
            .session
            .level_images()
            .expect("a Python Cache holds the Gaussian cache")
            .map_err(crate::error)?;
        levels
            .iter()
            .map(|img| image_array(py, cam.width, cam.height, img.pixels()))
            .collect()
    }

    /// Writes the levels as 3DGS PLY files `length_N.ply` into `folder`.
    fn save(&self, folder: PathBuf) -> PyResult<()> {
        self.session
            .save_cache(&folder)
            .map(drop)
            .map_err(crate::error)
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
        self.gaussian().gaussian_count()
    }
    #[getter]
    fn levels(&self) -> usize {
        self.gaussian().levels().len()
    }
    /// Frames rendered so far (warm-up included).
    #[getter]
    fn frames(&self) -> u32 {
        self.session.frames_rendered()
    }

    fn __repr__(&self) -> String {
        format!(
            "Cache({} Gaussians in {} levels, {} frames)",
            self.gaussian().gaussian_count(),
            self.gaussian().levels().len(),
            self.session.frames_rendered()
        )
    }
}
