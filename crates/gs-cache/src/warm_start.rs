//! The warm start: a fresh level's colours fitted straight to its first frames' samples.
//!
//! Adam moves a colour by about one learning rate per step whatever the error, so a cache that
//! starts from albedos needs tens of frames to reach the scene's radiance, and loses to plain
//! path tracing until it does (docs/results/schedule). But a level's image is linear in its
//! colours: with `w_i(p)` Gaussian `i`'s blending weight at pixel `p` (its alpha times the
//! transmittance in front of it), `I(p) = sum_i w_i(p) c_i`. So the colours that fit a target
//! `T` in least squares are one linear solve away, and one step of a simultaneous (Cimmino)
//! iteration moves each colour by the blending-weighted residuals it covers, scaled by the
//! matching row of `W^T W` summed (which bounds its largest eigenvalue, so the step cannot
//! overshoot):
//!
//! `c_i += sum_p w_i(p) (T(p) - I(p)) / D_i`, `D_i = sum_p w_i(p) A(p)`,
//!
//! with `A(p) = sum_j w_j(p)` the pixel's coverage (one minus its final transmittance). A
//! Gaussian alone on its pixels, or a stack of them over a uniform residual, is fitted in one
//! step; the fixed point is the least-squares fit. Both sums are the rasteriser's colour gradient
//! for an upstream gradient of `T - I` and of `A`, so the backward pass computes them with no
//! kernel of its own. Over the warm-start frames `D_i` is summed over the frames so far, so the
//! colours become a running mean of the frames' fits, each Gaussian's frames weighted by how much
//! of it they saw: a Gaussian's first sight of the samples sets its colour, and noisy per-frame
//! targets average out as in a sample mean. Positions, rotations and opacities keep training
//! with Adam meanwhile; only the colours are taken over.
//!
//! Measured against Adam alone (docs/results/warm_start), the mean also removes a bias: on
//! hydrogen, whose samples are heavy-tailed, Adam's bounded steps settle below the samples' mean.

use crate::init::SH_C0;
use splat_raster::raster::ForwardState;
use splat_raster::{Camera, GaussianCloud, PixelGrads, backward};

/// The smallest `D_i` a Gaussian needs over the masked pixels to be refitted: below it the
/// Gaussian is (nearly) invisible there and its colour is left alone.
const MIN_COVERAGE: f32 = 1e-4;

/// The smallest colour a step leaves (in the level's relative units, where the mean radiance is
/// about 1): a colour clamped to 0 has no gradient, so it could never be refitted again.
const COLOR_FLOOR: f32 = 1e-4;

/// A level as the frame drew it: what a warm-start step starts from.
pub(crate) struct Drawn<'a> {
    pub camera: &'a Camera,
    pub state: &'a ForwardState<f32>,
    /// The image drawn, in radiance.
    pub prediction: &'a [[f32; 3]],
    /// The cloud's colours are radiance over this.
    pub radiance_scale: f32,
}

/// One warm-start step on a degree-0 cloud drawn as `drawn`, towards `target` where `mask`
/// holds: [`warm_sums`], then [`apply_fit`] (what a level's training step does, in two parts).
#[cfg(test)]
pub(crate) fn fit_colors(
    cloud: &mut GaussianCloud<f32>,
    drawn: Drawn<'_>,
    target: &[[f32; 3]],
    mask: &[bool],
    weights: &mut [f32],
) -> usize {
    let sums = warm_sums(cloud, drawn, target, mask, None);
    apply_fit(cloud, &sums, weights)
}

/// What a warm-start step moves the colours by, per colour channel: the blending-weighted
/// residuals and the coverage-weighted blending weights (the step's numerator and `D_i`), both
/// times the same chain factor.
pub(crate) struct WarmSums {
    numerator: Vec<f32>,
    denominator: Vec<f32>,
}

