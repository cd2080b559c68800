//! Shards and exact merges: partial films of disjoint sample ranges, merged in any order,
//! equal the one-process film bit for bit; what a merge must refuse, it refuses.

mod common;

use common::data_dir;
use glam::Vec3;
use volume_pt::Control;
use volume_pt::{ExactRgb, Film, PartialRender, Scene, Shard, load_scene, render_samples};

fn small_scene() -> Scene {
    let mut scene = load_scene(&data_dir().join("scenes/default.toml")).unwrap();
    scene.camera = scene.camera.with_size(40, 28).unwrap();
    scene.settings.spp = 7;
    scene
}

fn film_of(scene: &Scene, samples: std::ops::Range<u32>, threads: usize) -> Film {
    let (w, h) = (scene.camera.width, scene.camera.height);
    render_into(scene, samples, threads, Film::new(w, h))
}

/// Renders `samples` of `scene` into `film` on `threads` threads.
fn render_into(
    scene: &Scene,
    samples: std::ops::Range<u32>,
    threads: usize,
    mut film: Film,
) -> Film {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        render_samples(
            &scene.media,
            &scene.camera,
            &scene.settings,
            samples,
            &mut film,
            &Control::none(),
        )
    });
    film
}

fn pixel_bits(img: &hdr_image::RgbImage) -> Vec<[u32; 3]> {
    img.pixels()
        .iter()
        .map(|p| p.to_array().map(f32::to_bits))
        .collect()
}

#[test]
fn merged_shards_equal_the_whole_render_bit_for_bit() {
    let scene = small_scene();
    let spp = scene.settings.spp;
    let whole = film_of(&scene, 0..spp, 2);
    let parts: Vec<PartialRender> = (0..3)
        .map(|i| {
            let range = Shard::new(i, 3).unwrap().samples(spp);
            // Each shard on its own thread count: the bits may not depend on it.
            let film = film_of(&scene, range.clone(), 1 + i as usize);
            PartialRender::from_film(&film, "k", spp, range)
        })
        .collect();
    let reference = PartialRender::from_film(&whole, "k", spp, 0..spp);
    for order in [[0, 1, 2], [2, 0, 1], [1, 2, 0]] {
        let merged = PartialRender::merge_all(order.iter().map(|&i| parts[i].clone())).unwrap();
        assert!(merged.is_complete());
        assert_eq!(merged, reference, "order {order:?}");
        assert_eq!(pixel_bits(&merged.image()), pixel_bits(&whole.image()));
    }
    // One part alone is not the whole render.
    assert!(!parts[1].is_complete());
}

#[test]
fn exact_sums_do_not_depend_on_grouping() {
    // Values whose f64 sum depends on the order of the additions (tiny ones next to 1 and 5e3
    // lose different low bits whether they are added before or after the large ones); the
    // assertion below checks that they do.
    let values = [1.0f32, 1.0e-9, 3.0e-9, 7.0e-10, 2.0e-9, 5.0e3, 1.0e-9];
    let f64_left = values.iter().fold(0.0f64, |a, &v| a + v as f64);
    let f64_right = values.iter().rev().fold(0.0f64, |a, &v| a + v as f64);
    assert_ne!(
        f64_left.to_bits(),
        f64_right.to_bits(),
        "the test's values must expose f64's grouping"
    );
    let exact = |order: &mut dyn Iterator<Item = &f32>| {
        let mut s = ExactRgb::ZERO;
        for &v in order {
            s += ExactRgb::from_sample(Vec3::splat(v)).unwrap();
        }
        s
    };
    assert_eq!(exact(&mut values.iter()), exact(&mut values.iter().rev()));
    // The fixed point keeps every sample to 2^-56: the mean agrees with f64 to f32 precision.
    let mut s = ExactRgb::ZERO;
    for &v in &values {
        s += ExactRgb::from_sample(Vec3::splat(v)).unwrap();
    }
    let mean = s.mean(values.len() as u32).x as f64;
    let expect = f64_left / values.len() as f64;
    assert!((mean - expect).abs() <= expect * 1e-7, "{mean} vs {expect}");
}

#[test]
fn bad_samples_are_refused_per_channel() {
    for bad in [
        Vec3::new(0.5, f32::NAN, 0.5),
        Vec3::new(f32::NAN, 0.5, 0.5),
        Vec3::new(0.5, 0.5, -volume_pt::film::MAX_SAMPLE_RADIANCE * 2.0),
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(0.0, f32::NEG_INFINITY, 0.0),
        Vec3::new(0.0, 0.0, volume_pt::film::MAX_SAMPLE_RADIANCE * 2.0),
    ] {
        assert!(ExactRgb::from_sample(bad).is_none(), "{bad:?}");
    }
    // Bright but allowed: the slow conversion path above 128 is exact too.
    let v = ExactRgb::from_sample(Vec3::new(1000.25, 129.0, 0.0)).unwrap();
    assert_eq!(v.0[0], (1000.25f64 * 2f64.powi(56)) as i128);
    assert_eq!(v.mean(1), Vec3::new(1000.25, 129.0, 0.0));
    // Negative samples (a control variate's) are kept, exactly, and sum with positive ones.
    let n = ExactRgb::from_sample(Vec3::new(-1000.25, -0.5, -1e-30)).unwrap();
    assert_eq!(n.0[0], -(1000.25f64 * 2f64.powi(56)) as i128);
    let mut sum = v;
    sum += n;
    assert_eq!(sum.mean(1), Vec3::new(0.0, 128.5, 0.0));
}

