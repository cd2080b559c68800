//! The GSCache paper's Eq. 5: the learning rate falls as `1 / (1 + ln t)` while the view stays put,
//! and returns to its initial value when the camera, the transfer function or the lights change.

/// Frames trained since the last reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Schedule {
    frames: u32,
}

impl Schedule {
    /// The factor for the next training step (t = 1 on the first step after a reset).
    pub fn next_scale(&mut self) -> f32 {
        self.frames = self.frames.saturating_add(1);
        1.0 / (1.0 + (self.frames as f32).ln())
    }

    pub fn reset(&mut self) {
        self.frames = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq5() {
        let mut s = Schedule::default();
        assert_eq!(s.next_scale(), 1.0);
        assert!((s.next_scale() - 1.0 / (1.0 + 2f32.ln())).abs() < 1e-7);
        s.reset();
        assert_eq!(s.next_scale(), 1.0);
    }
}
