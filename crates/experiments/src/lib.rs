//! experiments: the experiment runner. One file says what to compare, one command
//! (`gscache experiment`, or [`run_experiment`] from Rust) measures it and writes the tables,
//! plots and report. The image metrics are the `image-metrics` crate's.
//!
//! - [`error`]: the runner's one error type ([`Error`]); an interrupted run is its own variant.
//! - [`config`]: the experiment file (scene, methods, budgets, seeds, reference, fly-throughs,
//!   ablation sweeps), checked, with the sweeps expanded into methods.
//! - [`method`]: a method and the one cache it reads ([`method::MethodCache`]), with the
//!   warm-up settings of either cache in one generic table.
//! - [`reference`](mod@reference): high-spp references, made once and kept on disk by a hash of their inputs.
//! - [`records`]: what a measured run leaves (budgets, snapshots, a cache's record) and how its
//!   images travel in files; [`csv`]: the reports' CSV fields.
//! - [`measure`]: one method rendered progressively, snapshotted at every budget.
//! - [`denoised`]: a method's denoised twins (Intel Open Image Denoise), the filter's time
//!   counted in time budgets.
//! - [`command`]: the `gscache render` line that renders one frame of a method, bit for bit.
//! - [`flythrough`]: camera paths with scene edits; per-frame times and error.
//! - [`run`]: all of it, with the metrics and their spread over seeds.
//! - [`units`]: the same work split into units that shards measure and a merge assembles
//!   (volume-pt's `shard` splits one render's samples; this splits an experiment's units).
//! - [`figures`] and [`report`]: the plots, CSV, JSON and Markdown.
//! - [`camera_path`]: the camera paths of fly-throughs (an orbit, or key frames): render-session's.
//! - [`plot`]: charts and image grids (SVG, PNG) for reports.

#![forbid(unsafe_code)]

pub use render_session::camera_path;
pub mod command;
pub mod config;
pub mod csv;
pub mod denoised;
pub mod error;
pub mod figures;
pub mod flythrough;
pub mod measure;
pub mod method;
pub mod plot;
pub mod records;
pub mod reference;
pub mod report;
pub mod run;
pub mod units;

pub use config::{Experiment, load_experiment};
pub use error::{Error, Interrupted, Result};

/// Writes a text file for the user atomically ([`render_base::write_atomically`]): reports,
/// tables, charts and shard files alike.
pub fn write_text(path: &std::path::Path, text: &str) -> Result<()> {
    render_base::write_atomically(path, |file| {
        std::io::Write::write_all(file, text.as_bytes()).map_err(|e| e.to_string())
    })?;
    Ok(())
}
pub use run::Results;

use error::refuse;
use std::path::Path;

/// Runs the experiment in `path` (its output folder replaced by `output` when given) and
/// writes every result file; `progress` receives one line per step.
pub fn run_experiment(
    path: &Path,
    output: Option<&Path>,
    progress: &dyn Fn(&str),
) -> Result<Results> {
    let exp = load_with_output(path, output)?;
    let results = run::run(&exp, progress)?;
    write_outputs(&exp, &results, progress)?;
    Ok(results)
}

/// The folder of a run's finished units, one signed file each (`unit-NNNNN.json`), written as
/// each unit finishes: what `--resume` goes on from when the run was killed (the out-of-memory
/// killer, SLURM's hard kill) and no `interrupted-units.json` could be written. Removed when
/// the run completes.
pub const UNITS_FOLDER: &str = "finished-units";

/// [`run_experiment`] that stops between units when `control` is cancelled, keeping what it
/// measured in `OUTPUT/interrupted-units.json` (an [`Interrupted`] error says so), and that
/// takes the units of `resume` as measured: such a file, or a folder of finished units
/// ([`UNITS_FOLDER`], written as the run goes, so a killed run's work is on disk too). Resume
/// files of another version of the experiment are refused, and their units are checked as a
/// shard's are.
pub fn run_experiment_resumable(
    path: &Path,
    output: Option<&Path>,
    progress: &dyn Fn(&str),
    control: &render_session::Control,
    resume: Option<&Path>,
) -> Result<Results> {
    let exp = load_with_output(path, output)?;
    let (main, ablation) = run::all_budgets(&exp);
    let specs = units::all(&exp, &main, &ablation);
    let key = units::experiment_key(path, &exp, specs.len())?;
    let done = match resume {
        Some(from) => {
            let files = resume_files(from)?;
            let scene = run::experiment_scene(&exp)?;
            let pixels = scene.camera.width as usize * scene.camera.height as usize;
            // The checks of a shard merge, without requiring every unit.
            let units = units::checked_units(&files, &key, &specs, pixels)?;
            progress(&format!(
                "resuming: {} of {} units read from {}",
                units.len(),
                specs.len(),
                from.display()
            ));
            units
        }
        None => Default::default(),
    };
    let journal = exp.output.join(UNITS_FOLDER);
    std::fs::create_dir_all(&journal)
        .map_err(|e| Error::io(&journal, "cannot create the folder", e))?;
    let mut journal_error = None;
    let mut kept: Vec<(usize, units::UnitResult)> =
        done.iter().map(|(k, r)| (*k, r.clone())).collect();
    let outcome = run::run_resumable(&exp, progress, control, done, &mut |k, r| {
        kept.push((k, r.clone()));
        // On disk as soon as it is measured: a killed run loses only the unit under way.
        let unit = units::ShardFile {
            format: units::FORMAT,
            experiment: exp.name.clone(),
            key: key.clone(),
            shard: format!("unit {k}"),
            unit_count: specs.len(),
            units: vec![(k, r.clone())],
            checksum: String::new(),
        };
        if let Err(e) = unit.write(&journal.join(format!("unit-{k:05}.json"))) {
            journal_error.get_or_insert(e);
        }
    });
    if let Some(e) = journal_error {
        return Err(e.within("recording a finished unit for --resume"));
    }
    match outcome {
        Ok(results) => {
            write_outputs(&exp, &results, progress)?;
            // Every unit is in the results now: the journal is no longer needed.
            let _ = std::fs::remove_dir_all(&journal);
            Ok(results)
        }
        Err(Error::Cancelled) => {
            std::fs::create_dir_all(&exp.output)
                .map_err(|e| Error::io(&exp.output, "cannot create the output folder", e))?;
            let file = exp.output.join("interrupted-units.json");
            kept.sort_by_key(|(k, _)| *k);
            let done = kept.len();
            units::ShardFile {
                format: units::FORMAT,
                experiment: exp.name.clone(),
                key,
                shard: "interrupted".into(),
                unit_count: specs.len(),
                units: kept,
                checksum: String::new(),
            }
            .write(&file)?;
            Err(Interrupted {
                done,
                total: specs.len(),
                file,
                experiment: path.to_path_buf(),
            }
            .into())
        }
        Err(e) => Err(e),
    }
}

