//! The multiresolution hash encoding (Müller, Evans, Schied and Keller, "Instant neural graphics
//! primitives with a multiresolution hash encoding", 2022), forward and backward: a gather of
//! eight corners per level and its scatter-add backward, which a tensor library does 5-13x
//! slower (BENCHMARKS.md, `nrc_speed --burn-encoding`). The network's input gradient
//! ([`crate::mlp`]) is scattered back into the tables here.
//!
//! Level `l` has `N_l = floor(N_min b^l)` cells per axis, `b` spacing the levels geometrically
//! from `N_min` to `N_max`. A point `p` in the unit cube falls in cell `floor(p N_l)`; its eight
//! corners index the level's table directly when the level's `(N_l + 1)^3` corners fit, and
//! through the spatial hash `(x * 1) xor (y * 2654435761) xor (z * 805459861) mod T` when they
//! do not. The level's features are the trilinear blend of its corners' entries.
//!
//! Training updates the tables with Adam, entry by entry, skipping entries no record touched
//! (the hash-grid paper's sparse update): a step costs the batch, not the table.

use crate::config::NrcConfig;
use glam::Vec3;
use rayon::prelude::*;

const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// The tables and their Adam moments.
#[derive(Debug, Clone)]
pub struct HashGrid {
    levels: usize,
    features: usize,
    /// Entries per level (a power of two).
    table_size: usize,
    /// Cells per axis, per level.
    resolutions: Vec<u32>,
    /// `levels * table_size * features` values, level-major, then entry, then feature.
    params: Vec<f32>,
    first_moment: Vec<f32>,
    second_moment: Vec<f32>,
    /// Adam steps taken by each entry (the bias correction of sparse Adam is per entry).
    entry_steps: Vec<u32>,
    /// The bias corrections of the first steps, looked up by each entry's step count.
    corrections: BiasCorrections,
}

/// Sparse Adam's bias corrections `(lr / (1 - beta1^t), sqrt(1 - beta2^t))` for `t = 1, 2,
/// ...`, computed once for the optimiser's settings: a step looks its entries' corrections up
/// instead of taking two powers for each entry (a quarter of the step's time, measured). The
/// table holds exactly what [`bias_correction`] returns, so looking up changes no bit.
#[derive(Debug, Clone, Default)]
struct BiasCorrections {
    /// `(lr, beta1, beta2)` the table was made for, as bits.
    settings: [u64; 3],
    /// Entry `t - 1` is step `t`'s corrections.
    table: Vec<(f32, f32)>,
    /// Whether every later step's corrections equal the table's last: both powers are below
    /// 2^-60 there, so `1 - beta^t` rounds to 1 from then on.
    settled: bool,
}

/// Most steps [`BiasCorrections`] tabulates (beyond, with betas this close to 1, each entry
/// computes its own).
const MAX_TABULATED_STEPS: i32 = 8192;

/// Step `t`'s bias corrections (see [`BiasCorrections`]).
fn bias_correction(lr: f64, beta1: f64, beta2: f64, t: i32) -> (f32, f32) {
    (
        (lr / (1.0 - beta1.powi(t))) as f32,
        (1.0 - beta2.powi(t)).sqrt() as f32,
    )
}

impl BiasCorrections {
    fn fit(&mut self, lr: f64, beta1: f64, beta2: f64) {
        let settings = [lr.to_bits(), beta1.to_bits(), beta2.to_bits()];
        if settings == self.settings && !self.table.is_empty() {
            return;
        }
        self.settings = settings;
        self.table.clear();
        self.settled = false;
        let negligible = 2f64.powi(-60);
        for t in 1..=MAX_TABULATED_STEPS {
            self.table.push(bias_correction(lr, beta1, beta2, t));
            if beta1.abs().powi(t) < negligible && beta2.abs().powi(t) < negligible {
                self.settled = true;
                break;
            }
        }
    }

    /// Step `t`'s corrections (`t >= 1`).
    #[inline]
    fn get(&self, lr: f64, beta1: f64, beta2: f64, t: i32) -> (f32, f32) {
        match self.table.get(t as usize - 1) {
            Some(&c) => c,
            None if self.settled => *self.table.last().expect("a settled table is not empty"),
            None => bias_correction(lr, beta1, beta2, t),
        }
    }
}

/// One level's eight corners for a point: table entries and trilinear weights.
#[derive(Debug, Clone, Copy)]
struct Corners {
    entries: [u32; 8],
    weights: [f32; 8],
}

