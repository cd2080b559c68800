//! A ray's slots: how many a traversal keeps, their thresholds drawn from one number a slot,
//! and the estimate they give (see the module docs' **The estimate**).

use super::*;

/// The slots a traversal keeps for `samples_per_traversal`: at least one, at most
/// [`MAX_SLOTS`].
pub(super) fn slot_count(samples_per_traversal: u32) -> usize {
    (samples_per_traversal.max(1) as usize).min(MAX_SLOTS)
}

/// A ray's slots' thresholds ([`SampleKey::slot_thresholds`]) into `thresholds`; returns the
/// largest, the first the transmittance must fall below.
///
/// The estimate is the mean of the slots' colours, so the slots are interchangeable, and the
/// transmittance only falls, so the slots a ray has filled are always those whose thresholds
/// are above its transmittance: its state is how many it has filled, and its next threshold
/// the largest of the others ([`above_and_next`]). Nothing is sorted, no mask of open slots
/// is kept, and no branch is taken per slot.
#[inline(always)]
pub(super) fn draw_thresholds<L: Lanes>(
    token: L::Token,
    key: &SampleKey,
    thresholds: &mut [f32],
) -> f32 {
    key.slot_thresholds(thresholds);
    above_and_next::<L>(token, thresholds, f32::INFINITY).1
}

/// How many of `thresholds` are above `t`, and the largest not above it, or -1 (which no
/// transmittance falls below) when every one is. Thresholds are never NaN; a NaN `t` is above
/// none of them. Both are exact, so the same in any lanes: eight thresholds (the lookup's
/// default) are compared in `L`'s lanes at once, other counts one by one.
#[inline(always)]
pub(super) fn above_and_next<L: Lanes>(
    token: L::Token,
    thresholds: &[f32],
    t: f32,
) -> (usize, f32) {
    if let Ok(eight) = <&[f32; 8]>::try_from(thresholds) {
        let (t, none) = (L::splat(token, t), L::splat(token, -1.0));
        let (mut above, mut largest) = (0, none);
        for first in (0..8).step_by(L::N) {
            let u = L::load(token, &eight[first..]);
            let is_above = t.lt(u);
            above += L::count(is_above) as usize;
            largest = L::select(is_above, none, u).max(largest);
        }
        return (above, largest.reduce_max());
    }
    thresholds
        .iter()
        .fold((0, -1.0f32), |(above, largest), &u| {
            if t < u {
                (above + 1, largest)
            } else {
                (above, if u > largest { u } else { largest })
            }
        })
}

/// A ray's slots after its transmittance fell to `t` across a hit of colour `color`: every
/// unfilled slot whose threshold is above `t` takes the hit (adds the colour). `filled` as
/// [`draw_thresholds`] describes it; returns the next threshold.
#[inline(always)]
pub(super) fn fill_slots<L: Lanes>(
    token: L::Token,
    thresholds: &[f32],
    filled: &mut usize,
    colour: &mut Vec3,
    t: f32,
    color: Vec3,
) -> f32 {
    // The filled slots' thresholds are above every earlier transmittance, so above `t`: the
    // count of thresholds above `t` is the slots filled now (NaN counts none).
    let (above, next) = above_and_next::<L>(token, thresholds, t);
    let reached = above.max(*filled);
    *colour += (reached - *filled) as f32 * color;
    *filled = reached;
    next
}

/// [`LANES`] pixels' taking-part bytes (each 0 or 1) as a bit each, the first pixel's lowest:
/// one multiply moves byte `i`'s bit to bit `56 + i` (the partial products never overlap, so
/// nothing carries).
#[inline(always)]
pub(super) fn taking_part_bits(bytes: &[u8]) -> u8 {
    let word = u64::from_le_bytes(bytes[..LANES].try_into().expect("LANES bytes"));
    (word.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u8
}

/// One estimate: the mean of the slots' colours, `background` for each slot left unfilled.
pub(super) fn estimate(colour: Vec3, filled: usize, slots: usize, background: Vec3) -> Vec3 {
    (colour + (slots - filled) as f32 * background) / slots as f32
}

/// Gaussian `i`'s centre depth along the camera's forward axis, as
/// [`TraceGaussians::intersect`] computes it.
pub(super) fn depth_of(g: &TraceGaussians, camera: &Camera, forward: Vec3, i: usize) -> f32 {
    (g.means[i] - camera.position).dot(forward)
}
