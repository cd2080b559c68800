//! The one loop that makes a movie: warm-up, resume, frames, references.

use crate::error::{MovieError, Result};
use crate::folder::{FrameRecord, MovieFolder};
use crate::quality::{movie_jod, reference};
use crate::spec::{FrameBudget, MovieSpec};
use denoise::{Denoiser, Guides};
use hdr_image::RgbImage;
use render_base::Control;
use render_session::{CacheChoice, Edit, ImageBudget, Session};
use volume_pt::Scene;

/// What the loop tells its caller as it goes.
#[derive(Debug, Clone)]
pub enum Progress<'a> {
    /// Warm-up frame `done` of `total` rendered (training the cache).
    WarmUp { done: u32, total: u32 },
    /// Frame `done` of `total` made before brought the cache back to its state (a resume).
    Replay { done: u32, total: u32 },
    /// A reference rendered for frame `frame`.
    Reference { frame: u32, seconds: f64 },
    /// A frame written; `seconds_left` estimated from the frames so far.
    Frame {
        record: &'a FrameRecord,
        frames: u32,
        seconds_left: f64,
    },
}

/// What [`render_movie`] made (written as `summary.json` when the movie is complete).
#[derive(Debug, Clone, serde::Serialize)]
pub struct MovieSummary {
    /// Frames in the folder (all of them unless interrupted).
    pub frames_done: u32,
    /// Frames made by this call (the rest were there before).
    pub frames_made: u32,
    pub interrupted: bool,
    /// The movie's ColorVideoVDP JOD against the references (all frames done, with references).
    pub jod: Option<f64>,
    /// Means over the frames in the folder.
    pub mean_frame_ms: f64,
    pub mean_rel_mse: Option<f64>,
    pub mean_flicker: Option<f64>,
}