#[test]
fn merges_refuse_other_renders_and_repeated_ranges() {
    let scene = small_scene();
    let film = film_of(&scene, 0..2, 2);
    let a = PartialRender::from_film(&film, "render-a", 7, 0..2);
    let other_key = PartialRender::from_film(&film, "render-b", 7, 2..4);
    let again = PartialRender::from_film(&film, "render-a", 7, 1..3);
    let e = a.clone().merge(&other_key).unwrap_err().to_string();
    assert!(e.contains("different renders"), "{e}");
    let e = a.clone().merge(&again).unwrap_err().to_string();
    assert!(e.contains("given twice"), "{e}");
    let other_spp = PartialRender::from_film(&film, "render-a", 8, 2..4);
    assert!(a.clone().merge(&other_spp).is_err());
    assert!(PartialRender::merge_all(Vec::new()).is_err());
}

#[test]
fn partial_files_round_trip_and_refuse_damage() {
    let scene = small_scene();
    let film = film_of(&scene, 2..5, 2);
    let p = PartialRender::from_film(&film, "key", 7, 2..5);
    let dir = std::env::temp_dir().join(format!("vpt-shards-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("part.gspartial");
    p.write(&path).unwrap();
    assert_eq!(PartialRender::read(&path).unwrap(), p);
    let bytes = p.to_bytes();
    let origin = std::path::Path::new("x.gspartial");
    let e = PartialRender::from_bytes(&bytes[..bytes.len() - 1], origin)
        .unwrap_err()
        .to_string();
    assert!(e.contains("x.gspartial") && e.contains("52 a pixel"), "{e}");
    let e = PartialRender::from_bytes(b"P6 not a partial", origin)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a partial render"), "{e}");
    // The header alone edited: the checksum no longer matches (the values behind it are
    // checked too: see the unit tests in shard.rs).
    let header_end = 12 + bytes[12..].iter().position(|&b| b == b'\n').unwrap();
    let header = String::from_utf8(bytes[..header_end].to_vec()).unwrap();
    let mut edited = header.replace("\"spp\":7", "\"spp\":3").into_bytes();
    edited.extend_from_slice(&bytes[header_end..]);
    let e = PartialRender::from_bytes(&edited, origin)
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum does not match"), "{e}");
    // The checksum removed (issue 48, item 11: it was said not to match): said missing.
    let start = header.find(",\"checksum\":\"").unwrap();
    let end = start + header[start + 13..].find('"').unwrap() + 14;
    let mut removed = format!("{}{}", &header[..start], &header[end..]).into_bytes();
    assert!(!String::from_utf8_lossy(&removed).contains("checksum"));
    removed.extend_from_slice(&bytes[header_end..]);
    let e = PartialRender::from_bytes(&removed, origin)
        .unwrap_err()
        .to_string();
    assert!(e.contains("the checksum is missing"), "{e}");
    let e = PartialRender::read(&dir).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn shard_ranges_cover_the_samples_once() {
    for spp in [1, 5, 64, 1000] {
        for n in [1, 2, 3, 7, 8] {
            let mut next = 0;
            for i in 0..n {
                let r = Shard::new(i, n).unwrap().samples(spp);
                assert_eq!(r.start, next);
                next = r.end;
            }
            assert_eq!(next, spp);
        }
    }
    assert!(Shard::parse("3/3").is_err());
    assert!(Shard::parse("1/0").is_err());
    assert!(Shard::parse("two/3").is_err());
    assert_eq!(Shard::parse("2/5").unwrap().to_string(), "2/5");
}

#[test]
fn features_merge_across_shards_bit_for_bit() {
    let scene = small_scene();
    let spp = scene.settings.spp;
    let film = |samples: std::ops::Range<u32>, threads: usize| {
        let (w, h) = (scene.camera.width, scene.camera.height);
        render_into(&scene, samples, threads, Film::with_features(w, h))
    };
    let whole = film(0..spp, 2);
    let parts: Vec<PartialRender> = (0..3)
        .map(|i| {
            let range = Shard::new(i, 3).unwrap().samples(spp);
            PartialRender::from_film(&film(range.clone(), 1 + i as usize), "k", spp, range)
        })
        .collect();
    let merged = PartialRender::merge_all(parts.iter().rev().cloned()).unwrap();
    let reference = PartialRender::from_film(&whole, "k", spp, 0..spp);
    assert_eq!(merged, reference);
    let bits = |f: &hdr_image::FeatureImages| {
        let mut v: Vec<u32> = Vec::new();
        for k in 0..f.albedo.len() {
            v.extend(f.albedo[k].to_array().map(f32::to_bits));
            v.extend(f.normal[k].to_array().map(f32::to_bits));
            v.push(f.depth[k].to_bits());
            v.push(f.coverage[k].to_bits());
        }
        v
    };
    let merged_features = merged.feature_images().unwrap();
    assert_eq!(
        bits(&merged_features),
        bits(&whole.feature_images().unwrap())
    );
    // Some pixels hit the volume and some do not: the comparison is not of empty buffers.
    let coverage = &merged_features.coverage;
    assert!(coverage.contains(&1.0) && coverage.iter().any(|&c| c < 1.0));

    // The file round trip keeps them; a partial without features will not merge with one with.
    let dir = std::env::temp_dir().join(format!("vpt-features-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("part.gspartial");
    parts[0].write(&path).unwrap();
    assert_eq!(PartialRender::read(&path).unwrap(), parts[0]);
    std::fs::remove_dir_all(&dir).ok();
    let plain_range = Shard::new(1, 3).unwrap().samples(spp);
    let plain = film_of(&scene, plain_range.clone(), 2);
    let plain = PartialRender::from_film(&plain, "k", spp, plain_range);
    let e = parts[0].clone().merge(&plain).unwrap_err().to_string();
    assert!(e.contains("feature buffers"), "{e}");
}
