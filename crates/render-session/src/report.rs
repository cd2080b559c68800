//! What one frame did.

/// One frame's figures: the GSCache paper's PT, ST (or the neural cache's IT) and OT columns,
/// and what the caller needs to account for the frame.
#[derive(Debug, Clone, Default)]
pub struct FrameReport {
    /// The frame's index in the session (the sampling rule's `k`).
    pub frame: u32,
    /// Samples traced (pixels x spp).
    pub samples: u64,
    /// Path tracing (PT).
    pub trace_seconds: f64,
    /// Reading the cache: drawing the Gaussian levels (ST), or the neural cache's inference and
    /// composition (IT). Zero without a cache.
    pub lookup_seconds: f64,
    /// Gathering the paths' training samples into the Gaussian cache's targets (the neural
    /// cache counts its gathering in training). Zero without a cache.
    pub targets_seconds: f64,
    /// Training the cache (OT): its part of the frame's wall time. Zero without a cache.
    pub train_seconds: f64,
    /// The training step's own duration. The neural cache runs the previous frame's step
    /// beside this frame's path tracing, so its `train_seconds` is only the wait for the step
    /// after tracing (and filing the frame's records), and this is more; otherwise the two are
    /// equal.
    pub train_step_seconds: f64,
    /// Making a scratch film for a frame that keeps none (a warm-up frame).
    pub film_seconds: f64,
    /// Wall-clock seconds of the whole frame, accumulation included.
    pub seconds: f64,
    /// Samples that came out NaN or infinite and were counted as black.
    pub nonfinite_samples: u64,
    /// Training samples the cache refused (negative or not finite).
    pub dropped_training_samples: u64,
    /// Per level, the training loss before the step (the neural cache: one entry, the mean
    /// relative L2 loss of the step taken during this frame, on the previous frame's records;
    /// none when it took no step).
    pub loss: Vec<Option<f64>>,
    /// Per level of the Gaussian cache, the fraction of its pixels whose residual was gross
    /// this frame (the fallback's verdict: paths there go on as plain path tracing); `None`
    /// where the level was not judged. Empty for the other caches.
    pub stale_fraction: Vec<Option<f64>>,
    /// The Gaussian cache had handed the image off to plain path tracing.
    pub handed_off: bool,
    /// The frame went into the session's image (a warm-up frame does not).
    pub accumulated: bool,
    pub cancelled: bool,
}

impl FrameReport {
    /// Adds the next pass of the same image to this report: times and counts add up; the
    /// losses, verdicts and handoff are the last pass's.
    pub fn absorb(&mut self, next: FrameReport) {
        self.samples += next.samples;
        self.trace_seconds += next.trace_seconds;
        self.lookup_seconds += next.lookup_seconds;
        self.targets_seconds += next.targets_seconds;
        self.train_seconds += next.train_seconds;
        self.train_step_seconds += next.train_step_seconds;
        self.film_seconds += next.film_seconds;
        self.seconds += next.seconds;
        self.nonfinite_samples += next.nonfinite_samples;
        self.dropped_training_samples += next.dropped_training_samples;
        self.loss = next.loss;
        self.stale_fraction = next.stale_fraction;
        self.handed_off = next.handed_off;
        self.accumulated |= next.accumulated;
        self.cancelled |= next.cancelled;
    }

    /// The frame's wall time outside its named parts (the session's own bookkeeping): what a
    /// per-frame table must show so its parts add up to the frame (issue 31).
    pub fn other_seconds(&self) -> f64 {
        self.seconds
            - (self.trace_seconds
                + self.lookup_seconds
                + self.targets_seconds
                + self.train_seconds
                + self.film_seconds)
    }
}
