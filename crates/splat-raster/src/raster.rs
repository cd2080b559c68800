//! The tiled rasteriser: project, bin into 16x16 tiles, sort each tile by depth, composite front
//! to back; and the backward pass over the same lists.
//!
//! Compositing per pixel (3DGS): `alpha_i = min(0.99, opacity_i exp(-d^T K_i d / 2))`, skipped
//! below 1/255; `C = sum_i c_i alpha_i T_i + T_final * background`, `T_{i+1} = T_i (1 - alpha_i)`;
//! the splat that would take `T` below 1e-4 and every splat after it are left out. Colour is
//! HDR: nothing is clamped above.
//!
//! Determinism: the backward pass writes one gradient record per (tile, splat) entry, each tile's
//! pixels in a fixed order, and sums every Gaussian's records in tile order; no atomics, so
//! gradients are bit-identical for any thread count.

use crate::camera::Camera;
use crate::cloud::{CloudGradients, GaussianCloud};
use crate::project::*;
use crate::real::Real;
use rayon::prelude::*;

/// Side of a tile in pixels.
pub const TILE: u32 = 16;

/// Rasteriser settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterConfig {
    pub low_pass: LowPass,
    /// Gaussians whose camera-space depth is not beyond this are culled (world units).
    pub near: f32,
    pub background: [f32; 3],
    /// Also output the accumulated depth `sum_i z_i alpha_i T_i`.
    pub depth: bool,
}

impl Default for RasterConfig {
    fn default() -> Self {
        Self {
            low_pass: LowPass::Classic,
            near: 0.01,
            background: [0.0; 3],
            depth: false,
        }
    }
}

/// Rendered images, row-major, row 0 at the top.
#[derive(Debug, Clone)]
pub struct RenderOutput<F: Real> {
    pub width: u32,
    pub height: u32,
    pub color: Vec<[F; 3]>,
    pub transmittance: Vec<F>,
    /// Accumulated depth, when asked for.
    pub depth: Option<Vec<F>>,
}

/// What the backward pass needs from the forward pass.
#[derive(Debug, Clone)]
pub struct ForwardState<F: Real> {
    splats: Vec<Splat<F>>,
    /// Index of each splat's Gaussian.
    ids: Vec<u32>,
    /// Splat indices, tile-major, each tile sorted by depth.
    entries: Vec<u32>,
    /// Per tile, its range in `entries`.
    tile_ranges: Vec<(u32, u32)>,
    /// Per pixel, entries processed in its tile list (the last contributor + 1), tile-major.
    n_contrib: Vec<u32>,
    /// Per pixel final transmittance, tile-major.
    final_t: Vec<F>,
    tiles_x: u32,
    tiles_y: u32,
    config: RasterConfig,
}

impl<F: Real> ForwardState<F> {
    /// Number of (tile, splat) pairs.
    pub fn entry_count(&self) -> usize {
        self.entries.len()
    }
    /// Number of splats that survived culling.
    pub fn visible_count(&self) -> usize {
        self.splats.len()
    }
    /// Splat-pixel pairs the forward pass visits (every pixel of each splat's rectangle within
    /// its tiles; pixels whose transmittance is exhausted stop earlier): the work measure of the
    /// benchmarks.
    pub fn evaluations(&self) -> u64 {
        (0..self.tile_ranges.len())
            .into_par_iter()
            .map(|ti| {
                let (a, b) = self.tile_ranges[ti];
                let (x0, y0) = (
                    (ti as u32 % self.tiles_x) * TILE,
                    (ti as u32 / self.tiles_x) * TILE,
                );
                let mut n = 0u64;
                for &e in &self.entries[a as usize..b as usize] {
                    let s = &self.splats[e as usize];
                    let (ax, ay) = (s.rect[0].max(x0), s.rect[1].max(y0));
                    let (bx, by) = (s.rect[2].min(x0 + TILE - 1), s.rect[3].min(y0 + TILE - 1));
                    if ax <= bx && ay <= by {
                        n += ((bx - ax + 1) * (by - ay + 1)) as u64;
                    }
                }
                n
            })
            .sum()
    }
}

