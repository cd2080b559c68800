//! The experiment runner: one file says what to compare, one command measures it and writes
//! the tables, plots and report.
//!
//! - [`config`]: the experiment file (scene, methods, budgets, seeds, reference, fly-throughs,
//!   ablation sweeps), checked, with the sweeps expanded into methods.
//! - [`reference`]: high-spp references, made once and kept on disk by a hash of their inputs.
//! - [`measure`]: one method rendered progressively, snapshotted at every budget.
//! - [`denoised`]: a method's denoised twins (Intel Open Image Denoise), the filter's time
//!   counted in time budgets.
//! - [`command`]: the `gscache render` line that renders one frame of a method, bit for bit.
//! - [`flythrough`]: camera paths with scene edits; per-frame times and error.
//! - [`run`]: all of it, with the metrics and their spread over seeds.
//! - [`shard`]: the same work split into units that shards measure and a merge assembles.
//! - [`figures`] and [`report`]: the plots, CSV, JSON and Markdown.

pub mod command;
pub mod config;
pub mod denoised;
pub mod figures;
pub mod flythrough;
pub mod measure;
pub mod reference;
pub mod report;
pub mod run;
pub mod shard;

pub use config::{Experiment, load_experiment};
pub use run::Results;

use anyhow::Result;
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

/// An experiment stopped between units (Ctrl-C): the units measured so far were written to
/// `file`, which `--resume` reads to go on from there.
#[derive(Debug, thiserror::Error)]
#[error(
    "interrupted after {done} of {total} units; the measured units are in {}: go on with \
     `gscache experiment {} --resume {}`",
    file.display(),
    experiment.display(),
    file.display()
)]
pub struct Interrupted {
    pub done: usize,
    pub total: usize,
    pub file: std::path::PathBuf,
    pub experiment: std::path::PathBuf,
}

/// [`run_experiment`] that stops between units when `control` is cancelled, keeping what it
/// measured in `OUTPUT/interrupted-units.json` (an [`Interrupted`] error says so), and that
/// takes the units of `resume` (such a file) as measured. A resume file of another version of
/// the experiment is refused, and its units are checked as a shard's are.
pub fn run_experiment_resumable(
    path: &Path,
    output: Option<&Path>,
    progress: &dyn Fn(&str),
    control: &render_session::Control,
    resume: Option<&Path>,
) -> Result<Results> {
    let exp = load_with_output(path, output)?;
    let (main, ablation) = run::all_budgets(&exp);
    let specs = shard::units(&exp, &main, &ablation);
    let key = shard::experiment_key(path, &exp, specs.len())?;
    let done = match resume {
        Some(file) => {
            let f = shard::ShardFile::read(file)?;
            let scene = run::experiment_scene(&exp)?;
            let pixels = scene.camera.width as usize * scene.camera.height as usize;
            // The checks of a shard merge, without requiring every unit.
            let units = shard::checked_units(&[(file.to_path_buf(), f)], &key, &specs, pixels)?;
            progress(&format!(
                "resuming: {} of {} units read from {}",
                units.len(),
                specs.len(),
                file.display()
            ));
            units
        }
        None => Default::default(),
    };
    let mut kept: Vec<(usize, shard::UnitResult)> =
        done.iter().map(|(k, r)| (*k, r.clone())).collect();
    let outcome = run::run_resumable(&exp, progress, control, done, &mut |k, r| {
        kept.push((k, r.clone()))
    });
    match outcome {
        Ok(results) => {
            write_outputs(&exp, &results, progress)?;
            Ok(results)
        }
        Err(e) if e.is::<run::Cancelled>() => {
            std::fs::create_dir_all(&exp.output)?;
            let file = exp.output.join("interrupted-units.json");
            kept.sort_by_key(|(k, _)| *k);
            let done = kept.len();
            shard::ShardFile {
                format: shard::FORMAT,
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
    let units = shard::units(&exp, &main, &ablation);
    let file = shard::run_shard(path, &exp, &scene, &units, shard, progress)?;
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
    let specs = shard::units(&exp, &main, &ablation);
    let key = shard::experiment_key(path, &exp, specs.len())?;
    let files = shard_files
        .iter()
        .map(|p| Ok((p.clone(), shard::ShardFile::read(p)?)))
        .collect::<Result<Vec<_>>>()?;
    let scene = run::experiment_scene(&exp)?;
    let pixels = scene.camera.width as usize * scene.camera.height as usize;
    let measured = shard::gather_units(&files, &key, &specs, pixels)?;
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
