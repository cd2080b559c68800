//! Per-level training targets at the cache's resolution: for each level and cache pixel (a
//! bin of frame pixels, [`PixelMap`]), the weighted mean of the samples the frame's paths gave
//! there, and the spread of that mean (a bin without a sample takes no part in that level's
//! loss). The weights are 1, or with survivor weights the inverse of Algorithm 1's probability
//! of going on; they are kept through the binning, so a bin's target is the weighted mean of
//! every sample in it (a pixel's mean taken with weight 1 would undo them: one path per pixel
//! has a weighted mean equal to its own sample).
//!
//! The samples go straight into the bins. Kept per frame pixel first, the targets were four
//! frame-sized images per level (90 MB at 1280x720) to clear, fill and read back every frame:
//! at 16 cores that memory traffic, not arithmetic, made a tenth of the cold cache's frame
//! (issue 31). Each frame pixel's sample sum still enters its bin as it did then (an f32
//! weighted sum per pixel, added to the bin's f64 sums in row-major pixel order), so the
//! targets are the same bits.

use crate::control::{PathStatistics, Statistics};
use crate::resolution::PixelMap;
use crate::termination::luminance;
use glam::Vec3;
use rayon::prelude::*;
use splat_raster::MAX_SAMPLE_RADIANCE;

/// Training samples of one frame: per level, per cache pixel, row-major.
#[derive(Debug, Clone)]
pub struct TrainingTargets {
    /// Frame pixels to cache pixels (the bins).
    map: PixelMap,
    /// Per level, per bin: its samples' sums.
    bins: Vec<Vec<BinSums>>,
    /// Per bin, the paths through it (index 0) and, per level `l`, those that reached the
    /// level's vertex (index `l + 1`), stopped there or not: the support test's coverage
    /// ([`crate::support`]). Renderers that do not report paths leave them zero.
    paths: Vec<Vec<u32>>,
    /// Samples refused this frame for being not finite or too large in magnitude.
    dropped: u64,
    /// The unbiased estimator's statistics per cache pixel (see [`crate::control`]), and per
    /// frame pixel the moments of its paths' estimates.
    statistics: Option<(Statistics, Vec<[f32; 3]>)>,
}

/// Per cache row of `map`, the frame rows (of `height`) whose pixels it bins: a frame row's
/// pixels all fall in one cache row, and the rows' cache rows never decrease.
fn frame_rows_per_cache_row(map: &PixelMap, height: u32) -> Vec<std::ops::Range<u32>> {
    let cache_row = |y: u32| map.bin(0, y) / map.width as usize;
    let mut rows = vec![0..0; map.height as usize];
    let mut y = 0;
    while y < height {
        let j = cache_row(y);
        let start = y;
        while y < height && cache_row(y) == j {
            y += 1;
        }
        rows[j] = start..y;
    }
    rows
}

/// One bin's sums for one level: per colour channel the weighted sum of its samples and the
/// summed weights, the summed scalar weights ([`scalar_weight`]), the scalar-weighted sum of
/// their luminances and of their squared luminances, and the number of frame pixels' sums added
/// (the samples, when each pixel adds one).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct BinSums {
    sum: [f64; 3],
    channel_weight: [f64; 3],
    weight: f64,
    luminance: f64,
    square: f64,
    count: u64,
}

/// A sample's weight as one number, for the statistics that see luminance alone (the support
/// and fallback tests' spread, the loss's shares): the weights' luminance, and exactly their
/// common value when the channels agree (in f32 luminance's coefficients need not sum to 1, and
/// one weight for all channels must give what a scalar weight gave).
#[inline]
pub(crate) fn scalar_weight(weight: Vec3) -> f32 {
    if weight.x == weight.y && weight.y == weight.z {
        weight.x
    } else {
        luminance(weight)
    }
}

