//! The scalar grid: voxel values in memory and their reconstruction at a point.
//!
//! Convention (docs/architecture.md, Space and units): a grid of `dims` voxels occupies the box `[0, dims)` in index space;
//! voxel `(i, j, k)` is a sample at the cell centre `(i + 0.5, j + 0.5, k + 0.5)`. Between centres
//! the scalar is interpolated trilinearly; outside the outermost centres it is clamped to the edge
//! voxel, so the whole box is filled and density does not fade towards the faces.
//!
//! Voxels are kept in the file's own type ([`Voxels`]): a uint8 CT takes one byte a voxel, not
//! the four of an f32 copy, and a large volume's lookups move a quarter of the bytes. A value is
//! `scale * stored + offset` (a file's intensity scaling, NIfTI's `scl_slope`/`scl_inter`),
//! applied once after interpolation: interpolation is linear, so this equals interpolating the
//! scaled values, up to rounding. 32-bit integers and f64 are kept as f32 (integers above 2^24
//! and f64 are rounded, as before).
//!
//! The voxels are either all in memory ([`Storage::Whole`]) or streamed from their store
//! within a memory budget ([`Storage::Streamed`], see [`crate::bricks`]); both give the same
//! value at every point, bit for bit.

use crate::bricks::{Bricks, Survey};
use crate::error::{Error, Result};
use glam::{UVec3, Vec3};
use std::sync::Arc;

/// How the scalar is reconstructed between voxel centres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Filter {
    /// Interpolate the scalar trilinearly between voxel centres, then classify.
    #[default]
    Trilinear,
    /// Each voxel is a constant box: for exact comparison with other renderers.
    Nearest,
}

/// Voxel values in the type they are stored in, x fastest.
#[derive(Debug, Clone, PartialEq)]
pub enum Voxels {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    F32(Vec<f32>),
}

impl Voxels {
    pub fn len(&self) -> usize {
        match self {
            Voxels::U8(v) => v.len(),
            Voxels::I8(v) => v.len(),
            Voxels::U16(v) => v.len(),
            Voxels::I16(v) => v.len(),
            Voxels::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes one voxel takes in memory.
    pub fn bytes_per_voxel(&self) -> usize {
        match self {
            Voxels::U8(_) | Voxels::I8(_) => 1,
            Voxels::U16(_) | Voxels::I16(_) => 2,
            Voxels::F32(_) => 4,
        }
    }

    /// Stored value `i` as f32 (exact for every stored type).
    #[inline]
    pub(crate) fn get(&self, i: usize) -> f32 {
        match self {
            Voxels::U8(v) => v[i].into(),
            Voxels::I8(v) => v[i].into(),
            Voxels::U16(v) => v[i].into(),
            Voxels::I16(v) => v[i].into(),
            Voxels::F32(v) => v[i],
        }
    }

    /// The name of the stored type.
    pub fn type_name(&self) -> &'static str {
        match self {
            Voxels::U8(_) => "uint8",
            Voxels::I8(_) => "int8",
            Voxels::U16(_) => "uint16",
            Voxels::I16(_) => "int16",
            Voxels::F32(_) => "float32",
        }
    }

    /// The box `lo .. lo + size` of a grid of `dims` holding these voxels, x fastest.
    pub fn copy_box(&self, dims: UVec3, lo: UVec3, size: UVec3) -> Voxels {
        fn copy<T: Copy>(v: &[T], dims: UVec3, lo: UVec3, size: UVec3) -> Vec<T> {
            let mut out = Vec::with_capacity(size.x as usize * size.y as usize * size.z as usize);
            for z in lo.z..lo.z + size.z {
                for y in lo.y..lo.y + size.y {
                    let start = lo.x as usize
                        + dims.x as usize * (y as usize + dims.y as usize * z as usize);
                    out.extend_from_slice(&v[start..start + size.x as usize]);
                }
            }
            out
        }
        match self {
            Voxels::U8(v) => Voxels::U8(copy(v, dims, lo, size)),
            Voxels::I8(v) => Voxels::I8(copy(v, dims, lo, size)),
            Voxels::U16(v) => Voxels::U16(copy(v, dims, lo, size)),
            Voxels::I16(v) => Voxels::I16(copy(v, dims, lo, size)),
            Voxels::F32(v) => Voxels::F32(copy(v, dims, lo, size)),
        }
    }

    /// Smallest and largest stored value; for f32, the index of the first non-finite one.
    fn range(&self) -> std::result::Result<(f32, f32), usize> {
        fn span<T: Copy + Into<f32>>(v: &[T]) -> (f32, f32) {
            v.iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &x| {
                    let x = x.into();
                    (lo.min(x), hi.max(x))
                })
        }
        Ok(match self {
            Voxels::U8(v) => span(v),
            Voxels::I8(v) => span(v),
            Voxels::U16(v) => span(v),
            Voxels::I16(v) => span(v),
            Voxels::F32(v) => {
                if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                    return Err(i);
                }
                span(v)
            }
        })
    }
}

