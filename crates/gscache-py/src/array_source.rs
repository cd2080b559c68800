//! A volume streamed from a Python array: a zarr or dask array, an h5py dataset, an xarray or
//! anything else of shape (nz, ny, nx) that numpy can read a box of, rendered without a copy of
//! the whole. The streamed grid ([`volume_pt::bricks`]) asks for one brick at a time; each
//! request slices the array (`array[z0:z1, y0:y1, x0:x1]`) and converts the slice with
//! `numpy.ascontiguousarray`, so the array's own library reads only the chunks the brick covers
//! (a zarr array decodes them, a dask array computes them).
//!
//! **The interpreter lock.** A brick is read on whichever render thread first needs it, which
//! takes the GIL for the slice. Every call that may read bricks therefore runs with the GIL
//! released by its caller (the renders through `run::run_polled`; the grid's survey when the
//! volume is made, the scene builders and the volume's `range` through `detach`): a caller that
//! held it while waiting for the render threads would wait for ever. Bricks are read rarely (each is kept resident within
//! the budget), so the lock costs the renders little.

use numpy::PyArrayMethods;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use volume_pt::bricks::BrickSource;
use volume_pt::grid::Voxels;
use volume_pt::io::DType;

/// The brick edge for an array with no chunks of its own (a numpy memmap, an xarray of one):
/// 32 KiB of uint8 a brick, the chunk `gscache bench stream`'s stores were measured fastest
/// with (BENCHMARKS.md), and a small share of any budget.
const DEFAULT_BRICK: u32 = 32;

/// An array of shape (nz, ny, nx) read a box at a time (see the module docs).
#[derive(Debug)]
pub(crate) struct ArraySource {
    array: Py<PyAny>,
    /// The array's type, shape and dtype, for messages (see [`ArraySource::describe`]).
    name: String,
    pub(crate) dims: glam::UVec3,
    pub(crate) dtype: DType,
    brick: glam::UVec3,
    /// What names the voxels in any process, where the array's library says (see
    /// [`stable_name`]).
    stable_name: Option<String>,
}

/// What names an array's voxels in any process, where its library gives it cheaply: a zarr
/// array's store path (`file:///data/cells.zarr/0`; not an in-memory store's, which is the
/// process's own) or a dask array's name (a token of the graph that makes it, the same in every
/// process that builds it the same way). Dask workers that each open the same array then
/// render shards of the same render, which merge; other arrays are each their own.
fn stable_name(array: &Bound<'_, PyAny>) -> Option<String> {
    let module = array.get_type().module().ok()?.to_string();
    let text = |attr: &str| Some(array.getattr(attr).ok()?.str().ok()?.to_string());
    if module.starts_with("zarr.") {
        text("store_path").filter(|p| !p.starts_with("memory://"))
    } else if module.starts_with("dask.") {
        text("name")
    } else {
        None
    }
}

/// `word` after "a" or "an", as English reads it (`a list`, `an object`).
fn with_article(word: &str) -> String {
    let vowel = word.starts_with(['a', 'e', 'i', 'o', 'u', 'A', 'E', 'I', 'O', 'U']);
    format!("{} {word}", if vowel { "an" } else { "a" })
}

/// A dtype as numpy names it (`uint16`), as the readers' [`DType`].
fn dtype_of(array: &Bound<'_, PyAny>) -> PyResult<(DType, String)> {
    let name = array.getattr("dtype")?.str()?.to_string();
    let normalized = name.trim_start_matches(['<', '>', '=', '|']);
    let dtype = match normalized {
        "u1" => Some(DType::U8),
        "i1" => Some(DType::I8),
        "u2" => Some(DType::U16),
        "i2" => Some(DType::I16),
        "u4" => Some(DType::U32),
        "i4" => Some(DType::I32),
        "f4" => Some(DType::F32),
        "f8" => Some(DType::F64),
        other => DType::parse(other),
    };
    match dtype {
        Some(d) => Ok((d, name)),
        None => Err(PyTypeError::new_err(format!(
            "an array of {name}: expected uint8, int8, uint16, int16, uint32, int32, float32 or \
             float64"
        ))),
    }
}

