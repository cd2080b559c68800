//! What the pages are shown: every frame goes out through one [`Publisher`], raw from the
//! render thread or denoised from the filter thread ([`FilterThread`]), and a frame never
//! replaces a newer one.
//!
//! Why a thread of its own: Open Image Denoise takes 20-40 ms on a 320x180 preview and
//! 0.3-0.6 s on a 1280x720 view on 2 cores (BENCHMARKS.md). Run on the render thread (as until
//! issue 65) it blocked the next frame: a drag that started during a run showed nothing until
//! the run ended, seconds later at large sizes. Here the render thread hands an image over and
//! goes on; the filter works beside it, and a still view's run is abandoned the moment the view
//! changes (OIDN's progress monitor, [`denoise::Denoiser::abort_handle`]), so the drag's first
//! frame waits for nothing. A preview's run is never abandoned: it is short, and its image is
//! the newest clean one there is.
//!
//! The hand-over is one slot: the newest image waiting replaces one not yet started (the latest
//! frame wins, as on the frame channel), so the filter never works through a backlog of views
//! already gone.

use crate::worker::Frame;
use denoise::{DenoiseError, Options, Quality};
use hdr_image::RgbImage;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;
use tokio::sync::watch;

/// The frame channel, and the sequence number of the frame on it: each frame is numbered in
/// the order its image was rendered, and one older than the frame shown is dropped (a
/// denoised image that finished after a newer raw one, or the reverse).
pub struct Publisher {
    frames: watch::Sender<Option<Arc<Frame>>>,
    shown: Mutex<u64>,
}

impl Publisher {
    pub fn new(frames: watch::Sender<Option<Arc<Frame>>>) -> Self {
        Self {
            frames,
            shown: Mutex::new(0),
        }
    }

    /// Shows `frame`, rendered as number `sequence`, unless a newer one is shown.
    pub fn publish(&self, sequence: u64, frame: Frame) {
        let mut shown = lock(&self.shown);
        if sequence >= *shown {
            *shown = sequence;
            self.frames.send_replace(Some(Arc::new(frame)));
        }
    }

    /// Sends the frame shown again (a page that just connected sees it at once).
    pub fn repeat(&self) {
        let _shown = lock(&self.shown);
        // The read guard must be gone before the write: they share one lock.
        let current = self.frames.borrow().clone();
        if let Some(frame) = current {
            self.frames.send_replace(Some(frame));
        }
    }
}

/// A poisoned lock means a thread panicked holding it; the data (numbers and a slot) is still
/// whole, so the viewer goes on.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// What kind of image a [`FilterJob`] holds, which decides the filter's quality and whether a
/// change of view abandons it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobKind {
    /// A frame of a moving view (or the quick frame after an edit): filtered fast, never
    /// abandoned.
    Preview,
    /// The still view's image at `spp` samples a pixel: abandoned when the view changes.
    Still { spp: u32 },
}

/// One image for the filter thread.
pub struct FilterJob {
    /// The order the image was rendered in ([`Publisher::publish`]).
    pub sequence: u64,
    /// The view it belongs to: a still job of an older view is abandoned.
    pub view: u64,
    pub kind: JobKind,
    pub image: RgbImage,
    /// The scene's tone map and exposure, for encoding.
    pub output: volume_pt::scene::OutputDesc,
    /// The frame's statistics; the filter thread adds its own figures.
    pub stats: serde_json::Value,
}

/// What the render thread may read of the filter thread's work.
#[derive(Debug, Clone, Default)]
pub struct FilterStatus {
    /// Whether a job is waiting or under way.
    pub busy: bool,
    /// Seconds a preview pixel took to filter and encode, smoothed (0 until measured).
    pub preview_seconds_per_pixel: f64,
    /// Why the filter failed, once it has: denoising is then off.
    pub failed: Option<String>,
    /// Still images whose run was abandoned because the view changed.
    pub abandoned: u64,
}

#[derive(Default)]
struct Slot {
    waiting: Option<FilterJob>,
    /// The job under way: its view and kind.
    running: Option<(u64, JobKind)>,
    status: FilterStatus,
    stop: bool,
}

struct Shared {
    slot: Mutex<Slot>,
    wake: Condvar,
    /// The denoiser's abort flag ([`denoise::Denoiser::abort_handle`]).
    abort: Arc<AtomicBool>,
}

