//! The stochastic estimator for a camera's own rays, a scanline at a time instead of through
//! the BVH.
//!
//! The cache's ray-traced lookup traces one ray per cache pixel, all from the camera's centre,
//! in `Center` depth (each hit at its Gaussian's centre depth along the camera's forward axis).
//! Through the BVH such a ray cost about 7,000 instructions on clouds of a thousand Gaussians
//! (BENCHMARKS.md): the cache's Gaussians are large and overlap by design, so a ray's boxes
//! overlap many others, and the traversal must look a whole box's half-diagonal past the
//! farthest slot's hit before it may stop. Rays that share an origin need no BVH: the Gaussians
//! a pixel's ray can meet are those whose silhouettes (the screen ellipse of the alpha >= 1/255
//! ellipsoid seen from the camera) cover the pixel, and in `Center` depth every ray of the
//! camera meets them in one order, their centres' depth.
//!
//! So the Gaussians are sorted by centre depth once, and listed in that order in the bands of
//! rows their silhouettes cover. A row of pixels walks its band's list once, front to back: for
//! each Gaussian it solves for the pixels the silhouette covers on that row (a chord of the
//! ellipse) and tests only those pixels' rays. Walking in depth order, a hit can never come
//! before a slot's earlier hit, so a slot keeps the first hit it accepts, and a pixel is done
//! once every slot has one; the row stops when every pixel is done. An earlier version listed
//! the Gaussians per 8x8 tile and sorted each tile's list: a row then walked the tile's whole
//! list, three quarters of it Gaussians that missed every one of its pixels, and the grid's
//! building (a sort per tile) cost a third of the walk.
//!
//! The estimate is the BVH's ([`crate::estimators::trace_stochastic`]) bit for bit: the same
//! intersections (every Gaussian the BVH would find is on the pixel's chord; the response is
//! [`TraceGaussians::intersect`]'s), the same acceptance numbers, and the same closest accepted
//! hit per slot, which does not depend on the order hits are met. Two cases can differ: two
//! Gaussians at exactly the same depth (the BVH keeps the one it meets first, the walk the
//! lower index), and a box that reaches behind the camera's plane. Such a box has no bounded
//! silhouette: it is listed on every row, and a ray takes it where it meets the box at or after
//! its origin; the BVH also visits it as a leaf-mate of a box the ray meets, where its ellipsoid
//! can lie behind the camera.

use crate::gaussians::{OriginTerms, TraceGaussians};
use crate::random::{RandomKind, SLOT_LANES, SampleKey, acceptance, accepting_slots};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use render_base::camera::RayDirections;
use render_base::hash::Hash32;
use splat_raster::Camera;

/// Rows per band: a Gaussian is listed once per band its silhouette reaches, and a row walks
/// its band's list, skipping the Gaussians that miss the row. Smaller bands list Gaussians more
/// often; larger ones make each row skip more.
const BAND: u32 = 4;

/// Pixels whose silhouette tests are made together (one vector of f32 lanes).
const LANES: usize = 8;

/// Boxes nearer the camera's plane than this (in depth units) are treated as reaching behind it.
const NEAR: f32 = 1e-6;

/// The most slots a traversal keeps ([`crate::estimators::trace_stochastic`]'s bound).
const MAX_SLOTS: usize = 64;

/// A pixel is tested against a Gaussian when its centre lies inside the Gaussian's silhouette
/// ellipse grown by this factor (in the ellipse's quadratic form): the test only saves
/// `intersect` calls, so it must never refuse a ray that `intersect`, in f32, would accept.
const SILHOUETTE_SLACK: f32 = 1.0 + 1.0 / 64.0;

/// The chord a row walks is solved for an ellipse grown a little more than the pixels' own
/// test, and widened by a pixel each way: it may hold pixels the test refuses, never one the
/// test (rounded in f32) would take ([`Placed::chord_terms`]).
const CHORD_SLACK: f64 = SILHOUETTE_SLACK as f64 * (1.0 + 1.0 / 256.0);

