//! AdamW (decoupled weight decay, Loshchilov and Hutter) fused over the cloud's parameter
//! arrays: one pass per group, in parallel chunks, no allocation per step.
//!
//! Per element, at step `t` with learning rate `lr` and weight decay `wd`:
//! `m = b1 m + (1 - b1) g; v = b2 v + (1 - b2) g^2;
//!  p = p (1 - lr wd) - lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)`.
//! This is the update of PyTorch's and burn's AdamW; `tests/adamw_burn.rs` holds the two equal
//! (within 1e-6), which is why the bias corrections are computed in f32 and the arithmetic
//! follows burn's order. A non-finite gradient element is treated as 0, so no NaN reaches a
//! parameter.

use crate::cloud::GaussianCloud;
use rayon::prelude::*;

/// Learning rate and weight decay of one parameter group.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupSettings {
    pub lr: f32,
    pub weight_decay: f32,
}

/// Optimiser settings, one group per parameter array (means, log-scales, rotations, colours,
/// opacity logits).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamWConfig {
    pub beta1: f32,
    pub beta2: f32,
    pub epsilon: f32,
    pub means: GroupSettings,
    pub log_scales: GroupSettings,
    pub rotations: GroupSettings,
    pub colors: GroupSettings,
    pub opacity_logits: GroupSettings,
}

impl Default for AdamWConfig {
    /// 3DGS-style learning rates; weight decay 0 for means and rotations, 0.01 elsewhere.
    fn default() -> Self {
        let g = |lr, weight_decay| GroupSettings { lr, weight_decay };
        Self {
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-15,
            means: g(1.6e-4, 0.0),
            log_scales: g(5e-3, 0.01),
            rotations: g(1e-3, 0.0),
            colors: g(2.5e-3, 0.01),
            opacity_logits: g(5e-2, 0.01),
        }
    }
}

impl AdamWConfig {
    fn groups(&self) -> [GroupSettings; 5] {
        [
            self.means,
            self.log_scales,
            self.rotations,
            self.colors,
            self.opacity_logits,
        ]
    }
}

/// Optimiser state: first and second moments shaped like the cloud.
#[derive(Debug, Clone)]
pub struct AdamW {
    pub config: AdamWConfig,
    m: GaussianCloud<f32>,
    v: GaussianCloud<f32>,
    step: u32,
}

const CHUNK: usize = 1 << 14;

impl AdamW {
    pub fn new(config: AdamWConfig, cloud: &GaussianCloud<f32>) -> Self {
        Self {
            config,
            m: cloud.zeros_like(),
            v: cloud.zeros_like(),
            step: 0,
        }
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u32 {
        self.step
    }

    /// Forgets the moments (for a scene change) without reallocating.
    pub fn reset(&mut self) {
        for g in self.m.groups_mut().into_iter().chain(self.v.groups_mut()) {
            g.fill(0.0);
        }
        self.step = 0;
    }

    /// Reshapes the moments after the cloud was reshaped by [`GaussianCloud::gather`]: new
    /// Gaussian `i` keeps the moments of old Gaussian `rows[i]`, or starts from zero moments
    /// where it is `None` (a Gaussian made anew, as 3DGS's densification starts its children).
    /// The step count, and so the bias corrections, are kept. Panics if a row is out of range.
    pub fn gather(&mut self, rows: &[Option<usize>]) {
        self.m = self.m.gather_or_zero(rows);
        self.v = self.v.gather_or_zero(rows);
    }

    /// One update of `params` from `grads`; every learning rate is multiplied by `lr_scale`
    /// (for schedules).
    pub fn step(
        &mut self,
        params: &mut GaussianCloud<f32>,
        grads: &GaussianCloud<f32>,
        lr_scale: f32,
    ) {
        self.step += 1;
        let c = self.config;
        let t = self.step as i32;
        let bc1 = 1.0f32 - c.beta1.powi(t);
        let bc2 = 1.0f32 - c.beta2.powi(t);
        let (b1, b2, eps) = (c.beta1, c.beta2, c.epsilon);
        let (f1, f2) = (1.0 - b1, 1.0 - b2);
        let settings = c.groups();
        let grads = grads.groups();
        for ((((p, g), m), v), s) in params
            .groups_mut()
            .into_iter()
            .zip(grads.iter())
            .zip(self.m.groups_mut())
            .zip(self.v.groups_mut())
            .zip(settings)
        {
            assert_eq!(
                p.len(),
                g.1.len(),
                "gradient group {} has the wrong length",
                g.0
            );
            let lr = s.lr * lr_scale;
            let decay = (1.0 - lr as f64 * s.weight_decay as f64) as f32;
            p.par_chunks_mut(CHUNK)
                .zip(g.1.par_chunks(CHUNK))
                .zip(m.par_chunks_mut(CHUNK))
                .zip(v.par_chunks_mut(CHUNK))
                .for_each(|(((p, g), m), v)| {
                    for i in 0..p.len() {
                        let gi = if g[i].is_finite() { g[i] } else { 0.0 };
                        m[i] = m[i] * b1 + gi * f1;
                        v[i] = v[i] * b2 + (gi * gi) * f2;
                        let update = (m[i] / bc1) / ((v[i] / bc2).sqrt() + eps);
                        p[i] = p[i] * decay - update * lr;
                    }
                });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::ColorModel;

    /// A cloud of `n` Gaussians whose every parameter is `value(g)` for Gaussian `g`.
    fn cloud(n: usize, value: impl Fn(usize) -> f32) -> GaussianCloud<f32> {
        let mut c = GaussianCloud::new(ColorModel::Sh(0));
        for g in 0..n {
            let v = value(g);
            c.push([v; 3], [v; 3], [v; 4], &[v; 3], v);
        }
        c
    }

    /// After `gather`, a Gaussian taken from an old row steps exactly as that row would have,
    /// and a new one (`None`) as under a fresh optimiser: its moments are zero.
    #[test]
    fn gathered_rows_keep_their_moments_and_new_rows_start_at_zero() {
        let config = AdamWConfig::default();
        let grads = |n| cloud(n, |g| 0.5 + g as f32);
        let mut params = cloud(2, |g| g as f32);
        let mut opt = AdamW::new(config, &params);
        for _ in 0..3 {
            opt.step(&mut params, &grads(2), 1.0);
        }
        // Old row 1, then a new row, then old row 0.
        let mut kept = opt.clone();
        let mut gathered = params.gather(&[1, 0, 0]);
        kept.gather(&[Some(1), None, Some(0)]);
        // Each gathered row is given its source row's gradient.
        let new_grads = grads(2).gather(&[1, 0, 0]);
        kept.step(&mut gathered, &new_grads, 1.0);
        let mut expected = params.clone();
        opt.step(&mut expected, &grads(2), 1.0);
        let mut fresh_row = params.gather(&[0]);
        let mut fresh = AdamW::new(config, &fresh_row);
        fresh.step = opt.step - 1;
        fresh.step(&mut fresh_row, &grads(1), 1.0);
        for ((name, got), (_, want)) in gathered.groups().into_iter().zip(expected.groups()) {
            let w = want.len() / 2;
            assert_eq!(&got[..w], &want[w..], "{name}: the kept row 1");
            assert_eq!(&got[2 * w..], &want[..w], "{name}: the kept row 0");
        }
        for ((name, got), (_, want)) in gathered.groups().into_iter().zip(fresh_row.groups()) {
            let w = want.len();
            assert_eq!(&got[w..2 * w], want, "{name}: the new row");
        }
    }
}
