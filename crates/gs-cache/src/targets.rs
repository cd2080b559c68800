//! Per-level training targets: each pixel's weighted mean sample for each level this frame, and
//! how many samples it had (no sample: the pixel takes no part in that level's loss). The
//! weights are 1, or with survivor weights the inverse of Algorithm 1's probability of going on;
//! they are kept through the binning into cache pixels, so a bin's target is the weighted mean of
//! every sample in it (a pixel's mean taken with weight 1 would undo them: one path per pixel
//! has a weighted mean equal to its own sample).

use crate::control::{PathStatistics, Statistics};
use crate::resolution::PixelMap;
use crate::termination::luminance;
use glam::Vec3;
use rayon::prelude::*;
use splat_raster::MAX_SAMPLE_RADIANCE;

/// Training samples of one frame, one image per level, row-major.
#[derive(Debug, Clone)]
pub struct TrainingTargets {
    width: u32,
    height: u32,
    /// Per level, per pixel: the weighted sum of its samples.
    sums: Vec<Vec<[f32; 3]>>,
    /// Per level, per pixel: the sum of the weights.
    weights: Vec<Vec<f32>>,
    /// Per level, per pixel: the weighted sum of the squared luminances of its samples (for the
    /// spread the fallback's test needs: [`TrainingTargets::level_spread_binned`]).
    squares: Vec<Vec<f32>>,
    /// Per level, per pixel: how many samples were added.
    counts: Vec<Vec<u32>>,
    /// Samples refused this frame for being not finite or too large in magnitude.
    dropped: u64,
    /// The unbiased estimator's statistics per cache pixel (see [`crate::control`]), with the
    /// map from frame pixels to cache pixels.
    statistics: Option<(PixelMap, Statistics, Vec<[f32; 3]>)>,
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

/// One pixel's accumulators in [`TrainingTargets`] for one level.
struct Bin<'a> {
    sum: &'a mut [f32; 3],
    weight: &'a mut f32,
    square: &'a mut f32,
    count: &'a mut u32,
}

impl Bin<'_> {
    /// Adds `value` with `weight`; false (nothing added) for a value not finite or above
    /// [`MAX_SAMPLE_RADIANCE`] in magnitude, or a weight not finite and positive. Negative
    /// values are kept: the unbiased estimator's control variate makes them, and their mean is
    /// still the level's target. Written so that NaN fails.
    #[inline]
    fn add(self, value: [f32; 3], weight: f32) -> bool {
        if !(value
            .iter()
            .all(|v| (-MAX_SAMPLE_RADIANCE..=MAX_SAMPLE_RADIANCE).contains(v))
            && weight > 0.0
            && weight.is_finite())
        {
            return false;
        }
        for c in 0..3 {
            self.sum[c] += weight * value[c];
        }
        *self.weight += weight;
        *self.square += weight * luminance(Vec3::from_array(value)).powi(2);
        *self.count += 1;
        true
    }
}