/// One axis's chunk edge from the array's `chunks` entry for it: an int (zarr, h5py) or a
/// tuple of ints, the first the block size (dask). The streamed grid makes its bricks of whole
/// chunks within its own bounds (`volume_pt::bricks::brick_edge`).
fn chunk_edge(entry: &Bound<'_, PyAny>) -> Option<u32> {
    let n = entry
        .extract::<u64>()
        .ok()
        .or_else(|| entry.get_item(0).ok()?.extract::<u64>().ok())?;
    Some(u32::try_from(n).unwrap_or(u32::MAX).max(1))
}

impl ArraySource {
    /// The source for `array`, checked: three dimensions, each at least 1 and below 2^32, a
    /// supported dtype, and a `__getitem__`.
    pub(crate) fn new(array: &Bound<'_, PyAny>) -> PyResult<Self> {
        let kind = array.get_type().fully_qualified_name()?.to_string();
        let shape: Vec<u64> = array
            .getattr("shape")
            .and_then(|s| s.extract())
            .map_err(|_| {
                PyTypeError::new_err(format!(
                    "{}: expected a numpy array of shape (nz, ny, nx), or an array numpy \
                     can slice (zarr, dask, h5py); wrap a list in numpy.asarray(..., \
                     dtype=numpy.float32)",
                    with_article(&kind)
                ))
            })?;
        let [nz, ny, nx] = shape[..] else {
            return Err(PyTypeError::new_err(format!(
                "a {}-D {kind}: expected a 3-D array of shape (nz, ny, nx)",
                shape.len()
            )));
        };
        let dim = |n: u64| u32::try_from(n).ok().filter(|&n| n > 0);
        let (Some(x), Some(y), Some(z)) = (dim(nx), dim(ny), dim(nz)) else {
            return Err(crate::error(format!(
                "a {kind} of shape ({nz}, {ny}, {nx}): expected each axis 1 to 2^32 - 1 voxels"
            )));
        };
        if !array.hasattr("__getitem__")? {
            return Err(PyTypeError::new_err(format!(
                "a {kind} cannot be sliced: expected an array (numpy, zarr, dask, h5py)"
            )));
        }
        let (dtype, dtype_name) = dtype_of(array)?;
        let chunks = array.getattr("chunks").ok().filter(|c| !c.is_none());
        let edge = |axis: usize| {
            chunks
                .as_ref()
                .and_then(|c| c.get_item(axis).ok())
                .and_then(|e| chunk_edge(&e))
                .unwrap_or(DEFAULT_BRICK)
        };
        Ok(Self {
            array: array.clone().unbind(),
            name: format!(
                "{} of shape ({nz}, {ny}, {nx}) and dtype {dtype_name}",
                with_article(&kind)
            ),
            dims: glam::UVec3::new(x, y, z),
            dtype,
            brick: glam::UVec3::new(edge(2), edge(1), edge(0)),
            stable_name: stable_name(array),
        })
    }

    /// What the array is, for messages: `a zarr.core.array.Array of shape (512, 512, 512) and
    /// dtype uint16`.
    pub(crate) fn describe(&self) -> String {
        self.name.clone()
    }