/// Makes the movie `spec` of `scene` with the cache `choice` into `folder` (the whole movie, or
/// the part the folder holds), from the first frame it lacks. Each frame is written (EXR and PNG; the denoised pair with `denoiser`)
/// before the table records it; a cancelled frame is not written. `denoiser` must be given
/// exactly when the spec denoises. `control` cancels, and counts the frames made.
pub fn render_movie(
    scene: &Scene,
    choice: CacheChoice,
    spec: &MovieSpec,
    folder: &mut MovieFolder,
    mut denoiser: Option<&mut Denoiser>,
    control: &Control,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<MovieSummary> {
    let has_cache = !choice.is_none();
    spec.check(has_cache)?;
    if spec.denoise.is_some() != denoiser.is_some() {
        return Err(MovieError::Invalid(
            "a denoiser must be given exactly when the movie denoises".into(),
        ));
    }
    let guides = spec.denoise.map_or(Guides::None, |d| d.guides);
    let mut base = scene.clone();
    base.settings.spp = 1;
    let mut session = Session::new(base, choice)?.with_features(guides != Guides::None);
    // Every frame's sample indices are fixed before any work: they cannot wrap.
    let most_passes = match spec.budget {
        FrameBudget::Spp(s) => u64::from(s),
        FrameBudget::Seconds(_) => 1,
    };
    let planned = u64::from(spec.warmup) + u64::from(spec.frames) * most_passes;
    session.check_frames(u32::try_from(planned).map_err(|_| {
        MovieError::Invalid(format!(
            "{} frames of {most_passes} samples after {} warm-up frames: more than 2^32 passes",
            spec.frames, spec.warmup
        ))
    })?)?;
    let interrupted = |folder: &MovieFolder, made: u32| summary(folder, made, true, None);
    let range = folder.frames(spec);

    if range.start == 0 {
        for i in 0..spec.warmup {
            if control.cancelled() {
                return Ok(interrupted(folder, 0));
            }
            session.edit(Edit::Camera(spec.camera(scene, i % spec.frames)?))?;
            session.render_image(ImageBudget::Passes(1), &control.silent())?;
            progress(Progress::WarmUp {
                done: i + 1,
                total: spec.warmup,
            });
        }
    } else {
        // A part after the first: its frames take the samples one process would give them
        // (after the warm-up and every frame before), so without a cache they are that
        // process's frames, bit for bit. A cache trains on the `overlap` frames before the
        // part instead of all of them: the part's frames are close to one process's, not the
        // same (the seam).
        let FrameBudget::Spp(spp) = spec.budget else {
            return Err(MovieError::Invalid(
                "a movie in parts needs a sample budget per frame: with a time budget a frame's \
                 samples depend on how many passes every frame before it took"
                    .into(),
            ));
        };
        let overlap = if has_cache {
            folder.part().map_or(0, |p| p.overlap).min(range.start)
        } else {
            0
        };
        let before = range.start - overlap;
        session.skip_frames(spec.warmup + before * spp)?;
        for f in before..range.start {
            if control.cancelled() {
                return Ok(interrupted(folder, 0));
            }
            session.edit(Edit::Camera(spec.camera(scene, f)?))?;
            session.render_image(ImageBudget::Passes(spp), &control.silent())?;
            progress(Progress::WarmUp {
                done: f - before + 1,
                total: overlap,
            });
        }
    }
    let done: Vec<FrameRecord> = folder.done().to_vec();
    for r in &done {
        if session.frames_rendered() != r.first_sample_frame {
            return Err(MovieError::file(
                folder.dir(),
                format!(
                    "frame {} began at sample frame {} by the table, but the movie is at {} \
                     there: the table was changed by hand; move it away to start the movie \
                     again",
                    r.frame,
                    r.first_sample_frame,
                    session.frames_rendered()
                ),
            ));
        }
        if has_cache {
            if control.cancelled() {
                return Ok(interrupted(folder, 0));
            }
            session.edit(Edit::Camera(spec.camera(scene, r.frame)?))?;
            session.render_image(ImageBudget::Passes(r.passes), &control.silent())?;
            progress(Progress::Replay {
                done: r.frame - range.start + 1,
                total: done.len() as u32,
            });
        } else {
            session.skip_frames(r.passes)?;
        }
    }

    let start = std::time::Instant::now();
    let first = folder.next_frame();
    let mut made = 0u32;
    // The denoiser's share of a time budget: the mean of its times so far.
    let (mut denoise_sum, mut denoise_count) = (0.0f64, 0u32);
    let mut previous: Option<(RgbImage, RgbImage)> = match (first > range.start, spec.reference_spp)
    {
        (true, Some(spp)) => {
            let f = first - 1;
            let shown = RgbImage::read_exr(&folder.shown_exr(f))?;
            let cam = spec.camera(scene, f)?;
            Some((shown, reference(folder, scene, &cam, f, spp)?.image))
        }
        _ => None,
    };
    for f in first..range.end {
        if control.cancelled() {
            return Ok(interrupted(folder, made));
        }
        let camera = spec.camera(scene, f)?;
        session.edit(Edit::Camera(camera))?;
        let budget = match spec.budget {
            FrameBudget::Spp(s) => ImageBudget::Passes(s),
            FrameBudget::Seconds(t) => {
                let denoise = if denoise_count > 0 {
                    denoise_sum / f64::from(denoise_count)
                } else {
                    0.0
                };
                ImageBudget::Seconds((t - denoise).max(0.0))
            }
        };
        // Progress is counted in frames (below), not in the passes' samples.
        let image_report = session.render_image(budget, &control.silent())?;
        if image_report.report.cancelled || control.cancelled() {
            return Ok(interrupted(folder, made));
        }
        let image = session.image();
        let (exposure, tonemap) = (scene.output.exposure, scene.output.tonemap);
        image.write_exr(&folder.frame_file(f, ".exr"))?;
        image.write_png(&folder.frame_file(f, ".png"), exposure, tonemap)?;
        let mut denoise_seconds = 0.0;
        let shown = match (denoiser.as_deref_mut(), spec.denoise) {
            (Some(d), Some(ds)) => {
                let features = session.feature_images();
                let t = std::time::Instant::now();
                let out = d.denoise_guided(&image, features.as_ref(), guides, ds.options())?;
                denoise_seconds = t.elapsed().as_secs_f64();
                // The first frame may build the filter: the budget follows the later ones.
                if f > first {
                    denoise_sum += denoise_seconds;
                    denoise_count += 1;
                }
                out.write_exr(&folder.frame_file(f, ".denoised.exr"))?;
                out.write_png(&folder.frame_file(f, ".denoised.png"), exposure, tonemap)?;
                out
            }
            _ => image,
        };
        let rep = &image_report.report;
        let mut record = FrameRecord {
            frame: f,
            first_sample_frame: image_report.first_frame,
            passes: image_report.passes,
            trace_ms: rep.trace_seconds * 1e3,
            lookup_ms: rep.lookup_seconds * 1e3,
            train_ms: rep.train_seconds * 1e3,
            denoise_ms: denoise_seconds * 1e3,
            total_ms: (rep.seconds + denoise_seconds) * 1e3,
            rel_mse: None,
            flicker: None,
        };
        if let Some(spp) = spec.reference_spp {
            let r = reference(folder, scene, &camera, f, spp)?;
            if let Some(seconds) = r.rendered_seconds {
                progress(Progress::Reference { frame: f, seconds });
            }
            record.rel_mse = Some(image_metrics::rel_mse(shown.pixels(), r.image.pixels()));
            if let Some((prev, prev_ref)) = &previous {
                record.flicker = Some(image_metrics::flicker(
                    prev.pixels(),
                    shown.pixels(),
                    prev_ref.pixels(),
                    r.image.pixels(),
                ));
            }
            previous = Some((shown, r.image));
        }
        folder.record(record)?;
        made += 1;
        control.progress(1);
        let per_frame = start.elapsed().as_secs_f64() / f64::from(made);
        let record = folder.done().last().expect("just recorded");
        progress(Progress::Frame {
            record,
            frames: spec.frames,
            seconds_left: per_frame * f64::from(range.end - f - 1),
        });
    }
    let jod = match spec.reference_spp {
        Some(_) => Some(movie_jod(folder, scene, range, spec.fps)?),
        None => None,
    };
    let done = summary(folder, made, false, jod);
    folder.write_summary(&done)?;
    Ok(done)
}

fn summary(folder: &MovieFolder, made: u32, interrupted: bool, jod: Option<f64>) -> MovieSummary {
    let done = folder.done();
    let n = done.len().max(1) as f64;
    let mean_of = |v: &dyn Fn(&FrameRecord) -> Option<f64>| {
        let vals: Vec<f64> = done.iter().filter_map(v).collect();
        (!vals.is_empty()).then(|| vals.iter().sum::<f64>() / vals.len() as f64)
    };
    MovieSummary {
        frames_done: done.len() as u32,
        frames_made: made,
        interrupted,
        jod,
        mean_frame_ms: done.iter().map(|r| r.total_ms).sum::<f64>() / n,
        mean_rel_mse: mean_of(&|r| r.rel_mse),
        mean_flicker: mean_of(&|r| r.flicker),
    }
}
