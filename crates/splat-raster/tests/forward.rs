//! The tiled forward pass against the brute-force compositor, and the invariants: empty clouds,
//! hidden and culled Gaussians, degenerate parameters, thread counts, the pixel-centre convention.

mod common;

use common::*;
use glam::Vec3;
use splat_raster::raster::backward;
use splat_raster::reference::render_reference;
use splat_raster::{Camera, ColorModel, GaussianCloud, LowPass, PixelGrads, RasterConfig, render};

fn max_diff(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs()))
        .fold(0.0, f32::max)
}

#[test]
fn tiled_forward_equals_brute_force() {
    for (seed, model, lp) in [
        (1, ColorModel::Rgb, LowPass::Classic),
        (2, ColorModel::Sh(3), LowPass::Mip),
        (3, ColorModel::Sh(0), LowPass::Classic),
    ] {
        // Many overlapping Gaussians so that transmittance reaches the early stop.
        let mut cloud = random_cloud(300, model, seed).cast::<f32>();
        for v in cloud.opacity_logits.iter_mut() {
            *v += 2.0;
        }
        let cam = camera(67, 45); // not a multiple of the tile size
        let cfg = RasterConfig {
            low_pass: lp,
            background: [0.1, 0.2, 0.3],
            depth: true,
            ..Default::default()
        };
        let (tiled, state) = render(&cloud, &cam, &cfg);
        let reference = render_reference(&cloud, &cam, &cfg);
        let d = max_diff(&tiled.color, &reference.color);
        let dt = tiled
            .transmittance
            .iter()
            .zip(&reference.transmittance)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        let dd = tiled
            .depth
            .as_ref()
            .unwrap()
            .iter()
            .zip(reference.depth.as_ref().unwrap())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(
            d <= 1e-6 && dt <= 1e-6 && dd <= 1e-5,
            "{model:?}: colour {d}, T {dt}, depth {dd}"
        );
        assert!(
            tiled.transmittance.iter().any(|&t| t < 0.01),
            "the early stop is not exercised"
        );
        assert!(state.visible_count() > 200);
    }
}

#[test]
fn empty_cloud_gives_the_background() {
    let cloud = GaussianCloud::<f32>::new(ColorModel::Rgb);
    let cam = camera(33, 17);
    let cfg = RasterConfig {
        background: [0.25, 0.5, 2.0],
        ..Default::default()
    };
    let (out, _) = render(&cloud, &cam, &cfg);
    assert!(out.color.iter().all(|c| *c == [0.25, 0.5, 2.0]));
    assert!(out.transmittance.iter().all(|&t| t == 1.0));
}

