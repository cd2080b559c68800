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
//! [`PreviewGovernor`] picks from the frames' measured time to hold a target rate; then it
//! refines at full size. The split view previews too, both halves at the same size.

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
    /// The still view's last denoised image and the samples per pixel it was made at: shown
    /// until the next (see [`denoise_now`]).
    denoised: Option<(u32, RgbImage)>,
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
            denoised: None,
            views,
            channels_visible,
            time,
        })
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
        frames: watch::Sender<Option<Arc<Frame>>>,
        events: broadcast::Sender<Event>,
    ) {
        loop {
            let mut pending = Vec::new();
            if self.converged() {
                match commands.recv_timeout(Duration::from_millis(250)) {
                    Ok(c) => pending.push(c),
                    Err(RecvTimeoutError::Timeout) => continue,
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
                        let text = self.greeting("hello");
                        let _ = events.send(Event {
                            to: Recipients::One(client),
                            text: Arc::new(text),
                        });
                        // A new client sees the current image at once. (The read guard
                        // must be gone before the write: they share one lock.)
                        let current = frames.borrow().clone();
                        if let Some(frame) = current {
                            frames.send_replace(Some(frame));
                        }
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
                    let size = self.session.camera();
                    if (size.width, size.height) != (self.camera.width, self.camera.height) {
                        // A preview frame: the governor learns what a pixel costs (twice with
                        // the split view, whose halves render at equal time between frames).
                        let pixels = f64::from(size.width) * f64::from(size.height);
                        let sides = if self.split.is_some() { 2.0 } else { 1.0 };
                        self.governor.observe(report.seconds * sides, pixels);
                    }
                    if let Some(frame) = self.publishable(&report) {
                        frames.send_replace(Some(Arc::new(frame)));
                    }
                    // The raw frame is on screen while the filter runs; then its result.
                    if self.denoise_due()
                        && let Some(frame) = self.denoise_still(&report)
                    {
                        frames.send_replace(Some(Arc::new(frame)));
                    }
                    if self.preview {
                        // The quick frame is out: refine at full size from here.
                        self.preview = false;
                        if let Err(e) = self.set_camera() {
                            let _ = events.send(Event {
                                to: Recipients::All,
                                text: Arc::new(error_json(&e)),
                            });
                        }
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
            Change::Save | Change::Denoise(_) | Change::Train(_) | Change::Levels
        ) {
            self.preview = true;
        }
        match change {
            Change::Camera { camera, moving } => {
                self.camera = camera;
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
                let scene = self.session.scene().clone();
                let urls: Vec<String> = images
                    .iter()
                    .map(|img| {
                        format!(
                            "data:image/jpeg;base64,{}",
                            BASE64.encode(encode(img, &scene))
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
            Change::Denoise(on) => {
                if on && let Err(why) = self.denoiser.get() {
                    return Err(format!("denoising is not available: {why}"));
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
                // The albedo guides the filter; the next frame shows the change, even on a
                // converged view.
                self.session.set_features(on);
                self.session.clear_image();
                self.denoised = None;
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
    /// the first frame after an edit, with any method.
    fn set_camera(&mut self) -> Result<(), String> {
        let small = self.moving || self.preview;
        let camera = if small {
            let d = self.governor.divisor(self.camera.width, self.camera.height);
            self.camera
                .with_size(
                    (self.camera.width / d).max(1),
                    (self.camera.height / d).max(1),
                )
                .map_err(|e| e.to_string())?
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
        Ok(())
    }

    /// Whether the still view's image is due to be denoised now: with denoising on, at 4, 8,
    /// 16, ... samples per pixel and at the last (issue 49: every frame was denoised, 1.1-1.8 s
    /// each at 1280x720, and the first ones, of a sample or two, came out smeared).
    fn denoise_due(&self) -> bool {
        let spp = self.session.frames_in_image();
        self.denoise_on
            && !self.moving
            && !self.preview
            && denoise_now(spp, self.target_spp)
            && self.denoised.as_ref().is_none_or(|(at, _)| *at != spp)
    }

    /// The still image denoised (guided by the albedo, except beside the split view's other
    /// half), kept to be shown until the next, and published; `None` if the filter failed
    /// (denoising is then turned off, and said).
    fn denoise_still(&mut self, report: &FrameReport) -> Option<Frame> {
        let d = self.denoiser.get().ok()?;
        let spp = self.session.frames_in_image();
        let mut image = self.session.image();
        // The joined halves of the split view have no one albedo: unguided there.
        let features = self
            .session
            .feature_images()
            .filter(|_| self.split.is_none());
        if let Some(split) = &self.split {
            image = side_by_side(&split.image(), &image);
        }
        let t = Instant::now();
        let guides = denoise::Guides::Albedo;
        match d.denoise_guided(
            &image,
            features.as_ref(),
            guides,
            denoise::Options::default(),
        ) {
            Ok(out) => {
                let ms = t.elapsed().as_secs_f64() * 1e3;
                self.denoised = Some((spp, out.clone()));
                Some(self.frame_of(&out, report, ms, 0.0))
            }
            Err(e) => {
                self.denoise_on = false;
                self.denoised = None;
                eprintln!("gscache view: denoising turned off: {e}");
                None
            }
        }
    }

    /// The session's image (or, with denoising on, the last denoised image of this view, until
    /// the next), tone-mapped and encoded, with the frame's statistics; `None` if the frame
    /// added nothing to the image (cancelled before a sample).
    fn publishable(&mut self, report: &FrameReport) -> Option<Frame> {
        if self.session.frames_in_image() == 0 {
            return None;
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
        let spp = self.session.frames_in_image();
        // The denoised image belongs to this view while the view's image has at least its
        // samples: an edit empties the image, and its frames then start again from one.
        if self.denoised.as_ref().is_some_and(|(at, _)| *at > spp) || self.moving {
            self.denoised = None;
        }
        let start = Instant::now();
        let image = match (&self.denoised, self.denoise_on) {
            (Some((_, d)), true) => d.clone(),
            _ => {
                let mut image = self.session.image();
                if let Some(split) = &self.split {
                    image = side_by_side(&split.image(), &image);
                }
                image
            }
        };
        let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
        Some(self.frame_of(&image, report, 0.0, prepare_ms))
    }

    /// `image` as the page gets it: tone-mapped JPEG and the frame's statistics (`denoise_ms`:
    /// the filter's time on this image, `prepare_ms`: gathering it).
    fn frame_of(
        &self,
        image: &RgbImage,
        report: &FrameReport,
        denoise_ms: f64,
        prepare_ms: f64,
    ) -> Frame {
        let start = Instant::now();
        let jpeg = encode(image, self.session.scene());
        let encode_ms = start.elapsed().as_secs_f64() * 1e3 + prepare_ms;
        let stats = serde_json::json!({
            "type": "stats",
            "frame": report.frame,
            "spp": self.session.frames_in_image(),
            "target_spp": self.target_spp,
            "width": image.width(),
            "height": image.height(),
            "fps": self.fps,
            "trace_ms": report.trace_seconds * 1e3,
            "lookup_ms": report.lookup_seconds * 1e3,
            "train_ms": report.train_seconds * 1e3,
            "denoise_ms": denoise_ms,
            "encode_ms": encode_ms,
            "method": self.method.name(),
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
            // The samples per pixel of the denoised image shown, if one is.
            "denoised": self.denoise_on && !self.moving && self.denoised.is_some(),
            "denoised_spp": self.denoised.as_ref().filter(|_| self.denoise_on).map(|(at, _)| at),
        })
        .to_string();
        Frame { jpeg, stats }
    }
}

/// Whether a still image of `spp` samples (of `target`) is one to denoise: at 4, 8, 16, ...
/// and at the last. Below 4 the filter smears more than it removes; doubling the samples
/// between runs keeps the filter's share of the time bounded (each run costs what a few frames
/// do at 1280x720).
pub fn denoise_now(spp: u32, target: u32) -> bool {
    spp >= 4.min(target) && (spp.is_power_of_two() || spp >= target)
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
}

impl Default for PreviewGovernor {
    fn default() -> Self {
        // Until a frame is measured: about 25 ms for 120 000 pixels, plain path tracing at one
        // sample on 2 cores (the fixed preview of issue 47).
        Self {
            seconds_per_pixel: 0.025 / 120_000.0,
        }
    }
}

impl PreviewGovernor {
    /// A preview frame's render time: 15 frames a second leave about a third of each frame's
    /// 67 ms for the JPEG, the socket and the page.
    pub const FRAME_SECONDS: f64 = 0.045;

    /// Adds a preview frame of `pixels` that took `seconds` to the estimate (a moving mean
    /// that follows a change of method or scene within a few frames). Ignores what cannot be
    /// a measurement (zero, NaN).
    pub fn observe(&mut self, seconds: f64, pixels: f64) {
        let per_pixel = seconds / pixels;
        if per_pixel > 0.0 && per_pixel.is_finite() {
            self.seconds_per_pixel = 0.7 * self.seconds_per_pixel + 0.3 * per_pixel;
        }
    }

    /// The factor a `width x height` view is shrunk by while it moves: at least 2 (a drag is
    /// never at full size: its frames come and go), at most 16.
    pub fn divisor(&self, width: u32, height: u32) -> u32 {
        let frame = f64::from(width) * f64::from(height) * self.seconds_per_pixel;
        let d = (frame / Self::FRAME_SECONDS).sqrt().ceil();
        (d as u32).clamp(2, 16)
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
pub fn encode(image: &RgbImage, scene: &Scene) -> Vec<u8> {
    let rgb = hdr_image::tone_map(image.pixels(), scene.output.exposure, scene.output.tonemap);
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
    use super::{PreviewGovernor, denoise_now};

    #[test]
    fn a_still_view_is_denoised_at_doublings_from_four_samples_and_at_the_last() {
        let due: Vec<u32> = (1..=40).filter(|&s| denoise_now(s, 40)).collect();
        assert_eq!(due, [4, 8, 16, 32, 40]);
        // A view refining to fewer than four samples is denoised at its last.
        assert_eq!(
            (1..=3).filter(|&s| denoise_now(s, 3)).collect::<Vec<_>>(),
            [3]
        );
        assert!(denoise_now(1, 1));
    }

    #[test]
    fn the_governor_sizes_the_preview_from_what_frames_cost() {
        let mut g = PreviewGovernor::default();
        // Unmeasured: the fixed preview of before (25 ms for 120 000 pixels): 1280x720 is
        // 7.7x that many pixels, so a third of the width (9 times fewer pixels) fits 45 ms.
        assert_eq!(g.divisor(1280, 720), 3);
        // Frames that cost a microsecond a pixel (a cache on a slow machine): 1280x720 would
        // take 0.92 s, so the side shrinks by ceil(sqrt(0.92 / 0.045)) = 5, once the moving
        // mean has followed.
        for _ in 0..40 {
            g.observe(1e-6 * 10_000.0, 10_000.0);
        }
        assert_eq!(g.divisor(1280, 720), 5);
        // Never below 2 while moving, never above 16; nothing learnt from non-measurements.
        assert_eq!(g.divisor(64, 36), 2);
        for _ in 0..40 {
            g.observe(1.0, 1.0);
        }
        assert_eq!(g.divisor(1280, 720), 16);
        let before = g.divisor(1280, 720);
        g.observe(f64::NAN, 100.0);
        g.observe(0.01, 0.0);
        assert_eq!(g.divisor(1280, 720), before);
    }
}
