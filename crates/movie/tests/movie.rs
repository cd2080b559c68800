//! Movies end to end on a small view of the bundled default scene: resuming is bit for bit,
//! folders are never overwritten, references measure what they should, and ffmpeg makes a
//! playable video (when it is installed, as CI installs it).

use movie::{
    FrameBudget, MovieError, MovieFolder, MoviePath, MovieSpec, MovieSummary, Progress,
    VideoFormat, encode_video, render_movie,
};
use render_session::{CacheChoice, Control};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use volume_pt::Scene;

fn scene() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/scenes/default.toml");
    let mut s = volume_pt::load_scene(&path).unwrap();
    s.camera.width = 32;
    s.camera.height = 18;
    s
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gscache-movie-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn spec(frames: u32, spp: u32, warmup: u32) -> MovieSpec {
    MovieSpec {
        frames,
        fps: 10.0,
        path: MoviePath::Turntable { degrees: 90.0 },
        budget: FrameBudget::Spp(spp),
        warmup,
        denoise: None,
        reference_spp: None,
    }
}

fn cache() -> CacheChoice {
    let config = gs_cache::CacheConfig {
        points: 2000,
        ..Default::default()
    };
    CacheChoice::Gaussian { config, load: None }
}

/// Makes the movie into `dir`; with `stop_after`, cancels it once that many frames are written.
fn make(
    dir: &Path,
    spec: &MovieSpec,
    choice: CacheChoice,
    resume: bool,
    stop_after: Option<u32>,
) -> MovieSummary {
    let mut folder = MovieFolder::open(dir, "test", spec, resume).unwrap();
    let cancel = AtomicBool::new(false);
    let control = Control::new(&cancel, &|_| {});
    let mut progress = |p: Progress<'_>| {
        if let (Progress::Frame { record, .. }, Some(n)) = (p, stop_after)
            && record.frame + 1 >= n
        {
            cancel.store(true, Ordering::SeqCst);
        }
    };
    render_movie(
        &scene(),
        choice,
        spec,
        &mut folder,
        None,
        &control,
        &mut progress,
    )
    .unwrap()
}

fn frame_bytes(dir: &Path, f: u32) -> Vec<u8> {
    std::fs::read(dir.join(format!("frame_{f:06}.exr"))).unwrap()
}

#[test]
fn an_interrupted_movie_resumes_bit_for_bit_with_nee_and_with_a_cache() {
    for (name, choice, warmup) in [("nee", CacheChoice::None, 0), ("cache", cache(), 3)] {
        let s = spec(6, 2, warmup);
        let whole = scratch(&format!("whole-{name}"));
        let parts = scratch(&format!("parts-{name}"));
        let full = make(&whole, &s, choice.clone(), false, None);
        assert_eq!((full.frames_done, full.interrupted), (6, false));
        let first = make(&parts, &s, choice.clone(), false, Some(2));
        assert_eq!((first.frames_done, first.interrupted), (2, true), "{name}");
        let rest = make(&parts, &s, choice.clone(), true, None);
        assert_eq!((rest.frames_done, rest.frames_made), (6, 4), "{name}");
        for f in 0..6 {
            assert!(
                frame_bytes(&whole, f) == frame_bytes(&parts, f),
                "{name}: frame {f} differs after the resume"
            );
        }
        // The frames differ from each other (the camera turns): equal bytes above mean
        // something.
        assert!(frame_bytes(&whole, 0) != frame_bytes(&whole, 5));
        // The tables agree on each frame's samples.
        let table = |d: &Path| -> Vec<String> {
            std::fs::read_to_string(d.join("frames.csv"))
                .unwrap()
                .lines()
                .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(","))
                .collect()
        };
        assert_eq!(table(&whole), table(&parts), "{name}");
        // A frame whose file went missing is made again, and the same.
        std::fs::remove_file(parts.join("frame_000004.png")).unwrap();
        let again = make(&parts, &s, choice, true, None);
        assert_eq!((again.frames_done, again.frames_made), (6, 2), "{name}");
        assert!(frame_bytes(&whole, 5) == frame_bytes(&parts, 5), "{name}");
        for d in [whole, parts] {
            std::fs::remove_dir_all(d).ok();
        }
    }
}

