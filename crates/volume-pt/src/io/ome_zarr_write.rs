//! Making OME-Zarr stores (`gscache convert`): any volume the program reads, written as an
//! OME-Zarr 0.5 multiscale image on Zarr v3 through `zarrs`, so raw, NRRD, NIfTI and VTK data
//! can go where napari, Neuroglancer and the OME tools read.
//!
//! Level 0 is the volume as read (its own voxel type); each next level halves every axis (the
//! mean of each 2x2x2 block, partial at odd edges), until the largest axis fits one chunk.
//! Chunks are cubes (64 voxels a side by default), compressed with zstd. Axes `z`, `y`, `x`
//! (x fastest, as the grid keeps it), the spacing as each level's `scale` (doubled per level),
//! the unit where the volume names one NGFF knows. Optionally the chunks are kept in shards
//! (Zarr v3 sharding: a file a shard, each chunk decoded alone). The store must not exist
//! yet: nothing already on disk is replaced.
//!
//! Every level is written a chunk (or shard) at a time in parallel, level 0 from the volume
//! (in memory, or streamed from its file or store: `crate::bricks`), each further level from
//! the level just written, read back: a volume of any size converts in the memory of a few
//! chunks, to the same store the whole volume would give.

use super::LoadedVolume;
use crate::error::{Error, Result};
use crate::grid::Voxels;
use glam::UVec3;
use std::path::Path;
use std::sync::Arc;
use zarrs::array::codec::ZstdCodec;
use zarrs::array::{Array, ArrayBuilder, ArraySubset, DataType, Element, data_type};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::GroupBuilder;

/// The OME-Zarr (NGFF) version a store is written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum NgffVersion {
    /// OME-Zarr 0.4 on Zarr v2 (`.zgroup`, `.zattrs`, `.zarray`): what older readers take.
    #[cfg_attr(feature = "clap", value(name = "0.4"))]
    V0_4,
    /// OME-Zarr 0.5 on Zarr v3 (`zarr.json`), with sharding where asked.
    #[default]
    #[cfg_attr(feature = "clap", value(name = "0.5"))]
    V0_5,
}

/// How a store is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StoreOptions {
    /// Chunk side in voxels.
    pub chunk: u32,
    /// The most resolution levels (level 0 included).
    pub max_levels: u32,
    /// zstd's compression level.
    pub zstd_level: i32,
    /// Shard side in voxels (a multiple of `chunk`): chunks are stored in shard files of this
    /// size (Zarr v3 sharding: one file a shard, each chunk decoded alone); 0: a file a chunk.
    pub shard: u32,
    /// OME-Zarr 0.5 (Zarr v3, the default) or 0.4 (Zarr v2, no sharding).
    pub version: NgffVersion,
}

impl Default for StoreOptions {
    fn default() -> Self {
        Self {
            chunk: 64,
            max_levels: 8,
            zstd_level: 3,
            shard: 0,
            version: NgffVersion::V0_5,
        }
    }
}

impl StoreOptions {
    /// Checks the sizes, naming the store at `path` in the error.
    fn check(&self, path: &Path) -> Result<()> {
        let bad = |m: String| Error::format(path, m);
        if !(1..=4096).contains(&self.chunk) {
            return Err(bad(format!(
                "chunk {}: expected 1 to 4096 voxels a side",
                self.chunk
            )));
        }
        if self.shard != 0 && self.version == NgffVersion::V0_4 {
            return Err(bad(format!(
                "shard {}: sharding needs OME-Zarr 0.5 (Zarr v3); 0.4 stores a file a chunk",
                self.shard
            )));
        }
        if self.shard != 0 && (self.shard > 8192 || !self.shard.is_multiple_of(self.chunk)) {
            return Err(bad(format!(
                "shard {}: expected a multiple of the chunk ({}) up to 8192 voxels a side",
                self.shard, self.chunk
            )));
        }
        Ok(())
    }