/// Where a grid's voxels are.
#[derive(Debug, Clone)]
pub enum Storage {
    /// All in memory.
    Whole(Arc<Voxels>),
    /// Paged in from a store within a memory budget.
    Streamed(Arc<Bricks>),
}

/// A dense scalar grid, x fastest: voxel `(x, y, z)` is element `x + X * (y + Y * z)`.
///
/// Cloning shares the voxels (they are never changed after construction): a render session, a
/// Python scene and an experiment's per-method copies of a gigavoxel volume hold one copy.
#[derive(Debug, Clone)]
pub struct ScalarGrid {
    dims: UVec3,
    storage: Storage,
    /// value = scale * stored + offset.
    scale: f32,
    offset: f32,
    range: (f32, f32),
}

impl ScalarGrid {
    /// A grid of f32 values; fails on a size mismatch or a non-finite value.
    pub fn new(dims: UVec3, values: Vec<f32>) -> Result<Self> {
        Self::from_voxels(dims, Voxels::F32(values), 1.0, 0.0)
    }

    /// A grid of stored voxels whose values are `scale * stored + offset`; fails on a size
    /// mismatch, a non-finite voxel or scaling, or a scaling that overflows f32.
    pub fn from_voxels(dims: UVec3, voxels: Voxels, scale: f32, offset: f32) -> Result<Self> {
        let n = dims.x as u64 * dims.y as u64 * dims.z as u64;
        if n == 0 {
            return Err(Error::Invalid(format!(
                "volume dims {}x{}x{} hold no voxel: every dimension must be at least 1",
                dims.x, dims.y, dims.z
            )));
        }
        if n != voxels.len() as u64 {
            return Err(Error::Invalid(format!(
                "volume dims {}x{}x{} need {n} voxels, got {}",
                dims.x,
                dims.y,
                dims.z,
                voxels.len()
            )));
        }
        let (lo, hi) = voxels.range().map_err(|i| {
            let i = i as u64;
            let x = i % dims.x as u64;
            let y = (i / dims.x as u64) % dims.y as u64;
            let z = i / (dims.x as u64 * dims.y as u64);
            Error::Invalid(format!(
                "voxel ({x}, {y}, {z}) is {}: every voxel must be a finite number",
                voxels.get(i as usize)
            ))
        })?;
        Ok(Self {
            dims,
            storage: Storage::Whole(Arc::new(voxels)),
            scale,
            offset,
            range: scaled_range((lo, hi), scale, offset)?,
        })
    }

    /// A grid streamed from `bricks`, whose values are `scale * stored + offset`. Surveys the
    /// store (see [`crate::bricks`]) for the macrocell size a streamed grid of these dims uses
    /// by default and the automatic scene's histogram stride, unless a kept survey is found.
    pub fn streamed(bricks: Bricks, scale: f32, offset: f32) -> Result<Self> {
        let dims = bricks.dims();
        let survey = bricks.survey(
            crate::bricks::streamed_macrocell(dims, crate::medium::DEFAULT_MACROCELL),
            histogram_stride(dims),
        )?;
        Ok(Self {
            dims,
            range: scaled_range(survey.range, scale, offset)?,
            storage: Storage::Streamed(Arc::new(bricks)),
            scale,
            offset,
        })
    }

    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// The voxels as stored, when they are all in memory.
    pub fn voxels(&self) -> Option<&Voxels> {
        match &self.storage {
            Storage::Whole(v) => Some(v),
            Storage::Streamed(_) => None,
        }
    }

