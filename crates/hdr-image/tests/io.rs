//! EXR round trips, deterministic bytes, atomic writes, and the tone map's known values.

use glam::Vec3;
use hdr_image::{ImageError, RgbImage, ToneMap, tone_map};

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("hdr-image-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A 37x23 image (odd sizes: partial blocks) of values spanning f32's range, subnormals
/// included.
fn awkward_image() -> RgbImage {
    let (w, h) = (37, 23);
    let mut px = Vec::new();
    for i in 0..w * h {
        let t = i as f32;
        px.push(Vec3::new(
            (t * 0.37).sin().abs() * 1e4,
            f32::from_bits(1 + i),
            (i % 7) as f32 * 1e-30 + 3.0e38 * ((i % 3 == 0) as u32 as f32),
        ));
    }
    RgbImage::from_pixels(w, h, px).unwrap()
}

#[test]
fn exr_round_trip_is_bit_exact() {
    let img = awkward_image();
    let path = scratch("round_trip.exr");
    img.write_exr(&path).unwrap();
    let back = RgbImage::read_exr(&path).unwrap();
    assert_eq!((back.width(), back.height()), (img.width(), img.height()));
    for (a, b) in img.pixels().iter().zip(back.pixels()) {
        for c in 0..3 {
            assert_eq!(a[c].to_bits(), b[c].to_bits(), "{a} read back as {b}");
        }
    }
}

#[test]
fn exr_bytes_depend_only_on_the_pixels() {
    // The writer compresses blocks in parallel; the files must still be byte-identical.
    let img = awkward_image();
    let (a, b) = (scratch("same_a.exr"), scratch("same_b.exr"));
    img.write_exr(&a).unwrap();
    img.write_exr(&b).unwrap();
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
}

#[test]
fn a_failed_write_names_the_file_and_leaves_the_old_one() {
    let img = awkward_image();
    let path = scratch("kept.exr");
    img.write_exr(&path).unwrap();
    let before = std::fs::read(&path).unwrap();
    // A folder where the file should go: the rename over it fails after the data is written.
    let blocked = scratch("blocked.exr");
    std::fs::create_dir_all(blocked.join("inside")).unwrap();
    let err = img.write_exr(&blocked).unwrap_err();
    assert!(matches!(err, ImageError::Write { .. }));
    assert!(err.to_string().contains("blocked.exr"), "{err}");
    // No temporary file is left behind (only this file's: the other tests write beside it
    // at the same time).
    let leftovers: Vec<_> = std::fs::read_dir(blocked.parent().unwrap())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.starts_with(".blocked.exr")
        })
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    assert_eq!(std::fs::read(&path).unwrap(), before);
    // A missing folder is named too.
    let err = img
        .write_png(&scratch("no/such/folder/x.png"), 0.0, ToneMap::Clip)
        .unwrap_err();
    assert!(err.to_string().contains("x.png"), "{err}");
}

#[test]
fn reading_a_non_exr_names_the_file() {
    let path = scratch("not_an.exr");
    std::fs::write(&path, b"P6 1 1 255 abc").unwrap();
    let err = RgbImage::read_exr(&path).unwrap_err();
    assert!(err.to_string().contains("not_an.exr"), "{err}");
}

#[test]
fn sizes_must_match_the_pixels() {
    assert!(matches!(
        RgbImage::from_pixels(3, 2, vec![Vec3::ZERO; 5]),
        Err(ImageError::Size { .. })
    ));
    // width * height overflows u32: still refused, not wrapped.
    assert!(RgbImage::from_pixels(1 << 16, 1 << 16, vec![]).is_err());
}

#[test]
fn tone_map_known_values() {
    let px = [
        Vec3::new(0.0, 1.0, 0.5),
        Vec3::new(f32::NAN, f32::INFINITY, -1.0),
        Vec3::new(0.25, 2.0, 0.001),
    ];
    // sRGB(0.5) = 0.7354 -> 187.5 -> 188; sRGB(0.25) = 0.5371 -> 137; sRGB(0.001) = 0.01292 -> 3.3 -> 3.
    assert_eq!(
        tone_map(&px, 0.0, ToneMap::Clip),
        vec![0, 255, 188, 0, 0, 0, 137, 255, 3]
    );
    // One stop up doubles before the map: 0.25 -> 0.5 -> 188.
    assert_eq!(tone_map(&px[2..], 1.0, ToneMap::Clip)[0], 188);
    // ACES keeps highlights below white: 2.0 maps to aces(2) = 0.9099 -> sRGB 0.9592 -> 245.
    assert_eq!(tone_map(&px[2..], 0.0, ToneMap::Aces)[1], 245);
}
