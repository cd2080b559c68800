//! Atomic, link-safe file writes.
//!
//! A render that is interrupted, or a disk that fills, must never leave a truncated file where a
//! good one was; and a folder shared with other users must not let them choose what the program
//! overwrites. Writing to a temporary file beside the target and renaming it over the target
//! gives the first. The second needs more than that: a temporary file with a predictable name
//! (the project once used `.NAME.PID.partial`) can be planted in advance as a symbolic link to
//! any file the user can write, and opening it by name then writes through the link.
//!
//! So the temporary file is created by [`atomic_write_file`]:
//! - relative to a descriptor of the output folder (a renamed folder cannot redirect it);
//! - on Linux as an unnamed file (`O_TMPFILE`), linked under a random name only once complete,
//!   so there is no name to plant and nothing is left behind if the process is killed;
//! - elsewhere, or where the file system has no unnamed files, exclusively (`O_CREAT | O_EXCL`,
//!   which never follows a link) under a random name.
//!
//! The rename replaces the directory entry itself: if the target is a symbolic link, the link
//! is replaced by the new file and the file it pointed to is left untouched.

use atomic_write_file::AtomicWriteFile;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// A write that did not happen; the target is as it was.
#[derive(Debug, thiserror::Error)]
#[error("{}: cannot write: {message}", path.display())]
pub struct WriteError {
    pub path: PathBuf,
    pub message: String,
}

/// The writer [`write_atomically`] hands to its closure: buffered and seekable (EXR and PNG
/// encoders seek), on a file that no other process can open by name.
pub type AtomicWriter = BufWriter<AtomicWriteFile>;

/// Writes `path` through `write`, atomically: the file appears complete or the old one stays.
///
/// `write` fills the writer; an error from it (any message) discards everything written. The
/// data is flushed and synced before the rename, so a crash after this returns keeps the file.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut AtomicWriter) -> Result<(), String>,
) -> Result<(), WriteError> {
    let fail = |message: String| WriteError {
        path: path.into(),
        message,
    };
    if path.file_name().is_none() {
        return Err(fail("the path names no file".into()));
    }
    check_output(path)?;
    let file = AtomicWriteFile::open(path).map_err(|e| fail(e.to_string()))?;
    let mut writer = BufWriter::new(file);
    // On any error below the temporary file is dropped, which discards it.
    write(&mut writer).map_err(fail)?;
    writer.flush().map_err(|e| fail(e.to_string()))?;
    let file = writer
        .into_inner()
        .map_err(|e| fail(e.error().to_string()))?;
    let identity = FileIdentity::of(file.as_file());
    file.commit().map_err(|e| {
        // The unnamed file is given a random name before the rename; when the rename fails
        // (the target is a folder, say), `atomic_write_file` leaves that name behind. Only a
        // name that is a link to this very file (same device and inode) is removed.
        if let Some(identity) = identity {
            identity.remove_names_beside(path);
        }
        fail(e.to_string())
    })
}

/// Which file a directory entry is: device and inode.
#[derive(Clone, Copy, PartialEq, Eq)]
struct FileIdentity {
    device: u64,
    inode: u64,
}

impl FileIdentity {
    #[cfg(unix)]
    fn of(file: &std::fs::File) -> Option<Self> {
        use std::os::unix::fs::MetadataExt;
        let m = file.metadata().ok()?;
        Some(Self {
            device: m.dev(),
            inode: m.ino(),
        })
    }

    #[cfg(not(unix))]
    fn of(_file: &std::fs::File) -> Option<Self> {
        None
    }

    /// Removes every `.NAME.*` entry beside `path` that is this file (never following a link).
    #[cfg(unix)]
    fn remove_names_beside(self, path: &Path) {
        use std::os::unix::fs::MetadataExt;
        let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
            return;
        };
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let mut prefix = std::ffi::OsString::from(".");
        prefix.push(name);
        prefix.push(".");
        let prefix = prefix.as_encoded_bytes().to_vec();
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for entry in entries.flatten() {
            if !entry.file_name().as_encoded_bytes().starts_with(&prefix) {
                continue;
            }
            let same = std::fs::symlink_metadata(entry.path())
                .is_ok_and(|m| m.dev() == self.device && m.ino() == self.inode);
            if same {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }

    #[cfg(not(unix))]
    fn remove_names_beside(self, _path: &Path) {}
}

/// The system's folders of devices and kernel files: nothing the user made is there, and a
/// file written there changes the machine (as root, `-o /dev/stdout` once replaced the
/// machine's `/dev/stdout` link with a regular file).
const SYSTEM_FOLDERS: [&str; 3] = ["/dev", "/proc", "/sys"];

/// Linux's shared-memory folder: under `/dev`, but a file system of ordinary files that users
/// write scratch data to.
const SHARED_MEMORY: &str = "/dev/shm";

/// Checks that `path` may be an output: where it exists, a regular file (following links: a
/// link to a device is a device), and its nearest existing folder is not under a system
/// folder ([`SYSTEM_FOLDERS`]). A device, FIFO or socket is refused: gscache writes only
/// regular files, by replacing them whole.
pub fn check_output(path: &Path) -> Result<(), WriteError> {
    let fail = |message: String| WriteError {
        path: path.into(),
        message,
    };
    if let Ok(meta) = std::fs::metadata(path) {
        let kind = file_kind(&meta);
        if kind != "regular file" {
            return Err(fail(format!(
                "it is a {kind}: expected a regular file (gscache writes only regular files)"
            )));
        }
    }
    let existing = path
        .ancestors()
        .skip(1)
        .map(|d| {
            if d.as_os_str().is_empty() {
                Path::new(".")
            } else {
                d
            }
        })
        .find(|d| d.exists());
    if let Some(folder) = existing.and_then(|d| d.canonicalize().ok())
        && !folder.starts_with(SHARED_MEMORY)
        && let Some(system) = SYSTEM_FOLDERS
            .iter()
            .find(|s| folder.starts_with(Path::new(s)))
    {
        return Err(fail(format!(
            "it is under {system}, a folder of the system's devices and kernel files: expected a file of your own"
        )));
    }
    Ok(())
}

/// What kind of file a (followed) directory entry is, in words.
fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    let kind = meta.file_type();
    if kind.is_file() {
        return "regular file";
    }
    if kind.is_dir() {
        return "folder";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_char_device() || kind.is_block_device() {
            return "device";
        }
        if kind.is_fifo() {
            return "FIFO (named pipe)";
        }
        if kind.is_socket() {
            return "socket";
        }
    }
    "special file"
}

/// Checks, before any work, that a file can be created in folder `dir`, without leaving
/// anything there: a temporary file is opened as [`write_atomically`] would, then discarded.
pub fn check_writable(dir: &Path) -> Result<(), WriteError> {
    let probe = dir.join(".write-test");
    let fail = |e: std::io::Error| WriteError {
        path: dir.into(),
        message: e.to_string(),
    };
    AtomicWriteFile::open(&probe)
        .map_err(fail)?
        .discard()
        .map_err(fail)
}
