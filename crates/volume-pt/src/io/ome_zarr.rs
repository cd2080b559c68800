//! OME-Zarr (NGFF 0.4 on Zarr v2, 0.5 on Zarr v3): the multiscale image of a store folder,
//! through `zarrs` (the arrays: chunks, sharding, blosc/gzip/zstd) and `ome_zarr_metadata`
//! (the `multiscales` attributes: axes, datasets, coordinate transformations).
//!
//! One 3D volume is read, whole where it fits the memory budget, else streamed a chunk at a
//! time within it (see [`crate::bricks`]): the level asked for (default 0, the finest), one channel and one
//! time point (default the first of each), the spatial axes as stored. The store's last axis
//! (x in OME's `z, y, x` order) is the grid's fastest, so no transpose is needed. The spacing is
//! the level's `scale` (times the multiscale's own, where it has one) along the spatial axes,
//! and the unit their `unit` where all three agree. A missing chunk reads as the array's fill
//! value (as Zarr says); a chunk that cannot be decoded is an error naming the store, the array
//! and the fault. The size is checked against the memory available before anything is read.

use super::budget::{check_volume_size, human_bytes, measure_volume};
use super::{DType, LoadedVolume, grid_for};
use crate::bricks::{BrickSource, Bricks, brick_edge};
use crate::error::{Error, Result};
use crate::grid::{ScalarGrid, Voxels};
use glam::{UVec3, Vec3};
use ome_zarr_metadata::AnyOmeFields;
use ome_zarr_metadata::v0_4::{
    Axis, AxisType, AxisUnit, CoordinateTransform, CoordinateTransformScale,
};
use std::path::Path;
use std::sync::Arc;
use zarrs::array::{Array, ArrayError, ArraySubset, CodecOptions, ElementOwned, data_type};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::Group;

/// Which part of a store to read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ZarrSelection {
    /// Resolution level (index into the multiscale's datasets); `None`: 0, the finest.
    pub level: Option<u32>,
    /// Channel index along a `channel` axis (ignored without one).
    pub channel: u32,
    /// Time-point index along a `time` axis (ignored without one).
    pub time: u32,
}

/// The parts of one multiscale image the reader needs, whichever version wrote it.
struct Multiscale {
    axes: Vec<Axis>,
    /// Per level: the dataset's path and its scale.
    levels: Vec<(String, Option<Vec<f32>>)>,
    /// The multiscale's own scale, applied after each level's.
    scale: Option<Vec<f32>>,
    version: String,
    translated: bool,
}

/// The scale among `transforms` (`Ok(None)` without one); a scale given by a file is refused.
fn scale_of(
    transforms: &[CoordinateTransform],
    bad: &dyn Fn(String) -> Error,
) -> Result<Option<Vec<f32>>> {
    let mut scale = None;
    for t in transforms {
        if let CoordinateTransform::Scale(s) = t {
            match s {
                CoordinateTransformScale::List { scale: v } => scale = Some(v.clone()),
                CoordinateTransformScale::Path { path } => {
                    return Err(bad(format!(
                        "a scale given by the file {}: expected the scale as a list of numbers",
                        path.display()
                    )));
                }
            }
        }
    }
    Ok(scale)
}

fn multiscale(fields: AnyOmeFields, bad: &dyn Fn(String) -> Error) -> Result<Multiscale> {
    let translated = |ts: &[CoordinateTransform]| {
        ts.iter()
            .any(|t| matches!(t, CoordinateTransform::Translation(_)))
    };
    let none = || {
        bad(
            "the group's OME metadata has no `multiscales` image: expected an OME-Zarr image \
             (a plate, a well or labels cannot be rendered as one volume)"
                .into(),
        )
    };
    let version = fields.version();
    macro_rules! take {
        ($image:expr) => {{
            let image = $image;
            let mut levels = Vec::with_capacity(image.datasets.len());
            let mut moved = false;
            for d in &image.datasets {
                levels.push((
                    d.path.clone(),
                    scale_of(&d.coordinate_transformations, bad)?,
                ));
                moved |= translated(&d.coordinate_transformations);
            }
            let own = image.coordinate_transformations.clone().unwrap_or_default();
            Multiscale {
                axes: image.axes.clone(),
                levels,
                scale: scale_of(&own, bad)?,
                version,
                translated: moved || translated(&own),
            }
        }};
    }
    Ok(match fields {
        AnyOmeFields::V0_4(f) => take!(
            f.multiscales
                .as_ref()
                .and_then(|m| m.first())
                .ok_or_else(none)?
        ),
        AnyOmeFields::V0_5(f) => take!(
            f.multiscales
                .as_ref()
                .and_then(|m| m.first())
                .ok_or_else(none)?
        ),
    })
}

