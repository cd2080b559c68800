//! The stochastic estimator for a camera's own rays, through a screen grid instead of the BVH.
//!
//! The cache's ray-traced lookup traces one ray per cache pixel, all from the camera's centre,
//! in `Center` depth (each hit at its Gaussian's centre depth along the camera's forward axis).
//! Through the BVH such a ray cost about 7,000 instructions on clouds of a thousand Gaussians
//! (BENCHMARKS.md): the cache's Gaussians are large and overlap by design, so a ray's boxes
//! overlap many others, and the traversal must look a whole box's half-diagonal past the
//! farthest slot's hit before it may stop. Rays that share an origin need no BVH: the Gaussians
//! a pixel's ray can meet are those whose silhouettes (the screen ellipse of the alpha >= 1/255
//! ellipsoid seen from the camera) cover the pixel, and in `Center` depth every ray of the
//! camera meets them in one order, their centres' depth. So each Gaussian is listed in the
//! screen tiles its silhouette covers, each tile's list is sorted by centre depth once, and the
//! rays of a tile's row walk its list front to back together, each ray testing only the
//! Gaussians whose silhouette holds its pixel and stopping at the first Gaussian behind its
//! farthest slot: nothing behind it can replace a slot's hit.
//!
//! The estimate is the BVH's ([`crate::estimators::trace_stochastic`]) bit for bit: the same
//! intersections (every Gaussian the BVH would find is in the pixel's list; the response is
//! [`TraceGaussians::intersect`]'s), the same acceptance numbers, and the same closest accepted
//! hit per slot, which does not depend on the order hits are met. Two cases can differ: two
//! Gaussians at exactly the same depth (the BVH keeps the one it meets first, the grid the
//! lower index), and a box that reaches behind the camera's plane. Such a box has no bounded
//! silhouette: it is listed in every tile, and a ray takes it where it meets the box at or after
//! its origin; the BVH also visits it as a leaf-mate of a box the ray meets, where its ellipsoid
//! can lie behind the camera.

use crate::gaussians::{DepthMode, TraceGaussians};
use crate::random::{RandomKind, SampleKey, acceptance, slot_acceptances};
use glam::Vec3;
use rayon::prelude::*;
use render_base::hash::Hash32;
use splat_raster::Camera;

/// Pixels along a tile's side: smaller tiles walk fewer Gaussians that miss the pixel but list
/// each Gaussian more often. At the cache's 320x180 (one run each, 2 threads) 4, 8 and 16 gave
/// 48.6, 46.7 and 51.1 ms of lookup a frame, within the runs' noise of each other.
const TILE: u32 = 8;

/// Boxes nearer the camera's plane than this (in depth units) are treated as reaching behind it.
const NEAR: f32 = 1e-6;

/// The most slots a traversal keeps ([`crate::estimators::trace_stochastic`]'s bound).
const MAX_SLOTS: usize = 64;

/// A pixel is tested against a Gaussian when its centre lies inside the Gaussian's silhouette
/// ellipse grown by this factor (in the ellipse's quadratic form): the test only saves
/// `intersect` calls, so it must never refuse a ray that `intersect`, in f32, would accept.
const SILHOUETTE_SLACK: f32 = 1.0 + 1.0 / 64.0;

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
    let (width, forward) = (camera.width, camera.axes().2);
    let directions = camera.ray_directions();
    let mut image = vec![Vec3::ZERO; width as usize * camera.height as usize];
    // The walk compiled for AVX2 where the processor has it: the slots' acceptance numbers are
    // integer multiplies across slots, which the baseline x86-64 has no vector instruction for.
    // Both compilations give the same bits (no fused multiply-add; integers are exact).
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    let avx2 = false;
    image
        .par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let y = y as u32;
            let mut hits = vec![EMPTY_SLOT; LANES * slots];
            let mut states = vec![Hash32::default(); LANES * slots];
            // A tile's row of pixels at a time: its rays share the tile's list.
            for (tx, span) in row.chunks_mut(LANES).enumerate() {
                let x0 = tx as u32 * TILE;
                let rays: [CameraRay; LANES] = std::array::from_fn(|l| {
                    let (px, py) = ((x0 + l as u32) as f32 + 0.5, y as f32 + 0.5);
                    CameraRay {
                        o: camera.position,
                        d: directions.at(px, py),
                        forward,
                        pixel: [px, py],
                    }
                });
                let rays = &rays[..span.len()];
                let list = grid.list(tx as u32, y / TILE);
                let mut sums = [glam::DVec3::ZERO; LANES];
                for s in 0..spp {
                    let keys: [SampleKey; LANES] =
                        std::array::from_fn(|l| SampleKey::new(seed, y * width + x0 + l as u32, s));
                    let walk = Walk {
                        g: gaussians,
                        random,
                        background,
                    };
                    let scratch = Scratch {
                        hits: &mut hits,
                        states: &mut states,
                    };
                    if avx2 {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: `avx2` is true only where the processor runs AVX2 (checked
                        // by `is_x86_feature_detected!` above).
                        unsafe {
                            walk.estimate_avx2(rays, &keys, list, slots, scratch, &mut sums)
                        };
                    } else {
                        walk.estimate(rays, &keys, list, slots, scratch, &mut sums);
                    }
                }
                for (out, sum) in span.iter_mut().zip(sums) {
                    *out = (sum / spp as f64).as_vec3();
                }
            }
        });
    image
}