    /// The array's chunk grid (the shards where sharded) and inner chunks, for a level of
    /// `dims`.
    fn grid(&self, dims: UVec3) -> (UVec3, Option<UVec3>) {
        let chunk = UVec3::splat(self.chunk.max(1)).min(dims);
        if self.shard == 0 {
            (chunk, None)
        } else {
            let shard = UVec3::splat(self.shard).min((dims + chunk - 1) / chunk * chunk);
            (shard, Some(chunk))
        }
    }

    /// Creates the array of a level of `dims` at `at` (`/s0`...) with these chunks (and
    /// shards) and zstd, its metadata stored: Zarr v3 for OME-Zarr 0.5, v2 for 0.4.
    fn create_array<T: Into<zarrs::array::builder::ArrayBuilderFillValue>>(
        &self,
        store: &Arc<FilesystemStore>,
        at: &str,
        dims: UVec3,
        data_type: DataType,
        fill: T,
    ) -> std::result::Result<Array<FilesystemStore>, String> {
        let array = match self.version {
            NgffVersion::V0_5 => self
                .builder(dims, data_type, fill)
                .build(store.clone(), at)
                .map_err(|e| e.to_string())?,
            NgffVersion::V0_4 => {
                let zyx = |v: UVec3| [u64::from(v.z), u64::from(v.y), u64::from(v.x)];
                let dtype = [
                    (data_type::uint8(), "|u1"),
                    (data_type::int8(), "|i1"),
                    (data_type::uint16(), "<u2"),
                    (data_type::int16(), "<i2"),
                    (data_type::float32(), "<f4"),
                ]
                .into_iter()
                .find(|(t, _)| *t == data_type)
                .map(|(_, v2)| v2)
                .ok_or_else(|| format!("no Zarr v2 type for {data_type}"))?;
                let (chunk, _) = self.grid(dims);
                let metadata = serde_json::json!({
                    "zarr_format": 2,
                    "shape": zyx(dims),
                    "chunks": zyx(chunk),
                    "dtype": dtype,
                    "compressor": {"id": "zstd", "level": self.zstd_level},
                    "fill_value": 0,
                    "order": "C",
                    "filters": null,
                    "dimension_separator": "/",
                });
                let metadata: zarrs::metadata::v2::ArrayMetadataV2 =
                    serde_json::from_value(metadata).map_err(|e| e.to_string())?;
                Array::new_with_metadata(
                    store.clone(),
                    at,
                    zarrs::metadata::ArrayMetadata::V2(metadata),
                )
                .map_err(|e| e.to_string())?
            }
        };
        array.store_metadata().map_err(|e| e.to_string())?;
        Ok(array)
    }

    /// A builder for a level of `dims` with these chunks (and shards) and zstd.
    fn builder<T: Into<zarrs::array::builder::ArrayBuilderFillValue>>(
        &self,
        dims: UVec3,
        data_type: DataType,
        fill: T,
    ) -> ArrayBuilder {
        let zyx = |v: UVec3| vec![u64::from(v.z), u64::from(v.y), u64::from(v.x)];
        let (outer, inner) = self.grid(dims);
        let mut builder = ArrayBuilder::new(zyx(dims), zyx(outer), data_type, fill);
        builder
            .bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(self.zstd_level, false))])
            .dimension_names(Some(["z", "y", "x"]));
        if let Some(inner) = inner {
            builder.subchunk_shape(zyx(inner));
        }
        builder
    }
}

/// What was written.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenStore {
    /// Per level, its size in voxels (x, y, z).
    pub levels: Vec<UVec3>,
}

/// NGFF's name for a unit the readers give (`None`: one NGFF does not list; left out).
fn ngff_unit(units: &str) -> Option<&'static str> {
    Some(match units {
        "µm" | "um" | "micrometer" | "micron" => "micrometer",
        "mm" | "millimeter" => "millimeter",
        "nm" | "nanometer" => "nanometer",
        "cm" | "centimeter" => "centimeter",
        "m" | "meter" => "meter",
        "Å" | "angstrom" => "angstrom",
        _ => return None,
    })
}

