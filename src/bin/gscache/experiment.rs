//! `gscache experiment EXPERIMENT.toml`: renders every method of the file at every budget and seed
//! against a cached reference, flies its fly-throughs, sweeps its ablations, and writes
//! `runs.csv`, `summary.csv`, `results.json`, plots (PNG and SVG) and `report.md`. The file's
//! keys are documented in `docs/experiment-format.md`.

use crate::common::Global;
use anyhow::Result;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ExperimentArgs {
    /// Experiment files, run one after the other.
    #[arg(required = true)]
    experiments: Vec<PathBuf>,
    /// Output folder (default: the file's `output`, else target/experiments/NAME); only with
    /// one experiment file.
    #[arg(long)]
    output: Option<PathBuf>,
}

pub fn run(cli: ExperimentArgs, _global: &Global) -> Result<i32> {
    if cli.output.is_some() && cli.experiments.len() > 1 {
        anyhow::bail!("--output names one folder: give one experiment file with it");
    }
    for path in &cli.experiments {
        let start = std::time::Instant::now();
        let progress = |line: &str| eprintln!("[{:7.1} s] {line}", start.elapsed().as_secs_f64());
        gscache_cli::experiment::run_experiment(path, cli.output.as_deref(), &progress)?;
    }
    Ok(0)
}