struct Bins<F: Real> {
    splats: Vec<Splat<F>>,
    ids: Vec<u32>,
    entries: Vec<u32>,
    tile_ranges: Vec<(u32, u32)>,
}

fn project_all<F: Real>(
    cloud: &GaussianCloud<F>,
    cam: &CameraTerms<F>,
    config: &RasterConfig,
) -> (Vec<Splat<F>>, Vec<u32>) {
    let near = F::c(config.near as f64);
    let projected: Vec<Option<Splat<F>>> = (0..cloud.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|g| project(cloud, g, cam, config.low_pass, near))
        .collect();
    let mut splats = Vec::with_capacity(projected.len());
    let mut ids = Vec::with_capacity(projected.len());
    for (g, s) in projected.into_iter().enumerate() {
        if let Some(s) = s {
            splats.push(s);
            ids.push(g as u32);
        }
    }
    (splats, ids)
}

fn tile_span(s: &[u32; 4]) -> (u32, u32, u32, u32) {
    (s[0] / TILE, s[1] / TILE, s[2] / TILE, s[3] / TILE)
}

/// Bins splats into tiles; each tile's list is sorted by (depth, Gaussian id) when `sort`.
fn bin<F: Real>(
    splats: Vec<Splat<F>>,
    ids: Vec<u32>,
    tiles_x: u32,
    tiles_y: u32,
    sort: bool,
) -> Bins<F> {
    let n_tiles = (tiles_x * tiles_y) as usize;
    let mut counts = vec![0u32; n_tiles + 1];
    for s in &splats {
        let (tx0, ty0, tx1, ty1) = tile_span(&s.rect);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                counts[(ty * tiles_x + tx) as usize] += 1;
            }
        }
    }
    let mut offsets = vec![0u32; n_tiles + 1];
    for t in 0..n_tiles {
        offsets[t + 1] = offsets[t] + counts[t];
    }
    let mut cursor = offsets.clone();
    let mut entries = vec![0u32; offsets[n_tiles] as usize];
    for (i, s) in splats.iter().enumerate() {
        let (tx0, ty0, tx1, ty1) = tile_span(&s.rect);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                let t = (ty * tiles_x + tx) as usize;
                entries[cursor[t] as usize] = i as u32;
                cursor[t] += 1;
            }
        }
    }
    let tile_ranges: Vec<(u32, u32)> = (0..n_tiles).map(|t| (offsets[t], offsets[t + 1])).collect();
    if sort {
        // Split `entries` into per-tile slices and sort each in parallel.
        let mut slices: Vec<&mut [u32]> = Vec::with_capacity(n_tiles);
        let mut rest: &mut [u32] = &mut entries;
        for &(a, b) in &tile_ranges {
            let (head, tail) = rest.split_at_mut((b - a) as usize);
            slices.push(head);
            rest = tail;
        }
        slices.into_par_iter().for_each(|list| {
            list.sort_unstable_by(|&x, &y| {
                let (sx, sy) = (&splats[x as usize], &splats[y as usize]);
                sx.depth
                    .partial_cmp(&sy.depth)
                    .unwrap_or(std::cmp::Ordering::Equal)
                    .then(ids[x as usize].cmp(&ids[y as usize]))
            })
        });
    }
    Bins {
        splats,
        ids,
        entries,
        tile_ranges,
    }
}

/// Projected splats binned into tiles without sorting (for stochastic splatting): the splats,
/// their Gaussian ids, the tile-major entries, each tile's range, and the tiles per row.
#[allow(clippy::type_complexity)]
pub(crate) fn bin_for_stochastic(
    cloud: &GaussianCloud<f32>,
    camera: &Camera,
    config: &RasterConfig,
) -> (Vec<Splat<f32>>, Vec<u32>, Vec<u32>, Vec<(u32, u32)>, u32) {
    let cam = CameraTerms::<f32>::new(camera);
    let tiles_x = camera.width.div_ceil(TILE);
    let tiles_y = camera.height.div_ceil(TILE);
    let (splats, ids) = project_all(cloud, &cam, config);
    let b = bin(splats, ids, tiles_x, tiles_y, false);
    (b.splats, b.ids, b.entries, b.tile_ranges, tiles_x)
}

