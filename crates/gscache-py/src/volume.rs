//! `Volume` and `Scene`: what a render reads. A volume comes from a numpy array (any of the
//! readers' in-memory types, kept as it is: a uint8 CT stays 1 byte a voxel) or from a file
//! through the program's readers; a scene is the scene format's tables around a volume, or a
//! scene file, so the package and the program build scenes through the same code.

use crate::array_source::{ArraySource, is_numpy};
use numpy::PyReadonlyArray3;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use std::path::PathBuf;
use volume_pt::grid::{ScalarGrid, Voxels};
use volume_pt::io::{LoadedVolume, RawLayout, ReadHints, read_volume};
use volume_pt::scene::{SceneFile, build_scene_with_volume, scene_file_key, settings_fingerprint};
use volume_pt::{RenderKey, RenderSettings};

/// A scalar volume: voxels in their own type, x fastest.
#[pyclass(frozen, module = "gscache._gscache")]
pub struct Volume {
    pub(crate) loaded: LoadedVolume,
    /// Names the volume in messages: the file, or `<numpy uint8 array>`.
    pub(crate) name: PathBuf,
    /// What identifies the voxels in a render's key: a hash of an array's bytes, or a file's
    /// path and size.
    pub(crate) identity: RenderKey,
}

/// Hashes voxels in chunks, so no second copy of a large volume is made.
fn hash_voxels<T: Copy, const N: usize>(
    mut key: RenderKey,
    values: &[T],
    bytes: impl Fn(T) -> [u8; N],
) -> RenderKey {
    let mut buf = Vec::with_capacity(4096 * N);
    for chunk in values.chunks(4096) {
        buf.clear();
        for &v in chunk {
            buf.extend_from_slice(&bytes(v));
        }
        key = key.part(&buf);
    }
    key
}

fn array_voxels(array: &Bound<'_, PyAny>) -> PyResult<(Voxels, [usize; 3], &'static str)> {
    // `iter()` walks a view in logical (C) order whatever its strides: (z, y, x), x fastest.
    // The size is checked as a volume file's is (the program's own check, against the memory
    // available) before the copy is allocated: a broadcast view of a few bytes can claim
    // petabytes, and copying it used to abort the interpreter.
    fn take<T: numpy::Element + Copy>(
        a: PyReadonlyArray3<'_, T>,
        dtype: volume_pt::io::DType,
    ) -> PyResult<(Vec<T>, [usize; 3])> {
        let v = a.as_array();
        let s = v.shape();
        let shape = [s[0], s[1], s[2]];
        let dims = [s[2], s[1], s[0]].map(|n| i64::try_from(n).unwrap_or(i64::MAX));
        volume_pt::io::check_volume_size(std::path::Path::new("<numpy array>"), dims, dtype)
            .map_err(crate::error)?;
        let mut out = Vec::new();
        out.try_reserve_exact(v.len()).map_err(|_| {
            pyo3::exceptions::PyMemoryError::new_err(format!(
                "a {}x{}x{} array: not enough memory for its copy",
                s[2], s[1], s[0]
            ))
        })?;
        out.extend(v.iter().copied());
        Ok((out, shape))
    }
    // A list (or anything else without numpy's attributes) once raised AttributeError.
    let Ok(ndim) = array.getattr("ndim").and_then(|n| n.extract::<usize>()) else {
        return Err(PyTypeError::new_err(format!(
            "a {}: expected a numpy array of shape (nz, ny, nx) (wrap it in numpy.asarray(..., \
             dtype=numpy.float32))",
            array.get_type().name()?
        )));
    };
    let dtype = array.getattr("dtype")?.str()?.to_string();
    if ndim != 3 {
        return Err(PyTypeError::new_err(format!(
            "a {ndim}-D array: expected a 3-D array of shape (nz, ny, nx)"
        )));
    }
    // Another byte order (nibabel reads big-endian NIfTI as `>i2`) is converted to the
    // machine's: the values are the same, and the dtype is supported. It was refused.
    let swapped;
    let array = if array
        .getattr("dtype")?
        .getattr("byteorder")?
        .extract::<String>()?
        == ">"
        && cfg!(target_endian = "little")
    {
        let native = array
            .getattr("dtype")?
            .call_method1("newbyteorder", ("=",))?;
        swapped = array.call_method1("astype", (native,))?;
        &swapped
    } else {
        array
    };
    if let Ok(a) = array.extract::<PyReadonlyArray3<'_, u8>>() {
        let (v, s) = take(a, volume_pt::io::DType::U8)?;
        return Ok((Voxels::U8(v), s, "uint8"));
    }
    if let Ok(a) = array.extract::<PyReadonlyArray3<'_, i8>>() {
        let (v, s) = take(a, volume_pt::io::DType::I8)?;
        return Ok((Voxels::I8(v), s, "int8"));
    }
    if let Ok(a) = array.extract::<PyReadonlyArray3<'_, u16>>() {
        let (v, s) = take(a, volume_pt::io::DType::U16)?;
        return Ok((Voxels::U16(v), s, "uint16"));
    }
    if let Ok(a) = array.extract::<PyReadonlyArray3<'_, i16>>() {
        let (v, s) = take(a, volume_pt::io::DType::I16)?;
        return Ok((Voxels::I16(v), s, "int16"));
    }
    if let Ok(a) = array.extract::<PyReadonlyArray3<'_, f32>>() {
        let (v, s) = take(a, volume_pt::io::DType::F32)?;
        return Ok((Voxels::F32(v), s, "float32"));
    }
    Err(PyTypeError::new_err(format!(
        "an array of {dtype}: expected uint8, int8, uint16, int16 or float32 (convert with \
         `array.astype(numpy.float32)`; wider integers and float64 are stored as float32 by the \
         file readers too)"
    )))
}

