//! The network: a small ReLU MLP from the encoded inputs to RGB radiance, its forward pass, its
//! backward pass (the weights' and the inputs' gradients, for the relative L2 loss) and Adam,
//! written out over the [`crate::dense`] kernels.
//!
//! **Why not burn** (which ran this network until issue 31): its forward and backward took
//! 5.1-6.6 ms a training step on a 16-core Xeon whatever the number of threads, and 7.7 ms on
//! one core of the 2-core EPYC against 6.6-7.2 ms on two (BENCHMARKS.md). A batch of 4,096 rows
//! through 16 -> 64 -> 64 -> 3 is thin, so a general matrix library spends its time packing,
//! allocating and synchronising, not multiplying. burn stays as this module's test oracle: the
//! gradients and the optimiser are checked against its autodiff and its Adam.
//!
//! **Parallel, and the same bits on any number of threads.** A batch is cut into blocks of
//! [`BLOCK_ROWS`] rows, a fixed cut that does not depend on the threads. Each block's forward
//! and backward run on one thread and add that block's gradient and loss to its group's (a
//! group is one block, or several in order where a gradient per block would take too much
//! memory). The groups' gradients are then summed in group order. Which thread ran a group
//! changes nothing.

use crate::dense::{self, add_product, dot, transpose};
use crate::random::SplitMix;
use rayon::prelude::*;

/// Rows of a batch that one thread carries through the whole network: activations of 128 rows
/// by 64 neurons (32 KB a layer) stay in the second-level cache, and a 4,096-record batch is
/// 32 blocks, enough to share among 16 cores.
pub const BLOCK_ROWS: usize = 128;

/// The network: hidden layers of `width` neurons with ReLU, then a linear output of 3 (radiance
/// is clamped at zero where it is used, not by the network, so the loss sees negative
/// predictions).
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    /// Neurons of each layer, the inputs first and the 3 outputs last.
    dims: Vec<usize>,
    /// Every layer's weights (`fan_in x fan_out`, row-major) and then its biases, layer after
    /// layer: one flat vector, so the gradient and Adam's moments are flat vectors too.
    params: Vec<f32>,
    /// Every layer's weights transposed (`fan_out x fan_in`), for the backward pass and the
    /// narrow output layer; rebuilt whenever `params` change.
    transposed: Vec<f32>,
}

/// One layer's view of the flat parameters.
#[derive(Clone, Copy)]
struct Layer<'a> {
    fan_in: usize,
    fan_out: usize,
    weight: &'a [f32],
    bias: &'a [f32],
    weight_transposed: &'a [f32],
}

impl Mlp {
    /// A network from `inputs` through `hidden_layers` layers of `width` to 3 outputs, the
    /// weights drawn He-uniform from `seed` (each layer's `fan_in x fan_out` in row-major order),
    /// the biases zero.
    pub fn new(inputs: usize, width: usize, hidden_layers: usize, seed: u64) -> Self {
        let mut rng = SplitMix::new(seed);
        let mut dims = vec![inputs];
        dims.extend(std::iter::repeat_n(width, hidden_layers));
        dims.push(3);
        let mut params = Vec::new();
        for d in dims.windows(2) {
            let (fan_in, fan_out) = (d[0], d[1]);
            // He-uniform for ReLU layers: U(-sqrt(6 / fan_in), sqrt(6 / fan_in)).
            let bound = (6.0 / fan_in as f32).sqrt();
            params.extend((0..fan_in * fan_out).map(|_| (rng.next_f32() * 2.0 - 1.0) * bound));
            params.extend(std::iter::repeat_n(0.0, fan_out));
        }
        Self::from_parts(dims, params)
    }

