//! Edits to a session, and what each invalidates.
//!
//! Every edit empties the image (its samples no longer show the scene). What it does to the
//! cache is what the cache needs, no more:
//! - a camera move keeps the cache: its levels hold world-space radiance, and the Gaussian
//!   cache restarts its learning-rate schedule by itself when it sees a new camera;
//! - a change of what the volume looks like or how it is lit (transfer function, lights,
//!   environment, the media) restarts the Gaussian cache's schedule and warm start and
//!   distrusts every cache pixel until its residuals come in (`GsCache::reset_schedule`); the
//!   neural cache keeps training through it;
//! - new integrator settings (samples per frame, path length, integrator) keep the cache;
//! - new cache settings build a new cache.

use crate::cache::CacheChoice;
use glam::Vec3;
use render_base::Camera;
use std::path::PathBuf;
use volume_pt::{Clipping, Lights, PathSettings, SceneMedia, TransferFunction};

/// One change to a session.
#[derive(Debug, Clone)]
pub enum Edit {
    Camera(Camera),
    TransferFunction(TransferFunction),
    /// Channel `k`'s transfer function (`k` counts the channels after the first, volume-pt's
    /// `Medium::channels`): the caches restart as after a transfer-function edit.
    ChannelTransferFunction(usize, TransferFunction),
    /// The light spheres and the environment.
    Lights(Lights),
    /// The environment's radiance alone.
    Environment(Vec3),
    /// What is cut away of the medium (volume-pt's `clip`): the caches restart as after a
    /// transfer-function edit.
    Clipping(Clipping),
    /// Another volume: the whole medium and its lights, and the file they came from.
    Volume {
        media: Box<SceneMedia>,
        path: PathBuf,
    },
    /// Samples per pixel of each frame.
    Spp(u32),
    /// Integrator, path length and Russian roulette.
    Path(PathSettings),
    /// Another cache, or other settings for it: a new cache is built.
    Cache(CacheChoice),
}

/// What an edit did to the cache.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CacheEffect {
    /// Kept as it is.
    Kept,
    /// Schedule and warm start restarted, every pixel distrusted (the Gaussian cache).
    Restarted,
    /// Replaced by a new cache.
    Rebuilt,
}

/// What an edit invalidated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Invalidated {
    /// The image was emptied.
    pub image: bool,
    pub cache: CacheEffect,
}
