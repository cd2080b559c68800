//! The render session: the one sampling rule, what edits invalidate, warm-ups, and refusals.

use render_session::{Accumulation, CacheChoice, CacheEffect, Control, Edit, Session};
use std::path::PathBuf;
use volume_pt::{Film, Scene, load_scene, render};

fn small_scene() -> Scene {
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data");
    let mut s = load_scene(&data.join("scenes/default.toml")).unwrap();
    s.camera = s.camera.with_size(40, 24).unwrap();
    s.settings.spp = 2;
    s
}

fn bits(px: &[glam::Vec3]) -> Vec<[u32; 3]> {
    px.iter().map(|p| p.to_array().map(f32::to_bits)).collect()
}

fn small_cache() -> CacheChoice {
    CacheChoice::gaussian(gs_cache::CacheConfig {
        points: 64,
        levels: 2,
        ..Default::default()
    })
}

/// Frames 0..n of s spp at a still camera make the film of one render of n*s spp, bit for bit:
/// frame k takes sample indices k*s .. (k+1)*s.
#[test]
fn frames_of_a_session_are_one_render_of_all_their_samples() {
    let scene = small_scene();
    let mut session = Session::new(scene.clone(), CacheChoice::None).unwrap();
    for _ in 0..3 {
        session.next_frame(&Control::none()).unwrap();
    }
    assert_eq!(
        (session.frames_rendered(), session.frames_in_image()),
        (3, 3)
    );
    let mut whole = scene.clone();
    whole.settings.spp = 6;
    let mut film = Film::new(whole.camera.width, whole.camera.height);
    render(
        &whole.media,
        &whole.camera,
        &whole.settings,
        &mut film,
        &Control::none(),
    );
    assert_eq!(bits(&session.mean()), bits(&film.mean()));
    // A different split of the same samples: 6 frames of 1 spp.
    let mut one = scene;
    one.settings.spp = 1;
    let mut split = Session::new(one, CacheChoice::None).unwrap();
    for _ in 0..6 {
        split.next_frame(&Control::none()).unwrap();
    }
    assert_eq!(bits(&split.mean()), bits(&film.mean()));
}

#[test]
fn edits_say_what_they_invalidate() {
    let mut session = Session::new(small_scene(), small_cache()).unwrap();
    session.next_frame(&Control::none()).unwrap();
    assert_eq!(session.frames_in_image(), 1);
    // The same camera changes nothing.
    let cam = *session.camera();
    let same = session.edit(Edit::Camera(cam)).unwrap();
    assert!(!same.image && same.cache == CacheEffect::Kept);
    assert_eq!(session.frames_in_image(), 1);
    // A camera move empties the image and keeps the cache.
    let mut moved = cam;
    moved.position.x += 0.1;
    let r = session.edit(Edit::Camera(moved)).unwrap();
    assert!(r.image && r.cache == CacheEffect::Kept);
    assert_eq!(session.frames_in_image(), 0);
    // What the volume looks like restarts the Gaussian cache.
    session.next_frame(&Control::none()).unwrap();
    let tf = session.scene().media.medium.transfer_function().clone();
    let edited = tf.with_density_scale(tf.density_scale() * 2.0).unwrap();
    let r = session.edit(Edit::TransferFunction(edited)).unwrap();
    assert!(r.image && r.cache == CacheEffect::Restarted);
    // A resized camera keeps it, Gaussians and all (a view previews small while it moves):
    // the levels are drawn at the new size and go on training there.
    session.next_frame(&Control::none()).unwrap();
    let trained = session.cache().gaussian().unwrap().levels()[0]
        .cloud
        .clone();
    let r = session
        .edit(Edit::Camera(cam.with_size(20, 12).unwrap()))
        .unwrap();
    assert!(r.image && r.cache == CacheEffect::Kept);
    assert!(session.cache().gaussian().unwrap().levels()[0].cloud == trained);
    let small = session.next_frame(&Control::none()).unwrap();
    assert_eq!(session.image().width(), 20);
    assert!(small.train_seconds > 0.0, "it trains at the small size");
    assert!(session.cache().gaussian().unwrap().levels()[0].cloud != trained);
    // And back at full size.
    session.edit(Edit::Camera(cam)).unwrap();
    session.next_frame(&Control::none()).unwrap();
    assert_eq!(session.image().width(), cam.width);
    // Frames keep counting through every edit: no two frames share samples.
    assert_eq!(session.frames_rendered(), 5);
}

#[test]
fn a_warm_up_trains_without_touching_the_image() {
    let mut session = Session::new(small_scene(), small_cache()).unwrap();
    let reports = session.warm_up(3, 30.0, &Control::none()).unwrap();
    assert_eq!(reports.len(), 3);
    assert!(
        reports
            .iter()
            .all(|r| !r.accumulated && r.train_seconds > 0.0)
    );
    assert_eq!(
        (session.frames_rendered(), session.frames_in_image()),
        (3, 0)
    );
    assert_eq!(session.film().total_samples(), 0);
    let r = session.next_frame(&Control::none()).unwrap();
    assert!(r.accumulated && r.frame == 3);
    // Without a cache there is nothing to warm.
    let mut plain = Session::new(small_scene(), CacheChoice::None).unwrap();
    assert!(plain.warm_up(5, 0.0, &Control::none()).unwrap().is_empty());
    assert_eq!(plain.frames_rendered(), 0);
}

#[test]
fn per_frame_images_stand_alone() {
    let mut session = Session::new(small_scene(), CacheChoice::None)
        .unwrap()
        .with_accumulation(Accumulation::PerFrame);
    session.next_frame(&Control::none()).unwrap();
    session.next_frame(&Control::none()).unwrap();
    assert_eq!(session.frames_in_image(), 1);
    let pixels = 40 * 24;
    assert_eq!(session.film().total_samples(), 2 * pixels);
}

