//! The render thread. It owns the session and is the only one to touch it: edits arrive as
//! [`Command`]s between frames (a frame in flight is cancelled when one arrives, so an edit shows
//! at the next frame), and every frame is published tone-mapped as JPEG to a `watch` channel,
//! whose readers see only the latest: a slow or vanished client never holds rendering back.
//!
//! The still view accumulates (the session's progressive image) up to the scene's samples per
//! pixel, then the thread waits for the next edit. While the user drags the camera, and for the
//! first frame after an edit, the view renders smaller, with any method (the cache is kept
//! across sizes and goes on training from the small frames: where the frame budget is about one
//! sample, the Gaussian cache is the better preview, docs/results/cache_error.md), at the size
//! [`PreviewGovernor`] picks from the frames' measured time (rendering, filtering and encoding)
//! to hold a target rate; then it refines at full size. The split view previews too, both
//! halves at the same size.
//!
//! The full size is the page's view area in device pixels times the resolution scale, within
//! `--max-size` ([`Resolution`]); until a page says its size, the scene's.
//!
//! With denoising on, every frame shown is denoised, by the filter thread
//! ([`crate::display`]): each preview frame, and the still view's image at 1, 2, 4, 8, ...
//! samples a pixel and at the last (or until [`Denoising::until_spp`], from which the raw
//! image is shown), while the render thread goes on accumulating. Turning the filter on or
//! off keeps the samples taken. A drag renders each camera once and waits for the next.

use crate::display::{FilterJob, FilterThread, JobKind, Publisher};
use crate::protocol::{
    Change, ClientMessage, LightSettings, Method, SceneFacts, TransferSettings, ViewState, check,
    colour_bar, hello, transfer_settings_of,
};
use crate::save::{SaveRequest, save};
use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as BASE64;
use hdr_image::RgbImage;
use render_session::{Control, Edit, FrameReport, Session};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, watch};
use volume_pt::Scene;
use volume_pt::scene::ViewDesc;

/// A frame as the clients get it.
#[derive(Debug)]
pub struct Frame {
    pub jpeg: Vec<u8>,
    /// The frame's statistics as a JSON text message.
    pub stats: String,
}

/// A text message for some of the pages.
#[derive(Debug, Clone)]
pub struct Event {
    pub to: Recipients,
    pub text: Arc<String>,
}

/// Which pages an [`Event`] is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Recipients {
    One(u64),
    All,
    /// Every page but this one (the one whose edit it reports).
    Others(u64),
}

impl Recipients {
    /// Whether page `id` gets it.
    pub fn include(self, id: u64) -> bool {
        match self {
            Recipients::One(to) => to == id,
            Recipients::All => true,
            Recipients::Others(not) => not != id,
        }
    }
}

/// What the server asks of the render thread.
#[derive(Debug)]
pub enum Command {
    /// A client connected: send it the greeting.
    Hello {
        client: u64,
    },
    /// A message from a client: checked here, against the view's state, then applied; what is
    /// wrong with it goes back to that client.
    Message {
        client: u64,
        message: crate::protocol::ClientMessage,
    },
    /// A client left: if it was dragging, its drag ends; with no client left, rendering
    /// stops until one comes.
    Goodbye {
        client: u64,
    },
    Shutdown,
}

/// The size the view renders at, from the page's view area: `scale` times its device pixels,
/// fitted within `max_size` (the aspect kept).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resolution {
    pub scale: f32,
    pub max_size: (u32, u32),
}

impl Default for Resolution {
    /// Half the device pixels a side. On a 2-core Intel Xeon with the browser beside it, a
    /// 1280x720 window's view renders at 457x289 (0.5) or 686x433 (0.75): at 0.5 the first
    /// denoised full-size frame is on screen 270 ms after a release against 570 ms, and the
    /// image on screen 1 s and 5 s after it is closer to the converged view in FLIP, measured
    /// at the window's own pixels (the smaller image stretched as the browser stretches it)
    /// (BENCHMARKS.md, "The viewer on screen"). Within 1920x1080, which a 16-core machine
    /// refines at a few passes a second.
    fn default() -> Self {
        Self {
            scale: 0.5,
            max_size: (1920, 1080),
        }
    }
}

impl Resolution {
    /// The render size for a view area of `width x height` device pixels: at least 16 pixels
    /// a side.
    pub fn fit(&self, width: u32, height: u32) -> (u32, u32) {
        let (w, h) = (
            f64::from(width) * f64::from(self.scale),
            f64::from(height) * f64::from(self.scale),
        );
        let shrink = (f64::from(self.max_size.0) / w)
            .min(f64::from(self.max_size.1) / h)
            .min(1.0);
        (
            ((w * shrink).round() as u32).max(16),
            ((h * shrink).round() as u32).max(16),
        )
    }
}

/// How the viewer denoises what it shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Denoising {
    /// Whether denoising is on when the first page connects.
    pub start: DenoiseStart,
    /// The samples a pixel from which a still view shows its raw image rather than the
    /// filtered one (0: filtered to the last, the default). Against converged views in LDR
    /// FLIP the filtered image is ahead at every sample count measured (1-32) on hydrogen and
    /// the embryo, but behind from 8 on neghip, whose fine texture it smooths away
    /// (BENCHMARKS.md, "The viewer on screen"): data like that is better seen with 8 here.
    /// Every frame of a drag is filtered whatever this says.
    pub until_spp: u32,
}

/// Whether denoising is on from the start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DenoiseStart {
    Off,
    /// On where Open Image Denoise loads; off, without a word, where it does not.
    Auto,
    /// On; the first page is told if it cannot be.
    On,
}

impl Default for Denoising {
    fn default() -> Self {
        Self {
            start: DenoiseStart::Auto,
            until_spp: 0,
        }
    }
}