impl TrainingTargets {
    pub fn new(levels: usize, width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            sums: vec![vec![[0.0; 3]; n]; levels],
            weights: vec![vec![0.0; n]; levels],
            squares: vec![vec![0.0; n]; levels],
            counts: vec![vec![0; n]; levels],
            dropped: 0,
            statistics: None,
        }
    }

    /// These targets also gather the unbiased estimator's statistics per pixel of `map` (the
    /// cache's pixels).
    pub fn with_statistics(mut self, map: PixelMap) -> Self {
        let pixels = map.width as usize * map.height as usize;
        let frame_pixels = self.width as usize * self.height as usize;
        self.statistics = Some((
            map,
            Statistics::new(self.levels(), pixels),
            vec![[0.0; 3]; frame_pixels],
        ));
        self
    }

    /// The unbiased estimator's statistics per cache pixel, and per frame pixel the moments of
    /// its paths' estimates (paths, sum, sum of squares), if gathered.
    pub fn statistics(&self) -> Option<(&Statistics, &[[f32; 3]])> {
        self.statistics.as_ref().map(|(_, s, m)| (s, m.as_slice()))
    }

    /// Files one path's statistics at row-major frame pixel `pixel` (a renderer without
    /// tiles: the C ABI).
    pub fn add_path_statistics(&mut self, pixel: usize, path: &PathStatistics) {
        if let Some((map, s, moments)) = self.statistics.as_mut() {
            let w = map.frame_size().0 as usize;
            let mut one = Statistics::new(s.levels(), 1);
            one.add(0, path);
            s.add_tile(
                &one,
                ((pixel % w) as u32, (pixel / w) as u32, 1),
                map,
                moments,
            );
        }
    }

    pub fn levels(&self) -> usize {
        self.sums.len()
    }

    /// Whether these buffers serve a frame of `levels` levels at `width` x `height` whose
    /// statistics go per pixel of `statistics` (`None`: none gathered).
    pub fn fits(
        &self,
        levels: usize,
        width: u32,
        height: u32,
        statistics: Option<PixelMap>,
    ) -> bool {
        self.levels() == levels
            && (self.width, self.height) == (width, height)
            && self.statistics.as_ref().map(|(map, ..)| *map) == statistics
    }
    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Samples refused since the last [`TrainingTargets::clear`] (not finite, or too large): a
    /// caller reports them, so a renderer feeding NaN finds out.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Adds one sample for `level` at row-major pixel `pixel`. Samples that are not finite or
    /// above [`MAX_SAMPLE_RADIANCE`] in magnitude are dropped (they would poison the loss, or
    /// overflow it) and counted. Negative samples are kept: the unbiased estimator's control
    /// variate makes them, and their mean is still the level's target.
    pub fn add(&mut self, level: usize, pixel: usize, value: [f32; 3]) {
        self.add_weighted(level, pixel, value, 1.0);
    }

    /// [`TrainingTargets::add`] with a weight (finite and positive, else the sample is dropped
    /// and counted).
    pub fn add_weighted(&mut self, level: usize, pixel: usize, value: [f32; 3], weight: f32) {
        let bin = Bin {
            sum: &mut self.sums[level][pixel],
            weight: &mut self.weights[level][pixel],
            square: &mut self.squares[level][pixel],
            count: &mut self.counts[level][pixel],
        };
        if !bin.add(value, weight) {
            self.dropped += 1;
        }
    }

    /// Forgets every sample, keeping the buffers (filled in parallel: tens of megabytes at
    /// 1280x720).
    pub fn clear(&mut self) {
        const CHUNK: usize = 1 << 14;
        for s in &mut self.sums {
            s.par_chunks_mut(CHUNK).for_each(|c| c.fill([0.0; 3]));
        }
        for s in self.squares.iter_mut().chain(&mut self.weights) {
            s.par_chunks_mut(CHUNK).for_each(|c| c.fill(0.0));
        }
        for c in &mut self.counts {
            c.par_chunks_mut(CHUNK).for_each(|c| c.fill(0));
        }
        if let Some((map, s, moments)) = self.statistics.as_mut() {
            *s = Statistics::new(s.levels(), map.width as usize * map.height as usize);
            moments.fill([0.0; 3]);
        }
        self.dropped = 0;
    }

    /// [`TrainingTargets::level_target`] at the cache's resolution: each cache pixel takes the
    /// weighted mean of the samples of the frame pixels binned into it by `map`.
    pub fn level_target_binned(
        &self,
        level: usize,
        masked: bool,
        map: &PixelMap,
    ) -> (Vec<[f32; 3]>, Vec<bool>) {
        if map.is_identity() {
            return self.level_target(level, masked);
        }
        let n = map.width as usize * map.height as usize;
        let mut sums = vec![[0.0f64; 3]; n];
        let mut weights = vec![0.0f64; n];
        // Cache rows in parallel; within a bin the frame pixels add in the serial order.
        let rows = frame_rows_per_cache_row(map, self.height);
        sums.par_chunks_mut(map.width as usize)
            .zip(weights.par_chunks_mut(map.width as usize))
            .zip(rows.par_iter())
            .for_each(|((sums, weights), rows)| {
                for y in rows.clone() {
                    for x in 0..self.width {
                        let i = (y * self.width + x) as usize;
                        if self.counts[level][i] > 0 {
                            let b = map.bin(x, y) % map.width as usize;
                            for k in 0..3 {
                                sums[b][k] += self.sums[level][i][k] as f64;
                            }
                            weights[b] += self.weights[level][i] as f64;
                        }
                    }
                }
            });
        let mut target = vec![[0.0f32; 3]; n];
        let mut mask = vec![!masked; n];
        for b in 0..n {
            if weights[b] > 0.0 {
                target[b] = sums[b].map(|v| (v / weights[b]) as f32);
                mask[b] = true;
            }
        }
        (target, mask)
    }

    /// Per cache pixel of `map`, the number of samples binned into it and the variance of their
    /// weighted mean's luminance (the weighted sample variance over that number; NaN below two
    /// samples): how far the binned target may lie from its expectation by noise alone.
    pub fn level_spread_binned(&self, level: usize, map: &PixelMap) -> Vec<(u64, f32)> {
        let n = map.width as usize * map.height as usize;
        // Per bin: samples, summed weights, weighted luminance sum, weighted square sum. Cache
        // rows in parallel; within a bin the frame pixels add in the serial order.
        let mut acc = vec![(0u64, 0.0f64, 0.0f64, 0.0f64); n];
        let rows = frame_rows_per_cache_row(map, self.height);
        acc.par_chunks_mut(map.width as usize)
            .zip(rows.par_iter())
            .for_each(|(acc, rows)| {
                for y in rows.clone() {
                    for x in 0..self.width {
                        let i = (y * self.width + x) as usize;
                        let c = self.counts[level][i];
                        if c > 0 {
                            let a = &mut acc[map.bin(x, y) % map.width as usize];
                            a.0 += c as u64;
                            a.1 += self.weights[level][i] as f64;
                            a.2 += luminance(Vec3::from_array(self.sums[level][i])) as f64;
                            a.3 += self.squares[level][i] as f64;
                        }
                    }
                }
            });
        acc.into_iter()
            .map(|(count, weight, sum, squares)| {
                if count < 2 || !(weight > 0.0) {
                    return (count, f32::NAN);
                }
                let k = count as f64;
                let mean = sum / weight;
                let variance = ((squares / weight - mean * mean) * k / (k - 1.0)).max(0.0);
                (count, (variance / k) as f32)
            })
            .collect()
    }

    /// The weighted mean target image of `level` and its mask (pixels with at least one
    /// sample). With `masked = false` every pixel is valid and pixels without samples target
    /// zero.
    pub fn level_target(&self, level: usize, masked: bool) -> (Vec<[f32; 3]>, Vec<bool>) {
        let sums = &self.sums[level];
        let weights = &self.weights[level];
        let mut target = vec![[0.0f32; 3]; sums.len()];
        let mut mask = vec![!masked; sums.len()];
        for i in 0..sums.len() {
            if weights[i] > 0.0 {
                let inv = 1.0 / weights[i];
                target[i] = sums[i].map(|v| v * inv);
                mask[i] = true;
            }
        }
        (target, mask)
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
    /// Summed sample weights (sample counts when every weight is 1).
    weights: Vec<f32>,
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
            weights: vec![0.0; n],
            dropped: 0,
            statistics: None,
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
    /// gives); the path went through row-major tile pixel `in_tile`.
    pub fn add_samples(
        &mut self,
        in_tile: usize,
        samples: impl IntoIterator<Item = (usize, Vec3, f32)>,
    ) {
        let tile_pixels = self.width as usize * self.height as usize;
        for (level, value, weight) in samples {
            // One NaN would spoil the pixel's whole mean: refuse the sample, count it. Written
            // so that NaN fails.
            if !(value.is_finite()
                && value.min_element() >= -MAX_SAMPLE_RADIANCE
                && value.max_element() <= MAX_SAMPLE_RADIANCE
                && weight >= 0.0
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
    /// Adds each pixel's weighted mean sample of `tile`, with its summed weight, level by level. The tile must lie inside the
    /// image and have at most this frame's levels.
    pub fn add_tile(&mut self, tile: &TileTargets) {
        self.add_tiles(&[tile]);
    }

    /// [`TrainingTargets::add_tile`] for every tile of a frame, rows of the image in parallel:
    /// each pixel takes the same values in the same order as adding the tiles one after the
    /// other, so the targets are bit for bit the same on any number of threads. (Serial, this
    /// was a tenth of a cached frame at 1280x720 and did not scale: issue 31.)
    pub fn add_tiles(&mut self, tiles: &[&TileTargets]) {
        let (width, height) = (self.width as usize, self.height as usize);
        // The statistics (unbiased estimator only) go per cache pixel: in tile order, serially.
        for tile in tiles {
            self.dropped += tile.dropped;
            if let (Some((map, stats, moments)), Some(t)) =
                (self.statistics.as_mut(), tile.statistics.as_ref())
            {
                stats.add_tile(t, (tile.x0, tile.y0, tile.width), map, moments);
            }
        }
        // Per image row, the tiles that cross it, in the order given.
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
                self.width,
                self.height
            );
            for row in &mut crossing[rows] {
                row.push(tile);
            }
        }
        let levels = self.levels();
        let mut dropped = 0;
        for level in 0..levels {
            dropped += self.sums[level]
                .par_chunks_mut(width)
                .zip(self.weights[level].par_chunks_mut(width))
                .zip(self.squares[level].par_chunks_mut(width))
                .zip(self.counts[level].par_chunks_mut(width))
                .zip(crossing.par_iter().enumerate())
                .map(|((((sums, weights), squares), counts), (y, tiles))| {
                    let mut dropped = 0u64;
                    for tile in tiles.iter().filter(|t| level < t.levels) {
                        let tile_pixels = tile.width as usize * tile.height as usize;
                        let j = y - tile.y0 as usize;
                        for i in 0..tile.width as usize {
                            let k = level * tile_pixels + j * tile.width as usize + i;
                            if tile.weights[k] > 0.0 {
                                let x = tile.x0 as usize + i;
                                let mean = (tile.sums[k] / tile.weights[k]).to_array();
                                let bin = Bin {
                                    sum: &mut sums[x],
                                    weight: &mut weights[x],
                                    square: &mut squares[x],
                                    count: &mut counts[x],
                                };
                                if !bin.add(mean, tile.weights[k]) {
                                    dropped += 1;
                                }
                            }
                        }
                    }
                    dropped
                })
                .sum::<u64>();
        }
        self.dropped += dropped;
    }
}

#[cfg(test)]
mod tests {

    /// A target brighter than any sample a film accepts is refused and counted like a NaN one:
    /// frames of 3e38 targets once overflowed the loss and drew a level of infinite pixels
    /// (and the C ABI returned OK).
    #[test]
    fn targets_above_the_largest_sample_are_dropped() {
        let mut t = TrainingTargets::new(1, 2, 1);
        t.add(0, 0, [3e38; 3]);
        t.add(0, 0, [1.0, MAX_SAMPLE_RADIANCE * 2.0, 1.0]);
        t.add(0, 1, [MAX_SAMPLE_RADIANCE; 3]);
        assert_eq!(t.dropped(), 2);
    }

    use super::*;

    /// A NaN or huge sample is refused and counted; the pixel keeps the mean of the rest
    /// (before, one NaN made the pixel's whole mean NaN and the pixel was lost). A negative
    /// sample (the unbiased estimator's) is kept.
    #[test]
    fn bad_samples_are_counted_and_do_not_spoil_a_pixel() {
        let mut tile = TileTargets::new(1, 0, 0, 2, 1);
        tile.add_samples(0, [(0, Vec3::splat(1.0), 1.0), (0, Vec3::splat(3.0), 1.0)]);
        tile.add_samples(0, [(0, Vec3::new(f32::NAN, 0.0, 0.0), 1.0)]);
        tile.add_samples(
            0,
            [(0, Vec3::splat(-3e38), 1.0), (0, Vec3::ONE, f32::INFINITY)],
        );
        tile.add_samples(1, [(0, Vec3::splat(-1.0), 1.0)]);
        let mut targets = TrainingTargets::new(1, 2, 1);
        targets.add_tile(&tile);
        targets.add(0, 1, [f32::NAN; 3]);
        assert_eq!(targets.dropped(), 4);
        assert_eq!(targets.sums[0][0], [4.0; 3]); // the mean of 1 and 3, weight 2
        assert_eq!(targets.sums[0][1], [-1.0; 3]); // kept
        assert_eq!(targets.counts[0], vec![1, 1]);
        assert_eq!(targets.weights[0], vec![2.0, 1.0]);
        targets.clear();
        assert_eq!(targets.dropped(), 0);
    }

    /// Survivor weights survive the binning: two pixels in one cache pixel, each with one path,
    /// one of weight 1 and value 1, one of weight 3 and value 5: the bin's target is their
    /// weighted mean 4, not the plain mean 3 (which taking each pixel's mean with weight 1 gave).
    #[test]
    fn weights_are_kept_through_the_binning() {
        let mut tile = TileTargets::new(1, 0, 0, 2, 2);
        tile.add_samples(0, [(0, Vec3::splat(1.0), 1.0)]);
        tile.add_samples(1, [(0, Vec3::splat(5.0), 3.0)]);
        let mut targets = TrainingTargets::new(1, 2, 2);
        targets.add_tile(&tile);
        let map = PixelMap::for_size(2, 2, 2);
        assert_eq!((map.width, map.height), (1, 1));
        let (target, mask) = targets.level_target_binned(0, true, &map);
        assert_eq!((target, mask), (vec![[4.0; 3]], vec![true]));
        let (target, _) = targets.level_target(0, true);
        assert_eq!(&target[..2], &[[1.0; 3], [5.0; 3]]);
    }

    /// The parallel gather and binning (issue 31) give, on 1 and on 4 threads, bit for bit what
    /// adding each tile pixel's mean one after the other and binning serially gives: a
    /// 70x45 frame in 16x16 tiles (ragged at the edges), 2 levels, hashed samples with weights,
    /// some pixels empty, binned 4:1 with the map's odd edge bins.
    #[test]
    fn parallel_gather_and_binning_equal_the_serial_order() {
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
                        tile.add_samples(p as usize, [(level, value, 0.5 + 3.0 * r(5))]);
                    }
                }
                tiles.push(tile);
            }
        }
        // The reference: each tile pixel's weighted mean added one pixel at a time.
        let mut serial = TrainingTargets::new(levels, w, h);
        for tile in &tiles {
            let n = (tile.width * tile.height) as usize;
            for level in 0..levels {
                for j in 0..tile.height {
                    for i in 0..tile.width {
                        let k = level * n + (j * tile.width + i) as usize;
                        if tile.weights[k] > 0.0 {
                            let pixel = ((tile.y0 + j) * w + tile.x0 + i) as usize;
                            let mean = (tile.sums[k] / tile.weights[k]).to_array();
                            serial.add_weighted(level, pixel, mean, tile.weights[k]);
                        }
                    }
                }
            }
        }
        let map = PixelMap::for_size(w, h, 4);
        let refs: Vec<&TileTargets> = tiles.iter().collect();
        for threads in [1, 4] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let parallel = pool.install(|| {
                let mut t = TrainingTargets::new(levels, w, h);
                t.add_tiles(&refs);
                t
            });
            for level in 0..levels {
                let bits =
                    |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&parallel.sums[level]),
                    bits(&serial.sums[level]),
                    "{threads} threads"
                );
                assert_eq!(parallel.counts[level], serial.counts[level]);
                let (a, b) = (
                    pool.install(|| parallel.level_target_binned(level, true, &map)),
                    serial_binned(&serial, level, &map),
                );
                assert_eq!((bits(&a.0), a.1), (bits(&b.0), b.1), "{threads} threads");
                let spread = pool.install(|| parallel.level_spread_binned(level, &map));
                assert!(spread.iter().any(|&(n, v)| n >= 2 && v > 0.0));
            }
        }
    }

    /// The binning as it was written before it ran in parallel: frame rows then columns.
    fn serial_binned(
        t: &TrainingTargets,
        level: usize,
        map: &PixelMap,
    ) -> (Vec<[f32; 3]>, Vec<bool>) {
        let n = map.width as usize * map.height as usize;
        let mut sums = vec![[0.0f64; 3]; n];
        let mut weights = vec![0.0f64; n];
        for y in 0..t.height {
            for x in 0..t.width {
                let i = (y * t.width + x) as usize;
                if t.counts[level][i] > 0 {
                    let b = map.bin(x, y);
                    for k in 0..3 {
                        sums[b][k] += t.sums[level][i][k] as f64;
                    }
                    weights[b] += t.weights[level][i] as f64;
                }
            }
        }
        let target = (0..n)
            .map(|b| {
                if weights[b] > 0.0 {
                    sums[b].map(|v| (v / weights[b]) as f32)
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        (target, weights.iter().map(|&w| w > 0.0).collect())
    }
}
