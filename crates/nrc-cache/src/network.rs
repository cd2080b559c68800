//! The network: a small ReLU MLP from the encoded inputs to RGB radiance, as burn modules, so
//! burn's autodiff gives the weights' and the input's gradients and burn's Adam steps the
//! weights. Weights are drawn here (He-uniform, from the cache's seed) rather than by burn's
//! initialiser, so a cache is bit-identical for a seed.

use crate::random::SplitMix;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};

/// Hidden layers of `width` neurons with ReLU, then a linear output of 3 (radiance is clamped
/// at zero where it is used, not by the network, so the loss sees negative predictions).
#[derive(Module, Debug)]
pub struct Mlp {
    layers: Vec<Linear>,
}

impl Mlp {
    /// A network from `inputs` through `hidden_layers` layers of `width` to 3 outputs.
    pub fn new(
        inputs: usize,
        width: usize,
        hidden_layers: usize,
        seed: u64,
        device: &Device,
    ) -> Self {
        let mut rng = SplitMix::new(seed);
        let mut dims = vec![inputs];
        dims.extend(std::iter::repeat_n(width, hidden_layers));
        dims.push(3);
        let layers = dims
            .windows(2)
            .map(|d| {
                let (fan_in, fan_out) = (d[0], d[1]);
                // He-uniform for ReLU layers: U(-sqrt(6 / fan_in), sqrt(6 / fan_in)).
                let bound = (6.0 / fan_in as f32).sqrt();
                let w: Vec<f32> = (0..fan_in * fan_out)
                    .map(|_| (rng.next_f32() * 2.0 - 1.0) * bound)
                    .collect();
                Linear {
                    weight: Param::from_data(TensorData::new(w, [fan_in, fan_out]), device),
                    bias: Some(Param::from_data(
                        TensorData::new(vec![0.0f32; fan_out], [fan_out]),
                        device,
                    )),
                }
            })
            .collect();
        Self { layers }
    }

    /// Radiance for each row of `x` (`[rows, inputs]` to `[rows, 3]`).
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let last = self.layers.len() - 1;
        let mut h = x;
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(h);
            if i < last {
                h = relu(h);
            }
        }
        h
    }

    /// Multiply-adds per row of a forward pass.
    pub fn macs_per_row(&self) -> usize {
        self.layers
            .iter()
            .map(|l| {
                let d = l.weight.dims();
                d[0] * d[1]
            })
            .sum()
    }
}
