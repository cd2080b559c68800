//! A tile's shared buffers: what the rasteriser (`raster`) hands the per-pixel kernels (the
//! scalar one there, the lane kernels in `simd.rs`) and gets back. Both sides import this
//! module; neither imports the other's internals.

use crate::real::Real;

/// Side of a tile in pixels.
pub const TILE: u32 = 16;

/// A tile's output: colour (background not yet added), transmittance, depth, and the number of
/// entries of its list each pixel processed (the last contributor + 1), in tile-local order.
pub(crate) struct TileOut<F> {
    pub color: [[F; 3]; TILE_PIXELS],
    pub t: [F; TILE_PIXELS],
    pub depth: [F; TILE_PIXELS],
    pub n: [u32; TILE_PIXELS],
    /// Pixel evaluations run (see `ForwardState::lane_evaluations` in `raster`).
    pub lane_evaluations: u64,
}

impl<F: Real> TileOut<F> {
    pub(crate) fn new() -> Self {
        Self {
            color: [[F::zero(); 3]; TILE_PIXELS],
            t: [F::one(); TILE_PIXELS],
            depth: [F::zero(); TILE_PIXELS],
            n: [0; TILE_PIXELS],
            lane_evaluations: 0,
        }
    }
}

/// Pixels per tile.
pub(crate) const TILE_PIXELS: usize = (TILE * TILE) as usize;

/// The per-pixel inputs of the backward pass for one tile, in tile-local order; pixels outside
/// the image have no contributors.
pub(crate) struct TilePixels<F> {
    pub origin: [u32; 2],
    pub contributors: [u32; TILE_PIXELS],
    pub dl_dc: [[F; 3]; TILE_PIXELS],
    /// With respect to the accumulated depth; all zero unless `depth`.
    pub dl_dd: [F; TILE_PIXELS],
    /// d/d alpha_i of the terms that depend on T_final: background and T itself.
    pub bg_dot: [F; TILE_PIXELS],
    pub t_final: [F; TILE_PIXELS],
    /// Whether the loss has a depth term.
    pub depth: bool,
}
