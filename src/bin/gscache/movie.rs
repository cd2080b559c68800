//! `gscache movie SCENE -o FOLDER`: a turntable or key-framed movie of a volume with any
//! method, as numbered EXR and PNG frames and a video; resumable (the movie crate).

use crate::cache_flags::CacheFlags;
use crate::common::{INTERRUPTED, cancellation, finite_f32};
use crate::denoising::DenoiseArgs;
use anyhow::{Context, Result};
use movie::{
    DenoiseSpec, FrameBudget, MovieFolder, MoviePath, MovieSpec, Progress, VideoFormat,
    encode_video, ffmpeg_from_env, render_movie,
};
use render_session::Control;
use render_session::camera_path::Keyframe;
use std::path::{Path, PathBuf};
use volume_pt::RenderKey;

/// Make a movie: frames along a turntable about the scene's up (or key frames), each of `--spp`
/// samples or `--frame-seconds`, with NEE or a cache warmed up along the path, optionally
/// denoised, into a folder of numbered EXR and PNG frames and an MP4 or WebM video (ffmpeg).
/// Ctrl-C keeps every finished frame; `--resume` goes on from the first missing one, bit for bit.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct MovieArgs {
    /// Scene file (TOML), or a volume file (a scene is chosen for it, as `render` does).
    scene: PathBuf,
    /// The movie's folder: created, or empty; one holding this movie goes on with --resume.
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
    /// Frames in the movie.
    #[arg(long, default_value_t = 120)]
    frames: u32,
    /// Frames a second the video plays at.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Degrees the camera turns about the scene's up (its camera's `up`) through the volume's
    /// centre over the movie, starting at the scene's camera; 360 makes a loop.
    #[arg(long, value_name = "DEG", default_value_t = 360.0, value_parser = finite_f32)]
    turntable_degrees: f32,
    /// A key-framed path instead of the turntable: a TOML file of `[[key]]` tables with
    /// `frame`, `eye` and `target` (as the experiments' fly-throughs take them).
    #[arg(long, value_name = "FILE")]
    keys: Option<PathBuf>,
    /// Each frame's time budget in seconds instead of `--spp` samples: passes of 1 sample while
    /// the next fits, the cache's work and the denoiser charged. Frames then differ from run to
    /// run (the machine decides the passes); a resume replays the recorded passes.
    #[arg(long, value_name = "SECONDS")]
    frame_seconds: Option<f64>,
    /// Frames rendered along the path's start only to train the cache, before the movie.
    #[arg(long, default_value_t = 0)]
    warmup: u32,
    /// The video: mp4 (H.264), webm (VP9) or none (the frames alone).
    #[arg(long, value_enum, default_value_t = VideoChoice::Mp4)]
    video: VideoChoice,
    /// Go on with the movie in the folder from its first missing frame.
    #[arg(long)]
    resume: bool,
    /// Render each frame's NEE reference at this many samples a pixel (kept in
    /// FOLDER/reference) and report each frame's relMSE and flicker and the movie's
    /// ColorVideoVDP JOD: how close and how steady the movie is.
    #[arg(long, value_name = "SPP")]
    reference_spp: Option<u32>,
    /// What the command line changes of the scene (`--spp` is the samples of each frame).
    #[command(flatten)]
    overrides: volume_pt::SceneOverrides,
    #[command(flatten)]
    denoise: DenoiseArgs,
    #[command(flatten)]
    cache: CacheFlags,
}

/// The video a movie gets.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
enum VideoChoice {
    Mp4,
    Webm,
    None,
}

/// The key-frame file: `[[key]]` tables.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyFile {
    key: Vec<Keyframe>,
}

fn read_keys(path: &Path) -> Result<Vec<Keyframe>> {
    let text = volume_pt::io::read_text_file(path, "a key-frame file")?;
    let file: KeyFile = toml::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "{}: not a key-frame file ([[key]] tables of frame, eye, target): {e}",
            path.display()
        )
    })?;
    Ok(file.key)
}

impl MovieArgs {
    /// Notes which cache settings the command line named ([`CacheFlags::note_named`]).
    pub fn note_named(&mut self, matches: &clap::ArgMatches) {
        self.cache.note_named(matches);
    }
}

