//! The film: per-pixel running sums and per-pixel sample counts, so an image stopped at any
//! moment (Ctrl-C) is still the mean of the samples each pixel received.
//!
//! The sums are exact: each sample is truncated once to fixed point ([`ExactRgb`], 2^-56
//! steps in an i128), and integer addition does not depend on grouping. Films of disjoint
//! sample ranges rendered on different machines therefore merge, in any order, into the film
//! one process would have made, bit for bit (see [`crate::shard`]). An f64 sum would not: its
//! rounding depends on the order of the additions.
//!
//! A film may also carry feature buffers (AOVs: [`ExactFeatures`]), summed exactly over the
//! same samples as the colour, so that they merge across shards bit for bit too. They are what
//! a denoiser reads beside the colour, and what a compositor reads as albedo, normal, depth
//! and coverage layers.

use glam::Vec3;
use rayon::prelude::*;

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

    /// A sample in fixed point, or `None` when a channel is NaN, infinite or above
    /// [`MAX_SAMPLE_RADIANCE`] in magnitude. Negative samples are kept: an unbiased cache (a
    /// control variate, gs-cache's crate docs) makes them, and dropping them would bias the
    /// pixel's mean upwards. Each channel is checked on its own, written so NaN fails.
    #[inline]
    pub fn from_sample(l: Vec3) -> Option<Self> {
        let mut out = [0i128; 3];
        for (o, c) in out.iter_mut().zip(l.to_array()) {
            // `contains` is false for NaN.
            if !(-MAX_SAMPLE_RADIANCE..=MAX_SAMPLE_RADIANCE).contains(&c) {
                return None;
            }
            // |c| * 2^56 <= 2^95: too big for i64 only above 128, where the (slower) i128
            // conversion is used. Both truncate towards zero; the product is exact in f64.
            let scaled = c as f64 * EXACT_SCALE;
            *o = if scaled.abs() < 9.2e18 {
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

/// Fixed-point steps per unit of albedo or normal component: 2^30. Each sample adds at most
/// 2^30 in magnitude, so 2^32 samples (the count's limit) stay inside an i64 (2^62 < 2^63).
const FEATURE_SCALE: f64 = (1u64 << 30) as f64;
/// Fixed-point steps per world unit of depth: 2^32. A depth is at most [`MAX_SAMPLE_RADIANCE`]
/// (2^39, far beyond any scene: coordinates are limited to 1e6), so 2^32 samples stay far
/// inside an i128 (2^103).
const DEPTH_SCALE: f64 = (1u64 << 32) as f64;

/// One sample's features: what the camera ray met first (see the renderer's `feature_sample`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureSample {
    /// In [0, 1]: at a scattering event, transfer-function colour times single-scattering
    /// albedo; at an emitter seen directly, its radiance clamped.
    pub albedo: Vec3,
    /// Unit normal at a scattering event: minus the extinction gradient there, normalised (see
    /// [`crate::Medium::extinction_normal`]); 0 at an emitter.
    pub normal: Vec3,
    /// World distance from the camera to the scattering event; `None` where the ray met none
    /// (it counts as a miss for coverage and depth).
    pub depth: Option<f32>,
}

/// One pixel's feature sums in fixed point ([`FEATURE_SCALE`] and [`DEPTH_SCALE`] steps):
/// exact, so any grouping of the samples gives the same bits, like [`ExactRgb`].
///
/// A sample whose ray meets no scattering event adds the albedo of what it saw (an emitter's
/// radiance clamped to [0, 1]: the light's disc, the environment) and normal 0 (Open Image
/// Denoise's "no surface here"). Against 0 for every miss and OIDN's transparent-surface 1 it
/// was measured (BENCHMARKS.md, issue 28): the trimmed errors of the three are within 10-20%,
/// and it halved the error of the few pixels by a visible light that the guided filter makes
/// too bright.
/// `hits` counts the samples that met the medium, so coverage is `hits / count` (an unbiased
/// estimate of one minus the transmittance to the background: delta tracking collides with
/// exactly that probability) and depth is averaged over the hits alone.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExactFeatures {
    pub albedo: [i64; 3],
    pub normal: [i64; 3],
    pub depth: i128,
    pub hits: u32,
}

/// The largest magnitude one sample adds to an albedo or normal sum.
pub const MAX_FEATURE_STEPS: i64 = 1 << 30;
/// The largest depth sum one sample adds.
pub const MAX_DEPTH_STEPS: i128 = 1 << 71;

impl ExactFeatures {
    pub const ZERO: Self = Self {
        albedo: [0; 3],
        normal: [0; 3],
        depth: 0,
        hits: 0,
    };

    /// Adds one sample. A value out of range or not finite (which a valid scene cannot make)
    /// makes the sample count as a miss that saw black, written so NaN fails.
    #[inline]
    pub fn add(&mut self, f: FeatureSample) {
        let valid = f.albedo.cmpge(Vec3::ZERO).all()
            && f.albedo.cmple(Vec3::ONE).all()
            && f.normal.abs().cmple(Vec3::ONE).all()
            && f.depth
                .is_none_or(|d| (0.0..=MAX_SAMPLE_RADIANCE).contains(&d));
        if !valid {
            return;
        }
        for k in 0..3 {
            self.albedo[k] += (f.albedo[k] as f64 * FEATURE_SCALE) as i64;
            self.normal[k] += (f.normal[k] as f64 * FEATURE_SCALE) as i64;
        }
        if let Some(d) = f.depth {
            self.depth += (d as f64 * DEPTH_SCALE) as i128;
            self.hits += 1;
        }
    }

    /// Checked sum of two pixels' features (`None` on overflow).
    pub fn checked_add(&self, o: &Self) -> Option<Self> {
        let mut out = *self;
        for k in 0..3 {
            out.albedo[k] = out.albedo[k].checked_add(o.albedo[k])?;
            out.normal[k] = out.normal[k].checked_add(o.normal[k])?;
        }
        out.depth = out.depth.checked_add(o.depth)?;
        out.hits = out.hits.checked_add(o.hits)?;
        Some(out)
    }

    /// Whether these sums can come from `count` samples: no more hits than samples, albedo
    /// sums in `[0, count]`, normal sums within `±count`, depth within `[0, hits x 2^39]`
    /// (in their fixed-point steps).
    pub fn is_possible(&self, count: u32) -> bool {
        let most = count as i64 * MAX_FEATURE_STEPS;
        self.hits <= count
            && self.albedo.iter().all(|a| (0..=most).contains(a))
            && self.normal.iter().all(|n| (-most..=most).contains(n))
            && (0..=self.hits as i128 * MAX_DEPTH_STEPS).contains(&self.depth)
    }

    /// The pixel's mean features over its `count` samples: albedo, normal (not renormalised:
    /// shorter where the samples disagree, as Open Image Denoise expects), depth over the hits
    /// (infinite where none hit) and coverage.
    pub fn mean(&self, count: u32) -> PixelFeatures {
        if count == 0 {
            return PixelFeatures::EMPTY;
        }
        let n = count as f64 * FEATURE_SCALE;
        let v = |s: [i64; 3]| {
            Vec3::new(
                (s[0] as f64 / n) as f32,
                (s[1] as f64 / n) as f32,
                (s[2] as f64 / n) as f32,
            )
        };
        PixelFeatures {
            albedo: v(self.albedo),
            normal: v(self.normal),
            depth: if self.hits == 0 {
                f32::INFINITY
            } else {
                (self.depth as f64 / (self.hits as f64 * DEPTH_SCALE)) as f32
            },
            coverage: (self.hits as f64 / count as f64) as f32,
        }
    }
}

/// One pixel's mean features (see [`ExactFeatures::mean`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelFeatures {
    pub albedo: Vec3,
    pub normal: Vec3,
    pub depth: f32,
    pub coverage: f32,
}

