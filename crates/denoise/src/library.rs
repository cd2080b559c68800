//! Finding Open Image Denoise and binding the few C functions the filter calls.
//!
//! Looked for, in order:
//! 1. the file or folder named by `GSCACHE_OIDN` (the user's explicit choice);
//! 2. `libOpenImageDenoise.so.2` through the system loader (`LD_LIBRARY_PATH`, ldconfig);
//! 3. the copy inside the `pyoidn` Python package: the folder `python3` reports for it (a
//!    virtual environment's or the user's interpreter, whichever is first on `PATH`).
//!
//! The signatures below are those of OIDN 2.x's `oidn.h`; the device's `version` is checked
//! to be 2.x before any of them is trusted further than creating the device.

use crate::{DenoiseError, Result};
use std::ffi::{c_char, c_int, c_void};
use std::path::{Path, PathBuf};

/// The environment variable that names the library (a file, or the folder holding it).
pub const ENV_VAR: &str = "GSCACHE_OIDN";

/// How to get the library, for every message that says it is missing.
pub const INSTALL_HINT: &str = "Install it with `pip install pyoidn` (its wheel ships OIDN 2.5's \
     libraries; gscache finds them through python3), or set GSCACHE_OIDN to the path of \
     libOpenImageDenoise.so.2.";

/// The library's file name on this platform.
#[cfg(target_os = "linux")]
const FILE_NAME: &str = "libOpenImageDenoise.so.2";
#[cfg(target_os = "macos")]
const FILE_NAME: &str = "libOpenImageDenoise.2.dylib";
#[cfg(windows)]
const FILE_NAME: &str = "OpenImageDenoise.dll";

/// OIDN's opaque handles.
pub type Handle = *mut c_void;

/// `OIDN_DEVICE_TYPE_CPU`: the project is a CPU renderer; a GPU device would make its timings
/// incomparable with the renderer's own.
pub const DEVICE_TYPE_CPU: c_int = 1;
/// `OIDN_FORMAT_FLOAT3`: three packed f32 a pixel.
pub const FORMAT_FLOAT3: c_int = 3;
/// `OIDN_ERROR_NONE`.
pub const ERROR_NONE: c_int = 0;

/// The C functions used, resolved from the loaded library. The `Library` is kept alive as
/// long as any pointer taken from it.
pub struct Api {
    _library: libloading::Library,
    pub path: String,
    pub new_device: unsafe extern "C" fn(c_int) -> Handle,
    pub commit_device: unsafe extern "C" fn(Handle),
    pub release_device: unsafe extern "C" fn(Handle),
    pub set_device_int: unsafe extern "C" fn(Handle, *const c_char, c_int),
    pub get_device_int: unsafe extern "C" fn(Handle, *const c_char) -> c_int,
    pub get_device_error: unsafe extern "C" fn(Handle, *mut *const c_char) -> c_int,
    pub new_filter: unsafe extern "C" fn(Handle, *const c_char) -> Handle,
    #[allow(clippy::type_complexity)] // the C signature, as written in oidn.h
    pub set_shared_filter_image: unsafe extern "C" fn(
        Handle,
        *const c_char,
        *mut c_void,
        c_int,
        usize,
        usize,
        usize,
        usize,
        usize,
    ),
    pub set_filter_bool: unsafe extern "C" fn(Handle, *const c_char, bool),
    pub set_filter_int: unsafe extern "C" fn(Handle, *const c_char, c_int),
    pub commit_filter: unsafe extern "C" fn(Handle),
    pub execute_filter: unsafe extern "C" fn(Handle),
    pub release_filter: unsafe extern "C" fn(Handle),
}

impl std::fmt::Debug for Api {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Api").field("path", &self.path).finish()
    }
}

impl Api {
    /// Finds and loads the library (see the module docs for where it is looked for).
    pub fn find() -> Result<Self> {
        let mut searched = Vec::new();
        if let Some(named) = std::env::var_os(ENV_VAR) {
            let named = PathBuf::from(named);
            let file = if named.is_dir() {
                named.join(FILE_NAME)
            } else {
                named
            };
            // The user's explicit choice: its failure is reported as it is, not searched past.
            return Self::open(&file);
        }
        searched.push(format!("{ENV_VAR} (not set)"));
        match Self::open(Path::new(FILE_NAME)) {
            Ok(api) => return Ok(api),
            Err(_) => searched.push(format!("{FILE_NAME} on the system's library path")),
        }
        match pyoidn_folder() {
            Some(folder) => {
                let file = folder.join(FILE_NAME);
                if file.is_file() {
                    return Self::open(&file);
                }
                searched.push(format!("{} (pyoidn's copy: missing)", file.display()));
            }
            None => searched.push("the pyoidn Python package (python3 cannot import it)".into()),
        }
        Err(DenoiseError::NotFound { searched })
    }

    /// Loads the library at `path` and resolves every function used.
    pub fn open(path: &Path) -> Result<Self> {
        let shown = path.display().to_string();
        let fail = |message: String| DenoiseError::Load {
            path: shown.clone(),
            message,
        };
        // SAFETY: loading runs the library's initialisers. OIDN's are those of a C++ shared
        // library (static constructors, TBB's); it does not require being loaded in any
        // particular way, and the project loads it once per `Denoiser`.
        let library = unsafe { libloading::Library::new(path) }.map_err(|e| fail(e.to_string()))?;
        macro_rules! symbol {
            ($name:literal) => {
                // SAFETY: the type the symbol is read as is the signature `oidn.h` (2.x)
                // declares for this function; the device's version is checked to be 2.x
                // right after the device is created, before any call that depends on it.
                *unsafe { library.get(concat!($name, "\0").as_bytes()) }
                    .map_err(|e| fail(format!("no function {}: {e}", $name)))?
            };
        }
        Ok(Self {
            path: shown.clone(),
            new_device: symbol!("oidnNewDevice"),
            commit_device: symbol!("oidnCommitDevice"),
            release_device: symbol!("oidnReleaseDevice"),
            set_device_int: symbol!("oidnSetDeviceInt"),
            get_device_int: symbol!("oidnGetDeviceInt"),
            get_device_error: symbol!("oidnGetDeviceError"),
            new_filter: symbol!("oidnNewFilter"),
            set_shared_filter_image: symbol!("oidnSetSharedFilterImage"),
            set_filter_bool: symbol!("oidnSetFilterBool"),
            set_filter_int: symbol!("oidnSetFilterInt"),
            commit_filter: symbol!("oidnCommitFilter"),
            execute_filter: symbol!("oidnExecuteFilter"),
            release_filter: symbol!("oidnReleaseFilter"),
            _library: library,
        })
    }
}

/// The folder of pyoidn's bundled libraries, as the `python3` on `PATH` sees it.
fn pyoidn_folder() -> Option<PathBuf> {
    let out = std::process::Command::new("python3")
        .args([
            "-c",
            "import importlib.util, os; s = importlib.util.find_spec('pyoidn'); \
             print(os.path.join(os.path.dirname(s.origin), 'oidn', 'lib') if s else '')",
        ])
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    let folder = text.trim();
    (out.status.success() && !folder.is_empty()).then(|| PathBuf::from(folder))
}
