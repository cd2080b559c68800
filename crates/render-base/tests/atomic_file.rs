//! The atomic writer in a folder someone else can write to.
//!
//! Each attack below succeeded against the writer this crate replaced, which opened
//! `.NAME.PID.partial` by name: the planted link's target was overwritten (checked before the
//! change).

use render_base::{check_writable, write_atomically};
use std::io::Write;
use std::path::Path;

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "render-base-{name}-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

fn write_text(path: &Path, text: &str) -> Result<(), render_base::WriteError> {
    write_atomically(path, |w| {
        w.write_all(text.as_bytes()).map_err(|e| e.to_string())
    })
}

#[cfg(unix)]
#[test]
fn a_link_planted_at_the_old_temporary_name_is_not_followed() {
    let dir = scratch("planted");
    let victim_dir = scratch("planted-victim");
    let victim = victim_dir.join("precious.txt");
    std::fs::write(&victim, "the user's work").unwrap();
    let out = dir.join("out.exr");
    // Every name the old writer could have used in this process, and a few around it.
    for pid in [std::process::id(), std::process::id() + 1] {
        std::os::unix::fs::symlink(&victim, dir.join(format!(".out.exr.{pid}.partial"))).unwrap();
    }
    write_text(&out, "new image").unwrap();
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "the user's work");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "new image");
    assert!(
        std::fs::symlink_metadata(&out)
            .unwrap()
            .file_type()
            .is_file()
    );
}

#[cfg(unix)]
#[test]
fn an_output_that_is_a_link_is_replaced_not_written_through() {
    let dir = scratch("outlink");
    let victim_dir = scratch("outlink-victim");
    let victim = victim_dir.join("precious.txt");
    std::fs::write(&victim, "the user's work").unwrap();
    let out = dir.join("out.png");
    std::os::unix::fs::symlink(&victim, &out).unwrap();
    write_text(&out, "new image").unwrap();
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "the user's work");
    assert!(
        std::fs::symlink_metadata(&out)
            .unwrap()
            .file_type()
            .is_file()
    );
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "new image");
}

#[test]
fn a_failed_write_keeps_the_old_file_and_leaves_nothing_behind() {
    let dir = scratch("failed");
    let out = dir.join("out.exr");
    std::fs::write(&out, "old image").unwrap();
    let err = write_atomically(&out, |w| {
        w.write_all(b"half an ima").unwrap();
        Err("the encoder gave up".into())
    })
    .unwrap_err();
    assert!(err.to_string().contains("out.exr") && err.to_string().contains("encoder gave up"));
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old image");
    assert_eq!(entries(&dir), ["out.exr"]);
}

#[test]
fn a_successful_write_leaves_only_the_target() {
    let dir = scratch("ok");
    let out = dir.join("report.md");
    write_text(&out, "one").unwrap();
    write_text(&out, "two").unwrap();
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "two");
    assert_eq!(entries(&dir), ["report.md"]);
}

#[test]
fn the_writability_check_leaves_nothing_and_names_a_missing_folder() {
    let dir = scratch("probe");
    check_writable(&dir).unwrap();
    assert!(entries(&dir).is_empty());
    let missing = dir.join("no-such-folder");
    let err = check_writable(&missing).unwrap_err().to_string();
    assert!(err.contains("no-such-folder"), "{err}");
}

#[test]
fn a_path_without_a_file_name_is_refused() {
    let err = write_text(Path::new("/"), "x").unwrap_err().to_string();
    assert!(err.contains("names no file"), "{err}");
}

#[test]
fn a_rename_onto_a_folder_fails_and_leaves_nothing_behind() {
    let dir = scratch("folder");
    std::fs::create_dir_all(dir.join("out.exr").join("inside")).unwrap();
    let err = write_text(&dir.join("out.exr"), "x").unwrap_err();
    assert!(err.to_string().contains("out.exr"), "{err}");
    assert_eq!(entries(&dir), ["out.exr"]);
}

/// Issue 48, second item: `-o /dev/stdout` as root replaced the machine's `/dev/stdout` link
/// with a regular file. An output that is (or links to) a device, a FIFO or a socket, or that
/// lies under /dev, /proc or /sys, is refused, and nothing is written.
#[cfg(unix)]
#[test]
fn devices_fifos_and_system_folders_are_refused_as_outputs() {
    let dir = scratch("devices");
    let fifo = dir.join("pipe.exr");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success());
    assert!(made, "mkfifo failed");
    // A link to a device: following it finds the device (the link must not be replaced).
    let link = dir.join("null.exr");
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    for (path, kind) in [(&fifo, "FIFO"), (&link, "device")] {
        let err = write_text(path, "x").unwrap_err().to_string();
        assert!(err.contains(kind) && err.contains("regular file"), "{err}");
    }
    assert!(
        std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert_eq!(entries(&dir), ["null.exr", "pipe.exr"]);
    for path in [
        "/proc/self/out.exr",
        "/sys/out.exr",
        "/dev/stdout.png",
        "/dev/new-folder/out.exr",
    ] {
        let err = render_base::check_output(Path::new(path))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("folder of the system's devices"),
            "{path}: {err}"
        );
    }
    assert!(!Path::new("/dev/new-folder").exists());
    // An ordinary file, and a file that does not exist yet, are outputs.
    render_base::check_output(&dir.join("new.exr")).unwrap();
    write_text(&dir.join("new.exr"), "x").unwrap();
    render_base::check_output(&dir.join("new.exr")).unwrap();
}
