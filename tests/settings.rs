//! One settings type for the cache: the experiment file's `cache` keys, `gscache render`'s
//! `--cache-KEY` flags and the C ABI's `GsCacheConfig` fields are the same list, and a setting
//! written as flags reads back as the same value.

use clap::{Args, FromArgMatches};
use gs_cache::{CacheConfig, Lookup, Optimizer};
use gscache_cli::experiment::command::cache_args;

fn serde_keys() -> Vec<String> {
    toml::Table::try_from(CacheConfig::default())
        .unwrap()
        .keys()
        .cloned()
        .collect()
}

fn command() -> clap::Command {
    CacheConfig::augment_args(clap::Command::new("t").no_binary_name(true))
}

#[test]
fn every_key_is_a_flag_and_every_flag_a_key() {
    let mut flags: Vec<String> = command()
        .get_arguments()
        .filter_map(|a| a.get_long().map(str::to_string))
        .collect();
    let mut keys: Vec<String> = serde_keys()
        .iter()
        .map(|k| format!("cache-{}", k.replace('_', "-")))
        .collect();
    flags.sort();
    keys.sort();
    assert_eq!(flags, keys);
}

#[test]
fn the_c_header_has_the_same_fields_in_the_same_order() {
    let header = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/gs-cache/include/gs_cache.h"),
    )
    .unwrap();
    let start = header
        .find("typedef struct GsCacheConfig {")
        .expect("GsCacheConfig in the header");
    let body = &header[start..start + header[start..].find('}').unwrap()];
    let fields: Vec<String> = body
        .lines()
        .map(str::trim)
        .filter(|l| l.ends_with(';') && !l.starts_with("/*") && !l.starts_with('*'))
        .map(|l| {
            l.trim_end_matches(';')
                .split_whitespace()
                .last()
                .unwrap()
                .to_string()
        })
        .collect();
    let mut keys = serde_keys();
    // Serde writes keys in declaration order; so does cbindgen.
    let declared: Vec<String> = {
        let src = include_str!("../crates/gs-cache/src/config.rs");
        let s = &src[src.find("pub struct CacheConfig {").unwrap()..];
        let s = &s[..s.find("\n}\n").unwrap()];
        s.lines()
            .skip(1)
            .filter_map(|l| l.trim().strip_prefix("pub "))
            .filter_map(|l| l.split(':').next())
            .map(str::to_string)
            .collect()
    };
    assert_eq!(fields, declared);
    keys.sort();
    let mut sorted = fields.clone();
    sorted.sort();
    assert_eq!(sorted, keys);
}

#[test]
fn no_flags_give_the_defaults() {
    let m = command()
        .try_get_matches_from(Vec::<String>::new())
        .unwrap();
    assert_eq!(
        CacheConfig::from_arg_matches(&m).unwrap(),
        CacheConfig::default()
    );
}

#[test]
fn settings_written_as_flags_read_back_the_same() {
    let changed = CacheConfig {
        levels: 2,
        points: 12_345,
        lookup: Lookup::Rt,
        resolution_divisor: 2,
        rt_samples: 3,
        c: 0.25,
        threshold: 0.75,
        early: false,
        natural: false,
        survivor_weights: true,
        optimizer: Optimizer::Adam,
        decay: gs_cache::Decay::Off,
        lr_position: 1e-4,
        lr_color: 0.031,
        lr_rotation: 2e-3,
        lr_scales: 0.0125,
        lr_opacity: 0.07,
        lr_multiplier: 1.5,
        weight_decay: 0.02,
        size_cap: false,
        initial_opacity: 0.3,
        train: false,
        train_every: 3,
        adaptive_training: true,
        fallback: false,
        handoff_frames: 0,
        warm_start_frames: 2,
        masked_targets: false,
        normalized_radiance: false,
    };
    let args = cache_args(&changed);
    // Every field differs from its default, so every field is written.
    assert_eq!(args.len(), 2 * serde_keys().len(), "{args:?}");
    let m = command().try_get_matches_from(&args).unwrap();
    assert_eq!(CacheConfig::from_arg_matches(&m).unwrap(), changed);
    // The defaults need no flags at all.
    assert!(cache_args(&CacheConfig::default()).is_empty());
}
