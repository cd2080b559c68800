//! The integrators against each other and against closed forms: white furnace, uniform vs NEE,
//! majorant grid vs one global majorant, and a tiny light's single scattering.

mod common;

use common::*;
use glam::{DVec3, Vec3};
use volume_pt::Camera;
use volume_pt::integrator::{IntegratorKind, PathSettings, SceneMedia, radiance};
use volume_pt::sampling::SampleStream;
use volume_pt::{Light, Lights, Phase, SphereLight, load_scene};

/// White furnace: albedo 1 under a unit environment, unlimited length: every pixel is 1.
#[test]
fn white_furnace_both_integrators() {
    let data_scene = load_scene(&data_dir().join("scenes/default.toml")).unwrap();
    let mut neghip = data_scene.media.medium.clone();
    // Same data, albedo 1 everywhere: the real-volume furnace exercises the majorant grid.
    let tf = volume_pt::TransferFunction::from_points(
        (0.0, 255.0),
        &[
            (0.0, Vec3::ONE, 0.0),
            (0.2, Vec3::ONE, 0.0),
            (0.5, Vec3::ONE, 1.0),
        ],
        0.5,
    )
    .unwrap();
    neghip.set_transfer_function(tf);
    let media = [
        (
            "homogeneous",
            homogeneous(3.0, Vec3::ONE, 1.0, 8),
            Vec3::new(0.1, 0.2, -4.0),
            Vec3::Z,
        ),
        (
            "neghip",
            neghip,
            Vec3::new(0.0, 0.0, -60.0),
            Vec3::new(0.05, 0.02, 1.0).normalize(),
        ),
    ];
    for (name, medium, o, d) in media {
        for phase in [Phase::Isotropic, Phase::HenyeyGreenstein { g: 0.6 }] {
            let scene = scene(
                medium.clone(),
                phase,
                Lights {
                    lights: vec![],
                    environment: Vec3::ONE,
                },
            );
            for integrator in [IntegratorKind::Uniform, IntegratorKind::Nee] {
                let settings = PathSettings {
                    integrator,
                    max_depth: None,
                    rr_start_depth: 1,
                    show_lights: true,
                };
                let (mean, var) = path_stats(&scene, &settings, o, d, 100_000, 3);
                let se = var[0].sqrt();
                // 5 standard errors (false alarm 5.7e-7), and the error itself must be small.
                assert!(
                    (mean[0] - 1.0).abs() <= 5.0 * se + 1e-6 && se < 2e-3,
                    "{name} {phase:?} {integrator}: {} (se {se})",
                    mean[0]
                );
            }
        }
    }
}

/// Per-pixel mean and variance of the mean of luminance over `n` samples per pixel.
fn pixel_stats(
    scene: &SceneMedia,
    cam: &Camera,
    settings: &PathSettings,
    n: u32,
    seed: u64,
) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let pixel = (y * cam.width + x) as u64;
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for i in 0..n {
                let mut rng = SampleStream::new(seed, pixel, i as u64);
                let (jx, jy) = rng.next_2d();
                let d = cam.ray_direction(x as f32 + jx, y as f32 + jy);
                let l = radiance(scene, settings, cam.position, d, &mut rng);
                let lum = l.dot(Vec3::new(0.2126, 0.7152, 0.0722)) as f64;
                s += lum;
                s2 += lum * lum;
            }
            let m = s / n as f64;
            out.push((m, (s2 / n as f64 - m * m).max(0.0) / (n as f64 - 1.0)));
        }
    }
    out
}

/// Image-wide chi-square of per-pixel z-scores between two independent estimates; each pixel's
/// |z| must stay below 5 and the sum below the 1e-5 upper quantile of chi-square.
fn assert_agree(a: &[(f64, f64)], b: &[(f64, f64)], what: &str) {
    let mut scores = test_stats::ZScores::new();
    for (p, q) in a.iter().zip(b) {
        let v = p.1 + q.1;
        if v == 0.0 {
            assert_eq!(p.0, q.0, "{what}: noiseless pixels differ");
            continue;
        }
        scores.add(p.0 - q.0, v);
    }
    scores.assert_unbiased(what, 5.0, a.len() / 2 + 1);
}

fn lit_neghip() -> (SceneMedia, Camera) {
    let s = load_scene(&data_dir().join("scenes/default.toml")).unwrap();
    let mut media = s.media;
    // A large light, so that phase sampling alone finds it often enough for a fair z-test.
    media.lights = Lights {
        // Two spheres of different power and the environment: NEE picks among three
        // strategies with probabilities that change from vertex to vertex.
        lights: vec![
            Light::Sphere(SphereLight {
                center: Vec3::new(60.0, 70.0, 40.0),
                radius: 35.0,
                radiance: Vec3::new(3.0, 2.5, 2.0),
            }),
            Light::Sphere(SphereLight {
                center: Vec3::new(-70.0, 20.0, 50.0),
                radius: 25.0,
                radiance: Vec3::new(1.0, 1.5, 3.0),
            }),
        ],
        environment: Vec3::new(0.2, 0.25, 0.3),
    };
    let cam = Camera::look_at(
        Vec3::new(60.0, 45.0, 95.0),
        Vec3::ZERO,
        Vec3::Y,
        30.0,
        12,
        12,
    )
    .unwrap();
    (media, cam)
}

