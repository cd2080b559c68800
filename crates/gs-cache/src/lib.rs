//! gs-cache: the GSCache radiance cache (Bauer et al., 2025) for volume path tracers: one cloud of
//! 3D Gaussians per path length, drawn from the frame's camera into per-level cache images, read by
//! paths that stop early or end with nothing, and trained online from the paths' own noisy samples.
//! It knows nothing of volumes: a renderer gives it points with albedos to start from, a camera per
//! frame, and per pixel the samples its paths produce.
//!
//! - [`config`]: levels, sizes, termination, learning rates, lookup.
//! - [`init`]: initial levels from a point cloud (Eq. 2 scales from three nearest neighbours).
//! - [`cache`]: the levels, the per-frame lookup images, training (Eq. 4 loss, AdamW, Eq. 5).
//! - [`path`]: one path's bookkeeping: what to add, when to stop, what to train on.
//! - [`termination`]: Algorithm 1's continuation probability.
//! - [`control`]: the unbiased estimator's continuation probabilities, from measured error and
//!   cost.
//! - [`targets`]: per-level training targets with masks, gathered straight into cache pixels.
//! - [`resolution`]: levels drawn and trained at a fraction of the frame's resolution.
//! - [`schedule`]: Eq. 5's learning-rate schedule.
//! - [`density`]: adaptive density: Gaussians split where a level's fit misses its targets.
//! - [`fallback`]: plain path tracing where a level's last residual says it is stale.
//! - [`support`]: plain path tracing where too few paths reach a level's vertex for its fit
//!   to be more than the Gaussians' blur, or where the fit measurably misses its targets
//!   (error-aware termination).
//! - [`warm_start`]: a fresh level's colours fitted to its first frames' samples.
//! - [`persist`]: levels saved and loaded as 3DGS PLY files.
//! - [`capi`]: the C ABI (header `include/gs_cache.h`; a C program using it in `c/`).
//!
//! # The estimator
//!
//! Pixel `p`'s path has real scattering vertices `x_1, x_2, ...` with single-scattering albedos
//! `s_k` (RGB). The renderer's throughput after vertex `n` is `W_n = prod_{k<=n} s_k / b_{n-1}`,
//! where `b_{n-1}` is the product of the Russian-roulette survival probabilities before vertex `n`
//! (the GSCache paper's Eq. 3 attenuation). Let `D_n` be the radiance the renderer credits to path
//! length `n` per unit of `W_n` (next-event estimation at `x_n`, and emission reached by the
//! phase-sampled ray from `x_n`, MIS-weighted). The pixel estimate without the cache is `I = E_0 +
//! sum_{n>=1} W_n D_n` (`E_0`: emission seen by the camera ray).
//!
//! **What level `n` holds.** The radiance a path gathers from `x_n` on, per unit of `W_n`:
//! `R_n = sum_{j>=n} (W_j / W_n) D_j`. The cache's level `n` image is trained towards
//! `Lambda_n(p) = E[R_n | the path of p reached x_n]`: each frame, every path gives a sample
//! `R_n` to every level `n <= K` whose vertex it reached and went on from, and the HDR loss of
//! Eq. 4 (prediction detached in the denominator, so its minimiser over noisy samples is their
//! mean) is taken only over pixels with a sample (the masks). Dividing out `W_n` (the
//! "demodulation") is what lets one pixel-space value serve paths whose throughputs differ:
//! the path's own albedo product multiplies the cached value back, as in Eq. 3.
//!
//! **Early termination** (Algorithm 1). At vertex `n <= K`, before its next-event estimation,
//! `q_n = clamp(C luminance(prod_{k<=n} s_k), 0, 1)`, and 1 when `q_n >= 0.9`. With probability
//! `1 - q_n` the path stops and adds `W_n Lambda_n(p)`; otherwise it goes on with its throughput
//! unchanged. This is a *selection*, not a roulette: the expected value at the vertex is
//! `W_n [(1 - q_n) Lambda_n(p) + q_n E[R_n | x_n, history]]`, exact when the cache is. The
//! paper instead also divides survivors by `q_n` (Algorithm 1's `Tr_out / Tr`) and folds `q_n`
//! into `b`; then the expectation is `W_n [(1 - q_n) Lambda_n + E[R_n]]`, too bright by the
//! cache term even for a perfect cache, so we do not re-weight survivors. Our `b` holds only
//! true roulette probabilities.
//!
//! **Natural termination.** A path that leaves the volume after `x_n` (`n <= K`) having gathered
//! no radiance at all adds `W_n Lambda_n(p)` to the image (its training samples stay the true
//! zeros).
//!
//! **The bias we accept**, with `Z_n` the event "left the volume after `x_n` with nothing" and
//! `S_n` "stopped early at `x_n`":
//!
//! `E[I_cache] - E[I] = sum_{n<=K} Lambda_n(p) E[W_n 1(Z_n)]`
//! `                  + sum_{n<=K} E[1(S_n) W_n (Lambda_n(p) - E[R_n | x_n, history])]`.
//!
//! The first term is natural termination's: always >= 0, the cache's value times the weight of
//! the paths that found nothing, which a test measures. The second vanishes when the cache equals
//! the conditional expectation; a pixel-space cache can only hold its average over the vertices
//! seen through `p`, so what remains is training error plus the spread of `E[R_n | x_n]` across
//! those vertices (small at `n = 1`, where `x_1` lies on the camera ray; larger for deeper
//! levels, which is why deeper levels are given fewer Gaussians). `C` trades it: `C` large stops
//! no path (no early-termination bias); `C = 0` stops every path at `x_1`.
//!
//! **How large the second term gets, measured.** Stopping is not independent of the vertex: `q_n`
//! grows with the albedo product, so the paths that stop are the ones through darker albedo, and
//! they are given `Lambda_n(p)`, an average over all the vertices seen through `p`. Where the
//! albedo and the radiance from a vertex on are correlated across a pixel's footprint, the image
//! moves by their covariance. How the cache is fitted decides how much of it shows. The committed
//! experiment `docs/results/hydrogen_bias` isolates it with Adam alone (the GSCache paper's
//! training): with the defaults then (`C = 0.5`) hydrogen rendered 6.0% dark at 1 and 16 spp
//! (0.07% standard error); with early termination off -0.18% (+-0.13%), while turning off
//! natural termination or drawing at full resolution left it at -5.5 to -6.0%. (Its row
//! "re-weighting survivors" did not re-weight: at one path per pixel the weights cancelled when
//! each pixel's mean entered the targets with weight 1. Fixed since, the weights kept through
//! the binning, they change hydrogen's relMSE at 16 spp by 0.2%.) With the warm start's
//! least-squares colours ([`warm_start`], the default) it measures +0.1% at 1 spp and -0.6% at
//! 16 spp, and -1.4% at 64 spp without the handoff as Adam takes over after the warm start's 32
//! frames (BENCHMARKS.md): Adam's bounded steps settle away from the mean of the skewed samples
//! early termination leaves, and a least-squares fit is their mean. A user who
//! needs the image's brightness to better than that sets `early = false` (the cache then reads
//! only where paths end naturally, and its error gain falls: 1.0x on hydrogen) or a larger `C`.
//!
//! The second term has an exact correction, and the default applies it. A stop adds `W_n`
//! times the level's value *channel by channel*, so the image is unbiased where, in each colour
//! channel `c`, the level holds `Lambda_n^c = E[(1 - q) W_n^c R_n^c] / E[(1 - q) W_n^c]` over
//! the paths that reach the vertex: the stoppers' radiance weighted by their throughput in
//! that channel. The level's samples come from the paths that went on, drawn with probability
//! `q`, so each carries the weight `(1 - q) W_n^c / q` in channel `c` (`stopper_weights` with
//! `channel_weights`, derived at [`CachedPath::samples`]). Three things each undid part of it:
//!
//! - Weighting by `lum(W_n)` alone (the first form of `stopper_weights`) corrects the
//!   selection but not the covariance, across a pixel's footprint, of a vertex's albedo and
//!   the radiance from it on in one channel: a red shell round a blue core sends more red
//!   throughput *and* more red light (its paths scatter on in red), so the unweighted mean of
//!   the red samples is too small for the stoppers, whose red throughput is the shell's. On
//!   the blob scene (`data/scenes/blobs.toml`) the red channel rendered 2.7% dark (14% in the
//!   dense blobs) and on hydrogen the blue channel 5.4% (its blue halo round a warm core).
//! - Weights cancel within a target that holds one sample: a cache pixel's target is its
//!   samples' weighted mean, so at one sample (full resolution, a deep level) it is the sample
//!   whatever its weight, and one share of the loss per cache pixel and frame then fits the
//!   mean of the frames' targets. With `weighted_loss` each pixel's share of the loss, per
//!   channel, is its summed weight over the level's running mean, which fits the pooled
//!   weighted mean over frames, and where the Gaussians' blur must trade one pixel for
//!   another it favours where paths stop.
//! - Without the weights at all, the survivors are the paths through bright albedo (in
//!   hydrogen's core the shadowed ones), and the level learns their mean: -1.1% at the first
//!   level in the core.
//!
//! Measured (tools/cache_error.py, 64 still frames of 1 spp against 4096 spp;
//! docs/results/cache_error.md) the three together take the image's brightness error from
//! -0.93% to -0.27% on hydrogen (blue -5.4% to -0.4%), -0.47% to -0.18% on default (red -2.4%
//! to -0.1%), -0.48% to -0.16% on the blob scene (red -2.75% to -0.30%), and lower the raw
//! relMSE at equal time or leave it equal on all 18 stills of the six volumes (by up to 1.5x)
//! and in motion, so they are the default. What they cannot remove is the spread term: a
//! pixel-space value is an average over the vertices seen through the pixel, exact only in
//! expectation over them. The deeper levels' bias compounds (each trains on paths that stopped
//! into the next), so their stops can be made rarer on their own: `c_deep` is Algorithm 1's
//! `C` from path length 2 on.
//!
//! # The unbiased estimator (`unbiased = true`)
//!
//! The estimator above is biased wherever the cache is wrong, and a cache drawn at a quarter of
//! the resolution is wrong across every pixel's footprint. With `unbiased` the cache becomes a
//! control variate, and the image converges to plain path tracing's whatever the cache holds.
//!
//! **What a level holds.** The read comes *after* the vertex's next-event estimation, so level
//! `n` stands for what the path gathers from the direction it samples at `x_n` on:
//! `R'_n = R_n - D^NEE_n` per unit of `W_n` (the emission its phase-sampled ray meets, with its
//! MIS weight, belongs to `R'_n`). Direct lighting, the term with the most structure across a
//! pixel's footprint (shadows, the transfer function's edges), is never cached; measured, the
//! squared error of a tail against the cache fell 3x on hydrogen when the read moved past the
//! next-event estimation. A level trains on `R'_n` of the paths that went on past its
//! decision.
//!
//! **The decision.** At vertex `n <= K`, where the level is trusted, the path reads `C`, the
//! level's value at its pixel, and adds `W_n C`. With probability `q` it goes on, adding
//! `-W_n C / q` and dividing its throughput by `q`; otherwise it ends. The uniform number is a
//! hash of the path's key (seed, pixel, sample) and `n`, not a draw from its stream: a path that
//! goes on draws exactly the numbers the plain path would, so the two stay paired. Conditional
//! on everything before the decision, which fixes `W_n`, `C` and `q`, the added expectation is
//!
//! `W_n C + q (W_n E[R'_n | history] - W_n C) / q = W_n E[R'_n | history]`,
//!
//! the plain path's. By induction over the levels (each deeper decision is unbiased given its
//! own history) the image's expectation is plain path tracing's. What this needs:
//! - `C` must not depend on the path's own future: the levels are drawn before the frame's
//!   paths, from a cache trained on earlier frames; the ray-traced lookup's stochastic value
//!   is drawn once per frame, before the paths, and is as good a `C` as the rasterised one.
//!   Training on the frame's own paths only changes later frames: each frame is unbiased given
//!   the past, so their mean is too.
//! - `q` must be fixed before the uniform number is drawn: it comes from the path's throughput
//!   and a factor `kappa` measured on earlier frames ([`control`]).
//! - The fallback, natural termination, Algorithm 1's selection and the handoff are not needed:
//!   a distrusted level is plain path tracing there (unbiased too), and the others are off.
//!
//! `q = 1` is plain path tracing, bit for bit (the path adds nothing and draws nothing). A
//! path's estimate can be negative (`C - C / q < 0`); the film keeps negative samples, as
//! dropping them would bias the mean, and the denoiser is given them clamped at 0. Dropping the
//! `1 / q` leaves `C` for a stopped path and the plain path's `R'_n` for one that went on:
//! Algorithm 1's biased selection, which the unbiasedness test (`tests/unbiased.rs`) must see.
//! The C ABI offers the same decision (`gs_cache_control_variate`) and statistics
//! (`gs_cache_add_path_statistics`).
//!
//! **Its variance, and the choice of `q`.** With `w` the luminance of `W_n` and
//! `e = lum(W_n (R'_n - C))^2`, the tail adds `E[e / q]` to the variance and costs `E[q t]`
//! (`t`: its work). `q = kappa w` (clamped to `[min_continuation, 1]`) gives `A / kappa` and
//! `kappa B` with `A = E[e / w]`, `B = E[w t]`: dividing by `w` spends continuations where the
//! throughput is large, as the variance does. Minimising the image's relative variance per path
//! times its work per path over every cache pixel's `kappa_b` (a Lagrange multiplier shared by
//! the image) gives `kappa_b = sqrt(A_b / B_b * T / V)`, `A_b` relative to the pixel's squared
//! mean and `T`, `V` the image's work and relative variance per path. The statistics are
//! estimated from the paths that went on, weighted `1 / q`, over the last ~10 frames; `V` comes
//! from each frame pixel's own paths on a still view (a cache pixel's paths spread over frame
//! pixels whose differences are not noise); work is counted in random numbers drawn (one per
//! tracking step), so the choice, and the image, are the same on any machine. Training a level
//! unweighted on the paths that went on makes `C` their mean, which, since they go on with
//! probability in proportion to `w`, is the `w`-weighted mean that minimises `E[e / q]`.
//!
//! **What it can gain.** Going on always costs the plain path's variance `V = V_0 + V_1` and
//! work `T = T_0 + T_1` (`_1`: the tail past the decision, its variance measured against the
//! cache). The best any `q` can do is the two-level multilevel Monte Carlo optimum,
//! `(sqrt(V_0 T_0) + sqrt(V_1 T_1))^2`, a gain over `V T` of at most
//! `1 / (sqrt((1 - v)(1 - t)) + sqrt(v t))^2` with `v = V_1 / V` and `t = T_1 / T`: nothing
//! when the tail holds the same share of the variance as of the work. A pixel-space cache
//! predicts the tail's mean over the pixel, not the tail itself: the phase-sampled direction
//! and everything after it stay in `R'_n - C`. Measured on the six volumes (BENCHMARKS.md), `v`
//! and `t` are within a few percent of each other (hydrogen: level 1 holds 28% of the
//! variance and 51% of the work), and the bound is 1.00-1.06x; a dense white cloud measured
//! 1.04x. Where the bound is under 1.05x the rule lets every path go on, so on these volumes
//! the unbiased cache is plain path tracing plus the cache's own cost, and it stays off by
//! default. `render --cache-unbiased true` prints the bound per level.
//!
//! **Where the GSCache paper leaves things open.** (1) Which levels a path trains: every level it
//! reached and went on from, not only the one where it ended, so a path of length 3 trains levels
//! 1-3 (a path that stops into level `n` trains the shorter levels with the cached value included:
//! self-training). (2) A pixel whose path never reached level `n` gives that level no target
//! (masked out), rather than a zero target. Trained with zeros there (`masked_targets = false`),
//! level `n` learns `P(reach x_n) Lambda_n`, which renders too dark by that probability: this is
//! the darkening the GSCache paper's Fig. 4 attributes to a missing `beta`, and the masks are our
//! correction for it. (3) Units. Adam's steps are absolute (about one learning rate per step,
//! whatever the gradient's size), so the GSCache paper's colour rate moves a cache by a fixed
//! amount of radiance per frame: a scene whose level values are 10 adapts 10x slower than one whose
//! values are 1, and its albedo start (values near 1) is far off. We draw each level as `s_n *
//! cloud` with `s_n` the mean luminance of the level's first frame of samples, so the rates act
//! relative to the scene's radiance and the albedo start is scaled to it (`normalized_radiance`, on
//! by default; saved files hold absolute radiance). The estimator is unchanged: `s_n` is a constant
//! of the parametrisation. (4) Resolution. The levels are drawn and trained at a fraction of the
//! frame's resolution (`resolution_divisor`, 4 by default) and read back bilinearly: a cache
//! pixel then holds the average of `Lambda_n` over a footprint of about `d x d` frame pixels,
//! which widens the spread term of the bias above by the variation of `Lambda_n` across that
//! footprint, and in exchange gathers `d^2` times as many samples per cache pixel (lower variance,
//! faster convergence) at a fraction of the cost. On the committed volumes at 320x180 the trade
//! lowered both the error and the bias (docs/results/cost_default, cost_headsq). (5) The cache
//! for length 0 is never needed: camera rays that leave the
//! volume see the lights and the environment exactly. (6) The start. A level's image is linear
//! in its colours, so during its first frames (and after a scene change) the colours are fitted
//! to the samples by a least-squares step instead of Adam's bounded ones ([`warm_start`]); the
//! estimator is unchanged, the cache only gets closer to `Lambda_n` sooner. (7) Staleness. Where
//! a level's last residual is large beyond its noise, and everywhere in the frame after a scene
//! change, paths do not stop into it ([`fallback`]): those pixels are plain path tracing, so
//! their bias terms above vanish, at the variance plain path tracing has. (8) Support. The
//! second bias term is largest where a cache pixel's fit rests on few paths: where most of the
//! paths through it never reach the level's vertex (a thin halo, a silhouette its footprint
//! straddles), the level there is the Gaussians' blur of denser neighbours, and the bilinear
//! read mixes in pixels with no target at all. With `min_coverage`, paths stop into a level
//! only where, around their cache pixel, at least that fraction of the paths reached its vertex
//! ([`support`]); elsewhere they are plain path tracing, as under the fallback. (9) Measured
//! bias. Where paths do reach the vertex the fit may still miss `Lambda_n` (the Gaussians blur a
//! core's structure; in motion the fit lags the view, since a level drawn from a new camera
//! composites its Gaussians with other weights than the new rays' vertices have). With
//! `max_bias`, paths stop into a level only where the level's residual against its own targets,
//! pooled over the last frames and a 5x5 block of cache pixels (about the denoiser's
//! footprint), is within that fraction of the targets or within the noise ([`support`]). It
//! sees what the targets see: a bias the targets share (the deeper levels' values carried into
//! a shallower level's samples) passes it. (10) Density. The GSCache paper keeps the Gaussians
//! it starts from; 3DGS grows a cloud where it misses. With `densify_every` a level splits the
//! Gaussians whose fit misses its targets by more than the targets' own noise ([`density`]).
//! Measured, it finds little to split (hydrogen's first level grew by a seventh, the others'
//! hardly) and ties the fixed levels at equal time: beyond the noise, what a level misses is
//! set by its pixels' footprint, not by where its Gaussians sit (docs/results/cache_error.md),
//! so it is off by default.
//!
//! # How many passes of an image should read the cache
//!
//! An image of one view averages `k` passes (a still's frames, or a fly-through frame's 1-spp
//! passes), of which the first `m` read the cache (the handoff, `handoff_frames`). At a pixel,
//! a pass that reads it has mean `mu + b` (`b`: the cache's bias there) and variance `s_c^2`;
//! one that does not, mean `mu` and variance `s_n^2 > s_c^2`. A denoiser keeps a bias and
//! removes most of the noise (the breakdown in docs/results/cache_error.md: bias² is 75-89% of
//! the cache's error after Open Image Denoise); model it as leaving a fraction `phi` of the
//! variance. The image's squared error is then
//!
//! `E_k(m) = (m b / k)^2 + phi (m s_c^2 + (k - m) s_n^2) / k^2`,
//!
//! least at `m* = phi (s_n^2 - s_c^2) / (2 b^2)`, **whatever `k`**: the cache is worth a fixed
//! number of passes however long the image, and `phi` scales that number. Raw (`phi = 1`) the
//! measured best handoff was 16 passes (BENCHMARKS.md); Open Image Denoise's `phi`, its relMSE
//! over plain NEE's at 1 spp, is 0.10 on hydrogen, 0.021 on default and 0.018 on embryo, so
//! with the denoiser the same caches are worth 0.3-1.6 passes: `for_denoiser` hands off after 2
//! (1, 2 and 4 measured; docs/results/cache_error.md). At the optimum,
//!
//! `E_k(m*) / E_k(0) = 1 - (m* / 2k) (1 - s_c^2 / s_n^2)`:
//!
//! after a denoiser a biased cache can take at most the fraction `m* / 2k` off plain path
//! tracing's error, a few percent at 200 ms (`k` about 9 at 320x180), which is the ties the
//! equal-time tables show. Where it can win is where an image is one or two passes, and only
//! by how far its bias is below the denoised plain image's error (`b^2 < phi (s_n^2 - s_c^2)`
//! for `m* > 1/2`): the lever is the cache's bias, not how often it is read. The model takes
//! the `k - m` plain passes at plain path tracing's cost; a renderer must not charge them the
//! cache's bookkeeping (cached-pt traces a handed-off frame with the plain tracer: until it did,
//! those passes cost 12-14% more, which was most of what the denoised cache lost at 1 s).

pub mod cache;
pub mod capi;
pub mod config;
pub mod control;
pub mod density;
pub mod error;
pub mod fallback;
pub mod init;
pub mod path;
pub mod persist;
pub mod resolution;
pub mod schedule;
pub mod support;
pub mod targets;
pub mod termination;
#[cfg(test)]
mod test_support;
pub mod warm_start;

pub use cache::{CacheFrame, GsCache, GsCacheReport, Level};
pub use config::{
    CacheConfig, Decay, LearningRates, Lookup, MAX_LEVELS, Optimizer, TerminationConfig,
};
pub use error::{CacheError, Result};
pub use path::{CachedPath, ControlVariate};
pub use targets::{TileTargets, TrainingTargets};