    /// What identifies the voxels in a render's key (the volume's part of it): the array's
    /// [`stable_name`] where it has one, else this volume alone (the process, a counter and
    /// the time), so that no render of another array is ever taken for its.
    pub(crate) fn render_key(&self) -> volume_pt::RenderKey {
        static VOLUMES: AtomicU64 = AtomicU64::new(0);
        let key = volume_pt::RenderKey::new().part(self.name.as_bytes());
        match &self.stable_name {
            Some(stable) => key.part(stable.as_bytes()),
            None => {
                let nanos = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_nanos());
                key.part(&std::process::id().to_le_bytes())
                    .part(&VOLUMES.fetch_add(1, Ordering::Relaxed).to_le_bytes())
                    .part(&nanos.to_le_bytes())
            }
        }
    }

    /// Every voxel, read as one box (an array that fits the memory budget).
    pub(crate) fn read_whole(&self, py: Python<'_>) -> PyResult<Voxels> {
        self.read_box(py, glam::UVec3::ZERO, self.dims)
            .map_err(|e| crate::error(format!("{}: reading it whole failed: {e}", self.name)))
    }

    /// The bytes the voxels take in memory, as the readers keep them.
    pub(crate) fn bytes_in_memory(&self) -> u64 {
        self.dims.as_u64vec3().element_product() * self.dtype.bytes_in_memory() as u64
    }

    /// The box `lo .. lo + size` as numpy reads it: C-contiguous, in the type the voxels are
    /// kept in (wider integers and float64 as float32, as the file readers keep them).
    fn read_box(
        &self,
        py: Python<'_>,
        lo: glam::UVec3,
        size: glam::UVec3,
    ) -> Result<Voxels, String> {
        // A Python exception keeps its type in the message (`OSError: ...`).
        let raised = |e: PyErr| e.to_string();
        let hi = lo + size;
        let slice = |a: u32, b: u32| pyo3::types::PySlice::new(py, a as isize, b as isize, 1);
        let index = (slice(lo.z, hi.z), slice(lo.y, hi.y), slice(lo.x, hi.x));
        let part = self.array.bind(py).get_item(index).map_err(raised)?;
        let kept = self.dtype.kept_type_name();
        let dense = py
            .import("numpy")
            .and_then(|numpy| numpy.call_method1("ascontiguousarray", (part, kept)))
            .map_err(raised)?;
        let got: Vec<usize> = dense
            .getattr("shape")
            .and_then(|s| s.extract())
            .map_err(raised)?;
        let want = [size.z as usize, size.y as usize, size.x as usize];
        if got != want {
            return Err(format!(
                "its slice returned shape {got:?}, expected {want:?}"
            ));
        }
        fn copy<T: numpy::Element + Copy>(a: &Bound<'_, PyAny>) -> PyResult<Vec<T>> {
            let a = a.cast::<numpy::PyArrayDyn<T>>()?.readonly();
            Ok(a.as_slice()?.to_vec())
        }
        Ok(match self.dtype {
            DType::U8 => Voxels::U8(copy(&dense).map_err(raised)?),
            DType::I8 => Voxels::I8(copy(&dense).map_err(raised)?),
            DType::U16 => Voxels::U16(copy(&dense).map_err(raised)?),
            DType::I16 => Voxels::I16(copy(&dense).map_err(raised)?),
            DType::U32 | DType::I32 | DType::F32 | DType::F64 => {
                Voxels::F32(copy(&dense).map_err(raised)?)
            }
        })
    }
}

impl BrickSource for ArraySource {
    fn name(&self) -> String {
        self.describe()
    }

    fn brick_size(&self) -> glam::UVec3 {
        self.brick
    }

    fn type_name(&self) -> &'static str {
        self.dtype.kept_type_name()
    }

    fn read(&self, lo: glam::UVec3, size: glam::UVec3) -> volume_pt::Result<Voxels> {
        Python::attach(|py| self.read_box(py, lo, size)).map_err(|e| {
            volume_pt::Error::Invalid(format!(
                "{}: reading voxels {}..{}, {}..{}, {}..{} (x, y, z) failed: {e}",
                self.name,
                lo.x,
                lo.x + size.x,
                lo.y,
                lo.y + size.y,
                lo.z,
                lo.z + size.z
            ))
        })
    }

    /// An array's voxels may change under it, and nothing cheap says when: its survey is never
    /// kept.
    fn identity(&self) -> Option<String> {
        None
    }
}

/// Whether `array` is a numpy array (read whole, as before) rather than an array-like that is
/// sliced a box at a time.
pub(crate) fn is_numpy(array: &Bound<'_, PyAny>) -> bool {
    array.cast::<numpy::PyUntypedArray>().is_ok()
}