impl BinSums {
    /// Adds `value` with per-channel `weight` as one frame pixel's sums; false (nothing added)
    /// for a value not finite or above [`MAX_SAMPLE_RADIANCE`] in magnitude, or a weight with
    /// a channel not finite or negative or with no positive scalar weight. A channel of zero
    /// weight adds nothing to that channel (its target is 0 if no sample weighs it). Negative
    /// values are kept: the unbiased estimator's control variate makes them, and their mean is
    /// still the level's target. Written so that NaN fails. The products are rounded to f32 as
    /// a per-pixel f32 sum would hold them.
    #[inline]
    fn add(&mut self, value: [f32; 3], weight: Vec3) -> bool {
        let scalar = scalar_weight(weight);
        if !(value
            .iter()
            .all(|v| (-MAX_SAMPLE_RADIANCE..=MAX_SAMPLE_RADIANCE).contains(v))
            && weight.is_finite()
            && weight.min_element() >= 0.0
            && scalar > 0.0)
        {
            return false;
        }
        let weighted = [
            value[0] * weight.x,
            value[1] * weight.y,
            value[2] * weight.z,
        ];
        for c in 0..3 {
            self.sum[c] += weighted[c] as f64;
            self.channel_weight[c] += weight[c] as f64;
        }
        self.weight += scalar as f64;
        self.luminance += luminance(Vec3::from_array(value.map(|v| scalar * v))) as f64;
        self.square += (scalar * luminance(Vec3::from_array(value)).powi(2)) as f64;
        self.count += 1;
        true
    }

    /// The weighted mean per channel (0 in a channel no sample weighs).
    fn mean(&self) -> [f64; 3] {
        std::array::from_fn(|c| {
            if self.channel_weight[c] > 0.0 {
                self.sum[c] / self.channel_weight[c]
            } else {
                0.0
            }
        })
    }
}

impl TrainingTargets {
    /// Empty targets for `levels` levels of frames binned by `map`.
    pub fn new(levels: usize, map: PixelMap) -> Self {
        let n = map.width as usize * map.height as usize;
        Self {
            map,
            bins: vec![vec![BinSums::default(); n]; levels],
            paths: vec![vec![0; n]; levels + 1],
            dropped: 0,
            statistics: None,
        }
    }

    /// Counts one path through row-major frame pixel `pixel` that reached `length` vertices
    /// (a renderer without tiles: the C ABI).
    pub fn add_path(&mut self, pixel: usize, length: usize) {
        let w = self.width() as usize;
        let bin = self.map.bin((pixel % w) as u32, (pixel / w) as u32);
        for counts in self.paths.iter_mut().take(length.saturating_add(1)) {
            counts[bin] = counts[bin].saturating_add(1);
        }
    }

    /// Per bin, the paths through it, and per level the paths that reached its vertex (see
    /// [`crate::support`]).
    pub fn path_counts(&self) -> (&[u32], &[Vec<u32>]) {
        (&self.paths[0], &self.paths[1..])
    }

    /// These targets also gather the unbiased estimator's statistics per cache pixel.
    pub fn with_statistics(mut self) -> Self {
        let pixels = self.map.width as usize * self.map.height as usize;
        let frame_pixels = self.width() as usize * self.height() as usize;
        self.statistics = Some((
            Statistics::new(self.levels(), pixels),
            vec![[0.0; 3]; frame_pixels],
        ));
        self
    }

    /// The unbiased estimator's statistics per cache pixel, and per frame pixel the moments of
    /// its paths' estimates (paths, sum, sum of squares), if gathered.
    pub fn statistics(&self) -> Option<(&Statistics, &[[f32; 3]])> {
        self.statistics.as_ref().map(|(s, m)| (s, m.as_slice()))
    }

    /// Files one path's statistics at row-major frame pixel `pixel` (a renderer without
    /// tiles: the C ABI).
    pub fn add_path_statistics(&mut self, pixel: usize, path: &PathStatistics) {
        let map = self.map;
        if let Some((s, moments)) = self.statistics.as_mut() {
            let w = map.frame_size().0 as usize;
            let mut one = Statistics::new(s.levels(), 1);
            one.add(0, path);
            s.add_tile(
                &one,
                ((pixel % w) as u32, (pixel / w) as u32, 1),
                &map,
                moments,
            );
        }
    }

    pub fn levels(&self) -> usize {
        self.bins.len()
    }

    /// The map from frame pixels to the bins.
    pub fn map(&self) -> &PixelMap {
        &self.map
    }

    /// Whether these buffers serve a frame of `levels` levels binned by `map`, gathering the
    /// unbiased estimator's statistics or not.
    pub fn fits(&self, levels: usize, map: &PixelMap, statistics: bool) -> bool {
        self.levels() == levels && self.map == *map && self.statistics.is_some() == statistics
    }

    /// The frame's width in pixels.
    pub fn width(&self) -> u32 {
        self.map.frame_size().0
    }

    /// The frame's height in pixels.
    pub fn height(&self) -> u32 {
        self.map.frame_size().1
    }

