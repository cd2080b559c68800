//! Saving and loading a cache: one 3DGS PLY file per level (`length_1.ply`, `length_2.ply`, ...,
//! named by the path length each holds), which any splat viewer opens.

use crate::cache::GsCache;
use crate::config::CacheConfig;
use crate::error::{CacheError, Result};
use splat_raster::io::{read_ply, write_ply};
use std::path::{Path, PathBuf};

/// The file holding the level for paths of length `length`.
pub fn level_path(dir: &Path, length: usize) -> PathBuf {
    dir.join(format!("length_{length}.ply"))
}

impl GsCache {
    /// Writes every level into `dir` (created if missing).
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|source| CacheError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        for (i, level) in self.levels().iter().enumerate() {
            // The files hold absolute radiance, so that viewers show what the cache holds.
            let mut cloud = level.cloud.clone();
            crate::cache::scale_colors(&mut cloud, level.radiance_scale());
            write_ply(&level_path(dir, i + 1), &cloud)?;
        }
        Ok(())
    }

    /// Reads the levels `length_1.ply`, `length_2.ply`, ... from `dir` (as many as are present
    /// in sequence) into a cache with `config`'s settings.
    pub fn load(dir: &Path, config: CacheConfig) -> Result<Self> {
        let mut clouds = Vec::new();
        while clouds.len() < crate::config::MAX_LEVELS {
            let path = level_path(dir, clouds.len() + 1);
            if !path.exists() {
                break;
            }
            let cloud = read_ply(&path)?;
            if cloud.color_model != splat_raster::ColorModel::Sh(0) {
                return Err(CacheError::Format {
                    path,
                    message: format!(
                        "colour model {:?}: a cache level has SH degree 0",
                        cloud.color_model
                    ),
                });
            }
            // A cache this crate saved has none; training from one would spread NaN.
            let unusable = cloud.count_unusable();
            if unusable > 0 {
                return Err(CacheError::Format {
                    path,
                    message: format!(
                        "{unusable} of {} Gaussians have a non-finite parameter or a zero \
                         quaternion: expected a cache level saved by gs-cache",
                        cloud.len()
                    ),
                });
            }
            clouds.push(cloud);
        }
        if clouds.is_empty() {
            return Err(CacheError::Format {
                path: level_path(dir, 1),
                message: "no cache level found: expected length_1.ply, length_2.ply, ...".into(),
            });
        }
        let mut config = config;
        config.points = clouds[0].len();
        GsCache::from_levels(clouds, config)
    }
}
