//! An interrupted render keeps at least one sample in every pixel (issue 48, item 7): a first
//! pass of 256 samples rendered tile by tile, interrupted after 3 s, once left 1096 of 4096
//! pixels exactly black. The pass split changes no bit of a finished render.

mod common;

use common::data_dir;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use volume_pt::{Control, Film, load_scene, render_samples};

#[test]
fn an_interrupt_at_any_point_leaves_no_pixel_without_samples() {
    let mut scene = load_scene(&data_dir().join("scenes/default.toml")).unwrap();
    scene.camera = scene.camera.with_size(64, 64).unwrap();
    let (w, h) = (scene.camera.width, scene.camera.height);
    let pixels = (w * h) as u64;
    // Interrupted once this many samples are done: from the first tile of the first pass to
    // well into the render.
    for after in [1u64, 64, pixels / 2, 3 * pixels, 40 * pixels] {
        let cancel = AtomicBool::new(false);
        let done = AtomicU64::new(0);
        let progress = |n: u64| {
            if done.fetch_add(n, Ordering::SeqCst) + n >= after {
                cancel.store(true, Ordering::SeqCst);
            }
        };
        let mut film = Film::new(w, h);
        let stats = render_samples(
            &scene.media,
            &scene.camera,
            &scene.settings,
            0..100_000,
            &mut film,
            &Control::new(&cancel, &progress).keeping_every_pixel(),
        );
        assert!(stats.cancelled, "after {after}: not interrupted");
        let counts = film.counts();
        let empty = counts.iter().filter(|&&c| c == 0).count();
        assert_eq!(
            empty, 0,
            "interrupted after {after} samples: pixels with no sample"
        );
    }
}

#[test]
fn growing_passes_give_the_same_bits_as_one_sample_range() {
    let mut scene = load_scene(&data_dir().join("scenes/default.toml")).unwrap();
    scene.camera = scene.camera.with_size(24, 16).unwrap();
    let (w, h) = (scene.camera.width, scene.camera.height);
    let render = |ranges: &[std::ops::Range<u32>]| {
        let mut film = Film::new(w, h);
        for r in ranges {
            render_samples(
                &scene.media,
                &scene.camera,
                &scene.settings,
                r.clone(),
                &mut film,
                &Control::none(),
            );
        }
        film.exact_sums()
    };
    // One call (passes of 1, 2, 4, ... samples) against one call per sample.
    let singles: Vec<_> = (0..37).map(|s| s..s + 1).collect();
    assert_eq!(render(std::slice::from_ref(&(0..37))), render(&singles));
}
