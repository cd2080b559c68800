//! The cache: a [`HashGrid`] and an [`Mlp`], read in batches ([`NeuralCache::predict`]) and
//! trained in batches ([`NeuralCache::train`]) with the relative L2 loss and Adam.

use crate::config::{ConfigError, NrcConfig};
use crate::encoding::HashGrid;
use crate::mlp::{Adam, BlockWork, Gradient, Mlp};
use crate::random::SplitMix;
use glam::Vec3;
use rayon::prelude::*;

/// Where the cache is read: a path vertex.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Query {
    /// The vertex in the unit cube of the volume's bounds.
    pub position: Vec3,
    /// Unit direction the path arrived along.
    pub direction: Vec3,
    /// Single-scattering albedo at the vertex.
    pub albedo: Vec3,
    /// The data value at the vertex (the transfer function's argument), in [0, 1].
    pub value: f32,
}

/// A training record: a vertex of a training path, and the radiance the path gathered from
/// that vertex on per unit of its throughput there (the cache's target quantity).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TrainingRecord {
    pub query: Query,
    pub target: Vec3,
}

/// What one call to [`NeuralCache::train`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrainReport {
    /// Optimiser steps taken.
    pub steps: u32,
    /// Records the steps used.
    pub records: usize,
    /// Records refused (a target negative or not finite).
    pub refused: usize,
    /// Steps skipped because the loss was not finite (no parameter changed).
    pub skipped_steps: u32,
    /// Mean loss over the steps taken (before each step).
    pub mean_loss: f64,
}

/// Rows per inference batch: bounds the activations' memory (rows x width floats per layer).
const INFERENCE_ROWS: usize = 1024;

/// A neural radiance cache (Müller et al., 2021).
pub struct NeuralCache {
    config: NrcConfig,
    grid: HashGrid,
    mlp: Mlp,
    adam: Adam,
    /// The network's gradient and its scratch, kept between steps so no step allocates them.
    gradient: Gradient,
    /// A step's batch as the network and the grid read it, kept between steps likewise.
    batch: StepBatch,
    /// The tables' gradient, kept between steps so no step allocates it.
    grid_grad: Vec<f32>,
    steps: u64,
}

impl NeuralCache {
    /// A fresh cache (tables near zero, network He-initialised) from `config`, after checking it.
    pub fn new(config: NrcConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        let grid = HashGrid::new(&config, config.seed);
        let mlp = Mlp::new(
            config.input_width(),
            config.hidden_width as usize,
            config.hidden_layers as usize,
            config.seed ^ 0x004d_4c50,
        );
        let grid_grad = vec![0.0; grid.params().len()];
        Ok(Self {
            config,
            grid,
            mlp,
            adam: Adam::default(),
            gradient: Gradient::default(),
            batch: StepBatch::default(),
            grid_grad,
            steps: 0,
        })
    }

    pub fn config(&self) -> &NrcConfig {
        &self.config
    }

    /// Changes how many paths train the cache and how many steps it takes per frame (0 steps
    /// freezes it: it is read, never changed). The other settings fix the cache's shape and
    /// stay as built.
    pub fn set_training(
        &mut self,
        training_fraction: f32,
        steps_per_frame: u32,
    ) -> Result<(), ConfigError> {
        let config = NrcConfig {
            training_fraction,
            steps_per_frame,
            ..self.config
        };
        config.validate()?;
        self.config = config;
        Ok(())
    }

    pub fn grid(&self) -> &HashGrid {
        &self.grid
    }

    /// The network.
    pub fn network(&self) -> &Mlp {
        &self.mlp
    }

    pub fn grid_mut(&mut self) -> &mut HashGrid {
        &mut self.grid
    }

    /// Optimiser steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Bytes of parameters (tables and weights) and optimiser state.
    pub fn parameter_bytes(&self) -> usize {
        // The weights, and Adam's two moments of each.
        self.grid.bytes() + 3 * 4 * self.mlp.num_params()
    }

    /// Multiply-adds of one inference (the network only; the encoding adds 8 gathers per level).
    pub fn macs_per_query(&self) -> usize {
        self.mlp.macs_per_row()
    }

    /// The cached radiance at each query: never negative, never NaN (a NaN output reads as 0).
    pub fn predict(&self, queries: &[Query]) -> Vec<Vec3> {
        predict_with(&self.config, &self.grid, &self.mlp, queries)
    }

    /// Trains on `records` (a frame's training paths): draws up to `steps_per_frame *
    /// batch_size` of them at random (with `shuffle_seed`), then takes up to `steps_per_frame`
    /// Adam steps of `batch_size` records each, fewer when there are fewer records. Records
    /// whose target is negative or not finite are refused.
    pub fn train(&mut self, records: &[TrainingRecord], shuffle_seed: u64) -> TrainReport {
        let mut report = TrainReport::default();
        let mut usable: Vec<TrainingRecord> = records
            .iter()
            .filter(|r| {
                let ok = r.target.is_finite()
                    && r.target.min_element() >= 0.0
                    && r.query.position.is_finite()
                    && r.query.albedo.is_finite()
                    && r.query.direction.is_finite()
                    && r.query.value.is_finite();
                if !ok {
                    report.refused += 1;
                }
                ok
            })
            .copied()
            .collect();
        // A partial Fisher-Yates shuffle: the first `wanted` records become a uniform random
        // selection in random order, at a cost in the selection, not in all the records (a
        // 1280x720 frame files ten times what four steps use).
        let batch = self.config.batch_size as usize;
        let wanted = usable
            .len()
            .min(batch * self.config.steps_per_frame as usize);
        let mut rng = SplitMix::new(shuffle_seed);
        let n = usable.len();
        for i in 0..wanted {
            let j = i + (rng.next_u64() % (n - i) as u64) as usize;
            usable.swap(i, j);
        }
        usable.truncate(wanted);
        let mut loss_sum = 0.0;
        for chunk in usable
            .chunks(batch)
            .take(self.config.steps_per_frame as usize)
        {
            // A tail much smaller than a batch would be a noisy step: only full batches, or
            // the one batch there is.
            if chunk.len() < batch / 2 && report.steps > 0 {
                break;
            }
            match self.step(chunk) {
                Some(loss) => {
                    report.steps += 1;
                    report.records += chunk.len();
                    loss_sum += loss;
                }
                None => report.skipped_steps += 1,
            }
        }
        if report.steps > 0 {
            report.mean_loss = loss_sum / report.steps as f64;
        }
        report
    }

