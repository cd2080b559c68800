//! `gscache convert VOLUME OUT.ome.zarr`: any volume the program reads (raw, NRRD, NIfTI,
//! VTK/VTI, a level of an OME-Zarr store), written as an OME-Zarr 0.5 multiscale store that
//! napari, Neuroglancer and the OME tools read (volume-pt's `io::write_ome_zarr`). A raw file
//! or a store larger than `--memory-budget` is streamed: the store is written a chunk (or a
//! shard) at a time, each level from the one before it, in the memory of a few chunks.

use crate::common::Global;
use anyhow::{Context, Result};
use std::path::PathBuf;
use volume_pt::io::{ReadHints, StoreOptions, ZarrSelection, read_volume, write_ome_zarr};

/// Write a volume as an OME-Zarr store (0.5, Zarr v3, zstd, a level per halving).
#[derive(clap::Args, Debug)]
pub struct ConvertArgs {
    /// The volume: a raw file named `name_XxYxZ_type.raw`, NRRD, NIfTI, VTK/VTI, or an
    /// OME-Zarr store (its `--level`, `--channel`, `--time`).
    input: PathBuf,
    /// The store to write: a new folder (conventionally `NAME.ome.zarr`); an existing one is
    /// never replaced.
    output: PathBuf,
    /// Chunk side in voxels.
    #[arg(long, default_value_t = StoreOptions::default().chunk)]
    chunk: u32,
    /// The most resolution levels written (each halves every axis, until the volume fits a
    /// chunk).
    #[arg(long, default_value_t = StoreOptions::default().max_levels, value_parser = clap::value_parser!(u32).range(1..=16))]
    max_levels: u32,
    /// Shard side in voxels (a multiple of the chunk): chunks kept in one file a shard (Zarr
    /// v3 sharding), for stores of many chunks; 0: a file a chunk.
    #[arg(long, default_value_t = StoreOptions::default().shard)]
    shard: u32,
    /// OME-Zarr 0.5 (Zarr v3) or 0.4 (Zarr v2, for older readers; no sharding).
    #[arg(long, value_enum, default_value = "0.5")]
    ome_version: volume_pt::io::NgffVersion,
    /// An OME-Zarr input's level, channel and time point.
    #[arg(long)]
    level: Option<u32>,
    #[arg(long, default_value_t = 0)]
    channel: u32,
    #[arg(long, default_value_t = 0)]
    time: u32,
}

pub fn run(a: ConvertArgs, global: &Global) -> Result<i32> {
    let hints = ReadHints {
        memory_budget: None,
        zarr: ZarrSelection {
            level: a.level,
            channel: a.channel,
            time: a.time,
        },
        ..Default::default()
    };
    let volume = read_volume(&a.input, &hints)?;
    let options = StoreOptions {
        chunk: a.chunk,
        max_levels: a.max_levels,
        shard: a.shard,
        version: a.ome_version,
        ..Default::default()
    };
    let written = write_ome_zarr(&volume, &a.output, &options)
        .with_context(|| format!("converting {}", a.input.display()))?;
    if !global.quiet {
        let sizes: Vec<String> = written
            .levels
            .iter()
            .map(|d| format!("{}x{}x{}", d.x, d.y, d.z))
            .collect();
        println!(
            "wrote {}: OME-Zarr {}, {} levels ({}), chunks of {}^3, zstd",
            a.output.display(),
            match a.ome_version {
                volume_pt::io::NgffVersion::V0_4 => "0.4 (Zarr v2)",
                volume_pt::io::NgffVersion::V0_5 => "0.5 (Zarr v3)",
            },
            written.levels.len(),
            sizes.join(", "),
            a.chunk
        );
    }
    Ok(0)
}
