//! The cache drawn and trained at a fraction of the frame's resolution, and read back at the
//! frame's: the levels are smooth (each pixel holds an expectation over the paths through it),
//! so a coarser image holds nearly the same information for a fraction of the splat and
//! training time.
//!
//! A frame of `W x H` pixels and a divisor `d` give a cache image of `h = ceil(H / d)` rows and
//! `w = ceil(W h / H)` columns, drawn by a camera with the same pose and field of view: the two
//! pinhole images are then related by one scale `s = h / H` about their centres, so a frame
//! pixel's continuous position `(x, y)` lies at `(w/2 + s (x - W/2), s y)` in the cache image
//! (which covers at least the whole frame). Training bins each frame pixel's samples into the
//! cache pixel containing its centre; reading interpolates the cache image bilinearly at the
//! frame pixel's centre.

use rayon::prelude::*;
use splat_raster::Camera;

/// How frame pixels map into a cache image of lower resolution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelMap {
    frame_width: u32,
    frame_height: u32,
    /// The cache image's size.
    pub width: u32,
    pub height: u32,
    /// Cache pixels per frame pixel.
    scale: f32,
    /// Horizontal offset of the frame's left edge in the cache image.
    offset_x: f32,
}

impl PixelMap {
    /// The cache camera for `camera` at `1 / divisor` of its resolution, and the map between
    /// the two. `divisor` 1 gives the frame's own camera and the identity.
    pub fn new(camera: &Camera, divisor: u32) -> (Camera, Self) {
        let map = Self::for_size(camera.width, camera.height, divisor);
        let cache_camera = Camera {
            width: map.width,
            height: map.height,
            ..*camera
        };
        (cache_camera, map)
    }

    /// The map for frames of `frame_width` x `frame_height` pixels.
    pub fn for_size(frame_width: u32, frame_height: u32, divisor: u32) -> Self {
        let (fw, fh) = (frame_width.max(1), frame_height.max(1));
        let d = divisor.max(1);
        let height = fh.div_ceil(d).max(1);
        let width = if d == 1 {
            fw
        } else {
            ((fw as u64 * height as u64).div_ceil(fh as u64) as u32).max(1)
        };
        let scale = height as f32 / fh as f32;
        Self {
            frame_width: fw,
            frame_height: fh,
            width,
            height,
            scale,
            offset_x: 0.5 * width as f32 - scale * 0.5 * fw as f32,
        }
    }

    /// The frame's size.
    pub fn frame_size(&self) -> (u32, u32) {
        (self.frame_width, self.frame_height)
    }

    /// Whether the cache image is the frame's own.
    pub fn is_identity(&self) -> bool {
        self.width == self.frame_width && self.height == self.frame_height
    }

    /// Continuous cache-image position of frame pixel `(x, y)`'s centre.
    #[inline]
    fn position(&self, x: u32, y: u32) -> (f32, f32) {
        (
            self.offset_x + self.scale * (x as f32 + 0.5),
            self.scale * (y as f32 + 0.5),
        )
    }

    /// Row-major index of the cache pixel that holds frame pixel `(x, y)`'s centre.
    #[inline]
    pub fn bin(&self, x: u32, y: u32) -> usize {
        let (u, v) = self.position(x, y);
        let i = (u as u32).min(self.width - 1);
        let j = (v as u32).min(self.height - 1);
        (j * self.width + i) as usize
    }

    /// `cache` (a cache-resolution image) read at frame pixel `(x, y)`'s centre by bilinear
    /// interpolation between cache pixel centres, clamped at the image's edges.
    #[inline]
    pub fn sample(&self, cache: &[[f32; 3]], x: u32, y: u32) -> [f32; 3] {
        let (w, h) = (self.width as usize, self.height as usize);
        debug_assert_eq!(cache.len(), w * h);
        let (u, v) = self.position(x, y);
        let fy = (v - 0.5).clamp(0.0, (h - 1) as f32);
        let j0 = fy as usize;
        let j1 = (j0 + 1).min(h - 1);
        let ty = fy - j0 as f32;
        let fx = (u - 0.5).clamp(0.0, (w - 1) as f32);
        let i0 = fx as usize;
        let i1 = (i0 + 1).min(w - 1);
        let tx = fx - i0 as f32;
        let (a, b) = (cache[j0 * w + i0], cache[j0 * w + i1]);
        let (c, e) = (cache[j1 * w + i0], cache[j1 * w + i1]);
        std::array::from_fn(|k| {
            let top = a[k] + tx * (b[k] - a[k]);
            let bottom = c[k] + tx * (e[k] - c[k]);
            top + ty * (bottom - top)
        })
    }