#[test]
fn hidden_and_culled_gaussians_do_not_change_the_image() {
    let cloud = random_cloud(40, ColorModel::Rgb, 5).cast::<f32>();
    let cam = camera(48, 32);
    let cfg = RasterConfig::default();
    let (base, _) = render(&cloud, &cam, &cfg);
    let mut more = cloud.clone();
    let col = [5.0, 5.0, 5.0];
    // Behind the camera, outside the view, too faint to reach alpha 1/255, behind the near plane.
    more.push([0.3, -0.2, -6.0], [0.0; 3], [1.0, 0.0, 0.0, 0.0], &col, 3.0);
    more.push([40.0, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], &col, 3.0);
    more.push([0.0, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], &col, -9.0);
    more.push(
        [0.3, -0.2, -3.995],
        [-3.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        &col,
        3.0,
    );
    let (with, _) = render(&more, &cam, &cfg);
    assert_eq!(base.color, with.color);
    // Hidden behind an opaque wall: a wall of splats that takes T below 1e-4 everywhere.
    let mut wall = GaussianCloud::<f32>::new(ColorModel::Rgb);
    for i in 0..8 {
        wall.push(
            [0.3, -0.2, -2.0 + 0.01 * i as f32],
            [1.5, 1.5, -3.0],
            [1.0, 0.0, 0.0, 0.0],
            &[0.5, 0.5, 0.5],
            8.0,
        );
    }
    let (wall_only, _) = render(&wall, &cam, &cfg);
    // The early stop has triggered at every pixel (T is left between 1e-4 and 1e-2).
    assert!(wall_only.transmittance.iter().all(|&t| t < 1e-2));
    let mut wall_and_more = wall.clone();
    for g in 0..more.len() {
        let s = 3 * g;
        wall_and_more.push(
            [more.means[s], more.means[s + 1], more.means[s + 2]],
            [
                more.log_scales[s],
                more.log_scales[s + 1],
                more.log_scales[s + 2],
            ],
            [
                more.rotations[4 * g],
                more.rotations[4 * g + 1],
                more.rotations[4 * g + 2],
                more.rotations[4 * g + 3],
            ],
            &more.colors[s..s + 3],
            more.opacity_logits[g],
        );
    }
    let (behind, _) = render(&wall_and_more, &cam, &cfg);
    assert_eq!(wall_only.color, behind.color);
}

#[test]
fn degenerate_gaussians_never_reach_image_or_gradients() {
    let mut cloud = random_cloud(20, ColorModel::Sh(1), 9).cast::<f32>();
    let col = vec![0.3f32; 12];
    // (mean, log-scale, rotation, opacity logit)
    type Params = ([f32; 3], [f32; 3], [f32; 4], f32);
    let bad: [Params; 9] = [
        ([f32::NAN, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0),
        ([0.0, 0.0, 0.0], [f32::NAN; 3], [1.0, 0.0, 0.0, 0.0], 0.0),
        ([0.0, 0.0, 0.0], [-1.0; 3], [0.0, 0.0, 0.0, 0.0], 0.0),
        (
            [0.0, 0.0, 0.0],
            [-1.0; 3],
            [f32::INFINITY, 0.0, 0.0, 0.0],
            0.0,
        ),
        (
            [0.0, 0.0, 0.0],
            [f32::NEG_INFINITY; 3],
            [1.0, 0.0, 0.0, 0.0],
            2.0,
        ),
        (
            [0.0, 0.0, 0.0],
            [60.0, 60.0, 60.0],
            [1.0, 0.0, 0.0, 0.0],
            0.0,
        ),
        (
            [0.0, 0.0, 0.0],
            [-1.0, 89.0, -1.0],
            [0.3, 0.1, 0.2, 0.9],
            0.0,
        ),
        (
            [0.0, 0.0, f32::INFINITY],
            [-1.0; 3],
            [1.0, 0.0, 0.0, 0.0],
            0.0,
        ),
        ([0.0, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], f32::NAN),
    ];
    for (m, s, q, o) in bad {
        cloud.push(m, s, q, &col, o);
    }
    let cam = camera(40, 30);
    let cfg = RasterConfig::default();
    let (out, state) = render(&cloud, &cam, &cfg);
    assert!(out.color.iter().all(|c| c.iter().all(|v| v.is_finite())));
    assert!(out.transmittance.iter().all(|t| t.is_finite()));
    let ones = vec![[1.0f32; 3]; out.color.len()];
    let g = backward(
        &cloud,
        &cam,
        &state,
        PixelGrads {
            color: &ones,
            transmittance: None,
            depth: None,
        },
    );
    for (name, v) in g.groups() {
        assert!(
            v.iter().all(|x| x.is_finite()),
            "{name} has a non-finite gradient"
        );
    }
}

#[test]
fn one_and_two_threads_give_identical_images_and_gradients() {
    let cloud = random_cloud(500, ColorModel::Sh(2), 4).cast::<f32>();
    let cam = camera(96, 64);
    let cfg = RasterConfig {
        depth: true,
        ..Default::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let (out, state) = render(&cloud, &cam, &cfg);
                let up: Vec<[f32; 3]> = (0..out.color.len())
                    .map(|i| [(i % 7) as f32 - 3.0, 1.0, 0.5])
                    .collect();
                let g = backward(
                    &cloud,
                    &cam,
                    &state,
                    PixelGrads {
                        color: &up,
                        transmittance: None,
                        depth: None,
                    },
                );
                (out.color, g)
            })
    };
    let (c1, g1) = run(1);
    let (c2, g2) = run(2);
    let (c3, g3) = run(3);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(c1, c2);
    assert_eq!(c1, c3);
    for ((a, b), c) in g1
        .groups()
        .iter()
        .zip(g2.groups().iter())
        .zip(g3.groups().iter())
    {
        assert_eq!(bits(a.1), bits(b.1), "{}", a.0);
        assert_eq!(bits(a.1), bits(c.1), "{}", a.0);
    }
}

#[test]
fn pixel_centre_convention_holds() {
    // A tiny Gaussian on the ray through the centre of pixel (12, 7) lands in that pixel only,
    // symmetric about it.
    let cam =
        Camera::look_at(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 40.0, 32, 24).unwrap();
    let p = cam.position + 5.0 * cam.ray_direction(12.5, 7.5);
    let mut cloud = GaussianCloud::<f32>::new(ColorModel::Rgb);
    cloud.push(
        p.to_array(),
        [-6.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        &[1.0, 1.0, 1.0],
        5.0,
    );
    let (out, _) = render(&cloud, &cam, &RasterConfig::default());
    let at = |x: u32, y: u32| out.color[(y * 32 + x) as usize][0];
    let centre = at(12, 7);
    assert!(centre > 0.5, "{centre}");
    assert!((at(11, 7) - at(13, 7)).abs() < 1e-5 && (at(12, 6) - at(12, 8)).abs() < 1e-5);
    assert!(at(11, 7) < centre && at(12, 6) < centre);
}