/// The camera's image by the stochastic estimator (Sun et al., Algorithm 1, with
/// `samples_per_traversal` slots, section 3.5) in `Center` depth: per pixel the mean of `spp`
/// estimates, each the mean of its slots' closest accepted colours (`background` for a slot
/// with none). The same image as [`crate::trace_image`] with
/// `Estimator::Stochastic { samples_per_traversal }` and `DepthMode::Center` (see the module
/// docs for the one exception), at a fraction of its cost for these rays.
pub fn trace_camera_image(
    gaussians: &TraceGaussians,
    camera: &Camera,
    samples_per_traversal: u32,
    spp: u32,
    seed: u32,
    random: RandomKind,
    background: Vec3,
) -> Vec<Vec3> {
    let grid = ScreenGrid::new(gaussians, camera);
    let slots = (samples_per_traversal.max(1) as usize).min(MAX_SLOTS);
    let spp = spp.max(1);
    let width = camera.width as usize;
    let walk = Walk {
        g: gaussians,
        grid: &grid,
        origin: camera.position,
        forward: camera.axes().2,
        directions: camera.ray_directions(),
        width,
        slots,
        padded_slots: slots.next_multiple_of(SLOT_LANES),
        seed,
        random,
        background,
    };
    // The walk compiled for AVX2 where the processor has it: the slots' acceptance numbers are
    // integer multiplies across slots, which the baseline x86-64 has no vector instruction for.
    // Both compilations give the same bits (no fused multiply-add; integers are exact).
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    let avx2 = false;
    let mut image = vec![Vec3::ZERO; width * camera.height as usize];
    image.par_chunks_mut(width).enumerate().for_each_init(
        || Row::new(&walk),
        |row, (y, out)| {
            row.start(&walk, y as u32);
            for s in 0..spp {
                if avx2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: `avx2` is true only where the processor runs AVX2 (checked by
                    // `is_x86_feature_detected!` above).
                    unsafe {
                        walk.estimate_avx2(row, y as u32, s)
                    };
                } else {
                    walk.estimate(row, y as u32, s);
                }
            }
            for (out, sum) in out.iter_mut().zip(&row.sums) {
                *out = (*sum / spp as f64).as_vec3();
            }
        },
    );
    image
}

/// A slot before any hit.
const EMPTY_SLOT: u32 = u32::MAX;

/// One row's working memory, kept from row to row of a thread.
struct Row {
    /// Each pixel's ray direction by component, padded to whole groups of [`LANES`] with zero
    /// directions (which meet nothing).
    directions: [Vec<f32>; 3],
    /// Each pixel's ray direction along the camera's forward axis; a ray that does not point
    /// forward meets nothing.
    forward: Vec<f32>,
    /// Each pixel's slots' hits (a Gaussian's index in the tracing arrays, or [`EMPTY_SLOT`]),
    /// padded like `states`.
    hits: Vec<u32>,
    /// Each pixel's slots' acceptance hash states before a Gaussian's id
    /// ([`SampleKey::slot_states`]), padded to whole vectors of [`SLOT_LANES`] slots.
    states: Vec<Hash32>,
    /// Each pixel's slots holding a hit, a bit a slot.
    filled: Vec<u64>,
    /// Per group of [`LANES`] pixels, those still taking part, a bit a pixel.
    taking_part: Vec<u8>,
    /// Each pixel's estimates summed.
    sums: Vec<DVec3>,
}

impl Row {
    fn new(walk: &Walk) -> Self {
        let width = walk.width;
        let padded = width.next_multiple_of(LANES);
        Self {
            directions: std::array::from_fn(|_| vec![0.0; padded]),
            forward: vec![0.0; width],
            hits: vec![EMPTY_SLOT; width * walk.padded_slots],
            states: vec![Hash32::default(); width * walk.padded_slots],
            filled: vec![0; width],
            taking_part: vec![0; width.div_ceil(LANES)],
            sums: vec![DVec3::ZERO; width],
        }
    }

    /// Readies the row for row `y`'s estimates.
    fn start(&mut self, walk: &Walk, y: u32) {
        let py = y as f32 + 0.5;
        for (x, ahead) in self.forward.iter_mut().enumerate() {
            let d = walk.directions.at(x as f32 + 0.5, py);
            for (component, v) in self.directions.iter_mut().zip(d.to_array()) {
                component[x] = v;
            }
            *ahead = walk.forward.dot(d);
        }
        self.sums.fill(DVec3::ZERO);
    }
}