    /// `cache` read at every frame pixel's centre ([`PixelMap::sample`]).
    pub fn upsample(&self, cache: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let fw = self.frame_width as usize;
        let mut out = vec![[0.0f32; 3]; fw * self.frame_height as usize];
        // Rows in parallel: each output row is written by one task.
        out.par_chunks_mut(fw).enumerate().for_each(|(y, row)| {
            for (x, px) in row.iter_mut().enumerate() {
                *px = self.sample(cache, x as u32, y as u32);
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn camera(w: u32, h: u32) -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 40.0, w, h).unwrap()
    }

    #[test]
    fn the_cache_camera_sees_each_frame_pixel_where_the_map_puts_it() {
        // Odd sizes: the cache image is wider than the frame's share and offset.
        for (w, h, d) in [(320, 180, 2), (321, 181, 4), (97, 33, 3), (64, 48, 1)] {
            let cam = camera(w, h);
            let (cc, map) = PixelMap::new(&cam, d);
            assert_eq!((cc.width, cc.height), (map.width, map.height));
            for (x, y) in [(0, 0), (w - 1, h - 1), (w / 3, h / 2)] {
                let dir = cam.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
                let (u, v) = cc.project_camera_point(cc.world_to_camera(cam.position + dir));
                let (mu, mv) = map.position(x, y);
                assert!(
                    (u - mu).abs() < 1e-3 && (v - mv).abs() < 1e-3,
                    "{w}x{h}/{d} pixel ({x}, {y}): camera says ({u}, {v}), map ({mu}, {mv})"
                );
                assert!(u >= 0.0 && u <= cc.width as f32 && v >= 0.0 && v <= cc.height as f32);
            }
        }
    }

    #[test]
    fn identity_at_divisor_one() {
        let cam = camera(40, 30);
        let (cc, map) = PixelMap::new(&cam, 1);
        assert!(map.is_identity() && cc == cam);
        let img: Vec<[f32; 3]> = (0..1200).map(|i| [i as f32, 0.0, 1.0]).collect();
        assert_eq!(map.upsample(&img), img);
        for (x, y) in [(0, 0), (39, 29), (7, 11)] {
            assert_eq!(map.bin(x, y), (y * 40 + x) as usize);
        }
    }

    #[test]
    fn upsampling_reproduces_a_linear_ramp() {
        // Bilinear interpolation is exact on a linear function away from the clamped edges.
        let cam = camera(64, 32);
        let (_, map) = PixelMap::new(&cam, 2);
        let (w, h) = (map.width as usize, map.height as usize);
        let f = |u: f32, v: f32| 2.0 * u + 3.0 * v + 1.0;
        let low: Vec<[f32; 3]> = (0..w * h)
            .map(|k| {
                let (i, j) = ((k % w) as f32 + 0.5, (k / w) as f32 + 0.5);
                [f(i, j); 3]
            })
            .collect();
        let up = map.upsample(&low);
        for y in 2..30 {
            for x in 2..62 {
                let (u, v) = map.position(x, y);
                let got = up[(y * 64 + x) as usize][0];
                assert!(
                    (got - f(u, v)).abs() < 1e-3,
                    "({x}, {y}): {got} against {}",
                    f(u, v)
                );
            }
        }
    }

    #[test]
    fn binned_targets_are_the_mean_of_the_samples_in_each_cache_pixel() {
        use crate::TrainingTargets;
        let cam = camera(8, 4);
        let (_, map) = PixelMap::new(&cam, 2);
        assert_eq!((map.width, map.height), (4, 2));
        let mut t = TrainingTargets::new(1, map);
        // Frame pixels (0, 0), (1, 0), (0, 1) fall in cache pixel 0 (one sample each);
        // (1, 1) has none. Pixel (7, 3) alone fills cache pixel 7.
        t.add(0, 0, [1.0, 2.0, 3.0]);
        t.add(0, 1, [3.0, 2.0, 1.0]);
        t.add(0, 8, [2.0, 2.0, 2.0]);
        t.add(0, 31, [5.0, 0.0, 0.0]);
        let (target, mask) = t.level_target(0, true);
        assert_eq!(target[0], [2.0, 2.0, 2.0]);
        assert_eq!(target[7], [5.0, 0.0, 0.0]);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 2);
        assert!(mask[0] && mask[7]);
    }
}
