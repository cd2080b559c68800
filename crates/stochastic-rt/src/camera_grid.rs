//! The stochastic estimator for a camera's own rays, a scanline at a time in depth order
//! instead of through the BVH.
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
//! So the Gaussians are sorted by centre depth once (a radix sort of their depths' bits),
//! placed on the screen in that order four at a time (their silhouettes in f64 lanes,
//! `wide`), and listed in the bands of rows their silhouettes cover, eight to a chunk, lane by
//! lane. A row of pixels walks its band's list once, front to back: for a chunk's Gaussians at
//! once it solves for the pixels each silhouette covers on that row (a chord of the ellipse),
//! and evaluates those pixels' rays in windows of eight from the chord's first.
//!
//! **The estimate.** Sun et al.'s multi-sample estimator (Algorithm 1, section 3.5) gives each
//! of a ray's slots the closest hit its own acceptance test takes, each hit tested with a fresh
//! number: slot by slot, hit `k` (in depth order, met at transmittance `T_k` with alpha `a_k`)
//! with probability `a_k T_k`, slots independent. A walk in depth order knows `T_k`, so it draws
//! the same law from one number a slot ([`SampleKey::slot_thresholds`]): a slot takes the hit
//! across which the transmittance falls below its number. A hit then costs a multiply and a
//! compare, not a hash per slot, and a ray is done once its transmittance is below every
//! slot's number. The slots are interchangeable (the estimate is their mean), so a ray's
//! state is how many it has filled, and its next number the largest of the rest
//! (`draw_thresholds`). The image has the same expectation and the same variance as
//! [`crate::trace_image`]'s with `Estimator::Stochastic` and `DepthMode::Center` (both drawn
//! from that law), not the same bits; `tests/tracing.rs` checks its mean against the exact
//! composite, and [`reference_image`] defines it pixel by pixel.
//!
//! **A ray's alphas** are computed from terms each Gaussian shares across the camera's rays
//! ([`Facing`]): in the Gaussian's canonical frame a ray `(u, w, 1)` (camera space, on the
//! plane z = 1) is `K (u, w, 1)` with `K` the camera's axes there, and its squared distance from
//! the centre is `|o x K v|^2 / |K v|^2` for the camera's canonical offset `o`; on a row both
//! are linear in `u`. The alphas are [`crate::TraceGaussians::intersect`]'s to within rounding
//! (tested: at most 2.1e-4 relative, on needle-thin Gaussians seen from afar).

use crate::gaussians::TraceGaussians;
use crate::isa::{Baseline, Isa};
use crate::random::SampleKey;
use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use render_base::camera::RayDirections;
use splat_raster::Camera;
#[cfg(target_arch = "x86_64")]
use splat_raster::lanes::{Avx2, Avx2Token};
use splat_raster::lanes::{Lanes, exp};

use splat_raster::project::{ALPHA_MAX, ALPHA_MIN};
use splat_raster::raster::depth_order;
use wide::{Wide, Wide3};

mod wide;

/// Rows per band: a Gaussian is listed once per band its silhouette reaches, and a row walks
/// its band's list, skipping the Gaussians that miss the row. Smaller bands list Gaussians more
/// often; larger ones make each row skip more.
const BAND: u32 = 4;

/// Gaussians a task places ([`Screen::place_block_on`]): enough to pay for the task.
const PLACE_BLOCK: usize = 256;

/// Pixels whose rays are evaluated together (one vector of f32 lanes).
const LANES: usize = 8;

/// Boxes nearer the camera's plane than this (in depth units) are treated as reaching behind it.
const NEAR: f32 = 1e-6;

/// The most slots a traversal keeps ([`crate::estimators::trace_stochastic`]'s bound).
const MAX_SLOTS: usize = 64;

/// The chord a row walks is solved for the silhouette grown by this factor (in the ellipse's
/// quadratic form) and widened by a pixel each way: it only saves evaluating rays, so it must
/// hold every pixel whose ray, evaluated in f32, meets the Gaussian. The growth is 1.6% of the
/// squared distance (up to 0.17 at a cut-off of 11); the f32 distance moved alphas by at most 2e-4
/// relative in the tests (needles seen from afar), that is by 4e-4 in the distance.
const SILHOUETTE_SLACK: f64 = 1.0 + 1.0 / 64.0;

/// The camera's image by the stochastic estimator (Sun et al., Algorithm 1, with
/// `samples_per_traversal` slots, section 3.5) in `Center` depth: per pixel the mean of `spp`
/// estimates, each the mean of its slots' colours (`background` for a slot the ray leaves
/// empty), the slots drawn in depth order (see the module docs). The same on any number of
/// threads; AVX2 and the baseline's lanes differ in the last bits (`Isa`). A caller that
/// traces every frame keeps a [`CameraTracer`] instead.
pub fn trace_camera_image(
    gaussians: &TraceGaussians,
    camera: &Camera,
    samples_per_traversal: u32,
    spp: u32,
    seed: u32,
    background: Vec3,
) -> Vec<Vec3> {
    CameraTracer::default().trace(
        gaussians,
        camera,
        samples_per_traversal,
        spp,
        seed,
        background,
    )
}

/// [`trace_camera_image`] with its working memory kept from call to call: the grid's arrays
/// (a few hundred bytes a Gaussian) are rewritten, not allocated afresh. On the cache's saved
/// levels at 80x45, fresh arrays made the lookup a third slower in page faults alone
/// (BENCHMARKS.md).
#[derive(Default)]
pub struct CameraTracer {
    grid: ScreenGrid,
}

impl std::fmt::Debug for CameraTracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CameraTracer")
            .field("ranked", &self.grid.facing.len())
            .finish_non_exhaustive()
    }
}