/// The render thread's state.
pub struct Worker {
    pub session: Session,
    pub facts: SceneFacts,
    pub scene_text: String,
    pub scene_file: PathBuf,
    pub output: PathBuf,
    pub transfer: TransferSettings,
    pub lights: LightSettings,
    pub method: Method,
    pub denoiser: denoise::OnDemand,
    pub denoise_on: bool,
    pub moving: bool,
    /// The next frame is the quick one after an edit (plain path tracing: at the preview size).
    pub preview: bool,
    /// The camera at full size (the session's may be the half-size one while moving).
    pub camera: volume_pt::Camera,
    /// Samples per pixel at which a still view stops refining.
    pub target_spp: u32,
    /// The split view's plain path tracing (the left half), and the seconds each side has
    /// rendered since the last edit (they are kept equal).
    pub split: Option<Session>,
    seconds: [f64; 2],
    /// The pages connected now: with none, nothing is rendered (a viewer nobody watches
    /// burns no cores).
    watching: usize,
    /// The page whose last camera message said it was dragging, while it drags.
    mover: Option<u64>,
    /// Frames per second, smoothed.
    fps: f64,
    last_frame: Option<Instant>,
    /// Picks the preview's size.
    governor: PreviewGovernor,
    /// Where every frame shown goes.
    publisher: Arc<Publisher>,
    /// The filter thread, from the first time denoising is turned on.
    filter: Option<FilterThread>,
    /// Frames rendered: the order of what is shown ([`Publisher::publish`]).
    sequence: u64,
    /// The view's generation: it changes with every edit that empties the image, which
    /// abandons a still image's filtering.
    view: u64,
    /// The samples per pixel of the still image last handed to the filter (0: none yet).
    still_posted: u32,
    /// The last frame's report (the statistics of a filtered image asked for between frames).
    last_report: FrameReport,
    /// The page's view area in device pixels, once a page has said it.
    viewport: Option<(u32, u32)>,
    resolution: Resolution,
    /// Denoising asked for at start, turned on when the first page connects (so that a
    /// missing library is said to it), and the samples from which a still view is raw.
    denoising: Denoising,
    /// Whether the view changed since the last frame rendered (see [`Worker::drag_paused`]).
    fresh: bool,
    /// Edits of what is seen applied so far: a frame's statistics carry the count, so that a
    /// page (or a harness) tells a frame made after its edit from one already on its way.
    edits: u64,
    /// The named views (bookmarks), saved with the scene.
    views: Vec<ViewDesc>,
    /// Per `[[channel]]` table, whether it is shown (all are at first).
    channels_visible: Vec<bool>,
    /// The time point shown.
    time: u32,
}

impl Worker {
    /// A worker on `scene` (its text and file, for saving), writing into `output`.
    pub fn new(
        scene: Scene,
        scene_text: String,
        scene_file: PathBuf,
        output: PathBuf,
        denoiser: denoise::OnDemand,
        resolution: Resolution,
        frames: watch::Sender<Option<Arc<Frame>>>,
    ) -> crate::Result<Self> {
        let facts = SceneFacts::of(&scene);
        let channels_visible = vec![true; facts.channels.len()];
        let time = scene.time;
        let transfer = transfer_settings_of(scene.media.medium.transfer_function(), 16);
        let lights = LightSettings::of(&facts);
        let target_spp = scene.settings.spp.max(1);
        let camera = scene.camera;
        let views = scene.views.clone();
        let mut session = Session::new(scene, render_session::CacheChoice::None)?;
        // One sample per pixel a frame: an edit shows within one frame's time.
        session.edit(Edit::Spp(1))?;
        Ok(Self {
            session,
            facts,
            scene_text,
            scene_file,
            output,
            transfer,
            lights,
            method: Method::Nee,
            denoiser,
            denoise_on: false,
            moving: false,
            preview: false,
            camera,
            target_spp,
            split: None,
            seconds: [0.0; 2],
            watching: 0,
            mover: None,
            fps: 0.0,
            last_frame: None,
            governor: PreviewGovernor::default(),
            publisher: Arc::new(Publisher::new(frames)),
            filter: None,
            sequence: 0,
            view: 0,
            still_posted: 0,
            last_report: FrameReport::default(),
            viewport: None,
            resolution,
            denoising: Denoising {
                start: DenoiseStart::Off,
                until_spp: 0,
            },
            fresh: true,
            edits: 0,
            views,
            channels_visible,
            time,
        })
    }

    /// The same worker, denoising as `denoising` says (turned on, if asked, when the first
    /// page connects).
    pub fn with_denoising(mut self, denoising: Denoising) -> Self {
        self.denoising = denoising;
        self
    }

    /// The camera in force as a named view: its eye, the point the page orbits (in front of
    /// the camera, nearest the volume's centre) and the page's up.
    fn view_of_camera(&self, name: String) -> ViewDesc {
        let camera = &self.camera;
        let (_, down, forward) = camera.axes();
        let target = camera.position
            + forward * (self.facts.centre - camera.position).dot(forward).max(1e-3);
        let up = if self.facts.up.dot(forward).abs() < 0.999 {
            self.facts.up
        } else {
            -down
        };
        ViewDesc {
            name,
            eye: camera.position.to_array(),
            target: target.to_array(),
            up: up.to_array(),
        }
    }

    /// The view's whole state for a page, as a message of type `kind`: `hello` on connecting,
    /// `state` after a refused edit.
    fn greeting(&self, kind: &str) -> String {
        let view = ViewState {
            camera: &self.camera,
            transfer: &self.transfer,
            lights: &self.lights,
            clip: self.session.scene().media.medium.clipping(),
            views: &self.views,
            tf: self.session.scene().media.medium.transfer_function(),
            method: self.method,
            show_lights: self.session.scene().settings.path.show_lights,
            split: self.split.is_some(),
            denoise: self.denoise_on,
            denoiser: self.denoiser.offered(),
            channels_visible: &self.channels_visible,
            time: self.time,
            scale: self.resolution.scale,
            size: (self.camera.width, self.camera.height),
        };
        let mut message = hello(&self.facts, &view);
        message["type"] = serde_json::Value::from(kind);
        message.to_string()
    }

