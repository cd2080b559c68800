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

/// The schedule's state since the last change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schedule {
    decay: Decay,
    /// Frames trained since the last change.
    frames: u32,
    /// Frames trained since the decay started (Eq. 5's `t`); 0 before it has.
    decaying: u32,
    fast: f64,
    slow: f64,
}

impl Schedule {
    pub fn new(decay: Decay) -> Self {
        Self {
            decay,
            frames: 0,
            decaying: 0,
            fast: f64::NAN,
            slow: f64::NAN,
        }
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
}
