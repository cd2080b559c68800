//! One cache type above volume-pt's seam: none, the Gaussian cache, or the neural cache.
//!
//! [`CacheChoice`] says what to build; [`Cache::build`] is the one place a cache is built for a
//! scene (points found with the scene's seed, too few of them refused, settings validated, a
//! loaded cache validated as a new one is). A new cache plugs in here: a variant of each enum,
//! its build, and its arm of `Cache::frame` (trace through the seam, read, train).

use crate::error::{Result, SessionError};
use crate::report::FrameReport;
#[cfg(feature = "nrc")]
use crate::sampling::neural_cache_seed;
use gs_cache::{CacheConfig, GsCache};
use render_base::Camera;
use render_base::Control;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volume_pt::{Film, RenderSettings, Scene, SceneMedia, render_samples, sample_cache_points};

#[cfg(feature = "nrc")]
use cached_pt::nrc::NrcSequence;
#[cfg(feature = "nrc")]
use nrc_cache::{NeuralCache, NrcConfig};

/// Which cache a session reads and trains, and its settings.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum CacheChoice {
    /// Plain path tracing.
    #[default]
    None,
    /// The GSCache radiance cache (Bauer et al., 2025), initialised from the volume, or loaded
    /// from levels saved by [`crate::Session::save_cache`] when `load` names their folder.
    Gaussian {
        config: CacheConfig,
        load: Option<PathBuf>,
    },
    /// The neural radiance cache (Müller et al., 2021), the GSCache paper's baseline.
    #[cfg(feature = "nrc")]
    Neural(NrcConfig),
}

impl CacheChoice {
    /// The Gaussian cache with `config`, initialised from the volume.
    pub fn gaussian(config: CacheConfig) -> Self {
        CacheChoice::Gaussian { config, load: None }
    }

    pub fn is_none(&self) -> bool {
        matches!(self, CacheChoice::None)
    }
}

/// A built cache.
#[derive(Debug, Default)]
pub enum Cache {
    #[default]
    None,
    Gaussian(Box<GsCache>),
    /// The neural cache, with the last frame's training step possibly still to take (it runs
    /// beside the next frame's path tracing).
    #[cfg(feature = "nrc")]
    Neural(Box<NrcSequence>),
}

impl Cache {
    /// Builds `choice` for `scene` (whose camera sets the Gaussian cache's resolution and whose
    /// seed finds its points or seeds the network). Returns the cache and the seconds it took.
    pub fn build(scene: &Scene, choice: &CacheChoice) -> Result<(Self, f64)> {
        let start = Instant::now();
        let cache = match choice {
            CacheChoice::None => Cache::None,
            CacheChoice::Gaussian { config, load } => {
                let config = config.for_image(scene.camera.width, scene.camera.height);
                config.validate()?;
                let cache = match load {
                    Some(dir) => GsCache::load(dir, config)?,
                    None => {
                        let (points, albedo) = sample_cache_points(
                            &scene.media.medium,
                            config.points,
                            scene.settings.seed,
                        );
                        if points.len() < config.points {
                            return Err(SessionError::Invalid(format!(
                                "{}: only {} of {} cache points found: the transfer function \
                                 leaves the volume almost empty",
                                scene.volume_path.display(),
                                points.len(),
                                config.points
                            )));
                        }
                        GsCache::new(&points, &albedo, config)?
                    }
                };
                Cache::Gaussian(Box::new(cache))
            }
            #[cfg(feature = "nrc")]
            CacheChoice::Neural(config) => {
                let config = NrcConfig {
                    seed: neural_cache_seed(config.seed, scene.settings.seed),
                    ..*config
                };
                let cache =
                    NeuralCache::new(config).map_err(|e| SessionError::Neural(e.to_string()))?;
                Cache::Neural(Box::new(NrcSequence::new(cache)))
            }
        };
        Ok((cache, start.elapsed().as_secs_f64()))
    }

    pub fn is_none(&self) -> bool {
        matches!(self, Cache::None)
    }

    /// Bytes of the cache's parameters (without optimiser state for the Gaussian cache; with it
    /// for the neural cache, as each reports).
    pub fn parameter_bytes(&self) -> usize {
        match self {
            Cache::None => 0,
            Cache::Gaussian(c) => c.parameter_bytes(),
            #[cfg(feature = "nrc")]
            Cache::Neural(c) => c.cache().parameter_bytes(),
        }
    }

    /// Whether the cache trains, where that can be switched ([`Cache::set_training`]): the
    /// Gaussian cache; `None` for the others.
    pub fn training(&self) -> Option<bool> {
        self.gaussian().map(|c| c.config().train)
    }

    /// Turns the Gaussian cache's training on or off (a frozen cache keeps being read);
    /// refused for the others, which always train.
    pub fn set_training(&mut self, on: bool) -> Result<()> {
        match self {
            Cache::Gaussian(c) => {
                c.set_training(on);
                Ok(())
            }
            _ => Err(SessionError::Invalid(
                "training on or off: the method has no Gaussian cache".into(),
            )),
        }
    }

