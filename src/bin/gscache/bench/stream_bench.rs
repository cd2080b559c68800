//! `gscache bench stream`: the path tracer on an OME-Zarr store streamed within a memory
//! budget (see `volume_pt::bricks`).
//!
//! The store is made once by this tool (never by a test): the bundled neghip volume tiled to
//! `--voxels` per axis, uint8, in zstd chunks (default 32^3 in 256^3 shards; each tile
//! mirrored by a hash of its place, so chunks differ), written a shard at a time so a store of
//! any size takes the memory of a few shards. The scene is `bench large`'s: the default scene's size and extinction per world
//! unit around the tiled volume.
//!
//! Two tables:
//! - **Large** (a store larger than the budget): time to open it (the survey that bounds the
//!   majorants reads every chunk once; a later run finds it kept), time to the first image
//!   (1 spp), then samples per second over `--spp`, peak resident memory (`VmHWM`), bricks
//!   read and resident.
//! - **`--compare`** (a store that fits): samples per second read whole, streamed warm (every
//!   brick resident), streamed cold (the first image after opening with a kept survey: every
//!   brick read while rendering) and streamed under a budget of an eighth of the volume, in
//!   turns (whole, streamed, whole, streamed: the best of each), as ratios to read whole.

use anyhow::{Context, Result, bail};
use glam::UVec3;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volume_pt::{Film, Scene, load_scene, render};

#[derive(clap::Args, Debug)]
pub struct StreamArgs {
    #[command(flatten)]
    pub data: crate::bench::DataArg,
    /// Voxels along each axis of the generated store (a multiple of 64; 3264: 32.4 GiB).
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(64..=16384))]
    voxels: u32,
    /// Where the store and its scene are kept.
    #[arg(long, default_value = "out/stream")]
    dir: PathBuf,
    /// Image width and height.
    #[arg(long, default_value_t = 320, value_parser = clap::value_parser!(u32).range(1..=4096))]
    size: u32,
    /// Samples per pixel of the timed render.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=65536))]
    spp: u32,
    /// Memory budget of the large table (`4G`, `512M`...).
    #[arg(long, default_value = "4G", value_parser = volume_pt::io::parse_bytes)]
    budget: u64,
    /// Streamed against read whole, on a store that fits in memory.
    #[arg(long)]
    compare: bool,
    /// Chunk side of a new store (the unit a read decodes).
    #[arg(long, default_value_t = 32)]
    chunk: u32,
    /// Shard side of a new store (chunks kept in a file a shard); 0: a file a chunk.
    #[arg(long, default_value_t = 256)]
    shard: u32,
}

use crate::bench::large_bench::TILE_SIDE;

/// The voxels of the box at `lo` (size `size`), x fastest: the tile repeated, each copy
/// mirrored along each axis by a hash of its place.
fn tiled_box(tile: &[u8], lo: UVec3, size: UVec3) -> Vec<u8> {
    let s = TILE_SIDE as usize;
    let mut out = Vec::with_capacity((size.x * size.y * size.z) as usize);
    for z in lo.z..lo.z + size.z {
        for y in lo.y..lo.y + size.y {
            let mut x = lo.x;
            while x < lo.x + size.x {
                // One copy of the tile at a time along the row.
                let c = UVec3::new(x, y, z) / TILE_SIDE;
                let end = ((c.x + 1) * TILE_SIDE).min(lo.x + size.x);
                let h = render_base::hash::hash32(&[0x711e, c.x, c.y, c.z]);
                let flip = |v: u32, bit: u32| -> usize {
                    let v = (v % TILE_SIDE) as usize;
                    if h >> bit & 1 == 1 { s - 1 - v } else { v }
                };
                let row = s * (flip(y, 1) + s * flip(z, 2));
                out.extend((x..end).map(|x| tile[row + flip(x, 0)]));
                x = end;
            }
        }
    }
    out
}

fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn gib(b: u64) -> String {
    format!("{:.2}", b as f64 / (1u64 << 30) as f64)
}