/// What every row's walk reads.
struct Walk<'a> {
    g: &'a TraceGaussians,
    grid: &'a ScreenGrid,
    origin: Vec3,
    forward: Vec3,
    directions: RayDirections,
    width: usize,
    slots: usize,
    /// `slots` rounded up to whole vectors of [`SLOT_LANES`]: each pixel's share of the row's
    /// slot arrays.
    padded_slots: usize,
    seed: u32,
    random: RandomKind,
    background: Vec3,
}

impl Walk<'_> {
    /// Estimate `sample` for each pixel of row `y`, added to the row's sums: the mean of each
    /// ray's slots' closest accepted colours. The row's band is walked front to back once for
    /// all its rays; a ray takes part until every slot holds a hit, and the walk stops when no
    /// ray takes part. Each ray meets exactly the hits it would meet alone.
    #[inline(always)]
    fn estimate(&self, row: &mut Row, y: u32, sample: u32) {
        let (g, slots, width) = (self.g, self.slots, self.width);
        let full = u64::MAX >> (64 - slots);
        let hashed = self.random == RandomKind::Hash;
        let Row {
            directions,
            forward,
            hits,
            states,
            filled,
            taking_part,
            sums,
        } = row;
        hits.fill(EMPTY_SLOT);
        filled.fill(0);
        taking_part.fill(0);
        let mut left = 0usize;
        for (x, &ahead) in forward.iter().enumerate() {
            // Written so that NaN takes no part.
            if ahead > 0.0 {
                taking_part[x / LANES] |= 1 << (x % LANES);
                left += 1;
            }
        }
        let key = |x: usize| SampleKey::new(self.seed, y * width as u32 + x as u32, sample);
        let padded = self.padded_slots;
        if hashed {
            for (x, states) in states.chunks_exact_mut(padded).enumerate() {
                key(x).slot_states(states);
            }
        }
        let py = y as f32 + 0.5;
        for &rank in self.grid.band(y / BAND) {
            if left == 0 {
                break;
            }
            let p = &self.grid.placed[rank as usize];
            if !(p.rows[0] <= y && y <= p.rows[1]) {
                continue;
            }
            let Some([x0, x1]) = p.chord(y) else {
                continue;
            };
            let i = p.index as usize;
            let origin = &self.grid.origins[rank as usize];
            // The silhouette test's terms shared by the row.
            let dy = py - p.centre[1];
            let [qxx, qxy, qyy] = p.form;
            let (cross, last) = (2.0 * qxy * dy, qyy * dy * dy);
            for group in x0 as usize / LANES..=x1 as usize / LANES {
                let alive = taking_part[group];
                if alive == 0 {
                    continue;
                }
                // The silhouette test for the group's pixels at once (it only saves
                // `intersect` calls).
                let mut meets = 0u8;
                for l in 0..LANES {
                    let dx = (group * LANES + l) as f32 + 0.5 - p.centre[0];
                    let inside = qxx * dx * dx + cross * dx + last <= SILHOUETTE_SLACK;
                    meets |= (inside as u8) << l;
                }
                meets &= alive;
                if meets == 0 {
                    continue;
                }
                // The closest points of the group's rays at once (`intersect`'s formula, lane
                // by lane), then each ray the silhouette let through.
                let lanes = group * LANES..(group + 1) * LANES;
                let lane_of =
                    |c: &Vec<f32>| -> [f32; LANES] { c[lanes.clone()].try_into().unwrap() };
                let [dx, dy, dz] = [
                    lane_of(&directions[0]),
                    lane_of(&directions[1]),
                    lane_of(&directions[2]),
                ];
                let (_, q) = g.closest_points(i, origin, [&dx, &dy, &dz]);
                while meets != 0 {
                    let l = meets.trailing_zeros() as usize;
                    meets &= meets - 1;
                    let x = group * LANES + l;
                    let d = Vec3::new(dx[l], dy[l], dz[l]);
                    if p.reaches_behind && !meets_box(g, i, self.origin, d) {
                        continue;
                    }
                    let Some(alpha) = g.alpha(i, q[l]) else {
                        continue;
                    };
                    // `intersect`'s centre depth: the centre's depth over the direction's.
                    let t = p.depth / forward[x];
                    if !(t > 0.0 && t < f32::INFINITY) {
                        continue;
                    }
                    // Walking in depth order, a hit comes at or behind every earlier one: the
                    // slots without a hit take it where its number accepts it (the BVH's
                    // "strictly nearer than the slot's hit" is "empty" here).
                    let empty = !filled[x] & full;
                    let mut taken = 0u64;
                    if hashed {
                        let vectors = states[x * padded..(x + 1) * padded].as_chunks().0;
                        for (v, states) in vectors.iter().enumerate() {
                            let accepted = accepting_slots(states, g.ids[i], alpha);
                            taken |= (accepted as u64) << (v * SLOT_LANES);
                        }
                        taken &= empty;
                    } else {
                        let at = self.origin + t * d;
                        let key = key(x);
                        let mut open = empty;
                        while open != 0 {
                            let s = open.trailing_zeros();
                            open &= open - 1;
                            if acceptance(self.random, &key, g.ids[i], s, at) < alpha {
                                taken |= 1 << s;
                            }
                        }
                    }
                    if taken == 0 {
                        continue;
                    }
                    filled[x] |= taken;
                    let slots_of_x = &mut hits[x * padded..(x + 1) * padded];
                    while taken != 0 {
                        let s = taken.trailing_zeros() as usize;
                        taken &= taken - 1;
                        slots_of_x[s] = i as u32;
                    }
                    let done = filled[x] == full;
                    taking_part[group] &= !((done as u8) << l);
                    left -= done as usize;
                }
            }
        }
        for (slots_of_x, sum) in hits.chunks_exact(padded).zip(sums.iter_mut()) {
            let total: Vec3 = slots_of_x[..slots]
                .iter()
                .map(|&i| {
                    if i == EMPTY_SLOT {
                        self.background
                    } else {
                        g.color(i as usize, self.origin)
                    }
                })
                .sum();
            *sum += (total / slots as f32).as_dvec3();
        }
    }

    /// [`Walk::estimate`] compiled for AVX2.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn estimate_avx2(&self, row: &mut Row, y: u32, sample: u32) {
        self.estimate(row, y, sample)
    }
}