/// The filter thread: owns the denoiser, takes [`FilterJob`]s and publishes their results.
pub struct FilterThread {
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl FilterThread {
    /// Starts the thread; the denoiser is loaded by the caller (on the page's first request)
    /// and handed over here.
    pub fn start(denoiser: denoise::Denoiser, publisher: Arc<Publisher>) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot::default()),
            wake: Condvar::new(),
            abort: denoiser.abort_handle(),
        });
        let thread = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("gscache-view-filter".into())
                .spawn(move || filter_loop(denoiser, &shared, &publisher))?
        };
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Hands `job` over, replacing one that has not started.
    pub fn submit(&self, job: FilterJob) {
        let mut slot = lock(&self.shared.slot);
        slot.waiting = Some(job);
        self.shared.wake.notify_all();
    }

    /// The view is now `view`: a still image of another view, waiting or under way, is
    /// dropped or abandoned.
    pub fn view_changed(&self, view: u64) {
        let mut slot = lock(&self.shared.slot);
        if slot
            .waiting
            .as_ref()
            .is_some_and(|j| j.view != view && matches!(j.kind, JobKind::Still { .. }))
        {
            slot.waiting = None;
        }
        if let Some((running, JobKind::Still { .. })) = slot.running
            && running != view
        {
            // Cleared by the thread under this lock when it starts its next job, so this
            // reaches the run recorded as under way and no other.
            self.shared.abort.store(true, Ordering::Relaxed);
        }
    }

    /// Waits, at most `timeout`, while a preview is waiting or being filtered. The render
    /// thread calls it before rendering the next preview: rendering beside the filter slows
    /// both on a machine of few cores (each uses them all), so a drag's frame would reach the
    /// screen later for no more frames a second.
    pub fn wait_for_preview(&self, timeout: std::time::Duration) {
        let deadline = Instant::now() + timeout;
        let mut slot = lock(&self.shared.slot);
        loop {
            let preview = |kind: Option<JobKind>| kind == Some(JobKind::Preview);
            if !(preview(slot.waiting.as_ref().map(|j| j.kind))
                || preview(slot.running.map(|r| r.1)))
            {
                return;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return;
            }
            slot = self
                .shared
                .wake
                .wait_timeout(slot, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    /// What the thread has done.
    pub fn status(&self) -> FilterStatus {
        let slot = lock(&self.shared.slot);
        FilterStatus {
            busy: slot.waiting.is_some() || slot.running.is_some(),
            ..slot.status.clone()
        }
    }
}

impl Drop for FilterThread {
    fn drop(&mut self) {
        {
            let mut slot = lock(&self.shared.slot);
            slot.stop = true;
            slot.waiting = None;
            self.shared.abort.store(true, Ordering::Relaxed);
            self.shared.wake.notify_all();
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The filter's settings: OIDN's fast filter for every image, moving or still. Against
/// converged views in LDR FLIP (`tools/denoise_handoff.py`, BENCHMARKS.md "The viewer on
/// screen") it is ahead of the high-quality filter at every sample count on neghip (which
/// `high` smooths most: 0.032 against 0.046 at 8 samples), level on hydrogen and within 9% on
/// the embryo, at half the time. Colour alone guides it: the albedo leaves bright halos near
/// lights and gains nothing in FLIP on any standard volume, and keeping no guides means
/// turning the filter on keeps the samples already taken.
const FILTER: Options = Options {
    quality: Quality::Fast,
    prefilter: false,
};

fn filter_loop(mut denoiser: denoise::Denoiser, shared: &Shared, publisher: &Publisher) {
    loop {
        let job = {
            let mut slot = lock(&shared.slot);
            slot.running = None;
            // A render thread waiting for the preview to be done goes on.
            shared.wake.notify_all();
            let job = loop {
                if slot.stop {
                    return;
                }
                if let Some(job) = slot.waiting.take() {
                    break job;
                }
                slot = shared.wake.wait(slot).unwrap_or_else(|e| e.into_inner());
            };
            slot.running = Some((job.view, job.kind));
            shared.abort.store(false, Ordering::Relaxed);
            job
        };
        let start = Instant::now();
        let result = denoiser.denoise(&job.image, None, None, FILTER);
        let filter_seconds = start.elapsed().as_secs_f64();
        match result {
            Ok(image) => {
                let encode_start = Instant::now();
                let jpeg = crate::worker::encode(&image, &job.output);
                let encode_seconds = encode_start.elapsed().as_secs_f64();
                let mut stats = job.stats;
                stats["denoise_ms"] = serde_json::Value::from(filter_seconds * 1e3);
                stats["encode_ms"] = serde_json::Value::from(encode_seconds * 1e3);
                stats["denoised"] = serde_json::Value::from(true);
                stats["filter_runs_abandoned"] =
                    serde_json::Value::from(lock(&shared.slot).status.abandoned);
                if let JobKind::Still { spp } = job.kind {
                    stats["denoised_spp"] = serde_json::Value::from(spp);
                }
                let stats = stats.to_string();
                publisher.publish(job.sequence, Frame { jpeg, stats });
                match job.kind {
                    JobKind::Still { .. } => {}
                    JobKind::Preview => {
                        let mut slot = lock(&shared.slot);
                        let pixels = f64::from(image.width()) * f64::from(image.height());
                        let per_pixel = (filter_seconds + encode_seconds) / pixels;
                        let s = &mut slot.status.preview_seconds_per_pixel;
                        *s = if *s == 0.0 {
                            per_pixel
                        } else {
                            0.7 * *s + 0.3 * per_pixel
                        };
                    }
                }
            }
            Err(DenoiseError::Cancelled) => lock(&shared.slot).status.abandoned += 1,
            Err(e) => {
                lock(&shared.slot).status.failed = Some(e.to_string());
            }
        }
    }
}
