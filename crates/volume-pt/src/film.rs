//! The film: per-pixel running sums and per-pixel sample counts, so an image stopped at any
//! moment (Ctrl-C) is still the mean of the samples each pixel received.
//!
//! The sums are exact: each sample is truncated once to fixed point ([`ExactRgb`], 2^-56
//! steps in an i128), and integer addition does not depend on grouping. Films of disjoint
//! sample ranges rendered on different machines therefore merge, in any order, into the film
//! one process would have made, bit for bit (see [`crate::shard`]). An f64 sum would not: its
//! rounding depends on the order of the additions.

use glam::Vec3;

/// Side of the square tiles that threads take one at a time.
pub const TILE_SIZE: u32 = 16;

/// Fixed-point steps per unit of radiance: 2^56. A sample is truncated to a multiple of 2^-56
/// (1.4e-17), far below anything an f32 image can show.
const EXACT_SCALE: f64 = (1u64 << 56) as f64;

/// The largest radiance a sample may carry per channel: 2^39 (5.5e11). An i128 sum holds
/// 2^71 in these steps, so even 2^32 samples (the count's limit) at this bound cannot overflow.
/// A brighter sample is refused like a NaN one (counted, and black).
pub const MAX_SAMPLE_RADIANCE: f32 = render_base::MAX_SAMPLE_RADIANCE;

/// An RGB sum in fixed point (2^-56 steps): sums are exact, so any grouping gives the same bits.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExactRgb(pub [i128; 3]);

impl ExactRgb {
    pub const ZERO: Self = Self([0; 3]);

    /// A sample in fixed point, or `None` when a channel is NaN, negative, infinite or above
    /// [`MAX_SAMPLE_RADIANCE`]. Each channel is checked on its own, written so NaN fails.
    #[inline]
    pub fn from_sample(l: Vec3) -> Option<Self> {
        let mut out = [0i128; 3];
        for (o, c) in out.iter_mut().zip(l.to_array()) {
            // `contains` is false for NaN.
            if !(0.0..=MAX_SAMPLE_RADIANCE).contains(&c) {
                return None;
            }
            // c * 2^56 <= 2^95: too big for i64 only above 128, where the (slower) i128
            // conversion is used. Both truncate towards zero; the product is exact in f64.
            let scaled = c as f64 * EXACT_SCALE;
            *o = if scaled < 9.2e18 {
                scaled as i64 as i128
            } else {
                scaled as i128
            };
        }
        Some(Self(out))
    }

    /// The sum divided by `count`: the sum and the count rounded to f64, divided, rounded to f32.
    pub fn mean(&self, count: u32) -> Vec3 {
        let n = count as f64 * EXACT_SCALE;
        Vec3::new(
            (self.0[0] as f64 / n) as f32,
            (self.0[1] as f64 / n) as f32,
            (self.0[2] as f64 / n) as f32,
        )
    }
}

impl std::ops::AddAssign for ExactRgb {
    #[inline]
    fn add_assign(&mut self, o: Self) {
        for (a, b) in self.0.iter_mut().zip(o.0) {
            *a += b;
        }
    }
}

/// One tile of the film and its accumulators.
#[derive(Debug, Clone)]
pub struct Tile {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    pub sum: Vec<ExactRgb>,
    pub count: Vec<u32>,
}

impl Tile {
    /// The part of the image this tile covers.
    pub fn rect(&self) -> crate::cache::TileRect {
        crate::cache::TileRect {
            x0: self.x0,
            y0: self.y0,
            width: self.width,
            height: self.height,
        }
    }
}

/// Accumulated radiance for a whole image.
#[derive(Debug, Clone)]
pub struct Film {
    width: u32,
    height: u32,
    pub(crate) tiles: Vec<Tile>,
    /// Samples that came out NaN or infinite and were counted as black.
    pub nonfinite_samples: u64,
}

impl Film {
    pub fn new(width: u32, height: u32) -> Self {
        let mut tiles = Vec::new();
        for y0 in (0..height).step_by(TILE_SIZE as usize) {
            for x0 in (0..width).step_by(TILE_SIZE as usize) {
                let w = TILE_SIZE.min(width - x0);
                let h = TILE_SIZE.min(height - y0);
                let n = (w * h) as usize;
                tiles.push(Tile {
                    x0,
                    y0,
                    width: w,
                    height: h,
                    sum: vec![ExactRgb::ZERO; n],
                    count: vec![0; n],
                });
            }
        }
        Self {
            width,
            height,
            tiles,
            nonfinite_samples: 0,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Total number of samples taken over all pixels.
    pub fn total_samples(&self) -> u64 {
        self.tiles
            .iter()
            .flat_map(|t| t.count.iter())
            .map(|&c| c as u64)
            .sum()
    }

    /// Adds `l` to pixel `(x, y)`'s sum without counting a sample: the deferred part of
    /// samples already counted, such as a neural cache's value composed after the frame's
    /// paths are traced. Refused (false, and counted in `nonfinite_samples`) like a sample
    /// that is NaN, negative, infinite or too bright, or a pixel outside the film.
    pub fn add_deferred(&mut self, x: u32, y: u32, l: Vec3) -> bool {
        if x >= self.width || y >= self.height {
            return false;
        }
        let Some(v) = ExactRgb::from_sample(l) else {
            self.nonfinite_samples += 1;
            return false;
        };
        let tiles_x = self.width.div_ceil(TILE_SIZE);
        let t = &mut self.tiles[((y / TILE_SIZE) * tiles_x + x / TILE_SIZE) as usize];
        t.sum[((y - t.y0) * t.width + x - t.x0) as usize] += v;
        true
    }

    /// Mean radiance per pixel, row-major with row 0 at the top; pixels without samples are 0.
    pub fn mean(&self) -> Vec<Vec3> {
        let mut out = vec![Vec3::ZERO; (self.width * self.height) as usize];
        for t in &self.tiles {
            for j in 0..t.height {
                for i in 0..t.width {
                    let k = (j * t.width + i) as usize;
                    let px = ((t.y0 + j) * self.width + t.x0 + i) as usize;
                    if t.count[k] > 0 {
                        out[px] = t.sum[k].mean(t.count[k]);
                    }
                }
            }
        }
        out
    }

    /// [`Film::mean`] as an image.
    pub fn image(&self) -> hdr_image::RgbImage {
        hdr_image::RgbImage::from_pixels(self.width, self.height, self.mean())
            .expect("the film's mean has one pixel per film pixel")
    }

    /// The exact sums and the counts, row-major (what a [`crate::shard::PartialRender`] keeps).
    pub fn exact_sums(&self) -> (Vec<ExactRgb>, Vec<u32>) {
        let n = (self.width * self.height) as usize;
        let (mut sums, mut counts) = (vec![ExactRgb::ZERO; n], vec![0; n]);
        for t in &self.tiles {
            for j in 0..t.height {
                for i in 0..t.width {
                    let k = (j * t.width + i) as usize;
                    let px = ((t.y0 + j) * self.width + t.x0 + i) as usize;
                    sums[px] = t.sum[k];
                    counts[px] = t.count[k];
                }
            }
        }
        (sums, counts)
    }

    /// Samples per pixel, row-major.
    pub fn counts(&self) -> Vec<u32> {
        let mut out = vec![0; (self.width * self.height) as usize];
        for t in &self.tiles {
            for j in 0..t.height {
                for i in 0..t.width {
                    out[((t.y0 + j) * self.width + t.x0 + i) as usize] =
                        t.count[(j * t.width + i) as usize];
                }
            }
        }
        out
    }
}
