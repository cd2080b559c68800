//! Finding Open Image Denoise and binding the few C functions the filter calls.
//!
//! Looked for, in order:
//! 1. the file or folder named by `GSCACHE_OIDN` (the user's explicit choice);
//! 2. `libOpenImageDenoise.so.2` through the system loader (`LD_LIBRARY_PATH`, ldconfig);
//! 3. the copy inside the `pyoidn` Python package, as the installed package's own metadata
//!    places it: asked of the `python3` first on `PATH` (a virtual environment's or the user's
//!    interpreter), run isolated (`-I`: neither the current folder nor `PYTHON*` variables on
//!    its module path) from the root folder, so that nothing in the folder the program was
//!    started from can pose as the package.
//!
//! Loading a library runs its initialisers, so a library found by searching (3) is loaded
//! only from a trusted place (`trusted`): the file and every folder above it owned by the
//! user or root and writable by no one else, and not inside the current folder unless the
//! interpreter that reported it is installed there too (a virtual environment the user made
//! and put on `PATH`). A dataset or a cloned repository that ships a `pyoidn/` cannot run code
//! by being the folder `gscache` is run from.
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
/// `OIDN_ERROR_CANCELLED`: a progress monitor returned false (see [`ProgressMonitor`]).
pub const ERROR_CANCELLED: c_int = 6;

/// `OIDNProgressMonitorFunction`: called by OIDN's threads during a filter's execution with
/// the progress so far; returning false cancels the execution.
pub type ProgressMonitor = unsafe extern "C" fn(*mut c_void, f64) -> bool;

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
    pub set_filter_progress_monitor:
        unsafe extern "C" fn(Handle, Option<ProgressMonitor>, *mut c_void),
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
            // The user's explicit choice: its failure is reported as it is, not searched past.
            return Self::open(&named_library(&named)?);
        }
        searched.push(format!("{ENV_VAR} (not set)"));
        match Self::open(Path::new(FILE_NAME)) {
            Ok(api) => return Ok(api),
            Err(_) => searched.push(format!("{FILE_NAME} on the system's library path")),
        }
        match pyoidn_install() {
            Some(install) => {
                let file = install.library_folder.join(FILE_NAME);
                if !file.is_file() {
                    searched.push(format!("{} (pyoidn's copy: missing)", file.display()));
                } else {
                    let here = std::env::current_dir().and_then(|d| d.canonicalize()).ok();
                    match trusted(&file, &install.interpreter_prefix, here.as_deref()) {
                        Ok(file) => return Self::open(&file),
                        Err(why) => searched.push(format!(
                            "{} (pyoidn's copy: not loaded, {why})",
                            file.display()
                        )),
                    }
                }
            }
            None => searched
                .push("the pyoidn Python package (python3 does not have it installed)".into()),
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
            set_filter_progress_monitor: symbol!("oidnSetFilterProgressMonitorFunction"),
            release_filter: symbol!("oidnReleaseFilter"),
            _library: library,
        })
    }
}

/// The file `GSCACHE_OIDN` names: the library, or the folder holding it. A relative path is
/// taken from the current folder, as the user typed it (the system loader would otherwise
/// search its own path for a bare name and say "No such file" of a file that is there).
fn named_library(named: &std::ffi::OsStr) -> Result<PathBuf> {
    let refuse = |message: &str| DenoiseError::Load {
        path: format!("{ENV_VAR}={}", named.to_string_lossy()),
        message: message.to_string(),
    };
    if named.is_empty() {
        return Err(refuse(
            "the variable is set but empty; unset it, or set it to the library file or its folder",
        ));
    }
    let named = std::path::absolute(named)
        .map_err(|e| refuse(&format!("cannot make the path absolute: {e}")))?;
    let file = if named.is_dir() {
        named.join(FILE_NAME)
    } else {
        named
    };
    if !file.is_file() {
        return Err(refuse(&format!(
            "{} is not a file (expected {FILE_NAME}, or the folder holding it)",
            file.display()
        )));
    }
    Ok(file)
}

/// Where the `python3` on `PATH` has `pyoidn` installed.
#[derive(Debug)]
struct PyoidnInstall {
    /// The folder of the package's bundled libraries.
    library_folder: PathBuf,
    /// The interpreter's `sys.prefix`: where a virtual environment lives.
    interpreter_prefix: PathBuf,
}

/// The script that asks the interpreter where the installed `pyoidn` distribution puts its
/// libraries. It reads the distribution's metadata (`*.dist-info`) and imports nothing of the
/// package. Run with `-I`, the interpreter's path holds only its own library and site-packages;
/// the user's site-packages (`pip install --user`) is added back where a plain `python3` would
/// have it (outside a virtual environment).
const FIND_PYOIDN: &str = "\
import importlib.metadata as m, os, site, sys
user = site.getusersitepackages()
if sys.prefix == sys.base_prefix and os.path.isdir(user):
    sys.path.append(user)
try:
    d = m.distribution('pyoidn')
except m.PackageNotFoundError:
    raise SystemExit(3)
print(os.path.realpath(str(d.locate_file(os.path.join('pyoidn', 'oidn', 'lib')))))
print(os.path.realpath(sys.prefix))
";

