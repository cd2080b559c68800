//! The hand-written network (`nrc_cache::mlp`) against a reference written out in f64 from the
//! definitions: dense layers `h W + b` with ReLU between them, the relative L2 loss with the
//! prediction in the denominator held constant (Müller et al., 2021), its gradient by the
//! chain rule, and Adam (Kingma and Ba, 2015) in its textbook form. This is the default tier's
//! oracle; `mlp_burn.rs` compares the same network with burn (feature `burn-oracle`, which CI
//! runs).
//!
//! Tolerance: each entry within 2e-5 of the largest entry of its group (a layer's weights, its
//! biases, the inputs, the outputs). The f32 side rounds its sums over at most 301 rows to
//! about 1e-6 relative; the bugs this is for (a dropped ReLU mask, bias gradient or transpose,
//! a wrong loss scale or bias correction) change entries by a large fraction of the largest.

mod common;
use common::{
    ADAM, HIDDEN, INPUTS, LOSS_EPSILON, OracleAnswer, ROWS, WIDTH, assert_adam_matches,
    assert_network_matches, random_mlp_of,
};
use nrc_cache::Mlp;

/// The network's layers in f64: `(fan_in, fan_out, weights fan_in x fan_out, biases)`.
fn layers(mlp: &Mlp) -> Vec<(usize, usize, Vec<f64>, Vec<f64>)> {
    let p = mlp.params();
    let mut offset = 0;
    mlp.dims()
        .windows(2)
        .map(|d| {
            let (fan_in, fan_out) = (d[0], d[1]);
            let w = p[offset..offset + fan_in * fan_out]
                .iter()
                .map(|&x| x as f64)
                .collect();
            let b = p[offset + fan_in * fan_out..offset + (fan_in + 1) * fan_out]
                .iter()
                .map(|&x| x as f64)
                .collect();
            offset += (fan_in + 1) * fan_out;
            (fan_in, fan_out, w, b)
        })
        .collect()
}

/// One row through the network in f64: every layer's pre-activation (the last is the output).
fn forward_row(layers: &[(usize, usize, Vec<f64>, Vec<f64>)], x: &[f32]) -> Vec<Vec<f64>> {
    let mut a: Vec<f64> = x.iter().map(|&v| v as f64).collect();
    let mut pre = Vec::new();
    for (l, (fan_in, fan_out, w, b)) in layers.iter().enumerate() {
        let z: Vec<f64> = (0..*fan_out)
            .map(|j| b[j] + (0..*fan_in).map(|i| a[i] * w[i * fan_out + j]).sum::<f64>())
            .collect();
        a = if l + 1 < layers.len() {
            z.iter().map(|&v| v.max(0.0)).collect()
        } else {
            z.clone()
        };
        pre.push(z);
    }
    pre
}

/// The loss, its gradient and the outputs in f64.
fn reference(mlp: &Mlp, inputs: &[f32], targets: &[f32]) -> OracleAnswer {
    let layers = layers(mlp);
    let count = (ROWS * 3) as f64;
    let eps = LOSS_EPSILON as f64;
    let mut loss = 0.0;
    let mut d_params: Vec<Vec<f64>> = layers
        .iter()
        .map(|(fan_in, fan_out, ..)| vec![0.0; (fan_in + 1) * fan_out])
        .collect();
    let mut d_inputs = vec![0.0f64; ROWS * INPUTS];
    let mut outputs = Vec::with_capacity(ROWS * 3);
    for row in 0..ROWS {
        let x = &inputs[row * INPUTS..(row + 1) * INPUTS];
        let pre = forward_row(&layers, x);
        let out = pre.last().expect("an output layer");
        outputs.extend(out.iter().map(|&v| v as f32));
        // dL/d(output): the denominator is held constant.
        let mut delta: Vec<f64> = (0..3)
            .map(|c| {
                let (p, t) = (out[c], targets[row * 3 + c] as f64);
                let denominator = p * p + eps;
                loss += (p - t) * (p - t) / denominator / count;
                2.0 * (p - t) / denominator / count
            })
            .collect();
        for l in (0..layers.len()).rev() {
            let (fan_in, fan_out, w, _) = &layers[l];
            let below: Vec<f64> = if l == 0 {
                x.iter().map(|&v| v as f64).collect()
            } else {
                pre[l - 1].iter().map(|&v| v.max(0.0)).collect()
            };
            let d = &mut d_params[l];
            for i in 0..*fan_in {
                for j in 0..*fan_out {
                    d[i * fan_out + j] += below[i] * delta[j];
                }
            }
            for j in 0..*fan_out {
                d[fan_in * fan_out + j] += delta[j];
            }
            let back: Vec<f64> = (0..*fan_in)
                .map(|i| (0..*fan_out).map(|j| w[i * fan_out + j] * delta[j]).sum())
                .collect();
            if l == 0 {
                d_inputs[row * INPUTS..(row + 1) * INPUTS].copy_from_slice(&back);
            } else {
                // Through the ReLU below: zero where its input was not positive.
                delta = back
                    .iter()
                    .zip(&pre[l - 1])
                    .map(|(&g, &z)| if z > 0.0 { g } else { 0.0 })
                    .collect();
            }
        }
    }
    OracleAnswer {
        loss,
        params: d_params.concat().iter().map(|&v| v as f32).collect(),
        inputs: d_inputs.iter().map(|&v| v as f32).collect(),
        outputs,
    }
}

#[test]
fn forward_loss_and_gradients_match_the_f64_reference() {
    for (width, hidden) in [(WIDTH, HIDDEN), (8, 1), (WIDTH, 0)] {
        assert_network_matches(
            "the f64 reference",
            &random_mlp_of(width, hidden, 11),
            reference,
        );
    }
}

/// Adam against its textbook update in f64, fed the same gradients.
#[test]
fn adam_matches_its_definition() {
    let (beta1, beta2, epsilon, lr) = ADAM;
    let (mut m, mut v) = (Vec::new(), Vec::new());
    assert_adam_matches(|step, before, gradient| {
        m.resize(before.len(), 0.0f64);
        v.resize(before.len(), 0.0f64);
        let t = step as i32 + 1;
        (0..before.len())
            .map(|i| {
                let g = gradient[i] as f64;
                m[i] = beta1 * m[i] + (1.0 - beta1) * g;
                v[i] = beta2 * v[i] + (1.0 - beta2) * g * g;
                let m_hat = m[i] / (1.0 - beta1.powi(t));
                let v_hat = v[i] / (1.0 - beta2.powi(t));
                (-lr * m_hat / (v_hat.sqrt() + epsilon)) as f32
            })
            .collect()
    });
}