#[test]
fn counts_that_would_wrap_are_refused_before_any_work() {
    let mut session = Session::new(small_scene(), small_cache()).unwrap();
    // At 2 spp a frame takes two of a pixel's sample indices 0 .. 2^32 - 1.
    let err = session
        .warm_up(u32::MAX, 0.0, &Control::none())
        .unwrap_err()
        .to_string();
    assert!(err.contains("2^32"), "{err}");
    assert_eq!(session.frames_rendered(), 0);
    assert!(session.check_frames((1 << 31) - 1).is_ok());
    assert!(session.check_frames(1 << 31).is_err());
    let err = session.edit(Edit::Spp(0)).unwrap_err().to_string();
    assert!(err.contains("spp 0"), "{err}");
    let err = session
        .warm_up(1, f32::NAN, &Control::none())
        .unwrap_err()
        .to_string();
    assert!(err.contains("finite"), "{err}");
}

#[test]
fn a_cache_for_an_almost_empty_volume_is_refused_with_the_file() {
    let mut scene = small_scene();
    let tf = scene.media.medium.transfer_function().clone();
    let clear = tf.with_density_scale(0.0).unwrap();
    scene.media.medium.set_transfer_function(clear);
    let err = Session::new(scene, small_cache()).unwrap_err().to_string();
    assert!(
        err.contains("cache points") && err.contains("neghip"),
        "{err}"
    );
}

#[test]
fn a_cancelled_frame_is_not_counted_in_the_image() {
    let mut session = Session::new(small_scene(), CacheChoice::None).unwrap();
    let cancel = std::sync::atomic::AtomicBool::new(true);
    let r = session.next_frame(&Control::cancellable(&cancel)).unwrap();
    assert!(r.cancelled);
    assert_eq!(session.frames_in_image(), 0);
    assert_eq!(session.frames_rendered(), 1);
}

#[test]
fn a_light_edit_is_checked_like_a_scene_file() {
    let mut session = Session::new(small_scene(), CacheChoice::None).unwrap();
    let mut lights = session.scene().media.lights.clone();
    lights
        .lights
        .push(volume_pt::Light::Distant(volume_pt::DistantLight {
            direction: glam::Vec3::new(0.0, -2.0, 0.0),
            irradiance: glam::Vec3::ONE,
        }));
    session.edit(Edit::Lights(lights.clone())).unwrap();
    match session.scene().media.lights.lights.last() {
        Some(volume_pt::Light::Distant(d)) => assert_eq!(d.direction, glam::Vec3::NEG_Y),
        other => panic!("{other:?}"),
    }
    lights
        .lights
        .push(volume_pt::Light::Distant(volume_pt::DistantLight {
            direction: glam::Vec3::ZERO,
            irradiance: glam::Vec3::ONE,
        }));
    let err = session.edit(Edit::Lights(lights)).unwrap_err().to_string();
    assert!(err.contains("direction"), "{err}");
}

/// An image of passes is its own: it starts empty, holds exactly its passes (the samples of
/// frames `first .. first + passes`, so a second image of 2 passes after a first of 3 is the
/// render of samples 3..5 alone), and skipping frames of a session without a cache lands on
/// the same samples as rendering them (and a skip that would wrap the index is refused).
#[test]
fn an_image_of_passes_holds_its_own_frames_and_skipping_lands_on_the_same_samples() {
    use render_session::ImageBudget;
    let scene = small_scene();
    let mut session = Session::new(scene.clone(), CacheChoice::None).unwrap();
    let first = session
        .render_image(ImageBudget::Passes(3), &Control::none())
        .unwrap();
    assert_eq!((first.passes, first.first_frame), (3, 0));
    assert_eq!(first.report.samples, 3 * 2 * 40 * 24);
    let second = session
        .render_image(ImageBudget::Passes(2), &Control::none())
        .unwrap();
    assert_eq!((second.passes, second.first_frame), (2, 3));
    assert_eq!(session.frames_in_image(), 2);
    let mut skipping = Session::new(scene.clone(), CacheChoice::None).unwrap();
    skipping.skip_frames(3).unwrap();
    for _ in 0..2 {
        skipping.next_frame(&Control::none()).unwrap();
    }
    assert_eq!(bits(&session.mean()), bits(&skipping.mean()));
    // Not the first image's samples again.
    let mut from_start = Session::new(scene.clone(), CacheChoice::None).unwrap();
    from_start
        .render_image(ImageBudget::Passes(2), &Control::none())
        .unwrap();
    assert_ne!(bits(&session.mean()), bits(&from_start.mean()));
    // A time budget renders at least one pass; a zero budget exactly one.
    let timed = session
        .render_image(ImageBudget::Seconds(0.0), &Control::none())
        .unwrap();
    assert_eq!(timed.passes, 1);
    // What cannot be: no passes, a NaN budget, several passes where each frame replaces the
    // last.
    for bad in [ImageBudget::Passes(0), ImageBudget::Seconds(f64::NAN)] {
        assert!(session.render_image(bad, &Control::none()).is_err());
    }
    let mut per_frame = Session::new(scene.clone(), CacheChoice::None)
        .unwrap()
        .with_accumulation(Accumulation::PerFrame);
    let e = per_frame
        .render_image(ImageBudget::Passes(2), &Control::none())
        .unwrap_err();
    assert!(e.to_string().contains("Accumulation::Progressive"), "{e}");
    let e = session.skip_frames(u32::MAX).unwrap_err();
    assert!(e.to_string().contains("2^32"), "{e}");
}