    /// A network of layers `dims` (inputs first, outputs last) with parameters `params` in
    /// [`Mlp::params`]' layout.
    ///
    /// # Panics
    /// If `params` does not have the length `dims` needs, or a layer is empty.
    pub fn from_parts(dims: Vec<usize>, params: Vec<f32>) -> Self {
        assert!(
            dims.len() >= 2 && dims.iter().all(|&d| d > 0),
            "an MLP needs at least an input and an output layer, none empty: {dims:?}"
        );
        let count: usize = dims.windows(2).map(|d| (d[0] + 1) * d[1]).sum();
        assert_eq!(params.len(), count, "parameters for layers {dims:?}");
        let mut mlp = Self {
            transposed: vec![0.0; dims.windows(2).map(|d| d[0] * d[1]).sum()],
            dims,
            params,
        };
        mlp.refresh_transposed();
        mlp
    }

    /// Neurons of each layer, the inputs first and the outputs last.
    pub fn dims(&self) -> &[usize] {
        &self.dims
    }

    /// Every layer's weights (`fan_in x fan_out`, row-major) and then its biases, layer after
    /// layer.
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    pub fn inputs(&self) -> usize {
        self.dims[0]
    }

    /// Multiply-adds per row of a forward pass.
    pub fn macs_per_row(&self) -> usize {
        self.dims.windows(2).map(|d| d[0] * d[1]).sum()
    }

    /// Layers, not counting the inputs.
    fn layer_count(&self) -> usize {
        self.dims.len() - 1
    }

    /// Layer `l`'s view of the parameters, and where its weights start in them.
    fn layer(&self, l: usize) -> (Layer<'_>, usize) {
        let offset: usize = self.dims[..=l].windows(2).map(|d| (d[0] + 1) * d[1]).sum();
        let offset_transposed: usize = self.dims[..=l].windows(2).map(|d| d[0] * d[1]).sum();
        let (fan_in, fan_out) = (self.dims[l], self.dims[l + 1]);
        let layer = Layer {
            fan_in,
            fan_out,
            weight: &self.params[offset..offset + fan_in * fan_out],
            bias: &self.params[offset + fan_in * fan_out..][..fan_out],
            weight_transposed: &self.transposed[offset_transposed..][..fan_in * fan_out],
        };
        (layer, offset)
    }

    fn refresh_transposed(&mut self) {
        let mut offset = 0;
        let mut offset_transposed = 0;
        for d in self.dims.windows(2) {
            let (fan_in, fan_out) = (d[0], d[1]);
            transpose(
                &self.params[offset..],
                fan_in,
                fan_out,
                &mut self.transposed[offset_transposed..offset_transposed + fan_in * fan_out],
            );
            offset += (fan_in + 1) * fan_out;
            offset_transposed += fan_in * fan_out;
        }
    }

    /// The network's 3 outputs for each row of `inputs` (`rows x inputs()`, row-major) into
    /// `outputs` (`rows x 3`), on the calling thread: the caller parallelises over chunks of
    /// rows (inference does, 1,024 rows a chunk).
    ///
    /// # Panics
    /// If `inputs` is not a whole number of rows or `outputs` is not 3 per row.
    pub fn forward(&self, inputs: &[f32], outputs: &mut [f32], work: &mut BlockWork) {
        let width = self.inputs();
        assert!(
            inputs.len().is_multiple_of(width) && outputs.len() == inputs.len() / width * 3,
            "forward: {} inputs of width {width}, {} outputs",
            inputs.len(),
            outputs.len()
        );
        work.fit(&self.dims);
        let avx2 = dense::has_avx2();
        for (x, y) in inputs
            .chunks(BLOCK_ROWS * width)
            .zip(outputs.chunks_mut(BLOCK_ROWS * 3))
        {
            if avx2 {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `has_avx2` confirmed the processor runs AVX2 instructions.
                unsafe {
                    forward_block_avx2(self, x, work)
                };
            } else {
                forward_block(self, x, work);
            }
            y.copy_from_slice(&work.activations.last().expect("an output layer")[..y.len()]);
        }
    }

