//! The scalar grid: voxel values in memory and their reconstruction at a point.
//!
//! Convention (DESIGN.md): a grid of `dims` voxels occupies the box `[0, dims)` in index space;
//! voxel `(i, j, k)` is a sample at the cell centre `(i + 0.5, j + 0.5, k + 0.5)`. Between centres
//! the scalar is interpolated trilinearly; outside the outermost centres it is clamped to the edge
//! voxel, so the whole box is filled and density does not fade towards the faces.
//! Values are stored as f32 (4 bytes per voxel): every supported dtype converts exactly except
//! f64, which is rounded.

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

/// A dense scalar grid, x fastest: voxel `(x, y, z)` is element `x + X * (y + Y * z)`.
#[derive(Debug, Clone)]
pub struct ScalarGrid {
    dims: UVec3,
    values: Vec<f32>,
    range: (f32, f32),
}

impl ScalarGrid {
    /// A grid from voxel values; fails on a size mismatch or a non-finite value.
    pub fn new(dims: UVec3, values: Vec<f32>) -> Result<Self> {
        let n = dims.x as u64 * dims.y as u64 * dims.z as u64;
        if n == 0 {
            return Err(Error::Invalid(format!(
                "volume dims {}x{}x{} hold no voxel: every dimension must be at least 1",
                dims.x, dims.y, dims.z
            )));
        }
        if n != values.len() as u64 {
            return Err(Error::Invalid(format!(
                "volume dims {}x{}x{} need {n} voxels, got {}",
                dims.x,
                dims.y,
                dims.z,
                values.len()
            )));
        }
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for (i, &v) in values.iter().enumerate() {
            if !v.is_finite() {
                let x = i as u64 % dims.x as u64;
                let y = (i as u64 / dims.x as u64) % dims.y as u64;
                let z = i as u64 / (dims.x as u64 * dims.y as u64);
                return Err(Error::Invalid(format!(
                    "voxel ({x}, {y}, {z}) is {v}: every voxel must be a finite number"
                )));
            }
            lo = lo.min(v);
            hi = hi.max(v);
        }
        Ok(Self {
            dims,
            values,
            range: (lo, hi),
        })
    }

    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Smallest and largest voxel value.
    pub fn range(&self) -> (f32, f32) {
        self.range
    }

    #[inline]
    pub fn voxel(&self, x: u32, y: u32, z: u32) -> f32 {
        self.values
            [(x as usize) + self.dims.x as usize * (y as usize + self.dims.y as usize * z as usize)]
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
        let sx = 1usize;
        let sy = self.dims.x as usize;
        let sz = sy * self.dims.y as usize;
        let base = i0.x as usize + sy * i0.y as usize + sz * i0.z as usize;
        let dx = (i1.x - i0.x) as usize * sx;
        let dy = (i1.y - i0.y) as usize * sy;
        let dz = (i1.z - i0.z) as usize * sz;
        let v = &self.values;
        let c000 = v[base];
        let c100 = v[base + dx];
        let c010 = v[base + dy];
        let c110 = v[base + dx + dy];
        let c001 = v[base + dz];
        let c101 = v[base + dx + dz];
        let c011 = v[base + dy + dz];
        let c111 = v[base + dx + dy + dz];
        let x00 = c000 + f.x * (c100 - c000);
        let x10 = c010 + f.x * (c110 - c010);
        let x01 = c001 + f.x * (c101 - c001);
        let x11 = c011 + f.x * (c111 - c011);
        let y0 = x00 + f.y * (x10 - x00);
        let y1 = x01 + f.y * (x11 - x01);
        y0 + f.z * (y1 - y0)
    }
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

    #[test]
    fn non_finite_voxels_and_bad_sizes_are_rejected() {
        let e = ScalarGrid::new(UVec3::new(2, 1, 1), vec![0.0, f32::NAN]).unwrap_err();
        assert!(e.to_string().contains("voxel (1, 0, 0) is NaN"), "{e}");
        assert!(ScalarGrid::new(UVec3::new(2, 2, 1), vec![0.0; 3]).is_err());
        assert!(ScalarGrid::new(UVec3::new(0, 2, 1), vec![]).is_err());
    }
}
