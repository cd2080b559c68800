//! What a neural radiance cache is asked to be: its encoding, its network, how it learns and how
//! many paths teach it. One flat list, so the experiment file's `nrc` table and this struct have
//! the same keys. Defaults follow Müller et al. (2021) where a CPU can afford them; the
//! docs of each key say where and why they differ.

use serde::{Deserialize, Serialize};

/// Everything that defines a neural radiance cache: the experiment file's `nrc` keys (serde)
/// and, with the `clap` feature, `gscache render`'s `--nrc-KEY VALUE` flags, as the Gaussian
/// cache's `CacheConfig` has `--cache-KEY` (a test holds the lists equal).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(deny_unknown_fields, default)]
pub struct NrcConfig {
    /// Levels of the multiresolution hash grid (Müller et al., 2022: 16; 8 here: as good on
    /// the bundled volumes, whose radiance is smooth, and half the gathers).
    #[cfg_attr(feature = "clap", arg(id = "nrc-grid-levels", long = "nrc-grid-levels", default_value_t = DEFAULT.grid_levels))]
    pub grid_levels: u32,
    /// Features per level (2, as in the hash-grid paper).
    #[cfg_attr(feature = "clap", arg(id = "nrc-grid-features", long = "nrc-grid-features", default_value_t = DEFAULT.grid_features))]
    pub grid_features: u32,
    /// log2 of the entries per level's table. 2^14 (not the GPU's 2^19): on a CPU the lookup's
    /// cache misses grow with the table (a 2^16 table made the encoding 3x slower), and a
    /// volume's scattered radiance has far less detail than a scene's appearance.
    #[cfg_attr(feature = "clap", arg(id = "nrc-grid-log2-table", long = "nrc-grid-log2-table", default_value_t = DEFAULT.grid_log2_table))]
    pub grid_log2_table: u32,
    /// Cells along each axis of the coarsest level.
    #[cfg_attr(feature = "clap", arg(id = "nrc-grid-base-resolution", long = "nrc-grid-base-resolution", default_value_t = DEFAULT.grid_base_resolution))]
    pub grid_base_resolution: u32,
    /// Cells along each axis of the finest level; the levels are spaced geometrically between.
    /// 64: finer grids (256, 512) measured no better and trained slower on the bundled
    /// volumes, whose multiply-scattered radiance varies over several voxels.
    #[cfg_attr(feature = "clap", arg(id = "nrc-grid-finest-resolution", long = "nrc-grid-finest-resolution", default_value_t = DEFAULT.grid_finest_resolution))]
    pub grid_finest_resolution: u32,
    /// Neurons per hidden layer (64, as in the NRC paper).
    #[cfg_attr(feature = "clap", arg(id = "nrc-hidden-width", long = "nrc-hidden-width", default_value_t = DEFAULT.hidden_width))]
    pub hidden_width: u32,
    /// Hidden layers. The NRC paper uses 5; 2 here: 5 measured no lower error on the bundled
    /// volumes at 320x180 and cost 1.5-2x the inference and training time.
    #[cfg_attr(feature = "clap", arg(id = "nrc-hidden-layers", long = "nrc-hidden-layers", default_value_t = DEFAULT.hidden_layers))]
    pub hidden_layers: u32,
    /// The albedo at the vertex as an input (the NRC paper feeds the material's albedo). Off by
    /// default: the cached quantity is per unit of throughput, the albedo already divided out,
    /// and with it as an input the error at equal time was 1.3x higher on neghip (the GSCache
    /// paper also found positions alone best).
    #[cfg_attr(feature = "clap", arg(id = "nrc-input-albedo", long = "nrc-input-albedo", action = clap::ArgAction::Set, default_value_t = DEFAULT.input_albedo))]
    pub input_albedo: bool,
    /// The data value at the vertex (the transfer function's argument) as an input (off by
    /// default, as the albedo).
    #[cfg_attr(feature = "clap", arg(id = "nrc-input-value", long = "nrc-input-value", action = clap::ArgAction::Set, default_value_t = DEFAULT.input_value))]
    pub input_value: bool,
    /// The direction the path arrived from as an input (second-order spherical harmonics).
    /// Off by default: the GSCache paper found positions alone better for volumes, whose
    /// radiance past the first bounce is nearly isotropic (exact for an isotropic phase).
    #[cfg_attr(feature = "clap", arg(id = "nrc-input-direction", long = "nrc-input-direction", action = clap::ArgAction::Set, default_value_t = DEFAULT.input_direction))]
    pub input_direction: bool,
    /// Adam's learning rate (the NRC paper: 1e-2 for the grid and the network alike).
    #[cfg_attr(feature = "clap", arg(id = "nrc-learning-rate", long = "nrc-learning-rate", default_value_t = DEFAULT.learning_rate))]
    pub learning_rate: f64,
    /// Adam's first-moment decay.
    #[cfg_attr(feature = "clap", arg(id = "nrc-beta1", long = "nrc-beta1", default_value_t = DEFAULT.beta1))]
    pub beta1: f64,
    /// Adam's second-moment decay (0.99, the hash-grid paper's choice for sparse updates).
    #[cfg_attr(feature = "clap", arg(id = "nrc-beta2", long = "nrc-beta2", default_value_t = DEFAULT.beta2))]
    pub beta2: f64,
    /// Adam's epsilon.
    #[cfg_attr(feature = "clap", arg(id = "nrc-epsilon", long = "nrc-epsilon", default_value_t = DEFAULT.epsilon))]
    pub epsilon: f64,
    /// The relative L2 loss's `eps` in `(prediction - target)^2 / (prediction^2 + eps)`
    /// (prediction held constant in the denominator).
    #[cfg_attr(feature = "clap", arg(id = "nrc-loss-epsilon", long = "nrc-loss-epsilon", default_value_t = DEFAULT.loss_epsilon))]
    pub loss_epsilon: f32,
    /// Training records per optimiser step.
    #[cfg_attr(feature = "clap", arg(id = "nrc-batch-size", long = "nrc-batch-size", default_value_t = DEFAULT.batch_size))]
    pub batch_size: u32,
    /// Largest number of optimiser steps per frame (the NRC paper: 4); fewer when the frame
    /// produced fewer than `steps_per_frame * batch_size` records.
    #[cfg_attr(feature = "clap", arg(id = "nrc-steps-per-frame", long = "nrc-steps-per-frame", default_value_t = DEFAULT.steps_per_frame))]
    pub steps_per_frame: u32,
    /// Fraction of each frame's paths traced to their end as training paths (the NRC paper:
    /// about 3% of 1920x1080; more here because CPU frames are small).
    #[cfg_attr(feature = "clap", arg(id = "nrc-training-fraction", long = "nrc-training-fraction", default_value_t = DEFAULT.training_fraction))]
    pub training_fraction: f32,
    /// The GSCache paper's Algorithm 1 coefficient C, shared with the Gaussian cache: the
    /// GSCache paper compares NRC with the same termination heuristic.
    #[cfg_attr(feature = "clap", arg(id = "nrc-c", long = "nrc-c", default_value_t = DEFAULT.c))]
    pub c: f32,
    /// Algorithm 1's threshold.
    #[cfg_attr(feature = "clap", arg(id = "nrc-threshold", long = "nrc-threshold", default_value_t = DEFAULT.threshold))]
    pub threshold: f32,
    /// Seed of the weights' initialisation.
    #[cfg_attr(feature = "clap", arg(id = "nrc-seed", long = "nrc-seed", default_value_t = DEFAULT.seed))]
    pub seed: u64,
}

