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