/// The pixels of tile `ti` inside the image: (x, y, index within the tile).
pub(crate) fn tile_pixels(
    ti: usize,
    tiles_x: u32,
    w: u32,
    h: u32,
) -> impl Iterator<Item = (u32, u32, usize)> {
    let (x0, y0) = ((ti as u32 % tiles_x) * TILE, (ti as u32 / tiles_x) * TILE);
    (0..TILE * TILE).filter_map(move |k| {
        let (x, y) = (x0 + k % TILE, y0 + k / TILE);
        (x < w && y < h).then_some((x, y, k as usize))
    })
}

/// Evaluates alpha of splat `s` at pixel centre `(px, py)`; None when it is skipped.
#[inline(always)]
pub fn splat_alpha<F: Real>(s: &Splat<F>, px: F, py: F) -> Option<(F, F, F, F)> {
    let dx = px - s.xy[0];
    let dy = py - s.xy[1];
    let power = -F::c(0.5) * (s.conic[0] * dx * dx + s.conic[2] * dy * dy) - s.conic[1] * dx * dy;
    // Most evaluations are pixels a splat does not reach: reject them before `exp`.
    if power > F::zero() || power < s.power_min {
        return None;
    }
    let gauss = power.exp();
    let alpha = (s.opacity * gauss).min(F::c(ALPHA_MAX));
    if alpha < F::c(ALPHA_MIN) {
        return None;
    }
    Some((alpha, gauss, dx, dy))
}

