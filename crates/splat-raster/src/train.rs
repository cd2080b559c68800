//! One training step, the loop every fitting program runs: render, compare with the target,
//! back-propagate, update.

use crate::adamw::AdamW;
use crate::camera::Camera;
use crate::cloud::GaussianCloud;
use crate::loss::{Loss, loss_and_grad};
use crate::raster::{PixelGrads, RasterConfig, backward, render};

/// Renders `cloud` from `camera`, takes `loss` against `target` (row-major, masked pixels
/// excluded), back-propagates and steps `optimizer` with every learning rate scaled by
/// `lr_scale`. Returns the loss before the step.
#[allow(clippy::too_many_arguments)]
pub fn train_step(
    cloud: &mut GaussianCloud<f32>,
    camera: &Camera,
    config: &RasterConfig,
    target: &[[f32; 3]],
    mask: Option<&[bool]>,
    loss: Loss,
    optimizer: &mut AdamW,
    lr_scale: f32,
) -> f64 {
    let (image, state) = render(cloud, camera, config);
    let (value, grad) = loss_and_grad(loss, &image.color, target, mask);
    let grads = backward(
        cloud,
        camera,
        &state,
        PixelGrads {
            color: &grad,
            transmittance: None,
            depth: None,
        },
    );
    optimizer.step(cloud, &grads, lr_scale);
    value
}
