//! The denoiser against the real library. The tests that need it are ignored by default (a user
//! without it sees "ignored", not a pass); CI installs it and runs them with `--ignored`.

use denoise::{DenoiseError, Denoiser, Options, Quality};
use glam::Vec3;
use hdr_image::RgbImage;

/// The denoiser; a missing library fails the (explicitly requested) test with the message.
fn denoiser() -> Denoiser {
    Denoiser::load(2).unwrap_or_else(|e| panic!("{e}"))
}

/// A 64x64 image of a smooth ramp plus per-pixel noise from a hash (uniform, mean 0, sd
/// `noise / sqrt(3)` relative), and the clean ramp.
fn noisy_ramp(noise: f32) -> (RgbImage, RgbImage) {
    let (w, h) = (64u32, 64u32);
    let clean: Vec<Vec3> = (0..w * h)
        .map(|i| Vec3::splat(0.2 + 0.6 * (i % w) as f32 / w as f32))
        .collect();
    let noisy = clean
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let u =
                render_base::hash::unit_f32(render_base::hash::hash32(&[i as u32, 7])) * 2.0 - 1.0;
            *c * (1.0 + noise * u)
        })
        .collect();
    (
        RgbImage::from_pixels(w, h, noisy).unwrap(),
        RgbImage::from_pixels(w, h, clean).unwrap(),
    )
}

fn opts(quality: Quality) -> Options {
    Options {
        quality,
        prefilter: false,
    }
}

fn rel_mse(a: &RgbImage, b: &RgbImage) -> f64 {
    let s: f64 = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(x, y)| ((*x - *y) / (*y + 0.01)).length_squared() as f64 / 3.0)
        .sum();
    s / a.pixels().len() as f64
}

#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn denoising_removes_most_of_the_noise_of_a_smooth_image() {
    let mut d = denoiser();
    let (noisy, clean) = noisy_ramp(0.5);
    let before = rel_mse(&noisy, &clean);
    for quality in [Quality::Fast, Quality::High] {
        let out = d.denoise(&noisy, None, None, opts(quality)).unwrap();
        let after = rel_mse(&out, &clean);
        eprintln!("{quality}: relMSE {before} -> {after}");
        // Measured: 0.080 before, 0.0007 (fast) and 0.0006 (high) after: 116x and 129x. A
        // denoiser that did nothing, or returned another image, fails by far.
        assert!(
            after < before / 10.0,
            "{quality}: relMSE {before} -> {after}"
        );
    }
    // With guides of the right size and range, and the same image twice: same bits (the
    // filter is reused, and OIDN's CPU device is deterministic).
    let albedo = vec![Vec3::splat(0.5); 64 * 64];
    let normal = vec![Vec3::Z; 64 * 64];
    let a = d
        .denoise(&noisy, Some(&albedo), Some(&normal), opts(Quality::High))
        .unwrap();
    let b = d
        .denoise(&noisy, Some(&albedo), Some(&normal), opts(Quality::High))
        .unwrap();
    assert_eq!(a, b);
    assert!(rel_mse(&a, &clean) < before / 10.0);
}

/// Issue 65: a run can be abandoned from another thread. With the abort flag set, a run stops
/// at OIDN's first progress check and says so (a 1024x1024 high-quality run takes seconds
/// here: abandoned, it returns at once); cleared, the same denoiser gives the same bits as a
/// fresh one, at every size and setting it keeps built (four, in turn, then again).
#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn an_abandoned_run_stops_at_once_and_the_next_is_whole() {
    let mut d = denoiser();
    let (noisy, _) = noisy_ramp(0.5);
    let big = RgbImage::from_pixels(1024, 1024, vec![Vec3::splat(0.5); 1024 * 1024]).unwrap();
    let abort = d.abort_handle();
    abort.store(true, std::sync::atomic::Ordering::Relaxed);
    let start = std::time::Instant::now();
    let abandoned = d.denoise(&big, None, None, opts(Quality::High));
    assert!(
        matches!(abandoned, Err(DenoiseError::Cancelled)),
        "{abandoned:?}"
    );
    assert!(
        start.elapsed() < std::time::Duration::from_millis(500),
        "{:?}",
        start.elapsed()
    );
    // Set from another thread while the run is under way: it stops early too.
    abort.store(false, std::sync::atomic::Ordering::Relaxed);
    let flag = abort.clone();
    let setter = std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_millis(20));
        flag.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let midway = d.denoise(&big, None, None, opts(Quality::High));
    setter.join().unwrap();
    assert!(matches!(midway, Err(DenoiseError::Cancelled)), "{midway:?}");
    abort.store(false, std::sync::atomic::Ordering::Relaxed);
    let mut fresh = denoiser();
    let sizes = [(64, 64), (32, 64), (64, 32), (48, 48)];
    for round in 0..2 {
        for (k, &(w, h)) in sizes.iter().enumerate() {
            let image =
                RgbImage::from_pixels(w, h, noisy.pixels()[..(w * h) as usize].to_vec()).unwrap();
            let quality = [Quality::Fast, Quality::High][k % 2];
            let kept = d.denoise(&image, None, None, opts(quality)).unwrap();
            let new = fresh.denoise(&image, None, None, opts(quality)).unwrap();
            assert_eq!(kept, new, "round {round}, {w}x{h} {quality}");
        }
    }
}

#[test]
#[ignore = "needs Intel Open Image Denoise (pip install pyoidn, or GSCACHE_OIDN); run with `cargo test -- --ignored`"]
fn bad_inputs_are_refused_before_the_library_sees_them() {
    let mut d = denoiser();
    let (noisy, _) = noisy_ramp(0.1);
    let short = vec![Vec3::splat(0.5); 10];
    let e = d
        .denoise(&noisy, Some(&short), None, opts(Quality::Fast))
        .unwrap_err();
    assert!(
        e.to_string().contains("albedo") && e.to_string().contains("expected 4096"),
        "{e}"
    );
    let too_bright = vec![Vec3::splat(1.5); 64 * 64];
    let e = d
        .denoise(&noisy, Some(&too_bright), None, opts(Quality::Fast))
        .unwrap_err();
    assert!(e.to_string().contains("[0, 1]"), "{e}");
    let e = d
        .denoise(&noisy, None, Some(&too_bright), opts(Quality::Fast))
        .unwrap_err();
    assert!(e.to_string().contains("without an albedo"), "{e}");
    let mut nan = noisy.clone();
    nan.pixels_mut()[70] = Vec3::new(f32::NAN, 0.0, 0.0);
    let e = d
        .denoise(&nan, None, None, opts(Quality::Fast))
        .unwrap_err();
    assert!(e.to_string().contains("pixel (6, 1)"), "{e}");
}

#[test]
fn a_missing_library_gives_the_install_message() {
    // A path that is not the library: the message names it and says how to install OIDN.
    let e = Denoiser::from_library(
        std::path::Path::new("/nonexistent/libOpenImageDenoise.so.2"),
        1,
    )
    .unwrap_err();
    assert!(matches!(e, DenoiseError::Load { .. }));
    let text = e.to_string();
    assert!(
        text.contains("/nonexistent/libOpenImageDenoise.so.2")
            && text.contains("pip install pyoidn"),
        "{text}"
    );
    // Not a library at all (this test's own source file).
    let e = Denoiser::from_library(std::path::Path::new(file!()), 1).unwrap_err();
    assert!(e.to_string().contains("pip install pyoidn"), "{e}");
}
