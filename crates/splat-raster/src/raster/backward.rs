//! The backward pass: per tile, the gradients of every contributing splat (the scalar kernel;
//! the lane kernels are `crate::simd`'s), then each Gaussian's records summed in tile order
//! and its projection's adjoint, so gradients are bit-identical for any thread count.

use super::*;

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
    let zero = F::zero();

    let isa = Isa::of(state.config.kernel);
    let splats_f32 = as_f32::<_, Vec<Splat<f32>>>(&state.splats);
    // One record per live entry (tile-major, like `entries`), written tile by tile.
    let live_records = state.live_ranges.last().map_or(0, |r| r.1) as usize;
    // Zeroed in parallel: a serial fill is a fixed cost that no number of threads shortens.
    let mut records = Vec::with_capacity(live_records);
    records.par_extend(
        (0..live_records)
            .into_par_iter()
            .map(|_| SplatGrad::<F>::default()),
    );
    let per_tile = split_by_tile(&mut records, &state.live_ranges);
    per_tile.into_par_iter().enumerate().for_each(|(ti, rec)| {
        let a = state.tile_ranges[ti].0 as usize;
        let list = &state.entries[a..a + rec.len()];
        if list.is_empty() {
            return;
        }
        let origin = [
            (ti as u32 % state.tiles_x) * TILE,
            (ti as u32 / state.tiles_x) * TILE,
        ];
        let mut input = TilePixels {
            origin,
            contributors: [0; TILE_PIXELS],
            dl_dc: [[zero; 3]; TILE_PIXELS],
            dl_dd: [zero; TILE_PIXELS],
            bg_dot: [zero; TILE_PIXELS],
            t_final: [zero; TILE_PIXELS],
            depth: grads.depth.is_some(),
        };
        for (x, y, p) in tile_pixels(ti, state.tiles_x, w, h) {
            let q = (y * w + x) as usize;
            let dl_dc = grads.color[q];
            let dl_dt = grads.transmittance.map_or(zero, |g| g[q]);
            let dl_dd = grads.depth.map_or(zero, |g| g[q]);
            let bg_dot = dl_dc[0] * bg[0] + dl_dc[1] * bg[1] + dl_dc[2] * bg[2] + dl_dt;
            // A pixel with no upstream gradient (masked out of the loss) adds exactly nothing
            // to any splat: give it no contributors, so the kernels skip it.
            let silent = dl_dc == [zero; 3] && dl_dd == zero && bg_dot == zero;
            input.contributors[p] = if silent {
                0
            } else {
                state.n_contrib[ti * TILE_PIXELS + p]
            };
            input.dl_dc[p] = dl_dc;
            input.dl_dd[p] = dl_dd;
            input.bg_dot[p] = bg_dot;
            input.t_final[p] = state.final_t[ti * TILE_PIXELS + p];
        }
        if let (Some(isa), Some(splats), Some(input)) = (isa, splats_f32, as_f32(&input))
            && let Some(rec) = F::grads_as_f32(rec)
        {
            isa.backward_tile(splats, list, input, rec)
        } else {
            backward_tile_scalar(&state.splats, list, &input, rec)
        }
    });

    // For each splat, its records in tile order; for each Gaussian, its splat.
    let index = state.index.get_or_init(|| {
        SplatIndex::build(
            &state.entries,
            &state.tile_ranges,
            &state.live_ranges,
            &state.ids,
            state.splats.len(),
            cloud.len(),
        )
    });
    assert_eq!(
        index.splat_of.len(),
        cloud.len(),
        "backward over a cloud other than the one drawn"
    );
    let mut out = cloud.zeros_like();
    let lanes = (
        isa,
        as_f32::<_, GaussianCloud<f32>>(cloud),
        as_f32::<_, CameraTerms<f32>>(&cam),
        as_f32::<_, Vec<SplatGrad<f32>>>(&records),
    );
    if let ((Some(isa), Some(cloud), Some(cam), Some(records)), Some(out)) =
        (lanes, as_f32_mut::<_, GaussianCloud<f32>>(&mut out))
    {
        gradients_in_lanes(isa, cloud, cam, state.config.low_pass, records, index, out);
        sanitize(out);
    } else {
        let stride = cloud.color_stride();
        let GaussianCloud {
            means,
            log_scales,
            rotations,
            colors,
            opacity_logits,
            ..
        } = &mut out;
        // The scalar kernel and the f64 path: per Gaussian, in parallel, sum its splat's
        // records and back-propagate them into its parameters, written in place.
        (
            means.par_chunks_mut(3),
            log_scales.par_chunks_mut(3),
            rotations.par_chunks_mut(4),
            colors.par_chunks_mut(stride),
            opacity_logits.par_iter_mut(),
        )
            .into_par_iter()
            .with_min_len(256)
            .enumerate()
            .for_each(|(g, (dm, ds, dr, dc, dl))| {
                let si = index.splat_of[g] as usize;
                if si == u32::MAX as usize {
                    return; // culled: no gradient
                }
                let total = index.total(si, &records);
                project_backward(
                    cloud,
                    g,
                    &cam,
                    state.config.low_pass,
                    &total,
                    dm,
                    ds,
                    dr,
                    dc,
                    dl,
                );
            });
        sanitize(&mut out);
    }
    out
}

/// Gaussians per block of the lanes' parameter gradients: a block's summed splat gradients sit
/// on the stack, and the blocks are fixed by the cloud's size, never by the threads.
pub(super) const GRADIENT_BLOCK: usize = 256;

