//! The majorant grid: macrocells that bound extinction from above, and the DDA that walks them.
//!
//! Each macrocell covers `cell_size^3` voxels of index space. Its value range is the min/max of
//! every voxel that trilinear interpolation can touch inside the cell (the cell's voxels plus a
//! one-voxel halo), computed once from the data. A transfer function then turns each range into
//! the largest extinction it can produce (`TransferFunction::max_extinction`), so a transfer
//! function edit rebuilds the majorants from the ranges without reading the voxels again.
//! A cell whose majorant is 0 holds no medium: tracking steps over it without evaluating anything.

use crate::grid::ScalarGrid;
use crate::transfer::TransferFunction;
use glam::{IVec3, UVec3, Vec3};
use rayon::prelude::*;

/// Relative safety margin added to every majorant so that f32 rounding in interpolation and
/// classification can never make the extinction exceed it.
const MAJORANT_MARGIN: f32 = 1e-4;

/// Per-macrocell value ranges of a grid (halo included).
#[derive(Debug, Clone)]
pub struct ValueRanges {
    cell_size: u32,
    cells: UVec3,
    ranges: Vec<(f32, f32)>,
}

impl ValueRanges {
    /// Value ranges over macrocells of `cell_size` voxels; a `cell_size` at least as large as the
    /// grid gives one global cell (one global majorant).
    pub fn build(grid: &ScalarGrid, cell_size: u32) -> crate::error::Result<Self> {
        let dims = grid.dims();
        // A cell larger than the grid is one global majorant; clamping keeps the arithmetic
        // from wrapping for any u32 a scene or flag gives.
        let cell_size = cell_size.clamp(1, dims.max_element());
        let cells = UVec3::new(
            dims.x.div_ceil(cell_size),
            dims.y.div_ceil(cell_size),
            dims.z.div_ceil(cell_size),
        );
        Ok(Self {
            cell_size,
            cells,
            ranges: grid.cell_ranges(cell_size)?,
        })
    }

    pub fn cell_size(&self) -> u32 {
        self.cell_size
    }

    pub fn cells(&self) -> UVec3 {
        self.cells
    }
}

/// Upper and lower bounds of extinction per macrocell for one transfer function.
#[derive(Debug, Clone)]
pub struct MajorantGrid {
    cell_size: f32,
    inv_cell_size: f32,
    cells: IVec3,
    majorants: Vec<f32>,
    /// The smallest extinction in each cell (slightly under it): residual ratio tracking's
    /// control, whose share of the transmittance is exact.
    controls: Vec<f32>,
}

/// One stretch of a ray inside one macrocell: `t` from `t0` to `t1` with majorant `majorant` and
/// control extinction `control` (`0 <= control <= sigma_t <= majorant` inside the cell).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub t0: f32,
    pub t1: f32,
    pub majorant: f32,
    pub control: f32,
}

impl MajorantGrid {
    pub fn build(ranges: &ValueRanges, tf: &TransferFunction) -> Self {
        let majorants = ranges
            .ranges
            .par_iter()
            .map(|&(lo, hi)| {
                let m = tf.max_extinction(lo, hi);
                if m > 0.0 {
                    m * (1.0 + MAJORANT_MARGIN)
                } else {
                    0.0
                }
            })
            .collect();
        let controls = ranges
            .ranges
            .par_iter()
            .map(|&(lo, hi)| (tf.min_extinction(lo, hi) * (1.0 - MAJORANT_MARGIN)).max(0.0))
            .collect();
        Self {
            cell_size: ranges.cell_size as f32,
            inv_cell_size: 1.0 / ranges.cell_size as f32,
            cells: ranges.cells.as_ivec3(),
            majorants,
            controls,
        }
    }

    /// Adds `other`'s majorants and controls cell by cell (another channel's, over the same
    /// cells).
    pub fn add(&mut self, other: &MajorantGrid) {
        debug_assert_eq!(self.cells, other.cells);
        for (m, o) in self.majorants.iter_mut().zip(&other.majorants) {
            *m += o;
        }
        for (c, o) in self.controls.iter_mut().zip(&other.controls) {
            *c += o;
        }
    }

    /// The largest majorant of all cells.
    pub fn global_max(&self) -> f32 {
        self.majorants.iter().copied().fold(0.0, f32::max)
    }

    pub fn cell_count(&self) -> usize {
        self.majorants.len()
    }

    /// Fraction of cells with majorant 0.
    pub fn empty_fraction(&self) -> f64 {
        self.majorants.iter().filter(|&&m| m == 0.0).count() as f64 / self.majorants.len() as f64
    }

    /// Memory used by the majorants and controls, in bytes.
    pub fn bytes(&self) -> usize {
        (self.majorants.len() + self.controls.len()) * std::mem::size_of::<f32>()
    }

    /// Walks the cells that the index-space ray `o + t d` crosses for `t` in `[t_min, t_max]`,
    /// where `[t_min, t_max]` already lies inside the grid's box `[0, dims]`.
    pub fn segments(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Segments<'_> {
        let oc = o * self.inv_cell_size;
        let dc = d * self.inv_cell_size;
        let p = oc + dc * t_min;
        let cell = p.floor().as_ivec3().clamp(IVec3::ZERO, self.cells - 1);
        let mut step = IVec3::ZERO;
        let mut t_next = Vec3::INFINITY;
        let mut t_delta = Vec3::INFINITY;
        for a in 0..3 {
            if dc[a] > 0.0 {
                step[a] = 1;
                t_next[a] = ((cell[a] + 1) as f32 - oc[a]) / dc[a];
                t_delta[a] = 1.0 / dc[a];
            } else if dc[a] < 0.0 {
                step[a] = -1;
                t_next[a] = (cell[a] as f32 - oc[a]) / dc[a];
                t_delta[a] = -1.0 / dc[a];
            }
        }
        Segments {
            grid: self,
            cell,
            step,
            t_next,
            t_delta,
            t: t_min,
            t_end: t_max,
        }
    }

    #[inline]
    fn index(&self, c: IVec3) -> usize {
        (c.x + self.cells.x * (c.y + self.cells.y * c.z)) as usize
    }

    /// Size of a macrocell in voxels.
    pub fn cell_size(&self) -> f32 {
        self.cell_size
    }
}

/// Iterator over the macrocells along a ray (3D DDA, Amanatides and Woo).
pub struct Segments<'a> {
    grid: &'a MajorantGrid,
    cell: IVec3,
    step: IVec3,
    t_next: Vec3,
    t_delta: Vec3,
    t: f32,
    t_end: f32,
}

impl Iterator for Segments<'_> {
    type Item = Segment;

    #[inline]
    fn next(&mut self) -> Option<Segment> {
        // Written so that a NaN t stops the walk.
        if !(self.t < self.t_end) {
            return None;
        }
        let c = self.cell;
        if c.cmplt(IVec3::ZERO).any() || c.cmpge(self.grid.cells).any() {
            return None;
        }
        let axis = if self.t_next.x < self.t_next.y {
            if self.t_next.x < self.t_next.z { 0 } else { 2 }
        } else if self.t_next.y < self.t_next.z {
            1
        } else {
            2
        };
        let t1 = self.t_next[axis].min(self.t_end).max(self.t);
        let i = self.grid.index(c);
        let seg = Segment {
            t0: self.t,
            t1,
            majorant: self.grid.majorants[i],
            control: self.grid.controls[i],
        };
        self.t = t1;
        self.cell[axis] += self.step[axis];
        self.t_next[axis] += self.t_delta[axis];
        Some(seg)
    }
}
