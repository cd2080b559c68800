//! The C ABI from C: the committed header is what cbindgen makes of `src/capi.rs`, and a C
//! program (`c/drive_cache.c`) compiled against it and the static library initialises, reads,
//! trains, saves, loads and frees a cache with the values it expects.

use std::path::{Path, PathBuf};
use std::process::Command;

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The header as cbindgen generates it now.
fn generated_header() -> String {
    let dir = crate_dir();
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_crate(&dir)
        .with_config(config)
        .generate()
        .expect("cbindgen could not parse the crate");
    let mut out = Vec::new();
    bindings.write(&mut out);
    String::from_utf8(out).expect("header is UTF-8")
}

#[test]
fn header_matches_the_rust_api() {
    let path = crate_dir().join("include/gs_cache.h");
    let generated = generated_header();
    if std::env::var_os("GS_CACHE_WRITE_HEADER").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &generated).unwrap();
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "{} is out of date with src/capi.rs: regenerate it with \
         GS_CACHE_WRITE_HEADER=1 cargo test -p gs-cache --test c_abi",
        path.display()
    );
}

/// The static library cargo built for this test run: `libgs_cache-*.a` beside the test
/// executable (the newest, if older builds left others).
fn static_library() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    std::fs::read_dir(deps)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with("libgs_cache-") && name.ends_with(".a")
        })
        .max_by_key(|p| p.metadata().and_then(|m| m.modified()).ok())
        .unwrap_or_else(|| panic!("no libgs_cache-*.a in {}", deps.display()))
}

fn run(cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("could not run {cmd:?}: {e}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{text}",
        out.status
    );
    text
}

#[test]
#[cfg(unix)]
fn c_program_drives_a_cache() {
    let dir = crate_dir();
    let work = Path::new(env!("CARGO_TARGET_TMPDIR")).join("c_abi");
    std::fs::create_dir_all(&work).unwrap();
    let exe = work.join("drive_cache");
    // Linux needs these beside the Rust standard library; macOS has them in libSystem.
    let system_libs: &[&str] = if cfg!(target_os = "linux") {
        &["-lpthread", "-ldl", "-lm", "-lrt", "-lgcc_s"]
    } else {
        &["-lm"]
    };
    run(
        Command::new(std::env::var("CC").unwrap_or_else(|_| "cc".into()))
            .args(["-std=c11", "-O1", "-Wall", "-Wextra", "-Werror", "-I"])
            .arg(dir.join("include"))
            .arg(dir.join("c/drive_cache.c"))
            .arg(static_library())
            .args(system_libs)
            .arg("-o")
            .arg(&exe),
    );
    let out_dir = work.join("saved");
    let _ = std::fs::remove_dir_all(&out_dir);
    let text = run(Command::new(&exe).arg(&out_dir));
    println!("{text}");
    assert!(text.contains("all checks passed"), "{text}");
    assert!(out_dir.join("length_2.ply").exists());
}