    /// Nothing to render: no page is connected (a viewer nobody watches burns no cores), or
    /// the still view has its samples.
    fn converged(&self) -> bool {
        self.watching == 0
            || (!self.moving && !self.preview && self.session.frames_in_image() >= self.target_spp)
    }

    /// A drag whose camera has not moved since the last frame: another frame would only add
    /// a sample to a preview the next camera replaces. The render thread waits for that camera
    /// instead (at most [`Worker::DRAG_PAUSE`]), leaving the cores to the browser, whose
    /// pointer events and image decoding share them (issue 65: up to 45% of the frames shown
    /// in a drag were extra samples of a camera already on screen).
    fn drag_paused(&self) -> bool {
        self.moving && !self.fresh
    }

    /// How long a drag that has not moved waits before its preview is refined by a frame.
    const DRAG_PAUSE: Duration = Duration::from_millis(100);

    /// Reads time point `time` of the scene's volume (and its channels) and puts it in the
    /// view, keeping the view's transfer functions, clipping, phase and lights.
    fn show_time(&mut self, time: u32) -> Result<(), String> {
        if self.scene_text.trim().is_empty() {
            return Err("time: this scene has no scene file to read the volume again from".into());
        }
        let mut desc: volume_pt::scene::SceneFile = toml::from_str(&self.scene_text)
            .map_err(|e| format!("{}: {e}", self.scene_file.display()))?;
        desc.volume.time = time;
        let next =
            volume_pt::scene::build_scene(&self.scene_file, desc).map_err(|e| e.to_string())?;
        let now = &self.session.scene().media;
        let mut medium = next.media.medium;
        medium.set_transfer_function(now.medium.transfer_function().clone());
        medium
            .set_clipping(now.medium.clipping().clone())
            .map_err(|e| e.to_string())?;
        for (k, c) in now.medium.channels().iter().enumerate() {
            medium
                .set_channel_transfer_function(k, c.transfer_function().clone())
                .map_err(|e| e.to_string())?;
        }
        let media = volume_pt::SceneMedia {
            medium,
            phase: now.phase,
            lights: now.lights.clone(),
        };
        self.edit_all(Edit::Volume {
            media: Box::new(media),
            path: next.volume_path,
        })
    }

    /// Applies `edit` to the view's session and to the split view's, if on.
    fn edit_all(&mut self, edit: Edit) -> Result<(), String> {
        if let Some(split) = self.split.as_mut() {
            split.edit(edit.clone()).map_err(|e| e.to_string())?;
        }
        self.session.edit(edit).map_err(|e| e.to_string())?;
        self.seconds = [0.0; 2];
        Ok(())
    }

    /// With the split view on, renders a frame of whichever side has had less time, so the
    /// two stay at equal time; true if it rendered the plain side (nothing to publish yet).
    fn split_turn(&mut self, control: &Control) -> bool {
        let Some(split) = self.split.as_mut() else {
            return false;
        };
        if self.seconds[0] > self.seconds[1] {
            return false;
        }
        if let Ok(report) = split.next_frame(control) {
            self.seconds[0] += report.seconds;
        }
        true
    }

