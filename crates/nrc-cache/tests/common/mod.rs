//! What the network's two oracles share (`mlp.rs`, f64 by hand; `mlp_burn.rs`, burn): the
//! test's shapes, its data, and the comparison by parameter group.
//!
//! The shapes are chosen to reach every path of the kernels: 7 inputs (narrower than a register
//! tile), hidden layers of 20 (one whole 16-column tile and a tail of 4), the 3 outputs (the
//! narrow layer), and 301 rows (two whole blocks of 128 and a tail block of 45, whose last
//! row is not a whole 4-row tile).

#![allow(dead_code)] // each test binary uses its part

use nrc_cache::Mlp;
use nrc_cache::mlp::{Adam, BlockWork, Gradient};
use nrc_cache::random::SplitMix;

pub const INPUTS: usize = 7;
pub const WIDTH: usize = 20;
pub const HIDDEN: usize = 2;
pub const ROWS: usize = 301;
pub const LOSS_EPSILON: f32 = 1e-2;

/// A network of the test's shape with every parameter drawn, the biases too (a fresh `Mlp`'s
/// are zero, which would hide a dropped bias).
pub fn random_mlp(seed: u64) -> Mlp {
    random_mlp_of(WIDTH, HIDDEN, seed)
}

pub fn random_mlp_of(width: usize, hidden: usize, seed: u64) -> Mlp {
    let shape = Mlp::new(INPUTS, width, hidden, seed);
    let mut rng = SplitMix::new(seed);
    let params = shape
        .params()
        .iter()
        .map(|w| w + (rng.next_f32() - 0.5) * 0.2)
        .collect();
    Mlp::from_parts(shape.dims().to_vec(), params)
}

pub fn data(seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = SplitMix::new(seed);
    let inputs = (0..ROWS * INPUTS)
        .map(|_| rng.next_f32() * 2.0 - 1.0)
        .collect();
    let targets = (0..ROWS * 3).map(|_| rng.next_f32() * 3.0).collect();
    (inputs, targets)
}

/// Each entry of `got` within `tolerance` of the largest magnitude of its group in `expected`;
/// groups are consecutive runs of `group_lengths`.
pub fn assert_close_by_group(what: &str, got: &[f32], expected: &[f32], group_lengths: &[usize]) {
    assert_eq!(got.len(), expected.len(), "{what}: lengths");
    assert_eq!(group_lengths.iter().sum::<usize>(), got.len());
    let mut start = 0;
    for (g, &len) in group_lengths.iter().enumerate() {
        let e = &expected[start..start + len];
        let scale = e.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(
            scale > 0.0,
            "{what}: group {g} is all zero: the test would be empty"
        );
        for (i, (a, b)) in got[start..start + len].iter().zip(e).enumerate() {
            assert!(
                (a - b).abs() <= 2e-5 * scale,
                "{what}: group {g} entry {i}: {a} against the oracle's {b} (group scale {scale})"
            );
        }
        start += len;
    }
}

/// Each layer's weights, then its biases: the groups of `Mlp::params`.
pub fn parameter_groups(mlp: &Mlp) -> Vec<usize> {
    mlp.dims()
        .windows(2)
        .flat_map(|d| [d[0] * d[1], d[1]])
        .collect()
}

/// What an oracle says of a network on the test's data: the loss, its gradient (parameters in
/// `Mlp::params`' layout, then inputs) and the forward pass's outputs.
pub struct OracleAnswer {
    pub loss: f64,
    pub params: Vec<f32>,
    pub inputs: Vec<f32>,
    pub outputs: Vec<f32>,
}

/// The network's loss, gradients and forward pass on `data(12)` against `oracle`'s.
pub fn assert_network_matches(
    name: &str,
    mlp: &Mlp,
    oracle: impl Fn(&Mlp, &[f32], &[f32]) -> OracleAnswer,
) {
    let (inputs, targets) = data(12);
    let mut gradient = Gradient::default();
    let loss = mlp.loss_and_gradient(&inputs, &targets, LOSS_EPSILON, &mut gradient);
    let expected = oracle(mlp, &inputs, &targets);
    assert!(
        (loss - expected.loss).abs() <= 1e-5 * expected.loss.abs(),
        "loss {loss} against {name}'s {}",
        expected.loss
    );
    assert_close_by_group(
        &format!("parameter gradient of {:?}", mlp.dims()),
        &gradient.params,
        &expected.params,
        &parameter_groups(mlp),
    );
    assert_close_by_group(
        "input gradient",
        &gradient.inputs,
        &expected.inputs,
        &[ROWS * INPUTS],
    );
    let mut outputs = vec![0.0; ROWS * 3];
    mlp.forward(&inputs, &mut outputs, &mut BlockWork::default());
    assert_close_by_group("forward", &outputs, &expected.outputs, &[ROWS * 3]);
}

/// Adam's settings in the optimiser tests: `(beta1, beta2, epsilon, lr)`.
pub const ADAM: (f64, f64, f64, f64) = (0.9, 0.99, 1e-15, 1e-2);

/// Three Adam steps (the bias corrections differ at each) on the gradients of `data(20 +
/// step)`, each move compared with the one `oracle` makes from the same gradient (`step`, the
/// parameters before, the gradient); the moves are compared, not the parameters, whose size
/// would hide an error in the move.
pub fn assert_adam_matches(mut oracle: impl FnMut(usize, &[f32], &[f32]) -> Vec<f32>) {
    let (beta1, beta2, epsilon, lr) = ADAM;
    let mut mlp = random_mlp(13);
    let mut adam = Adam::default();
    let mut gradient = Gradient::default();
    for step in 0..3 {
        let (inputs, targets) = data(20 + step as u64);
        mlp.loss_and_gradient(&inputs, &targets, LOSS_EPSILON, &mut gradient);
        let before = mlp.params().to_vec();
        adam.step(&mut mlp, &gradient.params, lr, beta1, beta2, epsilon);
        let ours: Vec<f32> = mlp
            .params()
            .iter()
            .zip(&before)
            .map(|(a, b)| a - b)
            .collect();
        let theirs = oracle(step, &before, &gradient.params);
        assert_close_by_group(
            &format!("Adam step {step}"),
            &ours,
            &theirs,
            &parameter_groups(&mlp),
        );
    }
}
