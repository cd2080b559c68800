//! `gscache experiment EXPERIMENT.toml`: renders every method of the file at every budget and seed
//! against a cached reference, flies its fly-throughs, sweeps its ablations, and writes
//! `runs.csv`, `summary.csv`, `results.json`, plots (PNG and SVG) and `report.md`. The file's
//! keys are documented in `docs/experiment-format.md`.

use crate::common::Global;
use anyhow::Result;
use std::path::PathBuf;
use volume_pt::Shard;

#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct ExperimentArgs {
    #[command(subcommand)]
    merge: Option<MergeCommand>,
    /// Experiment files, run one after the other.
    #[arg(required = true)]
    experiments: Vec<PathBuf>,
    /// Output folder (default: the file's `output`, else out/experiments/NAME); only with one
    /// experiment file.
    #[arg(long, conflicts_with = "results_dir")]
    output: Option<PathBuf>,
    /// Write each experiment into DIR/NAME (NAME: the file's `name`). The committed results
    /// are rewritten with `--results-dir docs/results`; without it nothing under docs/ is
    /// touched.
    #[arg(long, value_name = "DIR")]
    results_dir: Option<PathBuf>,
    /// Measure only shard I/N of the experiment's units (each method or ablation variant with
    /// each seed, and each fly-through; unit k when k mod N = I) into `--shard-output`; then
    /// `gscache experiment merge FILE SHARDS...` writes the report. A SLURM job array runs
    /// one shard per task.
    #[arg(long, requires = "shard_output", value_parser = parse_shard)]
    shard: Option<Shard>,
    /// Where a shard's measured units go (JSON, written atomically).
    #[arg(long, requires = "shard")]
    shard_output: Option<PathBuf>,
    /// Go on from an interrupted or killed run: the units measured before it stopped are taken
    /// as measured. Give the run's output folder (its `interrupted-units.json`, written when
    /// Ctrl-C stops it, and `finished-units/`, written unit by unit, so a run killed by
    /// SIGKILL or the out-of-memory killer keeps its work too), or one such file.
    #[arg(long, conflicts_with = "shard")]
    resume: Option<PathBuf>,
}

#[derive(clap::Subcommand, Debug)]
enum MergeCommand {
    /// Merge the shard files of one experiment and write its tables, plots and report.
    Merge {
        /// The experiment file the shards ran.
        experiment: PathBuf,
        /// Every shard's file (`--shard-output`), in any order.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// Output folder (default: the file's `output`).
        #[arg(long)]
        output: Option<PathBuf>,
    },
}

fn parse_shard(s: &str) -> std::result::Result<Shard, String> {
    Shard::parse(s).map_err(|e| e.to_string())
}

pub fn run(cli: ExperimentArgs, _global: &Global) -> Result<i32> {
    let start = std::time::Instant::now();
    let progress = |line: &str| eprintln!("[{:7.1} s] {line}", start.elapsed().as_secs_f64());
    if let Some(MergeCommand::Merge {
        experiment,
        shards,
        output,
    }) = &cli.merge
    {
        experiments::merge_experiment(experiment, shards, output.as_deref(), &progress)?;
        return Ok(0);
    }
    if (cli.output.is_some() || cli.shard.is_some()) && cli.experiments.len() > 1 {
        anyhow::bail!(
            "--output and --shard name one experiment: give one experiment file with them"
        );
    }
    if let (Some(shard), Some(out)) = (cli.shard, &cli.shard_output) {
        crate::common::prepare_output(out)?;
        experiments::run_experiment_shard(&cli.experiments[0], shard, out, &progress)?;
        return Ok(0);
    }
    if cli.resume.is_some() && cli.experiments.len() > 1 {
        anyhow::bail!("--resume names one experiment's units: give one experiment file with it");
    }
    // Ctrl-C (or SIGTERM, SIGHUP) stops between units and keeps what was measured.
    let cancel = crate::common::cancellation()?;
    let control = volume_pt::Control::cancellable(&cancel);
    for path in &cli.experiments {
        let output = match &cli.results_dir {
            Some(dir) => Some(dir.join(experiments::load_experiment(path)?.name)),
            None => cli.output.clone(),
        };
        let run = experiments::run_experiment_resumable(
            path,
            output.as_deref(),
            &progress,
            &control,
            cli.resume.as_deref(),
        );
        if let Err(experiments::Error::Interrupted(stopped)) = &run {
            eprintln!("{stopped}");
            return Ok(crate::common::INTERRUPTED);
        }
        run?;
    }
    Ok(0)
}
