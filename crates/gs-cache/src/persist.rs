//! Saving and loading a cache: one 3DGS PLY file per level (`length_1.ply`, `length_2.ply`, ...,
//! named by the path length each holds), which any splat viewer opens, and `manifest.json`,
//! which says what the folder holds.
//!
//! A save is whole or absent. The levels and the manifest are written into a fresh folder
//! beside the target, then moved into its place; a folder a previous save left there is
//! replaced as a whole (never a mixture of two saves: saving 2 levels over 5 once left the old
//! levels 3 to 5 to be loaded with the new ones), and a folder that holds anything else is
//! refused. A load reads the manifest and refuses a folder without one, or whose files disagree
//! with it (a level missing, one more, one changed, or one cut short by a killed save).

use crate::cache::GsCache;
use crate::config::CacheConfig;
use crate::error::{CacheError, Result};
use serde::{Deserialize, Serialize};
use splat_raster::io::{read_ply, write_ply};
use std::path::{Path, PathBuf};

/// The manifest's file name inside a cache folder.
pub const MANIFEST: &str = "manifest.json";

/// What the manifest calls the folder's format, and its version.
const FORMAT: &str = "gs-cache levels";
const VERSION: u32 = 1;

/// The largest manifest read (a real one is well under 4 KiB).
const MAX_MANIFEST_BYTES: u64 = 1 << 20;

/// The file holding the level for paths of length `length`.
pub fn level_path(dir: &Path, length: usize) -> PathBuf {
    dir.join(format!("length_{length}.ply"))
}

/// `manifest.json`: the levels a save wrote, each with its size and checksum, and the settings
/// of the cache that wrote them.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    pub levels: Vec<LevelRecord>,
    /// The saving cache's settings (its level count is `levels.len()`).
    pub config: CacheConfig,
}

/// One level's file as written.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LevelRecord {
    pub file: String,
    pub gaussians: usize,
    pub bytes: u64,
    /// FNV-1a (64 bits) of the file's bytes, 16 hex digits.
    pub fnv1a64: String,
}

