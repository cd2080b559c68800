//! Projection and binning: the cloud projected in fixed chunks, its splats binned into 16x16
//! tiles, and each tile's list sorted front to back by a radix sort of the depths.

use super::*;
use crate::depth_sort::depth_order;

pub(super) struct Bins<F: Real> {
    pub(super) splats: Vec<Splat<F>>,
    pub(super) ids: Vec<u32>,
    pub(super) entries: Vec<u32>,
    pub(super) tile_ranges: Vec<(u32, u32)>,
}

pub(super) fn tile_span(s: &[u32; 4]) -> (u32, u32, u32, u32) {
    (s[0] / TILE, s[1] / TILE, s[2] / TILE, s[3] / TILE)
}

/// Gaussians per chunk of the parallel projection and binning: about 64 chunks, so that a
/// cache level's 5-20 thousand Gaussians still spread over many cores, but never under 1024
/// (each chunk keeps a count per tile) nor over 8192. It depends on the cloud's size alone,
/// never on the threads.
pub(super) fn chunk_size(gaussians: usize) -> usize {
    (gaussians / 64).clamp(1024, 8192)
}

/// One chunk's splats binned into tiles: tile `t`'s list is `keys[offsets[t]..offsets[t + 1]]`,
/// in splat order. A key holds the splat's index within the chunk in its low 32 bits and, when the lists are to
/// be depth sorted, the f32 bits of its depth above them (positive floats order as their bits,
/// so sorting the keys sorts by depth, ties to the lower index). The keys are made here, where
/// the splats are read in order, and not by a later pass that would look every entry's splat up
/// again in scattered order.
pub(super) struct ChunkBins {
    pub(super) offsets: Vec<u32>,
    pub(super) keys: Vec<u64>,
}

impl ChunkBins {
    /// Bins `splats` into `n_tiles` tiles of a grid `tiles_x` wide (a counting sort).
    fn new<F: Real>(splats: &[Splat<F>], tiles_x: u32, n_tiles: usize, depth_keys: bool) -> Self {
        let mut offsets = vec![0u32; n_tiles + 1];
        for s in splats {
            let (tx0, ty0, tx1, ty1) = tile_span(&s.rect);
            for ty in ty0..=ty1 {
                for tx in tx0..=tx1 {
                    offsets[(ty * tiles_x + tx) as usize + 1] += 1;
                }
            }
        }
        for t in 0..n_tiles {
            offsets[t + 1] += offsets[t];
        }
        let mut cursor = offsets.clone();
        let mut keys = vec![0u64; offsets[n_tiles] as usize];
        for (i, s) in splats.iter().enumerate() {
            let depth_bits = if depth_keys {
                ((s.depth.as_f64() as f32).to_bits() as u64) << 32
            } else {
                0
            };
            let key = depth_bits | i as u64;
            let (tx0, ty0, tx1, ty1) = tile_span(&s.rect);
            for ty in ty0..=ty1 {
                for tx in tx0..=tx1 {
                    let t = (ty * tiles_x + tx) as usize;
                    keys[cursor[t] as usize] = key;
                    cursor[t] += 1;
                }
            }
        }
        Self { offsets, keys }
    }

    fn len(&self, tile: usize) -> u32 {
        self.offsets[tile + 1] - self.offsets[tile]
    }

    fn list(&self, tile: usize) -> &[u64] {
        &self.keys[self.offsets[tile] as usize..self.offsets[tile + 1] as usize]
    }
}