/// Whether the ray meets Gaussian `i`'s box at or after its origin (the BVH's test, for the
/// boxes listed everywhere because they reach behind the camera).
fn meets_box(g: &TraceGaussians, i: usize, o: Vec3, d: Vec3) -> bool {
    let inv = d.recip();
    let a = (g.lower[i] - o) * inv;
    let b = (g.upper[i] - o) * inv;
    let near = a.min(b).max_element().max(0.0);
    let far = a.max(b).min_element();
    near <= far
}

/// The Gaussians in front of the camera, sorted by centre depth (ties by index), and per band
/// of rows the ones whose silhouettes may reach it, in that order.
struct ScreenGrid {
    /// Each Gaussian placed on the screen, by depth: a Gaussian's place here is its rank.
    placed: Vec<Placed>,
    /// Each rank's [`OriginTerms`] from the camera's centre.
    origins: Vec<OriginTerms>,
    /// Band `b`'s ranks are `ranks[starts[b]..starts[b + 1]]`, ascending.
    starts: Vec<usize>,
    ranks: Vec<u32>,
}

/// One Gaussian on the screen.
#[derive(Clone, Copy)]
struct Placed {
    /// Its centre's depth along the camera's forward axis.
    depth: f32,
    /// Its index in the tracing arrays.
    index: u32,
    /// Its silhouette: the pixels `p` with `(p - centre)^T Q (p - centre) <= 1` are those whose
    /// rays meet its alpha >= 1/255 ellipsoid. `Q = 0` where no bounded silhouette exists (a
    /// box reaching behind the camera, or rounding): every pixel of its rectangle is tested.
    centre: [f32; 2],
    /// `Q`'s entries xx, xy, yy.
    form: [f32; 3],
    /// The pixel columns and rows (inclusive) its silhouette may cover.
    columns: [u32; 2],
    rows: [u32; 2],
    /// The box reaches behind the camera's plane: the ray must meet the box at or after its
    /// origin, as the BVH requires.
    reaches_behind: bool,
    /// The silhouette's chords by row ([`Placed::chord_terms`]).
    chord_terms: [f32; 3],
}

