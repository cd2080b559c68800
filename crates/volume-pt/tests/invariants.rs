//! Invariants of the renderer: nothing to scatter gives the environment exactly; the image is
//! bit-identical for a seed whatever the thread count.

mod common;

use common::*;
use glam::{UVec3, Vec3};
use std::sync::atomic::AtomicBool;
use volume_pt::Control;
use volume_pt::integrator::IntegratorKind;
use volume_pt::{Film, Filter, Medium, ScalarGrid, TransferFunction, load_scene, render};

fn render_with_threads(scene: &volume_pt::Scene, threads: usize) -> Vec<Vec3> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut film = Film::new(scene.camera.width, scene.camera.height);
        render(
            &scene.media,
            &scene.camera,
            &scene.settings,
            &mut film,
            &Control::none(),
        );
        film.mean()
    })
}

fn small_default_scene() -> volume_pt::Scene {
    let mut s = load_scene(&data_dir().join("scenes/default.toml")).unwrap();
    s.camera.width = 40;
    s.camera.height = 24;
    s.settings.spp = 6;
    s
}

#[test]
fn zero_transfer_function_or_empty_volume_gives_the_environment_exactly() {
    let mut scene = small_default_scene();
    // Lights stay in the scene but outside the view.
    scene
        .media
        .lights
        .lights
        .retain(|l| matches!(l, volume_pt::Light::Sphere(s) if s.center.x > 0.0));
    let env = scene.media.lights.environment;
    for integrator in [IntegratorKind::Uniform, IntegratorKind::Nee] {
        scene.settings.path.integrator = integrator;
        // All-zero opacity.
        let zero_tf = TransferFunction::from_points(
            (0.0, 255.0),
            &[(0.0, Vec3::ONE, 0.0), (1.0, Vec3::ONE, 0.0)],
            5.0,
        )
        .unwrap();
        scene.media.medium.set_transfer_function(zero_tf);
        let img = render_with_threads(&scene, 2);
        assert!(
            img.iter().all(|p| *p == env),
            "{integrator}: zero TF must show the environment exactly"
        );

        // Empty volume: every voxel 0, and value 0 is transparent (the TF is not).
        let grid = ScalarGrid::new(UVec3::new(16, 8, 4), vec![0.0; 512]).unwrap();
        let tf = TransferFunction::from_points(
            (0.0, 1.0),
            &[(0.0, Vec3::ONE, 0.0), (0.5, Vec3::ONE, 1.0)],
            50.0,
        )
        .unwrap();
        scene.media.medium = Medium::new(
            grid,
            Filter::Trilinear,
            Vec3::splat(-20.0),
            Vec3::splat(2.5),
            tf,
            4,
        )
        .unwrap();
        assert_eq!(scene.media.medium.majorants().global_max(), 0.0);
        let img = render_with_threads(&scene, 2);
        assert!(
            img.iter().all(|p| *p == env),
            "{integrator}: empty volume must show the environment exactly"
        );
    }
}

#[test]
fn one_two_and_three_threads_give_identical_bits() {
    let scene = small_default_scene();
    let a = render_with_threads(&scene, 1);
    let b = render_with_threads(&scene, 2);
    let c = render_with_threads(&scene, 3);
    assert!(a.iter().any(|p| p.max_element() > 0.0), "image is black");
    let bits = |v: &[Vec3]| {
        v.iter()
            .flat_map(|p| p.to_array().map(f32::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(bits(&a), bits(&c));
}

#[test]
fn a_cancelled_render_keeps_the_mean_of_what_it_took() {
    let scene = small_default_scene();
    let mut film = Film::new(scene.camera.width, scene.camera.height);
    let cancel = AtomicBool::new(false);
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let stats = render(
        &scene.media,
        &scene.camera,
        &scene.settings,
        &mut film,
        &Control::new(&cancel, &|_| {
            if calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst) == 2 {
                cancel.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        }),
    );
    assert!(stats.cancelled);
    let counts = film.counts();
    assert!(counts.iter().any(|&c| c > 0), "nothing was kept");
    assert!(
        counts.iter().any(|&c| c < scene.settings.spp),
        "the render was not interrupted"
    );
    // Cancellation is read before every sample, so a pixel may stop part-way; every pixel holds
    // the mean of its first `c` samples, which is what an uninterrupted render of `c` spp gives
    // there (the same sample indices; sums grouped into other passes, so equal to rounding).
    let img = film.mean();
    let mut compared = 0;
    let mut by_count: std::collections::BTreeMap<u32, Vec<Vec3>> = Default::default();
    for &c in counts.iter().filter(|&&c| c > 0) {
        by_count.entry(c).or_insert_with(|| {
            let mut fewer = small_default_scene();
            fewer.settings.spp = c;
            render_with_threads(&fewer, 2)
        });
    }
    for (i, (p, &c)) in img.iter().zip(&counts).enumerate() {
        assert!(p.is_finite());
        if c > 0 {
            let q = by_count[&c][i];
            assert!(
                (*p - q).abs().max_element() <= 1e-6 * (1.0 + q.abs().max_element()),
                "pixel {i} with {c} samples: {p} vs {q}"
            );
            compared += 1;
        }
    }
    assert!(compared > 0);
}
