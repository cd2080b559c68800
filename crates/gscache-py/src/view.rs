//! `gscache.view`: the browser viewer (the viewer crate) started from Python, on a scene in
//! memory. The server runs on threads of its own; the handle stops it.

use crate::volume::Scene;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::net::IpAddr;
use std::path::PathBuf;

/// A running viewer: its URL, and `stop()`.
#[pyclass(module = "gscache._gscache")]
pub struct Viewer {
    inner: Option<viewer::Viewer>,
    url: String,
}

#[pymethods]
impl Viewer {
    #[getter]
    fn url(&self) -> String {
        self.url.clone()
    }

    /// Stops serving and rendering (also done when the handle is dropped).
    fn stop(&mut self, py: Python<'_>) {
        if let Some(v) = self.inner.take() {
            py.detach(|| v.stop());
        }
    }
}

/// Starts the viewer on `scene`; `text` and `file` are the scene file's text and path (for
/// Save; empty for a scene made from tables).
#[pyfunction]
#[pyo3(signature = (scene, text, file, port, bind, output, max_clients, denoise, denoise_until, scale))]
#[allow(clippy::too_many_arguments)] // the program's flags, one for one
pub fn _view(
    scene: &Scene,
    text: String,
    file: PathBuf,
    port: u16,
    bind: &str,
    output: PathBuf,
    max_clients: usize,
    denoise: &str,
    denoise_until: u32,
    scale: f32,
) -> PyResult<Viewer> {
    let start = match denoise {
        "off" => viewer::DenoiseStart::Off,
        "auto" => viewer::DenoiseStart::Auto,
        "on" => viewer::DenoiseStart::On,
        other => {
            return Err(PyValueError::new_err(format!(
                "denoise `{other}`: expected \"off\", \"auto\" or \"on\""
            )));
        }
    };
    // Written so that NaN is refused.
    if !viewer::protocol::SCALES.contains(&scale) {
        return Err(PyValueError::new_err(format!(
            "scale {scale}: expected {} to {}",
            viewer::protocol::SCALES.start(),
            viewer::protocol::SCALES.end()
        )));
    }
    let bind: IpAddr = bind
        .parse()
        .map_err(|e| PyValueError::new_err(format!("bind `{bind}`: {e}")))?;
    let v = viewer::serve(
        scene.scene.clone(),
        text,
        file,
        viewer::ServeOptions {
            bind,
            port,
            output,
            max_clients: max_clients.max(1),
            // Loaded when the page first turns denoising on: loading runs the library's code.
            denoiser: denoise::OnDemand::new(0),
            limits: viewer::Limits::default(),
            resolution: viewer::Resolution {
                scale,
                ..viewer::Resolution::default()
            },
            denoising: viewer::Denoising {
                start,
                until_spp: denoise_until,
            },
        },
    )
    .map_err(crate::error)?;
    Ok(Viewer {
        url: v.url().to_string(),
        inner: Some(v),
    })
}
