//! The movie's folder: `movie.json` (what the movie is), `frame_NNNNNN.exr` and `.png` (and
//! `.denoised.exr` / `.png`), `frames.csv` (what each frame took, its error where measured),
//! `reference/` (the references, if asked for), `summary.json` (once complete) and the video.
//!
//! The table is written after a frame's files, atomically, so a frame in the table is a frame
//! whose files are complete: it is what a resume trusts. A folder that holds anything but a
//! movie is refused, and a movie is never overwritten: resuming it must be asked for.

use crate::error::{MovieError, Result};
use crate::spec::MovieSpec;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

const MANIFEST: &str = "movie.json";
const TABLE: &str = "frames.csv";
const SUMMARY: &str = "summary.json";
const FORMAT: &str = "gscache-movie";
const VERSION: u32 = 1;
const HEADER: &str = "frame,first_sample_frame,passes,trace_ms,lookup_ms,train_ms,denoise_ms,total_ms,rel_mse,flicker";

/// The folder's manifest: the movie and the identity of what renders it (scene, method).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    format: String,
    version: u32,
    /// The caller's key of the scene and method (the same movie resumes only into the same).
    identity: String,
    spec: MovieSpec,
    /// A part's frames (a movie split across processes); none for a whole movie.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    part: Option<Part>,
}

/// Frames `first .. last` of a movie, made by one process of several (see
/// [`crate::render::render_movie`] for what a part starting after frame 0 renders first).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Part {
    pub first: u32,
    pub last: u32,
    /// With a cache: frames before `first` rendered again to train it (not written).
    pub overlap: u32,
}

/// What one frame took, and its error against its reference where references were asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    pub frame: u32,
    /// The session's frame index of the frame's first pass (its samples: see render-session's
    /// sampling rule): with `passes`, what a resume replays.
    pub first_sample_frame: u32,
    pub passes: u32,
    pub trace_ms: f64,
    pub lookup_ms: f64,
    pub train_ms: f64,
    pub denoise_ms: f64,
    /// The whole frame: its passes and the denoiser.
    pub total_ms: f64,
    /// relMSE of the frame shown (denoised, if denoising) against its reference.
    pub rel_mse: Option<f64>,
    /// Flicker (image-metrics) from the frame before.
    pub flicker: Option<f64>,
}

impl FrameRecord {
    fn csv(&self) -> String {
        let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6e}"));
        format!(
            "{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{},{}",
            self.frame,
            self.first_sample_frame,
            self.passes,
            self.trace_ms,
            self.lookup_ms,
            self.train_ms,
            self.denoise_ms,
            self.total_ms,
            opt(self.rel_mse),
            opt(self.flicker)
        )
    }

    fn parse(line: &str) -> Option<Self> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 10 {
            return None;
        }
        let num = |i: usize| f[i].parse::<f64>().ok().filter(|v| v.is_finite());
        let opt = |i: usize| -> Option<Option<f64>> {
            if f[i].is_empty() {
                Some(None)
            } else {
                num(i).map(Some)
            }
        };
        Some(Self {
            frame: f[0].parse().ok()?,
            first_sample_frame: f[1].parse().ok()?,
            passes: f[2].parse().ok().filter(|&p| p > 0)?,
            trace_ms: num(3)?,
            lookup_ms: num(4)?,
            train_ms: num(5)?,
            denoise_ms: num(6)?,
            total_ms: num(7)?,
            rel_mse: opt(8)?,
            flicker: opt(9)?,
        })
    }
}

/// An open movie folder.
#[derive(Debug)]
pub struct MovieFolder {
    dir: PathBuf,
    denoised: bool,
    part: Option<Part>,
    records: Vec<FrameRecord>,
}

impl MovieFolder {
    /// Opens `dir` for the movie `spec` rendered by what `identity` names: a new or empty
    /// folder starts the movie; one holding this movie's frames goes on from them with
    /// `resume` (and is refused without it); anything else is refused.
    pub fn open(dir: &Path, identity: &str, spec: &MovieSpec, resume: bool) -> Result<Self> {
        Self::open_part(dir, identity, spec, None, resume)
    }