impl Default for NrcConfig {
    fn default() -> Self {
        DEFAULT
    }
}

/// The defaults, as a constant: the command line's flags show them.
pub const DEFAULT: NrcConfig = NrcConfig {
    grid_levels: 8,
    grid_features: 2,
    grid_log2_table: 14,
    grid_base_resolution: 16,
    grid_finest_resolution: 64,
    hidden_width: 64,
    hidden_layers: 2,
    input_albedo: false,
    input_value: false,
    input_direction: false,
    learning_rate: 1e-2,
    beta1: 0.9,
    beta2: 0.99,
    epsilon: 1e-15,
    loss_epsilon: 1e-2,
    batch_size: 4096,
    steps_per_frame: 4,
    training_fraction: 0.06,
    c: 0.5,
    threshold: 0.9,
    seed: 0,
};

/// A setting outside what the cache can work with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("nrc setting `{key}` = {value}: expected {expected}")]
pub struct ConfigError {
    pub key: &'static str,
    pub value: String,
    pub expected: &'static str,
}

impl NrcConfig {
    /// Checks every setting; NaN fails every range check.
    pub fn validate(&self) -> Result<(), ConfigError> {
        fn check(
            ok: bool,
            key: &'static str,
            value: impl std::fmt::Display,
            expected: &'static str,
        ) -> Result<(), ConfigError> {
            if ok {
                Ok(())
            } else {
                Err(ConfigError {
                    key,
                    value: value.to_string(),
                    expected,
                })
            }
        }
        let c = self;
        check(
            (1..=32).contains(&c.grid_levels),
            "grid_levels",
            c.grid_levels,
            "1 to 32",
        )?;
        check(
            matches!(c.grid_features, 1 | 2 | 4 | 8),
            "grid_features",
            c.grid_features,
            "1, 2, 4 or 8",
        )?;
        check(
            (8..=24).contains(&c.grid_log2_table),
            "grid_log2_table",
            c.grid_log2_table,
            "8 to 24",
        )?;
        check(
            (2..=4096).contains(&c.grid_base_resolution),
            "grid_base_resolution",
            c.grid_base_resolution,
            "2 to 4096",
        )?;
        check(
            c.grid_finest_resolution >= c.grid_base_resolution
                && c.grid_finest_resolution <= 1 << 16,
            "grid_finest_resolution",
            c.grid_finest_resolution,
            "at least grid_base_resolution and at most 65536",
        )?;
        check(
            (1..=1024).contains(&c.hidden_width),
            "hidden_width",
            c.hidden_width,
            "1 to 1024",
        )?;
        check(
            (1..=16).contains(&c.hidden_layers),
            "hidden_layers",
            c.hidden_layers,
            "1 to 16",
        )?;
        check(
            c.learning_rate > 0.0 && c.learning_rate < 10.0,
            "learning_rate",
            c.learning_rate,
            "a rate in (0, 10)",
        )?;
        check(
            c.beta1 >= 0.0 && c.beta1 < 1.0,
            "beta1",
            c.beta1,
            "a decay in [0, 1)",
        )?;
        check(
            c.beta2 >= 0.0 && c.beta2 < 1.0,
            "beta2",
            c.beta2,
            "a decay in [0, 1)",
        )?;
        check(
            c.epsilon > 0.0 && c.epsilon < 1.0,
            "epsilon",
            c.epsilon,
            "a value in (0, 1)",
        )?;
        check(
            c.loss_epsilon > 0.0 && c.loss_epsilon.is_finite(),
            "loss_epsilon",
            c.loss_epsilon,
            "a finite value > 0",
        )?;
        check(
            (1..=1 << 20).contains(&c.batch_size),
            "batch_size",
            c.batch_size,
            "1 to 1048576",
        )?;
        check(
            c.steps_per_frame <= 64,
            "steps_per_frame",
            c.steps_per_frame,
            "0 to 64",
        )?;
        check(
            c.training_fraction >= 0.0 && c.training_fraction <= 1.0,
            "training_fraction",
            c.training_fraction,
            "a fraction in [0, 1]",
        )?;
        check(
            c.c >= 0.0 && c.c.is_finite(),
            "c",
            c.c,
            "a finite value >= 0",
        )?;
        check(
            c.threshold >= 0.0 && c.threshold <= 1.0,
            "threshold",
            c.threshold,
            "a probability in [0, 1]",
        )?;
        Ok(())
    }

    /// Inputs beside the grid's features: albedo (3), value (1), direction (9).
    pub fn extra_inputs(&self) -> usize {
        3 * self.input_albedo as usize
            + self.input_value as usize
            + 9 * self.input_direction as usize
    }

    /// Width of the network's input: the grid's features and the extra inputs.
    pub fn input_width(&self) -> usize {
        (self.grid_levels * self.grid_features) as usize + self.extra_inputs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_nan_is_refused() {
        NrcConfig::default().validate().unwrap();
        let bad = NrcConfig {
            learning_rate: f64::NAN,
            ..Default::default()
        };
        let e = bad.validate().unwrap_err();
        assert_eq!(e.key, "learning_rate");
        let bad = NrcConfig {
            training_fraction: f32::NAN,
            ..Default::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "training_fraction");
        let bad = NrcConfig {
            grid_features: 3,
            ..Default::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("1, 2, 4 or 8")
        );
    }
}