/// The unit of the spatial axes where they all name the same one, abbreviated where common.
fn spatial_unit(axes: &[&Axis]) -> Option<String> {
    let names: Vec<String> = axes
        .iter()
        .map(|a| match &a.unit {
            Some(AxisUnit::Space(u)) => serde_json::to_value(u)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string)),
            Some(AxisUnit::Custom(u)) => Some(u.clone()),
            _ => None,
        })
        .collect::<Option<Vec<_>>>()?;
    let first = names.first()?;
    if names.iter().any(|n| n != first) {
        return None;
    }
    Some(
        match first.as_str() {
            "micrometer" => "µm",
            "millimeter" => "mm",
            "nanometer" => "nm",
            "centimeter" => "cm",
            "meter" => "m",
            "angstrom" => "Å",
            other => other,
        }
        .to_string(),
    )
}

/// The voxels of `subset` in the array's own type.
fn retrieve<T: ElementOwned>(
    array: &Array<FilesystemStore>,
    subset: &ArraySubset,
    fault: &dyn Fn(ArrayError) -> Error,
    options: &CodecOptions,
) -> Result<Vec<T>> {
    array
        .retrieve_array_subset_opt::<Vec<T>>(subset, options)
        .map_err(fault)
}

/// The voxels of `subset`, each made an f32 by `widen` (the grid keeps 32- and 64-bit types
/// as f32).
fn widened<T: ElementOwned>(
    array: &Array<FilesystemStore>,
    subset: &ArraySubset,
    fault: &dyn Fn(ArrayError) -> Error,
    options: &CodecOptions,
    widen: impl Fn(T) -> f32,
) -> Result<Vec<f32>> {
    Ok(retrieve::<T>(array, subset, fault, options)?
        .into_iter()
        .map(widen)
        .collect())
}

/// The voxels of `subset` of an array of `dtype`, as the grid keeps them.
fn read_subset(
    array: &Array<FilesystemStore>,
    subset: &ArraySubset,
    dtype: DType,
    fault: &dyn Fn(ArrayError) -> Error,
    options: &CodecOptions,
) -> Result<Voxels> {
    let (a, s, f, o) = (array, subset, fault, options);
    Ok(match dtype {
        DType::U8 => Voxels::U8(retrieve(a, s, f, o)?),
        DType::I8 => Voxels::I8(retrieve(a, s, f, o)?),
        DType::U16 => Voxels::U16(retrieve(a, s, f, o)?),
        DType::I16 => Voxels::I16(retrieve(a, s, f, o)?),
        DType::U32 => Voxels::F32(widened(a, s, f, o, |v: u32| v as f32)?),
        DType::I32 => Voxels::F32(widened(a, s, f, o, |v: i32| v as f32)?),
        DType::F32 => Voxels::F32(retrieve(a, s, f, o)?),
        DType::F64 => Voxels::F32(widened(a, s, f, o, |v: f64| v as f32)?),
    })
}