/// Pixels walked together: a tile's row.
const LANES: usize = TILE as usize;

/// A slot before any hit: (distance, Gaussian, centre depth).
const EMPTY_SLOT: (f32, usize, f32) = (f32::INFINITY, usize::MAX, f32::INFINITY);

/// A camera ray through a pixel position; its hits are placed at their Gaussians' centre depth.
struct CameraRay {
    o: Vec3,
    d: Vec3,
    forward: Vec3,
    pixel: [f32; 2],
}

/// One Gaussian in a tile's list.
#[derive(Clone, Copy, Default)]
struct Entry {
    /// Its centre's depth along the camera's forward axis.
    depth: f32,
    index: u32,
    /// Its silhouette: the pixels `p` with `(p - centre)^T Q (p - centre) <= 1` are those whose
    /// rays meet its alpha >= 1/255 ellipsoid. `Q = 0` where no bounded silhouette exists (a
    /// box reaching behind the camera): every pixel is tested.
    centre: [f32; 2],
    /// `Q`'s entries xx, xy, yy.
    form: [f32; 3],
    /// The box reaches behind the camera's plane: the ray must meet the box at or after its
    /// origin, as the BVH requires.
    reaches_behind: bool,
}

/// An estimate's working memory, for `rays.len() * slots` slots: each slot's hit, and each
/// slot's acceptance hash state before the Gaussian's id ([`SampleKey::slot_states`]).
struct Scratch<'a> {
    hits: &'a mut [(f32, usize, f32)],
    states: &'a mut [Hash32],
}

/// What every estimate reads besides its rays and list.
struct Walk<'a> {
    g: &'a TraceGaussians,
    random: RandomKind,
    background: Vec3,
}

