//! nrc-cache: a neural radiance cache (Müller, Rousselle, Novák and Keller, "Real-time neural
//! radiance caching for path tracing", 2021) for volume path tracers, the baseline the GSCache
//! paper (Bauer et al., 2025) measures itself against. A multiresolution hash-grid encoding of
//! the vertex's position (Müller et al., 2022), with the albedo and data value there, feeds a
//! small ReLU MLP that predicts the radiance a path would gather from that vertex on per unit
//! of its throughput. Like gs-cache it knows nothing of volumes: a renderer gives it vertices
//! (a [`Query`]) and what training paths gathered from them (a [`TrainingRecord`]).
//!
//! - [`config`]: the encoding, the network, training, and how many paths train it.
//! - [`encoding`]: the hash grid, forward, backward and its sparse Adam.
//! - [`mlp`]: the network, forward, backward and Adam, parallel over fixed blocks of rows.
//! - [`dense`]: the small dense products the network is made of, the same bits on every
//!   instruction set.
//! - [`cache`]: batched inference and training steps (relative L2 loss).
//! - [`random`]: counter-based random numbers for initialisation and shuffling.
//!
//! # The estimator
//!
//! With the same notation as gs-cache's (throughput `W_n` after vertex `n`, radiance `R_n` a
//! path gathers from `x_n` on per unit of `W_n`), the cache learns `N(x) ~ E[R_n | x_n = x]`:
//! one function of the vertex for every path length, where gs-cache keeps one image per
//! length. A path stops at vertex `n` with the GSCache paper's Algorithm 1 probability
//! `1 - q_n` (the same rule, so the two caches are compared at equal termination, as the
//! GSCache paper does) and adds `W_n N(x_n)`; survivors are not re-weighted. A fraction of each
//! frame's paths are training paths (the NRC paper's rendering path plus a training suffix): the
//! image takes from them what a path that stopped would give, while they are traced on to
//! their end and every vertex they pass yields a record `(x_n, R_n)` (the renderer's side is in
//! cached-pt's `nrc` module).
//! Self-training (feeding the cache's own prediction back into the targets) is off, as in the
//! GSCache paper's comparison, so every target is an unbiased sample.

pub mod cache;
pub mod config;
pub mod dense;
pub mod encoding;
pub mod mlp;
pub mod random;

pub use cache::{NeuralCache, Query, TrainReport, TrainingRecord, spherical_harmonics_2};
pub use config::{ConfigError, NrcConfig};
pub use encoding::HashGrid;
pub use mlp::Mlp;