    /// The relative L2 loss of the predictions for `inputs` against `targets` (`rows x 3`), the
    /// mean over rows and channels of `(prediction - target)^2 / (prediction^2 +
    /// loss_epsilon)` with the prediction in the denominator held constant (Müller et al.,
    /// 2021: the minimiser over noisy targets is their mean, at any radiance scale); and its
    /// gradient, with respect to the parameters into `gradient.params` and to the inputs into
    /// `gradient.inputs`. Blocks run in parallel; the result is the same bits on any number of
    /// threads (module docs).
    pub fn loss_and_gradient(
        &self,
        inputs: &[f32],
        targets: &[f32],
        loss_epsilon: f32,
        gradient: &mut Gradient,
    ) -> f64 {
        self.loss_and_gradient_in_groups(
            inputs,
            targets,
            loss_epsilon,
            gradient,
            GROUP_GRADIENT_BYTES,
        )
    }

    /// [`Mlp::loss_and_gradient`] with the groups' gradients held to `group_bytes`.
    fn loss_and_gradient_in_groups(
        &self,
        inputs: &[f32],
        targets: &[f32],
        loss_epsilon: f32,
        gradient: &mut Gradient,
        group_bytes: usize,
    ) -> f64 {
        let width = self.inputs();
        let rows = inputs.len() / width;
        assert!(
            inputs.len() == rows * width && targets.len() == rows * 3,
            "loss_and_gradient: {} inputs of width {width}, {} targets",
            inputs.len(),
            targets.len()
        );
        let count = self.num_params();
        let (groups, group_rows) = gradient_groups(rows, count, group_bytes);
        gradient.group_params.clear();
        gradient.group_params.resize(groups * count, 0.0);
        gradient.group_losses.clear();
        gradient.group_losses.resize(groups, 0.0);
        gradient.inputs.clear();
        gradient.inputs.resize(rows * width, 0.0);
        // d loss / d prediction = 2 (prediction - target) / (held^2 + eps) / (3 rows).
        let scale = 2.0 / (3 * rows.max(1)) as f32;
        let avx2 = dense::has_avx2();
        inputs
            .par_chunks(group_rows * width)
            .zip(targets.par_chunks(group_rows * 3))
            .zip(gradient.group_params.par_chunks_mut(count))
            .zip(gradient.inputs.par_chunks_mut(group_rows * width))
            .zip(gradient.group_losses.par_iter_mut())
            .for_each_init(BlockWork::default, |work, ((((x, t), g), gx), loss)| {
                work.fit(&self.dims);
                // The group's blocks in order, each adding its gradient into the group's.
                for ((x, t), gx) in x
                    .chunks(BLOCK_ROWS * width)
                    .zip(t.chunks(BLOCK_ROWS * 3))
                    .zip(gx.chunks_mut(BLOCK_ROWS * width))
                {
                    let block = BlockJob {
                        inputs: x,
                        targets: t,
                        loss_epsilon,
                        scale,
                        params_gradient: g,
                        inputs_gradient: gx,
                    };
                    *loss += if avx2 {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: `has_avx2` confirmed the processor runs AVX2 instructions.
                        unsafe {
                            gradient_block_avx2(self, block, work)
                        }
                        #[cfg(not(target_arch = "x86_64"))]
                        unreachable!("has_avx2 is false off x86_64")
                    } else {
                        gradient_block(self, block, work)
                    };
                }
            });
        // The groups' gradients, summed in group order for each parameter.
        gradient.params.clear();
        gradient.params.resize(count, 0.0);
        let group_params = &gradient.group_params;
        gradient
            .params
            .par_chunks_mut(512)
            .enumerate()
            .for_each(|(chunk, sum)| {
                let start = chunk * 512;
                for group in group_params.chunks_exact(count) {
                    for (s, g) in sum.iter_mut().zip(&group[start..]) {
                        *s += g;
                    }
                }
            });
        gradient.group_losses.iter().sum::<f64>() / (3 * rows.max(1)) as f64
    }
}

/// Bytes the groups' partial gradients may take together (a step's only memory that grows with
/// the network and the batch together): 32 groups of the default network's 5,571 parameters
/// take 0.7 MB; a network of 16 layers of 1,024 (the largest the settings allow, 16.8 M
/// parameters) gets a single group.
const GROUP_GRADIENT_BYTES: usize = 64 << 20;