fn checksum(bytes: &[u8]) -> String {
    format!(
        "{:016x}",
        render_base::hash::fnv1a64(bytes, render_base::hash::FNV_OFFSET)
    )
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

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CacheError + '_ {
    move |source| CacheError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn format_error(path: &Path, message: impl Into<String>) -> CacheError {
    CacheError::Format {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Whether `name` is a file a save writes (a level or the manifest).
fn is_cache_file(name: &str) -> bool {
    name == MANIFEST
        || name
            .strip_prefix("length_")
            .and_then(|n| n.strip_suffix(".ply"))
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Checks that `dir`, where it exists, is a folder a save may replace: empty, or holding only
/// what a save writes (a previous save, with or without a manifest).
fn check_replaceable(dir: &Path) -> Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(dir) else {
        return Ok(());
    };
    if !meta.is_dir() {
        return Err(format_error(
            dir,
            "is not a folder: expected a folder for the cache's levels (or a new name)",
        ));
    }
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let entry = entry.map_err(io(dir))?;
        let name = entry.file_name();
        let name = name.to_string_lossy();
        let is_file = entry.file_type().is_ok_and(|t| t.is_file());
        if !(is_file && is_cache_file(&name)) {
            return Err(format_error(
                dir,
                format!(
                    "holds `{name}`, which no cache save writes: not replaced (choose an empty or new folder)"
                ),
            ));
        }
    }
    Ok(())
}

/// A name beside `dir` that nothing uses: `.NAME.WHAT-PID-N`.
fn sibling(dir: &Path, what: &str) -> PathBuf {
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "cache".into());
    let parent = dir.parent().unwrap_or(Path::new("."));
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    parent.join(format!(".{name}.{what}-{}-{stamp}", std::process::id()))
}

impl GsCache {
    /// Writes every level and the manifest into `dir`, whole (see the module docs): into a
    /// fresh folder beside it, then moved into its place. A previous save there is replaced;
    /// a folder holding anything else is refused.
    pub fn save(&self, dir: &Path) -> Result<()> {
        refuse_empty(dir)?;
        check_replaceable(dir)?;
        let parent = match dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            Some(p) => p,
            None => Path::new("."),
        };
        std::fs::create_dir_all(parent).map_err(io(parent))?;
        let fresh = sibling(dir, "saving");
        std::fs::create_dir(&fresh).map_err(io(&fresh))?;
        let written = self.write_levels(&fresh);
        let moved = written.and_then(|()| move_into_place(&fresh, dir));
        if moved.is_err() {
            let _ = std::fs::remove_dir_all(&fresh);
        }
        moved
    }

    /// Writes the levels and the manifest into the empty folder `dir`.
    fn write_levels(&self, dir: &Path) -> Result<()> {
        let mut levels = Vec::new();
        for (i, level) in self.levels().iter().enumerate() {
            // The files hold absolute radiance, so that viewers show what the cache holds.
            let mut cloud = level.cloud.clone();
            crate::cache::scale_colors(&mut cloud, level.radiance_scale());
            let path = level_path(dir, i + 1);
            write_ply(&path, &cloud)?;
            let bytes = std::fs::read(&path).map_err(io(&path))?;
            levels.push(LevelRecord {
                file: format!("length_{}.ply", i + 1),
                gaussians: cloud.len(),
                bytes: bytes.len() as u64,
                fnv1a64: checksum(&bytes),
            });
        }
        let manifest = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            levels,
            config: *self.config(),
        };
        let text = serde_json::to_string_pretty(&manifest)
            .map_err(|e| format_error(dir, format!("cannot write the manifest: {e}")))?;
        let path = dir.join(MANIFEST);
        render_base::write_atomically(&path, |f| {
            std::io::Write::write_all(f, text.as_bytes()).map_err(|e| e.to_string())
        })
        .map_err(|e| format_error(&path, e.message))
    }

    /// Reads the levels a save wrote into `dir`, checked against its manifest (see the module
    /// docs), into a cache with `config`'s settings; the level count and the first level's
    /// size are the saved cache's.
    pub fn load(dir: &Path, config: CacheConfig) -> Result<Self> {
        refuse_empty(dir)?;
        let manifest = read_manifest(dir)?;
        let mut clouds = Vec::new();
        for (i, record) in manifest.levels.iter().enumerate() {
            let path = level_path(dir, i + 1);
            let bytes = std::fs::read(&path).map_err(io(&path))?;
            if bytes.len() as u64 != record.bytes || checksum(&bytes) != record.fnv1a64 {
                return Err(format_error(
                    &path,
                    format!(
                        "{} bytes with checksum {}, but the manifest says {} bytes with checksum {}: the level was changed, or cut short by a save that did not finish",
                        bytes.len(),
                        checksum(&bytes),
                        record.bytes,
                        record.fnv1a64
                    ),
                ));
            }
            let cloud = read_ply(&path)?;
            if cloud.color_model != splat_raster::ColorModel::Sh(0) {
                return Err(format_error(
                    &path,
                    format!(
                        "colour model {:?}: a cache level has SH degree 0",
                        cloud.color_model
                    ),
                ));
            }
            // A cache this crate saved has none; training from one would spread NaN.
            let unusable = cloud.count_unusable();
            if unusable > 0 {
                return Err(format_error(
                    &path,
                    format!(
                        "{unusable} of {} Gaussians have a non-finite parameter or a zero \
                         quaternion: expected a cache level saved by gs-cache",
                        cloud.len()
                    ),
                ));
            }
            clouds.push(cloud);
        }
        let mut config = config;
        config.points = clouds[0].len();
        GsCache::from_levels(clouds, config)
    }
}

