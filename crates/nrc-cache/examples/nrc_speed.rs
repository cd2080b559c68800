//! Per-step costs of the neural radiance cache on a synthetic smooth field: encoding, network
//! inference, and one training step, at the default settings or with `--layers N`.
//!
//! `cargo run --release -p nrc-cache --example nrc_speed -- [--layers N] [--queries N]`

use glam::Vec3;
use nrc_cache::{NeuralCache, NrcConfig, Query, TrainingRecord};
use std::time::Instant;

fn field(p: Vec3) -> Vec3 {
    Vec3::new(
        1.0 + (3.0 * p.x).sin() * (2.0 * p.y).cos(),
        0.5 + 0.4 * (4.0 * p.z).sin(),
        0.2 + p.x * p.y,
    )
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str, default: usize| -> usize {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let config = NrcConfig {
        hidden_layers: arg("--layers", NrcConfig::default().hidden_layers as usize) as u32,
        grid_levels: arg("--levels", NrcConfig::default().grid_levels as usize) as u32,
        grid_log2_table: arg(
            "--log2-table",
            NrcConfig::default().grid_log2_table as usize,
        ) as u32,
        grid_finest_resolution: arg(
            "--finest",
            NrcConfig::default().grid_finest_resolution as usize,
        ) as u32,
        ..Default::default()
    };
    let queries_n = arg("--queries", 57_600);
    let mut cache = NeuralCache::new(config.clone()).expect("valid config");
    let mut rng = nrc_cache::random::SplitMix::new(3);
    let mut point = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    let queries: Vec<Query> = (0..queries_n)
        .map(|_| Query {
            position: point(),
            albedo: Vec3::splat(0.8),
            value: 0.5,
            ..Default::default()
        })
        .collect();
    let records: Vec<TrainingRecord> = (0..(config.batch_size * config.steps_per_frame) as usize)
        .map(|_| {
            let p = point();
            TrainingRecord {
                query: Query {
                    position: p,
                    albedo: Vec3::splat(0.8),
                    value: 0.5,
                    ..Default::default()
                },
                target: field(p),
            }
        })
        .collect();
    println!(
        "layers {}  width {}  inputs {}  MACs/query {}  parameters {:.1} MB",
        config.hidden_layers,
        config.hidden_width,
        config.input_width(),
        cache.macs_per_query(),
        cache.parameter_bytes() as f64 / 1e6
    );
    let points: Vec<Vec3> = queries.iter().map(|q| q.position).collect();
    let width = cache.grid().output_width();
    let mut rows = vec![0.0f32; points.len() * width];
    for _ in 0..3 {
        let t = Instant::now();
        cache.grid().encode_rows(&points, &mut rows, width);
        println!("encoding alone: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    }
    for round in 0..6 {
        let t = Instant::now();
        let out = cache.predict(&queries);
        let infer = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let r = cache.train(&records, round);
        let train = t.elapsed().as_secs_f64();
        let err: f64 = queries
            .iter()
            .zip(&out)
            .map(|(q, o)| ((*o - field(q.position)).length_squared()) as f64)
            .sum::<f64>()
            / queries.len() as f64;
        println!(
            "round {round}: inference {:.1} ms ({:.2} GMAC/s)  train {} steps x {} = {:.1} ms ({:.1} ms/step)  loss {:.4}  mse {:.4}",
            infer * 1e3,
            (cache.macs_per_query() * queries.len()) as f64 / infer / 1e9,
            r.steps,
            config.batch_size,
            train * 1e3,
            train * 1e3 / r.steps.max(1) as f64,
            r.mean_loss,
            err
        );
    }
}
