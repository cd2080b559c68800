//! Clipping: an axis-aligned box and planes that cut the medium away, so the inside of a volume
//! can be seen (a CT's organs behind the ribs, a cell's nucleus).
//!
//! The kept region is the volume's box intersected with the clip box and with one half-space
//! per plane: an intersection of convex sets, so every ray meets it in one interval. Clipping
//! narrows the interval the tracker works in ([`crate::Medium::clip`]) and nothing else: free
//! flights, shadow rays and the cache's start points see no medium outside it, exactly, so the
//! estimators stay unbiased for the clipped volume (no density is faded or sampled away). The
//! cut faces are not lit specially: light enters the kept medium through them as through any
//! boundary, which is what cutting a real translucent object would do.
//!
//! Everything is given in world units (the scene's); the medium keeps it in its index space.

use crate::medium::IndexRay;
use glam::Vec3;
use render_base::MAX_COORDINATE;
use serde::{Deserialize, Serialize};

/// The most planes a scene may give: each costs every ray a dot product and a division.
pub const MAX_CLIP_PLANES: usize = 16;

/// The scene file's `[clip]` table: what is cut away, in world units.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Clipping {
    /// `box = { min = [x, y, z], max = [x, y, z] }`: only the medium inside is kept.
    #[serde(default, rename = "box", skip_serializing_if = "Option::is_none")]
    pub bounds: Option<ClipBox>,
    /// `[[clip.plane]]` tables: the medium on the side each plane's normal points to is cut
    /// away (as ParaView's clip filter does by default).
    #[serde(default, rename = "plane", skip_serializing_if = "Vec::is_empty")]
    pub planes: Vec<ClipPlane>,
}

/// An axis-aligned box, world units.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ClipBox {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

/// A plane through `point` with `normal` (any length but zero); the side the normal points to
/// is cut away.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ClipPlane {
    pub point: [f32; 3],
    pub normal: [f32; 3],
}

impl Clipping {
    /// Whether anything is cut away.
    pub fn is_empty(&self) -> bool {
        self.bounds.is_none() && self.planes.is_empty()
    }

    /// Checks every value, naming the field at fault: finite coordinates within the scene's
    /// limits, a box with `min < max` on every axis, non-zero normals, at most
    /// [`MAX_CLIP_PLANES`] planes.
    pub fn validate(&self) -> Result<(), String> {
        let within = |v: [f32; 3]| v.iter().all(|c| c.abs() <= MAX_COORDINATE);
        if let Some(b) = &self.bounds {
            // Written so that NaN fails.
            if !(within(b.min) && within(b.max)) {
                return Err(format!(
                    "clip box {:?} .. {:?}: expected finite coordinates within +-{MAX_COORDINATE:e}",
                    b.min, b.max
                ));
            }
            if !(0..3).all(|a| b.min[a] < b.max[a]) {
                return Err(format!(
                    "clip box min {:?}, max {:?}: expected min < max on every axis",
                    b.min, b.max
                ));
            }
        }
        if self.planes.len() > MAX_CLIP_PLANES {
            return Err(format!(
                "{} clip planes: expected at most {MAX_CLIP_PLANES}",
                self.planes.len()
            ));
        }
        for (i, p) in self.planes.iter().enumerate() {
            let n = Vec3::from_array(p.normal);
            if !(within(p.point) && n.is_finite() && n.length_squared() > 0.0) {
                return Err(format!(
                    "clip plane {i}: point {:?}, normal {:?}: expected finite coordinates within \
                     +-{MAX_COORDINATE:e} and a non-zero normal",
                    p.point, p.normal
                ));
            }
        }
        Ok(())
    }
}

/// [`Clipping`] in a medium's index space, ready for rays.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct IndexClip {
    /// The clip box in index units (the whole line where there is none).
    lo: Vec3,
    hi: Vec3,
    /// Per plane, `(n, d)`: index-space points `u` with `n . u > d` are cut away.
    planes: Vec<(Vec3, f32)>,
}

impl IndexClip {
    /// `clip` (validated) for a medium whose index space is `u = (x - origin) / spacing`.
    pub(crate) fn new(clip: &Clipping, origin: Vec3, spacing: Vec3) -> Self {
        let (lo, hi) = clip
            .bounds
            .map_or((Vec3::NEG_INFINITY, Vec3::INFINITY), |b| {
                (
                    (Vec3::from_array(b.min) - origin) / spacing,
                    (Vec3::from_array(b.max) - origin) / spacing,
                )
            });
        // n . x > n . p with x = origin + spacing * u: (n * spacing) . u > n . (p - origin).
        let planes = clip
            .planes
            .iter()
            .map(|p| {
                let n = Vec3::from_array(p.normal).normalize();
                (n * spacing, n.dot(Vec3::from_array(p.point) - origin))
            })
            .collect();
        Self { lo, hi, planes }
    }