/// How a batch of `rows` is cut for [`Mlp::loss_and_gradient`]: into groups of whole blocks,
/// each group's gradient kept apart and the groups summed in order. One group per block while
/// their gradients fit `budget` bytes ([`GROUP_GRADIENT_BYTES`]), fewer and larger groups when
/// not. Depends on the batch and the network only, never on the threads. Returns the number of
/// groups and the rows of each (the last may have fewer).
fn gradient_groups(rows: usize, params: usize, budget: usize) -> (usize, usize) {
    let blocks = rows.div_ceil(BLOCK_ROWS).max(1);
    let affordable = (budget / (params.max(1) * 4)).max(1);
    let blocks_per_group = blocks.div_ceil(blocks.min(affordable));
    let groups = rows.div_ceil(blocks_per_group * BLOCK_ROWS);
    (groups, blocks_per_group * BLOCK_ROWS)
}

/// What a block's forward and backward need besides the network, and where its results go.
struct BlockJob<'a> {
    inputs: &'a [f32],
    targets: &'a [f32],
    loss_epsilon: f32,
    /// `2 / (3 rows)` of the whole batch: the mean's and the square's factors.
    scale: f32,
    params_gradient: &'a mut [f32],
    inputs_gradient: &'a mut [f32],
}

/// A thread's working memory for one block: every layer's activations and the backward pass's
/// deltas, sized once and reused block after block.
#[derive(Debug, Default)]
pub struct BlockWork {
    /// Each layer's outputs for the block (after ReLU for the hidden layers), `BLOCK_ROWS x
    /// fan_out`.
    activations: Vec<Vec<f32>>,
    /// d loss / d (a layer's outputs), and the same for the layer before it.
    delta: Vec<f32>,
    delta_before: Vec<f32>,
    /// A transposed operand of the weights' gradient product.
    transposed: Vec<f32>,
    /// The output layer's weight gradient, transposed (`3 x fan_in`).
    narrow_gradient: Vec<f32>,
}

impl BlockWork {
    fn fit(&mut self, dims: &[usize]) {
        let widest = dims.iter().copied().max().unwrap_or(0);
        self.activations.resize_with(dims.len() - 1, Vec::new);
        for (a, &d) in self.activations.iter_mut().zip(&dims[1..]) {
            a.resize(BLOCK_ROWS * d, 0.0);
        }
        for buffer in [
            &mut self.delta,
            &mut self.delta_before,
            &mut self.transposed,
            &mut self.narrow_gradient,
        ] {
            buffer.resize(BLOCK_ROWS * widest, 0.0);
        }
    }
}

/// The gradient [`Mlp::loss_and_gradient`] leaves, and its per-block scratch, kept between
/// steps so that no step allocates.
#[derive(Debug, Default)]
pub struct Gradient {
    /// d loss / d parameter, in [`Mlp::params`]' layout.
    pub params: Vec<f32>,
    /// d loss / d input, `rows x inputs`.
    pub inputs: Vec<f32>,
    /// Each group's gradient ([`gradient_groups`]), and its loss.
    group_params: Vec<f32>,
    group_losses: Vec<f64>,
}

/// The forward pass of one block of rows (`inputs` is at most [`BLOCK_ROWS`] rows) into
/// `work.activations`.
#[inline(always)]
fn forward_block(mlp: &Mlp, inputs: &[f32], work: &mut BlockWork) {
    let rows = inputs.len() / mlp.inputs();
    for l in 0..mlp.layer_count() {
        let (layer, _) = mlp.layer(l);
        let (fan_in, fan_out) = (layer.fan_in, layer.fan_out);
        let (before, after) = work.activations.split_at_mut(l);
        let x = if l == 0 {
            inputs
        } else {
            &before[l - 1][..rows * fan_in]
        };
        let out = &mut after[0][..rows * fan_out];
        if fan_out < 16 {
            // A narrow layer (the 3 outputs): one dot product per output, along the inputs.
            for (x, y) in x.chunks_exact(fan_in).zip(out.chunks_exact_mut(fan_out)) {
                for (o, y) in y.iter_mut().enumerate() {
                    let column = &layer.weight_transposed[o * fan_in..][..fan_in];
                    *y = layer.bias[o] + dot(x, column);
                }
            }
        } else {
            for y in out.chunks_exact_mut(fan_out) {
                y.copy_from_slice(layer.bias);
            }
            add_product(x, layer.weight, out, rows, fan_in, fan_out);
        }
        if l + 1 < mlp.layer_count() {
            for y in out.iter_mut() {
                *y = y.max(0.0);
            }
        }
    }
}

