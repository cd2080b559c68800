//! Probing: where a ray first meets visible medium, and the data there (the viewer's click on
//! the image).
//!
//! "Visible" is said by the light, not by a threshold on the data: the ray is marched through
//! the kept medium (the volume's box, less what clipping cuts away) in steps of a quarter of the
//! smallest voxel side, summing the optical depth the transfer function gives, and the probe
//! stops where [`VISIBLE_FRACTION`] of the light has been taken out. Deterministic (no random
//! numbers), so a click always reports the same point. The value reported is the voxel lookup's
//! there (the nearest voxel's stored value), beside the filtered value the tracker sees.

use crate::medium::Medium;
use glam::{UVec3, Vec3};

/// The fraction of the light along the ray that the medium before the probed point has taken out.
pub const VISIBLE_FRACTION: f32 = 0.05;

/// The most steps a probe takes (a 2048-voxel diagonal is about 14,000).
const MAX_STEPS: usize = 1 << 20;

/// What a ray met.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Probe {
    /// Distance along the ray (world units, the direction normalised).
    pub distance: f32,
    /// The point, world units.
    pub position: Vec3,
    /// The voxel it lies in (x, y, z).
    pub voxel: UVec3,
    /// That voxel's stored value (what a voxel lookup gives).
    pub value: f32,
    /// The value the tracker sees there (the scene's filter).
    pub filtered: f32,
    /// The transfer function's opacity at the filtered value.
    pub opacity: f32,
}

impl Medium {
    /// Where the ray from `origin` along `direction` first has [`VISIBLE_FRACTION`] of its
    /// light taken out by the kept medium; `None` where it passes with less (or misses the
    /// box, or `direction` is zero or not finite).
    pub fn probe(&self, origin: Vec3, direction: Vec3) -> Option<Probe> {
        let d = direction.try_normalize()?;
        if !origin.is_finite() {
            return None;
        }
        let ray = self.to_index_ray(origin, d);
        let (t0, t1) = self.clip(&ray, 0.0, f32::INFINITY)?;
        let spacing = self.spacing();
        let step = 0.25 * spacing.min_element();
        let needed = -(1.0 - VISIBLE_FRACTION).ln();
        let tf = self.transfer_function();
        let mut depth = 0.0f32;
        let mut k = 0usize;
        loop {
            // The midpoint of each step, so a thin layer is not stepped over at its edge.
            let t = t0 + (k as f32 + 0.5) * step;
            if !(t < t1) || k >= MAX_STEPS {
                return None;
            }
            let u = ray.at(t);
            let filtered = self.value(u);
            depth += self.extinction_with(filtered, u) * step;
            if depth >= needed {
                let dims = self.grid().dims();
                let voxel = u.floor().max(Vec3::ZERO).as_uvec3().min(dims - UVec3::ONE);
                return Some(Probe {
                    distance: t,
                    position: origin + d * t,
                    voxel,
                    value: self.grid().voxel(voxel.x, voxel.y, voxel.z),
                    filtered,
                    opacity: tf.opacity_at(tf.normalise(filtered)),
                });
            }
            k += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::{Filter, Medium, ScalarGrid, TransferFunction};
    use glam::{UVec3, Vec3};

    /// A 32^3 volume of spacing 2 (box [-32, 32]^3): value 10 where x < 16 voxels, 200 beyond,
    /// opacity 0 below the window's middle and 1 above, extinction 5 per unit at opacity 1.
    fn half_full() -> Medium {
        let n = 32u32;
        let values = (0..n * n * n)
            .map(|i| if i % n < 16 { 10.0 } else { 200.0 })
            .collect();
        let grid = ScalarGrid::new(UVec3::splat(n), values).unwrap();
        let tf = TransferFunction::from_points(
            (0.0, 255.0),
            &[
                (0.0, Vec3::ONE, 0.0),
                (0.5, Vec3::ONE, 0.0),
                (0.5001, Vec3::ONE, 1.0),
                (1.0, Vec3::ONE, 1.0),
            ],
            5.0,
        )
        .unwrap();
        Medium::new(
            grid,
            Filter::Nearest,
            Vec3::splat(-32.0),
            Vec3::splat(2.0),
            tf,
            8,
        )
        .unwrap()
    }

    #[test]
    fn a_probe_stops_where_the_visible_medium_begins() {
        let medium = half_full();
        // From -x: the opaque half starts at x = 0 (voxel 16); 5% of the light is gone
        // -ln(0.95) / 5 = 0.0103 units in, within the first step (0.5 units).
        let p = medium
            .probe(Vec3::new(-100.0, 0.3, 0.7), Vec3::X)
            .expect("the ray meets the opaque half");
        assert!(p.position.x >= 0.0 && p.position.x <= 0.5, "{p:?}");
        assert_eq!((p.voxel.x, p.value, p.opacity), (16, 200.0, 1.0));
        assert_eq!(
            p.value,
            medium.grid().voxel(p.voxel.x, p.voxel.y, p.voxel.z)
        );
        assert!((p.distance - (p.position.x + 100.0)).abs() < 1e-3);
        // Through the transparent half only (along y in x < 0): nothing.
        assert_eq!(medium.probe(Vec3::new(-10.0, -100.0, 0.0), Vec3::Y), None);
        // Missing the box, and a zero direction: nothing.
        assert_eq!(medium.probe(Vec3::new(-100.0, 50.0, 0.0), Vec3::X), None);
        assert_eq!(medium.probe(Vec3::ZERO, Vec3::ZERO), None);
    }

    #[test]
    fn a_probe_sees_the_clipped_volume() {
        let mut medium = half_full();
        // Cut x < 10 away: the probe starts at the cut, inside the opaque half.
        medium
            .set_clipping(crate::Clipping {
                bounds: None,
                planes: vec![crate::ClipPlane {
                    point: [10.0, 0.0, 0.0],
                    normal: [-1.0, 0.0, 0.0],
                }],
            })
            .unwrap();
        let p = medium.probe(Vec3::new(-100.0, 0.0, 0.0), Vec3::X).unwrap();
        assert!(p.position.x >= 10.0 && p.position.x <= 10.5, "{p:?}");
        assert_eq!(p.voxel.x, 21);
    }
}