    /// `[t0, t1]` narrowed to where the ray is in the kept region; `None` where it never is.
    #[inline]
    pub(crate) fn narrow(&self, r: &IndexRay, mut t0: f32, mut t1: f32) -> Option<(f32, f32)> {
        for a in 0..3 {
            if r.d[a] == 0.0 {
                if !(r.o[a] >= self.lo[a] && r.o[a] <= self.hi[a]) {
                    return None;
                }
            } else {
                let inv = 1.0 / r.d[a];
                let ta = (self.lo[a] - r.o[a]) * inv;
                let tb = (self.hi[a] - r.o[a]) * inv;
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        for &(n, d) in &self.planes {
            // Along the ray, n . u(t) = start + rate t is cut away above d.
            let (start, rate) = (n.dot(r.o), n.dot(r.d));
            if rate == 0.0 {
                if !(start <= d) {
                    return None;
                }
            } else {
                let t = (d - start) / rate;
                if rate > 0.0 {
                    t1 = t1.min(t);
                } else {
                    t0 = t0.max(t);
                }
            }
        }
        // Written so that NaN bounds mean no overlap.
        (t0 < t1).then_some((t0, t1))
    }

    /// Whether index-space point `u` is kept.
    #[inline]
    pub(crate) fn keeps(&self, u: Vec3) -> bool {
        u.cmpge(self.lo).all()
            && u.cmple(self.hi).all()
            && self.planes.iter().all(|&(n, d)| n.dot(u) <= d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(point: [f32; 3], normal: [f32; 3]) -> ClipPlane {
        ClipPlane { point, normal }
    }

    #[test]
    fn a_ray_keeps_the_interval_inside_the_box_and_behind_every_plane() {
        // Index space = world space shifted by -1 and halved.
        let (origin, spacing) = (Vec3::ONE, Vec3::splat(2.0));
        let clip = Clipping {
            bounds: Some(ClipBox {
                min: [-9.0, -9.0, -3.0],
                max: [9.0, 9.0, 5.0],
            }),
            planes: vec![plane([0.0, 0.0, 4.0], [0.0, 0.0, 3.0])],
        };
        clip.validate().unwrap();
        let index = IndexClip::new(&clip, origin, spacing);
        // A world ray along +z from z = -10, parameterised by world distance.
        let ray = IndexRay {
            o: (Vec3::new(0.0, 0.0, -10.0) - origin) / spacing,
            d: Vec3::Z / spacing,
        };
        let (t0, t1) = index.narrow(&ray, 0.0, f32::INFINITY).unwrap();
        // Kept: z from -3 (the box) to 4 (the plane cuts z > 4): t from 7 to 14.
        assert!(
            (t0 - 7.0).abs() < 1e-5 && (t1 - 14.0).abs() < 1e-5,
            "{t0} {t1}"
        );
        assert!(index.keeps(ray.at(10.0)) && !index.keeps(ray.at(15.0)));
        // The other way the plane cuts from the ray's start.
        let back = IndexRay {
            o: (Vec3::new(0.0, 0.0, 10.0) - origin) / spacing,
            d: -Vec3::Z / spacing,
        };
        let (t0, t1) = index.narrow(&back, 0.0, f32::INFINITY).unwrap();
        assert!(
            (t0 - 6.0).abs() < 1e-5 && (t1 - 13.0).abs() < 1e-5,
            "{t0} {t1}"
        );
        // Parallel to the plane on its cut side: nothing; on its kept side: the box's interval.
        let across = |z: f32| IndexRay {
            o: (Vec3::new(-20.0, 0.0, z) - origin) / spacing,
            d: Vec3::X / spacing,
        };
        assert_eq!(index.narrow(&across(4.5), 0.0, f32::INFINITY), None);
        let (t0, t1) = index.narrow(&across(3.5), 0.0, f32::INFINITY).unwrap();
        assert!(
            (t0 - 11.0).abs() < 1e-5 && (t1 - 29.0).abs() < 1e-5,
            "{t0} {t1}"
        );
    }

    #[test]
    fn bad_clipping_is_named() {
        let bad_box = Clipping {
            bounds: Some(ClipBox {
                min: [0.0, 0.0, 1.0],
                max: [1.0, 1.0, 1.0],
            }),
            planes: vec![],
        };
        assert!(bad_box.validate().unwrap_err().contains("min < max"));
        let nan = Clipping {
            bounds: None,
            planes: vec![plane([0.0; 3], [f32::NAN, 0.0, 1.0])],
        };
        assert!(nan.validate().unwrap_err().contains("clip plane 0"));
        let zero = Clipping {
            bounds: None,
            planes: vec![plane([0.0; 3], [0.0; 3])],
        };
        assert!(zero.validate().unwrap_err().contains("non-zero normal"));
        let many = Clipping {
            bounds: None,
            planes: vec![plane([0.0; 3], [0.0, 0.0, 1.0]); MAX_CLIP_PLANES + 1],
        };
        assert!(many.validate().unwrap_err().contains("at most"));
        assert!(Clipping::default().is_empty());
    }
}