/// One level's voxels, half the size of `v` (dims `d`) on every axis: the mean of each 2x2x2
/// block (fewer at odd edges), rounded to the nearest for integer types.
fn halve<T: Copy>(
    v: &[T],
    d: UVec3,
    to: impl Fn(T) -> f64,
    from: impl Fn(f64) -> T,
) -> (Vec<T>, UVec3) {
    let h = (d + UVec3::ONE) / 2;
    let (dx, dy) = (d.x as usize, d.y as usize);
    let mut out = Vec::with_capacity(h.x as usize * h.y as usize * h.z as usize);
    for z in 0..h.z {
        for y in 0..h.y {
            for x in 0..h.x {
                let (mut sum, mut n) = (0.0f64, 0u32);
                for k in (2 * z)..(2 * z + 2).min(d.z) {
                    for j in (2 * y)..(2 * y + 2).min(d.y) {
                        for i in (2 * x)..(2 * x + 2).min(d.x) {
                            sum += to(v[(k as usize * dy + j as usize) * dx + i as usize]);
                            n += 1;
                        }
                    }
                }
                out.push(from(sum / n as f64));
            }
        }
    }
    (out, h)
}

/// Where the levels go: the store, its path (for messages) and the options.
struct Target<'a> {
    store: &'a Arc<FilesystemStore>,
    path: &'a Path,
    options: &'a StoreOptions,
}

/// Writes every level of a volume of dims `d` as arrays `s0`, `s1`, ... of `data_type`, a
/// chunk (or shard) at a time in parallel, so a volume of any size takes the memory of a few
/// chunks: level 0's boxes come from `level0` (the volume in memory, or streamed from its
/// store), each further level's from the level just written, read back. Returns the levels'
/// dims. `to` and `from` take a voxel to and from f64 for the block means.
fn write_levels<T>(
    target: &Target<'_>,
    level0: &(dyn Fn(UVec3, UVec3) -> Result<Vec<T>> + Sync),
    d: UVec3,
    (data_type, fill): (DataType, T),
    to: impl Fn(T) -> f64 + Copy + Sync,
    from: impl Fn(f64) -> T + Copy + Sync,
) -> Result<Vec<UVec3>>
where
    T: Element + zarrs::array::ElementOwned + Copy + Send + Sync,
    T: Into<zarrs::array::builder::ArrayBuilderFillValue>,
{
    use rayon::prelude::*;
    let Target {
        store,
        path,
        options,
    } = *target;
    let bad = |m: String| Error::format(path, m);
    let chunk = u64::from(options.chunk.max(1));
    let one_thread = zarrs::array::CodecOptions::default().with_concurrent_target(1);
    let zyx = |lo: UVec3, size: UVec3| {
        ArraySubset::new_with_ranges(&[
            u64::from(lo.z)..u64::from(lo.z + size.z),
            u64::from(lo.y)..u64::from(lo.y + size.y),
            u64::from(lo.x)..u64::from(lo.x + size.x),
        ])
    };
    let mut dims = vec![d];
    let mut previous: Option<Array<FilesystemStore>> = None;
    for k in 0..options.max_levels.max(1) {
        let d = dims[k as usize];
        let array = options
            .create_array(store, &format!("/s{k}"), d, data_type.clone(), fill)
            .map_err(|e| bad(format!("level {k}: {e}")))?;
        let (unit, _) = options.grid(d);
        let counts = (d + unit - 1) / unit;
        let n = counts.x as u64 * counts.y as u64 * counts.z as u64;
        let below = previous.as_ref().map(|p| (p, dims[k as usize - 1]));
        (0..n).into_par_iter().try_for_each(|i| -> Result<()> {
            let c = UVec3::new(
                (i % counts.x as u64) as u32,
                ((i / counts.x as u64) % counts.y as u64) as u32,
                (i / (counts.x as u64 * counts.y as u64)) as u32,
            );
            let lo = c * unit;
            let size = unit.min(d - lo);
            let values: Vec<T> = match below {
                None => level0(lo, size)?,
                Some((below, bd)) => {
                    // The 2x2x2 blocks under this box (fewer at the level's far edges).
                    let (lo2, size2) = (lo * 2, (size * 2).min(bd - lo * 2));
                    let src: Vec<T> = below
                        .retrieve_array_subset_opt(&zyx(lo2, size2), &one_thread)
                        .map_err(|e| bad(format!("level {}: {e}", k - 1)))?;
                    halve(&src, size2, to, from).0
                }
            };
            array
                .store_array_subset_opt(&zyx(lo, size), &values[..], &one_thread)
                .map_err(|e| bad(format!("level {k}'s chunk {c}: {e}")))
        })?;
        if d.max_element() as u64 <= chunk || k + 1 == options.max_levels.max(1) {
            break;
        }
        previous = Some(array);
        dims.push((d + UVec3::ONE) / 2);
    }
    Ok(dims)
}