    /// Samples refused since the last [`TrainingTargets::clear`] (not finite, or too large): a
    /// caller reports them, so a renderer feeding NaN finds out.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Adds one sample for `level` at row-major frame pixel `pixel`. Samples that are not
    /// finite or above [`MAX_SAMPLE_RADIANCE`] in magnitude are dropped (they would poison the
    /// loss, or overflow it) and counted. Negative samples are kept: the unbiased estimator's
    /// control variate makes them, and their mean is still the level's target.
    pub fn add(&mut self, level: usize, pixel: usize, value: [f32; 3]) {
        self.add_weighted(level, pixel, value, 1.0);
    }

    /// [`TrainingTargets::add`] with a weight (finite and positive, else the sample is dropped
    /// and counted).
    pub fn add_weighted(&mut self, level: usize, pixel: usize, value: [f32; 3], weight: f32) {
        let w = self.width() as usize;
        let bin = self.map.bin((pixel % w) as u32, (pixel / w) as u32);
        if !self.bins[level][bin].add(value, Vec3::splat(weight)) {
            self.dropped += 1;
        }
    }

    /// Forgets every sample, keeping the buffers.
    pub fn clear(&mut self) {
        const CHUNK: usize = 1 << 12;
        for bins in &mut self.bins {
            bins.par_chunks_mut(CHUNK)
                .for_each(|c| c.fill(BinSums::default()));
        }
        for counts in &mut self.paths {
            counts.fill(0);
        }
        if let Some((s, moments)) = self.statistics.as_mut() {
            *s = Statistics::new(
                s.levels(),
                self.map.width as usize * self.map.height as usize,
            );
            moments.fill([0.0; 3]);
        }
        self.dropped = 0;
    }

    /// The target image of `level` at the cache's resolution and its mask: each cache pixel
    /// takes the weighted mean of the samples binned into it, and is in the mask when it has
    /// one. With `masked = false` every pixel is in the mask and pixels without samples target
    /// zero.
    pub fn level_target(&self, level: usize, masked: bool) -> (Vec<[f32; 3]>, Vec<bool>) {
        let identity = self.map.is_identity();
        self.bins[level]
            .iter()
            .map(|b| {
                if !(b.weight > 0.0) {
                    ([0.0; 3], !masked)
                } else if identity {
                    // A bin is a frame pixel: its mean in f32, as the pixel's own sums give it.
                    let mean = std::array::from_fn(|c| {
                        let w = b.channel_weight[c] as f32;
                        if w > 0.0 {
                            b.sum[c] as f32 * (1.0 / w)
                        } else {
                            0.0
                        }
                    });
                    (mean, true)
                } else {
                    (b.mean().map(|v| v as f32), true)
                }
            })
            .unzip()
    }

    /// Per colour channel, the mean over the cache pixels of `level` with a target of their
    /// samples' summed weight in that channel (0 where no pixel has one).
    pub fn level_mean_weight(&self, level: usize) -> [f64; 3] {
        let (sum, n) = self.bins[level].iter().filter(|b| b.weight > 0.0).fold(
            ([0.0f64; 3], 0u64),
            |(mut s, n), b| {
                for c in 0..3 {
                    s[c] += b.channel_weight[c];
                }
                (s, n + 1)
            },
        );
        sum.map(|s| s / n.max(1) as f64)
    }

    /// Per cache pixel of `level` and colour channel, its share of the training loss with
    /// `weighted_loss`: the summed weight of its samples in that channel over `scale` (the
    /// cache's running mean of [`TrainingTargets::level_mean_weight`], so the shares average
    /// about 1 and the loss keeps its scale); 0 where there is no scale. A pixel without a
    /// sample has no share when `masked` (it has no target), and one share, as without the
    /// weights, when not (it targets zero: [`TrainingTargets::level_target`]).
    pub fn level_loss_weights(&self, level: usize, scale: [f64; 3], masked: bool) -> Vec<[f32; 3]> {
        self.bins[level]
            .iter()
            .map(|b| {
                if !(b.weight > 0.0) {
                    return [if masked { 0.0 } else { 1.0 }; 3];
                }
                std::array::from_fn(|c| {
                    if scale[c] > 0.0 {
                        (b.channel_weight[c] / scale[c]) as f32
                    } else {
                        0.0
                    }
                })
            })
            .collect()
    }