    /// The loop: apply what arrived, render a frame unless the view has converged, publish it.
    pub fn run(
        mut self,
        commands: Receiver<Command>,
        cancel: Arc<AtomicBool>,
        events: broadcast::Sender<Event>,
    ) {
        loop {
            let mut pending = Vec::new();
            if self.converged() {
                // The still image's last filtering, if the filter was busy when the last
                // sample came: asked for again shortly.
                let owed = self.filter_still_if_due(&events);
                let wait = Duration::from_millis(if owed { 20 } else { 250 });
                match commands.recv_timeout(wait) {
                    Ok(c) => pending.push(c),
                    Err(RecvTimeoutError::Timeout) => continue,
                    Err(RecvTimeoutError::Disconnected) => return,
                }
            } else if self.drag_paused() {
                match commands.recv_timeout(Self::DRAG_PAUSE) {
                    Ok(c) => pending.push(c),
                    // The pointer rests, still pressed: the preview refines by a frame.
                    Err(RecvTimeoutError::Timeout) => self.fresh = true,
                    Err(RecvTimeoutError::Disconnected) => return,
                }
            }
            pending.extend(commands.try_iter());
            cancel.store(false, Ordering::SeqCst);
            for command in pending {
                match command {
                    Command::Shutdown => return,
                    Command::Hello { client } => {
                        self.watching += 1;
                        let start = std::mem::replace(&mut self.denoising.start, DenoiseStart::Off);
                        if start != DenoiseStart::Off
                            && let Err(e) = self.apply(Change::Denoise(true), client, &events)
                            && start == DenoiseStart::On
                        {
                            let _ = events.send(Event {
                                to: Recipients::One(client),
                                text: Arc::new(error_json(&e)),
                            });
                        }
                        let text = self.greeting("hello");
                        let _ = events.send(Event {
                            to: Recipients::One(client),
                            text: Arc::new(text),
                        });
                        // A new client sees the current image at once.
                        self.publisher.repeat();
                    }
                    Command::Goodbye { client } => {
                        self.watching = self.watching.saturating_sub(1);
                        if self.mover == Some(client) {
                            // A page that vanished mid-drag will send no "still" camera.
                            self.mover = None;
                            self.moving = false;
                            if let Err(e) = self.set_camera() {
                                let _ = events.send(Event {
                                    to: Recipients::All,
                                    text: Arc::new(error_json(&e)),
                                });
                            }
                        }
                    }
                    Command::Message { client, message } => {
                        // Every page shows the one view: a change one page made is pushed to
                        // the others (a drag once its camera rests; a save, the levels or a
                        // probe change nothing they show).
                        let shared = !matches!(
                            message,
                            ClientMessage::Camera { moving: true, .. }
                                | ClientMessage::Save {}
                                | ClientMessage::Levels {}
                                | ClientMessage::Probe { .. }
                        );
                        let applied = check(message, &self.facts, &self.lights)
                            .and_then(|change| self.apply(change, client, &events));
                        if applied.is_ok() && shared && self.watching > 1 {
                            let _ = events.send(Event {
                                to: Recipients::Others(client),
                                text: Arc::new(self.greeting("state")),
                            });
                        }
                        if let Err(message) = applied {
                            let _ = events.send(Event {
                                to: Recipients::One(client),
                                text: Arc::new(error_json(&message)),
                            });
                            // The page's fields go back to the values in force: a refused
                            // value left in a field was sent again with every later edit.
                            let _ = events.send(Event {
                                to: Recipients::One(client),
                                text: Arc::new(self.greeting("state")),
                            });
                        }
                    }
                }
            }
            if self.converged() {
                continue;
            }
            if (self.moving || self.preview)
                && let Some(filter) = self.filter.as_ref().filter(|_| self.denoise_on)
            {
                filter.wait_for_preview(Duration::from_millis(250));
            }
            let control = Control::cancellable(&cancel);
            if self.split_turn(&control) {
                continue;
            }
            match self.session.next_frame(&control) {
                // A cancelled frame is partial (some pixels without a sample) and an edit is
                // waiting that will empty the image anyway: not shown.
                Ok(report) if report.cancelled => {}
                Ok(report) => {
                    self.seconds[1] += report.seconds;
                    self.sequence += 1;
                    self.fresh = false;
                    let size = self.session.camera();
                    let small =
                        (size.width, size.height) != (self.camera.width, self.camera.height);
                    if small {
                        // A preview frame: the governor learns what a pixel costs (twice with
                        // the split view, whose halves render at equal time between frames).
                        let pixels = f64::from(size.width) * f64::from(size.height);
                        let sides = if self.split.is_some() { 2.0 } else { 1.0 };
                        self.governor.observe(report.seconds * sides, pixels);
                    }
                    self.last_report = report;
                    self.show(small, &events);
                    // The quick frame is out: a still view refines at full size from here. (A
                    // drag stays small: putting its camera in again made a second frame of
                    // every camera, issue 65's repeated views.)
                    if std::mem::take(&mut self.preview)
                        && !self.moving
                        && let Err(e) = self.set_camera()
                    {
                        let _ = events.send(Event {
                            to: Recipients::All,
                            text: Arc::new(error_json(&e)),
                        });
                    }
                }
                Err(e) => {
                    let _ = events.send(Event {
                        to: Recipients::All,
                        text: Arc::new(error_json(&format!("rendering failed: {e}"))),
                    });
                    // Back to plain path tracing, which needs nothing that can fail.
                    self.method = Method::Nee;
                    let _ = self
                        .session
                        .edit(Edit::Cache(render_session::CacheChoice::None));
                }
            }
        }
    }

