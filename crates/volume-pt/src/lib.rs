//! volume-pt: a delta-tracking volume path tracer with next-event estimation, for scalar
//! volumes (CT, MRI, simulation grids) seen through a transfer function.
//!
//! Read it in this order:
//! - [`io`]: reading raw, NRRD, VTK, NIfTI and OME-Zarr volumes into a [`grid::ScalarGrid`];
//!   [`bricks`]: a volume larger than memory streamed from its store within a budget.
//! - [`transfer`]: window, colour, opacity and density scale: scalar to medium.
//! - [`medium`] and [`majorant`]: the placed, classified volume and its macrocell majorants;
//!   [`clip`]: the box and planes that cut it.
//! - [`tracking`]: delta tracking (free flights) and ratio tracking (transmittance).
//! - [`probe`]: where a ray first meets visible medium, and the data there.
//! - [`phase`], [`lights`]: phase functions; the emitter types (sphere, distant) and a
//!   constant environment.
//! - [`integrator`]: the `uniform` and `nee` path estimators.
//! - [`render`](mod@render), [`film`]: tiles, passes, threads; exact accumulation.
//! - [`shard`]: a render split into sample ranges whose partial films merge bit for bit.
//! - [`cache`]: the seam a radiance cache plugs into (per-path hooks, per-frame cache, start points).
//! - [`scene`]: the TOML scene file; [`auto_scene`]: a scene chosen for a bare volume file
//!   (transfer function from its histogram, a framing camera, a key light), with
//!   [`colormap`]'s presets.
//! - [`sampling`]: counter-based random numbers and warps.

pub mod auto_scene;
pub mod bricks;
pub mod cache;
pub mod clip;
pub mod colormap;
pub mod error;
pub mod film;
pub mod grid;
pub mod integrator;
pub mod io;
pub mod lights;
pub mod majorant;
pub mod medium;
pub mod phase;
pub mod probe;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod shard;
pub mod tracking;
pub mod transfer;

pub use auto_scene::scene_for_volume;
pub use cache::{
    ControlVariate, FrameCache, NoCache, PathHooks, TilePixel, TileRect, Vertex, path_key,
    sample_cache_points,
};
pub use clip::{ClipBox, ClipPlane, Clipping};
pub use colormap::Colormap;
pub use error::{Error, Result};
pub use film::{ExactRgb, Film};
pub use grid::{Filter, ScalarGrid};
pub use integrator::{IntegratorKind, PathSettings, SceneMedia, radiance, radiance_with};
pub use lights::{DistantLight, Light, Lights, SphereLight};
pub use medium::Medium;
pub use phase::Phase;
pub use render::{
    CachedFrame, RenderSettings, RenderStats, render, render_frame_with, render_samples,
};
/// The camera and the cancellation and progress of long work (from render-base, re-exported
/// for callers).
pub use render_base::{Camera, Control};
pub use scene::{OpenedScene, Scene, SceneOverrides, load_scene, open_scene};
pub use shard::{PartialRender, RenderKey, Shard};
pub use transfer::TransferFunction;