/// The unit files `--resume` names: one file (`interrupted-units.json`, a shard file), or a
/// folder's `*.json` files (a run's [`UNITS_FOLDER`], or its output folder, whose
/// `interrupted-units.json` and [`UNITS_FOLDER`] are both read).
fn resume_files(from: &Path) -> Result<Vec<(std::path::PathBuf, units::ShardFile)>> {
    let mut paths = Vec::new();
    if from.is_dir() {
        let interrupted = from.join("interrupted-units.json");
        if interrupted.is_file() {
            paths.push(interrupted);
        }
        let folder = if from.join(UNITS_FOLDER).is_dir() {
            from.join(UNITS_FOLDER)
        } else {
            from.to_path_buf()
        };
        let mut units: Vec<_> = std::fs::read_dir(&folder)
            .map_err(|e| Error::io(&folder, "cannot read the folder", e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("unit-") && n.ends_with(".json"))
            })
            .collect();
        units.sort();
        paths.extend(units);
        if paths.is_empty() {
            refuse!(
                "{}: no finished units to resume from (expected interrupted-units.json or {UNITS_FOLDER}/unit-*.json)",
                from.display()
            );
        }
    } else {
        paths.push(from.to_path_buf());
    }
    let mut files = Vec::with_capacity(paths.len());
    for p in paths {
        let f = units::ShardFile::read(&p)?;
        files.push((p, f));
    }
    // A unit both in interrupted-units.json and in the folder is the same measurement: kept
    // once (the checks below refuse a unit given twice).
    let mut seen = std::collections::HashSet::new();
    for (_, f) in &mut files {
        f.units.retain(|(k, _)| seen.insert(*k));
    }
    Ok(files)
}

/// Measures shard `shard` of the experiment in `path` and writes its units to `shard_file`.
pub fn run_experiment_shard(
    path: &Path,
    shard: volume_pt::Shard,
    shard_file: &Path,
    progress: &dyn Fn(&str),
) -> Result<usize> {
    let exp = load_experiment(path)?;
    let scene = run::experiment_scene(&exp)?;
    let (main, ablation) = run::all_budgets(&exp);
    let units = units::all(&exp, &main, &ablation);
    let file = units::run_shard(path, &exp, &scene, &units, shard, progress)?;
    file.write(shard_file)?;
    progress(&format!(
        "shard {shard}: {} of {} units; wrote {}",
        file.units.len(),
        units.len(),
        shard_file.display()
    ));
    Ok(file.units.len())
}

/// Merges the shard files of the experiment in `path` and writes every result file, as
/// [`run_experiment`] would have.
pub fn merge_experiment(
    path: &Path,
    shard_files: &[std::path::PathBuf],
    output: Option<&Path>,
    progress: &dyn Fn(&str),
) -> Result<Results> {
    let exp = load_with_output(path, output)?;
    let (main, ablation) = run::all_budgets(&exp);
    let specs = units::all(&exp, &main, &ablation);
    let key = units::experiment_key(path, &exp, specs.len())?;
    let files = shard_files
        .iter()
        .map(|p| Ok((p.clone(), units::ShardFile::read(p)?)))
        .collect::<Result<Vec<_>>>()?;
    let scene = run::experiment_scene(&exp)?;
    let pixels = scene.camera.width as usize * scene.camera.height as usize;
    let measured = units::gather_units(&files, &key, &specs, pixels)?;
    let results = run::merge(&exp, measured, progress)?;
    write_outputs(&exp, &results, progress)?;
    Ok(results)
}

fn load_with_output(path: &Path, output: Option<&Path>) -> Result<Experiment> {
    let mut exp = load_experiment(path)?;
    if let Some(o) = output {
        exp.output = o.to_path_buf();
    }
    Ok(exp)
}

fn write_outputs(exp: &Experiment, results: &Results, progress: &dyn Fn(&str)) -> Result<()> {
    let scene = run::experiment_scene(exp)?;
    let figures = figures::write_all(&exp.output, results, &scene)?;
    report::write_reports(&exp.output, results, &figures)?;
    progress(&format!("wrote {}", exp.output.join("report.md").display()));
    Ok(())
}