    /// Applies one checked change.
    fn apply(
        &mut self,
        change: Change,
        client: u64,
        events: &broadcast::Sender<Event>,
    ) -> Result<(), String> {
        // After an edit of what is seen, the first frame comes quickly at the preview size.
        if !matches!(
            change,
            Change::Save
                | Change::Denoise(_)
                | Change::Train(_)
                | Change::Levels
                | Change::Probe { .. }
                | Change::View { .. }
        ) {
            self.preview = true;
            self.edits += 1;
        }
        match change {
            Change::Camera { camera, moving } => {
                // The protocol checks a camera at the scene's size; the view's is kept.
                self.camera = camera
                    .with_size(self.camera.width, self.camera.height)
                    .map_err(|e| e.to_string())?;
                // At a drag's release with the filter on, the drag's last frame, denoised, is
                // on screen already: the first pass goes straight to full size (a quick frame
                // of the same view would only hold the filter up).
                if self.moving && !moving && self.filter.is_some() && self.denoise_on {
                    self.preview = false;
                }
                self.moving = moving;
                self.mover = moving.then_some(client);
                self.set_camera()?;
            }
            Change::Transfer(tf, settings) => {
                let colours = colour_bar(&tf);
                self.edit_all(Edit::TransferFunction(tf))?;
                self.transfer = settings;
                self.set_camera()?;
                // Every page's colour bar, the editing page's too (the others get the state).
                let _ = events.send(Event {
                    to: Recipients::All,
                    text: Arc::new(
                        serde_json::json!({"type": "colours", "colours": colours}).to_string(),
                    ),
                });
            }
            Change::Probe { x, y } => {
                let camera = self.camera;
                let direction =
                    camera.ray_direction(x * camera.width as f32, y * camera.height as f32);
                let found = self
                    .session
                    .scene()
                    .media
                    .medium
                    .probe(camera.position, direction);
                let hit = found.map(|p| {
                    serde_json::json!({
                        "position": p.position.to_array(),
                        "distance": p.distance,
                        "voxel": p.voxel.to_array(),
                        "value": p.value,
                        "filtered": p.filtered,
                        "opacity": p.opacity,
                    })
                });
                let _ = events.send(Event {
                    to: Recipients::One(client),
                    text: Arc::new(
                        serde_json::json!({"type": "probe", "x": x, "y": y, "hit": hit})
                            .to_string(),
                    ),
                });
            }
            Change::View { name, remove } => {
                let mut views = self.views.clone();
                if remove {
                    views.retain(|v| v.name != name);
                } else {
                    let view = self.view_of_camera(name);
                    match views.iter_mut().find(|v| v.name == view.name) {
                        Some(old) => *old = view,
                        None => views.push(view),
                    }
                }
                ViewDesc::validate_all(&views, &self.camera)?;
                self.views = views;
                // The page that asked is told the list too.
                let _ = events.send(Event {
                    to: Recipients::One(client),
                    text: Arc::new(self.greeting("state")),
                });
            }
            Change::Lights(lights, directions, environment) => {
                self.edit_all(Edit::Lights(lights))?;
                self.lights = LightSettings {
                    lights: directions,
                    environment,
                };
                self.set_camera()?;
            }
            Change::Clip(clipping) => {
                self.edit_all(Edit::Clipping(clipping))?;
                self.set_camera()?;
            }
            Change::Method(method) => {
                self.session
                    .edit(Edit::Cache(method.cache_choice(self.denoise_on)))
                    .map_err(|e| e.to_string())?;
                self.method = method;
                self.set_camera()?;
                if let Some(split) = self.split.as_mut() {
                    split.clear_image();
                }
                self.seconds = [0.0; 2];
            }
            Change::Train(on) => {
                self.session
                    .cache_mut()
                    .set_training(on)
                    .map_err(|e| e.to_string())?;
            }
            Change::Channel { channel, visible } => {
                let shown = &self.facts.channels[channel].transfer;
                let tf = if visible {
                    shown.clone()
                } else {
                    shown.with_density_scale(0.0).map_err(|e| e.to_string())?
                };
                self.edit_all(Edit::ChannelTransferFunction(channel, tf))?;
                self.channels_visible[channel] = visible;
                self.set_camera()?;
            }
            Change::Time(time) => {
                self.show_time(time)?;
                self.time = time;
                self.set_camera()?;
            }
            Change::ShowLights(on) => {
                let mut path = self.session.scene().settings.path;
                path.show_lights = on;
                self.edit_all(Edit::Path(path))?;
                self.set_camera()?;
            }
            Change::ResetCache => {
                self.session
                    .edit(Edit::Cache(self.method.cache_choice(self.denoise_on)))
                    .map_err(|e| e.to_string())?;
                self.set_camera()?;
            }
            Change::Levels => {
                let images = self
                    .session
                    .level_images()
                    .ok_or("level images: the method has no Gaussian cache")?
                    .map_err(|e| e.to_string())?;
                let output = self.session.scene().output;
                let urls: Vec<String> = images
                    .iter()
                    .map(|img| {
                        format!(
                            "data:image/jpeg;base64,{}",
                            BASE64.encode(encode(img, &output))
                        )
                    })
                    .collect();
                let _ = events.send(Event {
                    to: Recipients::One(client),
                    text: Arc::new(
                        serde_json::json!({"type": "levels", "images": urls}).to_string(),
                    ),
                });
            }
            Change::Split(on) => {
                self.split = if on {
                    let mut plain = Session::new(
                        self.session.scene().clone(),
                        render_session::CacheChoice::None,
                    )
                    .map_err(|e| e.to_string())?;
                    plain
                        .edit(Edit::Camera(self.camera))
                        .map_err(|e| e.to_string())?;
                    Some(plain)
                } else {
                    None
                };
                self.session.clear_image();
                self.seconds = [0.0; 2];
                self.set_camera()?;
            }
            Change::Viewport { width, height } => {
                self.viewport = Some((width, height));
                self.resize()?;
            }
            Change::Scale(scale) => {
                self.resolution.scale = scale;
                self.resize()?;
            }
            Change::Denoise(on) => {
                if on && self.filter.is_none() {
                    let denoiser = self
                        .denoiser
                        .take()
                        .map_err(|why| format!("denoising is not available: {why}"))?;
                    let thread = FilterThread::start(denoiser, Arc::clone(&self.publisher))
                        .map_err(|e| format!("denoising: cannot start its thread: {e}"))?;
                    self.filter = Some(thread);
                }
                self.denoise_on = on;
                // A cache whose image is denoised reads its levels only where they have earned
                // trust, and the plain cache's reading comes back without the filter: the same
                // levels, trained on, with the other termination.
                let wanted = self.method.cache_choice(on);
                if let render_session::CacheChoice::Gaussian { config, .. } = &wanted {
                    self.session
                        .cache_mut()
                        .set_error_aware_termination(config)
                        .map_err(|e| e.to_string())?;
                }
                // The image keeps its samples (the filter needs no guides the image lacks), and
                // the change shows at once, even on a converged view: the image filtered, or
                // the raw image again.
                self.still_posted = 0;
                if self.session.frames_in_image() > 0 && !self.moving {
                    self.sequence += 1;
                    if on {
                        self.filter_still_if_due(events);
                    } else {
                        let frame = self.raw_frame();
                        self.publisher.publish(self.sequence, frame);
                    }
                }
            }
            Change::Save => {
                let image = self.session.image();
                let saved = save(SaveRequest {
                    dir: &self.output,
                    image: &image,
                    scene: self.session.scene(),
                    scene_text: &self.scene_text,
                    scene_file: &self.scene_file,
                    facts: &self.facts,
                    transfer: &self.transfer,
                    lights: &self.lights,
                    spp: self.target_spp,
                    session: &self.session,
                    views: &self.views,
                    time: self.time,
                })?;
                let files: Vec<String> = saved
                    .files
                    .iter()
                    .map(|f| f.display().to_string())
                    .collect();
                let _ = events.send(Event {
                    to: Recipients::One(client),
                    text: Arc::new(
                        serde_json::json!({"type": "saved", "files": files}).to_string(),
                    ),
                });
            }
        }
        Ok(())
    }

