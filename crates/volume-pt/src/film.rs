//! The film: per-pixel running sums in f64 and per-pixel sample counts, so an image stopped at
//! any moment (Ctrl-C) is still the mean of the samples each pixel received.

use glam::{DVec3, Vec3};

/// Side of the square tiles that threads take one at a time.
pub const TILE_SIZE: u32 = 16;

/// One tile of the film and its accumulators.
#[derive(Debug, Clone)]
pub struct Tile {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    pub sum: Vec<DVec3>,
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
                    sum: vec![DVec3::ZERO; n],
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

    /// Mean radiance per pixel, row-major with row 0 at the top; pixels without samples are 0.
    pub fn mean(&self) -> Vec<Vec3> {
        let mut out = vec![Vec3::ZERO; (self.width * self.height) as usize];
        for t in &self.tiles {
            for j in 0..t.height {
                for i in 0..t.width {
                    let k = (j * t.width + i) as usize;
                    let px = ((t.y0 + j) * self.width + t.x0 + i) as usize;
                    if t.count[k] > 0 {
                        out[px] = (t.sum[k] / t.count[k] as f64).as_vec3();
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
