//! The heterogeneous medium: a scalar grid placed in the world and classified by a transfer
//! function, with its majorant grid.
//!
//! Placement: the grid's box spans `origin .. origin + dims * spacing` in world units; voxel
//! `(i, j, k)` sits at `origin + (i + 0.5, j + 0.5, k + 0.5) * spacing`. Outside the box there is
//! no medium. Rays are tracked in index space (`u = (x - origin) / spacing`) with the world
//! distance `t` as parameter, so anisotropic spacing costs nothing in the inner loop.
//!
//! Channels: more grids of the same dims (an OME-Zarr image's `c` axis, or files of their own)
//! may be rendered together with the first, each classified by its own transfer function, as
//! microscopists' viewers composite them: extinctions add, and the scattering colour is the
//! extinction-weighted mix of the channels' colours. Each channel's majorants come from its own
//! value ranges and the cell's majorant is their sum (rounding is monotone, so the sum of
//! bounds bounds the sum). A medium of one channel evaluates exactly what it did before
//! channels existed.

use crate::clip::{Clipping, IndexClip};
use crate::grid::{Filter, ScalarGrid};
use crate::majorant::{MajorantGrid, Segments, ValueRanges};
use crate::transfer::TransferFunction;
use glam::Vec3;

/// Default macrocell size in voxels.
pub const DEFAULT_MACROCELL: u32 = 8;

/// A ray in the index space of the grid, parameterised by world distance.
#[derive(Debug, Clone, Copy)]
pub struct IndexRay {
    pub o: Vec3,
    pub d: Vec3,
}

impl IndexRay {
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }
}

/// A channel rendered together with the first: its grid, classification and value ranges.
#[derive(Debug, Clone)]
pub struct Channel {
    /// The channel's index in its image (for messages and the viewer).
    pub index: u32,
    grid: ScalarGrid,
    tf: TransferFunction,
    ranges: ValueRanges,
}

impl Channel {
    pub fn grid(&self) -> &ScalarGrid {
        &self.grid
    }

    pub fn transfer_function(&self) -> &TransferFunction {
        &self.tf
    }
}

/// Grid, placement, classification and majorants.
#[derive(Debug, Clone)]
pub struct Medium {
    grid: ScalarGrid,
    filter: Filter,
    origin: Vec3,
    spacing: Vec3,
    inv_spacing: Vec3,
    dims: Vec3,
    tf: TransferFunction,
    ranges: ValueRanges,
    majorants: MajorantGrid,
    /// What is cut away, as given (world units), and in index space (`None`: nothing, and
    /// [`Medium::clip`] does exactly what it did before clipping existed).
    clipping: Clipping,
    index_clip: Option<IndexClip>,
    /// Channels beyond the first (see the module docs); empty for most volumes.
    channels: Vec<Channel>,
}

impl Medium {
    /// A medium from a grid placed with its box's minimum corner at `origin`.
    pub fn new(
        grid: ScalarGrid,
        filter: Filter,
        origin: Vec3,
        spacing: Vec3,
        tf: TransferFunction,
        macrocell: u32,
    ) -> crate::Result<Self> {
        use render_base::MAX_COORDINATE;
        if !(spacing.min_element() > 0.0 && spacing.is_finite() && origin.is_finite()) {
            return Err(crate::Error::Invalid(format!(
                "volume spacing {spacing} / origin {origin} is invalid: expected finite values and \
                 spacing > 0"
            )));
        }
        // Written so that NaN fails (it cannot reach here, but the form is kept).
        let far = origin + spacing * grid.dims().as_vec3();
        if !(spacing.min_element() >= 1.0 / MAX_COORDINATE
            && origin.abs().max_element() <= MAX_COORDINATE
            && far.abs().max_element() <= MAX_COORDINATE)
        {
            return Err(crate::Error::Invalid(format!(
                "volume origin {origin}, spacing {spacing}: the box reaches {far}; expected \
                 coordinates within +-{MAX_COORDINATE:e} and a spacing of at least \
                 {:e} (check the file's units, or set `spacing` and `origin` in the scene)",
                1.0 / MAX_COORDINATE
            )));
        }
        let ranges = ValueRanges::build(&grid, macrocell)?;
        let majorants = MajorantGrid::build(&ranges, &tf);
        Ok(Self {
            dims: grid.dims().as_vec3(),
            grid,
            filter,
            origin,
            spacing,
            inv_spacing: 1.0 / spacing,
            tf,
            ranges,
            majorants,
            clipping: Clipping::default(),
            index_clip: None,
            channels: Vec::new(),
        })
    }

    /// Renders `grid` (the same dims as the first channel's) classified by `tf` together with
    /// the channels already here; `index` names it. The majorants are rebuilt.
    pub fn add_channel(
        &mut self,
        index: u32,
        grid: ScalarGrid,
        tf: TransferFunction,
    ) -> crate::Result<()> {
        if grid.dims() != self.grid.dims() {
            return Err(crate::Error::Invalid(format!(
                "channel {index} has {} voxels: expected the first channel's {}",
                grid.dims(),
                self.grid.dims()
            )));
        }
        let ranges = ValueRanges::build(&grid, self.ranges.cell_size())?;
        self.channels.push(Channel {
            index,
            grid,
            tf,
            ranges,
        });
        self.majorants = self.build_majorants();
        Ok(())
    }