impl Placed {
    /// The pixels of row `y` (inclusive) whose rays may meet it: its rectangle's columns, on a
    /// bounded silhouette narrowed to the ellipse's chord at the row's centre (see
    /// [`Placed::chord_terms`]); `None` where the chord misses the row.
    #[inline]
    fn chord(&self, y: u32) -> Option<[u32; 2]> {
        let [k1, k2, k3] = self.chord_terms;
        if !(k2 > 0.0) {
            return Some(self.columns);
        }
        let dy = y as f32 + 0.5 - self.centre[1];
        let squared = dy * dy * k1 + k2;
        if !(squared >= 0.0) {
            return None;
        }
        let (mid, half) = (self.centre[0] + dy * k3, squared.sqrt());
        // Pixel x's centre is x + 0.5; a pixel wider each way.
        let from = (mid - half - 1.5).ceil().max(self.columns[0] as f32);
        let to = (mid + half + 0.5).floor().min(self.columns[1] as f32);
        (from <= to).then_some([from as u32, to as u32])
    }

    /// The terms of [`Placed::chord`] for the silhouette `form`: the ellipse
    /// `a dx^2 + 2 b dy dx + c dy^2 <= s`, grown to `s =` [`CHORD_SLACK`], meets the row at
    /// `dy` from its centre where `dx = k3 dy +- sqrt(k1 dy^2 + k2)`, with
    /// `k1 = (b^2 - a c) / a^2`, `k2 = s / a` and `k3 = -b / a`; `k2 = 0` where there is no
    /// bounded silhouette (every column of the rectangle is walked). Solved in f64, rounded to
    /// f32 and evaluated in f32: the chord must hold every pixel that the pixels' own test
    /// (`SILHOUETTE_SLACK`, in f32) would take, and the larger slack moves the chord's ends
    /// by more than the rounding can (at a chord's end, `k1 dy^2 + k2` has `k2 / 256` to
    /// spare against a rounding error of about `k2 / 2^23`), a pixel's widening on top.
    fn chord_terms(form: [f32; 3]) -> [f32; 3] {
        let [a, b, c] = form.map(f64::from);
        if !(a > 0.0) {
            return [0.0; 3];
        }
        let terms = [(b * b - a * c) / (a * a), CHORD_SLACK / a, -b / a].map(|k| k as f32);
        if terms.iter().all(|k| k.is_finite()) && terms[1] > 0.0 {
            terms
        } else {
            [0.0; 3]
        }
    }
}

/// The camera's constants for placing Gaussians on its screen.
struct Screen {
    position: glam::DVec3,
    /// World to camera space (+X right, +Y down, +Z forward).
    to_camera: glam::DMat3,
    focal: f64,
    half: [f64; 2],
    size: [f64; 2],
}

impl Screen {
    fn new(camera: &Camera) -> Self {
        Self {
            position: camera.position.as_dvec3(),
            to_camera: glam::DMat3::from_quat(camera.rotation.as_dquat().inverse()),
            focal: camera.focal_pixels() as f64,
            half: [0.5 * camera.width as f64, 0.5 * camera.height as f64],
            size: [camera.width as f64, camera.height as f64],
        }
    }