#[test]
fn uniform_and_nee_agree_on_a_lit_volume() {
    let (media, cam) = lit_neghip();
    for max_depth in [Some(1), Some(8)] {
        let u = PathSettings {
            integrator: IntegratorKind::Uniform,
            max_depth,
            rr_start_depth: 3,
            show_lights: true,
        };
        let n = PathSettings {
            integrator: IntegratorKind::Nee,
            ..u
        };
        let a = pixel_stats(&media, &cam, &u, 6000, 1);
        let b = pixel_stats(&media, &cam, &n, 3000, 2);
        assert_agree(&a, &b, &format!("uniform vs nee, max depth {max_depth:?}"));
    }
}

#[test]
fn majorant_grid_and_global_majorant_agree() {
    let (media, cam) = lit_neghip();
    let mut global = media.clone();
    global.medium.set_macrocell_size(1 << 20).unwrap();
    assert_eq!(global.medium.majorants().cell_count(), 1);
    let s = PathSettings {
        integrator: IntegratorKind::Nee,
        max_depth: Some(8),
        rr_start_depth: 3,
        show_lights: true,
    };
    let a = pixel_stats(&media, &cam, &s, 3000, 4);
    let b = pixel_stats(&global, &cam, &s, 3000, 5);
    assert_agree(&a, &b, "macrocells vs global majorant");
}

/// Single scattering of a tiny light (radius 1e-4 at distance 10) in a thin slab, against the
/// closed form integrated in f64: L = int sigma_s e^(-sigma t) (1/4pi) Le Omega e^(-sigma s) dt.
#[test]
fn tiny_light_single_scattering_matches_quadrature() {
    let sigma = 0.5f32;
    let medium = homogeneous(sigma, Vec3::ONE, 1.0, 8);
    let r = 1e-4f64;
    let c = DVec3::new(0.0, 10.0, 0.0);
    let le = 1e9f32;
    let scene = scene(
        medium,
        Phase::Isotropic,
        Lights {
            lights: vec![Light::Sphere(SphereLight {
                center: c.as_vec3(),
                radius: r as f32,
                radiance: Vec3::splat(le),
            })],
            environment: Vec3::ZERO,
        },
    );
    let o = Vec3::new(0.0, 0.0, -5.0);
    let settings = PathSettings {
        integrator: IntegratorKind::Nee,
        max_depth: Some(1),
        rr_start_depth: 3,
        show_lights: true,
    };
    let (mean, var) = path_stats(&scene, &settings, o, Vec3::Z, 400_000, 8);

    let steps = 100_000;
    let s = sigma as f64;
    let exact: f64 = (0..steps)
        .map(|i| {
            let z = -0.5 + (i as f64 + 0.5) / steps as f64;
            let x = DVec3::new(0.0, 0.0, z);
            let to = c - x;
            let d = to.length();
            let sin2 = r * r / (d * d);
            let omega = 2.0 * std::f64::consts::PI * sin2 / (1.0 + (1.0 - sin2).sqrt());
            // Length inside the box towards the light: leaves through y = 0.5.
            let inside = 0.5 * d / to.y;
            s * (-s * (z + 0.5)).exp() / (4.0 * std::f64::consts::PI)
                * le as f64
                * omega
                * (-s * inside).exp()
                / steps as f64
        })
        .sum();
    let se = var[0].sqrt();
    eprintln!("tiny light: {} vs {exact} (se {se})", mean[0]);
    assert!(
        (mean[0] - exact).abs() <= 5.0 * se && se < 0.01 * exact,
        "{} vs {exact} (se {se})",
        mean[0]
    );
}