    /// Fails if a streamed grid could not read a brick while rendering (its voxels were taken as
    /// 0, so whatever read them is wrong): the caller refuses that image with this error.
    pub fn check_streaming(&self) -> Result<()> {
        match self.bricks().and_then(|b| b.failure()) {
            Some(failure) => Err(Error::Invalid(format!(
                "a brick of the streamed volume could not be read, so the image is wrong: \
                 {failure}"
            ))),
            None => Ok(()),
        }
    }

    /// The streamed voxels, when the grid is streamed.
    pub fn bricks(&self) -> Option<&Bricks> {
        match &self.storage {
            Storage::Whole(_) => None,
            Storage::Streamed(b) => Some(b),
        }
    }

    /// Every voxel's value as f32 (a copy: for tests and conversions, not for rendering).
    pub fn to_f32(&self) -> Vec<f32> {
        let d = self.dims;
        let mut out = Vec::with_capacity(d.x as usize * d.y as usize * d.z as usize);
        for z in 0..d.z {
            for y in 0..d.y {
                out.extend((0..d.x).map(|x| self.voxel(x, y, z)));
            }
        }
        out
    }

    /// The stored type's name (`uint8`, `int16`, `float32`...).
    pub fn type_name(&self) -> &'static str {
        match &self.storage {
            Storage::Whole(v) => v.type_name(),
            Storage::Streamed(b) => b.type_name(),
        }
    }

    /// Bytes a voxel takes in memory.
    pub fn bytes_per_voxel(&self) -> usize {
        match &self.storage {
            Storage::Whole(v) => v.bytes_per_voxel(),
            Storage::Streamed(b) => b.bytes_per_voxel(),
        }
    }

    /// Bytes the voxels take in memory: all of them, or a streamed grid's budget.
    pub fn bytes(&self) -> usize {
        match &self.storage {
            Storage::Whole(v) => v.len() * v.bytes_per_voxel(),
            Storage::Streamed(b) => usize::try_from(b.budget()).unwrap_or(usize::MAX),
        }
    }

    /// The values at every `stride`-th voxel along each axis (in no particular order; a
    /// streamed grid takes them from its survey).
    pub fn strided_values(&self, stride: u32) -> Result<Vec<f32>> {
        let stride = stride.max(1);
        let d = self.dims;
        match &self.storage {
            Storage::Whole(_) => {
                let mut values = Vec::new();
                for z in (0..d.z).step_by(stride as usize) {
                    for y in (0..d.y).step_by(stride as usize) {
                        for x in (0..d.x).step_by(stride as usize) {
                            values.push(self.voxel(x, y, z));
                        }
                    }
                }
                Ok(values)
            }
            Storage::Streamed(b) => {
                let survey = b.survey(
                    crate::bricks::streamed_macrocell(d, crate::medium::DEFAULT_MACROCELL),
                    stride,
                )?;
                Ok(survey
                    .sample
                    .iter()
                    .map(|&v| self.scale * v + self.offset)
                    .collect())
            }
        }
    }

    /// Per macrocell of `cell_size` voxels (clamped to the grid), the range of values
    /// interpolation can reach in it: its voxels and a one-voxel halo (see
    /// [`crate::majorant::ValueRanges`]). A streamed grid surveys its store (once per size).
    pub fn cell_ranges(&self, cell_size: u32) -> Result<Vec<(f32, f32)>> {
        let dims = self.dims;
        let cell_size = cell_size.clamp(1, dims.max_element());
        let cells = UVec3::new(
            dims.x.div_ceil(cell_size),
            dims.y.div_ceil(cell_size),
            dims.z.div_ceil(cell_size),
        );
        let count = cells.x as usize * cells.y as usize * cells.z as usize;
        let scaled = |(lo, hi): (f32, f32)| {
            let (a, b) = (self.scale * lo + self.offset, self.scale * hi + self.offset);
            (a.min(b), a.max(b))
        };
        match &self.storage {
            Storage::Whole(voxels) => {
                use rayon::prelude::*;
                Ok((0..count)
                    .into_par_iter()
                    .map(|i| {
                        let (nx, ny) = (cells.x as usize, cells.y as usize);
                        let c = UVec3::new(
                            (i % nx) as u32,
                            ((i / nx) % ny) as u32,
                            (i / (nx * ny)) as u32,
                        );
                        // Voxels [c*B - 1, (c+1)*B] (inclusive) are reachable by interpolation
                        // inside the cell.
                        let lo = (c * cell_size).saturating_sub(UVec3::ONE);
                        let hi = UVec3::new(
                            (c.x + 1).saturating_mul(cell_size),
                            (c.y + 1).saturating_mul(cell_size),
                            (c.z + 1).saturating_mul(cell_size),
                        );
                        self.range_in(voxels, lo, hi)
                    })
                    .collect())
            }
            Storage::Streamed(b) => {
                let survey: Arc<Survey> = b.survey(cell_size, histogram_stride(dims))?;
                Ok(survey.cell_ranges.iter().map(|&r| scaled(r)).collect())
            }
        }
    }

    /// Smallest and largest voxel value.
    pub fn range(&self) -> (f32, f32) {
        self.range
    }

    /// Smallest and largest value of the voxels in the box `lo..=hi` (inclusive, clamped to the
    /// grid) of an in-memory grid: one pass over each x-row in the stored type.
    fn range_in(&self, voxels: &Voxels, lo: UVec3, hi: UVec3) -> (f32, f32) {
        let hi = hi.min(self.dims - 1);
        let (sy, sz) = (
            self.dims.x as usize,
            self.dims.x as usize * self.dims.y as usize,
        );
        let mut r = (f32::INFINITY, f32::NEG_INFINITY);
        for z in lo.z..=hi.z {
            for y in lo.y..=hi.y {
                let start = lo.x as usize + sy * y as usize + sz * z as usize;
                let rows = start..start + (hi.x - lo.x) as usize + 1;
                r = fold_range(voxels, rows, r);
            }
        }
        let (a, b) = (
            self.scale * r.0 + self.offset,
            self.scale * r.1 + self.offset,
        );
        (a.min(b), a.max(b))
    }

    /// The value of voxel `(x, y, z)` (inside the grid).
    #[inline]
    pub fn voxel(&self, x: u32, y: u32, z: u32) -> f32 {
        let stored = match &self.storage {
            Storage::Whole(v) => v.get(
                (x as usize)
                    + self.dims.x as usize * (y as usize + self.dims.y as usize * z as usize),
            ),
            Storage::Streamed(b) => b.stored(UVec3::new(x, y, z)),
        };
        self.scale * stored + self.offset
    }

    /// The scalar at index-space point `u` (voxel centres at `i + 0.5`).
    #[inline]
    pub fn sample(&self, u: Vec3, filter: Filter) -> f32 {
        match filter {
            Filter::Trilinear => self.sample_trilinear(u),
            Filter::Nearest => self.sample_nearest(u),
        }
    }

    #[inline]
    pub fn sample_nearest(&self, u: Vec3) -> f32 {
        let max = (self.dims - 1).as_vec3();
        // Clamped to >= 0 first, so truncation is floor.
        let i = u.clamp(Vec3::ZERO, max).as_uvec3();
        self.voxel(i.x, i.y, i.z)
    }

    #[inline]
    pub fn sample_trilinear(&self, u: Vec3) -> f32 {
        let max = (self.dims - 1).as_vec3();
        let c = (u - 0.5).clamp(Vec3::ZERO, max);
        // c >= 0, so truncation is floor (and avoids a libm call on baseline x86-64).
        let i0 = c.as_uvec3();
        let f = c - i0.as_vec3();
        let i1 = (i0 + 1).min(self.dims - 1);
        let corners = match &self.storage {
            Storage::Whole(voxels) => {
                let sy = self.dims.x as usize;
                let sz = sy * self.dims.y as usize;
                let corner = Corner {
                    base: i0.x as usize + sy * i0.y as usize + sz * i0.z as usize,
                    dx: (i1.x - i0.x) as usize,
                    dy: (i1.y - i0.y) as usize * sy,
                    dz: (i1.z - i0.z) as usize * sz,
                };
                gather_voxels(voxels, corner)
            }
            Storage::Streamed(b) => b.corners(i0, i1),
        };
        self.scale * blend(corners, f) + self.offset
    }
}