/// Per-pixel features as the images a denoiser and an EXR take.
pub fn feature_images(
    width: u32,
    height: u32,
    pixels: &[PixelFeatures],
) -> hdr_image::FeatureImages {
    hdr_image::FeatureImages::new(
        width,
        height,
        pixels.iter().map(|p| p.albedo).collect(),
        pixels.iter().map(|p| p.normal).collect(),
        pixels.iter().map(|p| p.depth).collect(),
        pixels.iter().map(|p| p.coverage).collect(),
    )
    .expect("one feature per pixel")
}

impl PixelFeatures {
    /// A pixel without samples: no albedo, no normal, nothing hit.
    pub const EMPTY: Self = Self {
        albedo: Vec3::ZERO,
        normal: Vec3::ZERO,
        depth: f32::INFINITY,
        coverage: 0.0,
    };
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
    /// Feature sums, one per pixel; empty when the film keeps no features.
    pub features: Vec<ExactFeatures>,
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
    /// A film of colour alone.
    pub fn new(width: u32, height: u32) -> Self {
        Self::build(width, height, false)
    }

    /// A film that also keeps feature buffers ([`ExactFeatures`]): 68 more bytes a pixel, and
    /// a normal computed at each sample's first scattering event.
    pub fn with_features(width: u32, height: u32) -> Self {
        Self::build(width, height, true)
    }

