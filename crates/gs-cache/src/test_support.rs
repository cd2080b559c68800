//! Fixtures the crate's unit tests share.

use crate::{CacheConfig, GsCache};
use glam::Vec3;
use splat_raster::Camera;

/// A one-level cache of a 4x4x4 grid of 64 points (albedo 0.8) with `config`'s other settings,
/// and a 16x16 camera looking at the grid.
pub(crate) fn grid_cache(config: CacheConfig) -> (GsCache, Camera) {
    let points: Vec<Vec3> = (0..64)
        .map(|i| Vec3::new((i % 4) as f32, ((i / 4) % 4) as f32, (i / 16) as f32))
        .collect();
    let albedo = vec![Vec3::splat(0.8); points.len()];
    let config = CacheConfig {
        levels: 1,
        points: points.len(),
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