/// A new store folder at `path` for `options` (checked first): refused where anything is
/// there already, so nothing on disk is replaced.
fn new_store(path: &Path, options: &StoreOptions) -> Result<Arc<FilesystemStore>> {
    if std::fs::symlink_metadata(path).is_ok() {
        return Err(Error::format(
            path,
            "already exists: choose a new name (nothing is replaced)",
        ));
    }
    options.check(path)?;
    std::fs::create_dir_all(path).map_err(|e| Error::io(path, e))?;
    Ok(Arc::new(FilesystemStore::new(path).map_err(|e| {
        Error::format(path, format!("cannot create the store: {e}"))
    })?))
}

/// Writes `volume` as an OME-Zarr store at `path` (a folder that must not exist yet).
pub fn write_ome_zarr(
    volume: &LoadedVolume,
    path: &Path,
    options: &StoreOptions,
) -> Result<WrittenStore> {
    let bad = |m: String| Error::format(path, m);
    let store = new_store(path, options)?;
    let d = volume.grid.dims();
    let target = Target {
        store: &store,
        path,
        options,
    };
    let round = |v: f64| v.round();
    let grid = &volume.grid;
    // Level 0's box at `lo` of `size`, in the stored type `pick` takes out of a box of voxels.
    fn boxes<T: Copy + Send + 'static>(
        grid: &crate::grid::ScalarGrid,
        pick: fn(Voxels) -> Option<Vec<T>>,
    ) -> impl Fn(UVec3, UVec3) -> Result<Vec<T>> + Sync + '_ {
        move |lo, size| {
            let voxels = match (grid.voxels(), grid.bricks()) {
                (Some(v), _) => v.copy_box(grid.dims(), lo, size),
                (None, Some(b)) => b.copy_box(lo, size)?,
                (None, None) => unreachable!("a grid is whole or streamed"),
            };
            pick(voxels).ok_or_else(|| Error::Invalid("a brick of another type".into()))
        }
    }
    // One arm a stored type: its variant, zarr type, fill and rounding of block means.
    macro_rules! levels {
        ($variant:ident, $zarr:expr, $fill:expr, $from:expr) => {
            write_levels(
                &target,
                &boxes(grid, |v| match v {
                    Voxels::$variant(v) => Some(v),
                    _ => None,
                }),
                d,
                ($zarr, $fill),
                f64::from,
                $from,
            )?
        };
    }
    let levels = match grid.type_name() {
        "uint8" => levels!(U8, data_type::uint8(), 0u8, |m| round(m) as u8),
        "int8" => levels!(I8, data_type::int8(), 0i8, |m| round(m) as i8),
        "uint16" => levels!(U16, data_type::uint16(), 0u16, |m| round(m) as u16),
        "int16" => levels!(I16, data_type::int16(), 0i16, |m| round(m) as i16),
        _ => levels!(F32, data_type::float32(), 0f32, |m| m as f32),
    };
    if let Some(b) = grid.bricks()
        && let Some(failure) = b.failure()
    {
        return Err(bad(format!("reading the volume: {failure}")));
    }
    write_group(
        &store,
        path,
        levels.len(),
        volume.spacing.unwrap_or(glam::Vec3::ONE),
        volume.units.as_deref(),
        "2x2x2 block means",
        options.version,
    )?;
    Ok(WrittenStore { levels })
}

