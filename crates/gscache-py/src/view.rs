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
#[pyo3(signature = (scene, text, file, port, bind, output, max_clients))]
#[allow(clippy::too_many_arguments)] // the program's flags, one for one
pub fn _view(
    scene: &Scene,
    text: String,
    file: PathBuf,
    port: u16,
    bind: &str,
    output: PathBuf,
    max_clients: usize,
) -> PyResult<Viewer> {
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
            resolution: viewer::Resolution::default(),
            denoising: viewer::Denoising::default(),
        },
    )
    .map_err(crate::error)?;
    Ok(Viewer {
        url: v.url().to_string(),
        inner: Some(v),
    })
}