    /// Puts the camera into the session (and the split view's): smaller while moving and for
    /// the first frame after an edit, with any method. The image starts again: a new view.
    fn set_camera(&mut self) -> Result<(), String> {
        let small = self.moving || self.preview;
        let camera = if small {
            let filtered = self.filter.as_ref().filter(|_| self.denoise_on);
            let filter_cost = filtered.map_or(0.0, |f| f.status().preview_seconds_per_pixel);
            let (w, h) =
                self.governor
                    .preview_size(self.camera.width, self.camera.height, filter_cost);
            self.camera.with_size(w, h).map_err(|e| e.to_string())?
        } else {
            self.camera
        };
        if let Some(split) = self.split.as_mut() {
            split
                .edit(Edit::Camera(camera))
                .map_err(|e| e.to_string())?;
        }
        self.session
            .edit(Edit::Camera(camera))
            .map_err(|e| e.to_string())?;
        self.seconds = [0.0; 2];
        self.fresh = true;
        self.view += 1;
        self.still_posted = 0;
        if let Some(filter) = &self.filter {
            filter.view_changed(self.view);
        }
        Ok(())
    }

    /// The view's render size follows the page's view area and the resolution scale.
    fn resize(&mut self) -> Result<(), String> {
        let (width, height) = match self.viewport {
            Some((w, h)) => self.resolution.fit(w, h),
            None => (self.camera.width, self.camera.height),
        };
        if (width, height) != (self.camera.width, self.camera.height) {
            self.camera = self
                .camera
                .with_size(width, height)
                .map_err(|e| e.to_string())?;
        }
        self.set_camera()
    }

    /// Shows the frame just rendered (`small`: a preview): raw, or with denoising on through
    /// the filter thread (a preview always; the still image when [`Worker::filter_still_if_due`]
    /// says so).
    fn show(&mut self, small: bool, events: &broadcast::Sender<Event>) {
        if self.session.frames_in_image() == 0 {
            return;
        }
        let now = Instant::now();
        if let Some(last) = self.last_frame {
            let rate = 1.0 / now.duration_since(last).as_secs_f64().max(1e-6);
            self.fps = if self.fps == 0.0 {
                rate
            } else {
                0.8 * self.fps + 0.2 * rate
            };
        }
        self.last_frame = Some(now);
        let raw_from = self.denoising.until_spp;
        let spp = self.session.frames_in_image();
        if self.denoising(events) && (small || raw_from == 0 || spp < raw_from) {
            if small {
                self.submit(JobKind::Preview);
            } else {
                self.filter_still_if_due(events);
            }
        } else {
            let frame = self.raw_frame();
            self.publisher.publish(self.sequence, frame);
        }
    }

    /// Whether frames go through the filter thread; a filter that failed turns denoising off,
    /// and the pages are told why.
    fn denoising(&mut self, events: &broadcast::Sender<Event>) -> bool {
        let Some(filter) = self.filter.as_ref().filter(|_| self.denoise_on) else {
            return false;
        };
        if let Some(why) = filter.status().failed {
            self.denoise_on = false;
            self.filter = None;
            let _ = events.send(Event {
                to: Recipients::All,
                text: Arc::new(error_json(&format!("denoising turned off: {why}"))),
            });
            return false;
        }
        true
    }

    /// Hands the still image to the filter if it is due (at 1, 2, 4, 8, ... samples a pixel
    /// and at the last) and the filter is free; true if an image is owed that the busy filter
    /// could not take (asked again shortly).
    fn filter_still_if_due(&mut self, events: &broadcast::Sender<Event>) -> bool {
        if self.moving || self.preview || self.watching == 0 || !self.denoising(events) {
            return false;
        }
        let spp = self.session.frames_in_image();
        let raw_from = self.denoising.until_spp;
        if (raw_from > 0 && spp >= raw_from) || !still_due(spp, self.still_posted, self.target_spp)
        {
            return false;
        }
        let busy = self.filter.as_ref().is_some_and(|f| f.status().busy);
        if busy {
            return true;
        }
        self.still_posted = spp;
        self.submit(JobKind::Still { spp });
        false
    }

    /// Hands the image shown to the filter thread.
    fn submit(&mut self, kind: JobKind) {
        let Some(filter) = &self.filter else { return };
        let image = self.shown_image();
        let stats = self.stats(image.width(), image.height(), 0.0, 0.0);
        filter.submit(FilterJob {
            sequence: self.sequence,
            view: self.view,
            kind,
            image,
            output: self.session.scene().output,
            stats,
        });
    }

    /// The image as rendered: the session's, beside the split view's other half.
    fn shown_image(&self) -> RgbImage {
        let image = self.session.image();
        match &self.split {
            Some(split) => side_by_side(&split.image(), &image),
            None => image,
        }
    }

    /// The image as rendered, tone-mapped and encoded, with its statistics.
    fn raw_frame(&self) -> Frame {
        let start = Instant::now();
        let image = self.shown_image();
        let jpeg = encode(&image, &self.session.scene().output);
        let encode_ms = start.elapsed().as_secs_f64() * 1e3;
        let stats = self
            .stats(image.width(), image.height(), 0.0, encode_ms)
            .to_string();
        Frame { jpeg, stats }
    }