/// The grid's value range from its stored one; refuses a scaling that is not finite there.
fn scaled_range((lo, hi): (f32, f32), scale: f32, offset: f32) -> Result<(f32, f32)> {
    let (a, b) = (scale * lo + offset, scale * hi + offset);
    // Written so that NaN fails.
    if !(scale.is_finite() && offset.is_finite() && a.is_finite() && b.is_finite()) {
        return Err(Error::Invalid(format!(
            "intensity scaling {scale} * v + {offset} is not finite over the voxels' range \
             [{lo}, {hi}]"
        )));
    }
    Ok((a.min(b), a.max(b)))
}

/// The stride per axis at which about `1 << 20` voxels of a grid of `dims` are read: the
/// automatic scene's histogram sample.
pub fn histogram_stride(dims: UVec3) -> u32 {
    const SAMPLES: f64 = (1u64 << 20) as f64;
    let n = dims.x as f64 * dims.y as f64 * dims.z as f64;
    ((n / SAMPLES).cbrt().ceil() as u32).max(1)
}

/// Smallest and largest of `r` and the stored values `rows` of `voxels`.
pub(crate) fn fold_range(
    voxels: &Voxels,
    rows: std::ops::Range<usize>,
    r: (f32, f32),
) -> (f32, f32) {
    fn fold<T: Copy + Into<f32>>(row: &[T], r: (f32, f32)) -> (f32, f32) {
        row.iter().fold(r, |(a, b), &v| {
            let v = v.into();
            (a.min(v), b.max(v))
        })
    }
    match voxels {
        Voxels::U8(v) => fold(&v[rows], r),
        Voxels::I8(v) => fold(&v[rows], r),
        Voxels::U16(v) => fold(&v[rows], r),
        Voxels::I16(v) => fold(&v[rows], r),
        Voxels::F32(v) => fold(&v[rows], r),
    }
}

