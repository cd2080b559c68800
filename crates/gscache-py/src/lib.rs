//! `gscache._gscache`: the Rust side of the Python package `gscache` (python/gscache). The
//! Python layer adds keyword defaults, the `Interrupted` exception and the Dask helpers;
//! everything that renders is here.
//!
//! - [`volume`]: `Volume` (from a numpy array or a file) and `Scene` (the scene format's
//!   tables, or a scene file).
//! - [`array_source`]: a volume streamed from a Python array (zarr, dask, a memmap) a brick
//!   at a time, never copied whole.
//! - [`run`]: running work with the GIL released while the calling thread polls for Ctrl-C
//!   and reports progress.
//! - [`render`]: `render`, `render_partial` and `Partial` (shards that merge bit for bit).
//! - [`cache`]: `Cache`, the GSCache radiance cache driving the path tracer.
//! - [`clouds`]: `Cloud`, `splat_render`, `splat_trace`.
//! - [`images`]: EXR and PNG reading and writing.
//! - [`denoise`]: `Denoiser`, Intel Open Image Denoise loaded at run time.
//! - [`movie`]: `movie` (whole, or one part of it), the parts' merge and the video.
//!
//! Every error is a `GscacheError` carrying the message the program prints.

// The modules are private (Python is this crate's interface); the list above links them for
// readers of `cargo doc --document-private-items`.
#![allow(rustdoc::private_intra_doc_links)]

mod array_source;
mod cache;
mod clouds;
mod denoise;
mod images;
mod movie;
mod render;
mod run;
mod view;
mod volume;

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    _gscache,
    GscacheError,
    PyException,
    "An error of the renderer: a file, a scene or a setting it refuses, with the message the \
     `gscache` program prints."
);

/// Any displayable error as a `GscacheError` (the program's message, alternate form: with
/// its causes).
pub(crate) fn error(e: impl std::fmt::Display) -> PyErr {
    GscacheError::new_err(format!("{e:#}"))
}

#[pymodule]
fn _gscache(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("GscacheError", m.py().get_type::<GscacheError>())?;
    m.add_class::<volume::Volume>()?;
    m.add_class::<volume::Scene>()?;
    m.add_class::<render::Partial>()?;
    m.add_class::<cache::Cache>()?;
    m.add_class::<clouds::Cloud>()?;
    m.add_class::<denoise::Denoiser>()?;
    m.add_class::<view::Viewer>()?;
    m.add_function(wrap_pyfunction!(view::_view, m)?)?;
    m.add_function(wrap_pyfunction!(volume::set_memory_budget, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_image, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_partial, m)?)?;
    m.add_function(wrap_pyfunction!(movie::movie, m)?)?;
    m.add_function(wrap_pyfunction!(movie::merge_movie, m)?)?;
    m.add_function(wrap_pyfunction!(movie::encode_movie, m)?)?;
    m.add_function(wrap_pyfunction!(clouds::splat_render, m)?)?;
    m.add_function(wrap_pyfunction!(clouds::splat_trace, m)?)?;
    m.add_function(wrap_pyfunction!(images::read_exr, m)?)?;
    m.add_function(wrap_pyfunction!(images::write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(images::write_png, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