    /// Per cache pixel, the number of samples binned into it and the variance of their
    /// weighted mean's luminance (the weighted sample variance over that number; NaN below two
    /// samples): how far the binned target may lie from its expectation by noise alone.
    pub fn level_spread(&self, level: usize) -> Vec<(u64, f32)> {
        self.bins[level]
            .iter()
            .map(|b| {
                if b.count < 2 || !(b.weight > 0.0) {
                    return (b.count, f32::NAN);
                }
                let k = b.count as f64;
                let mean = b.luminance / b.weight;
                let variance = ((b.square / b.weight - mean * mean) * k / (k - 1.0)).max(0.0);
                (b.count, (variance / k) as f32)
            })
            .collect()
    }
}

/// One tile's share of a frame's targets, filled by one thread while the frame renders: per
/// level, per tile pixel, the sum and number of the samples its paths produced. The frame's
/// [`TrainingTargets`] take each pixel's mean ([`TrainingTargets::add_tile`]), so the level
/// index never leaves the cache.
#[derive(Debug, Clone)]
pub struct TileTargets {
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    levels: usize,
    sums: Vec<Vec3>,
    /// Summed sample weights per channel (sample counts when every weight is 1).
    weights: Vec<Vec3>,
    /// Per tile pixel, the paths through it (block 0) and per level those that reached its
    /// vertex (block `l + 1`), as [`TrainingTargets`] keeps them per bin.
    paths: Vec<u32>,
    /// Whether any path was counted (only a cache with the support test asks renderers to):
    /// tiles without counts skip the binning of `paths`.
    counted: bool,
    /// Samples refused for a non-finite or too large value, or a bad weight.
    dropped: u64,
    /// The unbiased estimator's statistics per tile pixel, when gathered.
    statistics: Option<Statistics>,
}

impl TileTargets {
    /// Empty targets for the `width` x `height` tile whose top-left pixel is `(x0, y0)`.
    pub fn new(levels: usize, x0: u32, y0: u32, width: u32, height: u32) -> Self {
        let n = width as usize * height as usize * levels;
        Self {
            x0,
            y0,
            width,
            height,
            levels,
            sums: vec![Vec3::ZERO; n],
            weights: vec![Vec3::ZERO; n],
            paths: vec![0; n + width as usize * height as usize],
            counted: false,
            dropped: 0,
            statistics: None,
        }
    }

    /// Counts one path through row-major tile pixel `in_tile` that reached `length` vertices
    /// ([`crate::CachedPath::length`] when it ended), for the support test's coverage.
    pub fn add_path(&mut self, in_tile: usize, length: usize) {
        let tile_pixels = self.width as usize * self.height as usize;
        self.counted = true;
        for block in 0..=length.min(self.levels) {
            let k = block * tile_pixels + in_tile;
            self.paths[k] = self.paths[k].saturating_add(1);
        }
    }

    /// This tile also gathers the unbiased estimator's statistics.
    pub fn with_statistics(mut self) -> Self {
        let pixels = self.width as usize * self.height as usize;
        self.statistics = Some(Statistics::new(self.levels, pixels));
        self
    }

    /// Files one path's statistics ([`crate::CachedPath::statistics`]).
    pub fn add_statistics(&mut self, in_tile: usize, path: &PathStatistics) {
        if let Some(s) = self.statistics.as_mut() {
            s.add(in_tile, path);
        }
    }

    /// Files one path's `(level, value, weight)` samples (what [`crate::CachedPath::samples`]
    /// gives: a weight per colour channel); the path went through row-major tile pixel
    /// `in_tile`.
    pub fn add_samples(
        &mut self,
        in_tile: usize,
        samples: impl IntoIterator<Item = (usize, Vec3, Vec3)>,
    ) {
        let tile_pixels = self.width as usize * self.height as usize;
        for (level, value, weight) in samples {
            // One NaN would spoil the pixel's whole mean: refuse the sample, count it. Written
            // so that NaN fails.
            if !(value.is_finite()
                && value.min_element() >= -MAX_SAMPLE_RADIANCE
                && value.max_element() <= MAX_SAMPLE_RADIANCE
                && weight.min_element() >= 0.0
                && weight.is_finite())
            {
                self.dropped += 1;
                continue;
            }
            let k = level * tile_pixels + in_tile;
            // Multiplying by a weight of 1 is exact: unweighted sums are unchanged.
            self.sums[k] += value * weight;
            self.weights[k] += weight;
        }
    }
}

impl TrainingTargets {
    /// Adds each pixel's weighted mean sample of `tile`, with its summed weight, level by
    /// level. The tile must lie inside the frame and have at most this frame's levels.
    pub fn add_tile(&mut self, tile: &TileTargets) {
        self.add_tiles(&[tile]);
    }

