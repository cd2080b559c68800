//! A brute-force compositor: every pixel looks at every splat, sorts those it sees by depth, and
//! composites them. No tiles, no bounding boxes: the reference the tiled rasteriser must equal.

use crate::camera::Camera;
use crate::cloud::GaussianCloud;
use crate::project::{CameraTerms, T_MIN, project};
use crate::raster::{RasterConfig, RenderOutput, splat_alpha};
use crate::real::Real;

pub fn render_reference<F: Real>(
    cloud: &GaussianCloud<F>,
    camera: &Camera,
    config: &RasterConfig,
) -> RenderOutput<F> {
    let cam = CameraTerms::<F>::new(camera);
    let near = F::c(config.near as f64);
    let splats: Vec<(u32, _)> = (0..cloud.len())
        .filter_map(|g| project(cloud, g, &cam, config.low_pass, near).map(|s| (g as u32, s)))
        .collect();
    let (w, h) = (camera.width, camera.height);
    let bg = config.background.map(|v| F::c(v as f64));
    let mut out = RenderOutput {
        width: w,
        height: h,
        color: vec![[F::zero(); 3]; (w * h) as usize],
        transmittance: vec![F::one(); (w * h) as usize],
        depth: config.depth.then(|| vec![F::zero(); (w * h) as usize]),
    };
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (F::c(x as f64 + 0.5), F::c(y as f64 + 0.5));
            let mut seen: Vec<_> = splats
                .iter()
                .filter_map(|(g, s)| {
                    splat_alpha(s, px, py).map(|(a, ..)| (*g, s.depth, a, s.color))
                })
                .collect();
            seen.sort_by(|a, b| a.1.partial_cmp(&b.1).unwrap().then(a.0.cmp(&b.0)));
            let (mut t, mut c, mut d) = (F::one(), [F::zero(); 3], F::zero());
            for (_, depth, alpha, color) in seen {
                let next = t * (F::one() - alpha);
                if next < F::c(T_MIN) {
                    break;
                }
                for ch in 0..3 {
                    c[ch] = c[ch] + alpha * t * color[ch];
                }
                d = d + alpha * t * depth;
                t = next;
            }
            let q = (y * w + x) as usize;
            out.color[q] = [c[0] + t * bg[0], c[1] + t * bg[1], c[2] + t * bg[2]];
            out.transmittance[q] = t;
            if let Some(dd) = out.depth.as_mut() {
                dd[q] = d;
            }
        }
    }
    out
}