    /// [`MovieFolder::open`] for `part` of the movie (all of it when `None`): the folder then
    /// holds frames `part.first .. part.last` only, named by their place in the movie.
    pub fn open_part(
        dir: &Path,
        identity: &str,
        spec: &MovieSpec,
        part: Option<Part>,
        resume: bool,
    ) -> Result<Self> {
        if let Some(p) = part
            && !(p.first < p.last && p.last <= spec.frames)
        {
            return Err(MovieError::Invalid(format!(
                "frames {} to {} of a movie of {}: expected a range within it, not empty",
                p.first, p.last, spec.frames
            )));
        }
        let manifest = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            identity: identity.into(),
            spec: spec.clone(),
            part,
        };
        let mut folder = Self {
            dir: dir.to_path_buf(),
            denoised: spec.denoise.is_some(),
            part,
            records: Vec::new(),
        };
        if dir.exists() && !dir.is_dir() {
            return Err(MovieError::file(
                dir,
                "not a folder: name a folder for the movie",
            ));
        }
        let manifest_path = dir.join(MANIFEST);
        if manifest_path.exists() {
            let found = read_manifest(&manifest_path)?;
            if !resume {
                return Err(MovieError::file(
                    dir,
                    "holds a movie already: go on with it with --resume, or name another folder \
                     (nothing in it is replaced)",
                ));
            }
            if found != manifest {
                return Err(MovieError::file(
                    dir,
                    format!(
                        "holds another movie than this one ({}): resume it with the settings it \
                         was made with, or name another folder",
                        describe_difference(&found, &manifest)
                    ),
                ));
            }
            folder.records = folder.finished(spec)?;
            return Ok(folder);
        }
        if dir.exists() {
            let mut entries = std::fs::read_dir(dir)
                .map_err(|e| MovieError::file(dir, format!("cannot read the folder: {e}")))?;
            if entries.next().is_some() {
                return Err(MovieError::file(
                    dir,
                    "holds other files and no movie: name a new or empty folder",
                ));
            }
        }
        create(dir, &manifest)?;
        Ok(folder)
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Frame `f`'s file ending in `suffix` (`.exr`, `.png`, `.denoised.exr`, `.denoised.png`):
    /// `frame_NNNNNN` and the suffix.
    pub fn frame_file(&self, f: u32, suffix: &str) -> PathBuf {
        self.dir.join(format!("frame_{f:06}{suffix}"))
    }

    /// The frames' PNG files as ffmpeg's pattern names them: the denoised ones when denoising.
    pub fn png_pattern(&self) -> PathBuf {
        let suffix = if self.denoised { ".denoised" } else { "" };
        self.dir.join(format!("frame_%06d{suffix}.png"))
    }

    /// The EXR of frame `f` as shown: the denoised one when denoising.
    pub fn shown_exr(&self, f: u32) -> PathBuf {
        let suffix = if self.denoised {
            ".denoised.exr"
        } else {
            ".exr"
        };
        self.frame_file(f, suffix)
    }

    /// The files frame `f` is made of.
    fn frame_files(&self, f: u32) -> Vec<PathBuf> {
        let suffixes: &[&str] = if self.denoised {
            &[".exr", ".png", ".denoised.exr", ".denoised.png"]
        } else {
            &[".exr", ".png"]
        };
        suffixes.iter().map(|s| self.frame_file(f, s)).collect()
    }

    /// The references' folder.
    pub fn reference_dir(&self) -> PathBuf {
        self.dir.join("reference")
    }

    /// The frames done: the table's rows from the folder's first frame on whose files are all
    /// there.
    pub fn done(&self) -> &[FrameRecord] {
        &self.records
    }

    /// The frames this folder holds: the part's, or the whole movie's.
    pub fn frames(&self, spec: &MovieSpec) -> std::ops::Range<u32> {
        self.part.map_or(0..spec.frames, |p| p.first..p.last)
    }

    /// The part this folder holds, if it is one.
    pub fn part(&self) -> Option<Part> {
        self.part
    }

    /// The frame after the last one done.
    pub fn next_frame(&self) -> u32 {
        self.first_frame() + self.records.len() as u32
    }

