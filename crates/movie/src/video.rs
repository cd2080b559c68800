//! The movie's video, encoded from its PNG frames by ffmpeg (Debian's `ffmpeg` package, or any
//! on the PATH): H.264 in MP4 (plays everywhere) or VP9 in WebM (for the web). Written beside
//! the frames under a temporary name and renamed, so a failed encode leaves no half video.

use crate::error::{MovieError, Result};
use crate::folder::MovieFolder;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The video's container and codec.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VideoFormat {
    /// H.264 (yuv420p, CRF 18: visually lossless for most renders) in MP4.
    Mp4,
    /// VP9 (constant quality 31) in WebM.
    Webm,
}

impl VideoFormat {
    fn extension(self) -> &'static str {
        match self {
            VideoFormat::Mp4 => "mp4",
            VideoFormat::Webm => "webm",
        }
    }

    fn codec_args(self) -> &'static [&'static str] {
        match self {
            VideoFormat::Mp4 => &[
                "-c:v",
                "libx264",
                "-pix_fmt",
                "yuv420p",
                "-crf",
                "18",
                "-movflags",
                "+faststart",
            ],
            VideoFormat::Webm => &[
                "-c:v",
                "libvpx-vp9",
                "-pix_fmt",
                "yuv420p",
                "-b:v",
                "0",
                "-crf",
                "31",
            ],
        }
    }
}

/// The ffmpeg a movie is encoded with: `$GSCACHE_FFMPEG`, else `ffmpeg` on the PATH.
pub fn ffmpeg_from_env() -> PathBuf {
    std::env::var_os("GSCACHE_FFMPEG").map_or_else(|| PathBuf::from("ffmpeg"), PathBuf::from)
}

/// Encodes the folder's frames `0..frames` at `fps` with the ffmpeg `exe` into `movie.mp4` or
/// `movie.webm` there; returns its path. Without ffmpeg, says how to get it (the frames stay
/// as they are).
pub fn encode_video(
    folder: &MovieFolder,
    frames: u32,
    fps: f64,
    format: VideoFormat,
    exe: &Path,
) -> Result<PathBuf> {
    let out = folder.dir().join(format!("movie.{}", format.extension()));
    let partial = folder.dir().join(format!(
        ".movie.{}.{}.partial.{}",
        std::process::id(),
        frames,
        format.extension()
    ));
    let mut cmd = Command::new(exe);
    cmd.args(["-hide_banner", "-loglevel", "error", "-nostdin", "-y"])
        .arg("-framerate")
        .arg(format!("{fps}"))
        .arg("-start_number")
        .arg("0")
        .arg("-i")
        .arg(folder.png_pattern())
        .arg("-frames:v")
        .arg(frames.to_string())
        // Even sizes: 4:2:0 chroma needs them.
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"])
        .args(format.codec_args())
        .arg(&partial)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let result = match cmd.output() {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(MovieError::Video(format!(
                "no video made: {} was not found (Debian: `apt-get install ffmpeg`; or set \
                 GSCACHE_FFMPEG to an ffmpeg); the frames are in {}",
                exe.display(),
                folder.dir().display()
            )));
        }
        Err(e) => {
            return Err(MovieError::Video(format!(
                "no video made: cannot run {}: {e}",
                exe.display()
            )));
        }
        Ok(r) => r,
    };
    if !result.status.success() {
        let _ = std::fs::remove_file(&partial);
        let said = String::from_utf8_lossy(&result.stderr);
        return Err(MovieError::Video(format!(
            "no video made: {} failed ({}): {}",
            exe.display(),
            result.status,
            said.trim()
        )));
    }
    std::fs::rename(&partial, &out).map_err(|e| {
        let _ = std::fs::remove_file(&partial);
        MovieError::file(&out, format!("cannot move the video into place: {e}"))
    })?;
    Ok(out)
}