/// Reads and checks `dir`'s manifest: its format, a level count of 1 to [`MAX_LEVELS`], and
/// the folder's level files exactly those it lists.
///
/// [`MAX_LEVELS`]: crate::config::MAX_LEVELS
pub fn read_manifest(dir: &Path) -> Result<Manifest> {
    let path = dir.join(MANIFEST);
    let meta = match std::fs::metadata(&path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let message = if level_path(dir, 1).exists() {
                "missing: the levels beside it were saved by an older gs-cache, or by a save that did not finish; save the cache again"
            } else {
                "missing: not a cache folder (expected the folder a cache save wrote: manifest.json, length_1.ply, ...)"
            };
            return Err(format_error(&path, message));
        }
        Err(e) => return Err(io(&path)(e)),
    };
    if !meta.is_file() || meta.len() > MAX_MANIFEST_BYTES {
        return Err(format_error(
            &path,
            format!(
                "not a manifest: expected a file of at most {MAX_MANIFEST_BYTES} bytes (found {} bytes, {})",
                meta.len(),
                if meta.is_file() {
                    "a file"
                } else {
                    "not a file"
                }
            ),
        ));
    }
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let manifest: Manifest = serde_json::from_str(&text)
        .map_err(|e| format_error(&path, format!("not a cache manifest: {e}")))?;
    if manifest.format != FORMAT || manifest.version != VERSION {
        return Err(format_error(
            &path,
            format!(
                "format `{}` version {}: expected `{FORMAT}` version {VERSION}",
                manifest.format, manifest.version
            ),
        ));
    }
    let count = manifest.levels.len();
    if !(1..=crate::config::MAX_LEVELS).contains(&count) {
        return Err(format_error(
            &path,
            format!(
                "{count} levels: expected 1 to {}",
                crate::config::MAX_LEVELS
            ),
        ));
    }
    for (i, record) in manifest.levels.iter().enumerate() {
        let expected = format!("length_{}.ply", i + 1);
        if record.file != expected {
            return Err(format_error(
                &path,
                format!(
                    "level {} is `{}`: expected `{expected}`",
                    i + 1,
                    record.file
                ),
            ));
        }
    }
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let name = entry.map_err(io(dir))?.file_name();
        let name = name.to_string_lossy();
        if name != MANIFEST
            && is_cache_file(&name)
            && !manifest.levels.iter().any(|r| r.file == name)
        {
            return Err(format_error(
                dir,
                format!(
                    "holds `{name}`, which its manifest ({count} levels) does not list: a mixture of two saves; save the cache again into an empty folder"
                ),
            ));
        }
    }
    Ok(manifest)
}