impl Volume {
    /// A volume from a numpy array of shape (nz, ny, nx), copied in its own type.
    fn from_numpy(array: &Bound<'_, PyAny>, spacing: Option<[f32; 3]>) -> PyResult<Self> {
        let (voxels, [nz, ny, nx], dtype) = array_voxels(array)?;
        let too_big = |n: usize| u32::try_from(n).is_err();
        if too_big(nx) || too_big(ny) || too_big(nz) {
            return Err(crate::error("array dimensions above 2^32 - 1 voxels"));
        }
        let dims = glam::UVec3::new(nx as u32, ny as u32, nz as u32);
        Self::from_voxels(dims, voxels, spacing, format!("numpy {dtype} array"))
    }

    /// A volume of `voxels` (x fastest) held in memory, named `<name>` in messages; its
    /// identity is a hash of the voxels.
    fn from_voxels(
        dims: glam::UVec3,
        voxels: Voxels,
        spacing: Option<[f32; 3]>,
        name: String,
    ) -> PyResult<Self> {
        let identity = RenderKey::new()
            .part(voxels.type_name().as_bytes())
            .part(format!("{dims:?}").as_bytes());
        let identity = match &voxels {
            Voxels::U8(v) => identity.part(v),
            Voxels::I8(v) => hash_voxels(identity, v, i8::to_le_bytes),
            Voxels::U16(v) => hash_voxels(identity, v, u16::to_le_bytes),
            Voxels::I16(v) => hash_voxels(identity, v, i16::to_le_bytes),
            Voxels::F32(v) => hash_voxels(identity, v, f32::to_le_bytes),
        };
        let grid = ScalarGrid::from_voxels(dims, voxels, 1.0, 0.0).map_err(crate::error)?;
        Ok(Self {
            loaded: LoadedVolume {
                grid,
                spacing: spacing.map(glam::Vec3::from_array),
                units: None,
                notes: Vec::new(),
            },
            name: PathBuf::from(format!("<{name}>")),
            identity,
        })
    }
}

