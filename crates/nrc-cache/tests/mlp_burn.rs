//! The hand-written network (`nrc_cache::mlp`) against burn, the framework oracle (feature
//! `burn-oracle`, which CI runs; `mlp.rs` holds it to an f64 reference in the default tier):
//! the same weights as burn `Linear` layers, burn's autodiff through the same relative L2 loss,
//! and burn's Adam fed the same gradient.
//!
//! The shapes are chosen to reach every path of the kernels: 7 inputs (narrower than a register
//! tile), hidden layers of 20 (one whole 16-column tile and a tail of 4), the 3 outputs (the
//! narrow layer), and 301 rows (two whole blocks of 128 and a tail block of 45, whose last
//! row is not a whole 4-row tile); the gradients also on hidden layers of 8 (narrow, like the
//! outputs) and on no hidden layer at all (inputs straight to outputs).
//!
//! Both sides are f32 with different summation orders, so they agree to rounding: each
//! gradient entry within 2e-5 of the largest entry of its layer (the sums run over at most 301
//! rows of terms of one sign or another; f32's rounding over such sums is about 1e-6
//! relative). The bugs these tests are for (a dropped ReLU mask, bias gradient or transpose, a
//! wrong scale or bias correction) change entries by a large fraction of that largest entry.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use nrc_cache::Mlp;

mod common;
use common::{
    ADAM, HIDDEN, INPUTS, LOSS_EPSILON, OracleAnswer, ROWS, WIDTH, assert_adam_matches,
    assert_network_matches, random_mlp, random_mlp_of,
};

#[derive(Module, Debug)]
struct BurnMlp {
    layers: Vec<Linear>,
}

impl BurnMlp {
    /// burn's layers holding `mlp`'s parameters (burn's `Linear` weight is `fan_in x fan_out`,
    /// the layout `Mlp::params` uses).
    fn from(mlp: &Mlp, device: &Device) -> Self {
        let mut offset = 0;
        let layers = mlp
            .dims()
            .windows(2)
            .map(|d| {
                let (fan_in, fan_out) = (d[0], d[1]);
                let p = mlp.params();
                let w = p[offset..offset + fan_in * fan_out].to_vec();
                let b = p[offset + fan_in * fan_out..offset + (fan_in + 1) * fan_out].to_vec();
                offset += (fan_in + 1) * fan_out;
                Linear {
                    weight: Param::from_data(TensorData::new(w, [fan_in, fan_out]), device),
                    bias: Some(Param::from_data(TensorData::new(b, [fan_out]), device)),
                }
            })
            .collect();
        Self { layers }
    }

    fn forward(&self, x: Tensor<2>) -> Tensor<2> {
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

    /// The parameters in `Mlp::params`' layout.
    fn params(&self) -> Vec<f32> {
        let mut out = Vec::new();
        for layer in &self.layers {
            out.extend(to_vec(layer.weight.val()));
            out.extend(to_vec(layer.bias.as_ref().unwrap().val()));
        }
        out
    }
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// burn's loss and gradients (parameters, then inputs) for `mlp` on `inputs` and `targets`.
fn burn_gradient(mlp: &Mlp, inputs: &[f32], targets: &[f32]) -> (f64, Vec<f32>, Vec<f32>) {
    let device = Device::flex().autodiff();
    let net = BurnMlp::from(mlp, &device);
    let x = Tensor::<2>::from_data(TensorData::new(inputs.to_vec(), [ROWS, INPUTS]), &device)
        .require_grad();
    let target = Tensor::<2>::from_data(TensorData::new(targets.to_vec(), [ROWS, 3]), &device);
    let prediction = net.forward(x.clone());
    let held = prediction.clone().detach();
    let denominator = held.clone() * held + LOSS_EPSILON;
    let diff = prediction - target;
    let loss = (diff.clone() * diff / denominator).mean();
    let loss_value = to_vec(loss.clone())[0] as f64;
    let mut grads = loss.backward();
    let input_grad = to_vec(x.grad_remove(&mut grads).unwrap());
    let mut params = Vec::new();
    for layer in &net.layers {
        params.extend(to_vec(layer.weight.grad(&grads).unwrap()));
        params.extend(to_vec(layer.bias.as_ref().unwrap().grad(&grads).unwrap()));
    }
    (loss_value, params, input_grad)
}

#[test]
fn forward_loss_and_gradients_match_burn() {
    for (width, hidden) in [(WIDTH, HIDDEN), (8, 1), (WIDTH, 0)] {
        assert_network_matches("burn", &random_mlp_of(width, hidden, 11), burn_answer);
    }
}

/// burn's loss, gradients and outputs.
fn burn_answer(mlp: &Mlp, inputs: &[f32], targets: &[f32]) -> OracleAnswer {
    let (loss, params, d_inputs) = burn_gradient(mlp, inputs, targets);
    let device = Device::flex();
    let outputs = to_vec(BurnMlp::from(mlp, &device).forward(Tensor::<2>::from_data(
        TensorData::new(inputs.to_vec(), [ROWS, INPUTS]),
        &device,
    )));
    OracleAnswer {
        loss,
        params,
        inputs: d_inputs,
        outputs,
    }
}

/// burn's Adam fed our gradients (so that only the optimisers are compared). Each side's
/// parameters carry on from its own steps (burn keeps its moments by parameter), so they drift
/// apart by rounding only.
#[test]
fn adam_matches_burn() {
    let (beta1, beta2, epsilon, lr) = ADAM;
    let device = Device::flex().autodiff();
    let mut burn_net = BurnMlp::from(&random_mlp(13), &device);
    let mut burn_adam = AdamConfig::new()
        .with_beta_1(beta1 as f32)
        .with_beta_2(beta2 as f32)
        .with_epsilon(epsilon as f32)
        .init();
    assert_adam_matches(|_, _, gradient| {
        let mut registered = GradientsParams::new();
        let mut offset = 0;
        for layer in &burn_net.layers {
            let [fan_in, fan_out] = layer.weight.dims();
            let g = &gradient[offset..];
            let w = TensorData::new(g[..fan_in * fan_out].to_vec(), [fan_in, fan_out]);
            let b = TensorData::new(g[fan_in * fan_out..][..fan_out].to_vec(), [fan_out]);
            registered.register(layer.weight.id, Tensor::<2>::from_data(w, &Device::flex()));
            let bias_id = layer.bias.as_ref().unwrap().id;
            registered.register(bias_id, Tensor::<1>::from_data(b, &Device::flex()));
            offset += (fan_in + 1) * fan_out;
        }
        let burn_before = burn_net.params();
        burn_net = burn_adam.step(lr, burn_net.clone(), registered);
        burn_net
            .params()
            .iter()
            .zip(&burn_before)
            .map(|(a, b)| a - b)
            .collect()
    });
}