/// Asks the `python3` on `PATH` where `pyoidn` is installed: isolated (`-I`), from the root
/// folder, with no standard input; `None` where there is no interpreter or no such package.
fn pyoidn_install() -> Option<PyoidnInstall> {
    let out = std::process::Command::new("python3")
        .args(["-I", "-c", FIND_PYOIDN])
        .current_dir("/")
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8(out.stdout).ok()?;
    let mut lines = text.lines();
    let (folder, prefix) = (lines.next()?.trim(), lines.next()?.trim());
    (!folder.is_empty() && !prefix.is_empty()).then(|| PyoidnInstall {
        library_folder: PathBuf::from(folder),
        interpreter_prefix: PathBuf::from(prefix),
    })
}

/// `file`, resolved, if it may be loaded (see the module docs) when the program runs in the
/// folder `here` (resolved); the reason otherwise.
fn trusted(
    file: &Path,
    interpreter_prefix: &Path,
    here: Option<&Path>,
) -> std::result::Result<PathBuf, String> {
    let file = file
        .canonicalize()
        .map_err(|e| format!("cannot resolve it: {e}"))?;
    // The root folder holds everything: being run from it says nothing of a file.
    if let Some(here) = here
        && here.parent().is_some()
        && file.starts_with(here)
        && !interpreter_prefix.starts_with(here)
    {
        return Err(format!(
            "it is inside the current folder {}, and the interpreter that reported it is not",
            here.display()
        ));
    }
    owned_and_unwritable_by_others(&file)?;
    Ok(file)
}

/// The file and every folder above it: owned by the user or root, and writable by no one else
/// (a folder writable by all but with its sticky bit, like `/tmp`, lets no one else replace
/// what is in it).
#[cfg(unix)]
fn owned_and_unwritable_by_others(file: &Path) -> std::result::Result<(), String> {
    use std::os::unix::fs::MetadataExt;
    // SAFETY: geteuid takes no arguments, touches no memory of ours and cannot fail (POSIX).
    let me = unsafe { libc::geteuid() };
    for path in file.ancestors() {
        let meta = std::fs::metadata(path).map_err(|e| format!("{}: {e}", path.display()))?;
        if meta.uid() != 0 && meta.uid() != me {
            return Err(format!(
                "{} belongs to another user (uid {})",
                path.display(),
                meta.uid()
            ));
        }
        let sticky_folder = meta.is_dir() && meta.mode() & 0o1000 != 0;
        if meta.mode() & 0o022 != 0 && !sticky_folder {
            return Err(format!(
                "{} is writable by others (mode {:o})",
                path.display(),
                meta.mode() & 0o7777
            ));
        }
    }
    Ok(())
}

#[cfg(not(unix))]
fn owned_and_unwritable_by_others(_file: &Path) -> std::result::Result<(), String> {
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("denoise-library-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("lib")).unwrap();
        std::fs::write(d.join("lib").join(FILE_NAME), b"not a library").unwrap();
        d.canonicalize().unwrap()
    }

    #[test]
    fn a_library_inside_the_current_folder_is_trusted_only_from_an_interpreter_there() {
        let d = scratch("here");
        let file = d.join("lib").join(FILE_NAME);
        let elsewhere = Path::new("/usr");
        let why = trusted(&file, elsewhere, Some(&d)).unwrap_err();
        assert!(why.contains("inside the current folder"), "{why}");
        // A virtual environment made in the folder and put on PATH by the user.
        assert_eq!(trusted(&file, &d.join("venv"), Some(&d)).unwrap(), file);
        // Run from elsewhere, or from the root folder, the same file is judged by its owner
        // and mode alone.
        assert_eq!(
            trusted(&file, elsewhere, Some(Path::new("/usr"))).unwrap(),
            file
        );
        assert_eq!(
            trusted(&file, elsewhere, Some(Path::new("/"))).unwrap(),
            file
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[cfg(unix)]
    #[test]
    fn a_library_in_a_folder_others_can_write_is_not_trusted() {
        use std::os::unix::fs::PermissionsExt;
        let d = scratch("writable");
        let file = d.join("lib").join(FILE_NAME);
        let set = |p: &Path, mode: u32| {
            std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap()
        };
        set(&d.join("lib"), 0o755);
        set(&file, 0o644);
        assert_eq!(trusted(&file, Path::new("/usr"), None).unwrap(), file);
        for (path, mode) in [
            (d.join("lib"), 0o777),
            (d.join("lib"), 0o775),
            (file.clone(), 0o666),
        ] {
            set(&path, mode);
            let why = trusted(&file, Path::new("/usr"), None).unwrap_err();
            assert!(
                why.contains("writable by others"),
                "{}: {why}",
                path.display()
            );
            set(&path, if path.is_dir() { 0o755 } else { 0o644 });
        }
        // Writable by all but sticky, like /tmp: no one else can replace what is in it.
        set(&d.join("lib"), 0o1777);
        assert_eq!(trusted(&file, Path::new("/usr"), None).unwrap(), file);
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn an_empty_or_missing_named_library_says_so() {
        let empty = named_library(std::ffi::OsStr::new(""))
            .unwrap_err()
            .to_string();
        assert!(empty.contains("set but empty"), "{empty}");
        let missing = named_library(std::ffi::OsStr::new("no-such-file-v1.so"))
            .unwrap_err()
            .to_string();
        // Named by its absolute path: the user sees which folder was looked in.
        assert!(
            missing.contains("is not a file")
                && missing.contains(std::env::current_dir().unwrap().to_str().unwrap()),
            "{missing}"
        );
    }
}