#[pymethods]
impl Volume {
    /// A volume from an array of shape (nz, ny, nx); `spacing` is the world size of a voxel
    /// along (x, y, z). An array that fits `memory_budget` (bytes, or a size such as `"4G"`;
    /// default: the process's budget, as [`Volume::read`]'s) is read whole: a numpy array
    /// copied in its own type, any other array numpy can read a box of (a zarr or dask array,
    /// an h5py dataset) as one box. A larger one (a numpy memmap too) is streamed from it a
    /// brick at a time, never copied whole (see `array_source`).
    #[staticmethod]
    #[pyo3(signature = (array, spacing=None, memory_budget=None))]
    fn from_array(
        py: Python<'_>,
        array: &Bound<'_, PyAny>,
        spacing: Option<[f32; 3]>,
        memory_budget: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        if let Some(s) = spacing
            && !s.iter().all(|v| v.is_finite() && *v > 0.0)
        {
            return Err(crate::error(format!(
                "spacing {s:?}: expected three finite sizes > 0"
            )));
        }
        let budget = match memory_budget {
            Some(b) => budget_bytes(b)?,
            None => volume_pt::io::memory_budget().map_err(crate::error)?,
        };
        // A numpy array within the budget is copied as it always was; a larger one (a memmap of
        // a file larger than memory) is streamed like any other array.
        if is_numpy(array) && array.getattr("nbytes")?.extract::<u64>()? <= budget {
            return Self::from_numpy(array, spacing);
        }
        let source = ArraySource::new(array)?;
        if source.bytes_in_memory() <= budget {
            // Read whole as one box: the same slicing, conversion and checks as a brick's.
            let voxels = source.read_whole(py)?;
            return Self::from_voxels(source.dims, voxels, spacing, source.describe());
        }
        let (dims, dtype) = (source.dims, source.dtype);
        let (name, identity) = (source.describe(), source.render_key());
        // The streamed grid surveys its bricks (on render threads that take the GIL to slice
        // the array: see `array_source`), so the GIL is released meanwhile.
        let grid = py
            .detach(|| {
                let bricks = volume_pt::bricks::Bricks::new(
                    dims,
                    std::sync::Arc::new(source),
                    dtype.bytes_in_memory(),
                    budget,
                )?;
                ScalarGrid::streamed(bricks, 1.0, 0.0)
            })
            .map_err(crate::error)?;
        Ok(Self {
            loaded: LoadedVolume {
                grid,
                spacing: spacing.map(glam::Vec3::from_array),
                units: None,
                notes: vec![format!(
                    "{name}, streamed within a memory budget of {}",
                    volume_pt::io::human_bytes(budget)
                )],
            },
            name: PathBuf::from(format!("<{name}>")),
            identity,
        })
    }

    /// A volume read from a file (raw, NRRD, VTK, NIfTI) or an OME-Zarr store, as a scene's
    /// `[volume]` table reads it: `dims`, `dtype`, `byte_order` and `header_bytes` describe raw
    /// files; `level`, `channel` and `time` pick an OME-Zarr store's resolution level (0, the
    /// finest, by default), channel and time point. `memory_budget` (bytes, or a size such as
    /// `"4G"`) bounds the memory the voxels take: a store larger is streamed within it (default:
    /// half the memory this process may use, or `GSCACHE_MEMORY_BUDGET`).
    #[staticmethod]
    #[pyo3(signature = (path, *, dims=None, dtype=None, byte_order=None, header_bytes=0, level=None, channel=0, time=0, memory_budget=None))]
    #[allow(clippy::too_many_arguments)]
    fn read(
        path: PathBuf,
        dims: Option<[u32; 3]>,
        dtype: Option<&str>,
        byte_order: Option<&str>,
        header_bytes: u64,
        level: Option<u32>,
        channel: u32,
        time: u32,
        memory_budget: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let memory_budget = memory_budget.map(budget_bytes).transpose()?;
        fn named<T: serde::de::DeserializeOwned>(
            what: &str,
            v: Option<&str>,
        ) -> PyResult<Option<T>> {
            v.map(|s| {
                serde_json::from_value(serde_json::Value::String(s.into()))
                    .map_err(|e| crate::error(format!("{what} `{s}`: {e}")))
            })
            .transpose()
        }
        let raw = RawLayout {
            dims: dims.map(glam::UVec3::from_array),
            dtype: named("dtype", dtype)?,
            byte_order: named("byte_order", byte_order)?.unwrap_or_default(),
            header_bytes,
        };
        let zarr = volume_pt::io::ZarrSelection {
            level,
            channel,
            time,
        };
        let loaded = read_volume(
            &path,
            &ReadHints {
                memory_budget,
                format: None,
                raw,
                zarr,
            },
        )
        .map_err(crate::error)?;
        let size = std::fs::metadata(&path).map_err(crate::error)?.len();
        let selected = [level.unwrap_or(0), channel, time];
        let identity = RenderKey::new()
            .part(path.to_string_lossy().as_bytes())
            .part(&size.to_le_bytes())
            .part(format!("{selected:?}").as_bytes());
        Ok(Self {
            loaded,
            name: path,
            identity,
        })
    }