/// The shape of the array's chunks, or of the inner chunks of its shards (the unit a read
/// decodes).
fn chunk_shape(array: &Array<FilesystemStore>, bad: &dyn Fn(String) -> Error) -> Result<Vec<u32>> {
    use zarrs::array::ArrayShardedExt;
    let origin = vec![0u64; array.dimensionality()];
    let shape: Vec<u64> = match array.subchunk_shape() {
        Some(inner) => inner.iter().map(|n| n.get()).collect(),
        None => array
            .chunk_shape(&origin)
            .map_err(|e| bad(format!("the chunk grid: {e}")))?
            .iter()
            .map(|n| n.get())
            .collect(),
    };
    Ok(shape
        .into_iter()
        .map(|n| u32::try_from(n).unwrap_or(u32::MAX))
        .collect())
}

/// One array of a store, read a brick at a time (a [`BrickSource`]).
#[derive(Debug)]
struct ZarrBricks {
    store: std::path::PathBuf,
    dataset: String,
    array: Arc<Array<FilesystemStore>>,
    /// The array's files as listed when it was opened.
    listing: Option<Listing>,
    /// The array's subset for the whole volume (time and channel fixed); a brick narrows the
    /// spatial ranges.
    ranges: Vec<std::ops::Range<u64>>,
    /// The array axes of z, y and x.
    spatial: [usize; 3],
    dtype: DType,
    brick: UVec3,
    selection: ZarrSelection,
}

impl ZarrBricks {
    /// The array's subset for the grid's box `lo .. lo + size` (time and channel fixed).
    fn subset(&self, lo: UVec3, size: UVec3) -> ArraySubset {
        let mut ranges = self.ranges.clone();
        let [z, y, x] = self.spatial;
        let span = |l: u32, n: u32| u64::from(l)..u64::from(l) + u64::from(n);
        ranges[z] = span(lo.z, size.z);
        ranges[y] = span(lo.y, size.y);
        ranges[x] = span(lo.x, size.x);
        ArraySubset::new_with_ranges(&ranges)
    }
}

impl BrickSource for ZarrBricks {
    fn name(&self) -> String {
        format!("{}: array `{}`", self.store.display(), self.dataset)
    }

    fn brick_size(&self) -> UVec3 {
        self.brick
    }

    fn type_name(&self) -> &'static str {
        self.dtype.kept_type_name()
    }

    fn read(&self, lo: UVec3, size: UVec3) -> Result<Voxels> {
        let subset = self.subset(lo, size);
        let fault =
            |e: ArrayError| Error::format(&self.store, format!("array `{}`: {e}", self.dataset));
        // One brick is decoded on the calling thread: the render's threads are the
        // parallelism, and a nested pool would run other bricks' work inside this one.
        let options = CodecOptions::default().with_concurrent_target(1);
        read_subset(&self.array, &subset, self.dtype, &fault, &options)
    }

    fn is_absent(&self, lo: UVec3, size: UVec3) -> bool {
        let Some(listing) = &self.listing else {
            return false;
        };
        let Ok(Some(chunks)) = self.array.chunks_in_array_subset(&self.subset(lo, size)) else {
            return false;
        };
        chunks.indices().iter().all(|indices| {
            let key = self.array.chunk_key(&indices);
            !listing.keys.contains(&key_hash(key.as_str()))
        })
    }

    fn identity(&self) -> Option<String> {
        let listing = self.listing.as_ref()?;
        Some(format!(
            "ome-zarr {}|{}|{:?}|{} files, {} bytes, newest {}",
            listing.store.display(),
            self.dataset,
            self.selection,
            listing.keys.len(),
            listing.bytes,
            listing.newest
        ))
    }
}

/// The files of one array of a store, listed once when it is opened: which chunk keys exist
/// (a hash of each), and the sizes and times that identify its data.
#[derive(Debug)]
struct Listing {
    store: std::path::PathBuf,
    keys: std::collections::HashSet<u64>,
    bytes: u64,
    newest: u128,
}

fn key_hash(key: &str) -> u64 {
    render_base::hash::fnv1a64(key.as_bytes(), render_base::hash::FNV_OFFSET)
}

/// Files a store must hold for each this many of the bricks it is streamed in before it is
/// streamed: a store that claims far more than it holds (a few kilobytes claiming terabytes)
/// is refused, where surveying it would take time for nothing.
const MOST_BRICKS_PER_FILE: u64 = 4096;