/// Writes the group's OME-Zarr 0.5 metadata: `levels` datasets `s0`, `s1`... whose scales
/// double from `spacing`, the unit where NGFF names it.
fn write_group(
    store: &Arc<FilesystemStore>,
    path: &Path,
    levels: usize,
    spacing: glam::Vec3,
    units: Option<&str>,
    description: &str,
    version: NgffVersion,
) -> Result<()> {
    let bad = |m: String| Error::format(path, m);
    let unit = units.and_then(ngff_unit);
    let axis = |name: &str| match unit {
        Some(u) => serde_json::json!({"name": name, "type": "space", "unit": u}),
        None => serde_json::json!({"name": name, "type": "space"}),
    };
    let datasets: Vec<serde_json::Value> = (0..levels)
        .map(|k| {
            let f = (1u64 << k) as f32;
            serde_json::json!({
                "path": format!("s{k}"),
                "coordinateTransformations": [{
                    "type": "scale",
                    "scale": [spacing.z * f, spacing.y * f, spacing.x * f],
                }],
            })
        })
        .collect();
    let mut multiscale = serde_json::json!({
        "name": path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
        "axes": [axis("z"), axis("y"), axis("x")],
        "datasets": datasets,
        "type": "mean",
        "metadata": {"description": description, "method": "gscache"},
    });
    if version == NgffVersion::V0_4 {
        // Zarr v2: the group's `.zgroup`, and `.zattrs` with the 0.4 multiscale (its version
        // inside it).
        multiscale["version"] = "0.4".into();
        let write = |name: &str, value: serde_json::Value| {
            let file = path.join(name);
            std::fs::write(&file, value.to_string()).map_err(|e| Error::io(&file, e))
        };
        write(".zgroup", serde_json::json!({"zarr_format": 2}))?;
        return write(".zattrs", serde_json::json!({"multiscales": [multiscale]}));
    }
    let ome = serde_json::json!({
        "version": "0.5",
        "multiscales": [multiscale],
    });
    let mut attributes = serde_json::Map::new();
    attributes.insert("ome".into(), ome);
    GroupBuilder::new()
        .attributes(attributes)
        .build(store.clone(), "/")
        .and_then(|g| g.store_metadata().map_err(Into::into))
        .map_err(|e| bad(format!("the group's metadata: {e}")))?;
    Ok(())
}

/// Writes a one-level uint8 OME-Zarr 0.5 store of `dims` at `path` (which must not exist),
/// chunk (or shard) by chunk in parallel, each one's voxels (x fastest) made by
/// `voxels(lo, size)`:
/// a store of any size in the memory of a few chunks (the benchmark's procedural stores).
pub fn write_store_by_chunks(
    path: &Path,
    dims: UVec3,
    options: &StoreOptions,
    spacing: glam::Vec3,
    voxels: impl Fn(UVec3, UVec3) -> Vec<u8> + Sync,
) -> Result<()> {
    let store = new_store(path, options)?;
    // The writer's own chunk loop, for one level.
    let one_level = StoreOptions {
        max_levels: 1,
        ..*options
    };
    let target = Target {
        store: &store,
        path,
        options: &one_level,
    };
    write_levels(
        &target,
        &|lo, size| Ok(voxels(lo, size)),
        dims,
        (data_type::uint8(), 0u8),
        f64::from,
        |m| m.round() as u8,
    )?;
    write_group(
        &store,
        path,
        1,
        spacing,
        None,
        "procedural",
        options.version,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halving_takes_block_means_with_partial_edges() {
        // 3x2x1: blocks {0, 1, 3, 4} and {2, 5}.
        let v = [0u8, 1, 2, 3, 4, 5];
        let (h, d) = halve(&v, UVec3::new(3, 2, 1), f64::from, |m| m.round() as u8);
        assert_eq!(d, UVec3::new(2, 1, 1));
        assert_eq!(h, vec![2, 4]); // (0+1+3+4)/4 = 2, (2+5)/2 = 3.5 -> 4
    }
}