pub fn run(args: MovieArgs, global: &crate::common::Global) -> Result<i32> {
    let opened = volume_pt::open_scene(&args.scene, volume_pt::Colormap::default())?;
    let features = args.denoise.needs_features();
    let scene = crate::render::finish_scene(opened.scene, &args.overrides, features)?;
    let choice = args.cache.choice(None, args.denoise.denoise)?;
    let path = match &args.keys {
        Some(file) => MoviePath::Keys {
            keys: read_keys(file)?,
        },
        None => MoviePath::Turntable {
            degrees: args.turntable_degrees,
        },
    };
    let budget = match args.frame_seconds {
        Some(t) => FrameBudget::Seconds(t),
        None => FrameBudget::Spp(scene.settings.spp),
    };
    let spec = MovieSpec {
        frames: args.frames,
        fps: args.fps,
        path,
        budget,
        warmup: args.warmup,
        denoise: args.denoise.denoise.then(|| DenoiseSpec {
            quality: args.denoise.denoise_quality,
            guides: args.denoise.denoise_guides,
            prefilter: args.denoise.options().prefilter,
        }),
        reference_spp: args.reference_spp,
    };
    spec.check(!choice.is_none())?;
    // What decides the frames besides the spec: the scene (its text, the volume, every
    // setting after the overrides) and the method.
    let identity = RenderKey::new()
        .part(opened.text.as_bytes())
        .part(scene.volume_path.to_string_lossy().as_bytes())
        .part(
            volume_pt::scene::settings_fingerprint(
                &scene.settings,
                &scene.camera,
                &scene.media.medium,
            )
            .as_bytes(),
        )
        .part(format!("{:?}|{:?}", scene.output, choice).as_bytes())
        .hex();
    let mut denoiser = args.denoise.load()?;
    let mut folder = MovieFolder::open(&args.output, &identity, &spec, args.resume)?;
    let already = folder.done().len();
    if already > 0 {
        eprintln!(
            "resuming {}: {already} of {} frames were made",
            args.output.display(),
            spec.frames
        );
    }
    let cancel = cancellation()?;
    let control = Control::new(&cancel, &|_| {});
    let quiet = global.quiet;
    let mut report = |p: Progress<'_>| {
        if quiet {
            return;
        }
        match p {
            Progress::WarmUp { done, total } if done == total || done % 10 == 0 => {
                eprintln!("warm-up: {done} of {total} frames")
            }
            Progress::Replay { done, total } if done == total || done % 10 == 0 => {
                eprintln!("bringing the cache back: {done} of {total} frames made before")
            }
            Progress::Reference { frame, seconds } => {
                eprintln!("reference of frame {frame}: {seconds:.1} s")
            }
            Progress::Frame {
                record: r,
                frames,
                seconds_left,
            } => eprintln!(
                "frame {} of {frames}: {} passes, {:.0} ms{}{}; about {} left",
                r.frame + 1,
                r.passes,
                r.total_ms,
                if r.denoise_ms > 0.0 {
                    format!(" ({:.0} ms denoising)", r.denoise_ms)
                } else {
                    String::new()
                },
                r.rel_mse
                    .map_or(String::new(), |e| format!(", relMSE {e:.2e}")),
                duration(seconds_left)
            ),
            _ => {}
        }
    };
    let summary = render_movie(
        &scene,
        choice,
        &spec,
        &mut folder,
        denoiser.as_mut(),
        &control,
        &mut report,
    )?;
    if summary.interrupted {
        eprintln!(
            "interrupted: {} of {} frames are in {} (every one finished); `--resume` goes on \
             from frame {}",
            summary.frames_done,
            spec.frames,
            args.output.display(),
            summary.frames_done + 1
        );
        return Ok(INTERRUPTED);
    }
    eprintln!(
        "{} frames in {} ({} made now), {:.0} ms a frame on average",
        summary.frames_done,
        args.output.display(),
        summary.frames_made,
        summary.mean_frame_ms
    );
    if let (Some(e), Some(j)) = (summary.mean_rel_mse, summary.jod) {
        eprintln!(
            "against the references: mean relMSE {e:.3e}, mean flicker {}, ColorVideoVDP {j:.3} \
             JOD (10: no visible difference)",
            summary
                .mean_flicker
                .map_or("-".to_string(), |f| format!("{f:.3e}"))
        );
    }
    let format = match args.video {
        VideoChoice::Mp4 => VideoFormat::Mp4,
        VideoChoice::Webm => VideoFormat::Webm,
        VideoChoice::None => return Ok(0),
    };
    let video = encode_video(&folder, spec.frames, spec.fps, format, &ffmpeg_from_env())
        .context("the frames are written; only the video is missing")?;
    eprintln!("wrote {}", video.display());
    Ok(0)
}

/// Seconds as "1 h 05 min", "4 min 10 s" or "12 s".
fn duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}
