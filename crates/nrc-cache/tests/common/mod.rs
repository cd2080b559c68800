//! What the network's two oracles share (`mlp.rs`, f64 by hand; `mlp_burn.rs`, burn): the
//! test's shapes, its data, and the comparison by parameter group.
//!
//! The shapes are chosen to reach every path of the kernels: 7 inputs (narrower than a register
//! tile), hidden layers of 20 (one whole 16-column tile and a tail of 4), the 3 outputs (the
//! narrow layer), and 301 rows (two whole blocks of 128 and a tail block of 45, whose last
//! row is not a whole 4-row tile).

#![allow(dead_code)] // each test binary uses its part

use nrc_cache::Mlp;
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
