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
//!
//! - [`slots`]: a ray's slots and their thresholds (the estimate's arithmetic).
//! - [`walk`]: a row of pixels walking its band's Gaussians front to back.
//! - [`facing`]: the terms a Gaussian shares across the camera's rays.
//! - [`placement`]: the Gaussians placed on the screen (their silhouettes, four at a time
//!   in f64 lanes by [`wide`]).
//! - [`grid`]: the Gaussians sorted by depth and listed per band of rows.

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

use splat_raster::depth_sort::depth_order;
use splat_raster::project::{ALPHA_MAX, ALPHA_MIN};
use wide::{Wide, Wide3};

mod facing;
mod grid;
mod placement;
mod slots;
mod walk;
mod wide;

use facing::*;
use grid::*;
use placement::*;
use slots::*;
use walk::*;

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
