//! The seam a radiance cache plugs into: what one path tells a cache and may ask of it
//! ([`PathHooks`]), what a cache provides for a frame's tiles ([`FrameCache`]), and points to
//! start a cache from ([`sample_cache_points`]).
//!
//! The path tracer knows no cache type: it is generic over [`FrameCache`], and the plain
//! renderer runs with [`NoCache`], whose hooks do nothing and draw no random numbers, so a plain
//! image is the same with or without a cache crate linked. The GSCache adapter lives in the
//! `cached-pt` crate; any other cache (a neural radiance cache, a grid) implements the same two
//! traits.

use crate::medium::Medium;
use crate::sampling::{SampleStream, uniform_sphere};
use crate::tracking::free_flight;
use glam::Vec3;
use rayon::prelude::*;

/// A real scattering vertex as a cache sees it: where it is, how the path got there, and what
/// the transfer function says of it. A path-space cache (gs-cache) reads only the albedo; a
/// world-space cache (a neural radiance cache) is queried and trained at the position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// World-space position.
    pub position: Vec3,
    /// Unit direction of the ray that arrived at it.
    pub direction: Vec3,
    /// Single-scattering albedo, by which the throughput has just been multiplied.
    pub albedo: Vec3,
    /// The transfer function's argument there: the data value, normalised to its range.
    pub value: f32,
}

/// One path's view of a cache. The integrator keeps its own throughput `W` and radiance `L` and
/// reports every change to them; every default does nothing, which is the plain path tracer.
pub trait PathHooks {
    /// A new real scattering vertex, whose albedo the throughput has just been multiplied by.
    fn vertex(&mut self, _vertex: &Vertex) {}
    /// The throughput was multiplied by `factor` (e.g. `1 / p` after surviving Russian roulette
    /// with probability `p`).
    fn scale(&mut self, _factor: Vec3) {}
    /// `W * x` was added to the path's radiance.
    fn radiance(&mut self, _x: Vec3) {}
    /// The probability of going on at the current vertex; the path draws a random number only
    /// when this is below 1.
    fn continue_probability(&self) -> f32 {
        1.0
    }
    /// The path stops into the cache at the current vertex: the radiance `x` the integrator adds
    /// as `W * x`.
    fn stop_into_cache(&mut self) -> Vec3 {
        Vec3::ZERO
    }
    /// An unbiased cache at the current vertex, asked after its next-event estimation (so the
    /// cache stands for what the path gathers from its next direction on): `None` (the
    /// default) to go on as plain path tracing, or the cache's control variate, whose decision
    /// the cache draws from its own key, never from the path's random stream. `work` is the
    /// path's work so far ([`crate::sampling::SampleStream::draws`]).
    fn control_variate(&mut self, _work: u64) -> Option<ControlVariate> {
        None
    }
    /// The path has ended after `work` ([`crate::sampling::SampleStream::draws`]).
    fn finished(&mut self, _work: u64) {}
    /// The path left the volume after its last vertex, having gathered `path_radiance` in all:
    /// radiance `x` the integrator adds as `W * x` (a cache's natural termination).
    fn escaped(&mut self, _path_radiance: Vec3) -> Vec3 {
        Vec3::ZERO
    }
    /// The radiance the path puts in the image, given what it gathered, `path_radiance`. The
    /// path itself by default; a cache whose training paths go on past the vertex where they
    /// would have stopped (a neural cache's training suffix) returns what they gathered before
    /// it, and adds its own value there later.
    fn image_radiance(&self, path_radiance: Vec3) -> Vec3 {
        path_radiance
    }
}

/// What an unbiased cache decided at a vertex ([`PathHooks::control_variate`]). Either way
/// the path adds `W * cached`; a path that goes on also adds `-W * cached / q` and divides its
/// throughput by `q`, so its expectation is the path's radiance whatever the cache holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ControlVariate {
    /// Add `W * cached` and end the path.
    Stop { cached: Vec3 },
    /// Add `W * (cached - cached / q)`, divide the throughput by `q` and go on.
    GoOn { cached: Vec3, q: f32 },
}

