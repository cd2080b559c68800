//! Does each cache level hold what its training targets ask? For a scene at a still camera,
//! after a warm-up, every frame's drawn level (at the cache's resolution) is compared with that
//! frame's targets (the weighted mean of the paths' samples binned into each cache pixel),
//! summed over frames in f64 per level: the drawn luminance over the targets' where a target
//! exists, for all cache pixels and for each quarter of them ranked by the drawn value. A level that
//! fits its targets reads 1.0; one drawn below them reads less, and the paths that stop into it
//! take that shortfall into the image (issue 53's breakdown).
//!
//! `cargo run --release -p cached-pt --example level_fit -- data/scenes/hydrogen.toml [KEY=VALUE...]`
//! (cache keys as in an experiment file's `cache` table, JSON values: `survivor_weights=true`).

use gs_cache::{CacheConfig, GsCache};
use std::path::PathBuf;
use volume_pt::Control;

const WIDTH: u32 = 320;
const HEIGHT: u32 = 180;
const WARMUP: u32 = 40;
const FRAMES: u32 = 64;

fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(
        args.next()
            .ok_or("usage: level_fit SCENE.toml [KEY=VALUE...]")?,
    );
    let mut table = serde_json::to_value(CacheConfig::default())?;
    for kv in args {
        let (k, v) = kv.split_once('=').ok_or("settings are KEY=VALUE")?;
        table[k] = serde_json::from_str(v)?;
    }
    let config: CacheConfig = serde_json::from_value(table)?;
    let mut scene = volume_pt::load_scene(&path)?;
    scene.camera = scene.camera.with_size(WIDTH, HEIGHT)?;
    scene.settings.spp = 1;
    let config = config.for_image(WIDTH, HEIGHT);
    let (points, albedo) =
        cached_pt::sample_cache_points(&scene.media.medium, config.points, scene.settings.seed);
    let mut cache = GsCache::new(&points, &albedo, config)?;
    let levels = config.levels;
    // Per level and cache pixel: the drawn and target luminance summed over the frames that
    // have a target there.
    let mut sums: Vec<Vec<(f64, f64)>> = Vec::new();
    for f in 0..WARMUP + FRAMES {
        cache.begin_frame(&scene.camera);
        let drawn: Vec<Vec<[f32; 3]>> = (0..levels)
            .map(|n| cache.frame().unwrap().drawn_image(n).to_vec())
            .collect();
        // The frame traced as `cached_pt::render_cached_frame` traces it, so that its targets
        // can be read before the step.
        let mut targets = cache.take_training_targets().unwrap();
        let termination = cache.config().termination();
        let frame = cache.frame().unwrap();
        let mut film = volume_pt::Film::new(WIDTH, HEIGHT);
        let traced = volume_pt::render_frame_with(
            &scene.media,
            &scene.camera,
            &scene.settings,
            f,
            &mut film,
            &cached_pt::GsFrame { frame, termination },
            &Control::none(),
        );
        let tiles: Vec<_> = traced.records.iter().map(|(_, t)| t).collect();
        targets.add_tiles(&tiles);
        if f >= WARMUP {
            for n in 0..levels {
                let (target, mask) = targets.level_target(n, true);
                if sums.len() <= n {
                    sums.push(vec![(0.0, 0.0); target.len()]);
                }
                for (i, ((t, m), d)) in target.iter().zip(&mask).zip(&drawn[n]).enumerate() {
                    if *m {
                        sums[n][i].0 += luminance(*d);
                        sums[n][i].1 += luminance(*t);
                    }
                }
            }
        }
        drop(tiles);
        cache.train(&targets)?;
        cache.recycle_training_targets(targets);
    }
    println!(
        "{}: drawn / target luminance over {FRAMES} frames after {WARMUP}, by quarters of the \
         cache pixels ranked by their drawn value (not by the noisy targets, which would \
         select their own noise)",
        path.display()
    );
    for (n, level) in sums.iter().enumerate() {
        let mut bins: Vec<(f64, f64)> = level.iter().copied().filter(|b| b.1 != 0.0).collect();
        bins.sort_by(|a, b| a.0.total_cmp(&b.0));
        let ratio = |part: &[(f64, f64)]| {
            part.iter().map(|b| b.0).sum::<f64>() / part.iter().map(|b| b.1).sum::<f64>()
        };
        let q = bins.len() / 4;
        println!(
            "level {}: all {:.4}; quarters dim to bright {:.4} {:.4} {:.4} {:.4}",
            n + 1,
            ratio(&bins),
            ratio(&bins[..q]),
            ratio(&bins[q..2 * q]),
            ratio(&bins[2 * q..3 * q]),
            ratio(&bins[3 * q..])
        );
    }
    Ok(())
}