/// The sums of one warm-start step on a degree-0 cloud drawn as `drawn`, towards `target`
/// where `mask` holds (`target` and `prediction` are radiance; the cloud's colours are radiance
/// over `radiance_scale`). Reads the cloud only, so a level's training step computes them beside
/// its own backward pass; the two passes they need run side by side too (issue 31).
pub(crate) fn warm_sums(
    cloud: &GaussianCloud<f32>,
    drawn: Drawn<'_>,
    target: &[[f32; 3]],
    mask: &[bool],
    weights: Option<&[[f32; 3]]>,
) -> WarmSums {
    let weight = |i: usize| weights.map_or([1.0; 3], |w| w[i]);
    let Drawn {
        camera,
        state,
        prediction,
        radiance_scale,
    } = drawn;
    let to_colour = 1.0 / radiance_scale;
    debug_assert_eq!(cloud.color_model, splat_raster::ColorModel::Sh(0));
    let residual: Vec<[f32; 3]> = prediction
        .iter()
        .zip(target)
        .zip(mask)
        .enumerate()
        .map(|(i, ((p, t), &m))| {
            if m {
                let w = weight(i);
                std::array::from_fn(|c| (t[c] - p[c]) * to_colour * w[c])
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let coverage: Vec<[f32; 3]> = mask
        .iter()
        .zip(state.transmittance(camera))
        .enumerate()
        .map(|(i, (&m, t))| {
            if m {
                weight(i).map(|w| (1.0 - t) * w)
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let gradient = |upstream: &[[f32; 3]]| {
        backward(
            cloud,
            camera,
            state,
            PixelGrads {
                color: upstream,
                transmittance: None,
                depth: None,
            },
        )
        .colors
    };
    let (numerator, denominator) = rayon::join(|| gradient(&residual), || gradient(&coverage));
    WarmSums {
        numerator,
        denominator,
    }
}

/// Moves each colour by its step: `weights` holds each colour channel's `D_i` summed over the
/// earlier warm-start frames (3 per Gaussian, zeros at the start); this frame's is added.
/// Colours are kept at or above a small floor (the rasteriser clamps them at 0). Returns how
/// many Gaussians were refitted.
pub(crate) fn apply_fit(
    cloud: &mut GaussianCloud<f32>,
    sums: &WarmSums,
    weights: &mut [f32],
) -> usize {
    debug_assert_eq!(weights.len(), cloud.colors.len());
    // Both sums carry the same chain factor (SH_C0, or 0 where a colour is clamped), which
    // cancels.
    let mut refitted = 0;
    for (((dc, num), den), summed) in cloud
        .colors
        .chunks_exact_mut(3)
        .zip(sums.numerator.chunks_exact(3))
        .zip(sums.denominator.chunks_exact(3))
        .zip(weights.chunks_exact_mut(3))
    {
        let mut any = false;
        for c in 0..3 {
            // Written so a NaN weight fails it: NaN never reaches a colour.
            if !(den[c] > MIN_COVERAGE * SH_C0) {
                continue;
            }
            summed[c] += den[c];
            let step = num[c] / summed[c];
            if !step.is_finite() {
                continue;
            }
            let colour = (0.5 + SH_C0 * dc[c] + step).max(COLOR_FLOOR);
            dc[c] = (colour - 0.5) / SH_C0;
            any = true;
        }
        refitted += any as usize;
    }
    refitted
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use splat_raster::{ColorModel, RasterConfig, render};

    fn camera() -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64).unwrap()
    }

    /// A degree-0 cloud of isotropic Gaussians at `centres` (x, y on the z = 0 plane), radius
    /// `sigma`, opacity `alpha`, colours `colours`.
    fn cloud(centres: &[[f32; 2]], sigma: f32, alpha: f32, colours: &[[f32; 3]]) -> GaussianCloud {
        let mut c = GaussianCloud::new(ColorModel::Sh(0));
        let logit = (alpha / (1.0 - alpha)).ln();
        for (xy, rgb) in centres.iter().zip(colours) {
            let dc = rgb.map(|v| (v - 0.5) / SH_C0);
            c.push(
                [xy[0], xy[1], 0.0],
                [sigma.ln(); 3],
                [1.0, 0.0, 0.0, 0.0],
                &dc,
                logit,
            );
        }
        c
    }

    fn colours(c: &GaussianCloud) -> Vec<[f32; 3]> {
        c.colors
            .chunks_exact(3)
            .map(|dc| [0, 1, 2].map(|k| 0.5 + SH_C0 * dc[k]))
            .collect()
    }

    /// Squared image error against `target` over the whole frame, in f64.
    fn error(image: &[[f32; 3]], target: &[[f32; 3]]) -> f64 {
        image
            .iter()
            .zip(target)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] as f64 - b[k] as f64).powi(2)))
            .sum()
    }

    /// One step from any start, scaled by a radiance scale, with the accumulated weights, and
    /// with every target, prediction and mask shape the cache gives it.
    fn step(c: &mut GaussianCloud, target: &[[f32; 3]], scale: f32, weights: &mut [f32]) -> f64 {
        let cam = camera();
        let (out, state) = render(c, &cam, &RasterConfig::default());
        let prediction: Vec<[f32; 3]> = out.color.iter().map(|p| p.map(|v| v * scale)).collect();
        let mask = vec![true; prediction.len()];
        let drawn = Drawn {
            camera: &cam,
            state: &state,
            prediction: &prediction,
            radiance_scale: scale,
        };
        fit_colors(c, drawn, target, &mask, weights);
        error(&prediction, target)
    }

    /// Gaussians far apart (no two overlap on any pixel) against a target that some colours
    /// produce exactly: one step lands on those colours, whatever the start and the radiance
    /// scale, to f32 rounding.
    #[test]
    fn isolated_gaussians_are_fitted_in_one_step() {
        let centres = [[-1.0, -1.0], [1.0, -1.0], [0.0, 1.0]];
        let truth = [[0.2, 1.5, 3.0], [4.0, 0.5, 0.05], [1.0, 1.0, 1.0]];
        let scale = 2.5;
        let target_cloud = cloud(&centres, 0.15, 0.8, &truth);
        let (out, _) = render(&target_cloud, &camera(), &RasterConfig::default());
        let target: Vec<[f32; 3]> = out.color.iter().map(|p| p.map(|v| v * scale)).collect();
        let mut c = cloud(&centres, 0.15, 0.8, &[[0.7; 3]; 3]);
        let mut weights = vec![0.0; 9];
        step(&mut c, &target, scale, &mut weights);
        for (got, want) in colours(&c).iter().zip(&truth) {
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() <= 1e-3 * want[k],
                    "{got:?} against {want:?}"
                );
            }
        }
    }

    /// Overlapping Gaussians (a 5x5 grid, each covering its neighbours): repeated steps with
    /// fresh weights (the iteration at full step) lower the error at every step (no overshoot)
    /// and reach a consistent target to 1e-4 of the start's error.
    #[test]
    fn overlapping_gaussians_converge_without_overshoot() {
        let centres: Vec<[f32; 2]> = (0..25)
            .map(|i| [(i % 5) as f32 * 0.3 - 0.6, (i / 5) as f32 * 0.3 - 0.6])
            .collect();
        let truth: Vec<[f32; 3]> = (0..25)
            .map(|i| [0.1 + (i % 7) as f32 * 0.3, 1.0, 2.0 - (i % 4) as f32 * 0.4])
            .collect();
        let target_cloud = cloud(&centres, 0.2, 0.6, &truth);
        let (out, _) = render(&target_cloud, &camera(), &RasterConfig::default());
        let mut c = cloud(&centres, 0.2, 0.6, &vec![[1.0; 3]; 25]);
        let start = step(&mut c, &out.color, 1.0, &mut vec![0.0; 75]);
        let mut last = start;
        for k in 0..200 {
            let e = step(&mut c, &out.color, 1.0, &mut vec![0.0; 75]);
            assert!(e <= last * (1.0 + 1e-4), "step {k}: error {e} after {last}");
            last = e;
        }
        assert!(last < 1e-4 * start, "error {last} from {start}");
    }

    /// Noisy targets over frames with the weights summed: an isolated Gaussian's colour is the
    /// mean of the frames' own fits (a running mean, not the last frame), to f32 rounding.
    #[test]
    fn summed_weights_give_the_running_mean() {
        let centres = [[0.0, 0.0]];
        let mut c = cloud(&centres, 0.2, 0.7, &[[1.0; 3]]);
        let mut weights = vec![0.0; 3];
        let frames = [0.5f32, 2.0, 1.25, 3.0, 0.75];
        for &v in &frames {
            let target_cloud = cloud(&centres, 0.2, 0.7, &[[v, 2.0 * v, 0.5]]);
            let (out, _) = render(&target_cloud, &camera(), &RasterConfig::default());
            step(&mut c, &out.color, 1.0, &mut weights);
        }
        let mean = frames.iter().sum::<f32>() / frames.len() as f32;
        let got = colours(&c)[0];
        for (g, w) in got.iter().zip([mean, 2.0 * mean, 0.5]) {
            assert!((g - w).abs() <= 1e-4 * w, "{got:?} against the mean {mean}");
        }
    }

    /// Pixels outside the mask take no part: a NaN target there changes nothing and no colour
    /// becomes NaN; a Gaussian that sees no masked pixel keeps its colour.
    #[test]
    fn masked_pixels_and_unseen_gaussians_are_left_alone() {
        let cam = camera();
        let mut c = cloud(&[[-1.0, 0.0], [1.0, 0.0]], 0.15, 0.8, &[[0.3; 3], [0.6; 3]]);
        let (out, state) = render(&c, &cam, &RasterConfig::default());
        // Mask: the left half only; the target is what colour 2 on the left Gaussian draws
        // there, and NaN on the right half.
        let two = cloud(&[[-1.0, 0.0], [1.0, 0.0]], 0.15, 0.8, &[[2.0; 3], [0.6; 3]]);
        let (drawn, _) = render(&two, &cam, &RasterConfig::default());
        let mask: Vec<bool> = (0..64 * 64).map(|p| p % 64 < 32).collect();
        let target: Vec<[f32; 3]> = mask
            .iter()
            .zip(&drawn.color)
            .map(|(&m, &t)| if m { t } else { [f32::NAN; 3] })
            .collect();
        let mut weights = vec![0.0; 6];
        let drawn = Drawn {
            camera: &cam,
            state: &state,
            prediction: &out.color,
            radiance_scale: 1.0,
        };
        let n = fit_colors(&mut c, drawn, &target, &mask, &mut weights);
        assert_eq!(n, 1);
        let got = colours(&c);
        assert!(got.iter().flatten().all(|v| v.is_finite()), "{got:?}");
        assert!((got[0][0] - 2.0).abs() < 2e-3, "{got:?}");
        assert_eq!(got[1], [0.6; 3]);
    }
}
