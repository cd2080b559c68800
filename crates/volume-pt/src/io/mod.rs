//! Reading volumes: raw, NRRD, VTK (legacy `.vtk` and XML `.vti`), NIfTI (`.nii`, `.nii.gz`)
//! and OME-Zarr stores (`.zarr` folders).
//!
//! Every reader gives the same thing, a [`LoadedVolume`]: voxels in their own type (see
//! [`crate::grid::Voxels`]) in x-fastest order, the
//! spacing the file states (if any) and notes about what was read but not used. Bad input is an
//! [`Error`] naming the file, the fault and what was expected.

mod budget;
mod nifti_reader;
mod nrrd;
mod ome_zarr;
mod ome_zarr_write;
mod raw;
mod series;
mod vtk;

pub use budget::{
    MAX_TEXT_FILE_BYTES, VolumeSize, available_memory, check_volume_size, human_bytes,
    measure_volume, memory_budget, parse_bytes, read_regular, read_text_file, set_memory_budget,
};
pub use ome_zarr::ZarrSelection;
pub use ome_zarr_write::{
    NgffVersion, StoreOptions, WrittenStore, write_ome_zarr, write_store_by_chunks,
};
pub use raw::{RawLayout, parse_raw_file_name};
pub use series::{MAX_TIME_POINTS, is_series, series_files};

use crate::error::{Error, Result};
use crate::grid::{ScalarGrid, Voxels};
use glam::{UVec3, Vec3};
use std::path::Path;

/// Element type of voxels on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DType {
    #[serde(alias = "uint8", alias = "uchar")]
    U8,
    #[serde(alias = "int8")]
    I8,
    #[serde(alias = "uint16", alias = "ushort")]
    U16,
    #[serde(alias = "int16", alias = "short")]
    I16,
    #[serde(alias = "uint32")]
    U32,
    #[serde(alias = "int32")]
    I32,
    #[serde(alias = "float32", alias = "float")]
    F32,
    #[serde(alias = "float64", alias = "double")]
    F64,
}

impl DType {
    pub fn size(self) -> usize {
        match self {
            DType::U8 | DType::I8 => 1,
            DType::U16 | DType::I16 => 2,
            DType::U32 | DType::I32 | DType::F32 => 4,
            DType::F64 => 8,
        }
    }

    /// Bytes a voxel of this type takes in the grid (8- and 16-bit types are kept as they are,
    /// the rest as f32; see [`crate::grid::Voxels`]).
    pub fn bytes_in_memory(self) -> usize {
        match self {
            DType::U8 | DType::I8 => 1,
            DType::U16 | DType::I16 => 2,
            DType::U32 | DType::I32 | DType::F32 | DType::F64 => 4,
        }
    }

    /// The name of the type a voxel of this type is kept in (see [`Self::bytes_in_memory`]),
    /// as [`crate::grid::Voxels::type_name`] gives it.
    pub fn kept_type_name(self) -> &'static str {
        match self {
            DType::U8 => "uint8",
            DType::I8 => "int8",
            DType::U16 => "uint16",
            DType::I16 => "int16",
            DType::U32 | DType::I32 | DType::F32 | DType::F64 => "float32",
        }
    }

    /// Parses the names used by the Open SciVis file-name convention and by scene files.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s.to_ascii_lowercase().as_str() {
            "u8" | "uint8" | "uchar" => DType::U8,
            "i8" | "int8" => DType::I8,
            "u16" | "uint16" | "ushort" => DType::U16,
            "i16" | "int16" | "short" => DType::I16,
            "u32" | "uint32" => DType::U32,
            "i32" | "int32" => DType::I32,
            "f32" | "float32" | "float" => DType::F32,
            "f64" | "float64" | "double" => DType::F64,
            _ => return None,
        })
    }
}

impl std::fmt::Display for DType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = match self {
            DType::U8 => "uint8",
            DType::I8 => "int8",
            DType::U16 => "uint16",
            DType::I16 => "int16",
            DType::U32 => "uint32",
            DType::I32 => "int32",
            DType::F32 => "float32",
            DType::F64 => "float64",
        };
        f.write_str(s)
    }
}

/// Byte order of multi-byte voxels on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ByteOrder {
    #[default]
    Little,
    Big,
}