/// Refuses a volume of `dims` in bricks of `brick` with more than [`MOST_BRICKS_PER_FILE`]
/// bricks for each file its array holds.
fn check_plausible(
    dims: UVec3,
    brick: UVec3,
    listing: &Listing,
    bad: &dyn Fn(String) -> Error,
) -> Result<()> {
    let n = (dims + brick - 1) / brick;
    let bricks = n.x as u64 * n.y as u64 * n.z as u64;
    let files = listing.keys.len() as u64;
    if bricks > MOST_BRICKS_PER_FILE * (files + 1) {
        return Err(bad(format!(
            "the array claims {}x{}x{} voxels ({bricks} bricks of {}x{}x{}) and holds {files} \
             files: expected a store that holds a file for at least one brick in \
             {MOST_BRICKS_PER_FILE} (refused rather than surveyed: a store this empty is more \
             likely damaged than sparse)",
            dims.x, dims.y, dims.z, brick.x, brick.y, brick.z
        )));
    }
    Ok(())
}

/// Lists the files under `dataset` of the store at `store` (`None` where a folder or a file's
/// metadata cannot be read: then nothing is taken as absent and no survey is kept).
fn list_array(store: &Path, dataset: &str) -> Option<Listing> {
    let store = std::fs::canonicalize(store).ok()?;
    let mut listing = Listing {
        store: store.clone(),
        keys: Default::default(),
        bytes: 0,
        newest: 0,
    };
    let mut stack = vec![store.join(dataset.trim_matches('/'))];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).ok()? {
            let entry = entry.ok()?;
            let meta = entry.metadata().ok()?;
            if meta.is_dir() {
                stack.push(entry.path());
                continue;
            }
            let path = entry.path();
            let relative = path.strip_prefix(&store).ok()?;
            let key: Vec<String> = relative
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            listing.keys.insert(key_hash(&key.join("/")));
            listing.bytes += meta.len();
            let t = meta
                .modified()
                .ok()?
                .duration_since(std::time::UNIX_EPOCH)
                .ok()?
                .as_nanos();
            listing.newest = listing.newest.max(t);
        }
    }
    Some(listing)
}

/// The store at `path` and its first multiscale image's metadata.
fn open_image(path: &Path) -> Result<(Arc<FilesystemStore>, Multiscale)> {
    let bad = |m: String| Error::format(path, m);
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_dir() {
        return Err(bad("an OME-Zarr store is a folder: this is a file".into()));
    }
    let store = Arc::new(
        FilesystemStore::new(path).map_err(|e| bad(format!("cannot open the store: {e}")))?,
    );
    let group = Group::open(store.clone(), "/").map_err(|e| {
        bad(format!(
            "not a Zarr group (no readable .zgroup or zarr.json): {e}"
        ))
    })?;
    let attributes = serde_json::Value::Object(group.attributes().clone());
    let fields: AnyOmeFields = serde_json::from_value(attributes)
        .map_err(|e| bad(format!("the group's OME-Zarr metadata: {e}")))?;
    let image = multiscale(fields, &bad)?;
    Ok((store, image))
}

/// The number of time points of the store at `path` (1 without a time axis).
pub fn time_points(path: &Path) -> Result<u32> {
    axis_length(path, AxisType::Time)
}

/// The number of channels of the store at `path` (1 without a channel axis).
pub fn channels(path: &Path) -> Result<u32> {
    axis_length(path, AxisType::Channel)
}

