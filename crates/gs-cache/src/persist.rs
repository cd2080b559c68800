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

/// An empty folder path is refused: it would mean the current folder, which the caller did not
/// name (the C ABI's `gs_cache_save(h, "")` once wrote its levels there).
fn refuse_empty(dir: &Path) -> Result<()> {
    if dir.as_os_str().is_empty() {
        return Err(CacheError::Config(
            "the cache folder path is empty: expected a folder to write the levels into".into(),
        ));
    }
    Ok(())
}

impl GsCache {
    /// Writes every level into `dir` (created if missing).
    pub fn save(&self, dir: &Path) -> Result<()> {
        refuse_empty(dir)?;
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
        refuse_empty(dir)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use splat_raster::{ColorModel, GaussianCloud};

    /// `GsCache::new` refuses non-finite points; a saved level holding them is refused the same
    /// way, naming the file, instead of spreading NaN through training.
    #[test]
    fn a_level_with_nan_gaussians_is_refused() {
        let dir = std::env::temp_dir().join(format!("gs-cache-nan-level-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut cloud = GaussianCloud::<f32>::new(ColorModel::Sh(0));
        for i in 0..8 {
            let x = if i == 3 { f32::NAN } else { i as f32 };
            cloud.push(
                [x, 0.0, 0.0],
                [-2.0; 3],
                [1.0, 0.0, 0.0, 0.0],
                &[0.1; 3],
                0.0,
            );
        }
        write_ply(&level_path(&dir, 1), &cloud).unwrap();
        let e = match GsCache::load(&dir, CacheConfig::default()) {
            Ok(_) => panic!("a NaN level was loaded"),
            Err(e) => e.to_string(),
        };
        assert!(
            e.contains("length_1.ply") && e.contains("1 of 8 Gaussians"),
            "{e}"
        );
    }

    /// A loaded cache is held to the settings checks a new one gets (it once skipped them: a
    /// NaN learning rate, or a last level of fewer than 4 Gaussians, was accepted from a file or
    /// through the C ABI's `gs_cache_load`).
    #[test]
    fn a_loaded_cache_is_validated_like_a_new_one() {
        let dir = std::env::temp_dir().join(format!("gs-cache-validated-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut cloud = GaussianCloud::<f32>::new(ColorModel::Sh(0));
        for i in 0..8 {
            cloud.push(
                [i as f32, 0.0, 0.0],
                [-2.0; 3],
                [1.0, 0.0, 0.0, 0.0],
                &[0.1; 3],
                0.0,
            );
        }
        write_ply(&level_path(&dir, 1), &cloud).unwrap();
        assert!(GsCache::load(&dir, CacheConfig::default()).is_ok());
        let bad = CacheConfig {
            lr_color: f32::NAN,
            ..Default::default()
        };
        let Err(e) = GsCache::load(&dir, bad) else {
            panic!("a NaN rate was accepted");
        };
        assert!(e.to_string().contains("lr_color"), "{e}");
        // Three levels of 8, 8 and 8 Gaussians would need at least 16 in the first.
        for l in 2..=3 {
            write_ply(&level_path(&dir, l), &cloud).unwrap();
        }
        let e = GsCache::load(&dir, CacheConfig::default())
            .err()
            .map(|e| e.to_string());
        assert!(e.is_some_and(|e| e.contains("too few")));
    }

    #[test]
    fn an_empty_folder_path_is_refused() {
        let e = GsCache::load(Path::new(""), CacheConfig::default())
            .err()
            .map(|e| e.to_string());
        assert!(e.is_some_and(|e| e.contains("path is empty")));
    }
}
