//! [`Session`]: a scene, a camera, a cache and an accumulating image; the one frame loop.

use crate::cache::{Cache, CacheChoice};
use crate::camera_path::orbit;
use crate::edit::{CacheEffect, Edit, Invalidated};
use crate::error::{Result, SessionError};
use crate::report::FrameReport;
use crate::sampling::{check_frames, frame_samples};
use glam::Vec3;
use hdr_image::RgbImage;
use render_base::Camera;
use render_base::Control;
use std::path::Path;
use std::time::Instant;
use volume_pt::{Film, Scene};

/// How frames make the session's image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Accumulation {
    /// Frames are averaged into one image until an edit empties it: a progressive render of a
    /// still view. The Gaussian cache counts them towards its handoff to plain path tracing.
    #[default]
    Progressive,
    /// Each frame is an image of its own (a fly-through, an interactive view in motion); the
    /// Gaussian cache never hands off.
    PerFrame,
}

/// How many passes (frames of the session's spp) make one image of [`Session::render_image`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ImageBudget {
    /// Exactly this many (at least one).
    Passes(u32),
    /// While the next pass, taken to cost the mean of the passes so far by the wall clock,
    /// fits in this many seconds; at least one. An interactive frame's budget.
    Seconds(f64),
}

/// What one image of [`Session::render_image`] took.
#[derive(Debug, Clone)]
pub struct ImageReport {
    /// Passes rendered into the image.
    pub passes: u32,
    /// The first pass's frame index (the sampling rule's `k`): with `passes`, which samples the
    /// image holds.
    pub first_frame: u32,
    /// The passes' reports summed ([`FrameReport::absorb`]).
    pub report: FrameReport,
}

/// One render session: see the crate docs.
#[derive(Debug)]
pub struct Session {
    scene: Scene,
    choice: CacheChoice,
    cache: Cache,
    cache_seconds: f64,
    film: Film,
    /// The next frame's index: the sampling rule's `k`. It never goes back, so no two frames of
    /// a session (warm-up included) draw the same samples.
    next_frame: u32,
    /// Frames in the image.
    image_frames: u32,
    accumulation: Accumulation,
    /// Whether the image keeps feature buffers (albedo, normal, depth, coverage).
    features: bool,
}

impl Session {
    /// A session on `scene` (its camera, settings and seed) with the cache `choice` built for it.
    pub fn new(scene: Scene, choice: CacheChoice) -> Result<Self> {
        if scene.settings.spp == 0 {
            return Err(SessionError::Invalid(
                "spp 0: expected at least 1 sample per pixel".into(),
            ));
        }
        let (cache, cache_seconds) = Cache::build(&scene, &choice)?;
        Ok(Self {
            film: Film::new(scene.camera.width, scene.camera.height),
            scene,
            choice,
            cache,
            cache_seconds,
            next_frame: 0,
            image_frames: 0,
            accumulation: Accumulation::Progressive,
            features: false,
        })
    }

    /// The same session keeping feature buffers beside the image, or not (see
    /// [`Session::feature_images`]). Empties the image.
    pub fn with_features(mut self, features: bool) -> Self {
        self.features = features;
        self.clear_image();
        self
    }

    /// [`Session::with_features`] on a session in place (a viewer turning denoising on).
    pub fn set_features(&mut self, features: bool) {
        if self.features != features {
            self.features = features;
            self.clear_image();
        }
    }

    /// The image's feature buffers (albedo, normal, depth, coverage over the same samples as
    /// the image); `None` unless the session keeps them ([`Session::with_features`]).
    pub fn feature_images(&self) -> Option<hdr_image::FeatureImages> {
        self.film.feature_images()
    }