/// The hooks of a path with no cache.
impl PathHooks for () {}

/// A path's pixel and its place in its tile: what a cache needs to file the path's samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TilePixel {
    /// Row-major index of the pixel in the image.
    pub pixel: u64,
    /// Row-major index of the pixel in its tile.
    pub in_tile: usize,
    /// A number of the path's own ([`path_key`] of the seed, the pixel and the sample index):
    /// a cache draws its own random decisions from it, leaving the path's stream alone.
    pub key: u64,
}

/// The key of sample `sample` of pixel `pixel` under `seed` ([`TilePixel::key`]): a splitmix64
/// hash, independent of the path's own stream.
#[inline]
pub fn path_key(seed: u64, pixel: u64, sample: u64) -> u64 {
    use render_base::hash::splitmix64;
    splitmix64(
        splitmix64(seed ^ 0x5851_f42d_4c95_7f2d) ^ splitmix64(pixel) ^ sample.rotate_left(32),
    )
}

/// A rectangle of the image that one thread renders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileRect {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

/// A radiance cache, read for one frame. Tiles render in parallel, so the frame is shared; each
/// tile owns the record its paths write into ([`FrameCache::TileRecord`]), which the cache's
/// owner collects after the frame (to train, for instance).
pub trait FrameCache: Sync {
    /// One path's hooks.
    type Path<'a>: PathHooks
    where
        Self: 'a;
    /// What one tile's paths leave behind.
    type TileRecord: Send;
    /// An empty record for `tile`.
    fn tile_record(&self, tile: TileRect) -> Self::TileRecord;
    /// The hooks for a new path through `pixel`.
    fn path(&self, pixel: TilePixel) -> Self::Path<'_>;
    /// The path through `pixel` ended; file what it learned in its tile's record.
    fn path_ended(&self, path: Self::Path<'_>, pixel: TilePixel, record: &mut Self::TileRecord);
}

/// No cache: the plain path tracer.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoCache;

impl FrameCache for NoCache {
    type Path<'a> = ();
    type TileRecord = ();
    fn tile_record(&self, _tile: TileRect) {}
    fn path(&self, _pixel: TilePixel) {}
    fn path_ended(&self, _path: (), _pixel: TilePixel, _record: &mut ()) {}
}

/// Points where random rays first scatter in the medium, with the albedo there: `n` of them,
/// in random order (the GSCache paper's section 3.2 starts its clouds from such points). Each
/// ray starts on a sphere around the volume and aims at a uniform point of the box; rays that
/// pass through without scattering are replaced. Gives up (returning fewer points) after `64 n`
/// rays, so an empty medium cannot hang it.
pub fn sample_cache_points(medium: &Medium, n: usize, seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
    let (lo, hi) = medium.bounds();
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length() * 1.01;
    const CHUNK: usize = 1024;
    let chunks = n.div_ceil(CHUNK);
    let found: Vec<Vec<(Vec3, Vec3)>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let want = CHUNK.min(n - c * CHUNK);
            let mut out = Vec::with_capacity(want);
            let mut attempt = 0u64;
            while out.len() < want && attempt < 64 * want as u64 {
                let mut rng = SampleStream::new(seed ^ 0x6a09_e667_f3bc_c908, c as u64, attempt);
                attempt += 1;
                let o = centre + radius * uniform_sphere(rng.next_2d());
                let (u, v) = rng.next_2d();
                let target = lo + (hi - lo) * Vec3::new(u, v, rng.next_f32());
                let Some(d) = (target - o).try_normalize() else {
                    continue;
                };
                let ray = medium.to_index_ray(o, d);
                if let Some(hit) = free_flight(medium, &ray, 0.0, f32::INFINITY, &mut rng) {
                    let albedo = medium.albedo_with(hit.value, ray.at(hit.t));
                    out.push((o + d * hit.t, albedo));
                }
            }
            out
        })
        .collect();
    found.into_iter().flatten().unzip()
}