/// Moves the complete folder `fresh` to `dir`: a previous save there is first moved aside,
/// then removed once the new one is in place (a crash between the two renames leaves it
/// beside, under `.NAME.replaced-*`, not lost).
fn move_into_place(fresh: &Path, dir: &Path) -> Result<()> {
    if std::fs::symlink_metadata(dir).is_ok() {
        let aside = sibling(dir, "replaced");
        std::fs::rename(dir, &aside).map_err(io(dir))?;
        if let Err(e) = std::fs::rename(fresh, dir) {
            let _ = std::fs::rename(&aside, dir);
            return Err(io(dir)(e));
        }
        let _ = std::fs::remove_dir_all(&aside);
        Ok(())
    } else {
        std::fs::rename(fresh, dir).map_err(io(dir))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use splat_raster::{ColorModel, GaussianCloud};

    /// Writes the manifest a save would for the `levels` PLY files already in `dir` (levels
    /// made by hand, as a test of what load does with their contents).
    fn sign(dir: &Path, levels: usize) {
        let levels = (1..=levels)
            .map(|l| {
                let bytes = std::fs::read(level_path(dir, l)).unwrap();
                LevelRecord {
                    file: format!("length_{l}.ply"),
                    gaussians: read_ply(&level_path(dir, l)).map_or(0, |c| c.len()),
                    bytes: bytes.len() as u64,
                    fnv1a64: checksum(&bytes),
                }
            })
            .collect();
        let manifest = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            levels,
            config: CacheConfig::default(),
        };
        std::fs::write(
            dir.join(MANIFEST),
            serde_json::to_string(&manifest).unwrap(),
        )
        .unwrap();
    }

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
        sign(&dir, 1);
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
        sign(&dir, 1);
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
        sign(&dir, 3);
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

    /// A cache of `levels` levels of 32, 16, 8, ... Gaussians.
    fn cache_of(levels: usize) -> GsCache {
        let clouds = (0..levels)
            .map(|l| {
                let mut cloud = GaussianCloud::<f32>::new(ColorModel::Sh(0));
                for i in 0..(32 >> l) {
                    cloud.push(
                        [i as f32, l as f32, 0.0],
                        [-2.0; 3],
                        [1.0, 0.0, 0.0, 0.0],
                        &[0.1; 3],
                        0.0,
                    );
                }
                cloud
            })
            .collect();
        GsCache::from_levels(clouds, CacheConfig::default()).unwrap()
    }

    fn scratch(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("gs-cache-persist-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut n: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        n.sort();
        n
    }

    /// Issue 48, item 6: saving 2 levels over a save of 3 left `length_3.ply`, and the load then
    /// mixed the two saves. A save now replaces the folder whole, and a load refuses a folder
    /// whose files disagree with its manifest.
    #[test]
    fn a_save_replaces_the_previous_one_whole_and_a_mixture_is_refused() {
        let root = scratch("stale");
        let dir = root.join("levels");
        cache_of(3).save(&dir).unwrap();
        assert_eq!(
            GsCache::load(&dir, CacheConfig::default())
                .unwrap()
                .levels()
                .len(),
            3
        );
        let third = std::fs::read(level_path(&dir, 3)).unwrap();
        cache_of(2).save(&dir).unwrap();
        assert_eq!(names(&dir), ["length_1.ply", "length_2.ply", MANIFEST]);
        assert_eq!(
            GsCache::load(&dir, CacheConfig::default())
                .unwrap()
                .levels()
                .len(),
            2
        );
        // Nothing left beside it (the fresh folder was moved, the old one removed).
        assert_eq!(names(&root), ["levels"]);
        // A level from another save put back beside them: a mixture, refused.
        std::fs::write(level_path(&dir, 3), &third).unwrap();
        let e = GsCache::load(&dir, CacheConfig::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("length_3.ply") && e.contains("mixture"), "{e}");
        std::fs::remove_file(level_path(&dir, 3)).unwrap();
        // A level cut short (a save killed while writing it, under the old writer): refused.
        let second = std::fs::read(level_path(&dir, 2)).unwrap();
        std::fs::write(level_path(&dir, 2), &second[..second.len() / 2]).unwrap();
        let e = GsCache::load(&dir, CacheConfig::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("length_2.ply") && e.contains("cut short"), "{e}");
        // A level missing.
        std::fs::remove_file(level_path(&dir, 2)).unwrap();
        let e = GsCache::load(&dir, CacheConfig::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("length_2.ply"), "{e}");
        // No manifest: levels of an older save, or of one that did not finish.
        std::fs::remove_file(dir.join(MANIFEST)).unwrap();
        let e = GsCache::load(&dir, CacheConfig::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("manifest.json") && e.contains("missing"), "{e}");
        let _ = std::fs::remove_dir_all(&root);
    }

    /// A save never replaces a folder holding anything a save does not write: the user's
    /// files stay as they were.
    #[test]
    fn a_save_into_a_folder_of_other_files_is_refused() {
        let root = scratch("foreign");
        std::fs::write(root.join("notes.txt"), "mine").unwrap();
        let e = cache_of(2).save(&root).err().unwrap().to_string();
        assert!(e.contains("notes.txt") && e.contains("not replaced"), "{e}");
        assert_eq!(names(&root), ["notes.txt"]);
        assert_eq!(
            std::fs::read_to_string(root.join("notes.txt")).unwrap(),
            "mine"
        );
        // Nothing was left beside it either.
        assert_eq!(
            names(root.parent().unwrap())
                .iter()
                .filter(|n| n.contains(&format!("gs-cache-persist-{}-foreign", std::process::id())))
                .count(),
            1
        );
        let _ = std::fs::remove_dir_all(&root);
    }
}