#[test]
fn a_movie_never_writes_over_what_is_in_its_folder() {
    let s = spec(2, 1, 0);
    let dir = scratch("folders");
    // A folder with someone's file in it.
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("notes.txt"), "mine").unwrap();
    let e = MovieFolder::open(&dir, "test", &s, false).unwrap_err();
    assert!(
        e.to_string().contains("holds other files and no movie"),
        "{e}"
    );
    assert!(MovieFolder::open(&dir, "test", &s, true).is_err());
    assert_eq!(
        std::fs::read_to_string(dir.join("notes.txt")).unwrap(),
        "mine"
    );
    std::fs::remove_dir_all(&dir).unwrap();
    // A movie is not made again over itself, nor resumed as another movie.
    make(&dir, &s, CacheChoice::None, false, None);
    let e = MovieFolder::open(&dir, "test", &s, false).unwrap_err();
    assert!(e.to_string().contains("holds a movie already"), "{e}");
    let e = MovieFolder::open(&dir, "test", &spec(3, 1, 0), true).unwrap_err();
    assert!(e.to_string().contains("holds another movie"), "{e}");
    let e = MovieFolder::open(&dir, "another scene", &s, true).unwrap_err();
    assert!(e.to_string().contains("another scene or method"), "{e}");
    // A file where the folder should be.
    let file = dir.join("frame_000000.png");
    let e = MovieFolder::open(&file, "test", &s, false).unwrap_err();
    assert!(e.to_string().contains("not a folder"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_movies_are_refused_before_any_work() {
    let check = |s: MovieSpec, cache: bool, says: &str| {
        let e = s.check(cache).unwrap_err().to_string();
        assert!(e.contains(says), "{e}");
    };
    check(spec(0, 1, 0), false, "0 frames");
    check(spec(2, 0, 0), false, "0 samples a frame");
    check(spec(2, 1, 4), false, "without a cache");
    let mut s = spec(2, 1, 0);
    s.budget = FrameBudget::Seconds(f64::NAN);
    check(s, false, "expected a finite time");
    let mut s = spec(2, 1, 0);
    s.fps = 0.0;
    check(s, false, "frames a second");
    let mut s = spec(2, 1, 0);
    s.path = MoviePath::Keys { keys: Vec::new() };
    check(s, false, "no keyframes");
}

/// With references, each frame's relMSE is its error against its own view: four times the
/// samples (8 against 2 spp of NEE, 64-spp references) must cut it by well over half (a
/// quarter, less the references' own noise), and flicker and JOD follow.
#[test]
fn references_measure_each_frame_and_the_movie() {
    let run = |spp: u32| {
        let dir = scratch(&format!("refs-{spp}"));
        let mut s = spec(4, spp, 0);
        s.reference_spp = Some(64);
        let summary = make(&dir, &s, CacheChoice::None, false, None);
        std::fs::remove_dir_all(&dir).ok();
        summary
    };
    let (low, high) = (run(2), run(8));
    let (e_low, e_high) = (low.mean_rel_mse.unwrap(), high.mean_rel_mse.unwrap());
    assert!(e_high < 0.5 * e_low, "8 spp {e_high} against 2 spp {e_low}");
    assert!(high.mean_flicker.unwrap() < low.mean_flicker.unwrap());
    let (j_low, j_high) = (low.jod.unwrap(), high.jod.unwrap());
    assert!(j_high > j_low && j_high <= 10.0, "{j_high} {j_low}");
}

/// ffmpeg turns the frames into an MP4 that starts as one does; a missing ffmpeg is said,
/// naming what to install, and leaves the frames.
#[test]
fn the_frames_become_a_video_and_a_missing_encoder_is_said() {
    let dir = scratch("video");
    let s = spec(3, 1, 0);
    make(&dir, &s, CacheChoice::None, false, None);
    let folder = MovieFolder::open(&dir, "test", &s, true).unwrap();
    let missing = Path::new("/nonexistent/ffmpeg");
    let e = encode_video(&folder, 3, 10.0, VideoFormat::Mp4, missing).unwrap_err();
    assert!(matches!(e, MovieError::Video(_)), "{e}");
    assert!(e.to_string().contains("apt-get install ffmpeg"), "{e}");
    assert!(dir.join("frame_000002.png").is_file());
    let ffmpeg = movie::ffmpeg_from_env();
    let present = std::process::Command::new(&ffmpeg)
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !present && std::env::var_os("GSCACHE_REQUIRE_FFMPEG").is_none() {
        eprintln!("ffmpeg not installed: the encoding itself is not tested here");
        std::fs::remove_dir_all(&dir).ok();
        return;
    }
    let video = encode_video(&folder, 3, 10.0, VideoFormat::Mp4, &ffmpeg).unwrap();
    let bytes = std::fs::read(&video).unwrap();
    assert_eq!(&bytes[4..8], b"ftyp", "not an MP4");
    // Nothing else was left in the folder: no partial file.
    let stray: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("partial"))
        .collect();
    assert!(stray.is_empty(), "{stray:?}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A movie made in parts (frame ranges, as Dask workers make it) and merged is one process's
/// movie, bit for bit, without a cache; parts that leave a gap, or are not finished, are
/// refused by the merge, and a time budget cannot be split.
#[test]
fn parts_merge_into_one_processes_movie() {
    use movie::{Part, merge_parts};
    let s = spec(6, 2, 0);
    let whole = scratch("parts-whole");
    make(&whole, &s, CacheChoice::None, false, None);
    let root = scratch("parts");
    let part = |first, last| Part {
        first,
        last,
        overlap: 0,
    };
    let make_part = |p: Part| -> PathBuf {
        let dir = root.join("parts").join(format!("{}-{}", p.first, p.last));
        let mut folder = MovieFolder::open_part(&dir, "test", &s, Some(p), false).unwrap();
        let cancel = AtomicBool::new(false);
        render_movie(
            &scene(),
            CacheChoice::None,
            &s,
            &mut folder,
            None,
            &Control::new(&cancel, &|_| {}),
            &mut |_| {},
        )
        .unwrap();
        dir
    };
    let (a, b) = (make_part(part(3, 6)), make_part(part(0, 3)));
    // Not covering every frame: refused, nothing merged.
    let gap = merge_parts(&root.join("gap"), "test", &s, std::slice::from_ref(&a)).unwrap_err();
    assert!(gap.to_string().contains("leave frames 0 to 3 out"), "{gap}");
    merge_parts(&root, "test", &s, &[a, b]).unwrap();
    for f in 0..6 {
        assert!(
            frame_bytes(&whole, f) == frame_bytes(&root, f),
            "frame {f} of the merged parts differs from one process's"
        );
    }
    assert!(!root.join("parts/0-3").exists() && !root.join("parts/3-6").exists());
    // A time budget's part after the first is refused: its samples depend on the frames before.
    let mut timed = spec(4, 1, 0);
    timed.budget = FrameBudget::Seconds(0.05);
    let dir = scratch("parts-timed");
    let mut folder = MovieFolder::open_part(&dir, "test", &timed, Some(part(2, 4)), false).unwrap();
    let e = render_movie(
        &scene(),
        CacheChoice::None,
        &timed,
        &mut folder,
        None,
        &Control::none(),
        &mut |_| {},
    )
    .unwrap_err();
    assert!(e.to_string().contains("needs a sample budget"), "{e}");
    for d in [whole, root, dir] {
        std::fs::remove_dir_all(d).ok();
    }
}