    /// Replaces the first channel's voxels by `grid` of the same dims (another time point of a
    /// series): placement, classification and clipping are kept, the ranges and majorants
    /// rebuilt.
    pub fn replace_grid(&mut self, grid: ScalarGrid) -> crate::Result<()> {
        if grid.dims() != self.grid.dims() {
            return Err(crate::Error::Invalid(format!(
                "the new voxels are {}: expected the volume's {}",
                grid.dims(),
                self.grid.dims()
            )));
        }
        self.ranges = ValueRanges::build(&grid, self.ranges.cell_size())?;
        self.grid = grid;
        self.majorants = self.build_majorants();
        Ok(())
    }

    /// The channels rendered together with the first.
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// Changes channel `k`'s transfer function (`k` counts the channels after the first).
    pub fn set_channel_transfer_function(
        &mut self,
        k: usize,
        tf: TransferFunction,
    ) -> crate::Result<()> {
        let Some(channel) = self.channels.get_mut(k) else {
            return Err(crate::Error::Invalid(format!(
                "channel {k}: the medium has {} channels after the first",
                self.channels.len()
            )));
        };
        channel.tf = tf;
        self.majorants = self.build_majorants();
        Ok(())
    }

    /// The majorants of every channel, summed per macrocell.
    fn build_majorants(&self) -> MajorantGrid {
        let mut m = MajorantGrid::build(&self.ranges, &self.tf);
        for c in &self.channels {
            m.add(&MajorantGrid::build(&c.ranges, &c.tf));
        }
        m
    }

    /// Cuts the medium to `clipping` (see [`crate::clip`]), replacing any earlier clipping; an
    /// empty one cuts nothing. Refused, with the field named, when a value is invalid.
    pub fn set_clipping(&mut self, clipping: Clipping) -> crate::Result<()> {
        clipping.validate().map_err(crate::Error::Invalid)?;
        self.index_clip =
            (!clipping.is_empty()).then(|| IndexClip::new(&clipping, self.origin, self.spacing));
        self.clipping = clipping;
        Ok(())
    }

    /// What is cut away (empty: nothing).
    pub fn clipping(&self) -> &Clipping {
        &self.clipping
    }

    /// Whether world point `x` lies in the kept medium: inside the volume's box and not
    /// clipped away.
    pub fn keeps(&self, x: Vec3) -> bool {
        let u = (x - self.origin) * self.inv_spacing;
        u.cmpge(Vec3::ZERO).all()
            && u.cmple(self.dims).all()
            && self.index_clip.as_ref().is_none_or(|c| c.keeps(u))
    }

    /// Changes the transfer function; the majorants are rebuilt from the stored value ranges.
    pub fn set_transfer_function(&mut self, tf: TransferFunction) {
        self.tf = tf;
        self.majorants = self.build_majorants();
    }

    /// Rebuilds the majorants over macrocells of `cell_size` voxels (reads the voxels; a
    /// streamed grid surveys its store, which can fail).
    pub fn set_macrocell_size(&mut self, cell_size: u32) -> crate::Result<()> {
        self.ranges = ValueRanges::build(&self.grid, cell_size)?;
        for c in &mut self.channels {
            c.ranges = ValueRanges::build(&c.grid, cell_size)?;
        }
        self.majorants = self.build_majorants();
        Ok(())
    }

    pub fn grid(&self) -> &ScalarGrid {
        &self.grid
    }
    pub fn transfer_function(&self) -> &TransferFunction {
        &self.tf
    }
    pub fn majorants(&self) -> &MajorantGrid {
        &self.majorants
    }
    pub fn filter(&self) -> Filter {
        self.filter
    }

