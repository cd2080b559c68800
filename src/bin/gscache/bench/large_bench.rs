//! `gscache bench large`: the path tracer on a volume of the GSCache paper's size (a gigavoxel).
//!
//! The volume is a bundled one tiled to the requested size (default: neghip, 64^3 uint8, tiled
//! 16 times along each axis into 1024^3 = 1.07 G voxels, 1 GiB as stored), written once as a raw
//! file and reused. The scene keeps the default scene's world size and extinction per world unit
//! (the spacing follows the tiling, the density scale does not), so the box is as thick as the
//! default scene's while each copy of the protein is 1/16 as thick: a ray crosses many copies
//! and its lookups reach the whole gigabyte, not one cached corner of it.
//!
//! Reported: the memory estimate the loader checks before allocating, load time, peak resident
//! memory (the kernel's `VmHWM`), bytes per voxel as kept, and samples per second.

use anyhow::{Context, Result, bail};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volume_pt::{Film, load_scene, render};

#[derive(clap::Args, Debug)]
pub struct LargeArgs {
    #[command(flatten)]
    pub data: crate::bench::DataArg,
    /// Voxels along each axis of the generated volume (1024: 1.07 G voxels).
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(64..=4096))]
    voxels: u32,
    /// Where the generated raw volume and its scene are kept (about `voxels^3` bytes).
    #[arg(long, default_value = "out/large")]
    dir: PathBuf,
    /// Image width and height.
    #[arg(long, default_value_t = 320, value_parser = clap::value_parser!(u32).range(1..=4096))]
    size: u32,
    /// Samples per pixel.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=65536))]
    spp: u32,
}

/// The tile: the bundled neghip volume.
const TILE: &str = "volumes/neghip_64x64x64_uint8.raw";
pub(crate) const TILE_SIDE: u32 = 64;

/// Writes `voxels^3` uint8 voxels tiled from `tile` (side `TILE_SIDE`), one z-slice at a time,
/// atomically, so an interrupted write never leaves a short file under the final name.
fn write_tiled(tile: &[u8], voxels: u32, path: &Path) -> Result<()> {
    let n = voxels as usize;
    let s = TILE_SIDE as usize;
    let mut slice = vec![0u8; n * n];
    render_base::write_atomically(path, |out| {
        for z in 0..n {
            for y in 0..n {
                let src = &tile[s * ((y % s) + s * (z % s))..][..s];
                for (x, v) in slice[y * n..(y + 1) * n].iter_mut().enumerate() {
                    *v = src[x % s];
                }
            }
            out.write_all(&slice).map_err(|e| e.to_string())?;
        }
        Ok(())
    })?;
    Ok(())
}

/// The default scene (`scenes/default.toml` of the bundled data) around the tiled volume (a
/// raw file, or `bench stream`'s store), scaled so the box has the default scene's size and
/// extinction per world unit.
pub(crate) fn scene_file(
    bundled: &Path,
    volume: &Path,
    voxels: u32,
    size: u32,
    spp: u32,
) -> Result<volume_pt::scene::SceneFile> {
    let default_scene = bundled.join("scenes/default.toml");
    let text = std::fs::read_to_string(&default_scene)
        .with_context(|| format!("reading {}", default_scene.display()))?;
    let mut scene: volume_pt::scene::SceneFile =
        toml::from_str(&text).with_context(|| format!("{}", default_scene.display()))?;
    let spacing = 1.0 / (voxels as f32 / TILE_SIDE as f32);
    scene.volume = volume_pt::scene::VolumeDesc {
        spacing: Some([spacing; 3]),
        ..volume_pt::scene::VolumeDesc::file(volume)
    };
    (scene.camera.width, scene.camera.height) = (size, size);
    scene.render.spp = spp;
    // The figures in BENCHMARKS.md were measured with the light spheres seen by the camera.
    scene.render.show_lights = true;
    Ok(scene)
}

/// The tile's voxels (the bundled neghip), checked for their size.
pub(crate) fn read_tile(data: &crate::bench::DataDirs) -> Result<Vec<u8>> {
    let tile_path = data.bundled.join(TILE);
    let tile =
        std::fs::read(&tile_path).with_context(|| format!("reading {}", tile_path.display()))?;
    if tile.len() != (TILE_SIDE as usize).pow(3) {
        bail!(
            "{TILE}: {} bytes, expected {}",
            tile.len(),
            TILE_SIDE.pow(3)
        );
    }
    Ok(tile)
}

/// Peak resident memory of this process so far, from `/proc/self/status` (Linux), in bytes.
fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

pub fn run(args: &LargeArgs, data: &crate::bench::DataDirs) -> Result<()> {
    if !args.voxels.is_multiple_of(TILE_SIDE) {
        bail!(
            "--voxels {} is not a multiple of the tile's {TILE_SIDE} voxels",
            args.voxels
        );
    }
    let tile = read_tile(data)?;
    std::fs::create_dir_all(&args.dir)
        .with_context(|| format!("creating {}", args.dir.display()))?;
    let v = args.voxels;
    let raw = std::path::absolute(args.dir.join(format!("neghip_tiled_{v}x{v}x{v}_uint8.raw")))?;
    let expected = (v as u64).pow(3);
    if std::fs::metadata(&raw).map(|m| m.len()).ok() != Some(expected) {
        let t = Instant::now();
        write_tiled(&tile, v, &raw)?;
        eprintln!(
            "wrote {} ({:.2} GB) in {:.1} s",
            raw.display(),
            expected as f64 / 1e9,
            t.elapsed().as_secs_f64()
        );
    }
    let scene_path = args.dir.join(format!("large_{v}.toml"));
    let scene = scene_file(&data.bundled, &raw, v, args.size, args.spp)?;
    let comment = format!(
        "Made by `gscache bench large`: neghip tiled {0}x{0}x{0}.",
        v / TILE_SIDE
    );
    experiments::write_text(&scene_path, &scene.to_toml(&comment)?)?;

    let before = peak_resident_bytes();
    let t = Instant::now();
    let scene = load_scene(&scene_path)?;
    let load = t.elapsed().as_secs_f64();
    let after_load = peak_resident_bytes();
    let medium = &scene.media.medium;
    let mut film = Film::new(args.size, args.size);
    let stats = render(
        &scene.media,
        &scene.camera,
        &scene.settings,
        &mut film,
        &volume_pt::Control::none(),
    );
    let peak = peak_resident_bytes();
    let gb = |b: Option<u64>| b.map_or("n/a".to_string(), |b| format!("{:.2}", b as f64 / 1e9));
    println!(
        "threads: {}; peak resident memory before loading {} GB\n",
        rayon::current_num_threads(),
        gb(before)
    );
    println!(
        "| volume | voxels | bytes a voxel (kept) | medium GB | load s | peak GB after load | peak GB after render | image | spp | render s | M samples/s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    println!(
        "| neghip tiled {v}^3 (uint8) | {:.3} G | {} | {:.2} | {load:.2} | {} | {} | {}x{} | {} | {:.2} | {:.3} |",
        expected as f64 / 1e9,
        medium.grid().bytes_per_voxel(),
        medium.memory_bytes() as f64 / 1e9,
        gb(after_load),
        gb(peak),
        args.size,
        args.size,
        args.spp,
        stats.seconds,
        stats.samples_per_second() / 1e6
    );
    Ok(())
}
