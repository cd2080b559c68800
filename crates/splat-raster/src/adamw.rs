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