    /// The last frame's statistics, for an image of `width x height` (`denoise_ms`: the
    /// filter's time on it, `encode_ms`: gathering and encoding it).
    fn stats(&self, width: u32, height: u32, denoise_ms: f64, encode_ms: f64) -> serde_json::Value {
        let report = &self.last_report;
        serde_json::json!({
            "type": "stats",
            "frame": report.frame,
            "sequence": self.sequence,
            "edits": self.edits,
            "spp": self.session.frames_in_image(),
            "target_spp": self.target_spp,
            "width": width,
            "height": height,
            "view_width": self.camera.width,
            "view_height": self.camera.height,
            "fps": self.fps,
            "trace_ms": report.trace_seconds * 1e3,
            "lookup_ms": report.lookup_seconds * 1e3,
            "train_ms": report.train_seconds * 1e3,
            "denoise_ms": denoise_ms,
            "encode_ms": encode_ms,
            "method": self.method.name(),
            // The camera the image was rendered from: a harness scores each shown frame
            // against a converged view of it.
            "eye": self.camera.position.to_array(),
            // The training loss per level (none on frames without a step): the page's
            // sparkline; and whether the cache trains.
            "loss": report.loss,
            "training": self.session.cache().training(),
            // Per level, the fraction of cache pixels whose residual was gross this frame (the
            // fallback's verdict: paths there go on as plain path tracing).
            "stale": (!report.stale_fraction.is_empty()).then_some(&report.stale_fraction),
            // Per level, the fraction of cache pixels paths may stop into (the fallback's and
            // error-aware termination's verdicts together; with the denoiser on, the trusted
            // cache's).
            "readable": self.session.cache().drawn_levels().map(|f| f.trusted_fractions()),
            "split": self.split.as_ref().map(|s| serde_json::json!({
                "left": "nee",
                "left_spp": s.frames_in_image(),
                "left_ms": self.seconds[0] * 1e3,
                "right_ms": self.seconds[1] * 1e3,
            })),
            "moving": self.moving,
            // Set by the filter thread on the images it denoised (with the samples per pixel
            // of a still image).
            "denoised": false,
            "denoised_spp": null,
        })
    }
}

/// Whether a still image of `spp` samples a pixel (refining to `target`) is due to be filtered
/// when the last one handed over had `posted` (0: none): at 1, 2, 4, 8, ... and at the last.
/// Doubling the samples between runs keeps the filter's share of the cores bounded (a run at
/// 1280x720 costs what two or three passes do on 2 cores), and a run missed while the filter
/// was busy is made at the next pass.
pub fn still_due(spp: u32, posted: u32, target: u32) -> bool {
    spp > posted && (spp >= posted.saturating_mul(2) || spp >= target)
}

/// Picks the size a moving view renders at: the largest whose frame, at the seconds a pixel
/// has cost in the last preview frames, fits [`PreviewGovernor::FRAME_SECONDS`]. So a drag
/// holds its rate whatever the method (a cached frame costs lookup and training besides the
/// tracing), the scene or the machine, and a still view's first frame after an edit comes as
/// fast.
#[derive(Debug, Clone)]
pub struct PreviewGovernor {
    /// Seconds a preview pixel took, smoothed over the last frames.
    seconds_per_pixel: f64,
    /// The factor in force.
    factor: Option<f64>,
}

impl Default for PreviewGovernor {
    fn default() -> Self {
        // Until a frame is measured: about 25 ms for 120 000 pixels, plain path tracing at one
        // sample on 2 cores (the fixed preview of issue 47).
        Self {
            seconds_per_pixel: 0.025 / 120_000.0,
            factor: None,
        }
    }
}

impl PreviewGovernor {
    /// A preview frame's time (rendering, and with denoising on filtering and encoding): 20
    /// frames a second leave about 5 ms of each frame's 50 ms for the socket and the page.
    pub const FRAME_SECONDS: f64 = 0.045;
    /// The preview's height is not made smaller than this (or than half the view's): when the
    /// page or the machine is busy, frames come less often rather than smaller than a
    /// readable preview (128x72 was seen under load before the floor). 120 rows: a 2-core
    /// Intel Xeon renders, filters and encodes a 190x120 preview in about 40 ms beside the
    /// browser.
    pub const MIN_HEIGHT: u32 = 120;
    /// The preview's factor moves in quarter steps.
    pub const STEP: f64 = 0.25;

    /// Adds a preview frame of `pixels` that took `seconds` to the estimate (a moving mean
    /// that follows a change of method or scene within a few frames). Ignores what cannot be
    /// a measurement (zero, NaN).
    pub fn observe(&mut self, seconds: f64, pixels: f64) {
        let per_pixel = seconds / pixels;
        if per_pixel > 0.0 && per_pixel.is_finite() {
            self.seconds_per_pixel = 0.7 * self.seconds_per_pixel + 0.3 * per_pixel;
        }
    }

    /// The factor a `width x height` view's sides are shrunk by while it moves, where
    /// filtering and encoding a preview pixel costs `filter_seconds_per_pixel` besides
    /// rendering it: at least 2 (a drag is never at full size: its frames come and go), no more
    /// than keeps the preview [`PreviewGovernor::MIN_HEIGHT`] tall, in steps of
    /// [`PreviewGovernor::STEP`]. The factor in force is kept while the one that fits is
    /// within a step of it, so a preview's size does not flicker with the measurements (each
    /// new size also builds a filter).
    pub fn divisor(&mut self, width: u32, height: u32, filter_seconds_per_pixel: f64) -> f64 {
        let per_pixel = self.seconds_per_pixel + filter_seconds_per_pixel.max(0.0);
        let frame = f64::from(width) * f64::from(height) * per_pixel;
        let most = (f64::from(height) / f64::from(Self::MIN_HEIGHT)).max(2.0);
        let fit = (frame / Self::FRAME_SECONDS).sqrt();
        let fit = if fit.is_nan() {
            most
        } else {
            fit.clamp(2.0, most)
        };
        let stepped = ((fit / Self::STEP).ceil() * Self::STEP).min(most);
        let kept = self
            .factor
            .filter(|&d| (d - fit).abs() < Self::STEP && d <= most);
        let d = kept.unwrap_or(stepped);
        self.factor = Some(d);
        d
    }

    /// The preview's size for a `width x height` view ([`PreviewGovernor::divisor`]).
    pub fn preview_size(
        &mut self,
        width: u32,
        height: u32,
        filter_seconds_per_pixel: f64,
    ) -> (u32, u32) {
        let d = self.divisor(width, height, filter_seconds_per_pixel);
        let side = |n: u32| ((f64::from(n) / d).round() as u32).max(1);
        (side(width), side(height))
    }
}

