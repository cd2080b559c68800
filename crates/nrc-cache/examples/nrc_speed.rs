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
    let mut cache = NeuralCache::new(config).expect("valid config");
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
    network_alone(&cache, &rows, width, config.batch_size as usize);
    if args.iter().any(|a| a == "--burn-encoding") {
        #[cfg(feature = "burn-oracle")]
        burn_encoding(&cache, &points, config.batch_size as usize);
        #[cfg(not(feature = "burn-oracle"))]
        eprintln!("--burn-encoding needs burn: run with `--features burn-oracle`");
        return;
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

/// The network without the encoding: a forward pass over every query's encoded row (in chunks
/// of 1,024 rows in parallel, as inference runs) and the loss and gradient of one batch, with
/// the multiply-adds per second each reaches.
fn network_alone(cache: &NeuralCache, rows: &[f32], grid_width: usize, batch: usize) {
    use nrc_cache::mlp::{BlockWork, Gradient};
    use rayon::prelude::*;
    let mlp = cache.network();
    let width = mlp.inputs();
    // The grid's encoding, padded with the constant inputs to the network's width.
    let inputs: Vec<f32> = rows
        .chunks_exact(grid_width)
        .flat_map(|r| {
            let mut row = r.to_vec();
            row.resize(width, 0.5);
            row
        })
        .collect();
    let n = inputs.len() / width;
    let macs = mlp.macs_per_row() as f64;
    let mut outputs = vec![0.0f32; n * 3];
    let mut gradient = Gradient::default();
    let targets = vec![1.0f32; batch * 3];
    for _ in 0..3 {
        let t = Instant::now();
        outputs
            .par_chunks_mut(1024 * 3)
            .zip(inputs.par_chunks(1024 * width))
            .for_each_init(BlockWork::default, |work, (y, x)| mlp.forward(x, y, work));
        let forward = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let loss = mlp.loss_and_gradient(&inputs[..batch * width], &targets, 1e-2, &mut gradient);
        let backward = t.elapsed().as_secs_f64();
        println!(
            "network alone: forward of {n} rows {:.2} ms ({:.1} GMAC/s); loss and gradient of {batch} rows {:.2} ms ({:.1} GMAC/s counting 3 passes), loss {loss:.3}",
            forward * 1e3,
            n as f64 * macs / forward / 1e9,
            backward * 1e3,
            3.0 * batch as f64 * macs / backward / 1e9,
        );
    }
}

/// The encoding's gather and its backward done by burn (`select` on the table, whose autodiff
/// backward is a scatter-add), the corner indices and weights computed in Rust, against the
/// plain-Rust encoding and backward: forward over every query, and forward plus backward over
/// one training batch.
#[cfg(feature = "burn-oracle")]
fn burn_encoding(cache: &NeuralCache, points: &[Vec3], batch: usize) {
    use burn::module::Param;
    use burn::tensor::{Device, Int, Tensor, TensorData};
    let grid = cache.grid();
    let width = grid.output_width();
    let levels = width / 2;
    let table_rows = grid.params().len() / 2;
    let device = Device::flex().autodiff();
    let table: Param<Tensor<2>> = Param::from_data(
        TensorData::new(grid.params().to_vec(), [table_rows, 2]),
        &device,
    );
    let encode = |pts: &[Vec3], table: &Param<Tensor<2>>| -> Tensor<2> {
        let (rows, weights) = grid.corner_rows(pts);
        let n = rows.len();
        let idx = Tensor::<1, Int>::from_data(TensorData::new(rows, [n]), &device);
        let w = Tensor::<2>::from_data(TensorData::new(weights, [n, 1]), &device);
        let corners = table.val().select(0, idx) * w;
        corners
            .reshape([pts.len() * levels, 8, 2])
            .sum_dim(1)
            .reshape([pts.len(), width])
    };
    for round in 0..4 {
        let t = Instant::now();
        let _ = grid.corner_rows(points);
        let indices = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let e = encode(points, &table);
        let _ = e.into_data();
        let burn_forward = t.elapsed().as_secs_f64();
        let mut rows = vec![0.0f32; points.len() * width];
        let t = Instant::now();
        grid.encode_rows(points, &mut rows, width);
        let rust_forward = t.elapsed().as_secs_f64();

        let pts = &points[..batch.min(points.len())];
        let upstream = vec![1.0f32; pts.len() * width];
        let t = Instant::now();
        let e = encode(pts, &table);
        let g = Tensor::<2>::from_data(
            TensorData::new(upstream.clone(), [pts.len(), width]),
            &device,
        );
        let grads = (e * g).sum().backward();
        let table_grad = table.val().grad(&grads).expect("the table has a gradient");
        let _ = table_grad.into_data();
        let burn_train = t.elapsed().as_secs_f64();
        let mut grad = vec![0.0f32; grid.params().len()];
        let t = Instant::now();
        let mut rows = vec![0.0f32; pts.len() * width];
        grid.encode_rows(pts, &mut rows, width);
        grid.backward(pts, &upstream, width, &mut grad);
        let rust_train = t.elapsed().as_secs_f64();
        println!(
            "round {round}: forward of {} points: burn {:.1} ms (of which {:.1} ms the corner indices, one thread), Rust {:.1} ms ({:.1}x); forward + backward of {}: burn {:.1} ms, Rust {:.1} ms ({:.1}x)",
            points.len(),
            burn_forward * 1e3,
            indices * 1e3,
            rust_forward * 1e3,
            burn_forward / rust_forward,
            pts.len(),
            burn_train * 1e3,
            rust_train * 1e3,
            burn_train / rust_train
        );
    }
}
