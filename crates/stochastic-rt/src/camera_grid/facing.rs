//! The terms a Gaussian shares across the camera's rays (see the module docs' **A ray's
//! alphas**): the camera's frame, a Gaussian's canonical frame seen from it, and a row's
//! linear terms.

use super::*;

/// The camera's centre and axes in f64, for [`Seen::new`].
pub(super) struct CameraFrame {
    pub(super) position: DVec3,
    /// Camera-space axes (+X right, +Y down, +Z forward) in world space, as columns.
    pub(super) axes: DMat3,
}

impl CameraFrame {
    pub(super) fn new(camera: &Camera) -> Self {
        Self {
            position: camera.position.as_dvec3(),
            axes: DMat3::from_quat(camera.rotation.as_dquat()),
        }
    }
}

/// What one Gaussian's alpha on any of the camera's rays needs (made in f64, kept in f32).
///
/// A ray through the plane point `(u, w)` has camera-space direction `v = (u, w, 1)`; in the
/// Gaussian's canonical frame (`C = S^-1 R^T`, [`TraceGaussians::canonical`]) it is
/// `K v = u K_x + w K_y + K_z`, with `K_*` the camera's axes there. The squared canonical
/// distance of the line from the centre is `|o x K v|^2 / |K v|^2` for `o = C (camera - mean)`,
/// and `o x K v = u M_x + w M_y + M_z` with `M_* = o x K_*`: on a row, both vectors are linear
/// in `u`. The cross product keeps the precision the closest point has (no difference of two
/// large squares).
#[derive(Clone, Copy, Default)]
pub(super) struct Facing {
    /// `K_x`, `K_y`, `K_z`.
    pub(super) axes: [Vec3; 3],
    /// `M_x`, `M_y`, `M_z`.
    pub(super) moments: [Vec3; 3],
    pub(super) opacity: f32,
    /// The squared canonical distance beyond which alpha is below 1/255.
    pub(super) cutoff: f32,
    /// Its colour seen from the camera.
    pub(super) color: Vec3,
}

impl Facing {
    pub(super) fn new(g: &TraceGaussians, i: usize, frame: &CameraFrame) -> Self {
        Self::seen(g, i, &Seen::new(g, i, frame), frame)
    }

    /// [`Facing::new`] from the terms the silhouette shares ([`Seen`]).
    #[inline(always)]
    pub(super) fn seen(g: &TraceGaussians, i: usize, seen: &Seen, frame: &CameraFrame) -> Self {
        let (o, axes) = (seen.offset, seen.axes);
        Self {
            axes: axes.map(|k| k.as_vec3()),
            moments: axes.map(|k| o.cross(k).as_vec3()),
            opacity: g.opacity[i],
            cutoff: g.cutoff[i],
            color: g.color(i, frame.position.as_vec3()),
        }
    }
}

/// A Gaussian's canonical frame (`C = S^-1 R^T`) seen from the camera, in f64: what its
/// silhouette ([`Screen::silhouette`]) and its facing terms ([`Facing`]) share, made once.
pub(super) struct Seen {
    /// `o = C (camera - mean)`.
    pub(super) offset: DVec3,
    /// The camera's axes in the canonical frame: `K_x`, `K_y`, `K_z`.
    pub(super) axes: [DVec3; 3],
}

impl Seen {
    #[inline(always)]
    pub(super) fn new(g: &TraceGaussians, i: usize, frame: &CameraFrame) -> Self {
        let rows = g.canonical[i].map(|r| r.as_dvec3());
        let in_canonical = |v: DVec3| DVec3::new(rows[0].dot(v), rows[1].dot(v), rows[2].dot(v));
        Self {
            offset: in_canonical(frame.position - g.means[i].as_dvec3()),
            axes: [frame.axes.x_axis, frame.axes.y_axis, frame.axes.z_axis].map(in_canonical),
        }
    }
}

/// A [`Facing`] on one row (`w` fixed): `K v` and `o x K v` as `u` times a slope plus a base.
pub(super) struct FacingRow {
    pub(super) slope: Vec3,
    pub(super) base: Vec3,
    pub(super) moment_slope: Vec3,
    pub(super) moment_base: Vec3,
    pub(super) opacity: f32,
    pub(super) cutoff: f32,
}

impl FacingRow {
    #[inline(always)]
    pub(super) fn new(f: &Facing, w: f32) -> Self {
        Self {
            slope: f.axes[0],
            base: f.axes[1] * w + f.axes[2],
            moment_slope: f.moments[0],
            moment_base: f.moments[1] * w + f.moments[2],
            opacity: f.opacity,
            cutoff: f.cutoff,
        }
    }

    /// The alphas on the rays through `u` (a lane each): `min(0.99, opacity e^(-d/2))` at the
    /// squared canonical distance `d`, and 0 where `d` is beyond the cut-off, the alpha below
    /// 1/255, or anything is not finite. Every lane computes what one ray alone gives.
    #[inline(always)]
    pub(super) fn alpha<L: Lanes>(&self, token: L::Token, u: L) -> L {
        let c = |v: f32| L::splat(token, v);
        let (s, b, ms, mb) = (self.slope, self.base, self.moment_slope, self.moment_base);
        let (kx, ky, kz) = (
            u.mul_add(c(s.x), c(b.x)),
            u.mul_add(c(s.y), c(b.y)),
            u.mul_add(c(s.z), c(b.z)),
        );
        let (mx, my, mz) = (
            u.mul_add(c(ms.x), c(mb.x)),
            u.mul_add(c(ms.y), c(mb.y)),
            u.mul_add(c(ms.z), c(mb.z)),
        );
        let along = kz.mul_add(kz, ky.mul_add(ky, kx * kx));
        let distance = mz.mul_add(mz, my.mul_add(my, mx * mx)) / along;
        let falloff = exp::<L>(token, distance * c(-0.5));
        let alpha = (c(self.opacity) * falloff).min(c(ALPHA_MAX as f32));
        // NaN fails both comparisons.
        let hit = distance.le(c(self.cutoff)) & alpha.ge(c(ALPHA_MIN as f32));
        L::keep(hit, alpha)
    }

    /// [`FacingRow::alpha`] on the one ray through `u`, in `isa`'s lanes (the walk's own).
    pub(super) fn alpha_on(&self, isa: Isa, u: f32) -> f32 {
        let mut out = [0.0f32; 8];
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2Fma(token) => self
                .alpha::<Avx2>(token, Avx2::splat(token, u))
                .store(&mut out),
            Isa::Baseline => self
                .alpha::<Baseline>((), Baseline::splat((), u))
                .store(&mut out),
        }
        out[0]
    }
}