/// Renders `spp` samples per pixel at `size`; (seconds, samples per second).
fn time_render(scene: &Scene, size: u32, spp: u32) -> Result<(f64, f64)> {
    let mut settings = scene.settings;
    settings.spp = spp;
    let mut film = Film::new(size, size);
    let stats = render(
        &scene.media,
        &scene.camera.with_size(size, size)?,
        &settings,
        &mut film,
        &volume_pt::Control::none(),
    );
    scene.media.medium.grid().check_streaming()?;
    let image = film.image();
    let mean = image
        .pixels()
        .iter()
        .map(|p| p.as_dvec3())
        .sum::<glam::DVec3>()
        / image.pixels().len() as f64;
    if !(mean.is_finite() && mean.max_element() > 0.0) {
        bail!("the image's mean is {mean}: expected a finite, lit image");
    }
    Ok((stats.seconds, stats.samples_per_second()))
}

pub fn run(args: &StreamArgs, data: &crate::bench::DataDirs) -> Result<()> {
    let v = args.voxels;
    if !v.is_multiple_of(TILE_SIDE) {
        bail!("--voxels {v} is not a multiple of the tile's {TILE_SIDE} voxels");
    }
    let tile = crate::bench::large_bench::read_tile(data)?;
    std::fs::create_dir_all(&args.dir)
        .with_context(|| format!("creating {}", args.dir.display()))?;
    let store = std::path::absolute(args.dir.join(format!(
        "neghip_tiled_{v}_c{}_s{}.ome.zarr",
        args.chunk, args.shard
    )))?;
    let voxel_bytes = (v as u64).pow(3);
    let spacing = 1.0 / (v as f32 / TILE_SIDE as f32);
    if !store.exists() {
        let t = Instant::now();
        let options = volume_pt::io::StoreOptions {
            chunk: args.chunk,
            max_levels: 1,
            zstd_level: 1,
            shard: args.shard,
            ..Default::default()
        };
        volume_pt::io::write_store_by_chunks(
            &store,
            UVec3::splat(v),
            &options,
            glam::Vec3::splat(spacing),
            |lo, size| tiled_box(&tile, lo, size),
        )?;
        eprintln!(
            "wrote {} ({} GiB of voxels) in {:.1} s",
            store.display(),
            gib(voxel_bytes),
            t.elapsed().as_secs_f64()
        );
    }
    let scene_path = write_scene(&data.bundled, &args.dir, &store, v, args.size, args.spp)?;
    println!(
        "threads: {}; store {} ({v}^3 uint8, {} GiB of voxels, {}^3 zstd chunks{})\n",
        rayon::current_num_threads(),
        store.display(),
        gib(voxel_bytes),
        args.chunk,
        if args.shard > 0 {
            format!(" in {}^3 shards", args.shard)
        } else {
            String::new()
        }
    );
    if args.compare {
        compare(&scene_path, voxel_bytes, args)
    } else {
        large(&scene_path, args)
    }
}

fn write_scene(
    bundled: &Path,
    dir: &Path,
    store: &Path,
    v: u32,
    size: u32,
    spp: u32,
) -> Result<PathBuf> {
    let scene = crate::bench::large_bench::scene_file(bundled, store, v, size, spp)?;
    let path = dir.join(format!("stream_{v}.toml"));
    let comment = format!(
        "Made by `gscache bench stream`: neghip tiled {0}x{0}x{0}, as an OME-Zarr store.",
        v / TILE_SIDE
    );
    experiments::write_text(&path, &scene.to_toml(&comment)?)?;
    Ok(path)
}