    /// (nz, ny, nx), as numpy indexes the array.
    #[getter]
    fn shape(&self) -> (u32, u32, u32) {
        let d = self.loaded.grid.dims();
        (d.z, d.y, d.x)
    }

    /// The type the voxels are kept in.
    #[getter]
    fn dtype(&self) -> &'static str {
        self.loaded.grid.type_name()
    }

    /// The smallest and largest value (after the file's intensity scaling).
    #[getter]
    fn range(&self, py: Python<'_>) -> (f32, f32) {
        // A streamed volume's range is its survey, which may read every brick (on render
        // threads that take the GIL to slice an array: see `array_source`).
        py.detach(|| self.loaded.grid.range())
    }

    /// The world size of a voxel along (x, y, z), when given or stated by the file.
    #[getter]
    fn spacing(&self) -> Option<[f32; 3]> {
        self.loaded.spacing.map(|s| s.to_array())
    }

    /// Whether the voxels are streamed from their store within a memory budget (not all in
    /// memory).
    #[getter]
    fn streamed(&self) -> bool {
        self.loaded.grid.bricks().is_some()
    }

    /// Bytes the voxels take in memory (a streamed volume's budget).
    #[getter]
    fn nbytes(&self) -> usize {
        self.loaded.grid.bytes()
    }

    /// The unit of the spacing, where the file names one (`mm`, `µm`...).
    #[getter]
    fn units(&self) -> Option<String> {
        self.loaded.units.clone()
    }

    /// A copy of the voxels as stored (before a file's intensity scaling), shape (nz, ny, nx)
    /// in their own type.
    fn to_numpy<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        use numpy::{PyArray1, PyArrayMethods};
        let (z, y, x) = self.shape();
        let shape = [z as usize, y as usize, x as usize];
        let Some(voxels) = self.loaded.grid.voxels() else {
            return Err(crate::error(format!(
                "{} is streamed (larger than the memory budget): to_numpy would copy all of it; \
                 read a coarser level (level=...) or raise memory_budget",
                self.name.display()
            )));
        };
        Ok(match voxels {
            Voxels::U8(v) => PyArray1::from_slice(py, v).reshape(shape)?.into_any(),
            Voxels::I8(v) => PyArray1::from_slice(py, v).reshape(shape)?.into_any(),
            Voxels::U16(v) => PyArray1::from_slice(py, v).reshape(shape)?.into_any(),
            Voxels::I16(v) => PyArray1::from_slice(py, v).reshape(shape)?.into_any(),
            Voxels::F32(v) => PyArray1::from_slice(py, v).reshape(shape)?.into_any(),
        })
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let (z, y, x) = self.shape();
        format!(
            "Volume({}, shape=({z}, {y}, {x}), dtype={}, range={:?})",
            self.name.display(),
            self.dtype(),
            self.range(py)
        )
    }
}

/// Where a scene came from: what its render key is built from besides the settings.
#[derive(Clone)]
pub(crate) enum Origin {
    /// A scene file: the key the program computes, so program and package shards merge.
    File(RenderKey),
    /// Tables from Python around a volume.
    Tables(RenderKey),
}

/// A scene ready to render.
#[pyclass(frozen, module = "gscache._gscache")]
pub struct Scene {
    pub(crate) scene: volume_pt::Scene,
    pub(crate) origin: Origin,
}

