//! Which SIMD lanes run the crate's lane code: AVX2 with FMA where the processor has them,
//! else the target's baseline. Results differ between the two in the last bits (the fused
//! multiply-adds); on one machine they are the same on any number of threads.

#[cfg(target_arch = "x86_64")]
use splat_raster::lanes::Avx2Token;

/// The lanes every processor of the target runs: SSE2 on x86-64, plain arrays elsewhere.
#[cfg(target_arch = "x86_64")]
pub(crate) type Baseline = splat_raster::lanes::Sse2;
#[cfg(not(target_arch = "x86_64"))]
pub(crate) type Baseline = splat_raster::lanes::Portable;

/// The lanes this processor runs best.
#[derive(Clone, Copy)]
pub(crate) enum Isa {
    #[cfg(target_arch = "x86_64")]
    Avx2(Avx2Token),
    Baseline,
}

impl Isa {
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if let Some(token) = Avx2Token::detect() {
            return Isa::Avx2(token);
        }
        Isa::Baseline
    }
}