    fn build(width: u32, height: u32, features: bool) -> Self {
        // The tiles are allocated in parallel: a 1280x720 film is 48 MB in 3600 tiles, which
        // took 5.6 ms of every warm-up frame serially (issue 31). Row-major order is kept.
        let corners: Vec<(u32, u32)> = (0..height)
            .step_by(TILE_SIZE as usize)
            .flat_map(|y0| {
                (0..width)
                    .step_by(TILE_SIZE as usize)
                    .map(move |x0| (x0, y0))
            })
            .collect();
        let tiles = corners
            .into_par_iter()
            .map(|(x0, y0)| {
                let w = TILE_SIZE.min(width - x0);
                let h = TILE_SIZE.min(height - y0);
                let n = (w * h) as usize;
                Tile {
                    x0,
                    y0,
                    width: w,
                    height: h,
                    sum: vec![ExactRgb::ZERO; n],
                    count: vec![0; n],
                    features: if features {
                        vec![ExactFeatures::ZERO; n]
                    } else {
                        Vec::new()
                    },
                }
            })
            .collect();
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

    /// Whether this film keeps feature buffers.
    pub fn has_features(&self) -> bool {
        self.tiles.first().is_some_and(|t| !t.features.is_empty())
    }

    /// Each pixel's mean features, row-major; `None` when the film keeps none.
    pub fn features(&self) -> Option<Vec<PixelFeatures>> {
        let sums = self.exact_features()?;
        Some(
            sums.iter()
                .zip(self.counts())
                .map(|(f, c)| f.mean(c))
                .collect(),
        )
    }

    /// [`Film::features`] as images; `None` when the film keeps none.
    pub fn feature_images(&self) -> Option<hdr_image::FeatureImages> {
        Some(feature_images(self.width, self.height, &self.features()?))
    }

    /// The exact feature sums, row-major; `None` when the film keeps none.
    pub fn exact_features(&self) -> Option<Vec<ExactFeatures>> {
        if !self.has_features() {
            return None;
        }
        let mut out = vec![ExactFeatures::ZERO; (self.width * self.height) as usize];
        self.for_each_pixel(|t, k, px| out[px] = t.features[k]);
        Some(out)
    }

    /// Calls `f(tile, index in tile, row-major pixel index)` for every pixel.
    fn for_each_pixel(&self, mut f: impl FnMut(&Tile, usize, usize)) {
        for t in &self.tiles {
            for j in 0..t.height {
                for i in 0..t.width {
                    f(
                        t,
                        (j * t.width + i) as usize,
                        ((t.y0 + j) * self.width + t.x0 + i) as usize,
                    );
                }
            }
        }
    }

    /// Total number of samples taken over all pixels (tiles in parallel: a session asks twice a
    /// frame, and a serial pass over a 1280x720 film was a millisecond of every frame).
    pub fn total_samples(&self) -> u64 {
        self.tiles
            .par_iter()
            .map(|t| t.count.iter().map(|&c| c as u64).sum::<u64>())
            .sum()
    }

    /// Adds `l` to pixel `(x, y)`'s sum without counting a sample: the deferred part of
    /// samples already counted, such as a neural cache's value composed after the frame's
    /// paths are traced. Refused (false, and counted in `nonfinite_samples`) like a sample
    /// that is NaN, infinite or too bright, or a pixel outside the film.
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

    /// [`Film::add_deferred`] for a frame's worth of values, the tiles in parallel:
    /// `tile_values(rect)` gives each tile's values as (pixel index within the tile,
    /// radiance). The film's sums are exact, so the result is the same bits as adding them one
    /// by one in any order; refused values are counted as `add_deferred` counts them. A neural
    /// cache composes a value into most of a frame's pixels: one serial loop over them would
    /// not scale with the cores (issue 31).
    pub fn add_deferred_by_tile<F, I>(&mut self, tile_values: F)
    where
        F: Fn(crate::cache::TileRect) -> I + Sync,
        I: IntoIterator<Item = (usize, Vec3)>,
    {
        let refused: u64 = self
            .tiles
            .par_iter_mut()
            .map(|t| {
                let mut refused = 0;
                for (k, l) in tile_values(t.rect()) {
                    if k >= t.sum.len() {
                        continue;
                    }
                    match ExactRgb::from_sample(l) {
                        Some(v) => t.sum[k] += v,
                        None => refused += 1,
                    }
                }
                refused
            })
            .sum();
        self.nonfinite_samples += refused;
    }

    /// Mean radiance per pixel, row-major with row 0 at the top; pixels without samples are 0.
    pub fn mean(&self) -> Vec<Vec3> {
        let mut out = vec![Vec3::ZERO; (self.width * self.height) as usize];
        self.for_each_pixel(|t, k, px| {
            if t.count[k] > 0 {
                out[px] = t.sum[k].mean(t.count[k]);
            }
        });
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
        self.for_each_pixel(|t, k, px| {
            sums[px] = t.sum[k];
            counts[px] = t.count[k];
        });
        (sums, counts)
    }

    /// Samples per pixel, row-major.
    pub fn counts(&self) -> Vec<u32> {
        let mut out = vec![0; (self.width * self.height) as usize];
        self.for_each_pixel(|t, k, px| out[px] = t.count[k]);
        out
    }
}