/// A copy holds no working memory (it is only that).
impl Clone for CameraTracer {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl CameraTracer {
    /// [`trace_camera_image`]'s image, the same bits.
    pub fn trace(
        &mut self,
        gaussians: &TraceGaussians,
        camera: &Camera,
        samples_per_traversal: u32,
        spp: u32,
        seed: u32,
        background: Vec3,
    ) -> Vec<Vec3> {
        self.grid.rebuild(gaussians, camera);
        let walk = Walk::new(&self.grid, camera, samples_per_traversal, seed, background);
        let spp = spp.max(1);
        let width = walk.width;
        let isa = Isa::detect();
        let mut image = vec![Vec3::ZERO; width * camera.height as usize];
        image.par_chunks_mut(width).enumerate().for_each_init(
            || Row::new(&walk),
            |row, (y, out)| {
                row.sums.fill(DVec3::ZERO);
                for s in 0..spp {
                    walk.estimate_on(isa, row, y as u32, s);
                }
                for (out, sum) in out.iter_mut().zip(&row.sums) {
                    *out = (*sum / spp as f64).as_vec3();
                }
            },
        );
        image
    }
}

/// [`trace_camera_image`]'s image by its definition: for each pixel, every Gaussian in front
/// of the camera in depth order, its alpha on the pixel's ray, and the slots filled as the
/// transmittance falls. No grid, no chords, no lanes but the one ray's: O(pixels x Gaussians),
/// for tests, which require the two to agree bit for bit.
pub fn reference_image(
    gaussians: &TraceGaussians,
    camera: &Camera,
    samples_per_traversal: u32,
    spp: u32,
    seed: u32,
    background: Vec3,
) -> Vec<Vec3> {
    let forward = camera.axes().2;
    let mut order: Vec<(f32, u32)> = (0..gaussians.len())
        .map(|i| (depth_of(gaussians, camera, forward, i), i as u32))
        .filter(|(depth, _)| *depth > 0.0)
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let frame = CameraFrame::new(camera);
    let facing: Vec<Facing> = order
        .iter()
        .map(|&(_, i)| Facing::new(gaussians, i as usize, &frame))
        .collect();
    let slots = slot_count(samples_per_traversal);
    let plane = camera.ray_directions();
    let (width, height) = (camera.width, camera.height);
    let isa = Isa::detect();
    let mut thresholds = vec![0.0f32; slots];
    let mut image = Vec::with_capacity((width * height) as usize);
    for y in 0..height {
        let w = plane.on_plane(0.5, y as f32 + 0.5)[1];
        for x in 0..width {
            let u = plane.on_plane(x as f32 + 0.5, y as f32 + 0.5)[0];
            let mut sum = DVec3::ZERO;
            for s in 0..spp.max(1) {
                let key = SampleKey::new(seed, y * width + x, s);
                let mut next = draw_thresholds::<Baseline>((), &key, &mut thresholds);
                let (mut t, mut filled, mut colour) = (1.0f32, 0, Vec3::ZERO);
                for f in &facing {
                    if filled == slots {
                        break;
                    }
                    let alpha = FacingRow::new(f, w).alpha_on(isa, u);
                    t *= 1.0 - alpha;
                    if t < next {
                        next = fill_slots::<Baseline>(
                            (),
                            &thresholds,
                            &mut filled,
                            &mut colour,
                            t,
                            f.color,
                        );
                    }
                }
                sum += estimate(colour, filled, slots, background).as_dvec3();
            }
            image.push((sum / spp.max(1) as f64).as_vec3());
        }
    }
    image
}

/// The slots a traversal keeps for `samples_per_traversal`: at least one, at most
/// [`MAX_SLOTS`].
fn slot_count(samples_per_traversal: u32) -> usize {
    (samples_per_traversal.max(1) as usize).min(MAX_SLOTS)
}

/// A ray's slots' thresholds ([`SampleKey::slot_thresholds`]) into `thresholds`; returns the
/// largest, the first the transmittance must fall below.
///
/// The estimate is the mean of the slots' colours, so the slots are interchangeable, and the
/// transmittance only falls, so the slots a ray has filled are always those whose thresholds
/// are above its transmittance: its state is how many it has filled, and its next threshold
/// the largest of the others ([`above_and_next`]). Nothing is sorted, no mask of open slots
/// is kept, and no branch is taken per slot.
#[inline(always)]
fn draw_thresholds<L: Lanes>(token: L::Token, key: &SampleKey, thresholds: &mut [f32]) -> f32 {
    key.slot_thresholds(thresholds);
    above_and_next::<L>(token, thresholds, f32::INFINITY).1
}

/// How many of `thresholds` are above `t`, and the largest not above it, or -1 (which no
/// transmittance falls below) when every one is. Thresholds are never NaN; a NaN `t` is above
/// none of them. Both are exact, so the same in any lanes: eight thresholds (the lookup's
/// default) are compared in `L`'s lanes at once, other counts one by one.
#[inline(always)]
fn above_and_next<L: Lanes>(token: L::Token, thresholds: &[f32], t: f32) -> (usize, f32) {
    if let Ok(eight) = <&[f32; 8]>::try_from(thresholds) {
        let (t, none) = (L::splat(token, t), L::splat(token, -1.0));
        let (mut above, mut largest) = (0, none);
        for first in (0..8).step_by(L::N) {
            let u = L::load(token, &eight[first..]);
            let is_above = t.lt(u);
            above += L::count(is_above) as usize;
            largest = L::select(is_above, none, u).max(largest);
        }
        return (above, largest.reduce_max());
    }
    thresholds
        .iter()
        .fold((0, -1.0f32), |(above, largest), &u| {
            if t < u {
                (above + 1, largest)
            } else {
                (above, if u > largest { u } else { largest })
            }
        })
}

/// A ray's slots after its transmittance fell to `t` across a hit of colour `color`: every
/// unfilled slot whose threshold is above `t` takes the hit (adds the colour). `filled` as
/// [`draw_thresholds`] describes it; returns the next threshold.
#[inline(always)]
fn fill_slots<L: Lanes>(
    token: L::Token,
    thresholds: &[f32],
    filled: &mut usize,
    colour: &mut Vec3,
    t: f32,
    color: Vec3,
) -> f32 {
    // The filled slots' thresholds are above every earlier transmittance, so above `t`: the
    // count of thresholds above `t` is the slots filled now (NaN counts none).
    let (above, next) = above_and_next::<L>(token, thresholds, t);
    let reached = above.max(*filled);
    *colour += (reached - *filled) as f32 * color;
    *filled = reached;
    next
}

/// [`LANES`] pixels' taking-part bytes (each 0 or 1) as a bit each, the first pixel's lowest:
/// one multiply moves byte `i`'s bit to bit `56 + i` (the partial products never overlap, so
/// nothing carries).
#[inline(always)]
fn taking_part_bits(bytes: &[u8]) -> u8 {
    let word = u64::from_le_bytes(bytes[..LANES].try_into().expect("LANES bytes"));
    (word.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u8
}

/// One estimate: the mean of the slots' colours, `background` for each slot left unfilled.
fn estimate(colour: Vec3, filled: usize, slots: usize, background: Vec3) -> Vec3 {
    (colour + (slots - filled) as f32 * background) / slots as f32
}

/// Gaussian `i`'s centre depth along the camera's forward axis, as
/// [`TraceGaussians::intersect`] computes it.
fn depth_of(g: &TraceGaussians, camera: &Camera, forward: Vec3, i: usize) -> f32 {
    (g.means[i] - camera.position).dot(forward)
}

/// One row's working memory, kept from row to row of a thread. The arrays read in lanes have
/// [`LANES`] - 1 pixels of padding past the row's end: a chord's window of [`LANES`] pixels
/// starts at any pixel of the row.
struct Row {
    /// Each pixel's transmittance so far.
    transmittance: Vec<f32>,
    /// Each pixel's next threshold ([`draw_thresholds`]): the transmittance falling below it
    /// fills a slot.
    next: Vec<f32>,
    /// Each pixel's slots' thresholds ([`draw_thresholds`]), `slots` a pixel.
    thresholds: Vec<f32>,
    /// Each pixel's slots filled (with a hit).
    filled: Vec<usize>,
    /// Each pixel's filled slots' colours summed.
    colour: Vec<Vec3>,
    /// Each pixel's 1 while it takes part, 0 once its slots are all filled (and in the
    /// padding): a window's [`LANES`] of them read as one word ([`taking_part_bits`]).
    taking_part: Vec<u8>,
    /// Each pixel's estimates summed.
    sums: Vec<DVec3>,
}

impl Row {
    /// Every pixel of row `y` at the start of `sample`: its slots' numbers drawn, none filled,
    /// the transmittance 1. Inlined into the walk, in its lanes' instruction set.
    #[inline(always)]
    fn start<L: Lanes>(&mut self, token: L::Token, walk: &Walk, y: u32, sample: u32) {
        let width = walk.width;
        self.transmittance.fill(1.0);
        self.filled.fill(0);
        self.colour.fill(Vec3::ZERO);
        self.taking_part[..width].fill(1);
        for (x, thresholds) in self.thresholds.chunks_exact_mut(walk.slots).enumerate() {
            let key = SampleKey::new(walk.seed, y * width as u32 + x as u32, sample);
            self.next[x] = draw_thresholds::<L>(token, &key, thresholds);
        }
    }

    fn new(walk: &Walk) -> Self {
        let padded = walk.width + LANES - 1;
        Self {
            transmittance: vec![1.0; padded],
            next: vec![-1.0; padded],
            thresholds: vec![0.0; walk.width * walk.slots],
            filled: vec![0; walk.width],
            colour: vec![Vec3::ZERO; walk.width],
            taking_part: vec![0; padded],
            sums: vec![DVec3::ZERO; walk.width],
        }
    }
}

/// What every row's walk reads.
struct Walk<'a> {
    grid: &'a ScreenGrid,
    plane: RayDirections,
    /// Each column's ray on the camera's plane z = 1 (its x), with [`Row`]'s padding (whose
    /// lanes never take part).
    columns: Vec<f32>,
    width: usize,
    slots: usize,
    seed: u32,
    background: Vec3,
}

impl<'a> Walk<'a> {
    fn new(
        grid: &'a ScreenGrid,
        camera: &Camera,
        samples_per_traversal: u32,
        seed: u32,
        background: Vec3,
    ) -> Self {
        let plane = camera.ray_directions();
        let width = camera.width as usize;
        let columns = (0..width + LANES - 1)
            .map(|x| plane.on_plane(x as f32 + 0.5, 0.5)[0])
            .collect();
        Self {
            grid,
            plane,
            columns,
            width,
            slots: slot_count(samples_per_traversal),
            seed,
            background,
        }
    }

