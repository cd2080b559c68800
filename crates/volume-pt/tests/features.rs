//! Feature buffers (AOVs): what each buffer holds on media whose answer is known. (That they
//! merge across shards bit for bit is tested with the shards, in shards.rs.)

mod common;

use common::{homogeneous, scene};
use glam::{UVec3, Vec3};
use volume_pt::integrator::SceneMedia;
use volume_pt::{
    Camera, Control, Film, Filter, Lights, Medium, Phase, RenderSettings, ScalarGrid,
    TransferFunction, render,
};

/// No lights; a grey environment of 0.3, which a ray that misses the medium sees.
fn no_lights() -> Lights {
    Lights {
        lights: vec![],
        environment: Vec3::splat(0.3),
    }
}

/// A camera on the +z axis looking at the origin, `size` pixels square.
fn camera(distance: f32, size: u32) -> Camera {
    Camera::look_at(Vec3::Z * distance, Vec3::ZERO, Vec3::Y, 20.0, size, size).unwrap()
}

fn features_of(media: &SceneMedia, camera: &Camera, spp: u32) -> Film {
    let mut film = Film::with_features(camera.width, camera.height);
    let settings = RenderSettings {
        spp,
        seed: 3,
        path: Default::default(),
    };
    render(media, camera, &settings, &mut film, &Control::none());
    film
}

#[test]
fn the_albedo_of_a_homogeneous_medium_is_its_albedo() {
    let albedo = Vec3::new(0.8, 0.5, 0.25);
    // Optically thick (200 mean free paths across): every ray that enters the cube scatters.
    let media = scene(
        homogeneous(200.0, albedo, 1.0, 4),
        Phase::Isotropic,
        no_lights(),
    );
    let cam = camera(4.0, 16);
    let film = features_of(&media, &cam, 8);
    let f = film.features().unwrap();
    // The cube (side 1 at distance 3.5) covers the middle of a 20-degree view: the centre 4x4
    // pixels see only the cube.
    for y in 6..10 {
        for x in 6..10 {
            let p = f[(y * 16 + x) as usize];
            assert_eq!(p.coverage, 1.0, "pixel ({x}, {y})");
            // Fixed point truncates each sample to 2^-30.
            assert!(
                (p.albedo - albedo).abs().max_element() < 1e-8,
                "pixel ({x}, {y}): albedo {} against {albedo}",
                p.albedo
            );
        }
    }
    // A corner ray misses the cube: the albedo is the environment it sees (an emitter's
    // radiance, clamped), normal 0, nothing hit.
    let corner = f[0];
    assert!((corner.albedo - Vec3::splat(0.3)).abs().max_element() < 1e-8);
    assert_eq!(corner.normal, Vec3::ZERO);
    assert_eq!(corner.coverage, 0.0);
    assert_eq!(corner.depth, f32::INFINITY);
}

#[test]
fn the_normal_of_a_linear_ramp_points_down_the_gradient() {
    // Values rise along +x; extinction follows them (a linear opacity ramp), so the normal is
    // -x everywhere, whatever the ray.
    let n = 16u32;
    let values: Vec<f32> = (0..n * n * n).map(|i| (i % n) as f32).collect();
    let grid = ScalarGrid::new(UVec3::splat(n), values).unwrap();
    let tf = TransferFunction::from_points(
        (0.0, (n - 1) as f32),
        &[(0.0, Vec3::ONE, 0.0), (1.0, Vec3::ONE, 1.0)],
        40.0,
    )
    .unwrap();
    let medium = Medium::new(
        grid,
        Filter::Trilinear,
        Vec3::splat(-0.5),
        // Anisotropic spacing: the world gradient must divide by it per axis.
        Vec3::new(1.0 / 16.0, 1.5 / 16.0, 0.5 / 16.0),
        tf,
        4,
    )
    .unwrap();
    let media = scene(medium, Phase::Isotropic, no_lights());
    let cam = Camera::look_at(Vec3::new(1.0, 2.0, 4.0), Vec3::ZERO, Vec3::Y, 20.0, 16, 16).unwrap();
    let film = features_of(&media, &cam, 4);
    let f = film.features().unwrap();
    let mut checked = 0;
    for p in f.iter().filter(|p| p.coverage == 1.0) {
        // Every sample's normal is exactly -x up to rounding, so the mean is too.
        assert!(
            (p.normal - Vec3::NEG_X).abs().max_element() < 1e-5,
            "normal {} against -x",
            p.normal
        );
        checked += 1;
    }
    assert!(
        checked >= 20,
        "only {checked} pixels saw the ramp on every sample"
    );
}

#[test]
fn the_depth_of_a_slab_is_its_distance() {
    // A very dense cube (mean free path 1e-5): rays scatter at its front face, z = 0.5.
    let media = scene(
        homogeneous(1e5, Vec3::splat(0.9), 1.0, 4),
        Phase::Isotropic,
        no_lights(),
    );
    let distance = 4.0;
    let cam = camera(distance, 17);
    let spp = 1024;
    let film = features_of(&media, &cam, spp);
    let f = film.features().unwrap();
    // A pixel's depth is the face's distance along its rays, averaged over the pixel (rays are
    // jittered uniformly over it), plus the mean free path. The average is integrated here on
    // a 64 x 64 grid of sub-pixel positions.
    let expected = |x: u32, y: u32| {
        let mut sum = 0.0f64;
        for j in 0..64 {
            for i in 0..64 {
                let d = cam.ray_direction(
                    x as f32 + (i as f32 + 0.5) / 64.0,
                    y as f32 + (j as f32 + 0.5) / 64.0,
                );
                sum += (distance as f64 - 0.5) / -(d.z as f64);
            }
        }
        sum / 4096.0 + 1e-5
    };
    // Pixels are 20 mrad wide, so a ray's length varies across one: by 1.8e-4 at the centre,
    // 5e-3 at (10, 5) and 1.2e-2 at (14, 2). 1024 samples estimate the mean to a standard
    // deviation of that / sqrt(12 x 1024) (1.6e-6, 4.6e-5, 1.1e-4); the tolerances are 5 of
    // them or more. At the centre the jitter's mean effect (1.2e-4) is 4x the tolerance, so a
    // depth taken from the pixel's centre ray alone fails.
    for (x, y, tolerance) in [(8u32, 8u32, 3e-5f64), (10, 5, 2.5e-4), (14, 2, 5.5e-4)] {
        let p = f[(y * 17 + x) as usize];
        assert_eq!(p.coverage, 1.0);
        let e = expected(x, y);
        assert!(
            (p.depth as f64 - e).abs() < tolerance,
            "pixel ({x}, {y}): depth {} against {e}",
            p.depth
        );
    }
}

#[test]
fn a_film_without_features_keeps_none() {
    let media = scene(
        homogeneous(1.0, Vec3::ONE, 1.0, 4),
        Phase::Isotropic,
        no_lights(),
    );
    let cam = camera(4.0, 4);
    let mut film = Film::new(4, 4);
    render(
        &media,
        &cam,
        &RenderSettings {
            spp: 1,
            seed: 3,
            path: Default::default(),
        },
        &mut film,
        &Control::none(),
    );
    assert!(!film.has_features() && film.features().is_none());
    // Colour alone is the same whether or not features are kept (they draw no random numbers).
    let with = features_of(&media, &cam, 1);
    assert_eq!(film.image(), with.image());
}