/// The first of a trilinear lookup's eight voxels and the steps to the others.
#[derive(Clone, Copy)]
pub(crate) struct Corner {
    pub base: usize,
    pub dx: usize,
    pub dy: usize,
    pub dz: usize,
}

/// A trilinear lookup's eight stored values, in the order [`blend`] takes them. One branch on
/// the stored type per lookup; the eight loads are monomorphic.
#[inline(always)]
pub(crate) fn gather_voxels(voxels: &Voxels, c: Corner) -> [f32; 8] {
    match voxels {
        Voxels::U8(v) => gather(v, c),
        Voxels::I8(v) => gather(v, c),
        Voxels::U16(v) => gather(v, c),
        Voxels::I16(v) => gather(v, c),
        Voxels::F32(v) => gather(v, c),
    }
}

#[inline(always)]
fn gather<T: Copy + Into<f32>>(v: &[T], c: Corner) -> [f32; 8] {
    let at = |k: usize| -> f32 { v[k].into() };
    let Corner { base, dx, dy, dz } = c;
    [
        at(base),
        at(base + dx),
        at(base + dy),
        at(base + dx + dy),
        at(base + dz),
        at(base + dx + dz),
        at(base + dy + dz),
        at(base + dx + dy + dz),
    ]
}

/// Trilinear interpolation of the eight corner values at fractions `f`.
#[inline(always)]
fn blend(c: [f32; 8], f: Vec3) -> f32 {
    let [c000, c100, c010, c110, c001, c101, c011, c111] = c;
    let x00 = c000 + f.x * (c100 - c000);
    let x10 = c010 + f.x * (c110 - c010);
    let x01 = c001 + f.x * (c101 - c001);
    let x11 = c011 + f.x * (c111 - c011);
    let y0 = x00 + f.y * (x10 - x00);
    let y1 = x01 + f.y * (x11 - x01);
    y0 + f.z * (y1 - y0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> ScalarGrid {
        // value = x + 10 y + 100 z
        let dims = UVec3::new(3, 4, 5);
        let mut v = Vec::new();
        for z in 0..5 {
            for y in 0..4 {
                for x in 0..3 {
                    v.push((x + 10 * y + 100 * z) as f32);
                }
            }
        }
        ScalarGrid::new(dims, v).unwrap()
    }

    #[test]
    fn voxel_centres_reproduce_voxels() {
        let g = ramp();
        assert_eq!(
            g.sample_trilinear(Vec3::new(1.5, 2.5, 3.5)),
            1.0 + 20.0 + 300.0
        );
        assert_eq!(
            g.sample_nearest(Vec3::new(1.9, 2.1, 3.0)),
            1.0 + 20.0 + 300.0
        );
    }

    #[test]
    fn trilinear_is_linear_between_centres_and_clamped_outside() {
        let g = ramp();
        let v = g.sample_trilinear(Vec3::new(1.0, 1.75, 2.5));
        assert!((v - (0.5 + 12.5 + 200.0)).abs() < 1e-4, "{v}");
        // Below the first centre the edge value holds.
        assert_eq!(g.sample_trilinear(Vec3::new(0.1, 0.5, 0.5)), 0.0);
        assert_eq!(
            g.sample_trilinear(Vec3::new(3.0, 4.0, 5.0)),
            2.0 + 30.0 + 400.0
        );
    }

    /// Every stored type gives the very value an f32 copy of its voxels gives, at every point
    /// (the same f32 arithmetic on the same numbers), and takes its own size in memory.
    #[test]
    fn native_types_sample_like_their_f32_copy() {
        let dims = UVec3::new(5, 4, 3);
        let n = 60;
        let hash = |i: u32| render_base::hash::hash32(&[0xb0c5, i]);
        let grids = [
            (Voxels::U8((0..n).map(|i| hash(i) as u8).collect()), 1),
            (Voxels::I8((0..n).map(|i| hash(i) as i8).collect()), 1),
            (Voxels::U16((0..n).map(|i| hash(i) as u16).collect()), 2),
            (Voxels::I16((0..n).map(|i| hash(i) as i16).collect()), 2),
            (
                Voxels::F32((0..n).map(|i| hash(i) as f32 * 1e-3).collect()),
                4,
            ),
        ];
        for (voxels, size) in grids {
            let native = ScalarGrid::from_voxels(dims, voxels.clone(), 1.0, 0.0).unwrap();
            let copy = ScalarGrid::new(dims, native.to_f32()).unwrap();
            assert_eq!(native.bytes(), n as usize * size);
            assert_eq!(native.range(), copy.range());
            for k in 0..2000u32 {
                let u = Vec3::new(
                    render_base::hash::unit_f32(hash(3 * k + 1000)) * 6.0 - 0.5,
                    render_base::hash::unit_f32(hash(3 * k + 1001)) * 5.0 - 0.5,
                    render_base::hash::unit_f32(hash(3 * k + 1002)) * 4.0 - 0.5,
                );
                assert_eq!(
                    native.sample_trilinear(u),
                    copy.sample_trilinear(u),
                    "{voxels:?}"
                );
                assert_eq!(native.sample_nearest(u), copy.sample_nearest(u));
            }
            // With an intensity scaling, scaling after interpolation matches interpolating the
            // scaled values up to rounding.
            let scaled = ScalarGrid::from_voxels(dims, voxels, 0.5, -1024.0).unwrap();
            let scaled_copy = ScalarGrid::new(
                dims,
                copy.to_f32().iter().map(|v| 0.5 * v - 1024.0).collect(),
            )
            .unwrap();
            for k in 0..500u32 {
                let u = Vec3::new(1.3, 2.2, 0.7) + 0.001 * k as f32;
                let (a, b) = (scaled.sample_trilinear(u), scaled_copy.sample_trilinear(u));
                assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
        // A scaling that overflows over the voxels' range is refused.
        let e =
            ScalarGrid::from_voxels(UVec3::new(2, 1, 1), Voxels::U16(vec![0, 65535]), 1e35, 0.0);
        assert!(e.unwrap_err().to_string().contains("not finite"));
    }

    #[test]
    fn non_finite_voxels_and_bad_sizes_are_rejected() {
        let e = ScalarGrid::new(UVec3::new(2, 1, 1), vec![0.0, f32::NAN]).unwrap_err();
        assert!(e.to_string().contains("voxel (1, 0, 0) is NaN"), "{e}");
        assert!(ScalarGrid::new(UVec3::new(2, 2, 1), vec![0.0; 3]).is_err());
        assert!(ScalarGrid::new(UVec3::new(0, 2, 1), vec![]).is_err());
    }
}