/// Renders the cloud; returns the images and the state the backward pass needs.
pub fn render<F: Real>(
    cloud: &GaussianCloud<F>,
    camera: &Camera,
    config: &RasterConfig,
) -> (RenderOutput<F>, ForwardState<F>) {
    let cam = CameraTerms::<F>::new(camera);
    let (w, h) = (camera.width, camera.height);
    let tiles_x = w.div_ceil(TILE);
    let tiles_y = h.div_ceil(TILE);
    let (splats, ids) = project_all(cloud, &cam, config);
    let bins = bin(splats, ids, tiles_x, tiles_y, true);
    let bg = config.background.map(|v| F::c(v as f64));
    let t_min = F::c(T_MIN);
    let tile_px = (TILE * TILE) as usize;
    let n_tiles = (tiles_x * tiles_y) as usize;

    struct TileOut<F> {
        color: Vec<[F; 3]>,
        t: Vec<F>,
        depth: Vec<F>,
        n: Vec<u32>,
    }
    let outs: Vec<TileOut<F>> = (0..n_tiles)
        .into_par_iter()
        .map(|ti| {
            let (a, b) = bins.tile_ranges[ti];
            let list = &bins.entries[a as usize..b as usize];
            let local: Vec<Splat<F>> = list.iter().map(|&i| bins.splats[i as usize]).collect();
            let tx = ti as u32 % tiles_x;
            let ty = ti as u32 / tiles_x;
            let mut out = TileOut {
                color: vec![[F::zero(); 3]; tile_px],
                t: vec![F::one(); tile_px],
                depth: vec![F::zero(); tile_px],
                n: vec![0; tile_px],
            };
            // Splat-major: each splat visits only the tile pixels inside its rectangle, in depth
            // order, so every pixel still sees its splats front to back with the same arithmetic
            // as a per-pixel loop.
            let (x0, y0) = (tx * TILE, ty * TILE);
            let mut done = vec![false; tile_px];
            let mut active = 0usize;
            for j in 0..TILE {
                for i in 0..TILE {
                    if x0 + i >= w || y0 + j >= h {
                        done[(j * TILE + i) as usize] = true;
                    } else {
                        active += 1;
                    }
                }
            }
            let mut col = vec![[F::zero(); 3]; tile_px];
            // Pixel-centre coordinates of the tile's columns and rows, converted once.
            let cx: [F; TILE as usize] =
                std::array::from_fn(|i| F::c((x0 + i as u32) as f64 + 0.5));
            let cy: [F; TILE as usize] =
                std::array::from_fn(|j| F::c((y0 + j as u32) as f64 + 0.5));
            let want_depth = config.depth;
            for (k, s) in local.iter().enumerate() {
                if active == 0 {
                    break;
                }
                let (ax, ay) = (s.rect[0].max(x0), s.rect[1].max(y0));
                let (bx, by) = (s.rect[2].min(x0 + TILE - 1), s.rect[3].min(y0 + TILE - 1));
                for y in ay..=by {
                    let py = cy[(y - y0) as usize];
                    for x in ax..=bx {
                        let p = ((y - y0) * TILE + (x - x0)) as usize;
                        if done[p] {
                            continue;
                        }
                        let Some((alpha, _, _, _)) = splat_alpha(s, cx[(x - x0) as usize], py)
                        else {
                            continue;
                        };
                        let t = out.t[p];
                        let next_t = t * (F::one() - alpha);
                        if next_t < t_min {
                            done[p] = true;
                            active -= 1;
                            continue;
                        }
                        let wgt = alpha * t;
                        let c = &mut col[p];
                        for ch in 0..3 {
                            c[ch] = c[ch] + wgt * s.color[ch];
                        }
                        if want_depth {
                            out.depth[p] = out.depth[p] + wgt * s.depth;
                        }
                        out.t[p] = next_t;
                        out.n[p] = k as u32 + 1;
                    }
                }
            }
            for p in 0..tile_px {
                let t = out.t[p];
                let c = col[p];
                out.color[p] = [c[0] + t * bg[0], c[1] + t * bg[1], c[2] + t * bg[2]];
            }
            out
        })
        .collect();

    let npx = (w * h) as usize;
    let mut color = vec![[F::zero(); 3]; npx];
    let mut transmittance = vec![F::one(); npx];
    let mut depth = if config.depth {
        Some(vec![F::zero(); npx])
    } else {
        None
    };
    let mut n_contrib = Vec::with_capacity(n_tiles * tile_px);
    let mut final_t = Vec::with_capacity(n_tiles * tile_px);
    for (ti, o) in outs.iter().enumerate() {
        for (x, y, p) in tile_pixels(ti, tiles_x, w, h) {
            let q = (y * w + x) as usize;
            color[q] = o.color[p];
            transmittance[q] = o.t[p];
            if let Some(d) = depth.as_mut() {
                d[q] = o.depth[p];
            }
        }
        n_contrib.extend_from_slice(&o.n);
        final_t.extend_from_slice(&o.t);
    }
    let state = ForwardState {
        splats: bins.splats,
        ids: bins.ids,
        entries: bins.entries,
        tile_ranges: bins.tile_ranges,
        n_contrib,
        final_t,
        tiles_x,
        tiles_y,
        config: *config,
    };
    (
        RenderOutput {
            width: w,
            height: h,
            color,
            transmittance,
            depth,
        },
        state,
    )
}

/// Upstream gradients per pixel, row-major.
#[derive(Debug, Clone, Copy)]
pub struct PixelGrads<'a, F: Real> {
    pub color: &'a [[F; 3]],
    /// Gradient with respect to the final transmittance (alpha = 1 - T), if the loss uses it.
    pub transmittance: Option<&'a [F]>,
    /// Gradient with respect to the accumulated depth, if the loss uses it.
    pub depth: Option<&'a [F]>,
}

