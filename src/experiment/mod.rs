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
//! - [`figures`] and [`report`]: the plots, CSV, JSON and Markdown.

pub mod command;
pub mod config;
pub mod figures;
pub mod flythrough;
pub mod measure;
pub mod reference;
pub mod report;
pub mod run;

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
    let mut exp = load_experiment(path)?;
    if let Some(o) = output {
        exp.output = o.to_path_buf();
    }
    let results = run::run(&exp, progress)?;
    let mut scene = volume_pt::load_scene(&exp.scene)?;
    if let Some((w, h)) = exp.size {
        scene.camera = scene.camera.with_size(w, h)?;
    }
    let figures = figures::write_all(&exp.output, &results, &scene)?;
    report::write_reports(&exp.output, &results, &figures)?;
    progress(&format!("wrote {}", exp.output.join("report.md").display()));
    Ok(results)
}