/// Projects the cloud and bins its splats into tiles; each tile's list is sorted by (depth,
/// Gaussian id) when `sort`.
///
/// In parallel, and as a serial pass would: fixed chunks of Gaussians are projected and binned
/// on their own, each while its splats are still in cache; then the splats are laid end to end
/// in Gaussian order and each tile concatenates its chunks' lists, every key moved by its
/// chunk's first splat. The chunks depend on the cloud's size alone, so the lists do not depend
/// on the thread count. (Serial, the binning was a sixth of a 300k-Gaussian frame at 2 threads
/// and bound the lookup's scaling: issue 31.)
pub(super) fn project_and_bin<F: Real>(
    cloud: &GaussianCloud<F>,
    cam: &CameraTerms<F>,
    config: &RasterConfig,
    sort: bool,
) -> Bins<F> {
    let near = F::c(config.near as f64);
    let near_f32 = config.near;
    let tiles_x = cam.width.div_ceil(TILE);
    let n_tiles = (tiles_x * cam.height.div_ceil(TILE)) as usize;
    let chunk = chunk_size(cloud.len());
    // The lane kernels' instruction set projects f32 clouds in lanes too.
    let isa = Isa::of(resolved_kernel::<F>(config.kernel));
    let lanes = (isa, as_f32(cloud), as_f32(cam));
    let chunks: Vec<(Vec<Splat<F>>, Vec<u32>, ChunkBins)> = (0..cloud.len().div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let gaussians = c * chunk..((c + 1) * chunk).min(cloud.len());
            let mut splats = Vec::with_capacity(gaussians.len());
            let mut ids = Vec::with_capacity(gaussians.len());
            match (lanes, as_f32_mut(&mut splats)) {
                ((Some(isa), Some(cloud), Some(cam)), Some(splats)) => isa.project_range(
                    cloud,
                    gaussians,
                    cam,
                    config.low_pass,
                    near_f32,
                    splats,
                    &mut ids,
                ),
                _ => {
                    for g in gaussians {
                        if let Some(s) = project(cloud, g, cam, config.low_pass, near) {
                            splats.push(s);
                            ids.push(g as u32);
                        }
                    }
                }
            }
            let bins = ChunkBins::new(&splats, tiles_x, n_tiles, sort);
            (splats, ids, bins)
        })
        .collect();
    // Each chunk's first splat, and the splats and their Gaussians end to end.
    let mut firsts = Vec::with_capacity(chunks.len());
    let mut n_splats = 0u64;
    for (splats, _, _) in &chunks {
        firsts.push(n_splats);
        n_splats += splats.len() as u64;
    }
    let mut splats = vec![Splat::<F>::default(); n_splats as usize];
    let mut ids = vec![0u32; n_splats as usize];
    {
        let mut splat_parts = Vec::with_capacity(chunks.len());
        let mut id_parts = Vec::with_capacity(chunks.len());
        let (mut splat_rest, mut id_rest) = (&mut splats[..], &mut ids[..]);
        for (part, _, _) in &chunks {
            let (head, tail) = splat_rest.split_at_mut(part.len());
            splat_parts.push(head);
            splat_rest = tail;
            let (head, tail) = id_rest.split_at_mut(part.len());
            id_parts.push(head);
            id_rest = tail;
        }
        (splat_parts, id_parts, &chunks).into_par_iter().for_each(
            |(splat_out, id_out, (part, part_ids, _))| {
                splat_out.copy_from_slice(part);
                id_out.copy_from_slice(part_ids);
            },
        );
    }
    let sizes: Vec<u32> = (0..n_tiles)
        .into_par_iter()
        .map(|t| chunks.iter().map(|(_, _, c)| c.len(t)).sum())
        .collect();
    let mut tile_ranges = Vec::with_capacity(n_tiles);
    let mut end = 0u32;
    for &n in &sizes {
        tile_ranges.push((end, end + n));
        end += n;
    }
    let mut keys = vec![0u64; end as usize];
    let mut entries = vec![0u32; end as usize];
    let exact_f32 = std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>();
    let key_lists = split_by_tile(&mut keys, &tile_ranges);
    let lists = split_by_tile(&mut entries, &tile_ranges);
    (key_lists, lists)
        .into_par_iter()
        .enumerate()
        .for_each_init(Vec::new, |scratch, (t, (keys, list))| {
            let mut k = 0;
            for ((_, _, c), &first) in chunks.iter().zip(&firsts) {
                let part = c.list(t);
                for (out, &key) in keys[k..k + part.len()].iter_mut().zip(part) {
                    *out = key + first;
                }
                k += part.len();
            }
            if sort {
                depth_order(keys, scratch, list);
            } else {
                for (e, k) in list.iter_mut().zip(keys.iter()) {
                    *e = *k as u32;
                }
            }
            if sort && !exact_f32 {
                // Wider floats: order by the exact depth (the f32 keys have put it nearly there).
                list.sort_by(|&x, &y| {
                    let (sx, sy) = (&splats[x as usize], &splats[y as usize]);
                    sx.depth
                        .partial_cmp(&sy.depth)
                        .unwrap_or(std::cmp::Ordering::Equal)
                        .then(ids[x as usize].cmp(&ids[y as usize]))
                });
            }
        });
    Bins {
        splats,
        ids,
        entries,
        tile_ranges,
    }
}

/// `values` (tile-major, like the entries) cut into each tile's slice.
pub(super) fn split_by_tile<'a, T>(
    values: &'a mut [T],
    tile_ranges: &[(u32, u32)],
) -> Vec<&'a mut [T]> {
    let mut slices = Vec::with_capacity(tile_ranges.len());
    let mut rest = values;
    for &(a, b) in tile_ranges {
        let (head, tail) = rest.split_at_mut((b - a) as usize);
        slices.push(head);
        rest = tail;
    }
    slices
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
    let b = project_and_bin(cloud, &cam, config, false);
    (
        b.splats,
        b.ids,
        b.entries,
        b.tile_ranges,
        camera.width.div_ceil(TILE),
    )
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
