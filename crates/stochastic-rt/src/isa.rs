//! Which SIMD lanes run the crate's lane code: splat-raster's one [`Isa`], AVX2 with FMA
//! where the processor has them, else the target's baseline. Results differ between the two in
//! the last bits (the fused multiply-adds); on one machine they are the same on any number of
//! threads.

pub(crate) use splat_raster::lanes::BaselineLanes as Baseline;
pub(crate) use splat_raster::lanes::Isa;
