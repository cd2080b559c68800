//! The learning-rate schedule. The GSCache paper's Eq. 5 lowers the rate as `1 / (1 + ln t)`
//! while the view stays put, `t` counting the frames since the camera, the transfer function or
//! the lights last changed, and returns it to its initial value on a change.
//!
//! Counting from the first still frame decays the rate before the cache has converged: on a
//! still headsq camera the cache was still 2x worse than NEE after 100 frames, while the same
//! camera restarting the schedule every frame ended 3.8x better (docs/results/schedule). With
//! [`Decay::Plateau`] the count starts only once the training error levels off: the rate stays
//! at its initial value while a fast moving average of the error is still clearly below a slow
//! one, and Eq. 5 takes over from the frame the two meet.
//!
//! The same test tells the cache when training has settled on a still view, so it can train on
//! fewer frames (`CacheConfig::adaptive_training`, the GSCache paper's suggestion in its
//! section 4.4): a settled schedule asks for a step on one frame in [`SETTLED_TRAIN_EVERY`].

use serde::{Deserialize, Serialize};

/// When Eq. 5's decay starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Decay {
    /// At the first frame after a change (the paper's).
    Paper,
    /// Once the training error stops falling.
    Plateau,
    /// Never: the initial rate throughout.
    Off,
}

/// Weights of the two moving averages of the training error, per frame.
const FAST: f64 = 0.3;
const SLOW: f64 = 0.1;
/// The error has levelled off when the fast average is within this fraction of the slow one.
const LEVEL: f64 = 0.97;
/// Frames after a change before a plateau may be declared (the averages need a few samples).
const MIN_FRAMES: u32 = 8;
/// Once the error has levelled off on a still view, a training step is taken on one frame in
/// this many (with adaptive training).
pub const SETTLED_TRAIN_EVERY: u32 = 4;

/// The schedule's state since the last change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schedule {
    decay: Decay,
    /// Frames trained since the last change.
    frames: u32,
    /// Frames trained since the decay started (Eq. 5's `t`); 0 before it has.
    decaying: u32,
    /// Frames asked about since the error levelled off (whatever the decay mode); 0 before.
    settled: u32,
    fast: f64,
    slow: f64,
}

impl Schedule {
    pub fn new(decay: Decay) -> Self {
        Self {
            decay,
            frames: 0,
            decaying: 0,
            settled: 0,
            fast: f64::NAN,
            slow: f64::NAN,
        }
    }

    /// Whether a frame should take a training step when training adapts to the error: every
    /// frame until the error has levelled off since the last change, then one in
    /// [`SETTLED_TRAIN_EVERY`]. Call once per frame.
    pub fn wants_step(&mut self) -> bool {
        if self.settled == 0 && !self.levelled_off() {
            return true;
        }
        self.settled = self.settled.saturating_add(1);
        self.settled % SETTLED_TRAIN_EVERY == 1
    }

    /// The factor for the next training step.
    pub fn next_scale(&mut self) -> f32 {
        self.frames = self.frames.saturating_add(1);
        let started = match self.decay {
            Decay::Paper => true,
            Decay::Off => false,
            Decay::Plateau => self.decaying > 0 || self.levelled_off(),
        };
        if !started {
            return 1.0;
        }
        self.decaying = self.decaying.saturating_add(1);
        1.0 / (1.0 + (self.decaying as f32).ln())
    }

    /// The training error of the step just taken (any measure that falls as the cache fits;
    /// non-finite values are ignored).
    pub fn observe(&mut self, error: f64) {
        if !error.is_finite() {
            return;
        }
        if self.fast.is_nan() {
            (self.fast, self.slow) = (error, error);
        } else {
            self.fast += FAST * (error - self.fast);
            self.slow += SLOW * (error - self.slow);
        }
    }

    fn levelled_off(&self) -> bool {
        self.frames > MIN_FRAMES && self.fast >= LEVEL * self.slow
    }

    /// The view or the scene changed: back to the initial rate.
    pub fn reset(&mut self) {
        *self = Self::new(self.decay);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq5() {
        let mut s = Schedule::new(Decay::Paper);
        assert_eq!(s.next_scale(), 1.0);
        assert!((s.next_scale() - 1.0 / (1.0 + 2f32.ln())).abs() < 1e-7);
        s.reset();
        assert_eq!(s.next_scale(), 1.0);
        let mut off = Schedule::new(Decay::Off);
        assert!((0..50).all(|_| off.next_scale() == 1.0));
    }

    #[test]
    fn plateau_waits_while_the_error_falls_then_decays() {
        let mut s = Schedule::new(Decay::Plateau);
        // The error halves every 10 frames for 60 frames: full rate throughout.
        for f in 0..60 {
            assert_eq!(s.next_scale(), 1.0, "frame {f}");
            s.observe(0.5f64.powf(f as f64 / 10.0));
        }
        // Then it stays flat: the averages meet and Eq. 5 starts at t = 1.
        let mut first_decayed = None;
        for f in 60..200 {
            let r = s.next_scale();
            if r < 1.0 && first_decayed.is_none() {
                first_decayed = Some(f);
                assert!(
                    (r - 1.0 / (1.0 + 2f32.ln())).abs() < 1e-6,
                    "t = 2 after t = 1: {r}"
                );
            }
            s.observe(0.5f64.powf(6.0));
        }
        let f = first_decayed.expect("a flat error must start the decay");
        assert!((61..140).contains(&f), "decay started at frame {f}");
        // A change restarts everything.
        s.reset();
        assert_eq!(s.next_scale(), 1.0);
        s.observe(f64::NAN);
        assert_eq!(s.next_scale(), 1.0);
    }

    /// Adaptive training asks for a step every frame while the error falls (and after any
    /// change), then on one frame in SETTLED_TRAIN_EVERY once it levels off, in any decay mode.
    #[test]
    fn steps_thin_out_once_the_error_levels_off() {
        for decay in [Decay::Paper, Decay::Plateau, Decay::Off] {
            let mut s = Schedule::new(decay);
            for f in 0..60 {
                assert!(s.wants_step(), "{decay:?} frame {f}");
                s.next_scale();
                s.observe(0.5f64.powf(f as f64 / 10.0));
            }
            let mut steps = Vec::new();
            for f in 60..200 {
                if s.wants_step() {
                    steps.push(f);
                    s.next_scale();
                    s.observe(0.5f64.powf(6.0));
                }
            }
            let first = steps[0];
            assert!(steps.len() > 20, "{decay:?}: {steps:?}");
            let gaps: Vec<u32> = steps.windows(2).map(|w| w[1] - w[0]).collect();
            let settled_at = gaps
                .iter()
                .position(|&g| g > 1)
                .expect("steps must thin out");
            assert!(
                gaps[settled_at..].iter().all(|&g| g == SETTLED_TRAIN_EVERY),
                "{decay:?}: {gaps:?} (first step at {first})"
            );
            assert!(
                steps[settled_at] < 140,
                "{decay:?}: settled late: {steps:?}"
            );
            s.reset();
            assert!(
                (0..5).all(|_| s.wants_step()),
                "a change trains every frame again"
            );
        }
    }
}
