//! The Gaussians placed on the screen: each silhouette's extent in pixels and bands, four at a
//! time in f64 lanes ([`super::wide`]), the scalar placement kept as their definition.

use super::*;

/// 2^23: a whole number `n` in `0..2^23` plus this is a float whose bits are
/// [`PIXEL_BIAS_BITS`] plus `n`, so a pixel's index goes from lanes to an integer without a
/// conversion.
pub(super) const PIXEL_BIAS: f32 = 8_388_608.0;
pub(super) const PIXEL_BIAS_BITS: u32 = PIXEL_BIAS.to_bits();

/// One Gaussian on the screen.
#[derive(Clone, Copy, Default)]
pub(super) struct Placed {
    /// Its silhouette's centre: the pixels `p` with `(p - centre)^T Q (p - centre) <= 1` are
    /// those whose rays meet its alpha >= 1/255 ellipsoid ([`Screen::silhouette`]).
    pub(super) centre: [f32; 2],
    /// The pixel columns and rows (inclusive) its silhouette may cover.
    pub(super) columns: [u32; 2],
    pub(super) rows: [u32; 2],
    /// The silhouette's chords by row ([`Placed::chord_terms`]); zero where no bounded
    /// silhouette exists (a box reaching behind the camera, or rounding): every pixel of its
    /// rectangle is evaluated.
    pub(super) chord_terms: [f32; 3],
}

impl Placed {
    /// The terms of [`ListedChunk::chords`] for the silhouette's quadratic form (xx, xy, yy): the
    /// ellipse `a dx^2 + 2 b dy dx + c dy^2 <= s`, grown to `s =` [`SILHOUETTE_SLACK`], meets
    /// the row at `dy` from its centre where `dx = k3 dy +- sqrt(k1 dy^2 + k2)`, with
    /// `k1 = (b^2 - a c) / a^2`, `k2 = s / a` and `k3 = -b / a`; `k2 = 0` where there is no
    /// bounded silhouette (every column of the rectangle is walked). Solved in f64, rounded to
    /// f32 and evaluated in f32; the growth and a pixel's widening each way cover the
    /// rounding of the chord and of the rays' own distances.
    #[inline(always)]
    #[cfg(test)]
    pub(super) fn chord_terms(form: [f64; 3]) -> [f32; 3] {
        let [a, b, c] = form;
        let terms = [(b * b - a * c) / (a * a), SILHOUETTE_SLACK / a, -b / a].map(|k| k as f32);
        Self::checked_chord_terms(a, terms)
    }

    /// [`Placed::chord_terms`] from its terms (rounded to f32) and the form's `a`: zero unless
    /// `a > 0`, the terms are finite and `k2 > 0`.
    #[inline(always)]
    pub(super) fn checked_chord_terms(a: f64, terms: [f32; 3]) -> [f32; 3] {
        if a > 0.0 && terms.iter().all(|k| k.is_finite()) && terms[1] > 0.0 {
            terms
        } else {
            [0.0; 3]
        }
    }
}

/// The camera's constants for placing Gaussians on its screen.
pub(super) struct Screen {
    /// The camera's centre and axes (its centre is the one `place` measures from).
    pub(super) frame: CameraFrame,
    /// World to camera space (+X right, +Y down, +Z forward).
    pub(super) to_camera: glam::DMat3,
    pub(super) focal: f64,
    pub(super) half: [f64; 2],
    pub(super) size: [f64; 2],
}

impl Screen {
    pub(super) fn new(camera: &Camera) -> Self {
        Self {
            frame: CameraFrame::new(camera),
            to_camera: glam::DMat3::from_quat(camera.rotation.as_dquat().inverse()),
            focal: camera.focal_pixels() as f64,
            half: [0.5 * camera.width as f64, 0.5 * camera.height as f64],
            size: [camera.width as f64, camera.height as f64],
        }
    }

