//! The fused AdamW against burn's AdamW (flex backend), the reference optimiser: identical
//! updates within 1e-6 over several steps, per parameter group with its own learning rate and
//! decoupled weight decay. burn's defaults (epsilon 1e-5, weight decay 1e-4) differ from ours, so
//! both are set explicitly on both sides.

use burn::module::{Module, Param};
use burn::optim::{AdamWConfig as BurnAdamWConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use splat_raster::adamw::AdamW;

mod common;
use common::{adamw_case, adamw_groups, adamw_lr_scale, random_gradient};

#[derive(Module, Debug)]
struct Group {
    w: Param<Tensor<1>>,
}

#[test]
fn fused_adamw_matches_burn() {
    let (cloud, config, mut rng) = adamw_case();
    let settings = adamw_groups(&config);
    let mut ours = AdamW::new(config, &cloud);
    let mut params = cloud.clone();

    let device = Device::flex().autodiff();
    let mut modules: Vec<Group> = cloud
        .groups()
        .iter()
        .map(|(_, v)| Group {
            w: Param::from_data(TensorData::new(v.to_vec(), [v.len()]), &device),
        })
        .collect();
    let mut optims: Vec<_> = settings
        .iter()
        .map(|s| {
            BurnAdamWConfig::new()
                .with_beta_1(0.9)
                .with_beta_2(0.999)
                .with_epsilon(1e-8)
                .with_weight_decay(s.weight_decay)
                .init()
        })
        .collect();

    let steps = 6;
    for step in 0..steps {
        let grads = random_gradient(&params, &mut rng);
        let lr_scale = adamw_lr_scale(step);
        ours.step(&mut params, &grads, lr_scale);
        for (gi, (module, optim)) in modules.iter_mut().zip(optims.iter_mut()).enumerate() {
            let gv = grads.groups()[gi].1.to_vec();
            let grad =
                Tensor::<1>::from_data(TensorData::new(gv.clone(), [gv.len()]), &Device::flex());
            let mut gp = GradientsParams::new();
            gp.register(module.w.id, grad);
            let lr = (settings[gi].lr * lr_scale) as f64;
            *module = optim.step(lr, module.clone(), gp);
        }
        for (gi, module) in modules.iter().enumerate() {
            let theirs: Vec<f32> = module.w.val().into_data().try_to_vec::<f32>().unwrap();
            let mine = params.groups()[gi].1;
            let worst = mine
                .iter()
                .zip(&theirs)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(
                worst <= 1e-6,
                "step {step}, group {}: max difference {worst:e}",
                params.groups()[gi].0
            );
        }
    }
}