impl Walk<'_> {
    /// One estimate for each of `rays` (one row of a tile, all on the same `list`, sorted by
    /// centre depth) with sample keys `keys`, added to `sums`: the mean of each ray's slots'
    /// closest accepted colours. The list is walked front to back once for all the rays; a
    /// ray takes part until the next Gaussian lies behind every one of its slots' hits, and the
    /// walk stops when no ray takes part. Each ray meets exactly the hits it would meet alone.
    #[inline(always)]
    fn estimate(
        &self,
        rays: &[CameraRay],
        keys: &[SampleKey; LANES],
        list: &[Entry],
        slots: usize,
        scratch: Scratch<'_>,
        sums: &mut [glam::DVec3; LANES],
    ) {
        let g = self.g;
        let n = rays.len();
        let Scratch { hits, states } = scratch;
        hits[..n * slots].fill(EMPTY_SLOT);
        let hashed = self.random == RandomKind::Hash;
        if hashed {
            for (key, states) in keys.iter().zip(states.chunks_exact_mut(slots)).take(n) {
                key.slot_states(states);
            }
        }
        // One Gaussian's acceptance numbers for a ray's slots.
        let mut numbers = [0.0f32; MAX_SLOTS];
        // Per ray, the centre depth of its farthest slot's hit: infinite while a slot is
        // empty. `intersect` places a hit at `depth / fd`, which never decreases with the
        // depth, so a Gaussian at or behind it cannot come before any of the ray's hits; one in
        // front of it whose hit rounds to the same distance is walked and replaces nothing (a
        // slot takes only a strictly nearer hit). A ray that does not point forward meets
        // nothing (written so that NaN meets nothing too); lanes past the row's end take no
        // part.
        let mut farthest = [f32::NEG_INFINITY; LANES];
        let mut px = [0.0f32; LANES];
        for (l, r) in rays.iter().enumerate() {
            px[l] = r.pixel[0];
            if r.forward.dot(r.d) > 0.0 {
                farthest[l] = f32::INFINITY;
            }
        }
        let py = rays[0].pixel[1];
        let mut walking = farthest.iter().fold(f32::NEG_INFINITY, |m, &f| m.max(f));
        for e in list {
            if !(e.depth < walking) {
                break;
            }
            // The silhouette test for the row's pixels at once (it only saves `intersect`
            // calls), and whether each ray still takes part.
            let dy = py - e.centre[1];
            let [qxx, qxy, qyy] = e.form;
            let (cross, last) = (2.0 * qxy * dy, qyy * dy * dy);
            let mut meets = [false; LANES];
            for l in 0..LANES {
                let dx = px[l] - e.centre[0];
                meets[l] = (qxx * dx * dx + cross * dx + last <= SILHOUETTE_SLACK)
                    & (e.depth < farthest[l]);
            }
            if !meets.iter().any(|&m| m) {
                continue;
            }
            let i = e.index as usize;
            // The rays share their origin: its terms once for the row.
            let origin = g.origin_terms(i, rays[0].o);
            for (l, r) in rays.iter().enumerate() {
                if !meets[l] || (e.reaches_behind && !meets_box(g, i, r)) {
                    continue;
                }
                let Some(h) = g.intersect_from(
                    i,
                    &origin,
                    r.d,
                    0.0,
                    f32::INFINITY,
                    DepthMode::Center,
                    r.forward,
                ) else {
                    continue;
                };
                let lane = &mut hits[l * slots..(l + 1) * slots];
                if hashed {
                    // Every slot's number, then the slots that take the hit: the same choice as
                    // numbering only the slots whose hit is farther (the numbers are pure).
                    let numbers = &mut numbers[..slots];
                    slot_acceptances(&states[l * slots..(l + 1) * slots], g.ids[i], numbers);
                    for (slot, &u) in lane.iter_mut().zip(numbers.iter()) {
                        if h.t < slot.0 && u < h.alpha {
                            *slot = (h.t, i, e.depth);
                        }
                    }
                } else {
                    let p = r.o + h.t * r.d;
                    for (s, slot) in lane.iter_mut().enumerate() {
                        if h.t < slot.0
                            && acceptance(self.random, &keys[l], g.ids[i], s as u32, p) < h.alpha
                        {
                            *slot = (h.t, i, e.depth);
                        }
                    }
                }
                farthest[l] = lane.iter().fold(0.0f32, |m, s| m.max(s.2));
            }
            walking = farthest.iter().fold(f32::NEG_INFINITY, |m, &f| m.max(f));
        }
        for (l, r) in rays.iter().enumerate() {
            let sum: Vec3 = hits[l * slots..(l + 1) * slots]
                .iter()
                .map(|&(_, i, _)| {
                    if i == usize::MAX {
                        self.background
                    } else {
                        g.color(i, r.o)
                    }
                })
                .sum();
            sums[l] += (sum / slots as f32).as_dvec3();
        }
    }
}

impl Walk<'_> {
    /// [`Walk::estimate`] compiled for AVX2.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn estimate_avx2(
        &self,
        rays: &[CameraRay],
        keys: &[SampleKey; LANES],
        list: &[Entry],
        slots: usize,
        scratch: Scratch<'_>,
        sums: &mut [glam::DVec3; LANES],
    ) {
        self.estimate(rays, keys, list, slots, scratch, sums)
    }
}

/// Whether the ray meets Gaussian `i`'s box at or after its origin (the BVH's test, for the
/// boxes listed everywhere because they reach behind the camera).
fn meets_box(g: &TraceGaussians, i: usize, r: &CameraRay) -> bool {
    let inv = r.d.recip();
    let a = (g.lower[i] - r.o) * inv;
    let b = (g.upper[i] - r.o) * inv;
    let near = a.min(b).max_element().max(0.0);
    let far = a.max(b).min_element();
    near <= far
}

