//! What every subcommand shares: the thread pool, cancellation, progress and output files.

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Options every subcommand takes.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct Global {
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, global = true, value_parser = clap::value_parser!(u16).range(1..=render_base::MAX_THREADS as i64))]
    pub threads: Option<u16>,
    /// No progress bar.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Memory the volume's voxels may take (`4G`, `512M`...); an OME-Zarr store larger is
    /// streamed from disk within it. Default: `GSCACHE_MEMORY_BUDGET`, else half the memory
    /// this process may use.
    #[arg(long, global = true, value_name = "SIZE", value_parser = volume_pt::io::parse_bytes)]
    pub memory_budget: Option<u64>,
}

impl Global {
    /// Starts the global thread pool with `--threads` workers, if given, and sets the
    /// process's memory budget.
    pub fn start_threads(&self) -> Result<()> {
        volume_pt::io::set_memory_budget(self.memory_budget);
        if let Some(t) = self.threads {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t.into())
                .build_global()
                .context("cannot start the thread pool")?;
        }
        Ok(())
    }

    /// A progress bar over `total` units named `unit`, hidden with `--quiet`.
    pub fn progress(&self, total: u64, unit: &str) -> ProgressBar {
        let bar = if self.quiet {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(total)
        };
        // The rate in thousands or millions a second ("1.35 M/s"): indicatif's own prints
        // "13,501.0297/s".
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{{bar:40}} {{percent:>3}}% {{human_pos}}/{{human_len}} {unit}, {{rate}}, eta {{eta}}"
            ))
            .expect("valid template")
            .with_key(
                "rate",
                |state: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                    let r = state.per_sec();
                    let _ = if r >= 1e6 {
                        write!(w, "{:.2} M/s", r / 1e6)
                    } else if r >= 1e3 {
                        write!(w, "{:.1} k/s", r / 1e3)
                    } else {
                        write!(w, "{r:.0}/s")
                    };
                },
            ),
        );
        bar
    }
}

/// The flag that stops long work: set by the first Ctrl-C, SIGTERM or SIGHUP, after which the
/// work finishes what is under way and writes what it has; a second signal quits at once.
pub fn cancellation() -> Result<Arc<AtomicBool>> {
    let cancel = Arc::new(AtomicBool::new(false));
    let flag = cancel.clone();
    ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!(
            "\ninterrupted: finishing the work under way, then writing what is done (interrupt again to quit now)"
        );
    })
    .context("cannot install the interrupt handler")?;
    Ok(cancel)
}

/// The exit status of a run that was interrupted and kept its partial result.
pub const INTERRUPTED: i32 = 130;

/// Makes sure `path` can be written before any work starts: creates its folder and tries a
/// file there, so a bad `-o` is found now, not after an hour's render.
pub fn prepare_output(path: &Path) -> Result<()> {
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(d) => d,
        None => Path::new("."),
    };
    // Before any folder is made: a device, a FIFO or a system folder is refused as it is.
    if !path.is_dir() {
        render_base::check_output(path)?;
    }
    std::fs::create_dir_all(dir).with_context(|| {
        format!(
            "{}: cannot create the folder for {}",
            dir.display(),
            path.display()
        )
    })?;
    if path.is_dir() {
        bail!("{}: is a folder: expected a file name", path.display());
    }
    // A fixed probe name opened by name would truncate whatever a planted link points to: the
    // probe is the atomic writer's own temporary file, which is then discarded.
    render_base::check_writable(dir)
        .with_context(|| format!("{}: cannot write into {}", path.display(), dir.display()))
}

/// Makes sure folder `dir` exists and can be written, before any work starts.
pub fn prepare_folder(dir: &Path) -> Result<()> {
    prepare_output(&dir.join("probe"))
}

/// A command-line number that must be finite: NaN and infinities are refused where they are
/// typed, not found later as a black image.
pub fn finite_f32(s: &str) -> std::result::Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|e| format!("`{s}`: {e}"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("`{s}` is not finite: expected a finite number"))
    }
}

/// A finite number > 0.
pub fn positive_f32(s: &str) -> std::result::Result<f32, String> {
    let v = finite_f32(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("`{s}`: expected a number > 0"))
    }
}

/// A number in [0, 1].
pub fn unit_f32(s: &str) -> std::result::Result<f32, String> {
    let v = finite_f32(s)?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("`{s}`: expected a number in [0, 1]"))
    }
}

/// Three finite numbers `x,y,z`.
pub fn finite_vec3(s: &str) -> std::result::Result<glam::Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(finite_f32)
        .collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [x, y, z] => Ok(glam::Vec3::new(x, y, z)),
        _ => Err(format!("`{s}`: expected three numbers `x,y,z`")),
    }
}

/// The EXR and PNG a render writes: `-o` and `--png` when given, else `default` and its PNG.
/// `-o NAME.png` names the PNG (the EXR goes beside it as NAME.exr): it once wrote the PNG over
/// the EXR ("wrote out/x.png and out/x.png").
pub fn output_paths(
    output: Option<&std::path::Path>,
    png: Option<&std::path::Path>,
    default: &std::path::Path,
) -> (PathBuf, PathBuf) {
    let exr = output.unwrap_or(default).to_path_buf();
    let named_png = exr
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let (exr, implied_png) = if named_png {
        (exr.with_extension("exr"), exr)
    } else {
        (exr.clone(), exr.with_extension("png"))
    };
    (exr, png.map_or(implied_png, |p| p.to_path_buf()))
}