    /// The same session with frames accumulated as `accumulation` says.
    pub fn with_accumulation(mut self, accumulation: Accumulation) -> Self {
        self.accumulation = accumulation;
        self
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    pub fn camera(&self) -> &Camera {
        &self.scene.camera
    }
    pub fn cache(&self) -> &Cache {
        &self.cache
    }
    /// The cache, to change what does not invalidate the image (the Gaussian cache's
    /// training on or off); an edit that does goes through [`Session::edit`].
    pub fn cache_mut(&mut self) -> &mut Cache {
        &mut self.cache
    }
    /// The cache choice the session was built with (or last edited to).
    pub fn cache_choice(&self) -> &CacheChoice {
        &self.choice
    }
    /// Seconds building (or loading) the cache took.
    pub fn cache_seconds(&self) -> f64 {
        self.cache_seconds
    }
    /// The accumulated film (exact sums: see volume-pt's film).
    pub fn film(&self) -> &Film {
        &self.film
    }
    /// The image: the mean of the frames accumulated since the last edit.
    pub fn image(&self) -> RgbImage {
        self.film.image()
    }
    /// The image's pixels.
    pub fn mean(&self) -> Vec<Vec3> {
        self.film.mean()
    }
    /// Frames rendered so far, warm-up included: the next frame's index.
    pub fn frames_rendered(&self) -> u32 {
        self.next_frame
    }
    /// Frames in the image (the last one possibly cut short by cancellation).
    pub fn frames_in_image(&self) -> u32 {
        self.image_frames
    }

    /// Empties the image; the next frame starts a new one. The cache is kept.
    pub fn clear_image(&mut self) {
        let (w, h) = (self.scene.camera.width, self.scene.camera.height);
        self.film = if self.features {
            Film::with_features(w, h)
        } else {
            Film::new(w, h)
        };
        self.image_frames = 0;
    }

    /// Renders the next frame at the session's camera into the image, reading and training the
    /// cache; progress goes to `control` in samples.
    pub fn next_frame(&mut self, control: &Control) -> Result<FrameReport> {
        let k = self.next_frame;
        let samples = frame_samples(k, self.scene.settings.spp)?;
        if self.accumulation == Accumulation::PerFrame {
            self.clear_image();
        } else if self.image_frames == 0 {
            self.cache.start_image();
        }
        let start = Instant::now();
        let before = self.film.total_samples();
        let camera = self.scene.camera;
        let report = self.cache.frame(
            &self.scene.media,
            &camera,
            &self.scene.settings,
            k,
            samples,
            Some(&mut self.film),
            control,
        )?;
        self.scene.media.medium.grid().check_streaming()?;
        self.next_frame = k + 1;
        // A frame cancelled part way still counts if it reached the image: every pixel keeps
        // the mean of the samples it finished.
        if self.film.total_samples() > before {
            self.image_frames += 1;
        }
        Ok(FrameReport {
            seconds: start.elapsed().as_secs_f64(),
            ..report
        })
    }

    /// Renders one image of its own: empties the image, then renders passes into it as `budget`
    /// says, each a frame of [`Session::next_frame`] (reading and training the cache). A
    /// fly-through's or movie's frame: with [`Accumulation::Progressive`] the passes average
    /// (and the Gaussian cache's handoff counts them, as in a still); with
    /// [`Accumulation::PerFrame`] each pass would replace the last, so only one is allowed.
    /// A cancelled pass ends the image.
    pub fn render_image(&mut self, budget: ImageBudget, control: &Control) -> Result<ImageReport> {
        let most = match budget {
            ImageBudget::Passes(0) => {
                return Err(SessionError::Invalid(
                    "an image of 0 passes: expected at least 1".into(),
                ));
            }
            ImageBudget::Passes(n) => n,
            ImageBudget::Seconds(t) if !(t >= 0.0 && t.is_finite()) => {
                return Err(SessionError::Invalid(format!(
                    "an image budget of {t} seconds: expected a finite time >= 0"
                )));
            }
            ImageBudget::Seconds(_) => u32::MAX,
        };
        if self.accumulation == Accumulation::PerFrame && most > 1 {
            return Err(SessionError::Invalid(
                "an image of several passes in a session that makes each frame an image of its \
                 own (Accumulation::PerFrame): use Accumulation::Progressive"
                    .into(),
            ));
        }
        self.clear_image();
        let first_frame = self.next_frame;
        let start = Instant::now();
        let mut report = self.next_frame(control)?;
        let mut passes = 1;
        while passes < most && !report.cancelled && !control.cancelled() {
            if let ImageBudget::Seconds(t) = budget {
                let spent = start.elapsed().as_secs_f64();
                if spent + spent / f64::from(passes) > t {
                    break;
                }
            }
            report.absorb(self.next_frame(control)?);
            passes += 1;
        }
        Ok(ImageReport {
            passes,
            first_frame,
            report,
        })
    }

    /// Moves the sampling rule's frame index on by `frames` without rendering them, so the
    /// next frame takes the samples it would take after them: a resumed movie's earlier frames
    /// without a cache, or a movie's part that starts where another process's ends. A cache
    /// learns nothing from frames skipped (a resume with a cache renders them again). Checked:
    /// the index cannot wrap.
    pub fn skip_frames(&mut self, frames: u32) -> Result<()> {
        check_frames(self.next_frame, frames, self.scene.settings.spp)?;
        self.next_frame = self.next_frame.checked_add(frames).ok_or_else(|| {
            SessionError::Invalid(format!(
                "{frames} frames after frame {} reach frame 2^32: use fewer frames",
                self.next_frame
            ))
        })?;
        Ok(())
    }

    /// Renders `frames` frames that train the cache without entering the image, the camera
    /// orbiting `orbit_degrees` about the volume's centre and arriving at the session's camera
    /// (0 keeps it still). Without a cache there is nothing to warm and nothing is rendered.
    /// Checked before any work: the frames must fit the sample indices.
    pub fn warm_up(
        &mut self,
        frames: u32,
        orbit_degrees: f32,
        control: &Control,
    ) -> Result<Vec<FrameReport>> {
        if self.cache.is_none() || frames == 0 {
            return Ok(Vec::new());
        }
        if !orbit_degrees.is_finite() {
            return Err(SessionError::Invalid(format!(
                "warm-up orbit {orbit_degrees} degrees: expected a finite angle"
            )));
        }
        check_frames(self.next_frame, frames, self.scene.settings.spp)?;
        let (lo, hi) = self.scene.media.medium.bounds();
        let centre = 0.5 * (lo + hi);
        let mut reports = Vec::with_capacity(frames as usize);
        for f in 0..frames {
            if control.cancelled() {
                break;
            }
            let camera = if orbit_degrees == 0.0 {
                self.scene.camera
            } else {
                orbit(&self.scene.camera, centre, orbit_degrees, f, frames + 1)
            };
            let k = self.next_frame;
            let samples = frame_samples(k, self.scene.settings.spp)?;
            let start = Instant::now();
            let report = self.cache.frame(
                &self.scene.media,
                &camera,
                &self.scene.settings,
                k,
                samples,
                None,
                control,
            )?;
            self.next_frame = k + 1;
            reports.push(FrameReport {
                seconds: start.elapsed().as_secs_f64(),
                ..report
            });
        }
        Ok(reports)
    }

    /// Checks before any work that `frames` more frames fit the sample indices (a frame count
    /// from a user could otherwise wrap).
    pub fn check_frames(&self, frames: u32) -> Result<()> {
        check_frames(self.next_frame, frames, self.scene.settings.spp)
    }

    /// Applies `edit`; says what it invalidated (see [`crate::edit`]).
    pub fn edit(&mut self, edit: Edit) -> Result<Invalidated> {
        let mut cache = CacheEffect::Kept;
        match edit {
            Edit::Camera(camera) => {
                if camera == self.scene.camera {
                    return Ok(Invalidated {
                        image: false,
                        cache,
                    });
                }
                // A new size keeps the cache: the Gaussians and the neural cache's grid live
                // in the volume's space, and the Gaussian cache draws its levels, fits its
                // per-pixel state and bins its targets at each frame's size. So a view can
                // preview small while it moves and refine at full size with one cache that
                // keeps learning (issue 52).
                self.scene.camera = camera;
            }
            Edit::TransferFunction(tf) => {
                self.scene.media.medium.set_transfer_function(tf);
                cache = self.cache.scene_changed();
            }
            Edit::ChannelTransferFunction(k, tf) => {
                self.scene
                    .media
                    .medium
                    .set_channel_transfer_function(k, tf)
                    .map_err(|e| SessionError::Invalid(e.to_string()))?;
                cache = self.cache.scene_changed();
            }
            Edit::Lights(mut lights) => {
                // Checked as a scene file's lights are (and distant directions normalised).
                for (i, light) in lights.lights.iter_mut().enumerate() {
                    light
                        .validate()
                        .map_err(|e| SessionError::Invalid(format!("light {i}: {e}")))?;
                }
                if !lights.environment.is_finite() || lights.environment.min_element() < 0.0 {
                    return Err(SessionError::Invalid(format!(
                        "environment radiance {}: expected finite values >= 0",
                        lights.environment
                    )));
                }
                self.scene.media.lights = lights;
                cache = self.cache.scene_changed();
            }
            Edit::Clipping(clipping) => {
                self.scene
                    .media
                    .medium
                    .set_clipping(clipping)
                    .map_err(|e| SessionError::Invalid(e.to_string()))?;
                cache = self.cache.scene_changed();
            }
            Edit::Environment(radiance) => {
                if !radiance.is_finite() || radiance.min_element() < 0.0 {
                    return Err(SessionError::Invalid(format!(
                        "environment radiance {radiance}: expected finite values >= 0"
                    )));
                }
                self.scene.media.lights.environment = radiance;
                cache = self.cache.scene_changed();
            }
            Edit::Volume { media, path } => {
                self.scene.media = *media;
                self.scene.volume_path = path;
                cache = self.cache.scene_changed();
            }
            Edit::Spp(spp) => {
                if spp == 0 {
                    return Err(SessionError::Invalid(
                        "spp 0: expected at least 1 sample per pixel".into(),
                    ));
                }
                self.scene.settings.spp = spp;
            }
            Edit::Path(path) => self.scene.settings.path = path,
            Edit::Cache(choice) => {
                self.choice = choice;
                self.rebuild_cache()?;
                cache = CacheEffect::Rebuilt;
            }
        }
        self.clear_image();
        Ok(Invalidated { image: true, cache })
    }

    fn rebuild_cache(&mut self) -> Result<()> {
        let (cache, seconds) = Cache::build(&self.scene, &self.choice)?;
        self.cache = cache;
        self.cache_seconds = seconds;
        Ok(())
    }

    /// Each Gaussian cache level drawn from the session's camera (level 0 holds paths of
    /// length 1); `None` for another cache.
    pub fn level_images(&mut self) -> Option<Result<Vec<RgbImage>>> {
        let camera = self.scene.camera;
        let cache = self.cache.gaussian_mut()?;
        let frame = cache.begin_frame(&camera);
        Some(
            (0..frame.levels())
                .map(|l| {
                    Ok(RgbImage::from_rgb(
                        camera.width,
                        camera.height,
                        frame.image(l),
                    )?)
                })
                .collect(),
        )
    }

    /// Writes the Gaussian cache's levels as 3DGS PLY files into `dir`; returns how many.
    pub fn save_cache(&self, dir: &Path) -> Result<usize> {
        self.cache.save(dir)
    }
}
