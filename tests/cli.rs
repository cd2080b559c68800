//! `gscache render` end to end: a render from the bundled scene, clear errors on bad input,
//! and Ctrl-C writing the image accumulated so far.

use std::path::PathBuf;
use std::process::{Command, Stdio};

fn render() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_gscache"));
    c.arg("render");
    c
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gscache-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn renders_the_default_scene_to_exr_and_png() {
    let d = scratch("default");
    let exr = d.join("a.exr");
    let png = d.join("a.png");
    let out = render()
        .arg(repo().join("data/scenes/default.toml"))
        .args([
            "--spp",
            "2",
            "--width",
            "64",
            "--height",
            "48",
            "--threads",
            "2",
            "-q",
        ])
        .arg("-o")
        .arg(&exr)
        .arg("--png")
        .arg(&png)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("rendered 64x48 at 2 spp") && stdout.contains("samples/s"),
        "{stdout}"
    );
    let image = hdr_image::RgbImage::read_exr(&exr).unwrap();
    let (w, h, px) = (image.width(), image.height(), image.pixels().to_vec());
    assert_eq!((w, h), (64, 48));
    assert!(px.iter().all(|p| p.is_finite()));
    // The environment is visible around the volume, and the volume is lit.
    let mean: f32 = px.iter().map(|p| p.y).sum::<f32>() / px.len() as f32;
    assert!(mean > 0.05, "image too dark: {mean}");
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (64, 48));
}

#[test]
fn bad_input_is_a_clear_error_not_a_panic() {
    let d = scratch("bad");
    let scene = d.join("bad.toml");
    std::fs::write(&scene, "[volume]\nfile = \"missing_8x8x8_uint8.raw\"\n[transfer]\ndensity_scale = 1\npoints = [{ value = 0, color = [1,1,1], opacity = 1 }]\n[camera]\neye = [0,0,5]\ntarget = [0,0,0]\nfov_y = 30\nwidth = 8\nheight = 8\n").unwrap();
    let out = render().arg(&scene).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with("error: ")
            && err.contains("missing_8x8x8_uint8.raw")
            && err.contains("no such file"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let out = render()
        .arg(repo().join("data/scenes/default.toml"))
        .args(["--width", "0"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("0x512") && !err.contains("panicked"), "{err}");
}

#[test]
fn an_interrupt_writes_what_was_accumulated_and_exits_130() {
    for signal in ["-INT", "-TERM"] {
        let d = scratch(&format!("signal{signal}"));
        let exr = d.join("partial.exr");
        let child = render()
            .arg(repo().join("data/scenes/default.toml"))
            .args(["--spp", "100000", "--width", "32", "--height", "32", "-q"])
            .arg("-o")
            .arg(&exr)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(1500));
        let status = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(status.success());
        let out = child.wait_with_output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert_eq!(
            out.status.code(),
            Some(130),
            "{signal}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(stdout.contains("interrupted after"), "{signal}: {stdout}");
        let px = hdr_image::RgbImage::read_exr(&exr).unwrap().into_pixels();
        assert!(px.iter().all(|p| p.is_finite()) && px.iter().any(|p| p.max_element() > 0.0));
    }
}

#[test]
fn an_unwritable_output_is_refused_before_rendering() {
    let d = scratch("unwritable");
    let file = d.join("a_file");
    std::fs::write(&file, b"x").unwrap();
    // The output's folder is a file: found at once, not after a million samples.
    let start = std::time::Instant::now();
    let out = render()
        .arg(repo().join("data/scenes/default.toml"))
        .args(["--spp", "1000000", "-q", "-o"])
        .arg(file.join("out.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("a_file"), "{err}");
    assert!(
        start.elapsed().as_secs() < 30,
        "the render ran before the check"
    );
    // Frames and warm-up without the cache are a mistake, not a silent plain render.
    let out = render()
        .arg(repo().join("data/scenes/default.toml"))
        .args(["--frames", "4", "-q", "-o"])
        .arg(d.join("x.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--cache"), "{err}");
}
