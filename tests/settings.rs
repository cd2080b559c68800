//! One settings type for each cache: the experiment file's `cache` keys, `gscache render`'s
//! `--cache-KEY` flags and the C ABI's `GsCacheConfig` fields are the same list, and a setting
//! written as flags reads back as the same value; the neural cache's `nrc` keys and `--nrc-KEY`
//! flags likewise.

use clap::{Args, FromArgMatches};
use experiments::method::CacheSettings;
use gs_cache::{CacheConfig, Lookup, Optimizer};
use nrc_cache::NrcConfig;

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
        c_deep: 1.75,
        threshold: 0.75,
        min_coverage: 0.4,
        max_bias: 0.07,
        early: false,
        natural: false,
        survivor_weights: true,
        stopper_weights: false,
        channel_weights: false,
        weighted_loss: false,
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
        unbiased: true,
        min_continuation: 0.2,
        continuation_scale: 0.75,
        densify_every: 7,
        densify_bias: 0.05,
        densify_max: 2.5,
    };
    let args = changed.changed_flags();
    // Every field differs from its default, so every field is written.
    assert_eq!(args.len(), 2 * serde_keys().len(), "{args:?}");
    let m = command().try_get_matches_from(&args).unwrap();
    assert_eq!(CacheConfig::from_arg_matches(&m).unwrap(), changed);
    // The defaults need no flags at all.
    assert!(CacheConfig::default().changed_flags().is_empty());
}

fn nrc_command() -> clap::Command {
    NrcConfig::augment_args(clap::Command::new("t").no_binary_name(true))
}

#[test]
fn every_neural_cache_key_is_a_flag_and_every_flag_a_key() {
    let mut flags: Vec<String> = nrc_command()
        .get_arguments()
        .filter_map(|a| a.get_long().map(str::to_string))
        .collect();
    let mut keys: Vec<String> = toml::Table::try_from(NrcConfig::default())
        .unwrap()
        .keys()
        .map(|k| format!("nrc-{}", k.replace('_', "-")))
        .collect();
    flags.sort();
    keys.sort();
    assert_eq!(flags, keys);
    let m = nrc_command()
        .try_get_matches_from(Vec::<String>::new())
        .unwrap();
    assert_eq!(
        NrcConfig::from_arg_matches(&m).unwrap(),
        NrcConfig::default()
    );
}

#[test]
fn neural_cache_settings_written_as_flags_read_back_the_same() {
    let changed = NrcConfig {
        grid_levels: 4,
        grid_features: 4,
        grid_log2_table: 12,
        grid_base_resolution: 8,
        grid_finest_resolution: 32,
        hidden_width: 32,
        hidden_layers: 3,
        input_albedo: true,
        input_value: true,
        input_direction: true,
        learning_rate: 3e-3,
        beta1: 0.8,
        beta2: 0.95,
        epsilon: 1e-10,
        loss_epsilon: 0.02,
        batch_size: 1024,
        steps_per_frame: 2,
        training_fraction: 0.1,
        c: 0.25,
        threshold: 0.75,
        seed: 7,
    };
    let args = changed.changed_flags();
    let keys = toml::Table::try_from(NrcConfig::default()).unwrap().len();
    assert_eq!(args.len(), 2 * keys, "{args:?}");
    let m = nrc_command().try_get_matches_from(&args).unwrap();
    assert_eq!(NrcConfig::from_arg_matches(&m).unwrap(), changed);
    assert!(NrcConfig::default().changed_flags().is_empty());
}

/// The settings a denoised image's cache changes are the ones named as its keys (the program
/// and Python keep a user's choice of any of them by those names).
#[test]
fn the_denoiser_settings_are_the_keys_named_for_them() {
    let plain = toml::Table::try_from(CacheConfig::default()).unwrap();
    let denoised = toml::Table::try_from(CacheConfig::default().for_denoiser()).unwrap();
    let mut changed: Vec<&str> = plain
        .keys()
        .filter(|k| plain[*k] != denoised[*k])
        .map(String::as_str)
        .collect();
    let mut named = CacheConfig::FOR_DENOISER_KEYS.to_vec();
    changed.sort();
    named.sort();
    assert_eq!(changed, named);
    CacheConfig::default().for_denoiser().validate().unwrap();
}
