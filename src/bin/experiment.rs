//! `experiment EXPERIMENT.toml`: renders every method of the file at every budget and seed
//! against a cached reference, flies its fly-throughs, sweeps its ablations, and writes
//! `runs.csv`, `summary.csv`, `results.json`, plots (PNG and SVG) and `report.md`. The file's
//! keys are documented in `docs/experiment-format.md`.

use anyhow::Result;
use clap::Parser;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    /// Experiment files, run one after the other.
    #[arg(required = true)]
    experiments: Vec<PathBuf>,
    /// Output folder (default: the file's `output`, else target/experiments/NAME); only with
    /// one experiment file.
    #[arg(long)]
    output: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if let Some(t) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()?;
    }
    if cli.output.is_some() && cli.experiments.len() > 1 {
        anyhow::bail!("--output names one folder: give one experiment file with it");
    }
    for path in &cli.experiments {
        let start = std::time::Instant::now();
        let progress = |line: &str| eprintln!("[{:7.1} s] {line}", start.elapsed().as_secs_f64());
        gscache_cli::experiment::run_experiment(path, cli.output.as_deref(), &progress)?;
    }
    Ok(())
}