impl HashGrid {
    /// Tables with every entry drawn uniformly from `[-1e-4, 1e-4]` (the hash-grid paper's
    /// initialisation), from `seed`.
    pub fn new(config: &NrcConfig, seed: u64) -> Self {
        let levels = config.grid_levels as usize;
        let features = config.grid_features as usize;
        let table_size = 1usize << config.grid_log2_table;
        let n_min = config.grid_base_resolution as f64;
        let n_max = config.grid_finest_resolution as f64;
        let growth = if levels > 1 {
            ((n_max.ln() - n_min.ln()) / (levels - 1) as f64).exp()
        } else {
            1.0
        };
        let resolutions = (0..levels)
            .map(|l| (n_min * growth.powi(l as i32) + 1e-9).floor() as u32)
            .collect();
        let n = levels * table_size * features;
        let mut rng = crate::random::SplitMix::new(seed);
        let params = (0..n)
            .map(|_| (rng.next_f32() * 2.0 - 1.0) * 1e-4)
            .collect();
        Self {
            levels,
            features,
            table_size,
            resolutions,
            params,
            first_moment: vec![0.0; n],
            second_moment: vec![0.0; n],
            entry_steps: vec![0; levels * table_size],
            corrections: BiasCorrections::default(),
        }
    }

    /// Width of a point's encoding: levels times features.
    pub fn output_width(&self) -> usize {
        self.levels * self.features
    }

    /// Cells per axis of each level.
    pub fn resolutions(&self) -> &[u32] {
        &self.resolutions
    }

    /// The parameters, level-major (for tests and persistence).
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// Mutable parameters (for finite-difference tests).
    pub fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    /// Bytes of parameters and optimiser state.
    pub fn bytes(&self) -> usize {
        (self.params.len() * 3 + self.entry_steps.len()) * 4
    }