    /// Estimate `sample` for each pixel of row `y`, added to the row's sums. The row's band is
    /// walked front to back once for all its rays; a ray takes part until every slot is
    /// filled, and the walk stops when no ray takes part. Each ray meets exactly the Gaussians
    /// [`reference_image`] finds on it, in the same order, with the same alphas.
    #[inline(always)]
    fn estimate<L: Lanes>(&self, token: L::Token, row: &mut Row, y: u32, sample: u32) {
        let (slots, width) = (self.slots, self.width);
        row.start::<L>(token, self, y, sample);
        let mut left = width;
        let w = self.plane.on_plane(0.5, y as f32 + 0.5)[1];
        let (mut first, mut last) = ([0u32; LANES], [0u32; LANES]);
        for chunk in self.grid.band(y / BAND) {
            if left == 0 {
                break;
            }
            // The chunk's chords on this row in lanes; then its Gaussians that meet the row, in
            // depth order.
            let mut meets = chunk.chords::<L>(token, y, &mut first, &mut last);
            while meets != 0 {
                let l = meets.trailing_zeros() as usize;
                meets &= meets - 1;
                let facing = &self.grid.facing[chunk.rank[l] as usize];
                let on_row = FacingRow::new(facing, w);
                self.walk_chord::<L>(
                    token,
                    (
                        (first[l] - PIXEL_BIAS_BITS) as usize,
                        (last[l] - PIXEL_BIAS_BITS) as usize,
                    ),
                    facing.color,
                    &on_row,
                    row,
                    &mut left,
                );
            }
        }
        let Row {
            filled,
            colour,
            sums,
            ..
        } = row;
        for (x, sum) in sums.iter_mut().enumerate() {
            *sum += estimate(colour[x], filled[x], slots, self.background).as_dvec3();
        }
    }