    /// World size of a voxel.
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// World-space bounds of the volume's box.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (self.origin, self.origin + self.dims * self.spacing)
    }

    #[inline]
    pub fn to_index_ray(&self, o: Vec3, d: Vec3) -> IndexRay {
        IndexRay {
            o: (o - self.origin) * self.inv_spacing,
            d: d * self.inv_spacing,
        }
    }

    /// The parameter interval where the ray is inside the box and the kept region of the
    /// clipping ([`crate::clip`]), within `[t_min, t_max]`.
    /// Robust to direction components that are zero (rays parallel to, or grazing, a face).
    #[inline(always)]
    pub fn clip(&self, r: &IndexRay, t_min: f32, t_max: f32) -> Option<(f32, f32)> {
        let mut t0 = t_min;
        let mut t1 = t_max;
        for a in 0..3 {
            if r.d[a] == 0.0 {
                if !(r.o[a] >= 0.0 && r.o[a] <= self.dims[a]) {
                    return None;
                }
            } else {
                let inv = 1.0 / r.d[a];
                let ta = (0.0 - r.o[a]) * inv;
                let tb = (self.dims[a] - r.o[a]) * inv;
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        // Written so that NaN bounds mean no overlap.
        let inside = (t0 < t1).then_some((t0, t1));
        match &self.index_clip {
            None => inside,
            Some(clip) => inside.and_then(|(t0, t1)| clip.narrow(r, t0, t1)),
        }
    }

    /// Majorant segments of the ray over `[t0, t1]` (an interval returned by [`Medium::clip`]).
    #[inline]
    pub fn segments(&self, r: &IndexRay, t0: f32, t1: f32) -> Segments<'_> {
        self.majorants.segments(r.o, r.d, t0, t1)
    }

    /// Data value at an index-space point.
    #[inline]
    pub fn value(&self, u: Vec3) -> f32 {
        self.grid.sample(u, self.filter)
    }

    /// Extinction per world unit at an index-space point.
    #[inline]
    pub fn extinction(&self, u: Vec3) -> f32 {
        self.extinction_with(self.value(u), u)
    }

    /// Extinction per world unit at index-space point `u` whose first channel's value is
    /// `value` (the other channels are looked up there).
    #[inline(always)]
    pub fn extinction_with(&self, value: f32, u: Vec3) -> f32 {
        let first = self.tf.extinction(value);
        if self.channels.is_empty() {
            first
        } else {
            self.channels_extinction(first, u)
        }
    }

    /// `first` plus the other channels' extinctions at `u`: kept out of line, so a medium of
    /// one channel tracks with the code it had before channels existed.
    #[inline(never)]
    fn channels_extinction(&self, first: f32, u: Vec3) -> f32 {
        self.channels.iter().fold(first, |sum, c| {
            sum + c.tf.extinction(c.grid.sample(u, self.filter))
        })
    }

    /// Single-scattering albedo at index-space point `u` whose first channel's value is
    /// `value`: with several channels, their colours weighted by their extinctions.
    #[inline(always)]
    pub fn albedo_with(&self, value: f32, u: Vec3) -> Vec3 {
        if self.channels.is_empty() {
            self.tf.albedo(value)
        } else {
            self.channels_albedo(value, u)
        }
    }

    /// [`Medium::albedo_with`] with several channels (out of line, as
    /// [`Medium::channels_extinction`]).
    #[inline(never)]
    fn channels_albedo(&self, value: f32, u: Vec3) -> Vec3 {
        let first = self.tf.extinction(value);
        let (mut weighted, mut total) = (self.tf.albedo(value) * first, first);
        for c in &self.channels {
            let v = c.grid.sample(u, self.filter);
            let sigma = c.tf.extinction(v);
            weighted += c.tf.albedo(v) * sigma;
            total += sigma;
        }
        // Written so that NaN takes the first channel's colour.
        if total > 0.0 {
            weighted / total
        } else {
            self.tf.albedo(value)
        }
    }

    /// The feature-buffer normal at world point `x`: minus the world-space gradient of the
    /// extinction, normalised, so it points from dense to thin medium (out of a surface).
    ///
    /// The gradient is taken by central differences one voxel either side along each axis, of
    /// the extinction the tracking sees (the scene's filter, then the transfer function), and
    /// divided by the spacing: a 4-voxel-wide stencil whose trilinear reads smooth it over
    /// about two voxels, enough to steady it on CT noise without blurring a surface away.
    /// Where the field is flat (a homogeneous region) the gradient is zero and `fallback` is
    /// returned (the renderer passes the direction back to the camera).
    pub fn extinction_normal(&self, x: Vec3, fallback: Vec3) -> Vec3 {
        let u = (x - self.origin) * self.inv_spacing;
        let mut g = Vec3::ZERO;
        for a in 0..3 {
            let mut e = Vec3::ZERO;
            e[a] = 1.0;
            g[a] = (self.extinction(u + e) - self.extinction(u - e)) * 0.5 * self.inv_spacing[a];
        }
        let n = -g.normalize_or_zero();
        // Written so that a NaN gradient takes the fallback too.
        if n.length_squared() > 0.5 {
            n
        } else {
            fallback
        }
    }

    /// Single-scattering albedo at an index-space point.
    #[inline]
    pub fn albedo(&self, u: Vec3) -> Vec3 {
        self.albedo_with(self.value(u), u)
    }

    /// Bytes held: the voxels, each macrocell's value range (two f32) and its majorant and
    /// control (two f32).
    pub fn memory_bytes(&self) -> usize {
        self.grid.bytes()
            + self
                .channels
                .iter()
                .map(|c| {
                    c.grid.bytes() + self.majorants.cell_count() * 2 * std::mem::size_of::<f32>()
                })
                .sum::<usize>()
            + self.majorants.cell_count() * 2 * std::mem::size_of::<f32>()
            + self.majorants.bytes()
    }
}