/// One block's loss (its sum over rows and channels, before the mean) and its gradient into
/// `job`'s slices: the forward pass, then back through the layers.
#[inline(always)]
fn gradient_block(mlp: &Mlp, job: BlockJob<'_>, work: &mut BlockWork) -> f64 {
    forward_block(mlp, job.inputs, work);
    let rows = job.inputs.len() / mlp.inputs();
    let outputs = &work.activations[mlp.layer_count() - 1];
    // The loss and its gradient at the outputs.
    let mut loss = 0.0f64;
    for (i, (&p, &t)) in outputs[..rows * 3].iter().zip(job.targets).enumerate() {
        let denominator = p * p + job.loss_epsilon;
        let diff = p - t;
        loss += (diff * diff / denominator) as f64;
        work.delta[i] = job.scale * diff / denominator;
    }
    // Back through the layers: each layer's weight gradient from its inputs and the delta at its
    // outputs, then the delta at its inputs.
    for l in (0..mlp.layer_count()).rev() {
        let (layer, offset) = mlp.layer(l);
        let (fan_in, fan_out) = (layer.fan_in, layer.fan_out);
        let layer_inputs: &[f32] = if l == 0 {
            job.inputs
        } else {
            &work.activations[l - 1][..rows * fan_in]
        };
        let delta = &work.delta[..rows * fan_out];
        let (weight_gradient, bias_gradient) = job.params_gradient
            [offset..offset + (fan_in + 1) * fan_out]
            .split_at_mut(fan_in * fan_out);
        if fan_out < 16 {
            // Narrow: delta^T @ inputs is fan_out x fan_in, wide along its rows.
            transpose(delta, rows, fan_out, &mut work.transposed);
            let narrow = &mut work.narrow_gradient[..fan_out * fan_in];
            narrow.fill(0.0);
            add_product(
                &work.transposed,
                layer_inputs,
                narrow,
                fan_out,
                rows,
                fan_in,
            );
            for (o, row) in narrow.chunks_exact(fan_in).enumerate() {
                for (i, g) in row.iter().enumerate() {
                    weight_gradient[i * fan_out + o] += g;
                }
            }
        } else {
            transpose(layer_inputs, rows, fan_in, &mut work.transposed);
            add_product(
                &work.transposed,
                delta,
                weight_gradient,
                fan_in,
                rows,
                fan_out,
            );
        }
        for d in delta.chunks_exact(fan_out) {
            for (b, g) in bias_gradient.iter_mut().zip(d) {
                *b += g;
            }
        }
        // The delta at the layer's inputs: delta @ weight^T, through the ReLU before it.
        let before = if l == 0 {
            &mut job.inputs_gradient[..rows * fan_in]
        } else {
            &mut work.delta_before[..rows * fan_in]
        };
        before.fill(0.0);
        add_product(
            delta,
            layer.weight_transposed,
            before,
            rows,
            fan_out,
            fan_in,
        );
        if l > 0 {
            for (d, &a) in before.iter_mut().zip(layer_inputs) {
                if a <= 0.0 {
                    *d = 0.0;
                }
            }
            std::mem::swap(&mut work.delta, &mut work.delta_before);
        }
    }
    loss
}

/// [`forward_block`] compiled for AVX2.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn forward_block_avx2(mlp: &Mlp, inputs: &[f32], work: &mut BlockWork) {
    forward_block(mlp, inputs, work)
}

/// [`gradient_block`] compiled for AVX2.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gradient_block_avx2(mlp: &Mlp, job: BlockJob<'_>, work: &mut BlockWork) -> f64 {
    gradient_block(mlp, job, work)
}

