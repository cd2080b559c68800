//! Gaussian clouds: `Cloud` (3DGS PLY or .splat), drawn by the rasteriser (`splat_render`) or
//! ray-traced with stochastic transparency (`splat_trace`, Sun et al., 2025), as
//! `gscache splat render | trace` draw them with `--eye` and `--target`.

use crate::render::image_array;
use glam::Vec3;
use numpy::PyArray3;
use pyo3::prelude::*;
use splat_raster::io::{read_cloud, write_ply};
use splat_raster::stochastic::render_stochastic;
use splat_raster::{Camera, GaussianCloud, LowPass, RasterConfig};
use std::path::PathBuf;
use stochastic_rt::{
    DepthMode, Estimator, GaussianScene, RandomKind, TraceSettings, trace_image_with,
};

/// A cloud of 3D Gaussians.
#[pyclass(frozen, module = "gscache._gscache")]
pub struct Cloud {
    cloud: GaussianCloud<f32>,
}

#[pymethods]
impl Cloud {
    /// Reads a 3DGS PLY (SH degree 0-3) or a .splat file.
    #[staticmethod]
    fn read(path: PathBuf) -> PyResult<Self> {
        Ok(Self {
            cloud: read_cloud(&path).map_err(crate::error)?,
        })
    }

    /// Writes a 3DGS PLY that any splat viewer opens.
    fn write(&self, path: PathBuf) -> PyResult<()> {
        write_ply(&path, &self.cloud).map_err(crate::error)
    }

    /// Gaussians with a non-finite parameter or a zero quaternion (every renderer skips them).
    #[getter]
    fn unusable(&self) -> usize {
        self.cloud.count_unusable()
    }

    fn __len__(&self) -> usize {
        self.cloud.len()
    }

    fn __repr__(&self) -> String {
        format!("Cloud({} Gaussians)", self.cloud.len())
    }
}

fn camera(
    eye: [f32; 3],
    target: [f32; 3],
    up: [f32; 3],
    fov: f32,
    width: u32,
    height: u32,
) -> PyResult<Camera> {
    Camera::look_at(
        Vec3::from_array(eye),
        Vec3::from_array(target),
        Vec3::from_array(up),
        fov,
        width,
        height,
    )
    .map_err(crate::error)
}

fn finite3(name: &str, v: [f32; 3]) -> PyResult<Vec3> {
    let v = Vec3::from_array(v);
    if v.is_finite() {
        Ok(v)
    } else {
        Err(crate::error(format!("{name} {v}: expected finite values")))
    }
}

/// Draws `cloud` with the rasteriser: sorted compositing, or stochastic (sort-free) splatting
/// with `stochastic` samples per pixel. Float32 (height, width, 3).
#[pyfunction]
#[pyo3(signature = (cloud, eye, target, *, up=[0.0, -1.0, 0.0], fov=50.0, width=1280, height=720, background=[0.0; 3], mip=false, stochastic=None, kernel="auto"))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments
pub(crate) fn splat_render<'py>(
    py: Python<'py>,
    cloud: &Cloud,
    eye: [f32; 3],
    target: [f32; 3],
    up: [f32; 3],
    fov: f32,
    width: u32,
    height: u32,
    background: [f32; 3],
    mip: bool,
    stochastic: Option<u32>,
    kernel: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    if stochastic == Some(0) {
        // The program refuses `--stochastic 0` at its flag; 0 samples would be a black image.
        return Err(crate::error(
            "stochastic = 0: expected at least 1 sample per pixel (or None for sorted compositing)",
        ));
    }
    let cam = camera(eye, target, up, fov, width, height)?;
    let cfg = RasterConfig {
        low_pass: if mip { LowPass::Mip } else { LowPass::Classic },
        background: finite3("background", background)?.to_array(),
        kernel: kernel.parse().map_err(crate::error)?,
        ..Default::default()
    };
    let c = &cloud.cloud;
    let color = py.detach(|| match stochastic {
        Some(n) => render_stochastic(c, &cam, &cfg, n, 0).color,
        None => splat_raster::render(c, &cam, &cfg).0.color,
    });
    let px: Vec<Vec3> = color.iter().map(|c| Vec3::from_array(*c)).collect();
    image_array(py, width, height, &px)
}

/// Ray-traces `cloud`: `mode` is `exact` (every hit sorted: the reference), `kbuffer`,
/// `stochastic` (one traversal, each hit accepted with its opacity) or `stochastic-pass`.
/// Returns (float32 (height, width, 3), estimates traced, interrupted): the GIL is released
/// and Ctrl-C stops it, each pixel keeping the mean of the estimates it finished (the Python
/// layer raises `Interrupted` with that image).
#[pyfunction]
#[pyo3(name = "_splat_trace", signature = (cloud, eye, target, *, up=[0.0, -1.0, 0.0], fov=50.0, width=1280, height=720, mode="stochastic", spp=16, seed=0, k=16, min_transmittance=0.0, samples_per_traversal=1, depth="mean", random="hash", background=[0.0; 3], threads=None))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments
pub(crate) fn splat_trace<'py>(
    py: Python<'py>,
    cloud: &Cloud,
    eye: [f32; 3],
    target: [f32; 3],
    up: [f32; 3],
    fov: f32,
    width: u32,
    height: u32,
    mode: &str,
    spp: u32,
    seed: u32,
    k: usize,
    min_transmittance: f32,
    samples_per_traversal: u32,
    depth: &str,
    random: &str,
    background: [f32; 3],
    threads: Option<usize>,
) -> PyResult<(Bound<'py, PyArray3<f32>>, u64, bool)> {
    let cam = camera(eye, target, up, fov, width, height)?;
    if spp == 0 || k == 0 || !(1..=64).contains(&samples_per_traversal) {
        return Err(crate::error(
            "spp and k must be at least 1, samples_per_traversal 1 to 64",
        ));
    }
    if !(0.0..=1.0).contains(&min_transmittance) {
        return Err(crate::error(format!(
            "min_transmittance {min_transmittance}: expected a number in [0, 1]"
        )));
    }
    let estimator = match mode {
        "exact" => Estimator::Exact,
        "kbuffer" => Estimator::KBuffer {
            k,
            min_transmittance,
        },
        "stochastic" => Estimator::Stochastic {
            samples_per_traversal,
        },
        "stochastic-pass" => Estimator::StochasticPass { k },
        other => {
            return Err(crate::error(format!(
                "mode `{other}`: expected exact, kbuffer, stochastic or stochastic-pass"
            )));
        }
    };
    let parse = |what: &str, v: &str| format!("{what} `{v}`");
    let depth_mode = <DepthMode as clap::ValueEnum>::from_str(depth, true)
        .map_err(|_| crate::error(parse("depth", depth) + ": expected mean or center"))?;
    let random = <RandomKind as clap::ValueEnum>::from_str(random, true)
        .map_err(|_| crate::error(parse("random", random) + ": expected hash or trig"))?;
    let settings = TraceSettings {
        estimator,
        depth_mode,
        spp,
        seed,
        background: finite3("background", background)?,
        random,
    };
    let c = &cloud.cloud;
    let outcome = crate::run::run_polled(py, threads, None, 0, |control| {
        trace_image_with(&GaussianScene::new(c), &cam, &settings, control).0
    })?;
    Ok((
        image_array(py, width, height, &outcome.value)?,
        outcome.done,
        outcome.interrupted,
    ))
}