    /// One Gaussian on the pixels `from..=to` of a row: each taking part moves its
    /// transmittance, and fills its slots where it falls below its next threshold. The chord
    /// is walked in windows of [`LANES`] pixels from `from` (not in groups aligned to the
    /// row), so that a chord of `n` pixels takes `ceil(n / LANES)` evaluations: a window's
    /// lanes past `to` miss the Gaussian, their alpha 0.
    #[inline(always)]
    fn walk_chord<L: Lanes>(
        &self,
        token: L::Token,
        (from, to): (usize, usize),
        color: Vec3,
        on_row: &FacingRow,
        row: &mut Row,
        left: &mut usize,
    ) {
        let slots = self.slots;
        let Row {
            transmittance,
            next,
            thresholds,
            filled,
            colour,
            taking_part,
            ..
        } = row;
        for start in (from..=to).step_by(LANES) {
            let alive = taking_part_bits(&taking_part[start..start + LANES]);
            if alive == 0 {
                continue;
            }
            // Every lane's transmittance moves (a miss's alpha is 0, which leaves it as it
            // was, bit for bit); the lanes that fall below their next threshold fill slots.
            let mut crossed = 0u8;
            let (columns, here, next_here) = (
                &self.columns[start..start + LANES],
                &mut transmittance[start..start + LANES],
                &next[start..start + LANES],
            );
            for first in (0..LANES).step_by(L::N) {
                let alpha = on_row.alpha::<L>(token, L::load(token, &columns[first..]));
                let t = L::load(token, &here[first..]);
                let t = t * (L::splat(token, 1.0) - alpha);
                t.store(&mut here[first..]);
                crossed |= (L::bits(t.lt(L::load(token, &next_here[first..]))) << first) as u8;
            }
            crossed &= alive;
            while crossed != 0 {
                let x = start + crossed.trailing_zeros() as usize;
                crossed &= crossed - 1;
                let own = &thresholds[x * slots..(x + 1) * slots];
                next[x] = fill_slots::<L>(
                    token,
                    own,
                    &mut filled[x],
                    &mut colour[x],
                    transmittance[x],
                    color,
                );
                let done = filled[x] == slots;
                taking_part[x] &= !done as u8;
                *left -= done as usize;
            }
        }
    }

    /// [`Walk::estimate`] in `isa`'s lanes.
    fn estimate_on(&self, isa: Isa, row: &mut Row, y: u32, sample: u32) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: an `Avx2Token` exists only where the processor runs AVX2 and FMA
            // (`Avx2Token::detect`), which is all `estimate_avx2_fma` requires.
            Isa::Avx2(token) => unsafe { self.estimate_avx2_fma(token, row, y, sample) },
            Isa::Baseline => self.estimate::<Baseline>((), row, y, sample),
        }
    }

    /// [`Walk::estimate`] compiled for AVX2 and FMA, in their lanes.
    ///
    /// # Safety
    /// The processor must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn estimate_avx2_fma(&self, token: Avx2Token, row: &mut Row, y: u32, sample: u32) {
        self.estimate::<Avx2>(token, row, y, sample)
    }
}

/// The camera's centre and axes in f64, for [`Seen::new`].
struct CameraFrame {
    position: DVec3,
    /// Camera-space axes (+X right, +Y down, +Z forward) in world space, as columns.
    axes: DMat3,
}