    fn first_frame(&self) -> u32 {
        self.part.map_or(0, |p| p.first)
    }

    /// Adds frame `record.frame` (the next) to the table, once its files are written.
    pub fn record(&mut self, record: FrameRecord) -> Result<()> {
        let expected = self.next_frame();
        if record.frame != expected {
            return Err(MovieError::Invalid(format!(
                "frame {} recorded where frame {expected} comes next",
                record.frame
            )));
        }
        self.records.push(record);
        self.write_table()
    }

    /// Writes the complete movie's summary (`summary.json`: means over the frames, the JOD).
    pub fn write_summary(&self, summary: &crate::render::MovieSummary) -> Result<()> {
        let path = self.dir.join(SUMMARY);
        let text = serde_json::to_string_pretty(summary)
            .map_err(|e| MovieError::file(&path, e.to_string()))?;
        write_text(&path, &text)
    }

    fn write_table(&self) -> Result<()> {
        let mut text = format!("{HEADER}\n");
        for r in &self.records {
            let _ = writeln!(text, "{}", r.csv());
        }
        write_text(&self.dir.join(TABLE), &text)
    }

    /// Reads the table and keeps the rows, from frame 0 on, whose files are all there; the
    /// table is written back with those alone (a frame whose files went missing, and every
    /// frame after it, is made again).
    fn finished(&self, spec: &MovieSpec) -> Result<Vec<FrameRecord>> {
        let path = self.dir.join(TABLE);
        let text = std::fs::read_to_string(&path)
            .map_err(|e| MovieError::file(&path, format!("cannot read the frame table: {e}")))?;
        let mut lines = text.lines();
        if lines.next() != Some(HEADER) {
            return Err(MovieError::file(
                &path,
                format!("not a movie's frame table: expected the header `{HEADER}`"),
            ));
        }
        let mut out: Vec<FrameRecord> = Vec::new();
        let range = self.frames(spec);
        for (i, line) in lines.enumerate() {
            let Some(r) = FrameRecord::parse(line) else {
                return Err(MovieError::file(
                    &path,
                    format!("row {}: `{line}` is not a frame's record", i + 1),
                ));
            };
            let next = range.start + out.len() as u32;
            if r.frame != next || !range.contains(&r.frame) {
                break;
            }
            if !self.frame_files(r.frame).iter().all(|p| p.is_file()) {
                break;
            }
            out.push(r);
        }
        Ok(out)
    }
}

/// Creates `dir` (if need be) with `manifest` and an empty table.
fn create(dir: &Path, manifest: &Manifest) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| MovieError::file(dir, format!("cannot create the folder: {e}")))?;
    let path = dir.join(MANIFEST);
    let text = serde_json::to_string_pretty(manifest)
        .map_err(|e| MovieError::file(&path, e.to_string()))?;
    write_text(&path, &text)?;
    write_text(&dir.join(TABLE), &format!("{HEADER}\n"))
}

fn read_manifest(path: &Path) -> Result<Manifest> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| MovieError::file(path, format!("cannot read the movie's manifest: {e}")))?;
    let m: Manifest = serde_json::from_str(&text)
        .map_err(|e| MovieError::file(path, format!("not a movie's manifest: {e}")))?;
    if m.format != FORMAT || m.version != VERSION {
        return Err(MovieError::file(
            path,
            format!(
                "a manifest of format {} version {}: expected {FORMAT} version {VERSION}",
                m.format, m.version
            ),
        ));
    }
    Ok(m)
}

/// What differs between two manifests, in words.
fn describe_difference(found: &Manifest, wanted: &Manifest) -> String {
    let mut parts = Vec::new();
    if found.identity != wanted.identity {
        parts.push("another scene or method".to_string());
    }
    if found.spec != wanted.spec {
        let show = |s: &MovieSpec| serde_json::to_string(s).unwrap_or_default();
        parts.push(format!(
            "its settings are {}, these are {}",
            show(&found.spec),
            show(&wanted.spec)
        ));
    }
    parts.join("; ")
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    render_base::write_atomically(path, |f| {
        std::io::Write::write_all(f, text.as_bytes()).map_err(|e| e.to_string())
    })
    .map_err(|e| MovieError::file(path, e.message))
}

