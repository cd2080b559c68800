//! `gscache render` end to end: a render from the bundled scene, clear errors on bad input,
//! Ctrl-C writing the image accumulated so far, a volume file with no scene, and the feature
//! layers and the denoiser.

use std::path::{Path, PathBuf};
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
    for signal in ["-INT", "-TERM", "-HUP"] {
        let d = scratch(&format!("signal{signal}"));
        let mut cmd = render();
        cmd.arg(repo().join("data/scenes/default.toml"))
            .args(["--spp", "100000", "--width", "32", "--height", "32", "-q"]);
        let stdout = interrupt_and_check(cmd, signal, &d.join("partial.exr"), "render");
        assert!(stdout.contains("interrupted after"), "{signal}: {stdout}");
    }
}

/// Starts `cmd` (writing its image to `exr`), sends `signal` after 1.5 s, and checks the run
/// kept its work: exit status 130 and a finite, not all-black image. Returns what it printed.
fn interrupt_and_check(mut cmd: Command, signal: &str, exr: &Path, what: &str) -> String {
    let child = cmd
        .arg("-o")
        .arg(exr)
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
    assert_eq!(
        out.status.code(),
        Some(130),
        "{what} {signal}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let px = hdr_image::RgbImage::read_exr(exr).unwrap().into_pixels();
    assert!(
        px.iter().all(|p| p.is_finite()) && px.iter().any(|p| p.max_element() > 0.0),
        "{what} {signal}"
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
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

fn gscache() -> Command {
    Command::new(env!("CARGO_BIN_EXE_gscache"))
}

/// Numbers that used to give a black image, a NaN image or an exploded cache with exit status 0
/// are refused before any work, with a message naming the flag or the fault.
#[test]
fn numbers_that_would_spoil_an_image_are_refused() {
    let d = scratch("numbers");
    let scene = repo().join("data/scenes/default.toml");
    let splats = repo().join("data/splats/fruit_drops_minimal_inria.ply");
    let out = |name: &str| d.join(name).to_string_lossy().into_owned();
    let scene = scene.to_string_lossy().into_owned();
    let splats = splats.to_string_lossy().into_owned();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["render".into(), scene.clone(), "--spp".into(), "0".into()],
            "--spp",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--cache".into(),
                "--frames".into(),
                "0".into(),
            ],
            "--frames",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--exposure".into(),
                "nan".into(),
            ],
            "not finite",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--cache".into(),
                "--warmup-orbit-degrees".into(),
                "inf".into(),
            ],
            "not finite",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--width".into(),
                "100000".into(),
            ],
            "too large",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--width".into(),
                "30000".into(),
                "--height".into(),
                "30000".into(),
            ],
            "memory",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--cache".into(),
                "--cache-points".into(),
                "18446744073709551615".into(),
            ],
            "at most",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--cache".into(),
                "--cache-lr-multiplier".into(),
                "1e30".into(),
            ],
            "at most 10",
        ),
        (
            vec![
                "splat".into(),
                "render".into(),
                splats.clone(),
                "--background".into(),
                "nan,0,0".into(),
            ],
            "not finite",
        ),
        (
            vec![
                "splat".into(),
                "render".into(),
                splats.clone(),
                "--stochastic".into(),
                "0".into(),
            ],
            "--stochastic",
        ),
        (
            vec![
                "splat".into(),
                "trace".into(),
                splats.clone(),
                "--spp".into(),
                "0".into(),
            ],
            "--spp",
        ),
        (
            vec![
                "splat".into(),
                "trace".into(),
                splats.clone(),
                "--k".into(),
                "18446744073709551615".into(),
            ],
            "--k",
        ),
        (
            vec![
                "splat".into(),
                "fit".into(),
                "x.exr".into(),
                "--points".into(),
                "1000000000000".into(),
            ],
            "--points",
        ),
        (
            vec![
                "render".into(),
                scene.clone(),
                "--threads".into(),
                "100000".into(),
            ],
            "--threads",
        ),
        (
            vec![
                "splat".into(),
                "trace".into(),
                splats.clone(),
                "--min-transmittance".into(),
                "nan".into(),
            ],
            "not finite",
        ),
        (
            vec![
                "splat".into(),
                "render".into(),
                splats.clone(),
                "--eye".into(),
                "0,0,5".into(),
                "--target".into(),
                "0,0,0".into(),
                "--up".into(),
                "0,0.000001,1".into(),
            ],
            "degenerate",
        ),
    ];
    for (args, needle) in cases {
        let started = std::time::Instant::now();
        let o = gscache()
            .args(&args)
            .args(["-q", "-o", &out("x.exr")])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} was accepted: {err}");
        assert!(
            err.contains(needle),
            "{args:?}: `{err}` does not mention `{needle}`"
        );
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(
            started.elapsed().as_secs() < 20,
            "{args:?} worked before refusing"
        );
    }
}

