//! `weighted_loss`: a level trained on frames whose samples weigh differently holds their
//! pooled weighted mean, as one fit of all the frames' samples would, where one share of the
//! loss per cache pixel and frame holds the mean of the frames' means.

use glam::Vec3;
use gs_cache::{CacheConfig, GsCache};
use splat_raster::Camera;

/// A one-level cache of a 4x4x4 grid of points drawn at 16x16 from a camera looking at it.
fn cache(config: CacheConfig) -> (GsCache, Camera) {
    let points: Vec<Vec3> = (0..64)
        .map(|i| Vec3::new((i % 4) as f32, ((i / 4) % 4) as f32, (i / 16) as f32))
        .collect();
    let albedo = vec![Vec3::splat(0.8); points.len()];
    let config = CacheConfig {
        levels: 1,
        points: points.len(),
        resolution_divisor: 1,
        ..config
    };
    let cache = GsCache::new(&points, &albedo, config).unwrap();
    let camera = Camera::look_at(
        Vec3::new(1.5, 1.5, 12.0),
        Vec3::new(1.5, 1.5, 1.5),
        Vec3::Y,
        40.0,
        16,
        16,
    )
    .unwrap();
    (cache, camera)
}

/// Trains for 400 frames on samples `frame_samples(frame)` = (value, weight) at every pixel,
/// and returns the centre pixel's value averaged over the last 40 frames (so the swing of
/// alternating frames cancels).
fn settled_value(
    config: CacheConfig,
    weighted_loss: bool,
    frame_samples: impl Fn(usize) -> (f32, f32),
) -> f32 {
    let (mut cache, camera) = cache(CacheConfig {
        weighted_loss,
        ..config
    });
    let centre = 8 * 16 + 8;
    let (frames, averaged) = (400, 40);
    let mut sum = 0.0f64;
    for frame in 0..frames {
        cache.begin_frame(&camera);
        if frame >= frames - averaged {
            sum += cache.frame().unwrap().value(0, centre).x as f64;
        }
        let mut targets = cache.take_training_targets().unwrap();
        let (value, weight) = frame_samples(frame);
        for pixel in 0..256 {
            targets.add_weighted(0, pixel, [value; 3], weight);
        }
        cache.train(&targets).unwrap();
        cache.recycle_training_targets(targets);
    }
    (sum / averaged as f64) as f32
}

/// Frames alternate between samples of 1 weighing 1 and samples of 5 weighing 3. Pooled, their
/// weighted mean is (1 + 3 * 5) / 4 = 4; the mean of the frames' means is 3.
///
/// Fitted by least squares alone (the warm start throughout, colours only), a level's value is
/// linear in its targets: each run is compared with a control trained on that constant every
/// frame (a level does not draw its target exactly: 64 Gaussians over 16x16 pixels), within 3%
/// (the controls lie 29% apart, and a weighted loss that did not pool would land at 3/4 of its
/// control).
///
/// Trained by Adam after the warm start (the default), both alternating runs settle below their
/// controls (Adam's bounded steps on targets that swing 5x from frame to frame: 16-18% here),
/// but the weighted one stays above the unweighted by the pooled means' ratio 4/3, within 8%.
#[test]
fn a_level_holds_the_pooled_weighted_mean_of_its_frames() {
    let alternating = |frame: usize| {
        if frame.is_multiple_of(2) {
            (1.0, 1.0)
        } else {
            (5.0, 3.0)
        }
    };
    let least_squares = CacheConfig {
        warm_start_frames: 1000,
        lr_position: 0.0,
        lr_opacity: 0.0,
        lr_rotation: 0.0,
        ..CacheConfig::default()
    };
    let weighted = settled_value(least_squares, true, alternating);
    let unweighted = settled_value(least_squares, false, alternating);
    let four = settled_value(least_squares, true, |_| (4.0, 1.0));
    let three = settled_value(least_squares, false, |_| (3.0, 1.0));
    eprintln!(
        "least squares: weighted {weighted} (control {four}), unweighted {unweighted} (control {three})"
    );
    assert!(
        (weighted / four - 1.0).abs() < 0.03,
        "weighted loss: {weighted}, want {four}"
    );
    assert!(
        (unweighted / three - 1.0).abs() < 0.03,
        "one share a pixel: {unweighted}, want {three}"
    );
    let adam = CacheConfig::default();
    let ratio = settled_value(adam, true, alternating) / settled_value(adam, false, alternating);
    eprintln!("Adam: weighted / unweighted {ratio}");
    assert!(
        (ratio / (4.0 / 3.0) - 1.0).abs() < 0.08,
        "Adam: weighted / unweighted {ratio}"
    );
}