    /// One Adam step on `batch`; the loss before it, or `None` (nothing changed) when the loss
    /// or a gradient is not finite.
    fn step(&mut self, batch: &[TrainingRecord]) -> Option<f64> {
        let width = self.config.input_width();
        let StepBatch {
            queries,
            positions,
            rows,
            targets,
        } = &mut self.batch;
        queries.clear();
        queries.extend(batch.iter().map(|r| r.query));
        positions.clear();
        positions.extend(batch.iter().map(|r| r.query.position));
        targets.clear();
        targets.extend(batch.iter().flat_map(|r| r.target.to_array()));
        encode_inputs(&self.config, &self.grid, queries, rows);
        let loss =
            self.mlp
                .loss_and_gradient(rows, targets, self.config.loss_epsilon, &mut self.gradient);
        let finite = |g: &[f32]| g.iter().all(|g| g.is_finite());
        if !loss.is_finite() || !finite(&self.gradient.params) || !finite(&self.gradient.inputs) {
            return None;
        }
        self.grid.backward(
            &self.batch.positions,
            &self.gradient.inputs,
            width,
            &mut self.grid_grad,
        );
        let lr = self.config.learning_rate;
        let (beta1, beta2, epsilon) = (self.config.beta1, self.config.beta2, self.config.epsilon);
        self.adam.step(
            &mut self.mlp,
            &self.gradient.params,
            lr,
            beta1,
            beta2,
            epsilon,
        );
        self.grid
            .adam_step(&mut self.grid_grad, lr, beta1, beta2, epsilon);
        self.steps += 1;
        Some(loss)
    }
}

/// [`NeuralCache::step`]'s batch: its queries, their positions, the network's input rows and the
/// targets (3 a record).
#[derive(Debug, Default)]
struct StepBatch {
    queries: Vec<Query>,
    positions: Vec<Vec3>,
    rows: Vec<f32>,
    targets: Vec<f32>,
}

impl std::fmt::Debug for NeuralCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NeuralCache")
            .field("config", &self.config)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

/// The network's input rows for `queries`: the grid's encoding, then the optional inputs.
fn encode_inputs(config: &NrcConfig, grid: &HashGrid, queries: &[Query], out: &mut Vec<f32>) {
    let width = config.input_width();
    let grid_width = grid.output_width();
    out.clear();
    out.resize(queries.len() * width, 0.0);
    let (albedo, value, direction) = (
        config.input_albedo,
        config.input_value,
        config.input_direction,
    );
    out.par_chunks_mut(width)
        .zip(queries.par_iter())
        .for_each(|(row, q)| {
            grid.encode(q.position, &mut row[..grid_width]);
            let mut k = grid_width;
            if albedo {
                row[k..k + 3].copy_from_slice(&q.albedo.to_array());
                k += 3;
            }
            if value {
                row[k] = q.value;
                k += 1;
            }
            if direction {
                row[k..k + 9].copy_from_slice(&spherical_harmonics_2(q.direction));
            }
        });
}

/// The radiance `net` and `grid` predict at each query: never negative, never NaN (a NaN output
/// reads as 0). Chunks of queries run in parallel, each through the whole network: small
/// matrices stay in cache, which measured faster than one large product per layer
/// (BENCHMARKS.md).
fn predict_with(config: &NrcConfig, grid: &HashGrid, net: &Mlp, queries: &[Query]) -> Vec<Vec3> {
    let mut radiance = vec![Vec3::ZERO; queries.len()];
    radiance
        .par_chunks_mut(INFERENCE_ROWS)
        .zip(queries.par_chunks(INFERENCE_ROWS))
        .for_each_init(
            || (Vec::new(), Vec::new(), BlockWork::default()),
            |(rows, outputs, work), (radiance, chunk)| {
                encode_inputs(config, grid, chunk, rows);
                outputs.resize(chunk.len() * 3, 0.0);
                net.forward(rows, outputs, work);
                for (r, c) in radiance.iter_mut().zip(outputs.chunks_exact(3)) {
                    // `max` returns the other operand for NaN: a NaN channel becomes 0.
                    *r = Vec3::new(c[0].max(0.0), c[1].max(0.0), c[2].max(0.0))
                        .min(Vec3::splat(f32::MAX));
                }
            },
        );
    radiance
}

/// Real spherical harmonics of bands 0 to 2 at a unit direction.
pub fn spherical_harmonics_2(d: Vec3) -> [f32; 9] {
    let (x, y, z) = (d.x, d.y, d.z);
    [
        render_base::SH_C0,
        0.488_602_5 * y,
        0.488_602_5 * z,
        0.488_602_5 * x,
        1.092_548_4 * x * y,
        1.092_548_4 * y * z,
        0.315_391_57 * (3.0 * z * z - 1.0),
        1.092_548_4 * x * z,
        0.546_274_2 * (x * x - y * y),
    ]
}