impl Scene {
    /// The key of a render of this scene with `settings` (see volume-pt's `shard`).
    pub(crate) fn key(&self, settings: &RenderSettings) -> String {
        let base = match &self.origin {
            Origin::File(k) | Origin::Tables(k) => k.clone(),
        };
        base.part(
            settings_fingerprint(settings, &self.scene.camera, &self.scene.media.medium).as_bytes(),
        )
        .hex()
    }
}

#[pymethods]
impl Scene {
    /// A scene from the scene format's tables (as JSON, without `volume.file`) around `volume`.
    /// The Python layer (`gscache.Scene`) builds the JSON from keyword arguments.
    #[new]
    fn new(py: Python<'_>, volume: &Volume, tables_json: &str) -> PyResult<Self> {
        let here = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
        let origin = here.join("<scene from Python>");
        let desc: SceneFile = serde_json::from_str(tables_json)
            .map_err(|e| crate::error(format!("{}: scene: {e}", origin.display())))?;
        // The majorants of a streamed volume come from its survey (see `Volume::range`).
        let scene = py
            .detach(|| {
                build_scene_with_volume(&origin, desc, volume.loaded.clone(), volume.name.clone())
            })
            .map_err(crate::error)?;
        let key = volume.identity.clone().part(tables_json.as_bytes());
        Ok(Self {
            scene,
            origin: Origin::Tables(key),
        })
    }

    /// A scene chosen for `volume` (as `gscache render VOLUME` chooses it: a transfer function
    /// from its histogram with colour map `colormap`, a framing camera, a key light) and its
    /// TOML text.
    #[staticmethod]
    #[pyo3(signature = (volume, colormap="bone", nifti=false))]
    fn from_volume(
        py: Python<'_>,
        volume: &Volume,
        colormap: &str,
        nifti: bool,
    ) -> PyResult<(Self, String)> {
        let colormap: volume_pt::Colormap = colormap.parse().map_err(crate::error)?;
        let format = nifti.then_some(volume_pt::io::Format::Nifti);
        // The histogram and majorants of a streamed volume come from its survey (see
        // `Volume::range`).
        let (scene, text) = py
            .detach(|| {
                volume_pt::auto_scene::scene_for_loaded(
                    volume.loaded.clone(),
                    &volume.name,
                    format,
                    colormap,
                )
            })
            .map_err(crate::error)?;
        let key = volume.identity.clone().part(text.as_bytes());
        Ok((
            Self {
                scene,
                origin: Origin::Tables(key),
            },
            text,
        ))
    }

    /// The automatic scene for the volume file at `path`, as `gscache render VOLUME` chooses
    /// it (a store of several channels composited, each in its colour: see
    /// `volume_pt::auto_scene::scene_for_volume`), and its TOML text. The render key is the
    /// file's path, size and the scene's text.
    #[staticmethod]
    fn from_volume_file(path: PathBuf, colormap: &str) -> PyResult<(Self, String)> {
        let colormap: volume_pt::Colormap = colormap.parse().map_err(crate::error)?;
        let (scene, text) =
            volume_pt::auto_scene::scene_for_volume(&path, colormap).map_err(crate::error)?;
        let size = std::fs::metadata(&path).map_err(crate::error)?.len();
        let key = RenderKey::new()
            .part(path.to_string_lossy().as_bytes())
            .part(&size.to_le_bytes())
            .part(text.as_bytes());
        Ok((
            Self {
                scene,
                origin: Origin::Tables(key),
            },
            text,
        ))
    }

    /// This scene with its clipping replaced by `clip_json` (the `[clip]` table as JSON: `box`
    /// and `plane`); `{}` clips nothing. The render key follows the clipping.
    fn with_clipping(&self, py: Python<'_>, clip_json: &str) -> PyResult<Self> {
        let clipping: volume_pt::Clipping =
            serde_json::from_str(clip_json).map_err(|e| crate::error(format!("clip: {e}")))?;
        let mut scene = self.scene.clone();
        py.detach(|| scene.media.medium.set_clipping(clipping))
            .map_err(crate::error)?;
        Ok(Self {
            scene,
            origin: self.origin.clone(),
        })
    }

