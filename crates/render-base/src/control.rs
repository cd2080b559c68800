//! How a caller steers long work: cancellation and progress, in one value.
//!
//! Every long loop in the project (a render, a cached frame, a warm-up, an experiment) takes a
//! [`Control`]. A program passes its Ctrl-C flag and its progress bar; a test or a caller that
//! wants neither passes [`Control::none()`].

use std::sync::atomic::{AtomicBool, Ordering};

/// Never set: the flag of [`Control::none`].
static NEVER_CANCELLED: AtomicBool = AtomicBool::new(false);
/// Ignores progress: the callback of [`Control::none`].
static NO_PROGRESS: fn(u64) = |_| {};

/// Cancellation and progress for one piece of long work.
///
/// Work reads [`Control::cancelled`] before each unit (a sample, a frame) and stops promptly
/// once it is set, keeping what it has; it reports finished units (samples) through
/// [`Control::progress`], from any thread.
#[derive(Clone, Copy)]
pub struct Control<'a> {
    cancel: &'a AtomicBool,
    progress: &'a (dyn Fn(u64) + Sync),
    /// A render's first sample of every pixel is taken even if cancelled meanwhile (see
    /// [`Control::keeping_every_pixel`]).
    every_pixel: bool,
}

impl std::fmt::Debug for Control<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Control")
            .field("cancelled", &self.cancelled())
            .finish_non_exhaustive()
    }
}

impl Control<'static> {
    /// Neither cancellable nor reporting.
    pub fn none() -> Self {
        Control {
            cancel: &NEVER_CANCELLED,
            progress: &NO_PROGRESS,
            every_pixel: false,
        }
    }
}

impl<'a> Control<'a> {
    /// Stops when `cancel` is set; reports progress to `progress(units_done)`.
    pub fn new(cancel: &'a AtomicBool, progress: &'a (dyn Fn(u64) + Sync)) -> Self {
        Control {
            cancel,
            progress,
            every_pixel: false,
        }
    }

    /// Stops when `cancel` is set; reports no progress.
    pub fn cancellable(cancel: &'a AtomicBool) -> Self {
        Control {
            cancel,
            progress: &NO_PROGRESS,
            every_pixel: false,
        }
    }

    /// The same cancellation with progress going to `progress` instead.
    pub fn with_progress<'b>(&self, progress: &'b (dyn Fn(u64) + Sync)) -> Control<'b>
    where
        'a: 'b,
    {
        Control {
            cancel: self.cancel,
            progress,
            every_pixel: self.every_pixel,
        }
    }

    /// The same cancellation, reporting no progress.
    pub fn silent(&self) -> Control<'a> {
        Control {
            cancel: self.cancel,
            progress: &NO_PROGRESS,
            every_pixel: self.every_pixel,
        }
    }

    /// The same control, asking a render to take the first sample of every pixel even when
    /// cancelled meanwhile: for an image that is kept when interrupted (a program's render,
    /// Python's `render`), where a pixel without a sample would be shown black. A frame that
    /// is thrown away when cancelled (the viewer's) does without, and stops at once.
    pub fn keeping_every_pixel(&self) -> Control<'a> {
        Control {
            every_pixel: true,
            ..*self
        }
    }

    /// Whether a render should take every pixel's first sample before it may stop.
    pub fn keeps_every_pixel(&self) -> bool {
        self.every_pixel
    }

    /// The same progress, never cancelled: for work that must finish once begun (a render's
    /// first sample of every pixel, without which a pixel would be shown black).
    pub fn uncancellable(&self) -> Control<'a> {
        Control {
            cancel: &NEVER_CANCELLED,
            progress: self.progress,
            every_pixel: self.every_pixel,
        }
    }

    /// Whether the work should stop now.
    #[inline]
    pub fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }

    /// Reports `units` more finished.
    #[inline]
    pub fn progress(&self, units: u64) {
        (self.progress)(units)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU64;

    #[test]
    fn none_is_never_cancelled_and_ignores_progress() {
        let c = Control::none();
        c.progress(5);
        assert!(!c.cancelled());
    }

    #[test]
    fn a_set_flag_cancels_and_progress_arrives() {
        let flag = AtomicBool::new(false);
        let done = AtomicU64::new(0);
        let report = |n| {
            done.fetch_add(n, Ordering::Relaxed);
        };
        let c = Control::new(&flag, &report);
        c.progress(3);
        c.silent().progress(100);
        assert!(!c.cancelled());
        flag.store(true, Ordering::Relaxed);
        assert!(c.cancelled() && c.silent().cancelled());
        assert_eq!(done.load(Ordering::Relaxed), 3);
    }
}