/// Per screen tile, the Gaussians whose silhouettes may cover it, by centre depth.
struct ScreenGrid {
    tiles_x: u32,
    /// Each tile's list: `starts[t]..starts[t + 1]` of `entries`.
    starts: Vec<usize>,
    /// Each tile's sorted by depth, ties by index.
    entries: Vec<Entry>,
}

/// Where a Gaussian goes in the grid: tiles `x0..=x1` by `y0..=y1`.
#[derive(Clone, Copy)]
struct Cover {
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    entry: Entry,
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

    /// Where Gaussian `i` (centre depth `depth`) goes: the tiles of the screen rectangle of its
    /// box's corners, narrowed to its silhouette's; every tile when its box reaches behind the
    /// camera's plane; `None` when its centre is not in front of the camera (`intersect` never
    /// places a hit there) or it is off the screen.
    fn cover(&self, g: &TraceGaussians, i: usize, depth: f32) -> Option<Cover> {
        if !(depth > 0.0) {
            return None;
        }
        let [w, h] = self.size;
        let tile = |p: f64, n: f64| (p.clamp(0.0, n - 1.0) as u32) / TILE;
        let everywhere = Entry {
            depth,
            index: i as u32,
            centre: [0.0; 2],
            form: [0.0; 3],
            reaches_behind: true,
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
                return Some(Cover {
                    x0: 0,
                    x1: tile(w, w),
                    y0: 0,
                    y1: tile(h, h),
                    entry: everywhere,
                });
            }
            let (u, v) = (
                self.half[0] + self.focal * c.x / c.z,
                self.half[1] + self.focal * c.y / c.z,
            );
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
        let mut entry = Entry {
            reaches_behind: false,
            ..everywhere
        };
        if let Some((centre, form, reach)) = self.silhouette(g, i) {
            entry.centre = [centre[0] as f32, centre[1] as f32];
            entry.form = form.map(|q| q as f32);
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
        Some(Cover {
            x0: tile(x0, w),
            x1: tile(x1, w),
            y0: tile(y0, h),
            y1: tile(y1, h),
            entry,
        })
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
        let tiles_x = camera.width.div_ceil(TILE);
        let tiles_y = camera.height.div_ceil(TILE);
        let tiles = (tiles_x * tiles_y) as usize;
        let forward = camera.axes().2;
        let screen = Screen::new(camera);
        let covers: Vec<Cover> = (0..g.len())
            .into_par_iter()
            .filter_map(|i| {
                // As `intersect` computes it, so that the walk's stop is exact.
                let depth = (g.means[i] - camera.position).dot(forward);
                screen.cover(g, i, depth)
            })
            .collect();
        // A counting sort by tile: counts, starts, then each Gaussian's entries in index order.
        let tiles_of = |c: Cover| {
            let Cover { x0, x1, y0, y1, .. } = c;
            (y0..=y1).flat_map(move |ty| (x0..=x1).map(move |tx| (ty * tiles_x + tx) as usize))
        };
        let mut counts = vec![0usize; tiles];
        for t in covers.iter().copied().flat_map(tiles_of) {
            counts[t] += 1;
        }
        let mut starts = Vec::with_capacity(tiles + 1);
        starts.push(0);
        for c in &counts {
            starts.push(starts.last().unwrap() + c);
        }
        let mut entries = vec![Entry::default(); starts[tiles]];
        let mut next = starts[..tiles].to_vec();
        for cover in &covers {
            for t in tiles_of(*cover) {
                entries[next[t]] = cover.entry;
                next[t] += 1;
            }
        }
        // Each tile's list by centre depth, ties by index: one order on any thread count.
        let mut lists = Vec::with_capacity(tiles);
        let mut rest = entries.as_mut_slice();
        for c in &counts {
            let (list, tail) = rest.split_at_mut(*c);
            lists.push(list);
            rest = tail;
        }
        lists.into_par_iter().for_each(|list| {
            list.sort_unstable_by(|a, b| a.depth.total_cmp(&b.depth).then(a.index.cmp(&b.index)));
        });
        Self {
            tiles_x,
            starts,
            entries,
        }
    }

    fn list(&self, tx: u32, ty: u32) -> &[Entry] {
        let t = (ty * self.tiles_x + tx) as usize;
        &self.entries[self.starts[t]..self.starts[t + 1]]
    }
}