    /// The clipping as JSON (the `[clip]` table).
    #[getter]
    fn clipping(&self) -> PyResult<String> {
        serde_json::to_string(self.scene.media.medium.clipping()).map_err(crate::error)
    }

    /// Reads a scene file (TOML), as `gscache render` does.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let scene = volume_pt::load_scene(&path).map_err(crate::error)?;
        let key = scene_file_key(&path, &scene).map_err(crate::error)?;
        Ok(Self {
            scene,
            origin: Origin::File(key),
        })
    }

    #[getter]
    fn width(&self) -> u32 {
        self.scene.camera.width
    }
    #[getter]
    fn height(&self) -> u32 {
        self.scene.camera.height
    }
    /// Samples per pixel the scene asks for.
    #[getter]
    fn spp(&self) -> u32 {
        self.scene.settings.spp
    }
    #[getter]
    fn seed(&self) -> u64 {
        self.scene.settings.seed
    }
    #[getter]
    fn integrator(&self) -> String {
        self.scene.settings.path.integrator.to_string()
    }
    /// Largest path length in scattering vertices; -1 for unlimited.
    #[getter]
    fn max_depth(&self) -> i64 {
        self.scene.settings.path.max_depth.map_or(-1, i64::from)
    }
    /// The PNG exposure (stops) and tone map the scene asks for.
    #[getter]
    fn exposure(&self) -> f32 {
        self.scene.output.exposure
    }
    #[getter]
    fn tonemap(&self) -> String {
        format!("{:?}", self.scene.output.tonemap).to_lowercase()
    }
    /// What the readers reported and warnings about likely mistakes.
    #[getter]
    fn notes(&self) -> Vec<String> {
        self.scene.notes.clone()
    }
    /// The render key of the scene's own settings (shards of one render share it).
    #[getter]
    fn render_key(&self) -> String {
        self.key(&self.scene.settings)
    }

    fn __repr__(&self) -> String {
        format!(
            "Scene({}, {}x{}, {} spp, {}, seed {})",
            self.scene.volume_path.display(),
            self.width(),
            self.height(),
            self.spp(),
            self.integrator(),
            self.seed()
        )
    }
}

/// The scene's settings with the caller's overrides.
pub(crate) fn settings_with(
    scene: &Scene,
    spp: Option<u32>,
    seed: Option<u64>,
    integrator: Option<&str>,
    max_depth: Option<i64>,
) -> PyResult<RenderSettings> {
    let integrator = integrator
        .map(|i| {
            <volume_pt::IntegratorKind as clap::ValueEnum>::from_str(i, true)
                .map_err(|_| crate::error(format!("integrator `{i}`: expected `uniform` or `nee`")))
        })
        .transpose()?;
    volume_pt::SceneOverrides {
        spp,
        seed,
        integrator,
        max_depth,
        ..Default::default()
    }
    .settings(scene.scene.settings)
    .map_err(crate::error)
}

/// A memory budget given as a number of bytes or a size such as `"4G"`.
fn budget_bytes(b: &Bound<'_, PyAny>) -> PyResult<u64> {
    match b.extract::<u64>() {
        Ok(n) if n > 0 => Ok(n),
        _ => {
            let text: String = b.str()?.extract()?;
            volume_pt::io::parse_bytes(&text)
                .map_err(|e| crate::error(format!("memory_budget: {e}")))
        }
    }
}

/// Sets the memory this process's volumes may take (bytes, or a size such as `"4G"`): an
/// OME-Zarr store larger is streamed from disk within it, as the program's `--memory-budget`
/// does; `None` returns to the default (`GSCACHE_MEMORY_BUDGET`, else half the memory the
/// process may use). A Dask worker's recipe calls it before loading its scene.
#[pyfunction]
#[pyo3(signature = (budget))]
pub fn set_memory_budget(budget: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    volume_pt::io::set_memory_budget(budget.map(budget_bytes).transpose()?);
    Ok(())
}