/// The large table: a store streamed within `--budget`.
fn large(scene_path: &Path, args: &StreamArgs) -> Result<()> {
    volume_pt::io::set_memory_budget(Some(args.budget));
    let t = Instant::now();
    let scene = load_scene(scene_path)?;
    let open = t.elapsed().as_secs_f64();
    let Some(bricks) = scene.media.medium.grid().bricks() else {
        bail!(
            "the store fits the budget of {} GiB and was read whole: use --compare, or a \
             larger --voxels",
            gib(args.budget)
        );
    };
    let surveyed = bricks.loads() > 0;
    let (first, _) = time_render(&scene, args.size, 1)?;
    let to_first = t.elapsed().as_secs_f64();
    let (seconds, sps) = time_render(&scene, args.size, args.spp)?;
    let peak = peak_resident_bytes().unwrap_or(0);
    println!(
        "| budget GiB | open s ({}) | first image s (1 spp) | time to first image s | render s ({} spp, {}^2) | M samples/s | peak RSS GiB | bricks read | bricks resident GiB |",
        if surveyed {
            "survey read every chunk"
        } else {
            "kept survey"
        },
        args.spp,
        args.size
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    println!(
        "| {} | {open:.1} | {first:.2} | {to_first:.1} | {seconds:.2} | {:.3} | {} | {} of {} | {} |",
        gib(args.budget),
        sps / 1e6,
        gib(peak),
        bricks.loads(),
        bricks.brick_count(),
        gib(bricks.resident_bytes())
    );
    Ok(())
}

/// The compare table: read whole against streamed, on a store that fits.
fn compare(scene_path: &Path, voxel_bytes: u64, args: &StreamArgs) -> Result<()> {
    let loads = |scene: &Scene| scene.media.medium.grid().bricks().map_or(0, |b| b.loads());
    let open = |budget: u64| -> Result<Scene> {
        volume_pt::io::set_memory_budget(Some(budget));
        Ok(load_scene(scene_path)?)
    };
    let whole = open(u64::MAX / 4)?;
    if whole.media.medium.grid().bricks().is_some() {
        bail!("the store was streamed with an unbounded budget");
    }
    // A budget under the whole read's (payload + kept) but above the voxels: streamed, and
    // every brick stays resident after the survey.
    let roomy = voxel_bytes + voxel_bytes / 2;
    // The first opening surveys the store (and keeps the bricks, as they fit); the second
    // finds the kept survey and starts with no brick resident: its first image is cold.
    let warm_scene = open(roomy)?;
    let cold_scene = open(roomy)?;
    if loads(&cold_scene) > 0 {
        bail!("the survey was not kept (is GSCACHE_CACHE_DIR=none?): no cold start to measure");
    }
    let cold = time_render(&cold_scene, args.size, args.spp)?;
    // Warm: every brick resident (the first render reads what the survey did not keep).
    time_render(&warm_scene, args.size, 1)?;
    // An eighth of the volume, or the least a streamed grid takes where that is more.
    let side = (voxel_bytes as f64).cbrt().round() as u32;
    let eighth = (voxel_bytes / 8).max(volume_pt::bricks::min_budget(
        UVec3::splat(side),
        UVec3::splat(args.chunk),
        1,
    ));
    let tight_scene = open(eighth)?;
    time_render(&tight_scene, args.size, 1)?;
    let (mut w, mut s, mut t) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..2 {
        w = w.max(time_render(&whole, args.size, args.spp)?.1);
        s = s.max(time_render(&warm_scene, args.size, args.spp)?.1);
        t = t.max(time_render(&tight_scene, args.size, args.spp)?.1);
    }
    println!(
        "| read | budget GiB | M samples/s ({} spp, {}^2) | against whole | bricks read |",
        args.spp, args.size
    );
    println!("|---|---|---|---|---|");
    println!("| whole | - | {:.3} | 1.00 | - |", w / 1e6);
    println!(
        "| streamed, warm | {} | {:.3} | {:.2} | {} |",
        gib(roomy),
        s / 1e6,
        s / w,
        loads(&warm_scene)
    );
    println!(
        "| streamed, cold (first image, kept survey) | {} | {:.3} | {:.2} | {} |",
        gib(roomy),
        cold.1 / 1e6,
        cold.1 / w,
        loads(&cold_scene)
    );
    println!(
        "| streamed, an eighth resident | {} | {:.3} | {:.2} | {} |",
        gib(eighth),
        t / 1e6,
        t / w,
        loads(&tight_scene)
    );
    Ok(())
}