impl CameraFrame {
    fn new(camera: &Camera) -> Self {
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
struct Facing {
    /// `K_x`, `K_y`, `K_z`.
    axes: [Vec3; 3],
    /// `M_x`, `M_y`, `M_z`.
    moments: [Vec3; 3],
    opacity: f32,
    /// The squared canonical distance beyond which alpha is below 1/255.
    cutoff: f32,
    /// Its colour seen from the camera.
    color: Vec3,
}

impl Facing {
    fn new(g: &TraceGaussians, i: usize, frame: &CameraFrame) -> Self {
        Self::seen(g, i, &Seen::new(g, i, frame), frame)
    }

    /// [`Facing::new`] from the terms the silhouette shares ([`Seen`]).
    #[inline(always)]
    fn seen(g: &TraceGaussians, i: usize, seen: &Seen, frame: &CameraFrame) -> Self {
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
struct Seen {
    /// `o = C (camera - mean)`.
    offset: DVec3,
    /// The camera's axes in the canonical frame: `K_x`, `K_y`, `K_z`.
    axes: [DVec3; 3],
}

impl Seen {
    #[inline(always)]
    fn new(g: &TraceGaussians, i: usize, frame: &CameraFrame) -> Self {
        let rows = g.canonical[i].map(|r| r.as_dvec3());
        let in_canonical = |v: DVec3| DVec3::new(rows[0].dot(v), rows[1].dot(v), rows[2].dot(v));
        Self {
            offset: in_canonical(frame.position - g.means[i].as_dvec3()),
            axes: [frame.axes.x_axis, frame.axes.y_axis, frame.axes.z_axis].map(in_canonical),
        }
    }
}

/// A [`Facing`] on one row (`w` fixed): `K v` and `o x K v` as `u` times a slope plus a base.
struct FacingRow {
    slope: Vec3,
    base: Vec3,
    moment_slope: Vec3,
    moment_base: Vec3,
    opacity: f32,
    cutoff: f32,
}

impl FacingRow {
    #[inline(always)]
    fn new(f: &Facing, w: f32) -> Self {
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
    fn alpha<L: Lanes>(&self, token: L::Token, u: L) -> L {
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
    fn alpha_on(&self, isa: Isa, u: f32) -> f32 {
        let mut out = [0.0f32; 8];
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2(token) => self
                .alpha::<Avx2>(token, Avx2::splat(token, u))
                .store(&mut out),
            Isa::Baseline => self
                .alpha::<Baseline>((), Baseline::splat((), u))
                .store(&mut out),
        }
        out[0]
    }
}

/// The Gaussians in front of the camera, sorted by centre depth (ties by index), and per band
/// of rows the ones whose silhouettes may reach it, in that order.
#[derive(Default)]
struct ScreenGrid {
    /// Each rank's terms for its alphas on the camera's rays.
    facing: Vec<Facing>,
    /// Band `b`'s Gaussians are `listed[starts[b]..starts[b + 1]]`, in depth order, a
    /// [`LANES`] of them a chunk: a row reads its band's in order, not scattered over the
    /// ranks, and solves a chunk's chords together.
    starts: Vec<usize>,
    listed: Vec<ListedChunk>,
    /// The building's working memory, kept for the next camera or cloud.
    scratch: GridScratch,
}

/// What [`ScreenGrid::rebuild`] makes and drops: kept so that a grid rebuilt every frame
/// writes to memory it already has (fresh, it cost the kernel a page fault each 4 KiB).
#[derive(Default)]
struct GridScratch {
    keys: Vec<u64>,
    sort: Vec<u64>,
    order: Vec<u32>,
    /// Each rank's place on the screen; `None` off the screen.
    placed: Vec<Option<Placed>>,
    next: Vec<usize>,
}

/// [`LANES`] Gaussians of a band's list, by lane: their ranks, and what their chords on a row
/// need ([`Placed::chord_terms`]). Lanes past the end of the list meet no row.
#[derive(Clone, Copy)]
struct ListedChunk {
    rank: [u32; LANES],
    /// The first and last row (inclusive) each may cover; +inf and -inf in an empty lane.
    rows: [[f32; LANES]; 2],
    /// The first and last column (inclusive).
    columns: [[f32; LANES]; 2],
    /// The silhouette's centre, x and y.
    centre: [[f32; LANES]; 2],
    /// [`Placed::chord_terms`].
    terms: [[f32; LANES]; 3],
}

impl ListedChunk {
    const EMPTY: Self = Self {
        rank: [0; LANES],
        rows: [[f32::INFINITY; LANES], [f32::NEG_INFINITY; LANES]],
        columns: [[0.0; LANES]; 2],
        centre: [[0.0; LANES]; 2],
        terms: [[0.0; LANES]; 3],
    };

    fn set(&mut self, lane: usize, rank: u32, p: &Placed) {
        self.rank[lane] = rank;
        for k in 0..2 {
            self.rows[k][lane] = p.rows[k] as f32;
            self.columns[k][lane] = p.columns[k] as f32;
            self.centre[k][lane] = p.centre[k];
        }
        for k in 0..3 {
            self.terms[k][lane] = p.chord_terms[k];
        }
    }

    /// The lanes whose Gaussians meet a pixel of row `y` (a bit each), with the first and last
    /// pixel they may meet there, `ceil(lo)..=floor(hi)`, as the bits of those whole numbers
    /// plus [`PIXEL_BIAS`]. A bounded silhouette (`k2 > 0`) is narrowed to the ellipse's
    /// chord at the row's centre, `dx = k3 dy +- sqrt(k1 dy^2 + k2)`, a pixel wider each way
    /// (pixel x's centre is x + 0.5); the rest keep their rectangle's columns. Plain multiplies
    /// and adds (no fused multiply-adds), so AVX2 and the baseline's lanes give the same
    /// chords.
    #[inline(always)]
    fn chords<L: Lanes>(
        &self,
        token: L::Token,
        y: u32,
        first_pixel: &mut [u32; LANES],
        last_pixel: &mut [u32; LANES],
    ) -> u32 {
        let c = |v: f32| L::splat(token, v);
        let (row, centre) = (y as f32, y as f32 + 0.5);
        let mut meets = 0;
        for first in (0..LANES).step_by(L::N) {
            let load = |v: &[f32; LANES]| L::load(token, &v[first..]);
            let in_rows = load(&self.rows[0]).le(c(row)) & c(row).le(load(&self.rows[1]));
            let [k1, k2, k3] = self.terms.each_ref().map(load);
            let (columns_from, columns_to) = (load(&self.columns[0]), load(&self.columns[1]));
            let dy = c(centre) - load(&self.centre[1]);
            let squared = dy * dy * k1 + k2;
            let (mid, half) = (load(&self.centre[0]) + dy * k3, squared.sqrt());
            // NaN (no chord) fails `le` and `ge`; `max` and `min` give their second operand,
            // so `lo` and `hi` are in the rectangle's columns, 0..=32767 (`MAX_IMAGE_SIDE`).
            let bounded = k2.gt(c(0.0));
            let lo = L::select(
                bounded,
                (mid - half - c(1.5)).max(columns_from),
                columns_from,
            );
            let hi = L::select(bounded, (mid + half + c(0.5)).min(columns_to), columns_to);
            // Adding 2^23 rounds to the nearest whole number, exactly (the spacing of floats
            // there is 1); one more or less where that went the wrong way.
            let bias = c(PIXEL_BIAS);
            let (lo_near, hi_near) = (lo + bias, hi + bias);
            let from = L::select((lo_near - bias).lt(lo), lo_near + c(1.0), lo_near);
            let to = L::select((hi_near - bias).gt(hi), hi_near - c(1.0), hi_near);
            let chord = squared.ge(c(0.0)) | L::and_not(in_rows, bounded);
            from.store_bits(&mut first_pixel[first..]);
            to.store_bits(&mut last_pixel[first..]);
            meets |= L::bits(in_rows & chord & from.le(to)) << first;
        }
        meets
    }
}

/// 2^23: a whole number `n` in `0..2^23` plus this is a float whose bits are
/// [`PIXEL_BIAS_BITS`] plus `n`, so a pixel's index goes from lanes to an integer without a
/// conversion.
const PIXEL_BIAS: f32 = 8_388_608.0;
const PIXEL_BIAS_BITS: u32 = PIXEL_BIAS.to_bits();

/// One Gaussian on the screen.
#[derive(Clone, Copy, Default)]
struct Placed {
    /// Its silhouette's centre: the pixels `p` with `(p - centre)^T Q (p - centre) <= 1` are
    /// those whose rays meet its alpha >= 1/255 ellipsoid ([`Screen::silhouette`]).
    centre: [f32; 2],
    /// The pixel columns and rows (inclusive) its silhouette may cover.
    columns: [u32; 2],
    rows: [u32; 2],
    /// The silhouette's chords by row ([`Placed::chord_terms`]); zero where no bounded
    /// silhouette exists (a box reaching behind the camera, or rounding): every pixel of its
    /// rectangle is evaluated.
    chord_terms: [f32; 3],
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
    fn chord_terms(form: [f64; 3]) -> [f32; 3] {
        let [a, b, c] = form;
        let terms = [(b * b - a * c) / (a * a), SILHOUETTE_SLACK / a, -b / a].map(|k| k as f32);
        Self::checked_chord_terms(a, terms)
    }

    /// [`Placed::chord_terms`] from its terms (rounded to f32) and the form's `a`: zero unless
    /// `a > 0`, the terms are finite and `k2 > 0`.
    #[inline(always)]
    fn checked_chord_terms(a: f64, terms: [f32; 3]) -> [f32; 3] {
        if a > 0.0 && terms.iter().all(|k| k.is_finite()) && terms[1] > 0.0 {
            terms
        } else {
            [0.0; 3]
        }
    }
}

/// The camera's constants for placing Gaussians on its screen.
struct Screen {
    /// The camera's centre and axes (its centre is the one `place` measures from).
    frame: CameraFrame,
    /// World to camera space (+X right, +Y down, +Z forward).
    to_camera: glam::DMat3,
    focal: f64,
    half: [f64; 2],
    size: [f64; 2],
}

impl Screen {
    fn new(camera: &Camera) -> Self {
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
    fn place(&self, g: &TraceGaussians, i: usize, depth: f32) -> Option<(Placed, Facing)> {
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
    fn place_block_on(
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
            Isa::Avx2(_) => unsafe {
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
    unsafe fn place_block_avx2_fma(
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
    fn place_block(
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
    fn place4(
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
    fn box_rectangle(&self, lo: DVec3, hi: DVec3) -> [f64; 4] {
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
    fn silhouette(&self, seen: &Seen, cutoff: f32) -> Option<([f64; 2], [f64; 3], [f64; 2])> {
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
fn pixel_span(from: f64, to: f64, size: f64) -> Option<[u32; 2]> {
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

impl ScreenGrid {
    /// The grid of `g` seen by `camera`, in the memory this grid holds.
    fn rebuild(&mut self, g: &TraceGaussians, camera: &Camera) {
        let bands = camera.height.div_ceil(BAND) as usize;
        let forward = camera.axes().2;
        let screen = Screen::new(camera);
        let isa = Isa::detect();
        let GridScratch {
            keys,
            sort,
            order,
            placed,
            next,
        } = &mut self.scratch;
        // The Gaussians in front of the camera by depth, ties by index: one order on any
        // thread count. A positive depth's bits order as it does ([`depth_order`]'s keys).
        let depth = |i: usize| depth_of(g, camera, forward, i);
        keys.clear();
        keys.extend((0..g.len()).filter_map(|i| {
            let d = depth(i);
            (d > 0.0).then_some((d.to_bits() as u64) << 32 | i as u64)
        }));
        order.clear();
        order.resize(keys.len(), 0);
        depth_order(keys, sort, order);
        // Then placed and faced (the silhouette and the facing terms share their canonical
        // frame) in that order, straight into the grid's arrays; every entry is overwritten,
        // so only a longer array's new tail is filled first.
        placed.resize(order.len(), None);
        self.facing.resize(order.len(), Facing::default());
        placed
            .par_chunks_mut(PLACE_BLOCK)
            .zip(self.facing.par_chunks_mut(PLACE_BLOCK))
            .zip(order.par_chunks(PLACE_BLOCK))
            .for_each(|((placed, facing), ranked)| {
                screen.place_block_on(isa, g, &depth, ranked, placed, facing)
            });

        // A counting sort of the ranks by band, each band's in rank order, each band's list
        // padded to whole chunks.
        let bands_of = |p: &Placed| (p.rows[0] / BAND) as usize..=(p.rows[1] / BAND) as usize;
        let starts = &mut self.starts;
        starts.clear();
        starts.resize(bands + 1, 0);
        for p in placed.iter().flatten() {
            for b in bands_of(p) {
                starts[b + 1] += 1;
            }
        }
        for b in 0..bands {
            starts[b + 1] = starts[b] + starts[b + 1].div_ceil(LANES) * LANES;
        }
        self.listed.clear();
        self.listed
            .resize(starts[bands] / LANES, ListedChunk::EMPTY);
        next.clear();
        next.extend_from_slice(&starts[..bands]);
        for (rank, p) in placed.iter().enumerate() {
            let Some(p) = p else { continue };
            for b in bands_of(p) {
                self.listed[next[b] / LANES].set(next[b] % LANES, rank as u32, p);
                next[b] += 1;
            }
        }
    }

    /// Band `b`'s Gaussians, front to back, in chunks.
    fn band(&self, b: u32) -> &[ListedChunk] {
        &self.listed[self.starts[b as usize] / LANES..self.starts[b as usize + 1] / LANES]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DepthMode;
    use render_base::hash::{hash32, unit_f32};
    use splat_raster::{ColorModel, GaussianCloud};

    /// A window's taking-part bytes read as bits: every pattern of [`LANES`] bytes, each bit
    /// where its byte is 1 and nowhere else, read from any offset of a row.
    #[test]
    fn taking_part_bytes_read_as_one_bit_each() {
        for pattern in 0..=255u8 {
            let mut bytes = [0u8; 3 + LANES];
            for l in 0..LANES {
                bytes[3 + l] = (pattern >> l) & 1;
            }
            assert_eq!(taking_part_bits(&bytes[3..]), pattern, "{pattern:08b}");
            // The same bytes one pixel later: the first lane's bit is now the padding's 0.
            assert_eq!(taking_part_bits(&bytes[2..]), pattern << 1, "{pattern:08b}");
        }
    }

    /// Filling counts the thresholds above the transmittance, in any order: slots filled
    /// earlier stay filled, the colour grows by the newly filled count, and the next threshold
    /// is the largest not above the transmittance (-1 when all are filled); for four slots
    /// (one by one) and for eight (in lanes), in every width of lanes this processor runs.
    #[test]
    fn filling_takes_every_threshold_above_the_transmittance() {
        check_filling::<splat_raster::lanes::Portable>(());
        check_filling::<Baseline>(());
        #[cfg(target_arch = "x86_64")]
        if let Some(token) = Avx2Token::detect() {
            check_filling::<Avx2>(token);
        }
    }

    fn check_filling<L: Lanes>(token: L::Token) {
        let fill = |thresholds: &[f32], filled: &mut usize, colour: &mut Vec3, t, color| {
            fill_slots::<L>(token, thresholds, filled, colour, t, color)
        };
        let four = [0.6f32, 0.2, 0.9, 0.6];
        let key = SampleKey::new(1, 2, 3);
        let mut drawn = [0.0f32; 8];
        let largest = draw_thresholds::<L>(token, &key, &mut drawn);
        assert_eq!(largest, drawn.iter().fold(0.0f32, |a, &b| a.max(b)));
        assert_eq!(above_and_next::<L>(token, &four, f32::INFINITY), (0, 0.9));
        let (mut filled, mut colour) = (0usize, Vec3::ZERO);
        let red = Vec3::X;
        assert_eq!(fill(&four, &mut filled, &mut colour, 0.7, red), 0.6);
        assert_eq!((filled, colour), (1, red));
        // Both equal thresholds at once.
        assert_eq!(fill(&four, &mut filled, &mut colour, 0.5, Vec3::Y), 0.2);
        assert_eq!((filled, colour), (3, Vec3::new(1.0, 2.0, 0.0)));
        // NaN fills nothing.
        fill(&four, &mut filled, &mut colour, f32::NAN, red);
        assert_eq!((filled, colour), (3, Vec3::new(1.0, 2.0, 0.0)));
        assert_eq!(fill(&four, &mut filled, &mut colour, 0.0, Vec3::Z), -1.0);
        assert_eq!((filled, colour), (4, Vec3::new(1.0, 2.0, 1.0)));
        assert_eq!(estimate(colour, filled, 4, Vec3::ONE), colour / 4.0);
        // Eight, the largest in each lane in turn: all of them next, and none above 1.
        for top in 0..8 {
            let mut eight = [0.6f32, 0.2, 0.9, 0.6, 0.05, 0.7, 0.3, 0.3];
            eight[top] = 0.95;
            assert_eq!(above_and_next::<L>(token, &eight, 1.0), (0, 0.95), "{top}");
            assert_eq!(above_and_next::<L>(token, &eight, f32::NAN), (0, 0.95));
        }
        // 0.95, 0.9 and both 0.6 are above 0.55; next the largest below, 0.3 (twice).
        let eight = [0.6f32, 0.2, 0.9, 0.6, 0.05, 0.95, 0.3, 0.3];
        let (mut filled, mut colour) = (0usize, Vec3::ZERO);
        assert_eq!(fill(&eight, &mut filled, &mut colour, 0.55, red), 0.3);
        assert_eq!((filled, colour), (4, 4.0 * red));
        assert_eq!(fill(&eight, &mut filled, &mut colour, 0.1, red), 0.05);
        assert_eq!(filled, 7);
        assert_eq!(fill(&eight, &mut filled, &mut colour, 0.01, red), -1.0);
        assert_eq!((filled, colour), (8, 8.0 * red));
    }

    /// Placing four Gaussians at once in f64 lanes ([`Screen::place4`], as the grid does, in
    /// AVX2 where the processor runs it, and in the baseline's) gives [`Screen::place`]'s bits:
    /// every field of the
    /// placed Gaussian and its facing terms, for 1,001 Gaussians (a short last group of four)
    /// seen from cameras that put some behind them, some straddling the camera's plane (no
    /// silhouette: the whole screen), some around the camera (no bounded ellipse: their box's
    /// rectangle), some off the screen, and needles among them.
    #[test]
    fn four_at_a_time_is_placing_one_by_one_bit_for_bit() {
        let r = |k: u32, i: u32| unit_f32(hash32(&[k, i, 7]));
        let mut cloud = GaussianCloud::new(ColorModel::Sh(0));
        for i in 0..1001 {
            let m = [0, 1, 2].map(|k| 6.0 * r(k, i) - 3.0);
            let mut ls = [3, 4, 5].map(|k| 3.0 * r(k, i) - 3.0);
            if i % 7 == 0 {
                ls[(i / 7 % 3) as usize] = -7.0;
            }
            if i % 11 == 0 {
                ls = [-16.0, -16.0, 1.0];
                ls.rotate_left((i / 11 % 3) as usize);
            }
            let q = [6, 7, 8, 9].map(|k| r(k, i) - 0.5);
            cloud.push(
                m,
                ls,
                q,
                &[r(10, i), r(11, i), r(12, i)],
                4.0 * r(13, i) - 2.0,
            );
        }
        let g = TraceGaussians::new(&cloud);
        let bits = |p: &Option<(Placed, Facing)>| -> Option<Vec<u32>> {
            let (p, f) = p.as_ref()?;
            let mut v = vec![p.centre[0].to_bits(), p.centre[1].to_bits()];
            v.extend(p.columns.iter().chain(&p.rows));
            v.extend(p.chord_terms.map(f32::to_bits));
            let vectors = f.axes.iter().chain(&f.moments).chain([&f.color]);
            v.extend(vectors.flat_map(|a| a.to_array().map(f32::to_bits)));
            v.extend([f.opacity.to_bits(), f.cutoff.to_bits()]);
            Some(v)
        };
        let mut kinds = [0usize; 5];
        for eye in [
            Vec3::new(0.3, -0.2, -9.0),
            Vec3::new(0.5, 0.4, 0.2),
            Vec3::new(7.0, 5.0, 6.0),
        ] {
            let camera = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 50.0, 64, 48).unwrap();
            let (screen, forward) = (Screen::new(&camera), camera.axes().2);
            let depth = |i: usize| depth_of(&g, &camera, forward, i);
            // Every Gaussian, behind the camera or not, in an order that is not the index's.
            let ranked: Vec<u32> = (0..g.len() as u32).map(|i| (i * 389) % 1001).collect();
            let placed_by = |isa: Isa| {
                let mut placed = vec![None; g.len()];
                let mut facing = vec![Facing::default(); g.len()];
                let blocks = placed
                    .chunks_mut(PLACE_BLOCK)
                    .zip(facing.chunks_mut(PLACE_BLOCK));
                for ((p, f), r) in blocks.zip(ranked.chunks(PLACE_BLOCK)) {
                    screen.place_block_on(isa, &g, &depth, r, p, f);
                }
                let placed_and_faced: Vec<_> = placed
                    .into_iter()
                    .zip(facing)
                    .map(|(p, f)| p.map(|p| (p, f)))
                    .collect();
                placed_and_faced
            };
            let (best, baseline) = (placed_by(Isa::detect()), placed_by(Isa::Baseline));
            for (rank, &i) in ranked.iter().enumerate() {
                let i = i as usize;
                let want = screen.place(&g, i, depth(i));
                assert_eq!(bits(&best[rank]), bits(&want), "Gaussian {i} from {eye}");
                assert_eq!(
                    bits(&baseline[rank]),
                    bits(&want),
                    "Gaussian {i} from {eye}"
                );
                let kind = match want {
                    None if depth(i) > 0.0 => 0,
                    None => 1,
                    Some((p, _)) if p.chord_terms[1] > 0.0 => 2,
                    Some((p, _)) if p.columns == [0, 63] && p.rows == [0, 47] => 3,
                    Some(_) => 4,
                };
                kinds[kind] += 1;
            }
        }
        // Off the screen, behind, a silhouette, the whole screen, a box's rectangle.
        eprintln!("placed by kind: {kinds:?}");
        assert!(kinds.iter().all(|&n| n > 0), "{kinds:?}");
    }

    /// A ray's alpha from the camera's shared terms ([`Facing`], [`FacingRow::alpha`]: the
    /// line's distance by a cross product in f32, the lanes' `exp`) is
    /// [`TraceGaussians::intersect`]'s (the closest point, libm's `exp`), and the same alpha in
    /// f64, to within 5e-4 relative, on every pixel of three cameras and 300 Gaussians with
    /// needles (one scale e^-6 of the others') among them; where only one of the two finds a
    /// hit, the hit is at the 1/255 threshold. When written: 2.1e-4 against `intersect` and
    /// 2.0e-4 against f64 (`intersect` itself 5.1e-5), the worst on the needles seen from afar;
    /// a wrong axis, moment or row term moves alphas by far more.
    #[test]
    fn a_rays_alpha_from_the_shared_terms_is_intersects() {
        let r = |k: u32, i: u32| unit_f32(hash32(&[k, i]));
        let mut cloud = GaussianCloud::new(ColorModel::Rgb);
        for i in 0..300 {
            let m = [0, 1, 2].map(|k| 2.0 * r(k, i) - 1.0);
            let mut ls = [3, 4, 5].map(|k| 3.0 * r(k, i) - 3.5);
            if i % 5 == 0 {
                ls[(i / 5 % 3) as usize] = -6.0;
            }
            let q = [6, 7, 8, 9].map(|k| r(k, i) - 0.5);
            cloud.push(m, ls, q, &[0.5, 0.5, 0.5], 4.0 * r(10, i) - 2.0);
        }
        let g = TraceGaussians::new(&cloud);
        let isa = Isa::detect();
        let (mut worst, mut worst_f64, mut both, mut one_sided) = (0.0f64, 0.0f64, 0, 0);
        for eye in [
            Vec3::new(0.3, -0.2, -4.0),
            Vec3::new(3.0, 2.0, 2.5),
            Vec3::new(0.0, 0.1, -1.2),
        ] {
            let camera = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 50.0, 40, 30).unwrap();
            let (frame, plane, forward) = (
                CameraFrame::new(&camera),
                camera.ray_directions(),
                camera.axes().2,
            );
            for i in 0..g.len() {
                if !(depth_of(&g, &camera, forward, i) > 0.0) {
                    continue;
                }
                let facing = Facing::new(&g, i, &frame);
                for y in 0..camera.height {
                    let w = plane.on_plane(0.5, y as f32 + 0.5)[1];
                    let on_row = FacingRow::new(&facing, w);
                    for x in 0..camera.width {
                        let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                        let d = plane.at(px, py);
                        let want = g
                            .intersect(i, eye, d, 0.0, f32::INFINITY, DepthMode::Center, forward)
                            .map(|h| h.alpha);
                        let got = on_row.alpha_on(isa, plane.on_plane(px, py)[0]);
                        let at_threshold = |a: f32| a < ALPHA_MIN as f32 * (1.0 + 1e-4);
                        match (want, got > 0.0) {
                            (Some(a), true) => {
                                both += 1;
                                worst = worst.max(((got - a) / a).abs() as f64);
                                let exact = alpha_f64(&g, i, eye, d);
                                worst_f64 = worst_f64.max((got as f64 / exact - 1.0).abs());
                            }
                            (Some(a), false) => {
                                assert!(at_threshold(a), "Gaussian {i}, pixel {x},{y}: missed {a}");
                                one_sided += 1;
                            }
                            (None, true) => {
                                assert!(at_threshold(got), "Gaussian {i}, pixel {x},{y}: {got}");
                                one_sided += 1;
                            }
                            (None, false) => {}
                        }
                    }
                }
            }
        }
        eprintln!(
            "{both} hits in both, {one_sided} in one; worst relative difference {worst:.2e} \
             against intersect, {worst_f64:.2e} against f64"
        );
        assert!(both > 20_000, "only {both} hits compared");
        assert!(worst < 5e-4 && worst_f64 < 5e-4, "{worst}, {worst_f64}");
    }

    /// Gaussian `i`'s alpha on the ray `o + t d`, in f64.
    fn alpha_f64(g: &TraceGaussians, i: usize, o: Vec3, d: Vec3) -> f64 {
        let rows = g.canonical[i].map(|r| r.as_dvec3());
        let in_canonical = |v: DVec3| DVec3::new(rows[0].dot(v), rows[1].dot(v), rows[2].dot(v));
        let offset = in_canonical(o.as_dvec3() - g.means[i].as_dvec3());
        let along = in_canonical(d.as_dvec3());
        let distance = offset.cross(along).length_squared() / along.length_squared();
        (g.opacity[i] as f64 * (-0.5 * distance).exp()).min(ALPHA_MAX)
    }
}