    /// Gaussian `i` (centre depth `depth`) on the screen, with its facing terms: the pixel
    /// rectangle of its silhouette (of its box's corners where it has no bounded silhouette);
    /// the whole screen when its box reaches behind the camera's plane; `None` when its centre
    /// is not in front of the camera (`intersect` never places a hit there) or it is off the
    /// screen.
    ///
    /// The definition [`Screen::place4`] computes four at a time (tested bit for bit).
    #[cfg(test)]
    pub(super) fn place(
        &self,
        g: &TraceGaussians,
        i: usize,
        depth: f32,
    ) -> Option<(Placed, Facing)> {
        if !(depth > 0.0) {
            return None;
        }
        let [w, h] = self.size;
        let everywhere = Placed {
            centre: [0.0; 2],
            columns: [0, w as u32 - 1],
            rows: [0, h as u32 - 1],
            chord_terms: [0.0; 3],
        };
        let seen = Seen::new(g, i, &self.frame);
        let facing = || Facing::seen(g, i, &seen, &self.frame);
        let (lo, hi) = (g.lower[i].as_dvec3(), g.upper[i].as_dvec3());
        // The box's nearest corner's depth: its centre's, less its half-extents along the
        // camera's forward axis.
        let forward = self.to_camera.row(2);
        let nearest =
            forward.dot(0.5 * (lo + hi) - self.frame.position) - forward.abs().dot(0.5 * (hi - lo));
        if !(nearest > NEAR as f64) {
            return Some((everywhere, facing()));
        }
        let mut placed = everywhere;
        let [u0, u1, v0, v1] = match self.silhouette(&seen, g.cutoff[i]) {
            Some((centre, form, reach)) => {
                placed.centre = [centre[0] as f32, centre[1] as f32];
                placed.chord_terms = Placed::chord_terms(form);
                [
                    centre[0] - reach[0],
                    centre[0] + reach[0],
                    centre[1] - reach[1],
                    centre[1] + reach[1],
                ]
            }
            None => self.box_rectangle(lo, hi),
        };
        // The pixels whose centres the rectangle covers, a pixel wider each way for rounding.
        placed.columns = pixel_span(u0 - 1.5, u1 + 0.5, w)?;
        placed.rows = pixel_span(v0 - 1.5, v1 + 0.5, h)?;
        Some((placed, facing()))
    }

