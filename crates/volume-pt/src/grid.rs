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

use crate::error::{Error, Result};
use glam::{UVec3, Vec3};

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
    fn get(&self, i: usize) -> f32 {
        match self {
            Voxels::U8(v) => v[i].into(),
            Voxels::I8(v) => v[i].into(),
            Voxels::U16(v) => v[i].into(),
            Voxels::I16(v) => v[i].into(),
            Voxels::F32(v) => v[i],
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

/// A dense scalar grid, x fastest: voxel `(x, y, z)` is element `x + X * (y + Y * z)`.
///
/// Cloning shares the voxels (they are never changed after construction): a render session, a
/// Python scene and an experiment's per-method copies of a gigavoxel volume hold one copy.
#[derive(Debug, Clone)]
pub struct ScalarGrid {
    dims: UVec3,
    voxels: std::sync::Arc<Voxels>,
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
        let (a, b) = (scale * lo + offset, scale * hi + offset);
        // Written so that NaN fails.
        if !(scale.is_finite() && offset.is_finite() && a.is_finite() && b.is_finite()) {
            return Err(Error::Invalid(format!(
                "intensity scaling {scale} * v + {offset} is not finite over the voxels' range \
                 [{lo}, {hi}]"
            )));
        }
        Ok(Self {
            dims,
            voxels: std::sync::Arc::new(voxels),
            scale,
            offset,
            range: (a.min(b), a.max(b)),
        })
    }

    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// The voxels as stored.
    pub fn voxels(&self) -> &Voxels {
        &self.voxels
    }

    /// Every voxel's value as f32 (a copy: for tests and conversions, not for rendering).
    pub fn to_f32(&self) -> Vec<f32> {
        (0..self.voxels.len()).map(|i| self.value_at(i)).collect()
    }

    /// Bytes the voxels take in memory.
    pub fn bytes(&self) -> usize {
        self.voxels.len() * self.voxels.bytes_per_voxel()
    }

    /// Smallest and largest voxel value.
    pub fn range(&self) -> (f32, f32) {
        self.range
    }

    /// Smallest and largest value of the voxels in the box `lo..=hi` (inclusive, clamped to the
    /// grid): one pass over each x-row in the stored type, for the majorant grid's ranges.
    pub fn range_in(&self, lo: UVec3, hi: UVec3) -> (f32, f32) {
        fn fold<T: Copy + Into<f32>>(row: &[T], r: (f32, f32)) -> (f32, f32) {
            row.iter().fold(r, |(a, b), &v| {
                let v = v.into();
                (a.min(v), b.max(v))
            })
        }
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
                r = match &*self.voxels {
                    Voxels::U8(v) => fold(&v[rows], r),
                    Voxels::I8(v) => fold(&v[rows], r),
                    Voxels::U16(v) => fold(&v[rows], r),
                    Voxels::I16(v) => fold(&v[rows], r),
                    Voxels::F32(v) => fold(&v[rows], r),
                };
            }
        }
        let (a, b) = (
            self.scale * r.0 + self.offset,
            self.scale * r.1 + self.offset,
        );
        (a.min(b), a.max(b))
    }

    #[inline]
    fn value_at(&self, i: usize) -> f32 {
        self.scale * self.voxels.get(i) + self.offset
    }

    #[inline]
    pub fn voxel(&self, x: u32, y: u32, z: u32) -> f32 {
        self.value_at(
            (x as usize) + self.dims.x as usize * (y as usize + self.dims.y as usize * z as usize),
        )
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
        let sy = self.dims.x as usize;
        let sz = sy * self.dims.y as usize;
        let corner = Corner {
            base: i0.x as usize + sy * i0.y as usize + sz * i0.z as usize,
            dx: (i1.x - i0.x) as usize,
            dy: (i1.y - i0.y) as usize * sy,
            dz: (i1.z - i0.z) as usize * sz,
        };
        // One branch on the stored type per lookup; the eight loads are monomorphic.
        let stored = match &*self.voxels {
            Voxels::U8(v) => trilinear(v, corner, f),
            Voxels::I8(v) => trilinear(v, corner, f),
            Voxels::U16(v) => trilinear(v, corner, f),
            Voxels::I16(v) => trilinear(v, corner, f),
            Voxels::F32(v) => trilinear(v, corner, f),
        };
        self.scale * stored + self.offset
    }
}

/// The first of a trilinear lookup's eight voxels and the steps to the others.
#[derive(Clone, Copy)]
struct Corner {
    base: usize,
    dx: usize,
    dy: usize,
    dz: usize,
}

#[inline(always)]
fn trilinear<T: Copy + Into<f32>>(v: &[T], c: Corner, f: Vec3) -> f32 {
    let at = |k: usize| -> f32 { v[k].into() };
    let Corner { base, dx, dy, dz } = c;
    let c000 = at(base);
    let c100 = at(base + dx);
    let c010 = at(base + dy);
    let c110 = at(base + dx + dy);
    let c001 = at(base + dz);
    let c101 = at(base + dx + dz);
    let c011 = at(base + dy + dz);
    let c111 = at(base + dx + dy + dz);
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
