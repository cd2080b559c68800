//! The forward pass: a tile composited front to back (the scalar kernel; the lane kernels are
//! `crate::simd`'s), and [`render`], which projects, bins, composites and gathers the images.

use super::*;

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

/// Splat `s`'s pixel rectangle clipped to the tile at `origin`: inclusive x0, y0, x1, y1 (empty
/// when x0 > x1 or y0 > y1).
pub(super) fn rect_in_tile<F: Real>(s: &Splat<F>, origin: [u32; 2]) -> [u32; 4] {
    let [x0, y0] = origin;
    [
        s.rect[0].max(x0),
        s.rect[1].max(y0),
        s.rect[2].min(x0 + TILE - 1),
        s.rect[3].min(y0 + TILE - 1),
    ]
}

/// The kernel that runs for float type `F`: lanes only exist for f32.
pub(super) fn resolved_kernel<F: Real>(asked: Kernel) -> Kernel {
    if std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>() {
        asked.resolve()
    } else {
        Kernel::Scalar
    }
}

/// `x` as its f32 instance, when `F` is f32 (generic code hands f32 data to the lane kernels
/// without `unsafe`).
pub(super) fn as_f32<T: Any, U: Any>(x: &T) -> Option<&U> {
    (x as &dyn Any).downcast_ref()
}

pub(super) fn as_f32_mut<T: Any, U: Any>(x: &mut T) -> Option<&mut U> {
    (x as &mut dyn Any).downcast_mut()
}

/// Front-to-back compositing of one tile, one pixel at a time: the reference kernel.
///
/// Splat-major: each splat visits only the tile pixels inside its rectangle, in depth order, so
/// every pixel still sees its splats front to back with the same arithmetic as a per-pixel loop.
pub(super) fn forward_tile_scalar<F: Real>(
    splats: &[Splat<F>],
    list: &[u32],
    origin: [u32; 2],
    size: [u32; 2],
    want_depth: bool,
    out: &mut TileOut<F>,
) {
    let ([x0, y0], [w, h]) = (origin, size);
    let t_min = F::c(T_MIN);
    let mut done = [false; TILE_PIXELS];
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
    // Pixel-centre coordinates of the tile's columns and rows, converted once.
    let cx: [F; TILE as usize] = std::array::from_fn(|i| F::c((x0 + i as u32) as f64 + 0.5));
    let cy: [F; TILE as usize] = std::array::from_fn(|j| F::c((y0 + j as u32) as f64 + 0.5));
    for (k, &si) in list.iter().enumerate() {
        if active == 0 {
            break;
        }
        let s = &splats[si as usize];
        let [ax, ay, bx, by] = rect_in_tile(s, [x0, y0]);
        for y in ay..=by {
            let py = cy[(y - y0) as usize];
            for x in ax..=bx {
                let p = ((y - y0) * TILE + (x - x0)) as usize;
                if done[p] {
                    continue;
                }
                out.lane_evaluations += 1;
                let Some((alpha, _, _, _)) = splat_alpha(s, cx[(x - x0) as usize], py) else {
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
                let c = &mut out.color[p];
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
}

/// A row-major `w` x `h` image from tile-major values (each tile's 16x16 pixels in a run,
/// tiles row by row), a row at a time in parallel, each tile's stretch of the row copied whole.
pub(super) fn tile_major_to_rows<T: Copy + Default + Send + Sync>(
    tile_major: &[T],
    w: u32,
    h: u32,
) -> Vec<T> {
    let tile = TILE as usize;
    let tiles_x = w.div_ceil(TILE) as usize;
    let mut img = vec![T::default(); (w * h) as usize];
    img.par_chunks_mut(w as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let (ty, py) = (y / tile, y % tile);
            for (tx, run) in row.chunks_mut(tile).enumerate() {
                let from = (ty * tiles_x + tx) * TILE_PIXELS + py * tile;
                run.copy_from_slice(&tile_major[from..from + run.len()]);
            }
        });
    img
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
    let bins = project_and_bin(cloud, &cam, config, true);
    let bg = config.background.map(|v| F::c(v as f64));
    let tile_px = TILE_PIXELS;
    let n_tiles = (tiles_x * tiles_y) as usize;

    let kernel = resolved_kernel::<F>(config.kernel);
    let isa = Isa::of(kernel);
    let splats_f32 = as_f32::<_, Vec<Splat<f32>>>(&bins.splats);
    // Tile-major outputs, written in parallel one tile each; the backward pass reads the counts
    // and final transmittances in this order.
    let tile_major = n_tiles * tile_px;
    let mut color_tm = vec![[F::zero(); 3]; tile_major];
    let mut final_t = vec![F::one(); tile_major];
    let mut n_contrib = vec![0u32; tile_major];
    let mut depth_tm = vec![F::zero(); if config.depth { tile_major } else { 0 }];
    let mut depth_chunks: Vec<Option<&mut [F]>> = if config.depth {
        depth_tm.chunks_mut(tile_px).map(Some).collect()
    } else {
        (0..n_tiles).map(|_| None).collect()
    };
    let lane_evaluations = (
        color_tm.par_chunks_mut(tile_px),
        final_t.par_chunks_mut(tile_px),
        n_contrib.par_chunks_mut(tile_px),
        depth_chunks.par_iter_mut(),
    )
        .into_par_iter()
        .enumerate()
        .map(|(ti, (color, t, n, depth))| {
            let (a, b) = bins.tile_ranges[ti];
            let list = &bins.entries[a as usize..b as usize];
            let origin = [(ti as u32 % tiles_x) * TILE, (ti as u32 / tiles_x) * TILE];
            let mut out = TileOut::new();
            match (isa, splats_f32, as_f32_mut(&mut out)) {
                (Some(isa), Some(splats), Some(out)) => {
                    isa.forward_tile(splats, list, origin, [w, h], config.depth, out)
                }
                _ => {
                    forward_tile_scalar(&bins.splats, list, origin, [w, h], config.depth, &mut out)
                }
            }
            for p in 0..tile_px {
                let (tp, c) = (out.t[p], out.color[p]);
                color[p] = [c[0] + tp * bg[0], c[1] + tp * bg[1], c[2] + tp * bg[2]];
            }
            t.copy_from_slice(&out.t);
            n.copy_from_slice(&out.n);
            if let Some(d) = depth {
                d.copy_from_slice(&out.depth);
            }
            out.lane_evaluations
        })
        .sum();

    // Each tile's live entries: up to its last contributor.
    let live_counts: Vec<u32> = n_contrib
        .par_chunks(tile_px)
        .map(|n| n.iter().copied().max().unwrap_or(0))
        .collect();
    let mut live_ranges = Vec::with_capacity(n_tiles);
    let mut live_end = 0u32;
    for &n in &live_counts {
        live_ranges.push((live_end, live_end + n));
        live_end += n;
    }
    let color = tile_major_to_rows(&color_tm, w, h);
    let transmittance = tile_major_to_rows(&final_t, w, h);
    let depth = config.depth.then(|| tile_major_to_rows(&depth_tm, w, h));
    let state = ForwardState {
        splats: bins.splats,
        ids: bins.ids,
        entries: bins.entries,
        tile_ranges: bins.tile_ranges,
        n_contrib,
        live_ranges,
        final_t,
        tiles_x,
        lane_evaluations,
        config: RasterConfig { kernel, ..*config },
        index: OnceLock::new(),
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