/// The file formats the readers understand.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    Raw,
    Nrrd,
    /// Legacy `.vtk` structured points or XML `.vti` image data.
    Vtk,
    Nifti,
    /// An OME-Zarr store (a folder): NGFF 0.4 (Zarr v2) or 0.5 (Zarr v3).
    #[serde(rename = "ome-zarr", alias = "zarr")]
    OmeZarr,
}

impl Format {
    /// The format a file name implies, if any.
    pub fn from_path(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_str()?.to_ascii_lowercase();
        if name.ends_with(".raw") || name.ends_with(".bin") {
            Some(Format::Raw)
        } else if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            Some(Format::Nrrd)
        } else if name.ends_with(".vtk") || name.ends_with(".vti") {
            Some(Format::Vtk)
        } else if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            Some(Format::Nifti)
        } else if name.ends_with(".zarr") {
            Some(Format::OmeZarr)
        } else {
            None
        }
    }
}

/// What a scene may say about a file whose header does not (raw), or to override the guess
/// from the extension.
#[derive(Debug, Clone, Default)]
pub struct ReadHints {
    pub format: Option<Format>,
    pub raw: RawLayout,
    /// The level, channel and time point of an OME-Zarr store.
    pub zarr: ZarrSelection,
    /// Bytes the voxels may take in memory; a store larger is streamed within it. `None`: the
    /// process's budget ([`memory_budget`]).
    pub memory_budget: Option<u64>,
}

/// A volume as read from disk.
#[derive(Debug, Clone)]
pub struct LoadedVolume {
    pub grid: ScalarGrid,
    /// Voxel spacing stated by the file, if it states one.
    pub spacing: Option<Vec3>,
    /// The unit of that spacing, where the file names one (`mm`, `um`, `m`...).
    pub units: Option<String>,
    /// Things the file said that the renderer does not use (an origin, a rotation, ...).
    pub notes: Vec<String>,
}

/// The number of time points of the volume at `path`: a series' files, an OME-Zarr store's time
/// axis, else 1.
pub fn time_points(path: &Path, hints: &ReadHints) -> Result<u32> {
    if series::is_series(path) {
        return Ok(series::series_files(path)?.len() as u32);
    }
    match hints.format.or_else(|| Format::from_path(path)) {
        Some(Format::OmeZarr) => ome_zarr::time_points(path),
        _ => Ok(1),
    }
}

/// The number of channels of the volume at `path`: an OME-Zarr store's channel axis, else 1.
pub fn channels(path: &Path, hints: &ReadHints) -> Result<u32> {
    match hints.format.or_else(|| Format::from_path(path)) {
        Some(Format::OmeZarr) if !series::is_series(path) => ome_zarr::channels(path),
        _ => Ok(1),
    }
}

/// Reads the volume at `path`, choosing the reader from `hints.format` or the file name. A
/// folder (not an OME-Zarr store) or a name with `*` is a time series: time point
/// `hints.zarr.time` is read (see [`series_files`]).
pub fn read_volume(path: &Path, hints: &ReadHints) -> Result<LoadedVolume> {
    if series::is_series(path) {
        let files = series::series_files(path)?;
        let t = hints.zarr.time as usize;
        let Some(file) = files.get(t) else {
            return Err(Error::format(
                path,
                format!(
                    "time {t}: the series has {} time points (0 to {})",
                    files.len(),
                    files.len() - 1
                ),
            ));
        };
        let mut one = hints.clone();
        one.zarr.time = 0;
        // One file of the series, read as a file (a name with `*` in it is not a pattern here).
        let mut loaded = read_file_volume(file, &one)?;
        loaded.notes.push(format!(
            "time point {t} of {}: {}",
            files.len(),
            file.file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default()
        ));
        return Ok(loaded);
    }
    read_file_volume(path, hints)
}

