//! `gscache`: the one program. Subcommands:
//!
//! - `render`: path-trace a volume scene, optionally with the radiance cache, or one shard of it;
//! - `merge`: join a sharded render's partial films into its image;
//! - `convert`: write any volume the program reads as an OME-Zarr store;
//! - `movie`: frames along a camera path into a folder and a video (the movie crate);
//! - `view`: the render session in a browser (the viewer crate), for exploring a volume;
//! - `splat render | fit | trace`: Gaussian clouds with the rasteriser or the ray tracer;
//! - `experiment`: methods at budgets against a reference, fly-throughs, ablations, a report;
//! - `bench ...`: the renderers' speed, as Markdown tables.
//!
//! `--threads` and `--quiet` apply to all of them; long work stops cleanly on Ctrl-C, SIGTERM
//! or SIGHUP and keeps what it has done (see `common`).

#![forbid(unsafe_code)]

/// `println!` that never panics. The standard one panics when stdout is a closed pipe
/// (`gscache render ... | head -c 1`); this one drops the line and lets the work (an image being
/// written) finish. Defined before the modules, so it shadows the standard macro in all of them.
macro_rules! println {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

/// `eprintln!` that never panics on a closed stderr (see `println!` above).
macro_rules! eprintln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

mod bench;
mod cache_flags;
mod common;
mod convert;
mod denoising;
mod experiment;
mod merge;
mod movie;
mod render;
mod splat;
mod view;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "gscache",
    version,
    about = "Volume path tracing with a Gaussian radiance cache (GSCache, Bauer et al. 2025), on the CPU"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    #[command(flatten)]
    global: common::Global,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Path-trace a volume scene (TOML) to EXR and PNG, optionally reading the radiance cache.
    Render(Box<render::RenderArgs>),
    /// Merge the partial films of a sharded render (`render --shard`) into its image.
    Merge(merge::MergeArgs),
    /// Write a volume (raw, NRRD, NIfTI, VTK/VTI, OME-Zarr) as an OME-Zarr 0.5 store.
    Convert(convert::ConvertArgs),
    /// Render, fit or ray-trace 3D Gaussian clouds (3DGS PLY or .splat).
    #[command(subcommand)]
    Splat(splat::SplatCommand),
    /// Run experiment files: methods at budgets against a reference, with a report.
    Experiment(experiment::ExperimentArgs),
    /// Measure the renderers' speed (Markdown tables).
    Bench(bench::BenchArgs),
    /// Make a movie: a turntable or key-framed path, any method, numbered EXR and PNG frames
    /// and a video; resumable.
    Movie(Box<movie::MovieArgs>),
    /// Explore a scene in the browser: orbit, edit the transfer function and the lights, switch
    /// methods, with the image refining live (prints a URL with a token; Ctrl-C stops it).
    View(view::ViewArgs),
}

/// The command line, with `render`'s and `movie`'s many cache settings grouped under their own headings and
/// left out of the short help (`-h`: what a first render needs; `--help`: everything).
fn command() -> clap::Command {
    Cli::command()
        .mut_subcommand("render", group_cache_settings)
        .mut_subcommand("movie", group_cache_settings)
}

/// A subcommand's cache and denoiser flags under their own headings, the caches' settings
/// left out of the short help.
fn group_cache_settings(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|a| {
        let long = a.get_long().unwrap_or_default().to_string();
        let heading = if long.starts_with("cache-") {
            "Gaussian cache settings (--cache-KEY; the keys of an experiment's cache table)"
        } else if long.starts_with("nrc-") {
            "Neural cache settings (--nrc-KEY; the keys of an experiment's nrc table)"
        } else if long.starts_with("denoise") || long == "features" {
            "Feature buffers and denoising"
        } else {
            return a;
        };
        let a = a.help_heading(heading);
        if long.starts_with("cache-") || long.starts_with("nrc-") {
            a.hide_short_help(true)
        } else {
            a
        }
    })
    .after_help(
        "The Gaussian and neural caches' settings (--cache-KEY, --nrc-KEY) are listed by --help.",
    )
}

fn main() {
    let matches = command().get_matches();
    let mut cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // Which cache settings the user named, for the settings a denoised image changes.
    if let Some((_, sub)) = matches.subcommand() {
        match &mut cli.command {
            Command::Render(a) => a.note_named(sub),
            Command::Movie(a) => a.note_named(sub),
            _ => {}
        }
    }
    let result = cli.global.start_threads().and_then(|()| match cli.command {
        Command::Render(a) => render::run(*a, &cli.global),
        Command::Merge(a) => merge::run(a),
        Command::Convert(a) => convert::run(a, &cli.global),
        Command::Splat(c) => splat::run(c, &cli.global),
        Command::Experiment(a) => experiment::run(a, &cli.global),
        Command::Bench(a) => bench::run(a),
        Command::Movie(a) => movie::run(*a, &cli.global),
        Command::View(a) => view::run(a, &cli.global),
    });
    match result {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}