    /// [`Screen::place`] for the Gaussians `ranked` (indices) into `placed` and `facing`, four
    /// at a time ([`Screen::place4`]), in code compiled for `isa`. A Gaussian off the screen
    /// (or behind the camera) is `None`; its facing terms are written all the same.
    pub(super) fn place_block_on(
        &self,
        isa: Isa,
        g: &TraceGaussians,
        depth_of: &(impl Fn(usize) -> f32 + Sync),
        ranked: &[u32],
        placed: &mut [Option<Placed>],
        facing: &mut [Facing],
    ) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: an `Avx2Token` exists only where the processor runs AVX2 and FMA
            // (`Avx2Token::detect`), which is all `place_block_avx2_fma` requires.
            Isa::Avx2Fma(_) => unsafe {
                self.place_block_avx2_fma(g, depth_of, ranked, placed, facing)
            },
            Isa::Baseline => self.place_block(g, depth_of, ranked, placed, facing),
        }
    }

    /// [`Screen::place_block_on`] compiled for AVX2 and FMA: [`Wide`]'s lanes become vectors,
    /// the arithmetic the same (Rust fuses no multiply-add unasked).
    ///
    /// # Safety
    /// The processor must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn place_block_avx2_fma(
        &self,
        g: &TraceGaussians,
        depth_of: &(impl Fn(usize) -> f32 + Sync),
        ranked: &[u32],
        placed: &mut [Option<Placed>],
        facing: &mut [Facing],
    ) {
        self.place_block(g, depth_of, ranked, placed, facing)
    }

    #[inline(always)]
    pub(super) fn place_block(
        &self,
        g: &TraceGaussians,
        depth_of: &(impl Fn(usize) -> f32 + Sync),
        ranked: &[u32],
        placed: &mut [Option<Placed>],
        facing: &mut [Facing],
    ) {
        let groups = ranked
            .chunks(4)
            .zip(placed.chunks_mut(4).zip(facing.chunks_mut(4)));
        for (four, (placed, facing)) in groups {
            // A short last group repeats its last Gaussian in the spare lanes.
            let last = four.len() - 1;
            let at = |l: usize| four[l.min(last)] as usize;
            let indices = [at(0), at(1), at(2), at(3)];
            let depths = [
                depth_of(indices[0]),
                depth_of(indices[1]),
                depth_of(indices[2]),
                depth_of(indices[3]),
            ];
            self.place4(g, indices, depths, placed, facing);
        }
    }

    /// [`Screen::place`] for four Gaussians (`indices`, centre depths `depths`; a depth not
    /// above 0 gives `None`) into `placed` and `facing` (the first `placed.len()` of them), bit
    /// for bit: [`Seen::new`]'s, [`Screen::silhouette`]'s and [`Facing::seen`]'s arithmetic in
    /// f64 lanes, the same operations in the same order; then each lane's branches.
    #[inline(always)]
    pub(super) fn place4(
        &self,
        g: &TraceGaussians,
        indices: [usize; 4],
        depths: [f32; 4],
        placed: &mut [Option<Placed>],
        facing: &mut [Facing],
    ) {
        let frame = &self.frame;
        // Seen::new.
        let row = |r: usize| Wide3::from_fn(|l| g.canonical[indices[l]][r]);
        let rows = [row(0), row(1), row(2)];
        let in_canonical = |v: Wide3| Wide3 {
            x: rows[0].dot(v),
            y: rows[1].dot(v),
            z: rows[2].dot(v),
        };
        let in_canonical_one = |v: DVec3| Wide3 {
            x: rows[0].dot_one(v),
            y: rows[1].dot_one(v),
            z: rows[2].dot_one(v),
        };
        let position = Wide3::splat(frame.position);
        let offset = in_canonical(position - Wide3::from_fn(|l| g.means[indices[l]]));
        let axes = [
            in_canonical_one(frame.axes.x_axis),
            in_canonical_one(frame.axes.y_axis),
            in_canonical_one(frame.axes.z_axis),
        ];
        // The box's nearest corner's depth ([`Screen::place`]).
        let (lo, hi) = (
            Wide3::from_fn(|l| g.lower[indices[l]]),
            Wide3::from_fn(|l| g.upper[indices[l]]),
        );
        let forward = self.to_camera.row(2);
        let nearest = (0.5 * (lo + hi) - position).dot_one(forward)
            - (0.5 * (hi - lo)).dot_one(forward.abs());
        // Screen::silhouette.
        let (a, k) = (offset, axes);
        let outside = a.dot(a) - Wide::from_fn(|l| g.cutoff[indices[l]] as f64);
        let gv = [k[0].dot(a), k[1].dot(a), k[2].dot(a)];
        let entry = |r: usize, c: usize| outside * k[r].dot(k[c]) - gv[r] * gv[c];
        let (p00, p01, p11) = (entry(0, 0), entry(0, 1), entry(1, 1));
        let (p02, p12, p22) = (entry(0, 2), entry(1, 2), entry(2, 2));
        let det = p00 * p11 - p01 * p01;
        let (i00, i01, i11) = (p11 / det, -p01 / det, p00 / det);
        let u0 = [-(i00 * p02 + i01 * p12), -(i01 * p02 + i11 * p12)];
        let kk = p02 * (i00 * p02 + i01 * p12) + p12 * (i01 * p02 + i11 * p12) - p22;
        let f = self.focal;
        let scale = 1.0 / (f * f * kk);
        let form = [p00 * scale, p01 * scale, p11 * scale];
        let centre = [self.half[0] + f * u0[0], self.half[1] + f * u0[1]];
        let slack = SILHOUETTE_SLACK;
        let reach = [
            (f * f * kk * i00 * slack).sqrt(),
            (f * f * kk * i11 * slack).sqrt(),
        ];
        // Facing::seen.
        let moments = [
            offset.cross(axes[0]),
            offset.cross(axes[1]),
            offset.cross(axes[2]),
        ];
        // And what each lane keeps, rounded to f32 in lanes: the facing terms, the
        // silhouette's centre and [`Placed::chord_terms`]'s terms (its operations).
        let axes32 = [axes[0].to_f32(), axes[1].to_f32(), axes[2].to_f32()];
        let moments32 = [
            moments[0].to_f32(),
            moments[1].to_f32(),
            moments[2].to_f32(),
        ];
        let centre32 = [centre[0].to_f32(), centre[1].to_f32()];
        let [fa, fb, fc] = form;
        let terms = [
            ((fb * fb - fa * fc) / (fa * fa)).to_f32(),
            (SILHOUETTE_SLACK / fa).to_f32(),
            (-fb / fa).to_f32(),
        ];
        // The silhouette's rectangle, a pixel wider each way (as `place` widens it).
        let rectangle = [
            centre[0] - reach[0] - 1.5,
            centre[0] + reach[0] + 0.5,
            centre[1] - reach[1] - 1.5,
            centre[1] + reach[1] + 0.5,
        ];
        let eye = frame.position.as_vec3();
        let [w, h] = self.size;
        for (l, (slot, facing)) in placed.iter_mut().zip(facing).enumerate() {
            let (i, depth) = (indices[l], depths[l]);
            *facing = Facing {
                axes: [axes32[0].lane(l), axes32[1].lane(l), axes32[2].lane(l)],
                moments: [
                    moments32[0].lane(l),
                    moments32[1].lane(l),
                    moments32[2].lane(l),
                ],
                opacity: g.opacity[i],
                cutoff: g.cutoff[i],
                color: g.color(i, eye),
            };
            if !(depth > 0.0) {
                *slot = None;
                continue;
            }
            let mut placed = Placed {
                centre: [0.0; 2],
                columns: [0, w as u32 - 1],
                rows: [0, h as u32 - 1],
                chord_terms: [0.0; 3],
            };
            if !(nearest.0[l] > NEAR as f64) {
                *slot = Some(placed);
                continue;
            }
            let bounded = outside.0[l] > 0.0
                && p00.0[l] > 0.0
                && det.0[l] > 0.0
                && kk.0[l] > 0.0
                && [
                    form[0], form[1], form[2], centre[0], centre[1], reach[0], reach[1],
                ]
                .iter()
                .all(|v| v.0[l].is_finite());
            let [u0, u1, v0, v1] = if bounded {
                placed.centre = [centre32[0][l], centre32[1][l]];
                placed.chord_terms =
                    Placed::checked_chord_terms(fa.0[l], [terms[0][l], terms[1][l], terms[2][l]]);
                rectangle.map(|v| v.0[l])
            } else {
                let [u0, u1, v0, v1] = self.box_rectangle(lo.lane(l), hi.lane(l));
                [u0 - 1.5, u1 + 0.5, v0 - 1.5, v1 + 0.5]
            };
            // The pixels whose centres the rectangle covers.
            *slot = pixel_span(u0, u1, w)
                .zip(pixel_span(v0, v1, h))
                .map(|(columns, rows)| {
                    placed.columns = columns;
                    placed.rows = rows;
                    placed
                });
        }
    }

    /// The screen rectangle [u0, u1, v0, v1] of a box wholly in front of the camera: its
    /// corners' projections' bounds. For the Gaussians without a bounded silhouette.
    pub(super) fn box_rectangle(&self, lo: DVec3, hi: DVec3) -> [f64; 4] {
        let mut rectangle = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for k in 0..8 {
            let corner = DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            let c = self.to_camera * (corner - self.frame.position);
            let (u, v) = (
                self.half[0] + self.focal * c.x / c.z,
                self.half[1] + self.focal * c.y / c.z,
            );
            let [u0, u1, v0, v1] = rectangle;
            rectangle = [u0.min(u), u1.max(u), v0.min(v), v1.max(v)];
        }
        rectangle
    }

    /// Gaussian `i`'s silhouette on the screen, in f64: its centre, its quadratic form
    /// (xx, xy, yy) and its half-extents grown by [`SILHOUETTE_SLACK`]; `None` when it is not a
    /// bounded ellipse (the camera inside the ellipsoid, or rounding).
    ///
    /// A ray `o + t d` meets the ellipsoid `|C (x - m)|^2 <= cutoff` when its closest canonical
    /// distance is inside: `|a|^2 |b|^2 - (a . b)^2 <= cutoff |b|^2` with `a = C (o - m)` and
    /// `b = C d`. With `d = R v` for the camera-space direction `v = (u, 1)`, that is
    /// `v^T P v <= 0` for `P = (|a|^2 - cutoff) K^T K - g g^T`, `K = C R`, `g = K^T a`; completing
    /// the square in `u` gives the ellipse `(u - u0)^T P2 (u - u0) <= k`, `u0 = -P2^-1 p`,
    /// `k = p^T P2^-1 p - p33`, with `P2` the upper-left 2x2 of `P` and `p` its last column.
    #[cfg(test)]
    pub(super) fn silhouette(
        &self,
        seen: &Seen,
        cutoff: f32,
    ) -> Option<([f64; 2], [f64; 3], [f64; 2])> {
        // K's columns are the camera's axes in the canonical frame: (K^T K)_rc = K_r . K_c,
        // and g = K^T a has g_c = K_c . a.
        let (a, k) = (seen.offset, seen.axes);
        let outside = a.length_squared() - cutoff as f64;
        let gv = [k[0].dot(a), k[1].dot(a), k[2].dot(a)];
        let entry = |r: usize, c: usize| outside * k[r].dot(k[c]) - gv[r] * gv[c];
        let (p00, p01, p11) = (entry(0, 0), entry(0, 1), entry(1, 1));
        let (p02, p12, p22) = (entry(0, 2), entry(1, 2), entry(2, 2));
        let det = p00 * p11 - p01 * p01;
        if !(outside > 0.0 && p00 > 0.0 && det > 0.0) {
            return None;
        }
        // P2^-1
        let (i00, i01, i11) = (p11 / det, -p01 / det, p00 / det);
        let u0 = [-(i00 * p02 + i01 * p12), -(i01 * p02 + i11 * p12)];
        let k = p02 * (i00 * p02 + i01 * p12) + p12 * (i01 * p02 + i11 * p12) - p22;
        if !(k > 0.0) {
            return None;
        }
        let f = self.focal;
        let scale = 1.0 / (f * f * k);
        let form = [p00 * scale, p01 * scale, p11 * scale];
        let centre = [self.half[0] + f * u0[0], self.half[1] + f * u0[1]];
        // The ellipse's half-extents: sqrt of Q^-1's diagonal, Q^-1 = f^2 k P2^-1.
        let slack = SILHOUETTE_SLACK;
        let reach = [
            (f * f * k * i00 * slack).sqrt(),
            (f * f * k * i11 * slack).sqrt(),
        ];
        let finite = form
            .iter()
            .chain(&centre)
            .chain(&reach)
            .all(|v| v.is_finite());
        finite.then_some((centre, form, reach))
    }
}

/// The whole pixels from `floor(from)` to `ceil(to)`, clipped to `0..size` (a whole number of
/// pixels); `None` when none is left or either end is NaN. Without `floor` and `ceil`, which
/// are a call to libm each on the x86-64 baseline (a tenth of placing a Gaussian): a
/// non-negative number's floor is its truncation, and the clipping commutes with both.
#[inline(always)]
pub(super) fn pixel_span(from: f64, to: f64, size: f64) -> Option<[u32; 2]> {
    // floor(from) < size and ceil(to) >= 0, written so that NaN fails.
    if !(from < size && to > -1.0) {
        return None;
    }
    // Both in (-1, size), size at most `MAX_IMAGE_SIDE`: exact as u32 (negatives give 0).
    let first = from.max(0.0) as u32;
    let to = to.min(size - 1.0);
    let last = to as u32 + ((to as u32 as f64) < to) as u32;
    (first <= last).then_some([first, last])
}