    /// [`TrainingTargets::add_tile`] for every tile of a frame, the cache's rows in parallel:
    /// each bin takes its frame pixels' sums in row-major order, whatever the tiles' order, so
    /// the targets are bit for bit the same on any number of threads.
    pub fn add_tiles(&mut self, tiles: &[&TileTargets]) {
        let (width, height) = (self.width() as usize, self.height() as usize);
        let map = self.map;
        // The statistics (unbiased estimator only) go per cache pixel: in tile order, serially.
        for tile in tiles {
            self.dropped += tile.dropped;
            if let (Some((stats, moments)), Some(t)) =
                (self.statistics.as_mut(), tile.statistics.as_ref())
            {
                stats.add_tile(t, (tile.x0, tile.y0, tile.width), &map, moments);
            }
        }
        // Per frame row, the tiles that cross it, left to right.
        let mut crossing: Vec<Vec<&TileTargets>> = vec![Vec::new(); height];
        for tile in tiles {
            let rows = tile.y0 as usize..(tile.y0 + tile.height) as usize;
            assert!(
                rows.end <= height && (tile.x0 + tile.width) as usize <= width,
                "tile at ({}, {}) of {}x{} lies outside the {}x{} image",
                tile.x0,
                tile.y0,
                tile.width,
                tile.height,
                width,
                height
            );
            for row in &mut crossing[rows] {
                row.push(tile);
            }
        }
        for row in &mut crossing {
            row.sort_by_key(|t| t.x0);
        }
        // A frame pixel's cache column depends on its column alone.
        let column: Vec<usize> = (0..width as u32)
            .map(|x| map.bin(x, 0) % map.width as usize)
            .collect();
        let rows = frame_rows_per_cache_row(&map, height as u32);
        let cache_width = map.width as usize;
        let mut dropped = 0;
        for (level, bins) in self.bins.iter_mut().enumerate() {
            dropped += bins
                .par_chunks_mut(cache_width)
                .zip(rows.par_iter())
                .map(|(bins, rows)| {
                    let mut dropped = 0u64;
                    for y in rows.clone() {
                        for tile in crossing[y as usize].iter().filter(|t| level < t.levels) {
                            let tile_pixels = tile.width as usize * tile.height as usize;
                            let j = y as usize - tile.y0 as usize;
                            for i in 0..tile.width as usize {
                                let k = level * tile_pixels + j * tile.width as usize + i;
                                let weight = tile.weights[k];
                                if scalar_weight(weight) > 0.0 {
                                    let mean = tile.sums[k] / weight;
                                    // A channel no sample weighs has no mean.
                                    let mean =
                                        Vec3::select(weight.cmpgt(Vec3::ZERO), mean, Vec3::ZERO);
                                    let bin = &mut bins[column[tile.x0 as usize + i]];
                                    if !bin.add(mean.to_array(), weight) {
                                        dropped += 1;
                                    }
                                }
                            }
                        }
                    }
                    dropped
                })
                .sum::<u64>();
        }
        self.dropped += dropped;
        // The path counts, block by block (block 0: every path; block l + 1: level l's), where
        // a renderer counted them.
        let counting = tiles.iter().any(|t| t.counted);
        for (block, counts) in self.paths.iter_mut().enumerate().filter(|_| counting) {
            counts
                .par_chunks_mut(cache_width)
                .zip(rows.par_iter())
                .for_each(|(counts, rows)| {
                    for y in rows.clone() {
                        for tile in crossing[y as usize]
                            .iter()
                            .filter(|t| t.counted && block <= t.levels)
                        {
                            let tile_pixels = tile.width as usize * tile.height as usize;
                            let j = y as usize - tile.y0 as usize;
                            for i in 0..tile.width as usize {
                                let k = block * tile_pixels + j * tile.width as usize + i;
                                let count = &mut counts[column[tile.x0 as usize + i]];
                                *count = count.saturating_add(tile.paths[k]);
                            }
                        }
                    }
                });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `w` x `h` pixels kept at its own resolution.
    fn identity(w: u32, h: u32) -> PixelMap {
        PixelMap::for_size(w, h, 1)
    }

    /// Paths counted in tiles reach the bins as paths counted one by one do: every path in
    /// block 0, and in each level's block those that reached its vertex.
    #[test]
    fn path_counts_bin_like_single_paths() {
        let map = PixelMap::for_size(8, 4, 2);
        let mut tiles = TileTargets::new(2, 4, 0, 4, 4);
        let mut direct = TrainingTargets::new(2, map);
        // Frame pixel (5, 1): lengths 0, 1, 3; pixel (4, 0): length 2.
        for (x, y, length) in [(5u32, 1u32, 0usize), (5, 1, 1), (5, 1, 3), (4, 0, 2)] {
            tiles.add_path(((y * 4) + x - 4) as usize, length);
            direct.add_path((y * 8 + x) as usize, length);
        }
        let mut binned = TrainingTargets::new(2, map);
        binned.add_tile(&tiles);
        let bin = map.bin(5, 1);
        for t in [&binned, &direct] {
            let (paths, reached) = t.path_counts();
            assert_eq!((paths[bin], reached[0][bin], reached[1][bin]), (4, 3, 2));
            assert_eq!(paths.iter().sum::<u32>(), 4, "one bin holds them all");
        }
        binned.clear();
        assert_eq!(binned.path_counts().0[bin], 0);
    }

    /// A target brighter than any sample a film accepts is refused and counted like a NaN one:
    /// frames of 3e38 targets once overflowed the loss and drew a level of infinite pixels
    /// (and the C ABI returned OK).
    #[test]
    fn targets_above_the_largest_sample_are_dropped() {
        let mut t = TrainingTargets::new(1, identity(2, 1));
        t.add(0, 0, [3e38; 3]);
        t.add(0, 0, [1.0, MAX_SAMPLE_RADIANCE * 2.0, 1.0]);
        t.add(0, 1, [MAX_SAMPLE_RADIANCE; 3]);
        assert_eq!(t.dropped(), 2);
    }

    /// A NaN or huge sample is refused and counted; the pixel keeps the mean of the rest
    /// (before, one NaN made the pixel's whole mean NaN and the pixel was lost). A negative
    /// sample (the unbiased estimator's) is kept.
    #[test]
    fn bad_samples_are_counted_and_do_not_spoil_a_pixel() {
        let mut tile = TileTargets::new(1, 0, 0, 2, 1);
        tile.add_samples(
            0,
            [
                (0, Vec3::splat(1.0), Vec3::ONE),
                (0, Vec3::splat(3.0), Vec3::ONE),
            ],
        );
        tile.add_samples(0, [(0, Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE)]);
        tile.add_samples(
            0,
            [
                (0, Vec3::splat(-3e38), Vec3::ONE),
                (0, Vec3::ONE, Vec3::splat(f32::INFINITY)),
            ],
        );
        tile.add_samples(1, [(0, Vec3::splat(-1.0), Vec3::ONE)]);
        let mut targets = TrainingTargets::new(1, identity(2, 1));
        targets.add_tile(&tile);
        targets.add(0, 1, [f32::NAN; 3]);
        assert_eq!(targets.dropped(), 4);
        let bins = &targets.bins[0];
        assert_eq!(bins[0].sum, [4.0; 3]); // the mean of 1 and 3, weight 2
        assert_eq!(bins[1].sum, [-1.0; 3]); // kept
        assert_eq!((bins[0].count, bins[1].count), (1, 1));
        assert_eq!((bins[0].weight, bins[1].weight), (2.0, 1.0));
        assert_eq!(
            targets.level_target(0, true),
            (vec![[2.0; 3], [-1.0; 3]], vec![true, true])
        );
        targets.clear();
        assert_eq!(targets.dropped(), 0);
        assert!(targets.bins[0].iter().all(|b| *b == BinSums::default()));
    }

    /// Survivor weights survive the binning: two pixels in one cache pixel, each with one path,
    /// one of weight 1 and value 1, one of weight 3 and value 5: the bin's target is their
    /// weighted mean 4, not the plain mean 3 (which taking each pixel's mean with weight 1 gave).
    #[test]
    fn weights_are_kept_through_the_binning() {
        let mut tile = TileTargets::new(1, 0, 0, 2, 2);
        tile.add_samples(0, [(0, Vec3::splat(1.0), Vec3::ONE)]);
        tile.add_samples(1, [(0, Vec3::splat(5.0), Vec3::splat(3.0))]);
        let map = PixelMap::for_size(2, 2, 2);
        assert_eq!((map.width, map.height), (1, 1));
        let mut targets = TrainingTargets::new(1, map);
        targets.add_tile(&tile);
        let (target, mask) = targets.level_target(0, true);
        assert_eq!((target, mask), (vec![[4.0; 3]], vec![true]));
        let mut unbinned = TrainingTargets::new(1, identity(2, 2));
        unbinned.add_tile(&tile);
        let (target, _) = unbinned.level_target(0, true);
        assert_eq!(&target[..2], &[[1.0; 3], [5.0; 3]]);
    }

    /// With a weight per channel each channel's target is its own weighted mean: three pixels
    /// in one cache pixel, values 1, 5 and 7 weighing (1, 3, 0), (3, 1, 2) and (1, 1, 0), give
    /// (4.6, 3, 5) where one weight for all channels would give one mean; a channel no sample
    /// weighs targets 0; the loss shares are each channel's summed weight over the scale given.
    #[test]
    fn each_channel_takes_its_own_weighted_mean() {
        let mut tile = TileTargets::new(1, 0, 0, 2, 2);
        tile.add_samples(0, [(0, Vec3::splat(1.0), Vec3::new(1.0, 3.0, 0.0))]);
        tile.add_samples(1, [(0, Vec3::splat(5.0), Vec3::new(3.0, 1.0, 2.0))]);
        tile.add_samples(2, [(0, Vec3::splat(7.0), Vec3::new(1.0, 1.0, 0.0))]);
        let map = PixelMap::for_size(2, 2, 2);
        let mut targets = TrainingTargets::new(1, map);
        targets.add_tile(&tile);
        let (target, _) = targets.level_target(0, true);
        let want = [
            (1.0 + 15.0 + 7.0) / 5.0,
            (3.0 + 5.0 + 7.0) / 5.0,
            10.0 / 2.0,
        ];
        for c in 0..3 {
            assert!((target[0][c] - want[c]).abs() < 1e-6, "{:?}", target[0]);
        }
        assert_eq!(targets.level_mean_weight(0), [5.0, 5.0, 2.0]);
        assert_eq!(
            targets.level_loss_weights(0, [2.5, 5.0, 4.0], true),
            vec![[2.0, 1.0, 0.5]]
        );
        // One pixel's only sample weighs nothing in blue: its blue target is 0, not NaN.
        let mut tile = TileTargets::new(1, 0, 0, 1, 1);
        tile.add_samples(0, [(0, Vec3::splat(2.0), Vec3::new(1.0, 1.0, 0.0))]);
        let mut targets = TrainingTargets::new(1, identity(1, 1));
        targets.add_tile(&tile);
        assert_eq!(targets.level_target(0, true).0, vec![[2.0, 2.0, 0.0]]);
    }

    /// The targets as they were gathered before they went straight into the bins (issue 31):
    /// per frame pixel, f32 sums of each tile pixel's weighted mean, added tile after tile;
    /// then per bin, f64 sums of its pixels in row-major order.
    struct PerPixel {
        width: u32,
        sums: Vec<[f32; 3]>,
        weights: Vec<f32>,
        squares: Vec<f32>,
        counts: Vec<u32>,
    }

    impl PerPixel {
        fn gather(tiles: &[TileTargets], level: usize, width: u32, height: u32) -> Self {
            let n = (width * height) as usize;
            let mut p = PerPixel {
                width,
                sums: vec![[0.0; 3]; n],
                weights: vec![0.0; n],
                squares: vec![0.0; n],
                counts: vec![0; n],
            };
            for tile in tiles {
                let tile_pixels = (tile.width * tile.height) as usize;
                for j in 0..tile.height {
                    for i in 0..tile.width {
                        let k = level * tile_pixels + (j * tile.width + i) as usize;
                        // The test's weights are one number for every channel.
                        let w = tile.weights[k].x;
                        if w > 0.0 {
                            let q = ((tile.y0 + j) * width + tile.x0 + i) as usize;
                            let mean = (tile.sums[k] / w).to_array();
                            for c in 0..3 {
                                p.sums[q][c] += w * mean[c];
                            }
                            p.weights[q] += w;
                            p.squares[q] += w * luminance(Vec3::from_array(mean)).powi(2);
                            p.counts[q] += 1;
                        }
                    }
                }
            }
            p
        }

        /// Per bin: the target, whether it has a sample, the samples and the spread.
        fn binned(&self, map: &PixelMap) -> Vec<([f32; 3], bool, u64, f32)> {
            let n = (map.width * map.height) as usize;
            let mut acc = vec![([0.0f64; 3], 0.0f64, 0.0f64, 0.0f64, 0u64); n];
            for (q, &c) in self.counts.iter().enumerate() {
                if c > 0 {
                    let a = &mut acc[map.bin(q as u32 % self.width, q as u32 / self.width)];
                    for k in 0..3 {
                        a.0[k] += self.sums[q][k] as f64;
                    }
                    a.1 += self.weights[q] as f64;
                    a.2 += luminance(Vec3::from_array(self.sums[q])) as f64;
                    a.3 += self.squares[q] as f64;
                    a.4 += c as u64;
                }
            }
            acc.iter()
                .map(|&(sum, weight, lum, square, count)| {
                    let target = if weight > 0.0 {
                        sum.map(|v| (v / weight) as f32)
                    } else {
                        [0.0; 3]
                    };
                    let spread = if count < 2 {
                        f32::NAN
                    } else {
                        let k = count as f64;
                        let mean = lum / weight;
                        (((square / weight - mean * mean) * k / (k - 1.0)).max(0.0) / k) as f32
                    };
                    (target, weight > 0.0, count, spread)
                })
                .collect()
        }
    }

    /// Gathered straight into the bins, in parallel, the targets and spreads are bit for bit
    /// what the per-pixel gather and a serial binning give, on 1 and on 4 threads: a 70x45
    /// frame in 16x16 tiles (ragged at the edges, given out of order), 2 levels, hashed
    /// samples with weights, some pixels empty, binned 4:1 with the map's odd edge bins and
    /// 1:1.
    #[test]
    fn binned_gather_equals_the_per_pixel_gather() {
        use render_base::hash::{hash32, unit_f32};
        let (w, h, levels) = (70u32, 45u32, 2usize);
        let mut tiles = Vec::new();
        for y0 in (0..h).step_by(16) {
            for x0 in (0..w).step_by(16) {
                let (tw, th) = (16.min(w - x0), 16.min(h - y0));
                let mut tile = TileTargets::new(levels, x0, y0, tw, th);
                for p in 0..(tw * th) {
                    for n in 0..3u32 {
                        let r = |k: u32| unit_f32(hash32(&[x0, y0, p, n, k]));
                        if r(0) < 0.3 {
                            continue; // an empty sample slot
                        }
                        let level = (r(1) * levels as f32) as usize;
                        let value = Vec3::new(r(2), 10.0 * r(3), r(4) - 0.2);
                        tile.add_samples(
                            p as usize,
                            [(level, value, Vec3::splat(0.5 + 3.0 * r(5)))],
                        );
                    }
                }
                tiles.push(tile);
            }
        }
        let mut shuffled: Vec<&TileTargets> = tiles.iter().collect();
        shuffled.reverse();
        shuffled.swap(1, 4);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for divisor in [4, 1] {
            let map = PixelMap::for_size(w, h, divisor);
            for threads in [1, 4] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let binned = pool.install(|| {
                    let mut t = TrainingTargets::new(levels, map);
                    t.add_tiles(&shuffled);
                    t
                });
                for level in 0..levels {
                    let expected = PerPixel::gather(&tiles, level, w, h).binned(&map);
                    let (target, mask) = binned.level_target(level, true);
                    let spread = binned.level_spread(level);
                    let what = format!("divisor {divisor}, {threads} threads, level {level}");
                    let flat = |t: &[[f32; 3]]| t.iter().flatten().copied().collect::<Vec<_>>();
                    let expected_target: Vec<[f32; 3]> = expected.iter().map(|e| e.0).collect();
                    if divisor > 1 {
                        assert_eq!(
                            bits(&flat(&target)),
                            bits(&flat(&expected_target)),
                            "{what}"
                        );
                    } else {
                        // A bin is a pixel: its f32 mean, as the per-pixel sums gave it.
                        let p = PerPixel::gather(&tiles, level, w, h);
                        let own: Vec<[f32; 3]> = (0..p.sums.len())
                            .map(|q| {
                                if p.weights[q] > 0.0 {
                                    let inv = 1.0 / p.weights[q];
                                    p.sums[q].map(|v| v * inv)
                                } else {
                                    [0.0; 3]
                                }
                            })
                            .collect();
                        assert_eq!(bits(&flat(&target)), bits(&flat(&own)), "{what}");
                    }
                    assert_eq!(mask, expected.iter().map(|e| e.1).collect::<Vec<_>>());
                    assert_eq!(
                        spread
                            .iter()
                            .map(|s| (s.0, s.1.to_bits()))
                            .collect::<Vec<_>>(),
                        expected
                            .iter()
                            .map(|e| (e.2, e.3.to_bits()))
                            .collect::<Vec<_>>(),
                        "{what}"
                    );
                    if divisor > 1 {
                        assert!(spread.iter().any(|&(n, v)| n >= 2 && v > 0.0));
                    }
                }
            }
        }
    }
}
