//! Image losses and their gradients, each with a per-pixel mask (pixels that received no sample
//! take no part). Every loss is a mean over the valid pixels and the three channels.
//!
//! The HDR loss is the GSCache paper's Eq. 4 (after Lehtinen et al.'s Noise2Noise):
//! `L = mean (x - y)^2 / (sg(y) + 0.01)^2` for the noisy target `x` and the prediction `y`, where
//! `sg` stops the gradient: the denominator only rescales each pixel, so the minimiser over many
//! noisy samples of one value is their mean (an undetached denominator would bias it).

/// Which loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Loss {
    Hdr,
    L1,
    L2,
}

/// The constant added to the prediction in the HDR loss's denominator.
pub const HDR_EPSILON: f64 = 0.01;

/// Loss value and its gradient with respect to the prediction (zero at masked-out pixels).
/// `mask = None` uses every pixel. Non-finite targets are treated as masked out.
pub fn loss_and_grad(
    kind: Loss,
    prediction: &[[f32; 3]],
    target: &[[f32; 3]],
    mask: Option<&[bool]>,
) -> (f64, Vec<[f32; 3]>) {
    assert_eq!(prediction.len(), target.len());
    if let Some(m) = mask {
        assert_eq!(m.len(), prediction.len());
    }
    let valid = |i: usize| mask.is_none_or(|m| m[i]) && target[i].iter().all(|v| v.is_finite());
    let count = (0..prediction.len()).filter(|&i| valid(i)).count();
    let mut grad = vec![[0.0f32; 3]; prediction.len()];
    if count == 0 {
        return (0.0, grad);
    }
    let norm = 1.0 / (3 * count) as f64;
    let mut total = 0.0f64;
    for i in 0..prediction.len() {
        if !valid(i) {
            continue;
        }
        for c in 0..3 {
            let y = prediction[i][c] as f64;
            let x = target[i][c] as f64;
            let (l, g) = match kind {
                Loss::Hdr => {
                    let d = y.max(0.0) + HDR_EPSILON;
                    let w = 1.0 / (d * d);
                    ((y - x) * (y - x) * w, 2.0 * (y - x) * w)
                }
                Loss::L1 => ((y - x).abs(), (y - x).signum()),
                Loss::L2 => ((y - x) * (y - x), 2.0 * (y - x)),
            };
            total += l;
            grad[i][c] = (g * norm) as f32;
        }
    }
    (total * norm, grad)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_and_gradients_by_hand() {
        let p = [[1.0f32, 2.0, 0.0], [0.5, 0.5, 0.5]];
        let t = [[0.0f32, 2.0, 1.0], [9.0, 9.0, 9.0]];
        let mask = [true, false];
        let (l, g) = loss_and_grad(Loss::L2, &p, &t, Some(&mask));
        assert!((l - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(g[0], [2.0 / 3.0, 0.0, -2.0 / 3.0]);
        assert_eq!(g[1], [0.0; 3]);
        let (l, _) = loss_and_grad(Loss::L1, &p, &t, Some(&mask));
        assert!((l - 2.0 / 3.0).abs() < 1e-12);
        let (l, g) = loss_and_grad(Loss::Hdr, &p, &t, Some(&mask));
        let want = (1.0 / 1.01f64.powi(2) + 1.0 / 0.01f64.powi(2)) / 3.0;
        assert!((l - want).abs() < 1e-9 * want, "{l} vs {want}");
        assert!((g[0][0] as f64 - 2.0 / 1.01f64.powi(2) / 3.0).abs() < 1e-6);
    }
}