/// Joins the parts of a movie (folders of [`MovieFolder::open_part`], together covering every
/// frame once, each complete) into the new or empty folder `dir`, as one process would have
/// made it: the frames (and references) are moved into it in order and the table written
/// whole. The parts' folders are removed once empty; anything else in them stays.
pub fn merge_parts(
    dir: &Path,
    identity: &str,
    spec: &MovieSpec,
    parts: &[PathBuf],
) -> Result<MovieFolder> {
    let mut opened = Vec::new();
    for p in parts {
        let manifest = read_manifest(&p.join(MANIFEST))?;
        let Some(part) = manifest.part else {
            return Err(MovieError::file(p, "a whole movie, not a part of one"));
        };
        if manifest.identity != identity || manifest.spec != *spec {
            return Err(MovieError::file(
                p,
                format!(
                    "a part of another movie ({})",
                    describe_difference(
                        &manifest,
                        &Manifest {
                            identity: identity.into(),
                            spec: spec.clone(),
                            ..manifest.clone()
                        }
                    )
                ),
            ));
        }
        let folder = MovieFolder::open_part(p, identity, spec, Some(part), true)?;
        if folder.next_frame() != part.last {
            return Err(MovieError::file(
                p,
                format!(
                    "holds frames {} to {} of its part's {} to {}: finish it (resume it) first",
                    part.first,
                    folder.next_frame(),
                    part.first,
                    part.last
                ),
            ));
        }
        opened.push(folder);
    }
    opened.sort_by_key(|f| f.first_frame());
    let mut next = 0;
    for f in &opened {
        if f.first_frame() != next {
            return Err(MovieError::Invalid(format!(
                "the parts leave frames {next} to {} out, or give them twice",
                f.first_frame()
            )));
        }
        next = f.next_frame();
    }
    if next != spec.frames {
        return Err(MovieError::Invalid(format!(
            "the parts end at frame {next} of {}",
            spec.frames
        )));
    }
    // The parts may be inside the folder (a shared one the workers wrote into): only a
    // movie already there is refused.
    if dir.join(MANIFEST).exists() {
        return Err(MovieError::file(
            dir,
            "holds a movie already: name another folder for the merged movie",
        ));
    }
    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        identity: identity.into(),
        spec: spec.clone(),
        part: None,
    };
    create(dir, &manifest)?;
    let mut whole = MovieFolder {
        dir: dir.to_path_buf(),
        denoised: spec.denoise.is_some(),
        part: None,
        records: Vec::new(),
    };
    for part in &opened {
        for r in part.done() {
            for file in part.frame_files(r.frame) {
                let name = file.file_name().expect("a frame file has a name");
                move_file(&file, &dir.join(name))?;
            }
            let reference = part
                .reference_dir()
                .join(format!("frame_{:06}.exr", r.frame));
            if reference.is_file() {
                let into = whole.reference_dir();
                std::fs::create_dir_all(&into)
                    .map_err(|e| MovieError::file(&into, format!("cannot create it: {e}")))?;
                move_file(
                    &reference,
                    &into.join(reference.file_name().expect("named")),
                )?;
            }
            whole.records.push(r.clone());
        }
    }
    whole.write_table()?;
    for part in &opened {
        for name in [MANIFEST, TABLE, SUMMARY] {
            let _ = std::fs::remove_file(part.dir.join(name));
        }
        let _ = std::fs::remove_dir(part.reference_dir());
        let _ = std::fs::remove_dir(&part.dir);
    }
    Ok(whole)
}

/// Moves `from` to `to` (a rename; a copy and removal across file systems).
fn move_file(from: &Path, to: &Path) -> Result<()> {
    if std::fs::rename(from, to).is_ok() {
        return Ok(());
    }
    std::fs::copy(from, to)
        .and_then(|_| std::fs::remove_file(from))
        .map(|_| ())
        .map_err(|e| MovieError::file(from, format!("cannot move it to {}: {e}", to.display())))
}