/// The left half of `left` beside the right half of `right` (images of one size), with a dark
/// line between them.
pub fn side_by_side(left: &RgbImage, right: &RgbImage) -> RgbImage {
    let (w, h) = (right.width(), right.height());
    if (left.width(), left.height()) != (w, h) {
        return right.clone();
    }
    let mut out = right.clone();
    let half = w / 2;
    let pixels = out.pixels_mut();
    for y in 0..h {
        for x in 0..half {
            let i = (y * w + x) as usize;
            pixels[i] = left.pixels()[i];
        }
        pixels[(y * w + half) as usize] = glam::Vec3::ZERO;
    }
    out
}

/// An error as the page's JSON message.
pub fn error_json(message: &str) -> String {
    serde_json::json!({"type": "error", "message": message}).to_string()
}

/// Tone-maps `image` as the scene's output says and encodes it as JPEG (quality 90).
pub fn encode(image: &RgbImage, output: &volume_pt::scene::OutputDesc) -> Vec<u8> {
    let rgb = hdr_image::tone_map(image.pixels(), output.exposure, output.tonemap);
    let mut out = Vec::new();
    let encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90);
    // The buffer is exactly width x height x 3 by construction; an encoder error would be a bug.
    image::ImageEncoder::write_image(
        encoder,
        &rgb,
        image.width(),
        image.height(),
        image::ExtendedColorType::Rgb8,
    )
    .expect("an RGB8 buffer of the image's size encodes");
    out
}

#[cfg(test)]
mod tests {
    use super::{PreviewGovernor, Resolution, still_due};

    #[test]
    fn a_still_view_is_filtered_at_doublings_from_one_sample_and_at_the_last() {
        // Each image handed over as soon as it is due.
        let mut posted = 0;
        let mut due = Vec::new();
        for spp in 1..=40 {
            if still_due(spp, posted, 40) {
                due.push(spp);
                posted = spp;
            }
        }
        assert_eq!(due, [1, 2, 4, 8, 16, 32, 40]);
        // A filter busy at 4 samples takes the image at 5, and then doubles from there.
        assert!(!still_due(4, 4, 40));
        assert!(still_due(5, 2, 40));
        assert!(!still_due(9, 5, 40));
        assert!(still_due(10, 5, 40));
        // The last is due whatever the doubling, once.
        assert!(still_due(40, 32, 40));
        assert!(!still_due(40, 40, 40));
    }

    #[test]
    fn the_view_renders_at_the_scaled_view_area_within_the_cap() {
        let r = Resolution {
            scale: 0.75,
            max_size: (1920, 1080),
        };
        assert_eq!(r.fit(1280, 720), (960, 540));
        // A 4K area at scale 1 fits the cap, its aspect kept; so does a tall one.
        let full = Resolution { scale: 1.0, ..r };
        assert_eq!(full.fit(3840, 2160), (1920, 1080));
        assert_eq!(full.fit(1000, 2000), (540, 1080));
        // Never below 16 pixels a side.
        assert_eq!(full.fit(4, 4), (16, 16));
    }

    #[test]
    fn the_governor_sizes_the_preview_from_what_frames_cost() {
        let fresh = PreviewGovernor::default;
        // Unmeasured: the fixed preview of before (25 ms for 120 000 pixels): 1280x720 is
        // 7.7x that many pixels, so the sides shrink by sqrt(0.192 / 0.045) = 2.07, stepped up
        // to 2.25: 569x320.
        assert_eq!(fresh().preview_size(1280, 720, 0.0), (569, 320));
        // Filtering that costs what rendering does doubles a pixel's cost: sqrt(2) times more,
        // 2.92, stepped to 3.
        assert_eq!(fresh().divisor(1280, 720, 0.025 / 120_000.0), 3.0);
        // Frames that cost a microsecond a pixel (a cache on a slow machine): 1280x720 would
        // take 0.92 s, a factor of 4.52, stepped to 4.75, once the moving mean has followed;
        // the floor of 120 rows stops a view of 432 rows at 3.6 when pixels cost ten times
        // that.
        let mut g = fresh();
        for _ in 0..40 {
            g.observe(1e-6 * 10_000.0, 10_000.0);
        }
        assert!((g.seconds_per_pixel - 1e-6).abs() < 1e-9);
        assert_eq!(g.divisor(1280, 720, 0.0), 4.75);
        assert_eq!(fresh_like(&g).divisor(768, 432, 1e-5), 3.6);
        // The factor in force is kept while the one that fits is within a step: a 5%
        // costlier pixel (a fit of 4.64) keeps 4.75 where a fresh governor would step to 4.75
        // too, 10% (4.74) keeps it, and twice the cost (6.4) moves it to the floor, 6.
        assert_eq!(g.divisor(1280, 720, 0.05e-6), 4.75);
        g.factor = Some(4.5);
        assert_eq!(g.divisor(1280, 720, 0.1e-6), 4.5);
        assert_eq!(g.divisor(1280, 720, 1e-6), 6.0);
        // Never below 2 while moving; nothing learnt from non-measurements; a NaN filter
        // cost counts as none.
        assert_eq!(fresh().divisor(64, 36, 0.0), 2.0);
        let before = fresh_like(&g).divisor(3840, 2160, 0.0);
        g.observe(f64::NAN, 100.0);
        g.observe(0.01, 0.0);
        assert_eq!(fresh_like(&g).divisor(3840, 2160, 0.0), before);
        assert_eq!(fresh().divisor(1280, 720, f64::NAN), 2.25);
    }

    /// `g`'s measurements without the factor in force.
    fn fresh_like(g: &PreviewGovernor) -> PreviewGovernor {
        PreviewGovernor {
            factor: None,
            ..g.clone()
        }
    }
}