/// Gaussians no renderer can use are skipped with a count, not silently.
#[test]
fn unusable_gaussians_are_counted() {
    use splat_raster::{ColorModel, GaussianCloud};
    let d = scratch("unusable");
    let mut cloud = GaussianCloud::<f32>::new(ColorModel::Sh(0));
    cloud.push([0.0; 3], [-2.0; 3], [1.0, 0.0, 0.0, 0.0], &[0.5; 3], 2.0);
    cloud.push(
        [f32::NAN, 0.0, 0.0],
        [-2.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        &[0.5; 3],
        2.0,
    );
    cloud.push([0.1; 3], [-2.0; 3], [0.0; 4], &[0.5; 3], 2.0);
    let ply = d.join("c.ply");
    splat_raster::io::write_ply(&ply, &cloud).unwrap();
    let o = gscache()
        .args(["splat", "render"])
        .arg(&ply)
        .args(["--width", "16", "--height", "16", "-q", "-o"])
        .arg(d.join("c.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("2 of 3 Gaussians"), "{err}");
}

/// A scene whose paths are very long (a density scale 10^4 too large) still stops promptly on
/// an interrupt: cancellation is read before every sample, not only between 16x16 tiles.
#[test]
fn an_interrupt_stops_inside_a_slow_tile() {
    let d = scratch("slow-tile");
    let text = std::fs::read_to_string(repo().join("data/scenes/headsq.toml")).unwrap();
    let dense: String = text
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("density_scale") {
                "density_scale = 3000.0".to_string()
            } else if l.trim_start().starts_with("file") {
                l.replace("../volumes", &repo().join("data/volumes").to_string_lossy())
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let scene = d.join("dense.toml");
    std::fs::write(&scene, dense).unwrap();
    // One tile: before, nothing was checked until all of its samples were done.
    let child = render()
        .arg(&scene)
        .args([
            "--spp", "100000", "--width", "16", "--height", "16", "-q", "-o",
        ])
        .arg(d.join("dense.exr"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let signalled = std::time::Instant::now();
    Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(err.contains("optical depth"), "no units warning: {err}");
    assert!(
        signalled.elapsed().as_secs_f64() < 5.0,
        "took {:?} to stop",
        signalled.elapsed()
    );
}

/// A fit's target must be a finite image in a regular file: NaN pixels would become NaN
/// gradients, and a FIFO would block the reader.
#[test]
fn a_fit_target_with_nan_or_no_end_is_refused() {
    let d = scratch("fit-target");
    let mut px = vec![glam::Vec3::splat(0.5); 16];
    px[5] = glam::Vec3::new(f32::NAN, 0.0, 0.0);
    let exr = d.join("nan.exr");
    hdr_image::RgbImage::from_pixels(4, 4, px)
        .unwrap()
        .write_exr(&exr)
        .unwrap();
    let o = gscache()
        .args(["splat", "fit"])
        .arg(&exr)
        .args([
            "--width",
            "4",
            "--height",
            "4",
            "--iterations",
            "1",
            "-q",
            "-o",
        ])
        .arg(d.join("f.ply"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("pixel (1, 1) is [NaN, 0, 0]"),
        "{err}"
    );
    if Path::new("/dev/zero").exists() {
        let o = gscache()
            .args(["splat", "fit", "/dev/zero", "-q", "-o"])
            .arg(d.join("f.ply"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains("not a regular file"),
            "{err}"
        );
    }
}

#[test]
fn bench_large_tiles_the_bundled_volume_and_renders_it() {
    let d = scratch("large");
    let out = Command::new(env!("CARGO_BIN_EXE_gscache"))
        .args([
            "bench", "large", "--voxels", "128", "--size", "16", "--spp", "1",
        ])
        .arg("--dir")
        .arg(&d)
        .args(["--threads", "2"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("| neghip tiled 128^3 (uint8) | 0.002 G | 1 |"),
        "{stdout}"
    );
    // Voxel (x, y, z) of the tiled file is voxel (x % 64, y % 64, z % 64) of the tile.
    let tiled = std::fs::read(d.join("neghip_tiled_128x128x128_uint8.raw")).unwrap();
    let tile = std::fs::read(repo().join("data/volumes/neghip_64x64x64_uint8.raw")).unwrap();
    assert_eq!(tiled.len(), 128 * 128 * 128);
    for (x, y, z) in [
        (0, 0, 0),
        (70, 3, 5),
        (31, 100, 64),
        (127, 127, 127),
        (64, 65, 126),
    ] {
        assert_eq!(
            tiled[x + 128 * (y + 128 * z)],
            tile[x % 64 + 64 * (y % 64 + 64 * (z % 64))],
            "voxel ({x}, {y}, {z})"
        );
    }
    let bad = Command::new(env!("CARGO_BIN_EXE_gscache"))
        .args(["bench", "large", "--voxels", "100"])
        .arg("--dir")
        .arg(&d)
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("not a multiple of the tile's 64 voxels"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
    std::fs::remove_dir_all(&d).unwrap();
}

/// `render --shard I/N --partial` on three shards (each with its own thread count), then
/// `merge` in a shuffled order, writes the one-process EXR byte for byte; the refusals hold.
#[test]
fn sharded_render_merges_to_the_same_bytes() {
    let d = scratch("shards");
    let scene = repo().join("data/scenes/default.toml");
    let size = ["--width", "48", "--height", "40", "--spp", "7", "-q"];
    let whole = d.join("whole.exr");
    let out = render()
        .arg(&scene)
        .args(size)
        .arg("-o")
        .arg(&whole)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for i in 0..3 {
        let out = render()
            .arg(&scene)
            .args(size)
            .args([
                "--threads",
                &(i + 1).to_string(),
                "--shard",
                &format!("{i}/3"),
            ])
            .arg("--partial")
            .arg(d.join(format!("p{i}")))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let merge = |parts: &[&str], exr: &Path| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_gscache"));
        c.arg("merge");
        for p in parts {
            c.arg(d.join(p));
        }
        c.arg("-o").arg(exr).output().unwrap()
    };
    let merged = d.join("merged.exr");
    let out = merge(&["p2", "p0", "p1"], &merged);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read(&merged).unwrap(),
        std::fs::read(&whole).unwrap()
    );
    // The PNG too: the parts carry the scene's tone map (aces), which merge once replaced
    // with clip.
    assert_eq!(
        std::fs::read(merged.with_extension("png")).unwrap(),
        std::fs::read(whole.with_extension("png")).unwrap()
    );

    let err = |o: std::process::Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = err(merge(&["p0", "p1"], &d.join("x.exr")));
    assert!(e.contains("some shards are missing"), "{e}");
    let e = err(merge(&["p0", "p1", "p0"], &d.join("x.exr")));
    assert!(e.contains("given twice"), "{e}");
    // A shard of another render (another seed) is refused by its key.
    let out = render()
        .arg(&scene)
        .args(size)
        .args(["--seed", "9", "--shard", "2/3", "--partial"])
        .arg(d.join("other"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let e = err(merge(&["p0", "p1", "other"], &d.join("x.exr")));
    assert!(e.contains("different renders"), "{e}");
    let e = err(render()
        .arg(&scene)
        .args(["--shard", "3/3", "--partial", "x"])
        .output()
        .unwrap());
    assert!(e.contains("0 <= I < N"), "{e}");
    let e = err(render()
        .arg(&scene)
        .args(["--cache", "--shard", "0/2", "--partial"])
        .arg(d.join("c"))
        .output()
        .unwrap());
    assert!(e.contains("cannot be split"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// `render --nrc` renders with the neural cache, prints its per-frame costs and writes the
/// image; a bad `--nrc-KEY` names the key, the value and what was expected, before any work.
#[test]
fn the_neural_cache_renders_and_its_bad_settings_are_named() {
    let d = scratch("nrc");
    let exr = d.join("nrc.exr");
    let scene = repo().join("data/scenes/default.toml");
    let out = gscache()
        .arg("render")
        .arg(&scene)
        .args(["--width", "48", "--height", "32", "--spp", "1", "--nrc"])
        .args(["--warmup", "4", "--frames", "2", "-q", "-o"])
        .arg(&exr)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("inference and composition"), "{err}");
    let image = hdr_image::RgbImage::read_exr(&exr).unwrap();
    assert!(image.pixels().iter().all(|p| p.is_finite()));
    assert!(image.pixels().iter().any(|p| p.max_element() > 0.0));
    let cases: [(&[&str], &str); 5] = [
        (&["--nrc-hidden-layers", "0"], "hidden_layers"),
        (&["--nrc-learning-rate", "nan"], "learning_rate"),
        (&["--nrc-no-such-key", "1"], "--nrc-no-such-key"),
        (&["--nrc-hidden-layers", "many"], "--nrc-hidden-layers"),
        (&["--cache"], "cannot be used with"),
    ];
    for (args, expected) in cases {
        assert_refused(&scene, &["--nrc"], args, expected, &d);
    }
}

/// `render SCENE` at 16x16 with `base` and `args` fails naming `expected`, and writes no image.
fn assert_refused(scene: &Path, base: &[&str], args: &[&str], expected: &str, d: &Path) {
    let out = gscache()
        .arg("render")
        .arg(scene)
        .args(["--width", "16", "--height", "16"])
        .args(base)
        .args(args)
        .arg("-o")
        .arg(d.join("bad.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains(expected),
        "{args:?}: {err}"
    );
    assert!(!d.join("bad.exr").exists(), "{args:?} wrote an image");
}

/// The benches take their data from `--data` (an installed program has no source tree to read
/// from); a folder that is not a clone's `data/` is named, before any work.
#[test]
fn the_benches_take_their_data_folder_from_a_flag() {
    let d = scratch("bench-data");
    for bench in ["pt", "splat", "large", "cache", "stability", "trace"] {
        let out = gscache()
            .args(["bench", bench, "--data"])
            .arg(d.join("nowhere"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("--data") && err.contains("nowhere"),
            "{bench}: {err}"
        );
    }
}

/// A closed pipe is not a panic: `gscache render bad.toml 2>&1 | head -c 1` once exited 101
/// ("failed printing to stderr"). Both streams are closed before the program writes a word.
#[cfg(unix)]
#[test]
fn a_closed_pipe_is_not_a_panic() {
    let d = scratch("pipe");
    let bad = d.join("bad.toml");
    std::fs::write(&bad, "[volume]\nfile = \"missing.raw\"\n").unwrap();
    let out = gscache()
        .arg("render")
        .arg(&bad)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .and_then(|mut child| {
            // Close the reading ends at once: every write the program makes meets EPIPE.
            drop(child.stdout.take());
            drop(child.stderr.take());
            child.wait()
        })
        .unwrap();
    assert_eq!(out.code(), Some(1), "{out:?}");
}

/// Frame counts that would pass a pixel's 2^32 sample indices are refused before any work
/// (`--warmup 4294967295` once wrapped and rendered black with exit 0), and nothing is written.
#[test]
fn frame_counts_that_would_wrap_are_refused() {
    let d = scratch("wrap");
    let exr = d.join("wrapped.exr");
    for args in [
        &["--warmup", "4294967295", "--frames", "1", "--spp", "1"][..],
        &["--warmup", "4294967294", "--frames", "2", "--spp", "1"][..],
        &["--frames", "2147483648", "--spp", "2"][..],
    ] {
        let out = render()
            .arg(repo().join("data/scenes/default.toml"))
            .args(["--width", "8", "--height", "8", "-q", "--cache"])
            .args(args)
            .arg("-o")
            .arg(&exr)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("2^32"), "{args:?}: {err}");
        assert!(!exr.exists(), "{args:?} wrote an image");
    }
}

/// `splat trace` and `splat render --stochastic` keep their image on SIGINT and SIGTERM (each
/// pixel the mean of what it finished) and exit 130: they once lost it.
#[test]
fn an_interrupted_splat_render_or_trace_writes_what_it_has() {
    let asset = repo().join("data/splats/fruit_drops_minimal.ply");
    let view = [
        "--eye",
        "0.76,-0.2,-1.4",
        "--target",
        "0.76,0.13,-2.1",
        "--width",
        "32",
        "--height",
        "24",
        "-q",
    ];
    for (what, args) in [
        ("trace", &["trace", "--spp", "100000000"][..]),
        ("stochastic", &["render", "--stochastic", "100000000"][..]),
    ] {
        for signal in ["-INT", "-TERM"] {
            let d = scratch(&format!("splat-{what}{signal}"));
            let mut cmd = gscache();
            cmd.arg("splat").args(args).arg(&asset).args(view);
            interrupt_and_check(cmd, signal, &d.join("partial.exr"), what);
        }
    }
}

/// Asserts that every file in `written` still holds the bytes it had (the run `what` left the
/// earlier outputs intact), then adds `path`, which `what` must have written.
fn keep_written(written: &mut Vec<(PathBuf, Vec<u8>)>, path: PathBuf, what: &str) {
    for (earlier, bytes) in written.iter() {
        assert!(
            std::fs::read(earlier).unwrap() == *bytes,
            "{what} changed {}",
            earlier.display()
        );
    }
    let bytes =
        std::fs::read(&path).unwrap_or_else(|e| panic!("{what}: no {}: {e}", path.display()));
    written.push((path, bytes));
}

/// Output names: `-o NAME.png` names the PNG and puts the EXR beside it (it once wrote the PNG
/// over the EXR: "wrote out/x.png and out/x.png"), and a cached render's default name differs
/// from the plain one's, so neither overwrites the other.
#[test]
fn outputs_do_not_overwrite_each_other() {
    let d = scratch("outputs");
    let png = d.join("x.png");
    let out = render()
        .arg(repo().join("data/scenes/default.toml"))
        .args(["--spp", "1", "--width", "16", "--height", "12", "-q", "-o"])
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
        stdout.contains("x.exr") && stdout.contains("x.png"),
        "{stdout}"
    );
    assert!(hdr_image::RgbImage::read_exr(&d.join("x.exr")).is_ok());
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
    // Each method's render leaves the earlier ones' files as they were, byte for byte.
    let mut written: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    for (flags, name) in [
        (&[][..], "default.exr"),
        (&["--cache"][..], "default.cache.exr"),
        (&["--nrc"][..], "default.nrc.exr"),
    ] {
        let out = render()
            .current_dir(&d)
            .arg(repo().join("data/scenes/default.toml"))
            .args(["--spp", "1", "--width", "16", "--height", "12", "-q"])
            .args(flags)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        keep_written(
            &mut written,
            d.join("out").join(name),
            &format!("{flags:?}"),
        );
    }
}

/// `splat render` and `splat trace` name their default output after the asset (every render
/// once wrote out/splat.exr, whatever the asset), the trace apart from the raster render.
#[test]
fn splat_outputs_are_named_after_the_asset() {
    let d = scratch("splat-names");
    // Two assets, each rendered and traced: every output stays as written, byte for byte.
    let mut written: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    for (asset, sub, name) in [
        (
            "fruit_drops_minimal.ply",
            "render",
            "fruit_drops_minimal.exr",
        ),
        (
            "fruit_drops_minimal.ply",
            "trace",
            "fruit_drops_minimal.trace.exr",
        ),
        (
            "fruit_drops_minimal_inria.ply",
            "render",
            "fruit_drops_minimal_inria.exr",
        ),
        (
            "fruit_drops_minimal_inria.ply",
            "trace",
            "fruit_drops_minimal_inria.trace.exr",
        ),
    ] {
        let out = gscache()
            .current_dir(&d)
            .args(["splat", sub])
            .arg(repo().join("data/splats").join(asset))
            .args(["--width", "16", "--height", "12", "-q"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{sub}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        keep_written(
            &mut written,
            d.join("out").join(name),
            &format!("{sub} {asset}"),
        );
    }
}

#[test]
fn short_help_is_short_and_long_help_lists_the_cache_settings_grouped() {
    let help = |flag: &str| {
        let out = render().arg(flag).output().unwrap();
        assert!(out.status.success());
        String::from_utf8(out.stdout).unwrap()
    };
    let (short, long) = (help("-h"), help("--help"));
    // Measured: 45 lines against 166 before the cache settings left the short help.
    assert!(
        short.lines().count() < 60,
        "{} lines",
        short.lines().count()
    );
    assert!(!short.contains("--cache-levels") && !short.contains("--nrc-grid-levels"));
    assert!(short.contains("--cache") && short.contains("listed by --help"));
    for heading in [
        "Gaussian cache settings",
        "Neural cache settings",
        "Feature buffers and denoising",
    ] {
        assert!(long.contains(heading), "--help lacks `{heading}`");
    }
    assert!(long.contains("--cache-levels") && long.contains("--nrc-grid-levels"));
}

/// A volume file renders with no TOML: a scene is chosen for it, the image shows the data
/// (not just the background), and the scene saved with --save-scene renders the same image.
#[test]
fn a_volume_file_renders_with_a_chosen_scene_that_can_be_saved() {
    let d = scratch("auto");
    let size = ["--spp", "2", "--width", "64", "--height", "48", "-q"];
    for volume in [
        "data/fixtures/neghip.nii.gz",
        "data/fixtures/headsq_gzip.nrrd",
        "data/volumes/original/hydrogen.vti",
        "data/volumes/ironProt_68x68x68_uint8.raw",
    ] {
        let name = Path::new(volume)
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let (exr, scene) = (
            d.join(format!("{name}.exr")),
            d.join(format!("{name}.toml")),
        );
        let out = render()
            .arg(repo().join(volume))
            .args(size)
            .arg("-o")
            .arg(&exr)
            .arg("--save-scene")
            .arg(&scene)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{volume}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let image = hdr_image::RgbImage::read_exr(&exr).unwrap();
        // The corner is background (the environment); 2.5% of the pixels or more differ from
        // it by 10%: the volume is in the frame and visible (measured at 64x48: 5% for
        // hydrogen's small orbital to 23% for the head; a black or empty image has 0).
        let bg = image.get(0, 0);
        let shown = image
            .pixels()
            .iter()
            .filter(|p| (**p - bg).abs().max_element() > 0.1 * bg.max_element())
            .count();
        assert!(
            shown * 40 > image.pixels().len(),
            "{volume}: only {shown} pixels show the volume"
        );
        // The saved scene is the one rendered.
        let again = d.join(format!("{name}.again.exr"));
        let out = render()
            .arg(&scene)
            .args(size)
            .arg("-o")
            .arg(&again)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(
            image,
            hdr_image::RgbImage::read_exr(&again).unwrap(),
            "{volume}"
        );
    }
    // The saved scene may not replace the volume it describes.
    let volume = d.join("copy.nii.gz");
    std::fs::copy(repo().join("data/fixtures/neghip.nii.gz"), &volume).unwrap();
    let before = std::fs::read(&volume).unwrap();
    let out = render()
        .arg(&volume)
        .arg("--save-scene")
        .arg(&volume)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("the volume being rendered"));
    assert_eq!(std::fs::read(&volume).unwrap(), before);
    // The volume-only flags are refused with a scene, and a colour map must exist.
    let out = render()
        .arg(repo().join("data/scenes/default.toml"))
        .args(["--colormap", "viridis"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("a scene already"));
    let out = render()
        .arg(repo().join("data/fixtures/neghip.nii.gz"))
        .args(["--colormap", "jet"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("viridis"));
}

// `--denoise` and `--features` end to end: the feature layers in the EXR, the denoiser wired to
// the render (its error falls as measured), and the message where Open Image Denoise is
// missing. The test that needs the library is ignored by default (a user without it sees
// "ignored", not a pass); CI installs it and runs it with `--ignored`.

/// `gscache render` of the default scene at 160x90 with `args`.
fn render_small(args: &[&str]) -> Command {
    let mut c = render();
    c.arg(repo().join("data/scenes/default.toml"))
        .args(["--width", "160", "--height", "90", "--threads", "2", "-q"])
        .args(args);
    c
}

fn read(path: &Path) -> Vec<glam::Vec3> {
    hdr_image::RgbImage::read_exr(path)
        .unwrap_or_else(|e| panic!("{e}"))
        .into_pixels()
}

#[test]
fn denoise_without_the_library_says_how_to_install_it() {
    let d = scratch("missing");
    let out = render_small(&["--spp", "1", "--denoise", "-o"])
        .arg(d.join("x.exr"))
        .env("GSCACHE_OIDN", "/nonexistent/libOpenImageDenoise.so.2")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    // A refusal (exit 1), not a crash (101, or a signal), before any rendering: nothing written.
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--denoise") && err.contains("pip install pyoidn"),
        "{err}"
    );
    assert!(!d.join("x.exr").exists() && !d.join("x.denoised.exr").exists());
}

#[test]
fn features_are_written_as_named_layers() {
    let d = scratch("layers");
    let exr = d.join("f.exr");
    let out = render_small(&["--spp", "2", "--features", "-o"])
        .arg(&exr)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta = exr::meta::MetaData::read_from_file(&exr, false).unwrap();
    let names: Vec<String> = meta.headers[0]
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    for want in [
        "R",
        "G",
        "B",
        "albedo.R",
        "albedo.G",
        "albedo.B",
        "N.X",
        "N.Y",
        "N.Z",
        "Z",
        "coverage.A",
    ] {
        assert!(
            names.iter().any(|n| n == want),
            "{want} missing from {names:?}"
        );
    }
    // The colour is the plain render's, bit for bit: features draw no random numbers.
    let plain = d.join("p.exr");
    assert!(
        render_small(&["--spp", "2", "-o"])
            .arg(&plain)
            .status()
            .unwrap()
            .success()
    );
    assert_eq!(read(&exr), read(&plain));
}

#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn denoising_the_default_scene_cuts_its_error() {
    let d = scratch("wired");
    let reference = d.join("ref.exr");
    assert!(
        render_small(&["--spp", "256", "-o"])
            .arg(&reference)
            .status()
            .unwrap()
            .success()
    );
    let noisy = d.join("x.exr");
    let out = render_small(&["--spp", "1", "--seed", "7", "--denoise", "-o"])
        .arg(&noisy)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = read(&reference);
    let before = image_metrics::rel_mse(&read(&noisy), &r);
    let after = image_metrics::rel_mse(&read(&d.join("x.denoised.exr")), &r);
    assert!(d.join("x.denoised.png").is_file());
    // Measured at 160x90 with seed 7 (OIDN 2.5.1, high quality, guided by the albedo): 0.106
    // raw and 0.0068 denoised, 15.5x, the 256-spp reference's own noise included. Required:
    // 10x, a margin for other CPUs' arithmetic; a denoiser that was not run (1x), or ran on
    // another image, cannot reach it.
    eprintln!("relMSE at 1 spp: {before:.4} raw, {after:.4} denoised");
    assert!(after * 10.0 < before, "relMSE {before} -> {after}");
}

/// A cached render that will be denoised takes error-aware termination's settings
/// (`CacheConfig::for_denoiser`) unless the command line names one of them: its raw image is
/// the one those flags give by hand, bit for bit, and naming one keeps the user's choice.
#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn a_denoised_cached_render_reads_the_cache_only_where_it_has_earned_trust() {
    let d = scratch("denoised_cache");
    let cached = [
        "--cache", "--warmup", "4", "--frames", "4", "--seed", "3", "-o",
    ];
    let run = |name: &str, extra: &[&str]| {
        let exr = d.join(name);
        let out = render_small(extra).args(cached).arg(&exr).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{err}");
        (read(&exr), err)
    };
    let (denoised, note) = run("a.exr", &["--denoise"]);
    assert!(note.contains("earned trust"), "{note}");
    let trust = [
        "--cache-min-coverage",
        "0.5",
        "--cache-max-bias",
        "0.03",
        "--cache-handoff-frames",
        "2",
    ];
    let (by_hand, quiet) = run("b.exr", &trust);
    assert!(!quiet.contains("earned trust"), "{quiet}");
    assert!(
        denoised == by_hand,
        "the denoised render's raw image is the trusted cache's"
    );
    let (named, quiet) = run("c.exr", &["--denoise", "--cache-max-bias", "0"]);
    let (plain, _) = run("d.exr", &["--cache-max-bias", "0"]);
    assert!(!quiet.contains("earned trust"), "{quiet}");
    assert!(
        named == plain && named != by_hand,
        "a named setting is the user's"
    );
}

/// `render --cache --cache-unbiased true` renders the unbiased cache and prints, per level, the
/// most any q could gain there (gs-cache's crate docs); its bad settings are named.
#[test]
fn the_unbiased_cache_renders_and_reports_its_bound() {
    let d = scratch("unbiased");
    let exr = d.join("u.exr");
    let scene = repo().join("data/scenes/hydrogen.toml");
    let out = gscache()
        .arg("render")
        .arg(&scene)
        .args(["--width", "48", "--height", "32", "--spp", "1", "--cache"])
        .args(["--cache-unbiased", "true", "--warmup", "4"])
        .args(["--frames", "8", "-q", "-o"])
        .arg(&exr)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    for level in 1..=3 {
        assert!(
            err.contains(&format!("unbiased cache, level {level}: mean q"))
                && err.contains("no q can gain more than"),
            "{err}"
        );
    }
    let image = hdr_image::RgbImage::read_exr(&exr).unwrap();
    assert!(image.pixels().iter().all(|p| p.is_finite()));
    for (args, expected) in [
        (["--cache-min-continuation", "0"], "min_continuation"),
        (["--cache-continuation-scale", "-1"], "continuation_scale"),
    ] {
        assert_refused(
            &scene,
            &["--cache", "--cache-unbiased", "true"],
            &args,
            expected,
            &d,
        );
    }
}

/// The cached renders are the same bytes on 1 and 3 threads: both caches train in parallel
/// (the Gaussian cache's levels side by side, each level's parts by rows and tiles, adaptive
/// density's choices from the rasteriser's sums), and nothing of that may show in the image. Cold caches, so the warm start and the fallback's
/// first verdicts run too.
#[test]
fn cached_renders_are_the_same_bytes_on_any_thread_count() {
    let d = scratch("cached-threads");
    let scene = repo().join("data/scenes/default.toml");
    let runs: [&[&str]; 5] = [
        &["--cache", "--warmup", "0", "--frames", "6"],
        // Adaptive density: its passes split and drop Gaussians every other frame.
        &[
            "--cache",
            "--cache-densify-every",
            "2",
            "--cache-densify-bias",
            "0",
            "--warmup",
            "4",
            "--frames",
            "4",
        ],
        &[
            "--cache",
            "--cache-lookup",
            "rt",
            "--warmup",
            "2",
            "--frames",
            "3",
        ],
        &[
            "--cache",
            "--cache-unbiased",
            "true",
            "--warmup",
            "2",
            "--frames",
            "3",
        ],
        &["--nrc", "--warmup", "2", "--frames", "3"],
    ];
    for args in runs {
        let bytes: Vec<Vec<u8>> = ["1", "3"]
            .iter()
            .map(|threads| {
                let exr = d.join(format!("t{threads}.exr"));
                let out = render()
                    .arg(&scene)
                    .args(args)
                    .args(["--width", "96", "--height", "54", "--spp", "1", "-q"])
                    .args(["--threads", threads])
                    .arg("-o")
                    .arg(&exr)
                    .output()
                    .unwrap();
                assert!(
                    out.status.success(),
                    "{args:?}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
                std::fs::read(&exr).unwrap()
            })
            .collect();
        assert!(bytes[0] == bytes[1], "{args:?}: 1 and 3 threads differ");
    }
}

// Issue 48, first item: no library is loaded from the folder the program runs in. A folder
// that ships a `pyoidn` package (with its distribution metadata, and a "library" whose
// initialiser writes a marker file) stands for an unpacked dataset or a cloned repository.

/// A hostile folder: `pyoidn/` with a library whose constructor writes `marker` (compiled with
/// the system's C compiler where there is one; else a file that is no library, which the old
/// loader still tried to open and named in its error). Returns (folder, marker, compiled).
fn hostile_folder(name: &str) -> (PathBuf, PathBuf, bool) {
    let d = scratch(name);
    let marker = d.join("constructor-ran");
    let lib = d.join("pyoidn/oidn/lib");
    std::fs::create_dir_all(&lib).unwrap();
    std::fs::write(d.join("pyoidn/__init__.py"), "").unwrap();
    let info = d.join("pyoidn-2.5.1.0.dist-info");
    std::fs::create_dir_all(&info).unwrap();
    std::fs::write(
        info.join("METADATA"),
        "Metadata-Version: 2.1\nName: pyoidn\nVersion: 2.5.1.0\n",
    )
    .unwrap();
    let so = lib.join("libOpenImageDenoise.so.2");
    let source = d.join("evil.c");
    std::fs::write(
        &source,
        format!(
            "#include <stdio.h>\n__attribute__((constructor)) static void ran(void) {{ FILE *f = fopen(\"{}\", \"w\"); if (f) {{ fputs(\"ran\", f); fclose(f); }} }}\n",
            marker.display()
        ),
    )
    .unwrap();
    let compiled = Command::new("cc")
        .args(["-shared", "-fPIC", "-o"])
        .arg(&so)
        .arg(&source)
        .status()
        .is_ok_and(|s| s.success());
    if !compiled {
        std::fs::write(&so, b"not a library").unwrap();
    }
    (d, marker, compiled)
}

#[test]
fn a_pyoidn_in_the_working_folder_is_never_loaded() {
    let (d, marker, compiled) = hostile_folder("hostile-cwd");
    let out = render_small(&["--spp", "1", "--denoise", "-o"])
        .arg(d.join("x.exr"))
        .env_remove("GSCACHE_OIDN")
        .current_dir(&d)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    eprintln!("compiled a constructor: {compiled}\n{err}");
    assert!(!marker.exists(), "the folder's library ran: {err}");
    // Whether or not this machine has the real library, the folder's copy is never tried (the
    // folder itself is named where the real one denoised: `wrote .../x.denoised.exr`).
    assert!(!err.contains("cannot use it"), "{err}");
    assert!(!err.contains(&*d.join("pyoidn").to_string_lossy()), "{err}");
}

#[test]
fn the_viewer_loads_the_denoiser_only_when_first_used() {
    let (d, marker, compiled) = hostile_folder("lazy-view");
    if !compiled {
        eprintln!("no C compiler: the constructor cannot be built; nothing to observe");
        return;
    }
    // Named by GSCACHE_OIDN: the user's explicit choice, loaded, but only when asked for.
    let mut child = Command::new(env!("CARGO_BIN_EXE_gscache"))
        .arg("view")
        .arg(repo().join("data/scenes/default.toml"))
        .args(["--port", "0", "--width", "64", "--height", "48", "--output"])
        .arg(d.join("out"))
        .env("GSCACHE_OIDN", d.join("pyoidn/oidn/lib"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufRead::read_line(
        &mut std::io::BufReader::new(child.stdout.take().unwrap()),
        &mut line,
    )
    .unwrap();
    let started = line.starts_with("http://");
    let ran = marker.exists();
    let _ = child.kill();
    let _ = child.wait();
    assert!(started, "no URL: {line:?}");
    assert!(!ran, "the viewer loaded the denoiser at start-up");
}

/// Issue 48, second item: an output that links to a device is refused before any work, the
/// link is kept, and no PNG is written beside it.
#[cfg(unix)]
#[test]
fn an_output_that_is_a_device_is_refused() {
    let d = scratch("device-output");
    let link = d.join("x.exr");
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    let out = render_small(&["--spp", "1", "-o"])
        .arg(&link)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("device") && err.contains("regular file"),
        "{err}"
    );
    assert!(
        std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    let names: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["x.exr"]);
}

/// Issue 51, item 6: the warm-up orbit has one name, `--warmup-orbit-degrees` (the experiment
/// files' `warmup_orbit_degrees`); the old `--warmup-orbit` still works and renders the same
/// bytes.
#[test]
fn the_old_warmup_orbit_flag_is_an_alias() {
    let d = scratch("orbit-alias");
    for (flag, name) in [("--warmup-orbit-degrees", "new"), ("--warmup-orbit", "old")] {
        let out = render_small(&[
            "--cache", "--spp", "1", "--warmup", "3", "--frames", "1", flag, "30", "-o",
        ])
        .arg(d.join(format!("{name}.exr")))
        .output()
        .unwrap();
        assert!(
            out.status.success(),
            "{flag}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert_eq!(
        std::fs::read(d.join("new.exr")).unwrap(),
        std::fs::read(d.join("old.exr")).unwrap()
    );
}
