//! `movie`: `gscache movie` from Python (the movie crate): a movie of a scene into a folder,
//! whole or one part of it (a range of frames, for the Dask helpers), and the merge of parts.

use crate::run::run_polled;
use crate::volume::Scene;
use ::movie::{MovieFolder, MovieSpec, Part, merge_parts, render_movie};
use pyo3::prelude::*;
use render_session::CacheChoice;
use std::path::PathBuf;

fn spec_from(spec_json: &str) -> PyResult<MovieSpec> {
    serde_json::from_str(spec_json).map_err(|e| crate::error(format!("movie: {e}")))
}

/// The movie's cache from its settings as JSON (none: NEE). A movie that will be `denoised`
/// takes [`gs_cache::CacheConfig::for_denoiser`]'s termination unless the settings name one
/// of its keys, as `gscache movie --denoise` does.
fn choice_from(cache_json: Option<&str>, denoised: bool) -> PyResult<CacheChoice> {
    let Some(j) = cache_json else {
        return Ok(CacheChoice::None);
    };
    let bad = |e: serde_json::Error| crate::error(format!("cache config: {e}"));
    let value: serde_json::Value = serde_json::from_str(j).map_err(bad)?;
    let named = gs_cache::CacheConfig::FOR_DENOISER_KEYS
        .iter()
        .any(|k| value.get(k).is_some());
    let mut config: gs_cache::CacheConfig = serde_json::from_value(value).map_err(bad)?;
    if denoised && !named {
        config = config.for_denoiser();
    }
    config.validate().map_err(crate::error)?;
    Ok(CacheChoice::gaussian(config))
}

/// What decides the movie's frames besides its spec: the scene (its key with its settings)
/// and the cache.
fn identity(scene: &Scene, choice: &CacheChoice) -> String {
    format!(
        "{}|{:?}|{choice:?}",
        scene.key(&scene.scene.settings),
        scene.scene.output
    )
}

/// Makes the movie `spec_json` (a `MovieSpec` as JSON) of `scene` with the Gaussian cache
/// `cache_json` (its settings as JSON; none: NEE) into `folder`, or its frames
/// `part = (first, last, overlap)`. Returns (frames in the folder, interrupted, the summary as
/// JSON).
#[pyfunction]
#[pyo3(name = "_movie", signature = (scene, folder, spec_json, cache_json=None, resume=false, part=None, threads=None, progress=None))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments
pub(crate) fn movie(
    py: Python<'_>,
    scene: &Scene,
    folder: PathBuf,
    spec_json: &str,
    cache_json: Option<&str>,
    resume: bool,
    part: Option<(u32, u32, u32)>,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<(u32, bool, String)> {
    let spec = spec_from(spec_json)?;
    let choice = choice_from(cache_json, spec.denoise.is_some())?;
    spec.check(!choice.is_none()).map_err(crate::error)?;
    let part = part.map(|(first, last, overlap)| Part {
        first,
        last,
        overlap,
    });
    let mut denoiser = match spec.denoise {
        Some(_) => Some(
            denoise::Denoiser::load(threads.unwrap_or_else(rayon::current_num_threads))
                .map_err(crate::error)?,
        ),
        None => None,
    };
    let id = identity(scene, &choice);
    let mut movie_folder =
        MovieFolder::open_part(&folder, &id, &spec, part, resume).map_err(crate::error)?;
    let range = movie_folder.frames(&spec);
    let total = u64::from(range.end - movie_folder.next_frame());
    let s = &scene.scene;
    let outcome = run_polled(py, threads, progress.as_ref(), total, |control| {
        render_movie(
            s,
            choice,
            &spec,
            &mut movie_folder,
            denoiser.as_mut(),
            control,
            &mut |_| {},
        )
    })?;
    let summary = outcome.value.map_err(crate::error)?;
    let json = serde_json::json!({
        "frames_done": summary.frames_done,
        "frames_made": summary.frames_made,
        "mean_frame_ms": summary.mean_frame_ms,
        "mean_rel_mse": summary.mean_rel_mse,
        "mean_flicker": summary.mean_flicker,
        "jod": summary.jod,
    })
    .to_string();
    Ok((
        summary.frames_done,
        summary.interrupted || outcome.interrupted,
        json,
    ))
}

/// Joins the movie's parts (folders made by `_movie` with `part`) into `folder`, in order.
#[pyfunction]
#[pyo3(name = "_merge_movie", signature = (scene, folder, spec_json, parts, cache_json=None))]
pub(crate) fn merge_movie(
    scene: &Scene,
    folder: PathBuf,
    spec_json: &str,
    parts: Vec<PathBuf>,
    cache_json: Option<&str>,
) -> PyResult<u32> {
    let spec = spec_from(spec_json)?;
    let choice = choice_from(cache_json, spec.denoise.is_some())?;
    let merged =
        merge_parts(&folder, &identity(scene, &choice), &spec, &parts).map_err(crate::error)?;
    Ok(merged.done().len() as u32)
}

/// Encodes the folder's frames into `movie.mp4` or `movie.webm` with ffmpeg; returns its path.
#[pyfunction]
#[pyo3(name = "_encode_movie", signature = (scene, folder, spec_json, format, cache_json=None))]
pub(crate) fn encode_movie(
    scene: &Scene,
    folder: PathBuf,
    spec_json: &str,
    format: &str,
    cache_json: Option<&str>,
) -> PyResult<PathBuf> {
    let spec = spec_from(spec_json)?;
    let choice = choice_from(cache_json, spec.denoise.is_some())?;
    let format = match format {
        "mp4" => ::movie::VideoFormat::Mp4,
        "webm" => ::movie::VideoFormat::Webm,
        other => {
            return Err(crate::error(format!(
                "video `{other}`: expected `mp4`, `webm` or None"
            )));
        }
    };
    let opened =
        MovieFolder::open(&folder, &identity(scene, &choice), &spec, true).map_err(crate::error)?;
    ::movie::encode_video(
        &opened,
        spec.frames,
        spec.fps,
        format,
        &::movie::ffmpeg_from_env(),
    )
    .map_err(crate::error)
}
