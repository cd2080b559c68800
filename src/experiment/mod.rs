//! The experiment runner: one file says what to compare, one command measures it and writes
//! the tables, plots and report.
//!
//! - [`config`]: the experiment file (scene, methods, budgets, seeds, reference, fly-throughs,
//!   ablation sweeps), checked, with the sweeps expanded into methods.
//! - [`reference`]: high-spp references, made once and kept on disk by a hash of their inputs.
//! - [`measure`]: one method rendered progressively, snapshotted at every budget.
//! - [`command`]: the `gscache render` line that renders one frame of a method, bit for bit.
//! - [`flythrough`]: camera paths with scene edits; per-frame times and error.
//! - [`run`]: all of it, with the metrics and their spread over seeds.
//! - [`shard`]: the same work split into units that shards measure and a merge assembles.
//! - [`figures`] and [`report`]: the plots, CSV, JSON and Markdown.

pub mod command;
pub mod config;
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