    /// Takes error-aware termination's settings and the handoff (`min_coverage`, `max_bias`,
    /// `handoff_frames`) from `config` and keeps the levels (see
    /// [`GsCache::set_error_aware_termination`]); nothing to do for the others.
    pub fn set_error_aware_termination(&mut self, config: &gs_cache::CacheConfig) -> Result<()> {
        if let Cache::Gaussian(c) = self {
            c.set_error_aware_termination(config)
                .map_err(|e| SessionError::Invalid(e.to_string()))?;
        }
        Ok(())
    }

    /// The levels as the last frame drew and read them (the Gaussian cache, after its first
    /// frame): what an experiment keeps as the cache's picture.
    pub fn drawn_levels(&self) -> Option<&gs_cache::CacheFrame> {
        self.gaussian().and_then(GsCache::frame)
    }

    /// The Gaussian cache, if that is what this is: for callers that study the cache itself
    /// (its parameters, its files); a frame's figures are in [`FrameReport`].
    pub fn gaussian(&self) -> Option<&GsCache> {
        match self {
            Cache::Gaussian(c) => Some(c),
            _ => None,
        }
    }

    pub fn gaussian_mut(&mut self) -> Option<&mut GsCache> {
        match self {
            Cache::Gaussian(c) => Some(c),
            _ => None,
        }
    }

    /// The neural cache, if that is what this is, as its steps so far left it (the last
    /// frame's step may still be to take: [`NrcSequence::finish`]).
    #[cfg(feature = "nrc")]
    pub fn neural(&self) -> Option<&NeuralCache> {
        match self {
            Cache::Neural(c) => Some(c.cache()),
            _ => None,
        }
    }

    /// What the scene looks like changed: see [`crate::edit`].
    pub(crate) fn scene_changed(&mut self) -> crate::CacheEffect {
        match self {
            Cache::Gaussian(c) => {
                c.reset_schedule();
                crate::CacheEffect::Restarted
            }
            _ => crate::CacheEffect::Kept,
        }
    }

    /// A progressive image starts: frames from now on are averaged into one image (the
    /// Gaussian cache's handoff counts them).
    pub(crate) fn start_image(&mut self) {
        if let Cache::Gaussian(c) = self {
            c.start_image();
        }
    }

    /// Renders frame `frame` (whose samples are `samples`, by the sampling rule) from `camera`
    /// into `film` (none for a warm-up frame), reading and then training the cache.
    #[allow(clippy::too_many_arguments)] // one frame's inputs: plain references, no per-call struct
    pub(crate) fn frame(
        &mut self,
        media: &SceneMedia,
        camera: &Camera,
        settings: &RenderSettings,
        frame: u32,
        samples: std::ops::Range<u32>,
        film: Option<&mut Film>,
        control: &Control,
    ) -> Result<FrameReport> {
        let accumulated = film.is_some();
        let report = match self {
            Cache::None => {
                let clock = Instant::now();
                let mut scratch;
                let film = match film {
                    Some(f) => f,
                    None => {
                        scratch = Film::new(camera.width, camera.height);
                        &mut scratch
                    }
                };
                let film_seconds = clock.elapsed().as_secs_f64();
                let s = render_samples(media, camera, settings, samples, film, control);
                FrameReport {
                    samples: s.samples,
                    trace_seconds: s.seconds,
                    film_seconds,
                    nonfinite_samples: s.nonfinite_samples,
                    cancelled: s.cancelled,
                    ..Default::default()
                }
            }
            Cache::Gaussian(cache) => {
                let s = cached_pt::render_cached_frame(
                    media, camera, settings, frame, film, cache, control,
                )?;
                FrameReport {
                    samples: s.samples,
                    trace_seconds: s.trace_seconds,
                    lookup_seconds: s.lookup_seconds,
                    targets_seconds: s.targets_seconds,
                    train_seconds: s.train_seconds,
                    train_step_seconds: s.train_seconds,
                    film_seconds: s.film_seconds,
                    nonfinite_samples: s.nonfinite_samples,
                    dropped_training_samples: s.dropped_training_samples,
                    loss: cache.report().mse.clone(),
                    stale_fraction: cache.report().stale_fraction.clone(),
                    handed_off: cache.report().handed_off,
                    cancelled: s.cancelled,
                    ..Default::default()
                }
            }
            #[cfg(feature = "nrc")]
            Cache::Neural(cache) => {
                let s = cached_pt::nrc::render_nrc_frame(
                    media, camera, settings, frame, film, cache, control,
                );
                FrameReport {
                    samples: s.samples,
                    trace_seconds: s.trace_seconds,
                    lookup_seconds: s.inference_seconds,
                    train_seconds: s.train_seconds,
                    train_step_seconds: s.train_step_seconds,
                    film_seconds: s.film_seconds,
                    nonfinite_samples: s.nonfinite_samples,
                    loss: vec![(s.train.steps > 0).then_some(s.train.mean_loss)],
                    cancelled: s.cancelled,
                    ..Default::default()
                }
            }
        };
        Ok(FrameReport {
            frame,
            accumulated,
            ..report
        })
    }

    /// Writes the Gaussian cache's levels as 3DGS PLY files into `dir`; returns how many.
    pub fn save(&self, dir: &Path) -> Result<usize> {
        match self {
            Cache::Gaussian(c) => {
                c.save(dir)?;
                Ok(c.levels().len())
            }
            _ => Err(SessionError::Invalid(
                "only the Gaussian cache is saved as files: this session has another or none"
                    .into(),
            )),
        }
    }
}