/// Single scattering of a distant light in a homogeneous cube, against the closed form. The
/// camera ray runs along +z through the centre of the unit cube; the light travels along -x, so
/// every point of the ray is 0.5 from the face it enters by and
/// L = albedo E (1/4pi) e^(-sigma/2) (1 - e^(-sigma)).
///
/// Statistic: the mean of 2^25 paths per channel against the closed form, |z| < 5 (two-sided
/// false alarm 5.7e-7 a channel). Measured relative sd 0.77 a path, so the standard error is
/// 1.3e-4 of the mean: a 0.1% bias is 7.6 standard errors. Giving the delta light a MIS weight
/// (the power heuristic against the phase pdf) instead of 1 fails it.
#[test]
fn distant_light_single_scattering_in_a_homogeneous_cube_matches_the_closed_form() {
    use rayon::prelude::*;
    use volume_pt::DistantLight;
    let sigma = 1.0f32;
    let albedo = Vec3::new(0.9, 0.5, 0.2);
    let irradiance = Vec3::new(3.0, 2.0, 1.0);
    let scene = scene(
        homogeneous(sigma, albedo, 1.0, 8),
        Phase::Isotropic,
        Lights {
            lights: vec![Light::Distant(DistantLight {
                direction: Vec3::NEG_X,
                irradiance,
            })],
            environment: Vec3::ZERO,
        },
    );
    let settings = PathSettings {
        integrator: IntegratorKind::Nee,
        max_depth: Some(1),
        rr_start_depth: 3,
        show_lights: true,
    };
    let o = Vec3::new(0.0, 0.0, -5.0);
    let chunks = 32u64;
    let per_chunk = 1u64 << 20;
    let sums: Vec<([f64; 3], [f64; 3])> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let (mut s, mut s2) = ([0.0f64; 3], [0.0f64; 3]);
            for i in 0..per_chunk {
                let mut rng = SampleStream::new(11, c, i);
                let l = radiance(&scene, &settings, o, Vec3::Z, &mut rng);
                for k in 0..3 {
                    s[k] += l[k] as f64;
                    s2[k] += (l[k] as f64).powi(2);
                }
            }
            (s, s2)
        })
        .collect();
    let n = (chunks * per_chunk) as f64;
    let s = sigma as f64;
    let shape = (-s * 0.5).exp() * (1.0 - (-s).exp()) / (4.0 * std::f64::consts::PI);
    for k in 0..3 {
        let sum: f64 = sums.iter().map(|x| x.0[k]).sum();
        let sum2: f64 = sums.iter().map(|x| x.1[k]).sum();
        let mean = sum / n;
        let se = ((sum2 / n - mean * mean) / (n - 1.0)).sqrt();
        let exact = albedo[k] as f64 * irradiance[k] as f64 * shape;
        let z = (mean - exact) / se;
        eprintln!(
            "distant light, channel {k}: {mean} vs {exact} (z {z:.2}, se/mean {:.2e})",
            se / mean
        );
        assert!(z.abs() < 5.0, "channel {k}: {mean} vs {exact}, z = {z}");
    }
    // Only next-event estimation finds a delta light: phase sampling alone sees nothing.
    let uniform = PathSettings {
        integrator: IntegratorKind::Uniform,
        ..settings
    };
    let (mean, _) = path_stats(&scene, &uniform, o, Vec3::Z, 1000, 12);
    assert_eq!(mean, [0.0; 3]);
}

/// `show_lights = false`: camera rays pass through the light spheres (a pixel fully covered by
/// the default scene's bright disc drops to what lies behind it), while every pixel whose rays
/// cannot reach a sphere is bit for bit the same (it draws the same random numbers), and the
/// spheres still light the volume.
#[test]
fn hidden_lights_are_not_seen_by_the_camera() {
    use volume_pt::{Film, render};
    let path =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/scenes/default.toml");
    let mut scene = load_scene(&path).unwrap();
    scene.camera = scene.camera.with_size(64, 64).unwrap();
    let image = |show: bool| {
        let mut settings = scene.settings;
        settings.spp = 4;
        settings.path.show_lights = show;
        let mut film = Film::new(64, 64);
        render(
            &scene.media,
            &scene.camera,
            &settings,
            &mut film,
            &volume_pt::Control::none(),
        );
        film.mean()
    };
    let (shown, hidden) = (image(true), image(false));
    let lights = &scene.media.lights;
    let (mut covered, mut clear, mut lit) = (0, 0, 0);
    for y in 0..64u32 {
        for x in 0..64u32 {
            let hits = |u: f32, v: f32| {
                let d = scene.camera.ray_direction(x as f32 + u, y as f32 + v);
                lights.nearest(scene.camera.position, d, 0.0).is_some()
            };
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)];
            let i = (y * 64 + x) as usize;
            if corners.iter().all(|&(u, v)| hits(u, v)) {
                covered += 1;
                assert!(
                    shown[i].min_element() > 50.0,
                    "pixel ({x}, {y}): {}",
                    shown[i]
                );
                assert!(
                    hidden[i].max_element() < 5.0,
                    "pixel ({x}, {y}): {}",
                    hidden[i]
                );
            } else if !corners.iter().any(|&(u, v)| hits(u, v)) {
                clear += 1;
                assert_eq!(shown[i], hidden[i], "pixel ({x}, {y})");
                if hidden[i].max_element() > 0.2 {
                    lit += 1;
                }
            }
        }
    }
    assert!(
        covered >= 1 && clear > 3000 && lit > 300,
        "{covered} {clear} {lit}"
    );
}