/// [`read_volume`] of one file or store (never a series).
fn read_file_volume(path: &Path, hints: &ReadHints) -> Result<LoadedVolume> {
    let format = match hints.format.or_else(|| Format::from_path(path)) {
        Some(f) => f,
        None => {
            return Err(Error::format(
                path,
                "unknown volume format: expected a .raw, .nrrd, .nhdr, .vtk, .vti, .nii or \
                 .nii.gz file, a .zarr store, or `format = ...` in the scene",
            ));
        }
    };
    // Refuse a missing file, a directory, a device or a FIFO before any reader opens it (an
    // OME-Zarr store is a folder of small files, each read by zarrs).
    if format != Format::OmeZarr {
        budget::open_regular(path)?;
    }
    match format {
        Format::Raw => raw::read(path, &hints.raw, budget(hints)?),
        Format::Nrrd => nrrd::read(path),
        Format::Vtk => vtk::read(path),
        Format::Nifti => nifti_reader::read(path),
        Format::OmeZarr => ome_zarr::read(path, &hints.zarr, budget(hints)?),
    }
}

/// The memory budget `hints` give, else the process's.
fn budget(hints: &ReadHints) -> Result<u64> {
    match hints.memory_budget {
        Some(b) => Ok(b),
        None => memory_budget(),
    }
}

/// Decodes packed voxels of `dtype` in `order`, keeping 8- and 16-bit types as they are (see
/// [`crate::grid`]); 32-bit integers and f64 become f32.
pub(crate) fn decode_voxels(bytes: &[u8], dtype: DType, order: ByteOrder) -> Voxels {
    macro_rules! decode {
        ($t:ty, $n:expr) => {
            bytes.chunks_exact($n).map(|c| {
                let a: [u8; $n] = c.try_into().expect("chunks_exact gives $n bytes");
                match order {
                    ByteOrder::Little => <$t>::from_le_bytes(a),
                    ByteOrder::Big => <$t>::from_be_bytes(a),
                }
            })
        };
    }
    let n = bytes.len() / dtype.size();
    match dtype {
        DType::U8 => Voxels::U8(collect_voxels(bytes.iter().copied(), n)),
        DType::I8 => Voxels::I8(collect_voxels(bytes.iter().map(|&b| b as i8), n)),
        DType::U16 => Voxels::U16(collect_voxels(decode!(u16, 2), n)),
        DType::I16 => Voxels::I16(collect_voxels(decode!(i16, 2), n)),
        DType::U32 => Voxels::F32(collect_voxels(decode!(u32, 4).map(|v| v as f32), n)),
        DType::I32 => Voxels::F32(collect_voxels(decode!(i32, 4).map(|v| v as f32), n)),
        DType::F32 => Voxels::F32(collect_voxels(decode!(f32, 4), n)),
        DType::F64 => Voxels::F32(collect_voxels(decode!(f64, 8).map(|v| v as f32), n)),
    }
}

/// The `n` voxels of `values` in a buffer reserved once and backed by huge pages where the
/// system offers them (the voxels are read at random while rendering; see
/// [`budget::advise_huge_pages`]).
fn collect_voxels<T>(values: impl Iterator<Item = T>, n: usize) -> Vec<T> {
    let mut out = Vec::with_capacity(n);
    budget::advise_huge_pages(&mut out);
    out.extend(values);
    out
}

/// [`decode_voxels`] of `bytes[skip..]`, reusing the buffer for bytes (no copy of a
/// gigavoxel uint8 volume: the peak is the file's size, not twice it).
pub(crate) fn decode_voxels_owned(
    mut bytes: Vec<u8>,
    skip: usize,
    dtype: DType,
    order: ByteOrder,
) -> Voxels {
    match dtype {
        DType::U8 => {
            bytes.drain(..skip.min(bytes.len()));
            Voxels::U8(bytes)
        }
        _ => decode_voxels(&bytes[skip.min(bytes.len())..], dtype, order),
    }
}

/// Builds the grid, turning a grid error into one that names the file.
pub(crate) fn grid_for(path: &Path, dims: UVec3, voxels: Voxels) -> Result<ScalarGrid> {
    scaled_grid_for(path, dims, voxels, 1.0, 0.0)
}

/// [`grid_for`] with an intensity scaling `scale * stored + offset`.
pub(crate) fn scaled_grid_for(
    path: &Path,
    dims: UVec3,
    voxels: Voxels,
    scale: f32,
    offset: f32,
) -> Result<ScalarGrid> {
    ScalarGrid::from_voxels(dims, voxels, scale, offset)
        .map_err(|e| Error::format(path, e.to_string()))
}

/// Reads a whole file whose header (or name) has not yet said how big it should be: bounded by
/// the memory available, refused if it is not a regular file.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>> {
    budget::read_regular(path, available_memory(), "a volume file")
}
