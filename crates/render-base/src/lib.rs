//! render-base: what every crate of the renderer shares.
//!
//! - [`atomic_file`]: the one way the project writes a file for a user. The file appears whole
//!   or not at all, and no one who can write to the output folder can redirect the write.
//! - [`control`]: cancellation and progress for long work, in one value ([`Control::none()`]
//!   for neither).
//! - [`camera`]: the pinhole camera and the pixel convention every renderer shares (the
//!   rasteriser, the ray tracers and the path tracer draw the same pixel for the same ray).
//! - [`hash`]: the stateless hashes every random decision is built on (the splitmix64
//!   finaliser, a 32-bit word hash).
//! - [`SH_C0`]: the degree-0 spherical-harmonic constant that maps colours to 3DGS coefficients.

#![forbid(unsafe_code)]

/// The most worker threads any entry point (the program's `--threads`, Python's `threads=`)
/// accepts: one limit, so the two cannot drift apart. More than this is a typo, and a pool of
/// 100,000 threads hangs the machine rather than failing.
pub const MAX_THREADS: usize = 1024;

/// The largest radiance one sample may carry per channel: 2^39 (5.5e11). The film refuses a
/// brighter sample like a NaN one (its exact sums stay within an i128), and the caches refuse it
/// as a training target (a level trained on 3e38 drew infinite pixels): one bound for both.
pub const MAX_SAMPLE_RADIANCE: f32 = (1u64 << 39) as f32;

/// The largest coordinate, size or distance a volume scene may state (scene units), and the
/// inverse of the smallest voxel spacing. Positions are f32: at 1e6 a unit is still resolved to
/// 0.06, and a larger value is a unit mistake (metres read as micrometres, a NIfTI `pixdim` of
/// 1e30) that would render nonsense or march forever rather than fail.
pub const MAX_COORDINATE: f32 = 1e6;

pub mod atomic_file;
pub mod camera;
pub mod control;
pub mod hash;

/// The degree-0 real spherical harmonic, 1 / (2 sqrt(pi)): a 3DGS colour coefficient `dc` is
/// the colour `0.5 + SH_C0 * dc`.
pub const SH_C0: f32 = 0.282_094_8;

pub use atomic_file::{AtomicWriter, WriteError, check_output, check_writable, write_atomically};
pub use camera::{Camera, CameraError, MAX_IMAGE_SIDE};
pub use control::Control;
