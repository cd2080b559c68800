//! Where a level has seen enough paths to be read: error-aware termination's support test
//! (issue 53). A level's value at a cache pixel is a fit to the samples of the paths that
//! reached its vertex there. Where few of the paths through a cache pixel reach the vertex (a
//! thin halo, a silhouette the pixel's footprint straddles), the fit is made mostly by the
//! Gaussians' reach from denser neighbours, and the bilinear read mixes in cache pixels that
//! hold no target at all: the cache's error there is its reconstruction, not noise, and the
//! denoiser keeps it as blotches and dark rims (docs/results/cache_error.md, points 4 and 5).
//!
//! **The test.** Per level and cache pixel, the *coverage* is the fraction of the paths
//! through the pixel that reached the level's vertex (stopped or not), kept as decayed sums
//! over the last frames (`reached / paths`, each multiplied by [`DECAY`] per frame, so a
//! camera move forgets in a few frames). Paths may stop into a level at a cache pixel (early
//! or natural termination) only when every cache pixel of its 3x3 neighbourhood, which holds
//! the four the bilinear read interpolates, has coverage at least `min_coverage`. Elsewhere
//! they go on as plain path tracing does, which costs variance, never brightness.
//!
//! Coverage is a property of the volume, the transfer function and the view, not of the
//! cache's state: it needs no residual test and is as good after one frame as after many
//! (the fallback's residual test, [`crate::fallback`], answers the other question: whether the
//! fit has caught up with a change). A cache pixel no path went through has no coverage and
//! blocks its neighbours: the frame's empty border and the volume's outside.

/// Each frame, the decayed sums are multiplied by this before the frame's counts are added:
/// about three frames of memory, so a moving view's coverage follows it.
pub const DECAY: f32 = 0.7;

/// Per level, per cache pixel: the decayed path counts and the verdict they give.
#[derive(Debug, Clone, Default)]
pub struct Support {
    width: u32,
    height: u32,
    /// Decayed count of the paths through each cache pixel (the same for every level).
    paths: Vec<f32>,
    /// Per level, the decayed count of those paths that reached its vertex.
    reached: Vec<Vec<f32>>,
    /// Per level, whether paths may stop into it at each cache pixel.
    supported: Vec<Vec<bool>>,
}

impl Support {
    /// Sized for `levels` levels of `width` x `height` cache pixels. A new size forgets
    /// everything: no pixel is supported until a frame's paths are counted.
    pub fn fit(&mut self, levels: usize, width: u32, height: u32) {
        if self.width != width || self.height != height || self.reached.len() != levels {
            let n = width as usize * height as usize;
            *self = Self {
                width,
                height,
                paths: vec![0.0; n],
                reached: vec![vec![0.0; n]; levels],
                supported: vec![vec![false; n]; levels],
            };
        }
    }

    /// Whether paths may stop into `level` at row-major cache pixel `bin`.
    #[inline]
    pub fn supported(&self, level: usize, bin: usize) -> bool {
        self.supported[level][bin]
    }

    /// The fraction of `level`'s cache pixels supported.
    pub fn supported_fraction(&self, level: usize) -> f64 {
        let s = &self.supported[level];
        s.iter().filter(|&&b| b).count() as f64 / s.len().max(1) as f64
    }

    /// Adds a frame's counts: `paths[b]` paths went through cache pixel `b`, and
    /// `reached[level][b]` of them reached the level's vertex. Then every verdict is taken
    /// again with `min_coverage`. A frame that counted no path at all (a renderer that does
    /// not report them) changes nothing.
    pub fn update(&mut self, paths: &[u32], reached: &[Vec<u32>], min_coverage: f32) {
        if paths.iter().all(|&p| p == 0) {
            return;
        }
        debug_assert_eq!(paths.len(), self.paths.len());
        for (sum, &p) in self.paths.iter_mut().zip(paths) {
            *sum = *sum * DECAY + p as f32;
        }
        for (sums, counts) in self.reached.iter_mut().zip(reached) {
            for (sum, &r) in sums.iter_mut().zip(counts) {
                *sum = *sum * DECAY + r as f32;
            }
        }
        let (w, h) = (self.width as usize, self.height as usize);
        for (level, supported) in self.supported.iter_mut().enumerate() {
            // Written so that a pixel with no paths (0 / 0) fails the test.
            let covered: Vec<bool> = self.reached[level]
                .iter()
                .zip(&self.paths)
                .map(|(&r, &p)| r >= min_coverage * p && p > 0.0)
                .collect();
            for j in 0..h {
                for i in 0..w {
                    let rows = j.saturating_sub(1)..(j + 2).min(h);
                    supported[j * w + i] = rows
                        .into_iter()
                        .all(|y| (i.saturating_sub(1)..(i + 2).min(w)).all(|x| covered[y * w + x]));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pixel_is_supported_only_when_its_neighbourhood_is_covered() {
        let mut support = Support::default();
        support.fit(1, 5, 3);
        assert_eq!(support.supported_fraction(0), 0.0, "nothing counted yet");
        // Every pixel saw 10 paths; all reached the vertex but at pixel (4, 0), where 3 did.
        let paths = vec![10u32; 15];
        let mut reached = vec![10u32; 15];
        reached[4] = 3;
        support.update(&paths, &[reached.clone()], 0.5);
        let verdicts: Vec<bool> = (0..15).map(|b| support.supported(0, b)).collect();
        // (4, 0)'s neighbours (3, 0), (3, 1), (4, 1) and itself fail; the rest pass.
        let expected: Vec<bool> = (0..15).map(|b| ![3, 4, 8, 9].contains(&b)).collect();
        assert_eq!(verdicts, expected);
        // A frame without counts changes nothing; a low threshold passes everything.
        support.update(&[0; 15], &[vec![0; 15]], 0.5);
        assert_eq!(support.supported_fraction(0), 11.0 / 15.0);
        support.update(&paths, &[reached], 0.2);
        assert_eq!(support.supported_fraction(0), 1.0);
        // A pixel no path went through blocks its neighbours, whatever the threshold.
        let mut paths = vec![10u32; 15];
        paths[7] = 0;
        let mut fresh = Support::default();
        fresh.fit(1, 5, 3);
        fresh.update(&paths, &[vec![0; 15]], 0.0);
        assert!(!fresh.supported(0, 7) && !fresh.supported(0, 1) && fresh.supported(0, 4));
    }

    #[test]
    fn coverage_is_a_decayed_fraction_of_the_paths() {
        let mut support = Support::default();
        support.fit(1, 1, 1);
        // Two frames: 10 paths all reaching, then 10 paths none reaching. Decayed sums:
        // reached 7, paths 17: coverage 0.41.
        support.update(&[10], &[vec![10]], 0.4);
        support.update(&[10], &[vec![0]], 0.4);
        assert!(support.supported(0, 0));
        let mut again = support.clone();
        again.update(&[0], &[vec![0]], 0.42);
        assert!(
            again.supported(0, 0),
            "a frame without counts keeps the verdict"
        );
        support.update(&[10], &[vec![0]], 0.2);
        // reached 4.9, paths 21.9: 0.22.
        assert!(support.supported(0, 0));
        support.update(&[10], &[vec![0]], 0.2);
        assert!(!support.supported(0, 0), "3.43 of 25.3 paths: 0.14");
    }
}