    /// Gaussian `i` (centre depth `depth`) on the screen: the pixel rectangle of its box's
    /// corners, narrowed to its silhouette's; the whole screen when its box reaches behind the
    /// camera's plane; `None` when its centre is not in front of the camera (`intersect` never
    /// places a hit there) or it is off the screen.
    fn place(&self, g: &TraceGaussians, i: usize, depth: f32) -> Option<Placed> {
        if !(depth > 0.0) {
            return None;
        }
        let [w, h] = self.size;
        let everywhere = Placed {
            depth,
            index: i as u32,
            centre: [0.0; 2],
            form: [0.0; 3],
            columns: [0, w as u32 - 1],
            rows: [0, h as u32 - 1],
            reaches_behind: true,
            chord_terms: [0.0; 3],
        };
        let (lo, hi) = (g.lower[i].as_dvec3(), g.upper[i].as_dvec3());
        let (mut u0, mut u1, mut v0, mut v1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for k in 0..8 {
            let corner = glam::DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            let c = self.to_camera * (corner - self.position);
            if !(c.z > NEAR as f64) {
                return Some(everywhere);
            }
            let (u, v) = (
                self.half[0] + self.focal * c.x / c.z,
                self.half[1] + self.focal * c.y / c.z,
            );
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
        let mut placed = Placed {
            reaches_behind: false,
            ..everywhere
        };
        if let Some((centre, form, reach)) = self.silhouette(g, i) {
            placed.centre = [centre[0] as f32, centre[1] as f32];
            placed.form = form.map(|q| q as f32);
            placed.chord_terms = Placed::chord_terms(placed.form);
            u0 = u0.max(centre[0] - reach[0]);
            u1 = u1.min(centre[0] + reach[0]);
            v0 = v0.max(centre[1] - reach[1]);
            v1 = v1.min(centre[1] + reach[1]);
        }
        // The pixels whose centres the rectangle covers, a pixel wider each way for rounding.
        let (x0, x1) = ((u0 - 1.5).floor(), (u1 + 0.5).ceil());
        let (y0, y1) = ((v0 - 1.5).floor(), (v1 + 0.5).ceil());
        if !(x1 >= 0.0 && y1 >= 0.0 && x0 < w && y0 < h && x0 <= x1 && y0 <= y1) {
            return None;
        }
        placed.columns = [x0.max(0.0) as u32, x1.min(w - 1.0) as u32];
        placed.rows = [y0.max(0.0) as u32, y1.min(h - 1.0) as u32];
        Some(placed)
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
    fn silhouette(&self, g: &TraceGaussians, i: usize) -> Option<([f64; 2], [f64; 3], [f64; 2])> {
        let rows = g.canonical[i].map(|r| r.as_dvec3());
        let a = rows.map(|r| r.dot(self.position - g.means[i].as_dvec3()));
        let a = glam::DVec3::from_array(a);
        // K's rows: each canonical row in camera space (R^T = to_camera).
        let k_rows = rows.map(|r| self.to_camera * r);
        let outside = a.length_squared() - g.cutoff[i] as f64;
        let gv = k_rows[0] * a.x + k_rows[1] * a.y + k_rows[2] * a.z;
        let entry = |r: usize, c: usize| {
            let ktk: f64 = k_rows.iter().map(|k| k[r] * k[c]).sum();
            outside * ktk - gv[r] * gv[c]
        };
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
        let slack = SILHOUETTE_SLACK as f64;
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

impl ScreenGrid {
    fn new(g: &TraceGaussians, camera: &Camera) -> Self {
        let bands = camera.height.div_ceil(BAND) as usize;
        let forward = camera.axes().2;
        let screen = Screen::new(camera);
        let mut placed: Vec<Placed> = (0..g.len())
            .into_par_iter()
            .filter_map(|i| {
                // As `intersect` computes it, so that the walk's order is its hits' order.
                let depth = (g.means[i] - camera.position).dot(forward);
                screen.place(g, i, depth)
            })
            .collect();
        // By depth, ties by index (the keys are distinct): one order on any thread count.
        placed.par_sort_unstable_by(|a, b| {
            let by_depth = a.depth.total_cmp(&b.depth);
            by_depth.then(a.index.cmp(&b.index))
        });
        let origins = placed
            .par_iter()
            .map(|p| g.origin_terms(p.index as usize, camera.position))
            .collect();
        // A counting sort of the ranks by band, each band's in rank order.
        let bands_of = |p: &Placed| (p.rows[0] / BAND) as usize..=(p.rows[1] / BAND) as usize;
        let mut starts = vec![0usize; bands + 1];
        for p in &placed {
            for b in bands_of(p) {
                starts[b + 1] += 1;
            }
        }
        for b in 0..bands {
            starts[b + 1] += starts[b];
        }
        let mut ranks = vec![0u32; starts[bands]];
        let mut next = starts[..bands].to_vec();
        for (rank, p) in placed.iter().enumerate() {
            for b in bands_of(p) {
                ranks[next[b]] = rank as u32;
                next[b] += 1;
            }
        }
        Self {
            placed,
            origins,
            starts,
            ranks,
        }
    }

    /// Band `b`'s ranks, front to back.
    fn band(&self, b: u32) -> &[u32] {
        &self.ranks[self.starts[b as usize]..self.starts[b as usize + 1]]
    }
}