    #[inline]
    fn corners(&self, level: usize, p: Vec3) -> Corners {
        let res = self.resolutions[level];
        let side = res + 1;
        // Dense when the level's corners fit its table (then `side^3 <= 2^24`, no overflow).
        let dense = (side as u64).pow(3) <= self.table_size as u64;
        // Points outside the unit cube are clamped onto it (a vertex on the volume's boundary
        // may sit a rounding error outside); NaN becomes 0 (`max` returns the other operand).
        let q = p.max(Vec3::ZERO).min(Vec3::ONE) * res as f32;
        // `q` is in [0, res], where truncation is the floor: a conversion, where `floor` is a
        // call to the C library on the baseline x86-64 (7% of inference, measured).
        let cell_of = |x: f32| (x as u32).min(res - 1);
        let (cx, cy, cz) = (cell_of(q.x), cell_of(q.y), cell_of(q.z));
        let f = q - Vec3::new(cx as f32, cy as f32, cz as f32);
        // Per axis: the two corner coordinates' contributions to the index, and the weights.
        let (ix, iy, iz) = if dense {
            (
                [cx, cx + 1],
                [cy * side, (cy + 1) * side],
                [cz * side * side, (cz + 1) * side * side],
            )
        } else {
            (
                [cx.wrapping_mul(PRIMES[0]), (cx + 1).wrapping_mul(PRIMES[0])],
                [cy.wrapping_mul(PRIMES[1]), (cy + 1).wrapping_mul(PRIMES[1])],
                [cz.wrapping_mul(PRIMES[2]), (cz + 1).wrapping_mul(PRIMES[2])],
            )
        };
        let (wx, wy, wz) = ([1.0 - f.x, f.x], [1.0 - f.y, f.y], [1.0 - f.z, f.z]);
        let mask = self.table_size as u32 - 1;
        let mut out = Corners {
            entries: [0; 8],
            weights: [0.0; 8],
        };
        for k in 0..8 {
            let (dx, dy, dz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
            out.entries[k] = if dense {
                ix[dx] + iy[dy] + iz[dz]
            } else {
                (ix[dx] ^ iy[dy] ^ iz[dz]) & mask
            };
            out.weights[k] = wx[dx] * wy[dy] * wz[dz];
        }
        out
    }

    /// Every point's corners as rows of the whole table: `(entry, weight)` pairs, point-major,
    /// then level, then corner, with entries counted across levels (`level * table_size +
    /// entry`). What a tensor library needs to do the gather itself (the benchmark that
    /// compares it with [`HashGrid::encode`] uses it).
    pub fn corner_rows(&self, points: &[Vec3]) -> (Vec<i64>, Vec<f32>) {
        let n = points.len() * self.levels * 8;
        let (mut rows, mut weights) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for &p in points {
            for level in 0..self.levels {
                let c = self.corners(level, p);
                for k in 0..8 {
                    rows.push((level * self.table_size + c.entries[k] as usize) as i64);
                    weights.push(c.weights[k]);
                }
            }
        }
        (rows, weights)
    }

    /// Writes the encoding of `p` (a point of the unit cube) into `out` (`output_width` values).
    pub fn encode(&self, p: Vec3, out: &mut [f32]) {
        if self.features == 2 {
            // The default width, unrolled: the gather is the encoding's whole cost.
            for level in 0..self.levels {
                let c = self.corners(level, p);
                let table =
                    &self.params[level * self.table_size * 2..(level + 1) * self.table_size * 2];
                let (mut a, mut b) = (0.0f32, 0.0f32);
                for k in 0..8 {
                    let e = c.entries[k] as usize * 2;
                    a += c.weights[k] * table[e];
                    b += c.weights[k] * table[e + 1];
                }
                out[level * 2] = a;
                out[level * 2 + 1] = b;
            }
            return;
        }
        let f = self.features;
        for level in 0..self.levels {
            let c = self.corners(level, p);
            let table = &self.params[level * self.table_size * f..];
            let dst = &mut out[level * f..(level + 1) * f];
            dst.fill(0.0);
            for k in 0..8 {
                let e = c.entries[k] as usize * f;
                for j in 0..f {
                    dst[j] += c.weights[k] * table[e + j];
                }
            }
        }
    }

    /// Encodes every point into the rows of `out` (row stride `stride`, encoding in the
    /// first `output_width` columns), in parallel.
    pub fn encode_rows(&self, points: &[Vec3], out: &mut [f32], stride: usize) {
        out.par_chunks_mut(stride)
            .zip(points.par_iter())
            .for_each(|(row, &p)| self.encode(p, &mut row[..self.output_width()]));
    }

    /// Adds the gradient of a loss with respect to the tables into `grad` (same layout as the
    /// parameters), given its gradient with respect to the encodings: rows of `encoding_grad`
    /// with stride `stride`, the encoding in the first `output_width` columns. Levels own
    /// disjoint slices of the tables, so they run in parallel without atomics.
    pub fn backward(
        &self,
        points: &[Vec3],
        encoding_grad: &[f32],
        stride: usize,
        grad: &mut [f32],
    ) {
        let f = self.features;
        grad.par_chunks_mut(self.table_size * f)
            .enumerate()
            .for_each(|(level, g)| {
                for (i, &p) in points.iter().enumerate() {
                    let src = &encoding_grad[i * stride + level * f..i * stride + (level + 1) * f];
                    if src.iter().all(|&x| x == 0.0) {
                        continue;
                    }
                    let c = self.corners(level, p);
                    for k in 0..8 {
                        let e = c.entries[k] as usize * f;
                        for j in 0..f {
                            g[e + j] += c.weights[k] * src[j];
                        }
                    }
                }
            });
    }

    /// One Adam step on the entries whose gradient is not zero; `grad` is zeroed as it is
    /// read, ready for the next step. A gradient that is not finite skips its entry (and is
    /// counted in the returned number) so that no NaN reaches a parameter.
    pub fn adam_step(
        &mut self,
        grad: &mut [f32],
        lr: f64,
        beta1: f64,
        beta2: f64,
        eps: f64,
    ) -> u64 {
        let f = self.features;
        let (b1, b2) = (beta1 as f32, beta2 as f32);
        let skipped = std::sync::atomic::AtomicU64::new(0);
        self.corrections.fit(lr, beta1, beta2);
        let corrections = &self.corrections;
        self.params
            .par_chunks_mut(f * 4096)
            .zip(self.first_moment.par_chunks_mut(f * 4096))
            .zip(self.second_moment.par_chunks_mut(f * 4096))
            .zip(self.entry_steps.par_chunks_mut(4096))
            .zip(grad.par_chunks_mut(f * 4096))
            .for_each(|((((p, m), v), steps), g)| {
                for (e, step) in steps.iter_mut().enumerate() {
                    let ge = &mut g[e * f..(e + 1) * f];
                    if ge.iter().all(|&x| x == 0.0) {
                        continue;
                    }
                    if !ge.iter().all(|x| x.is_finite()) {
                        skipped.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        ge.fill(0.0);
                        continue;
                    }
                    *step += 1;
                    let t = (*step).min(i32::MAX as u32) as i32;
                    // Per-entry bias correction: an entry touched for the first time gets the
                    // full first step, however many steps the table has taken.
                    let (step_size, c2_sqrt) = corrections.get(lr, beta1, beta2, t);
                    for j in e * f..(e + 1) * f {
                        let gj = g[j];
                        m[j] = b1 * m[j] + (1.0 - b1) * gj;
                        v[j] = b2 * v[j] + (1.0 - b2) * gj * gj;
                        p[j] -= step_size * m[j] / (v[j].sqrt() / c2_sqrt + eps as f32);
                        g[j] = 0.0;
                    }
                }
            });
        skipped.into_inner()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table's corrections are the computed ones, bit for bit, at every step count: before
    /// the table settles, after it (where it answers with its last entry), and for betas so
    /// close to 1 that it never settles within its length.
    #[test]
    fn tabulated_bias_corrections_are_the_computed_ones() {
        for (lr, beta1, beta2) in [(1e-2, 0.9, 0.99), (3e-3, 0.9999, 0.99999), (1e-2, 0.0, 0.5)] {
            let mut table = BiasCorrections::default();
            table.fit(lr, beta1, beta2);
            for t in (1..20_000).chain([i32::MAX]) {
                let (a, b) = table.get(lr, beta1, beta2, t);
                let (x, y) = bias_correction(lr, beta1, beta2, t);
                assert_eq!(
                    (a.to_bits(), b.to_bits()),
                    (x.to_bits(), y.to_bits()),
                    "betas {beta1}, {beta2} at step {t}"
                );
            }
        }
    }
}