/// Adam (Kingma and Ba, 2015) over a flat parameter vector, in burn's form, which is tested
/// against: `p -= lr m sqrt(1 - beta2^t) / (1 - beta1^t) / (sqrt(v) + eps sqrt(1 - beta2^t))`.
#[derive(Debug, Clone, Default)]
pub struct Adam {
    first_moment: Vec<f32>,
    second_moment: Vec<f32>,
    steps: i32,
}

impl Adam {
    /// One step of `mlp`'s parameters along `gradient` (in [`Mlp::params`]' layout).
    pub fn step(
        &mut self,
        mlp: &mut Mlp,
        gradient: &[f32],
        lr: f64,
        beta1: f64,
        beta2: f64,
        eps: f64,
    ) {
        let n = mlp.params.len();
        assert_eq!(gradient.len(), n, "a gradient for every parameter");
        self.first_moment.resize(n, 0.0);
        self.second_moment.resize(n, 0.0);
        self.steps = self.steps.saturating_add(1);
        let (b1, b2) = (beta1 as f32, beta2 as f32);
        let c2_sqrt = (1.0 - beta2.powi(self.steps)).sqrt();
        let factor = (lr * c2_sqrt / (1.0 - beta1.powi(self.steps))) as f32;
        let eps = (eps * c2_sqrt) as f32;
        for (((p, m), v), &g) in mlp
            .params
            .iter_mut()
            .zip(&mut self.first_moment)
            .zip(&mut self.second_moment)
            .zip(gradient)
        {
            *m = b1 * *m + (1.0 - b1) * g;
            *v = b2 * *v + (1.0 - b2) * g * g;
            *p -= factor * *m / (v.sqrt() + eps);
        }
        mlp.refresh_transposed();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_are_blocks_until_their_gradients_outgrow_the_budget() {
        // The default network and batch: a group per block.
        assert_eq!(
            gradient_groups(4096, 5_571, GROUP_GRADIENT_BYTES),
            (32, 128)
        );
        assert_eq!(
            gradient_groups(4000, 5_571, GROUP_GRADIENT_BYTES),
            (32, 128)
        );
        assert_eq!(gradient_groups(0, 5_571, GROUP_GRADIENT_BYTES), (0, 128));
        // The largest network the settings allow: one group, whatever the batch.
        let largest = 16 * 1025 * 1024;
        assert_eq!(
            gradient_groups(65_536, largest, GROUP_GRADIENT_BYTES),
            (1, 65_536)
        );
        // Room for 10 of 32 blocks: groups of 4 blocks (8 groups).
        assert_eq!(gradient_groups(4096, 1000, 10 * 4000), (8, 512));
    }

    /// Several blocks to a group give the gradient of one block to a group, to rounding (the
    /// order of the sums differs, nothing else).
    #[test]
    fn grouped_blocks_give_the_same_gradient() {
        let mlp = Mlp::new(5, 24, 2, 3);
        let rows = 1000;
        let mut rng = SplitMix::new(4);
        let inputs: Vec<f32> = (0..rows * 5).map(|_| rng.next_f32() - 0.5).collect();
        let targets: Vec<f32> = (0..rows * 3).map(|_| rng.next_f32()).collect();
        let (mut one, mut grouped) = (Gradient::default(), Gradient::default());
        let count = mlp.num_params();
        let a = mlp.loss_and_gradient_in_groups(&inputs, &targets, 1e-2, &mut one, usize::MAX);
        let b =
            mlp.loss_and_gradient_in_groups(&inputs, &targets, 1e-2, &mut grouped, 3 * count * 4);
        assert_eq!(one.group_losses.len(), 8);
        assert_eq!(grouped.group_losses.len(), 3);
        assert!((a - b).abs() <= 1e-12 * a.abs(), "loss {a} against {b}");
        let scale = one.params.iter().fold(0.0f32, |m, g| m.max(g.abs()));
        for (x, y) in one.params.iter().zip(&grouped.params) {
            assert!((x - y).abs() <= 1e-5 * scale, "{x} against {y}");
        }
        assert_eq!(one.inputs, grouped.inputs);
    }
}