/// Gradients of the loss with respect to every parameter of `cloud`.
pub fn backward<F: Real>(
    cloud: &GaussianCloud<F>,
    camera: &Camera,
    state: &ForwardState<F>,
    grads: PixelGrads<'_, F>,
) -> CloudGradients<F> {
    let cam = CameraTerms::<F>::new(camera);
    let (w, h) = (camera.width, camera.height);
    let bg = state.config.background.map(|v| F::c(v as f64));
    let tile_px = (TILE * TILE) as usize;
    let n_tiles = (state.tiles_x * state.tiles_y) as usize;
    let zero = F::zero();

    // One record per entry, tile by tile.
    let records: Vec<Vec<SplatGrad<F>>> = (0..n_tiles)
        .into_par_iter()
        .map(|ti| {
            let (a, b) = state.tile_ranges[ti];
            let list = &state.entries[a as usize..b as usize];
            let mut rec = vec![SplatGrad::<F>::default(); list.len()];
            if list.is_empty() {
                return rec;
            }
            let local: Vec<Splat<F>> = list.iter().map(|&i| state.splats[i as usize]).collect();
            let tx = ti as u32 % state.tiles_x;
            let ty = ti as u32 / state.tiles_x;
            let (x0, y0) = (tx * TILE, ty * TILE);
            // Per-pixel state of the back-to-front walk.
            #[derive(Clone, Copy)]
            struct Px<F> {
                n: u32,
                dl_dc: [F; 3],
                dl_dd: F,
                bg_dot: F,
                t_final: F,
                t: F,
                accum: [F; 3],
                accum_d: F,
                last_alpha: F,
                last_color: [F; 3],
                last_depth: F,
            }
            let mut px = vec![
                Px {
                    n: 0,
                    dl_dc: [zero; 3],
                    dl_dd: zero,
                    bg_dot: zero,
                    t_final: zero,
                    t: zero,
                    accum: [zero; 3],
                    accum_d: zero,
                    last_alpha: zero,
                    last_color: [zero; 3],
                    last_depth: zero,
                };
                tile_px
            ];
            for j in 0..TILE {
                for i in 0..TILE {
                    let (x, y) = (x0 + i, y0 + j);
                    if x >= w || y >= h {
                        continue;
                    }
                    let p = (j * TILE + i) as usize;
                    let q = (y * w + x) as usize;
                    let dl_dc = grads.color[q];
                    let dl_dt = grads.transmittance.map_or(zero, |g| g[q]);
                    let t_final = state.final_t[ti * tile_px + p];
                    px[p] = Px {
                        n: state.n_contrib[ti * tile_px + p],
                        dl_dc,
                        dl_dd: grads.depth.map_or(zero, |g| g[q]),
                        // d/d alpha_i of the terms that depend on T_final: background and T itself.
                        bg_dot: dl_dc[0] * bg[0] + dl_dc[1] * bg[1] + dl_dc[2] * bg[2] + dl_dt,
                        t_final,
                        t: t_final,
                        ..px[p]
                    };
                }
            }
            let cx: [F; TILE as usize] =
                std::array::from_fn(|i| F::c((x0 + i as u32) as f64 + 0.5));
            let cy: [F; TILE as usize] =
                std::array::from_fn(|j| F::c((y0 + j as u32) as f64 + 0.5));
            for k in (0..local.len()).rev() {
                let s = &local[k];
                let r = &mut rec[k];
                let (ax, ay) = (s.rect[0].max(x0), s.rect[1].max(y0));
                let (bx, by) = (
                    s.rect[2].min(x0 + TILE - 1).min(w - 1),
                    s.rect[3].min(y0 + TILE - 1).min(h - 1),
                );
                for y in ay..=by {
                    let py = cy[(y - y0) as usize];
                    for x in ax..=bx {
                        let st = &mut px[((y - y0) * TILE + (x - x0)) as usize];
                        if k as u32 >= st.n {
                            continue;
                        }
                        let Some((alpha, gauss, dx, dy)) =
                            splat_alpha(s, cx[(x - x0) as usize], py)
                        else {
                            continue;
                        };
                        st.t = st.t / (F::one() - alpha);
                        let wgt = alpha * st.t;
                        for ch in 0..3 {
                            r.color[ch] = r.color[ch] + wgt * st.dl_dc[ch];
                        }
                        r.depth = r.depth + wgt * st.dl_dd;
                        let mut dl_dalpha = zero;
                        for ch in 0..3 {
                            st.accum[ch] = st.last_alpha * st.last_color[ch]
                                + (F::one() - st.last_alpha) * st.accum[ch];
                            dl_dalpha = dl_dalpha + (s.color[ch] - st.accum[ch]) * st.dl_dc[ch];
                        }
                        st.accum_d =
                            st.last_alpha * st.last_depth + (F::one() - st.last_alpha) * st.accum_d;
                        dl_dalpha = dl_dalpha + (s.depth - st.accum_d) * st.dl_dd;
                        dl_dalpha = dl_dalpha * st.t;
                        st.last_alpha = alpha;
                        st.last_color = s.color;
                        st.last_depth = s.depth;
                        dl_dalpha = dl_dalpha - st.t_final / (F::one() - alpha) * st.bg_dot;
                        // alpha = min(0.99, opacity * G): no gradient through the cap.
                        if s.opacity * gauss > F::c(ALPHA_MAX) {
                            continue;
                        }
                        r.opacity = r.opacity + gauss * dl_dalpha;
                        let dl_dpower = alpha * dl_dalpha;
                        r.xy[0] = r.xy[0] + dl_dpower * (s.conic[0] * dx + s.conic[1] * dy);
                        r.xy[1] = r.xy[1] + dl_dpower * (s.conic[1] * dx + s.conic[2] * dy);
                        r.conic[0] = r.conic[0] - F::c(0.5) * dx * dx * dl_dpower;
                        r.conic[1] = r.conic[1] - dx * dy * dl_dpower;
                        r.conic[2] = r.conic[2] - F::c(0.5) * dy * dy * dl_dpower;
                    }
                }
            }
            rec
        })
        .collect();

    // For each splat, its records in tile order.
    let n_splats = state.splats.len();
    let mut counts = vec![0u32; n_splats + 1];
    for &e in &state.entries {
        counts[e as usize + 1] += 1;
    }
    for i in 0..n_splats {
        counts[i + 1] += counts[i];
    }
    let mut slots = vec![0u32; state.entries.len()];
    let mut cursor = counts.clone();
    for (pos, &e) in state.entries.iter().enumerate() {
        slots[cursor[e as usize] as usize] = pos as u32;
        cursor[e as usize] += 1;
    }
    let flat: Vec<&SplatGrad<F>> = records.iter().flat_map(|r| r.iter()).collect();

    let mut out = cloud.zeros_like();
    let stride = cloud.color_stride();
    // Per splat (in Gaussian order), sum its records and back-propagate into its parameters.
    // (Gaussian, d mean, d log-scale, d rotation, d colour, d opacity logit).
    type GaussianGrad<F> = (u32, [F; 3], [F; 3], [F; 4], Vec<F>, F);
    let per_gaussian: Vec<GaussianGrad<F>> = (0..n_splats)
        .into_par_iter()
        .with_min_len(256)
        .map(|si| {
            let mut total = SplatGrad::<F>::default();
            for &pos in &slots[counts[si] as usize..counts[si + 1] as usize] {
                total.add(flat[pos as usize]);
            }
            let g = state.ids[si] as usize;
            let (mut dm, mut ds, mut dr, mut dc, mut dl) =
                ([zero; 3], [zero; 3], [zero; 4], vec![zero; stride], zero);
            project_backward(
                cloud,
                g,
                &cam,
                state.config.low_pass,
                &total,
                &mut dm,
                &mut ds,
                &mut dr,
                &mut dc,
                &mut dl,
            );
            (g as u32, dm, ds, dr, dc, dl)
        })
        .collect();
    for (g, dm, ds, dr, dc, dl) in per_gaussian {
        let g = g as usize;
        out.means[3 * g..3 * g + 3].copy_from_slice(&dm);
        out.log_scales[3 * g..3 * g + 3].copy_from_slice(&ds);
        out.rotations[4 * g..4 * g + 4].copy_from_slice(&dr);
        out.colors[stride * g..stride * (g + 1)].copy_from_slice(&dc);
        out.opacity_logits[g] = dl;
    }
    sanitize(&mut out);
    out
}

/// Replaces non-finite gradient values by 0: a NaN never reaches a parameter.
fn sanitize<F: Real>(g: &mut CloudGradients<F>) {
    for group in g.groups_mut() {
        for v in group.iter_mut() {
            if !v.is_finite() {
                *v = F::zero();
            }
        }
    }
}