/// Per block of Gaussians, in parallel: sum each Gaussian's splat records in tile order, then
/// back-propagate them into its parameters in lanes (`project_lanes`), written in place.
pub(super) fn gradients_in_lanes(
    isa: Isa,
    cloud: &GaussianCloud<f32>,
    cam: &CameraTerms<f32>,
    low_pass: LowPass,
    records: &[SplatGrad<f32>],
    index: &SplatIndex,
    out: &mut GaussianCloud<f32>,
) {
    let stride = cloud.color_stride();
    let GaussianCloud {
        means,
        log_scales,
        rotations,
        colors,
        opacity_logits,
        ..
    } = out;
    (
        means.par_chunks_mut(3 * GRADIENT_BLOCK),
        log_scales.par_chunks_mut(3 * GRADIENT_BLOCK),
        rotations.par_chunks_mut(4 * GRADIENT_BLOCK),
        colors.par_chunks_mut(stride * GRADIENT_BLOCK),
        opacity_logits.par_chunks_mut(GRADIENT_BLOCK),
    )
        .into_par_iter()
        .enumerate()
        .for_each(
            |(block, (means, log_scales, rotations, colors, opacity_logits))| {
                let first = block * GRADIENT_BLOCK;
                let mut totals = [None; GRADIENT_BLOCK];
                let totals = &mut totals[..opacity_logits.len()];
                for (i, total) in totals.iter_mut().enumerate() {
                    let si = index.splat_of[first + i] as usize;
                    if si == u32::MAX as usize {
                        continue; // culled: no gradient
                    }
                    *total = Some(index.total(si, records));
                }
                let out = GradientBlock {
                    means,
                    log_scales,
                    rotations,
                    colors,
                    opacity_logits,
                };
                isa.project_backward_range(cloud, first, totals, cam, low_pass, out);
            },
        );
}

/// Back-to-front gradients of one tile, one pixel at a time: the reference kernel. One record
/// per splat of the tile's list.
pub(super) fn backward_tile_scalar<F: Real>(
    splats: &[Splat<F>],
    list: &[u32],
    input: &TilePixels<F>,
    records: &mut [SplatGrad<F>],
) {
    let zero = F::zero();
    let [x0, y0] = input.origin;
    // Per-pixel state of the back-to-front walk.
    #[derive(Clone, Copy)]
    struct Px<F> {
        t: F,
        accum: [F; 3],
        accum_d: F,
        last_alpha: F,
        last_color: [F; 3],
        last_depth: F,
    }
    let mut px: [Px<F>; TILE_PIXELS] = std::array::from_fn(|p| Px {
        t: input.t_final[p],
        accum: [zero; 3],
        accum_d: zero,
        last_alpha: zero,
        last_color: [zero; 3],
        last_depth: zero,
    });
    let cx: [F; TILE as usize] = std::array::from_fn(|i| F::c((x0 + i as u32) as f64 + 0.5));
    let cy: [F; TILE as usize] = std::array::from_fn(|j| F::c((y0 + j as u32) as f64 + 0.5));
    // Entries past every pixel's last contributor add nothing: start at the last one.
    let last = input.contributors.iter().copied().max().unwrap_or(0) as usize;
    for k in (0..last.min(list.len())).rev() {
        let s = &splats[list[k] as usize];
        let r = &mut records[k];
        let [ax, ay, bx, by] = rect_in_tile(s, [x0, y0]);
        for y in ay..=by {
            let py = cy[(y - y0) as usize];
            for x in ax..=bx {
                let p = ((y - y0) * TILE + (x - x0)) as usize;
                // Pixels outside the image have no contributors.
                if k as u32 >= input.contributors[p] {
                    continue;
                }
                let Some((alpha, gauss, dx, dy)) = splat_alpha(s, cx[(x - x0) as usize], py) else {
                    continue;
                };
                let st = &mut px[p];
                let (dl_dc, dl_dd) = (input.dl_dc[p], input.dl_dd[p]);
                st.t = st.t / (F::one() - alpha);
                let wgt = alpha * st.t;
                for ch in 0..3 {
                    r.color[ch] = r.color[ch] + wgt * dl_dc[ch];
                }
                r.depth = r.depth + wgt * dl_dd;
                let mut dl_dalpha = zero;
                for ch in 0..3 {
                    st.accum[ch] = st.last_alpha * st.last_color[ch]
                        + (F::one() - st.last_alpha) * st.accum[ch];
                    dl_dalpha = dl_dalpha + (s.color[ch] - st.accum[ch]) * dl_dc[ch];
                }
                st.accum_d =
                    st.last_alpha * st.last_depth + (F::one() - st.last_alpha) * st.accum_d;
                dl_dalpha = dl_dalpha + (s.depth - st.accum_d) * dl_dd;
                dl_dalpha = dl_dalpha * st.t;
                st.last_alpha = alpha;
                st.last_color = s.color;
                st.last_depth = s.depth;
                dl_dalpha = dl_dalpha - input.t_final[p] / (F::one() - alpha) * input.bg_dot[p];
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
}

/// Replaces non-finite gradient values by 0: a NaN never reaches a parameter.
pub(super) fn sanitize<F: Real>(g: &mut CloudGradients<F>) {
    for group in g.groups_mut() {
        group.par_chunks_mut(1 << 14).for_each(|chunk| {
            for v in chunk {
                if !v.is_finite() {
                    *v = F::zero();
                }
            }
        });
    }
}
