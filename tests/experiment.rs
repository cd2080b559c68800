//! The experiment runner end to end on a tiny experiment (bundled neghip, 48x27): every file
//! is written, every number is finite, the reference is reused by a second run, and bad files
//! are refused with a message naming the fault.

use std::path::{Path, PathBuf};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gscache-exp-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn tiny_experiment(dir: &Path) -> PathBuf {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/scenes/default.toml");
    let text = format!(
        r#"
name = "tiny"
scene = "{}"
width = 48
height = 27
seeds = [1, 2, 3]
output = "out"
[reference]
spp = 64
dir = "{}"
[budgets]
spp = [1, 8]
seconds = [0.02]
[[method]]
name = "nee"
integrator = "nee"
[[method]]
name = "cache raster"
integrator = "nee"
cache = {{ points = 2000, warmup = 4 }}
[[flythrough]]
name = "light moves"
frames = 8
warmup = 2
error_every = 3
reference_spp = 16
[[flythrough.event]]
frame = 5
light_offset = [0.3, 0.0, 0.0]
[[flythrough]]
name = "path"
frames = 3
methods = ["nee"]
error_every = 1
reference_spp = 16
[[flythrough.key]]
frame = 0
eye = [60.0, 45.0, 95.0]
target = [0.0, 0.0, 0.0]
[[flythrough.key]]
frame = 2
eye = [-60.0, 45.0, 95.0]
target = [0.0, 5.0, 0.0]
[[ablation]]
name = "C"
method = "cache raster"
parameter = "c"
values = [0.0, 1.0]
budgets = {{ spp = [2] }}
"#,
        scene.display(),
        dir.join("refs").display()
    );
    let path = dir.join("tiny.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn tiny_experiment_writes_everything_and_reuses_its_reference() {
    let dir = scratch("tiny");
    let file = tiny_experiment(&dir);
    let quiet = |_: &str| {};
    let first = experiments::run_experiment(&file, None, &quiet).unwrap();
    let out = dir.join("out");
    for f in [
        "runs.csv",
        "summary.csv",
        "ablations.csv",
        "flythrough.csv",
        "results.json",
        "report.md",
        "plots/error_vs_time.png",
        "plots/error_vs_time.svg",
        "plots/images_0.jpg",
        "plots/images_1.jpg",
        "plots/cache_levels.png",
        "plots/loss_0.png",
        "plots/flythrough_0_time.png",
        "plots/flythrough_0_error.png",
        "plots/flythrough_1_time.png",
        "plots/ablation_0.png",
        "plots/ablation_0_time.png",
    ] {
        let p = out.join(f);
        assert!(
            std::fs::metadata(&p).map(|m| m.len() > 0).unwrap_or(false),
            "{} missing or empty",
            p.display()
        );
    }
    assert!(!first.reference.reused);
    // 2 methods x 3 budgets x 3 seeds, plus 2 ablation values x 1 budget x 3 seeds.
    let runs = std::fs::read_to_string(out.join("runs.csv")).unwrap();
    assert_eq!(runs.lines().count(), 1 + 18 + 6, "{runs}");
    assert_eq!(first.runs.len(), 18 + 6);
    for r in &first.runs {
        assert!(
            r.rel_mse.is_finite() && r.psnr_hdr.is_finite() && r.smape.is_finite(),
            "{r:?}"
        );
        assert!(r.seconds > 0.0 && r.efficiency.is_finite() && r.nonfinite_samples == 0);
    }
    for s in &first.summary {
        let b = s.bias.expect("3 seeds give a bias estimate");
        assert!(
            b.rel_bias_sq.is_finite() && b.brightness.is_finite(),
            "{s:?}"
        );
    }
    // NEE's error falls with samples: 8 spp against 1 spp (variance ~1/spp; the means over 3
    // seeds are far apart at this size).
    let nee = |spp| {
        first
            .summary
            .iter()
            .find(|s| s.method == "nee" && s.budget == experiments::records::Budget::Spp(spp))
            .unwrap()
            .rel_mse
    };
    assert!(nee(8) < 0.5 * nee(1), "{} vs {}", nee(8), nee(1));
    // The fly-through evaluated frames before and after the light moved.
    let evaluated: Vec<u32> = first
        .flythroughs
        .iter()
        .filter(|f| f.method == "cache raster" && f.rel_mse.is_some())
        .map(|f| f.frame)
        .collect();
    assert!(evaluated.contains(&0) && evaluated.contains(&5) && evaluated.contains(&9));
    // The key-framed path: every frame evaluated against its own view's reference.
    let path: Vec<_> = first
        .flythroughs
        .iter()
        .filter(|f| f.flythrough == "path")
        .collect();
    assert_eq!(path.len(), 3);
    assert!(
        path.iter()
            .all(|f| f.method == "nee" && f.rel_mse.is_some_and(|e| e.is_finite() && e > 0.0))
    );
    // Without a time budget a frame is one pass.
    assert!(first.flythroughs.iter().all(|f| f.passes == 1));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(json["summary"].as_array().unwrap().len(), 6);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Ablation `C`") && report.contains("plots/error_vs_time.png"));

    let reference = first.reference.file.clone();
    let modified = std::fs::metadata(&reference).unwrap().modified().unwrap();
    let second = experiments::run_experiment(&file, None, &quiet).unwrap();
    assert!(second.reference.reused);
    assert_eq!(second.reference.file, reference);
    assert_eq!(
        std::fs::metadata(&reference).unwrap().modified().unwrap(),
        modified
    );
    // A kept reference with a NaN pixel is rendered again, not reused (it once gave relMSE
    // NaN, PSNR 2760 dB and an efficiency of 1e300).
    let mut damaged = hdr_image::RgbImage::read_exr(&reference).unwrap();
    damaged.pixels_mut()[5] = glam::Vec3::new(f32::NAN, 0.0, 0.0);
    damaged.write_exr(&reference).unwrap();
    let third = experiments::run_experiment(&file, None, &quiet).unwrap();
    assert!(!third.reference.reused);
    assert!(
        third
            .runs
            .iter()
            .all(|r| r.rel_mse.is_finite() && r.psnr_hdr < 200.0)
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_experiment_files_are_refused_with_the_fault_named() {
    let dir = scratch("bad");
    let file = tiny_experiment(&dir);
    let text = std::fs::read_to_string(&file).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        text.replace("parameter = \"c\"", "parameter = \"cc\""),
    )
    .unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gscache"))
        .arg("experiment")
        .arg(&bad)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("bad.toml") && err.contains("`cc` is not a cache setting"),
        "{err}"
    );
    let missing = dir.join("missing.toml");
    std::fs::write(&missing, text.replace("default.toml", "nowhere.toml")).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gscache"))
        .arg("experiment")
        .arg(&missing)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("nowhere.toml"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Runs `gscache` with a report's command line `args`, writing `-o exr`, and counts the pixels
/// of `read` (the image written, or its denoised twin) whose bits differ from `want`.
fn pixels_differing_from_the_line(
    args: &[String],
    exr: &Path,
    read: &Path,
    want: &[glam::Vec3],
) -> usize {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gscache"))
        .args(args)
        .args(["-q", "-o"])
        .arg(exr)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let got = hdr_image::RgbImage::read_exr(read).unwrap().into_pixels();
    assert_eq!(got.len(), want.len());
    got.iter()
        .zip(want)
        .filter(|(a, b)| a.to_array().map(f32::to_bits) != b.to_array().map(f32::to_bits))
        .count()
}

/// The report gives, per method, a `gscache render` line that renders its image at any spp:
/// that line must give the runner's own image at every budget, bit for bit, a time budget
/// included (for a cache: after the same warm-up along the same orbit). This is the one
/// sampling rule at work: frame `k` of `s` spp takes sample indices `k*s .. (k+1)*s`.
#[test]
fn the_reports_command_line_renders_the_runners_image_at_every_budget() {
    use experiments::command::render_args;
    use experiments::measure::run_method;
    use experiments::records::Budget;
    let dir = scratch("command");
    let file = tiny_experiment(&dir);
    let exp = experiments::load_experiment(&file).unwrap();
    let mut scene = volume_pt::load_scene(&exp.scene).unwrap();
    let (w, h) = exp.size.unwrap();
    scene.camera.width = w;
    scene.camera.height = h;
    let seed = exp.seeds[1];
    assert!(exp.methods.iter().any(|m| m.cache.gaussian().is_some()));
    assert!(exp.methods.iter().any(|m| !m.has_cache()));
    let budgets = [Budget::Spp(1), Budget::Spp(3), Budget::Seconds(0.005)];
    for method in &exp.methods {
        let (snaps, _) = run_method(
            &scene,
            method,
            seed,
            &budgets,
            None,
            &mut experiments::denoised::Denoisers::new(),
        )
        .unwrap();
        assert_eq!(snaps.len(), budgets.len());
        for snap in &snaps {
            let exr = dir.join(format!(
                "{}-{}.exr",
                method.name.replace(' ', "_"),
                snap.spp
            ));
            let args = render_args(
                &exp.scene,
                w,
                h,
                method,
                exp.denoise.as_ref(),
                seed,
                snap.spp,
            );
            let differing = pixels_differing_from_the_line(&args, &exr, &exr, &snap.image);
            assert_eq!(
                differing, 0,
                "method `{}` at {} ({} spp): {differing} pixels differ",
                method.name, snap.budget, snap.spp
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// The tiny experiment in 3 shards (one through the program on 1 thread), merged: every
/// spp-budget metric, seed spread and bias, and every fly-through error has the one-process
/// run's bits. A missing, doubled or stale shard is refused.
#[test]
fn sharded_experiment_merges_to_the_one_process_results() {
    use experiments::records::Budget;
    let dir = scratch("shards");
    let file = tiny_experiment(&dir);
    let quiet = |_: &str| {};
    let whole = experiments::run_experiment(&file, None, &quiet).unwrap();
    let part = |i: u32| dir.join(format!("shard-{i}.json"));
    for i in [0, 2] {
        let shard = volume_pt::Shard::new(i, 3).unwrap();
        experiments::run_experiment_shard(&file, shard, &part(i), &quiet).unwrap();
    }
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gscache"))
        .args(["-q", "--threads", "1", "experiment"])
        .arg(&file)
        .args(["--shard", "1/3", "--shard-output"])
        .arg(part(1))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let parts = [part(2), part(0), part(1)];
    let merged_dir = dir.join("merged");
    let merged = experiments::merge_experiment(&file, &parts, Some(&merged_dir), &quiet).unwrap();
    assert!(merged_dir.join("report.md").exists());
    assert_eq!(merged.runs.len(), whole.runs.len());
    let mut compared = 0;
    for (a, b) in whole.runs.iter().zip(&merged.runs) {
        assert_eq!((&a.method, a.budget, a.seed), (&b.method, b.budget, b.seed));
        if matches!(a.budget, Budget::Spp(_)) {
            assert_eq!(a.spp, b.spp);
            for (x, y) in [
                (a.rel_mse, b.rel_mse),
                (a.psnr_hdr, b.psnr_hdr),
                (a.psnr_tonemapped, b.psnr_tonemapped),
                (a.smape, b.smape),
            ] {
                assert_eq!(x.to_bits(), y.to_bits(), "{a:?} vs {b:?}");
            }
            compared += 1;
        }
    }
    assert_eq!(
        compared,
        12 + 6,
        "2 methods x 2 spp budgets x 3 seeds + the ablation's 6"
    );
    for (a, b) in whole.summary.iter().zip(&merged.summary) {
        if matches!(a.budget, Budget::Spp(_)) {
            assert_eq!(a.rel_mse.to_bits(), b.rel_mse.to_bits(), "{}", a.method);
            assert_eq!(a.rel_mse_sd.to_bits(), b.rel_mse_sd.to_bits());
            let (x, y) = (a.bias.unwrap(), b.bias.unwrap());
            assert_eq!(x.rel_bias_sq.to_bits(), y.rel_bias_sq.to_bits());
            assert_eq!(x.brightness.to_bits(), y.brightness.to_bits());
        }
    }
    assert_eq!(whole.flythroughs.len(), merged.flythroughs.len());
    let errors = |r: &experiments::Results| -> Vec<Option<u64>> {
        r.flythroughs
            .iter()
            .map(|f| f.rel_mse.map(f64::to_bits))
            .collect()
    };
    assert_eq!(errors(&whole), errors(&merged));
    assert!(errors(&whole).iter().flatten().count() > 0);

    let merge = |files: &[PathBuf]| {
        experiments::merge_experiment(&file, files, Some(&merged_dir), &quiet)
            .unwrap_err()
            .to_string()
    };
    let e = merge(&[part(0), part(1)]);
    assert!(e.contains("are missing"), "{e}");
    let e = merge(&[part(0), part(1), part(2), part(1)]);
    assert!(e.contains("given twice"), "{e}");
    // The experiment file changed after the shards ran: they are stale.
    let text = std::fs::read_to_string(&file).unwrap();
    std::fs::write(
        &file,
        text.replace("seeds = [1, 2, 3]", "seeds = [1, 2, 4]"),
    )
    .unwrap();
    let e = merge(&parts);
    assert!(e.contains("another version of the experiment"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A shard file is checked before it is merged: a flipped byte fails its checksum, and behind
/// the checksum (the file re-signed after the edit, as a careless script might) every value is
/// checked as a fresh measurement would be, so a short image, a NaN pixel, a negative time, a
/// 0-spp snapshot or a deleted snapshot is refused with the file and the unit, never panicked
/// on or merged into a silently wrong table.
#[test]
fn tampered_shard_files_are_refused() {
    use experiments::records::Budget;
    use experiments::units::{ShardFile, UnitResult};
    let dir = scratch("tampered");
    let file = tiny_experiment(&dir);
    let quiet = |_: &str| {};
    let whole = dir.join("all.json");
    experiments::run_experiment_shard(&file, volume_pt::Shard::new(0, 1).unwrap(), &whole, &quiet)
        .unwrap();
    let merge = |p: &Path| {
        experiments::merge_experiment(&file, &[p.to_path_buf()], Some(&dir.join("m")), &quiet)
            .map(|_| ())
            .map_err(|e| format!("{e:#}"))
    };
    merge(&whole).expect("the untouched shard merges");
    // One byte flipped inside an image's base64: the checksum no longer matches.
    let text = std::fs::read_to_string(&whole).unwrap();
    let at = text.find("\"image\":\"").unwrap() + 20;
    let mut flipped = text.into_bytes();
    flipped[at] = if flipped[at] == b'A' { b'B' } else { b'A' };
    let path = dir.join("flipped.json");
    std::fs::write(&path, flipped).unwrap();
    let e = merge(&path).unwrap_err();
    assert!(e.contains("flipped.json") && e.contains("checksum"), "{e}");
    // The checksum removed (issue 48, item 11: it was said not to match): said missing.
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&whole).unwrap()).unwrap();
    json.as_object_mut().unwrap().remove("checksum").unwrap();
    let path = dir.join("unsigned.json");
    std::fs::write(&path, json.to_string()).unwrap();
    let e = merge(&path).unwrap_err();
    assert!(
        e.contains("unsigned.json") && e.contains("checksum is missing"),
        "{e}"
    );
    // Edits re-signed by `write`: the values behind the checksum are checked.
    type Edit = fn(&mut ShardFile);
    fn first_method(f: &mut ShardFile) -> &mut Vec<experiments::records::Snapshot> {
        f.units
            .iter_mut()
            .find_map(|(_, u)| match u {
                UnitResult::Method { snapshots, .. } => Some(snapshots),
                _ => None,
            })
            .unwrap()
    }
    let cases: [(Edit, &str); 6] = [
        (
            |f| {
                first_method(f)[0].image.pop();
            },
            "1295 pixels",
        ),
        (|f| first_method(f)[0].image[7].y = f32::NAN, "pixel 7"),
        (|f| first_method(f)[1].image[3].x = -1.0, "pixel 3"),
        (|f| first_method(f)[0].seconds = -1.0, "-1"),
        (|f| first_method(f)[2].spp = 0, "0 spp"),
        (
            |f| {
                first_method(f).retain(|s| s.budget != Budget::Spp(8));
            },
            "budget 8 spp",
        ),
    ];
    for (i, (edit, needle)) in cases.into_iter().enumerate() {
        let mut f = ShardFile::read(&whole).unwrap();
        edit(&mut f);
        let path = dir.join(format!("edit{i}.json"));
        f.write(&path).unwrap();
        let e = merge(&path).unwrap_err();
        assert!(
            e.contains(&format!("edit{i}.json")) && e.contains("unit 0") && e.contains(needle),
            "case {i}: {e}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A resumed run's rows are the one-process run's: the same units in the same order, and the
/// same relMSE bits at every spp budget (time budgets depend on the machine's speed).
fn assert_same_runs(whole: &experiments::Results, resumed: &experiments::Results) {
    use experiments::records::Budget;
    assert_eq!(resumed.runs.len(), whole.runs.len());
    for (a, b) in whole.runs.iter().zip(&resumed.runs) {
        assert_eq!((&a.method, a.budget, a.seed), (&b.method, b.budget, b.seed));
        if matches!(a.budget, Budget::Spp(_)) {
            assert_eq!(a.rel_mse.to_bits(), b.rel_mse.to_bits(), "{a:?}");
        }
    }
}

/// Ctrl-C stops an experiment between units and keeps what it measured; `--resume` goes on
/// from there, and the result has the one-process run's relMSE bits at every spp budget (as a
/// shard merge has). Here the stop comes after the first method's three seeds.
#[test]
fn an_interrupted_experiment_keeps_its_units_and_resumes() {
    use std::sync::atomic::{AtomicBool, Ordering};
    let dir = scratch("resume");
    let file = tiny_experiment(&dir);
    let quiet = |_: &str| {};
    let whole = experiments::run_experiment(&file, None, &quiet).unwrap();
    let cancel = AtomicBool::new(false);
    let stop_after_first_method = |line: &str| {
        if line.ends_with(" runs") {
            cancel.store(true, Ordering::SeqCst);
        }
    };
    let control = volume_pt::Control::cancellable(&cancel);
    let out = dir.join("stopped");
    let e = experiments::run_experiment_resumable(
        &file,
        Some(&out),
        &stop_after_first_method,
        &control,
        None,
    )
    .unwrap_err();
    let experiments::Error::Interrupted(stopped) = &e else {
        panic!("{e}")
    };
    assert_eq!(stopped.done, 3, "{stopped}");
    assert!(stopped.to_string().contains("--resume"), "{stopped}");
    let resumed = experiments::run_experiment_resumable(
        &file,
        Some(&out),
        &quiet,
        &volume_pt::Control::none(),
        Some(&stopped.file),
    )
    .unwrap();
    assert_same_runs(&whole, &resumed);
    // A resume file from another version of the experiment is refused.
    std::fs::write(
        &file,
        std::fs::read_to_string(&file)
            .unwrap()
            .replace("seeds = [1, 2, 3]", "seeds = [1, 2, 4]"),
    )
    .unwrap();
    let e = experiments::run_experiment_resumable(
        &file,
        Some(&out),
        &quiet,
        &volume_pt::Control::none(),
        Some(&stopped.file),
    )
    .unwrap_err();
    assert!(format!("{e:#}").contains("another version"), "{e:#}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 48, item 8: a run killed outright (SIGKILL: the out-of-memory killer, SLURM's hard
/// kill) wrote no `interrupted-units.json` and started again from nothing. Each unit is now on
/// disk as it finishes (`finished-units/`), and `--resume OUTPUT` goes on from there to the
/// one-process run's relMSE bits.
#[cfg(unix)]
#[test]
fn a_killed_experiment_resumes_from_its_finished_units() {
    let dir = scratch("killed");
    let file = tiny_experiment(&dir);
    let quiet = |_: &str| {};
    // Also makes the shared reference, so the killed run starts measuring at once.
    let whole = experiments::run_experiment(&file, None, &quiet).unwrap();
    let out = dir.join("killed-out");
    let units = out.join(experiments::UNITS_FOLDER);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_gscache"))
        .args(["-q", "experiment"])
        .arg(&file)
        .arg("--output")
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    // Whole unit files only (not the atomic writer's temporary names).
    let finished = |dir: &Path| {
        std::fs::read_dir(dir).map_or(0, |d| {
            d.filter(|e| {
                e.as_ref()
                    .is_ok_and(|e| e.file_name().to_string_lossy().starts_with("unit-"))
            })
            .count()
        })
    };
    while finished(&units) == 0 {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before any unit was seen"
        );
        assert!(
            started.elapsed().as_secs() < 300,
            "no unit finished in 300 s"
        );
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL: no handler runs
    child.wait().unwrap();
    let kept = finished(&units);
    assert!(!out.join("interrupted-units.json").exists());
    assert!((1..9).contains(&kept), "{kept} units on disk");
    let resumed = experiments::run_experiment_resumable(
        &file,
        Some(&out),
        &quiet,
        &volume_pt::Control::none(),
        Some(&out),
    )
    .unwrap();
    assert_same_runs(&whole, &resumed);
    // Complete: the journal is gone.
    assert!(!units.exists());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn denoised_twins_are_measured_against_the_baselines_twins() {
    let dir = scratch("denoised");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/scenes/default.toml");
    let file = dir.join("twins.toml");
    std::fs::write(
        &file,
        format!(
            r#"
scene = "{}"
width = 64
height = 36
output = "out"
denoise = true
[reference]
spp = 64
dir = "{}"
[budgets]
spp = [1]
seconds = [0.01, 0.3]
[[method]]
name = "nee"
integrator = "nee"
[[method]]
name = "uniform"
integrator = "uniform"
"#,
            scene.display(),
            dir.join("refs").display()
        ),
    )
    .unwrap();
    let exp = experiments::load_experiment(&file).unwrap();
    let r = experiments::run::run(&exp, &|_| {}).unwrap();
    let names: Vec<&str> = r.methods.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "nee",
            "nee + OIDN",
            "nee + OIDN (albedo)",
            "uniform",
            "uniform + OIDN",
            "uniform + OIDN (albedo)"
        ]
    );
    let row = |m: &str, b: experiments::records::Budget| {
        r.summary
            .iter()
            .find(|s| s.method == m && s.budget == b)
            .unwrap_or_else(|| panic!("no row for {m} at {b}"))
            .clone()
    };
    use experiments::records::Budget;
    // At 1 spp the twin denoises the same image: same spp, more time (the filter's), less error.
    let (raw, twin) = (
        row("nee", Budget::Spp(1)),
        row("nee + OIDN", Budget::Spp(1)),
    );
    assert_eq!(raw.spp, twin.spp);
    assert!(twin.seconds > raw.seconds);
    assert!(
        twin.rel_mse < raw.rel_mse,
        "{} !< {}",
        twin.rel_mse,
        raw.rel_mse
    );
    // At 0.3 s the twin renders for 0.3 s less the filter's measured cost (the plan, checked
    // here rather than by counting frames: at 64x36 the filter costs a few of ~600 frames,
    // and counts from two timed runs differ by more on a loaded machine), and its time (render
    // plus filter) comes to about the budget. At 0.01 s, less than the filter alone takes, it
    // still denoises a whole frame.
    let spec = exp.denoise.clone().expect("denoise = true");
    let mut denoisers = experiments::denoised::Denoisers::new();
    let plan = experiments::denoised::plan(&mut denoisers, &[Budget::Seconds(0.3)], &spec, 64, 36)
        .unwrap();
    let cost = denoisers
        .cost(64, 36, denoise::Guides::None, &spec)
        .unwrap();
    assert!(cost > 0.0 && cost < 0.3, "{cost}");
    let render_budget = plan
        .iter()
        .find(|p| p.0 == denoise::Guides::None)
        .map(|p| p.2)
        .unwrap();
    assert_eq!(render_budget, Budget::Seconds(0.3 - cost));
    let twin = row("nee + OIDN", Budget::Seconds(0.3));
    assert!(twin.seconds >= 0.3 * 0.9);
    let tiny = row("nee + OIDN", Budget::Seconds(0.01));
    assert!(tiny.spp >= 1.0);
    // Twins are compared with the baseline's twin with the same guides (a gain of exactly 1 for
    // the baseline's own twin), plain methods with the plain baseline.
    assert_eq!(
        row("nee + OIDN (albedo)", Budget::Spp(1)).gain_vs_baseline,
        Some(1.0)
    );
    let u = row("uniform + OIDN", Budget::Spp(1));
    let expected = row("nee + OIDN", Budget::Spp(1)).rel_mse / u.rel_mse;
    assert!((u.gain_vs_baseline.unwrap() - expected).abs() < 1e-12);
    assert!(
        r.summary
            .iter()
            .all(|s| s.flip.is_some() && s.ssim.is_some())
    );
    // The report's command line gives each twin's image bit for bit, guided ones included
    // (the runner gives the filter its guides as they are: the line must say so, since the
    // program prefilters them by default).
    for twin in ["nee + OIDN", "nee + OIDN (albedo)"] {
        let method = r.methods.iter().find(|m| m.name == twin).unwrap();
        let (_, _, want) = r
            .images
            .snapshots
            .iter()
            .find(|(m, b, _)| m == twin && *b == Budget::Spp(1))
            .unwrap();
        let exr = dir.join("twin.exr");
        let (w, h) = exp.size.unwrap();
        let args = experiments::command::render_args(
            &exp.scene,
            w,
            h,
            method,
            r.denoise.as_ref(),
            r.seeds[0],
            1,
        );
        let denoised = exr.with_extension("denoised.exr");
        let differing = pixels_differing_from_the_line(&args, &exr, &denoised, want);
        assert_eq!(differing, 0, "`{twin}`: {differing} pixels differ");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// An experiment writes under `out/experiments/NAME` of the folder it runs in unless told
/// otherwise, and the committed experiment files name no output, so running one never
/// rewrites the committed results (`--results-dir docs/results` does, when asked).
#[test]
fn experiments_write_under_out_unless_told_to_write_elsewhere() {
    let dir = scratch("default-output");
    let file = tiny_experiment(&dir);
    let text = std::fs::read_to_string(&file).unwrap();
    let unnamed = dir.join("unnamed.toml");
    std::fs::write(
        &unnamed,
        text.replace("output = \"out\"\n", "")
            .replace("name = \"tiny\"", "name = \"mine\"")
            .split("[[flythrough]]")
            .next()
            .unwrap(),
    )
    .unwrap();
    let run = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_gscache"))
            .current_dir(&dir)
            .args(["-q", "experiment"])
            .arg(&unnamed)
            .args(extra)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    run(&[]);
    let first = dir.join("out/experiments/mine/report.md");
    let report = std::fs::read(&first).unwrap();
    run(&["--results-dir", "committed"]);
    assert!(dir.join("committed/mine/report.md").is_file());
    assert!(
        std::fs::read(&first).unwrap() == report,
        "the second run rewrote the first's report"
    );
    // Every committed experiment file, in experiments/ and its folders.
    let mut files = Vec::new();
    let mut folders = vec![Path::new(env!("CARGO_MANIFEST_DIR")).join("experiments")];
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                folders.push(path);
            } else if path.extension().is_some_and(|e| e == "toml") {
                files.push(path);
            }
        }
    }
    assert!(files.len() >= 24, "{files:?}");
    for path in files {
        let table: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        if !table.contains_key("scene") {
            continue; // a scene file the experiments read (experiments/scenes), not an experiment
        }
        assert!(
            !table.contains_key("output"),
            "{} names an output folder: running it would rewrite committed results",
            path.display()
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A fly-through with a time budget per frame: a 48x27 frame (about a millisecond a pass, a few
/// more with a cache's training) holds several passes in 0.25 s, and each frame is still
/// measured against its own view's reference.
#[test]
fn a_frame_budget_fills_each_frame_with_passes() {
    let dir = scratch("budget");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/scenes/default.toml");
    let file = dir.join("budget.toml");
    std::fs::write(
        &file,
        format!(
            r#"
scene = "{}"
width = 48
height = 27
output = "out"
[reference]
spp = 16
dir = "{}"
[budgets]
spp = [1]
[[method]]
name = "nee"
integrator = "nee"
[[method]]
name = "cache"
integrator = "nee"
cache = {{ points = 2000, warmup = 2 }}
[[flythrough]]
name = "budgeted"
frames = 3
error_every = 1
reference_spp = 16
orbit_degrees = 10.0
frame_seconds = 0.25
clip_frames = 2
"#,
            scene.display(),
            dir.join("refs").display()
        ),
    )
    .unwrap();
    let r = experiments::run_experiment(&file, None, &|_: &str| {}).unwrap();
    assert_eq!(r.flythroughs.len(), 6, "3 frames of 2 methods");
    for f in &r.flythroughs {
        assert!(f.passes > 1, "{f:?}");
        assert!(f.rel_mse.is_some_and(|e| e.is_finite() && e > 0.0), "{f:?}");
        // Every frame is scored (error_every = 1): flicker from the second frame on, and the
        // closing clip's JOD on the last only, below 10 (a few spp are visibly noisy) and above
        // the scale's floor.
        assert_eq!(f.flicker.is_some(), f.frame > 0, "{f:?}");
        assert_eq!(f.jod.is_some(), f.frame == 2, "{f:?}");
        assert!(f.jod.is_none_or(|j| j > 0.0 && j < 9.9), "{f:?}");
        assert_eq!(f.denoise_ms, 0.0, "no twins without `denoise = true`");
    }
    let csv = std::fs::read_to_string(dir.join("out/flythrough.csv")).unwrap();
    assert!(
        csv.starts_with("flythrough,method,frame,warmup,passes,"),
        "{csv}"
    );
    assert!(
        csv.lines().next().unwrap().ends_with(",flip,flicker,jod"),
        "{csv}"
    );
    let report = std::fs::read_to_string(dir.join("out/report.md")).unwrap();
    assert!(report.contains("| flicker | JOD |"), "{report}");
    // A clip longer than the measured frames is refused, naming the field.
    let text = std::fs::read_to_string(&file).unwrap();
    std::fs::write(&file, text.replace("clip_frames = 2", "clip_frames = 4")).unwrap();
    let e = experiments::run_experiment(&file, None, &|_: &str| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("clip_frames = 4: expected at most the 3 measured frames"),
        "{e}"
    );
    std::fs::write(&file, text).unwrap();
    // A budget must be a positive finite number of seconds.
    let text = std::fs::read_to_string(&file)
        .unwrap()
        .replace("frame_seconds = 0.25", "frame_seconds = 0.0");
    std::fs::write(&file, text).unwrap();
    let e = experiments::run_experiment(&file, None, &|_: &str| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frame_seconds = 0: expected a finite budget > 0"),
        "{e}"
    );
}

/// A fly-through's denoised twins: every frame denoised with the denoiser's time charged to the
/// frame (the passes fill what it leaves of the budget), scored like the raw frames, and steadier
/// than them: the filter removes the frame-to-frame noise that flicker counts twice. The budget
/// holds a few passes, and the references' 1024 spp keep their own noise (which flicker counts
/// too) well below the raw frames'.
#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn a_flythroughs_twins_are_denoised_every_frame_within_its_budget() {
    let dir = scratch("fly_twins");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/scenes/default.toml");
    let file = dir.join("twins.toml");
    std::fs::write(
        &file,
        format!(
            r#"
scene = "{}"
width = 64
height = 36
output = "out"
denoise = true
denoise_guides = ["albedo"]
[reference]
spp = 16
dir = "{}"
[budgets]
spp = [1]
[[method]]
name = "nee"
integrator = "nee"
[[flythrough]]
name = "budgeted, denoised"
frames = 4
warmup = 1
reference_spp = 1024
orbit_degrees = 10.0
frame_seconds = 0.03
clip_frames = 3
denoise_quality = "fast"
"#,
            scene.display(),
            dir.join("refs").display()
        ),
    )
    .unwrap();
    let r = experiments::run_experiment(&file, None, &|_: &str| {}).unwrap();
    let of = |m: &str| -> Vec<&experiments::flythrough::FrameRecord> {
        r.flythroughs.iter().filter(|f| f.method == m).collect()
    };
    let (raw, twin) = (of("nee"), of("nee + OIDN (albedo)"));
    assert_eq!((raw.len(), twin.len()), (5, 5), "{:?}", r.flythroughs);
    for f in &twin {
        assert!(f.denoise_ms > 0.0, "{f:?}");
        assert!(f.total_ms >= f.denoise_ms + f.trace_ms - 1e-9, "{f:?}");
    }
    // Frames 0 (error_every) and 2..=4 (the clip) are scored; flicker on 3 and 4.
    let scored: Vec<u32> = twin
        .iter()
        .filter(|f| f.rel_mse.is_some())
        .map(|f| f.frame)
        .collect();
    assert_eq!(scored, [0, 2, 3, 4]);
    let flicker = |fr: &[&experiments::flythrough::FrameRecord]| -> f64 {
        fr.iter().filter_map(|f| f.flicker).sum::<f64>()
    };
    assert!(
        flicker(&twin) < 0.5 * flicker(&raw),
        "denoised {} against raw {}",
        flicker(&twin),
        flicker(&raw)
    );
    // The clip's JOD is the twin's own (at 64x36 on a Full HD display the filter's blur and the
    // noise it removes weigh about alike, so no order is asserted).
    let jod = |fr: &[&experiments::flythrough::FrameRecord]| fr[4].jod.unwrap();
    assert!(jod(&twin) != jod(&raw) && (0.0..10.0).contains(&jod(&twin)));
    std::fs::remove_dir_all(&dir).ok();
}
