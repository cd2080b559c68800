//! Null-collision tracking over the majorant grid.
//!
//! - [`free_flight`]: delta tracking (Woodcock). Within a macrocell of majorant `m`, tentative
//!   collisions are exponential with rate `m`; one at `x` is real with probability
//!   `sigma_t(x) / m`. The exponential is memoryless, so crossing into the next macrocell simply
//!   draws afresh with the new rate. Cells with `m = 0` are stepped over without a draw.
//! - [`transmittance`]: residual ratio tracking: each macrocell's smallest extinction `c` is
//!   attenuated exactly, `exp(-c L)`, and only the residual is tracked against `m - c`,
//!   multiplying by `1 - (sigma_t - c) / (m - c)`, with Russian roulette once the estimate falls
//!   below [`RR_TRANSMITTANCE`] (survivors are reset to that value, so the estimate stays
//!   unbiased). [`ratio_transmittance`] is plain ratio tracking, the baseline.
//!
//! Both guarantee progress: if `t + step` rounds to `t` (a dense medium far from the origin),
//! `t` moves to the next representable float, so no loop can stall.

use crate::medium::{IndexRay, Medium};
use crate::sampling::SampleStream;

/// Ratio-tracking estimates below this play Russian roulette.
pub const RR_TRANSMITTANCE: f32 = 0.1;

#[inline]
fn advance(t: f32, step: f32) -> f32 {
    let n = t + step;
    if n > t { n } else { t.next_up() }
}

#[inline]
fn exp_step(rng: &mut SampleStream, majorant: f32) -> f32 {
    // 1 - u lies in (0, 1], so the logarithm is finite.
    -(1.0 - rng.next_f32()).ln() / majorant
}

/// A real collision: where it is along the ray, and the data value there, which the caller needs
/// for the albedo (returned so that the voxels are not fetched twice at the same point).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collision {
    pub t: f32,
    pub value: f32,
}

/// The first real collision in `[t0, t1]`, or None if the ray passes through.
#[inline]
pub fn free_flight(
    medium: &Medium,
    ray: &IndexRay,
    t0: f32,
    t1: f32,
    rng: &mut SampleStream,
) -> Option<Collision> {
    let (t0, t1) = medium.clip(ray, t0, t1)?;
    for seg in medium.segments(ray, t0, t1) {
        // Written so that NaN majorants are skipped like empty cells.
        if !(seg.majorant > 0.0) {
            continue;
        }
        let mut t = seg.t0;
        loop {
            t = advance(t, exp_step(rng, seg.majorant));
            if !(t < seg.t1) {
                break;
            }
            let u = ray.at(t);
            let value = medium.value(u);
            if rng.next_f32() * seg.majorant < medium.extinction_with(value, u) {
                return Some(Collision { t, value });
            }
        }
    }
    None
}

/// Unbiased estimate of the transmittance over `[t0, t1]` by residual ratio tracking (Novák et
/// al. 2014, "Residual ratio tracking for estimating attenuation in participating media"), with
/// each macrocell's smallest extinction as its control `c`: `exp(-c L)` is exact, and only the
/// residual `sigma_t - c` is tracked, against the residual majorant `m - c`. Where a cell's
/// extinction is constant the estimate is exact with no random number; where `c = 0` it is
/// [`ratio_transmittance`].
#[inline]
pub fn transmittance(
    medium: &Medium,
    ray: &IndexRay,
    t0: f32,
    t1: f32,
    rng: &mut SampleStream,
) -> f32 {
    track_transmittance(medium, ray, t0, t1, rng, true)
}

/// Unbiased estimate of the transmittance over `[t0, t1]` by plain ratio tracking (every
/// tentative collision of the full majorant multiplies by its null probability): the baseline
/// [`transmittance`] is measured against.
#[inline]
pub fn ratio_transmittance(
    medium: &Medium,
    ray: &IndexRay,
    t0: f32,
    t1: f32,
    rng: &mut SampleStream,
) -> f32 {
    track_transmittance(medium, ray, t0, t1, rng, false)
}

/// Residual ratio tracking with each cell's control, or plain ratio tracking (a control of 0,
/// which makes every step the same as ratio tracking's).
#[inline(always)]
fn track_transmittance(
    medium: &Medium,
    ray: &IndexRay,
    t0: f32,
    t1: f32,
    rng: &mut SampleStream,
    use_control: bool,
) -> f32 {
    let Some((t0, t1)) = medium.clip(ray, t0, t1) else {
        return 1.0;
    };
    let mut tr = 1.0f32;
    for seg in medium.segments(ray, t0, t1) {
        if !(seg.majorant > 0.0) {
            continue;
        }
        let control = if use_control { seg.control } else { 0.0 };
        if control > 0.0 {
            tr *= (-control * (seg.t1 - seg.t0)).exp();
        }
        let residual_majorant = seg.majorant - control;
        // Written so that NaN skips the tracking, like an exact cell.
        if !(residual_majorant > 0.0) {
            continue;
        }
        let mut t = seg.t0;
        loop {
            t = advance(t, exp_step(rng, residual_majorant));
            if !(t < seg.t1) {
                break;
            }
            let residual = medium.extinction(ray.at(t)) - control;
            tr *= (1.0 - residual / residual_majorant).max(0.0);
            if tr < RR_TRANSMITTANCE {
                if tr <= 0.0 || rng.next_f32() * RR_TRANSMITTANCE >= tr {
                    return 0.0;
                }
                tr = RR_TRANSMITTANCE;
            }
        }
    }
    tr
}