/// The length of the store's axis of type `kind` at level 0 (1 without one).
fn axis_length(path: &Path, kind: AxisType) -> Result<u32> {
    let bad = |m: String| Error::format(path, m);
    let (store, image) = open_image(path)?;
    let Some(axis) = image
        .axes
        .iter()
        .position(|a| a.r#type.as_ref() == Some(&kind))
    else {
        return Ok(1);
    };
    let Some((dataset, _)) = image.levels.first() else {
        return Ok(1);
    };
    let array = Array::open(store, &format!("/{}", dataset.trim_matches('/')))
        .map_err(|e| bad(format!("array `{dataset}` (level 0): {e}")))?;
    Ok(array
        .shape()
        .get(axis)
        .map_or(1, |&n| u32::try_from(n).unwrap_or(u32::MAX)))
}

/// Reads the volume `selection` names from the OME-Zarr store at `path` (a folder): whole
/// where reading it takes at most `budget` bytes, else streamed within `budget` (see
/// [`crate::bricks`]).
pub fn read(path: &Path, selection: &ZarrSelection, budget: u64) -> Result<LoadedVolume> {
    let bad = |m: String| Error::format(path, m);
    let (store, image) = open_image(path)?;
    let mut notes = vec![format!("OME-Zarr {}", image.version)];

    // Axes: time and channel (at most one of each, fixed by the selection), three spatial.
    let mut spatial = Vec::new();
    let mut fixed = Vec::new();
    for (i, axis) in image.axes.iter().enumerate() {
        match axis.r#type.as_ref() {
            Some(AxisType::Space) => spatial.push(i),
            Some(AxisType::Time) => fixed.push((i, selection.time, "time")),
            Some(AxisType::Channel) => fixed.push((i, selection.channel, "channel")),
            // An axis without a type (or a custom one) is spatial when named as one.
            _ if matches!(axis.name.as_str(), "x" | "y" | "z") => spatial.push(i),
            _ => fixed.push((i, 0, "other")),
        }
    }
    let names: Vec<&str> = image.axes.iter().map(|a| a.name.as_str()).collect();
    if let Some(twice) = names
        .iter()
        .enumerate()
        .find(|(i, n)| names[..*i].contains(n))
        .map(|(_, n)| n)
    {
        return Err(bad(format!(
            "axes {names:?} name `{twice}` twice: expected each axis named once"
        )));
    }
    if spatial.len() != 3 {
        return Err(bad(format!(
            "axes {names:?} have {} spatial axes: expected 3 (a 2D image is not a volume)",
            spatial.len()
        )));
    }
    if spatial.windows(2).any(|w| w[1] != w[0] + 1) || spatial[2] != image.axes.len() - 1 {
        return Err(bad(format!(
            "axes {names:?}: expected the three spatial axes last, as OME-Zarr orders them"
        )));
    }

    // The level.
    let level = selection.level.unwrap_or(0) as usize;
    let Some((dataset, level_scale)) = image.levels.get(level) else {
        return Err(bad(format!(
            "level {level}: the image has {} levels (0 to {})",
            image.levels.len(),
            image.levels.len().saturating_sub(1)
        )));
    };
    let array_path = format!("/{}", dataset.trim_matches('/'));
    let array = Array::open(store, &array_path)
        .map_err(|e| bad(format!("array `{dataset}` (level {level}): {e}")))?;
    let shape = array.shape().to_vec();
    if shape.len() != image.axes.len() {
        return Err(bad(format!(
            "array `{dataset}` has {} dimensions ({shape:?}) for {} axes {names:?}",
            shape.len(),
            image.axes.len()
        )));
    }
    let mut ranges: Vec<std::ops::Range<u64>> = Vec::with_capacity(shape.len());
    for (i, &n) in shape.iter().enumerate() {
        match fixed.iter().find(|f| f.0 == i) {
            Some(&(_, index, what)) => {
                if u64::from(index) >= n {
                    return Err(bad(format!(
                        "{what} {index}: axis `{}` of array `{dataset}` has {n} (0 to {})",
                        names[i],
                        n.saturating_sub(1)
                    )));
                }
                if n > 1 && what == "other" {
                    notes.push(format!("axis `{}`: the first of {n} is read", names[i]));
                }
                ranges.push(u64::from(index)..u64::from(index) + 1);
            }
            None => ranges.push(0..n),
        }
    }
    // Grid dims x, y, z: the last spatial axis is the fastest.
    let to_i64 = |n: u64| i64::try_from(n).unwrap_or(i64::MAX);
    let dims = [shape[spatial[2]], shape[spatial[1]], shape[spatial[0]]].map(to_i64);
    let data_type = array.data_type();
    let dtype = [
        (data_type::uint8(), DType::U8),
        (data_type::int8(), DType::I8),
        (data_type::uint16(), DType::U16),
        (data_type::int16(), DType::I16),
        (data_type::uint32(), DType::U32),
        (data_type::int32(), DType::I32),
        (data_type::float32(), DType::F32),
        (data_type::float64(), DType::F64),
    ]
    .into_iter()
    .find(|(t, _)| t == data_type)
    .map(|(_, d)| d)
    .ok_or_else(|| {
        bad(format!(
            "array `{dataset}` holds {data_type}: expected uint8, int8, uint16, int16, uint32, int32, float32 or float64"
        ))
    })?;
    let (size, needed) = measure_volume(path, dims, dtype)?;
    let streamed = needed > budget;
    notes.push(format!(
        "level {level} of {} (`{dataset}`), {}x{}x{} {dtype}, {}{}",
        image.levels.len(),
        size.dims.x,
        size.dims.y,
        size.dims.z,
        human_bytes(size.payload_bytes as u64),
        if streamed {
            format!(
                ", streamed within a memory budget of {}",
                human_bytes(budget)
            )
        } else {
            String::new()
        }
    ));

    let array = Arc::new(array);
    let grid = if streamed {
        let chunk = chunk_shape(&array, &bad)?;
        let listing = list_array(path, dataset);
        if let Some(listing) = &listing {
            let brick = UVec3::new(
                brick_edge(chunk[spatial[2]]),
                brick_edge(chunk[spatial[1]]),
                brick_edge(chunk[spatial[0]]),
            );
            check_plausible(size.dims, brick, listing, &bad)?;
        }
        let source = ZarrBricks {
            store: path.to_path_buf(),
            dataset: dataset.clone(),
            array: array.clone(),
            listing,
            ranges: ranges.clone(),
            spatial: [spatial[0], spatial[1], spatial[2]],
            dtype,
            brick: UVec3::new(chunk[spatial[2]], chunk[spatial[1]], chunk[spatial[0]]),
            selection: *selection,
        };
        let bricks = Bricks::new(size.dims, Arc::new(source), dtype.bytes_in_memory(), budget)?;
        ScalarGrid::streamed(bricks, 1.0, 0.0)?
    } else {
        check_volume_size(path, dims, dtype)?;
        let subset = ArraySubset::new_with_ranges(&ranges);
        let fault = |e: zarrs::array::ArrayError| bad(format!("array `{dataset}`: {e}"));
        grid_for(
            path,
            size.dims,
            read_subset(&array, &subset, dtype, &fault, &CodecOptions::default())?,
        )?
    };

    // Spacing along x, y, z: the level's scale times the multiscale's.
    let factor = |s: &Option<Vec<f32>>, axis: usize| -> Result<f32> {
        match s {
            None => Ok(1.0),
            Some(v) if v.len() == image.axes.len() => Ok(v[axis]),
            Some(v) => Err(bad(format!(
                "a scale of {} values for {} axes {names:?}",
                v.len(),
                image.axes.len()
            ))),
        }
    };
    let mut spacing = [0.0f32; 3];
    for (k, &axis) in [spatial[2], spatial[1], spatial[0]].iter().enumerate() {
        spacing[k] = factor(level_scale, axis)? * factor(&image.scale, axis)?;
    }
    let spacing = Vec3::from_array(spacing);
    // Written so that NaN fails.
    if !(spacing.min_element() > 0.0 && spacing.is_finite()) {
        return Err(bad(format!(
            "level {level}'s spacing {spacing}: expected finite sizes > 0"
        )));
    }
    if image.translated {
        notes.push("OME-Zarr translation is not applied: the scene places the volume".into());
    }
    let units = spatial_unit(&spatial.iter().map(|&i| &image.axes[i]).collect::<Vec<_>>());
    Ok(LoadedVolume {
        grid,
        spacing: Some(spacing),
        units,
        notes,
    })
}
