//! The `gscache render` command line that renders a method's image exactly as the experiment
//! runner does (the same image, bit for bit): what a report prints so a reader can reproduce any
//! row, and what a test holds to that promise. Both render through a render session, whose one
//! sampling rule (frame `k` of `s` spp takes sample indices `k*s .. (k+1)*s`) makes a run's
//! image at `n` spp the same as one render of `n` spp, or of `n` frames of 1 spp.

use super::config::{DenoiseSpec, MethodSpec};
use std::path::Path;

/// `--PREFIX-KEY VALUE` for each of `config`'s keys whose value differs from `defaults`'.
pub fn flag_args<T: serde::Serialize>(prefix: &str, config: &T, defaults: &T) -> Vec<String> {
    let table = toml::Table::try_from(config).expect("settings are plain TOML values");
    let defaults = toml::Table::try_from(defaults).expect("settings are plain TOML values");
    let mut args = Vec::new();
    for (key, value) in &table {
        if defaults.get(key) == Some(value) {
            continue;
        }
        args.push(format!("--{prefix}-{}", key.replace('_', "-")));
        args.push(match value {
            toml::Value::String(s) => s.clone(),
            other => short_value(other),
        });
    }
    args
}

/// The arguments of `gscache render` that render `method`'s image of `spp` samples per pixel
/// (the `spp` of a run's row, whatever its budget) with `seed` at `width` x `height`: for a
/// cache, `spp` frames of 1 spp after its warm-up along the same orbit; for a denoised twin,
/// denoised as `denoise` (the experiment's) says.
pub fn render_args(
    scene: &Path,
    width: u32,
    height: u32,
    method: &MethodSpec,
    denoise: Option<&DenoiseSpec>,
    seed: u64,
    spp: u32,
) -> Vec<String> {
    let per_frame = if method.has_cache() { 1 } else { spp };
    let mut args = vec![
        "render".to_string(),
        scene.display().to_string(),
        "--width".into(),
        width.to_string(),
        "--height".into(),
        height.to_string(),
        "--spp".into(),
        per_frame.to_string(),
        "--integrator".into(),
        method.integrator.to_string(),
        "--seed".into(),
        seed.to_string(),
    ];
    args.extend(method.cache.render_flags(spp));
    // A twin is the method's image denoised with the runner's settings, which the program's
    // flags repeat where they differ from the program's defaults.
    if let Some(guides) = method.denoised {
        let options = denoise.map_or(denoise::Options::default(), DenoiseSpec::options);
        args.extend([
            "--denoise".into(),
            "--denoise-guides".into(),
            guides.to_string(),
        ]);
        if options.quality != denoise::Options::default().quality {
            args.extend(["--denoise-quality".into(), options.quality.to_string()]);
        }
        if guides != denoise::Guides::None && !options.prefilter {
            args.push("--denoise-raw-guides".into());
        }
    }
    args
}

/// [`render_args`] as one line a shell takes.
pub fn render_command(
    scene: &Path,
    width: u32,
    height: u32,
    method: &MethodSpec,
    denoise: Option<&DenoiseSpec>,
    seed: u64,
    spp: u32,
) -> String {
    let quote = |a: &str| {
        if a.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=,".contains(c))
        {
            a.to_string()
        } else {
            format!("'{}'", a.replace('\'', r"'\''"))
        }
    };
    let args: Vec<String> = render_args(scene, width, height, method, denoise, seed, spp)
        .iter()
        .map(|a| quote(a))
        .collect();
    format!("gscache {}", args.join(" "))
}

/// A setting's value as it was typed: an f32 setting in its shortest form that reads back the
/// same (`0.1`, not the f64 expansion `0.10000000149011612` that serialising it gives).
pub fn short_value(value: &toml::Value) -> String {
    match value {
        toml::Value::Float(f) if (*f as f32) as f64 == *f => format!("{}", *f as f32),
        other => other.to_string(),
    }
}

/// Settings as `key = value, ...` (an experiment file's table), values as typed.
pub fn settings_text<T: serde::Serialize>(settings: &T) -> String {
    let Ok(table) = toml::Table::try_from(settings) else {
        return String::new();
    };
    table
        .iter()
        .map(|(k, v)| format!("{k} = {}", short_value(v)))
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use gs_cache::CacheConfig;

    #[test]
    fn settings_print_as_they_were_typed() {
        let c = CacheConfig {
            lr_color: 0.3,
            c: 0.7,
            ..Default::default()
        };
        let args = crate::method::CacheSettings::changed_flags(&c);
        let at = args.iter().position(|a| a == "--cache-lr-color").unwrap();
        assert_eq!(args[at + 1], "0.3");
        let text = settings_text(&c);
        assert!(
            text.contains("lr_color = 0.3,") && text.contains("c = 0.7,"),
            "{text}"
        );
        assert!(
            !text.contains("0.30000001") && !text.contains("0.69999998"),
            "{text}"
        );
    }
}
