//! The `gscache render` command line that renders one frame of a method exactly as the
//! experiment runner does (the same image, bit for bit): what a report prints so a reader can
//! reproduce any row, and what a test holds to that promise.

use super::config::Method;
use super::measure::pass_seed;
use gs_cache::CacheConfig;
use nrc_cache::NrcConfig;
use std::path::Path;

/// `--cache-KEY VALUE` for every cache setting that differs from the default: the experiment
/// file's `cache` keys, spelt as the command line's flags (`lr_color` is `--cache-lr-color`).
pub fn cache_args(config: &CacheConfig) -> Vec<String> {
    let table = toml::Table::try_from(config).expect("cache settings are plain TOML values");
    let defaults = toml::Table::try_from(CacheConfig::default())
        .expect("cache settings are plain TOML values");
    let mut args = Vec::new();
    for (key, value) in &table {
        if defaults.get(key) == Some(value) {
            continue;
        }
        args.push(format!("--cache-{}", key.replace('_', "-")));
        args.push(match value {
            toml::Value::String(s) => s.clone(),
            other => other.to_string(),
        });
    }
    args
}

/// `--nrc-set KEY=VALUE` for each neural cache setting that differs from its default.
pub fn nrc_args(config: &NrcConfig) -> Vec<String> {
    let table = toml::Table::try_from(config).expect("nrc settings are plain TOML values");
    let defaults =
        toml::Table::try_from(NrcConfig::default()).expect("nrc settings are plain TOML values");
    let mut args = Vec::new();
    for (key, value) in &table {
        if defaults.get(key) == Some(value) {
            continue;
        }
        args.push("--nrc-set".into());
        args.push(format!("{key}={value}"));
    }
    args
}

/// The arguments of `gscache render` that render the first 1-spp image of `method` with `seed`
/// at `width` x `height`: for a cache, after its warm-up along the same orbit.
pub fn render_args(
    scene: &Path,
    width: u32,
    height: u32,
    method: &Method,
    seed: u64,
) -> Vec<String> {
    let mut args = vec![
        "render".to_string(),
        scene.display().to_string(),
        "--width".into(),
        width.to_string(),
        "--height".into(),
        height.to_string(),
        "--spp".into(),
        "1".into(),
        "--integrator".into(),
        method.integrator.to_string(),
    ];
    match (&method.cache, &method.nrc) {
        // Plain methods render pass k with seed pass_seed(seed, k); the first image is pass 0.
        (None, None) => args.extend(["--seed".into(), pass_seed(seed, 0).to_string()]),
        (None, Some(n)) => {
            args.extend(["--seed".into(), seed.to_string(), "--nrc".into()]);
            args.extend(nrc_args(&n.settings));
            args.extend([
                "--warmup".into(),
                n.warmup.to_string(),
                "--warmup-orbit".into(),
                n.warmup_orbit_degrees.to_string(),
            ]);
        }
        (Some(c), _) => {
            args.extend(["--seed".into(), seed.to_string(), "--cache".into()]);
            args.extend(cache_args(&c.settings));
            args.extend([
                "--warmup".into(),
                c.warmup.to_string(),
                "--warmup-orbit".into(),
                c.warmup_orbit_degrees.to_string(),
            ]);
        }
    }
    args
}

/// [`render_args`] as one line a shell takes.
pub fn render_command(scene: &Path, width: u32, height: u32, method: &Method, seed: u64) -> String {
    let quote = |a: &str| {
        if a.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=,".contains(c))
        {
            a.to_string()
        } else {
            format!("'{}'", a.replace('\'', r"'\''"))
        }
    };
    let args: Vec<String> = render_args(scene, width, height, method, seed)
        .iter()
        .map(|a| quote(a))
        .collect();
    format!("gscache {}", args.join(" "))
}
