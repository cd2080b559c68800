//! f32 SIMD lanes for the per-pixel kernels, and a vector `exp` with a stated error bound.
//!
//! [`Lanes`] is the small set of operations the kernels need. It has three implementations:
//! - [`Avx2`]: 8 lanes with AVX2 and FMA (x86-64);
//! - [`Sse2`]: 4 lanes with SSE2, which every x86-64 CPU has;
//! - [`Portable`]: 4 lanes as a plain array, for every other target (LLVM vectorises it to NEON
//!   on aarch64), and a third witness in the tests.
//!
//! Soundness of the intrinsics: an [`Avx2`] value can only be made from an [`Avx2Token`], and a
//! token only by [`Avx2Token::detect`] after `is_x86_feature_detected!` found AVX2 and FMA. Every
//! operation takes existing values, so whenever one runs, a token was made before it on this
//! CPU. SSE2 is part of the x86-64 baseline, so its intrinsics are always available there.
//!
//! Lanes that a kernel masks out may hold any value (NaN included); every operation here is
//! defined for every input, so they cannot fault, and masks keep them out of the results.
//!
//! Why `std::arch` and not a crate: `wide` picks its instructions when the crate is compiled, so
//! one portable binary would not use AVX2; `pulp` (already built for burn's matrix kernels)
//! dispatches at run time, but its 4-lane x86 level computes `mul_add` in software, lane by
//! lane. Plain arrays left to the auto-vectoriser were tried first: LLVM split the 8-lane
//! operations into 128-bit halves with spills, and the backward pass ran slower than the scalar
//! kernel. So each operation here is one intrinsic, and the proof of soundness is the token.

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Sub};

/// The operations of one SIMD width. Masks are lanes whose bits are all ones (true) or all zeros.
pub trait Lanes:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self>
{
    /// A lane condition.
    type Mask: Copy + BitAnd<Output = Self::Mask> + BitOr<Output = Self::Mask>;
    /// What proves the CPU runs these lanes.
    type Token: Copy;
    /// Lanes per vector.
    const N: usize;
    /// Whether `mul_add` rounds once (an FMA instruction).
    const FUSED: bool;

    fn splat(token: Self::Token, x: f32) -> Self;
    /// The first `N` values of `x`.
    fn load(token: Self::Token, x: &[f32]) -> Self;
    /// Writes the lanes to the first `N` values of `out`.
    fn store(self, out: &mut [f32]);
    /// Lanes holding the bits of the first `N` integers of `x`.
    fn load_bits(token: Self::Token, x: &[u32]) -> Self;
    /// Writes the lanes' bits to the first `N` values of `out`.
    fn store_bits(self, out: &mut [u32]);
    /// `self * b + c` (one rounding when `FUSED`).
    fn mul_add(self, b: Self, c: Self) -> Self;
    /// The smaller of each pair; `b` when either is NaN.
    fn min(self, b: Self) -> Self;
    /// The larger of each pair; `b` when either is NaN.
    fn max(self, b: Self) -> Self;
    fn lt(self, b: Self) -> Self::Mask;
    fn le(self, b: Self) -> Self::Mask;
    fn gt(self, b: Self) -> Self::Mask;
    fn ge(self, b: Self) -> Self::Mask;
    /// Lanes where the bits of `self` are below those of `b`, both read as i32.
    fn bits_lt(self, b: Self) -> Self::Mask;
    /// `a` where `m` holds, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// `a` where `m` holds, else 0.
    fn keep(m: Self::Mask, a: Self) -> Self;
    /// `m` and not `n`.
    fn and_not(m: Self::Mask, n: Self::Mask) -> Self::Mask;
    fn any(m: Self::Mask) -> bool;
    fn count(m: Self::Mask) -> u32;
    /// Bit `i` set where lane `i` holds.
    fn bits(m: Self::Mask) -> u32;
    /// All lanes false.
    fn no_lanes(token: Self::Token) -> Self::Mask;
    /// Lane `i` is `f(i)`.
    fn mask_from_fn(token: Self::Token, f: impl Fn(usize) -> bool) -> Self::Mask;
    /// The float whose bits are `(bits(self) - k) << 23`, lane by lane (integer wrap-around).
    fn exponent_bits(self, k: u32) -> Self;
    /// The square root, correctly rounded (IEEE 754; NaN for negative lanes).
    fn sqrt(self) -> Self;
    /// `(m, e)` with `self = m 2^e` and `m` in `[1, 2)`, for a positive normal float: the
    /// mantissa bits under the exponent of 1, and the unbiased exponent as a float. Other lanes
    /// give some finite `m` and `e` (callers mask them out).
    fn split_exponent(self) -> (Self, Self);

    /// Each vector's lane sum, in a fixed order (so the same on every run): the per-splat
    /// gradient sums of a tile, eight at a time. The vector widths override it with shuffles
    /// that reduce all eight at once.
    #[inline(always)]
    fn reduce8(v: [Self; 8]) -> [f32; 8] {
        v.map(Self::reduce_sum)
    }

    /// The largest lane (exact: any order gives it). Lanes are not NaN where it is used.
    #[inline(always)]
    fn reduce_max(self) -> f32 {
        let mut v = [0.0f32; 16];
        self.store(&mut v);
        v[1..Self::N]
            .iter()
            .fold(v[0], |largest, &x| if x > largest { x } else { largest })
    }

    /// The lanes' sum, added in a fixed order, so it is the same on every run.
    #[inline(always)]
    fn reduce_sum(self) -> f32 {
        let mut v = [0.0f32; 16];
        self.store(&mut v);
        let mut width = Self::N;
        while width > 1 {
            width /= 2;
            for i in 0..width {
                v[i] += v[i + width];
            }
        }
        v[0]
    }
}

/// Lowest input of [`exp`]: its result is then a normal f32 (no subnormal scale).
pub const EXP_MIN: f32 = -87.0;
/// Highest input of [`exp`]: its result is then finite.
pub const EXP_MAX: f32 = 88.0;
/// Bound on [`exp`]'s relative error against the exact value on `[EXP_MIN, EXP_MAX]`, with and
/// without FMA (2.5 units in the last place of 1.0). The truncation of the degree-7 Taylor series
/// on `|r| <= ln 2 / 2` is below `1.42 r^8 / 8! < 7.3e-9`; the rest is the rounding of the
/// reduction and of Horner's steps. The tests check it against f64 on a dense sweep.
pub const EXP_MAX_REL_ERROR: f32 = 3.0e-7;

/// `e^x` per lane, inputs clamped to `[EXP_MIN, EXP_MAX]` (a NaN lane gives some finite value:
/// callers mask such lanes out).
///
/// Cody-Waite: `x = n ln 2 + r` with `n = round(x / ln 2)` and `|r| <= ln 2 / 2`; `e^r` by its
/// Taylor series to degree 7; `2^n` built in the exponent bits. `n` is rounded by adding
/// `1.5 * 2^23`, which leaves it in the low mantissa bits of the sum.
#[inline(always)]
pub fn exp<L: Lanes>(token: L::Token, x: L) -> L {
    const ROUND: f32 = 12_582_912.0; // 1.5 * 2^23
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    // ln 2 split so that n * LN2_HI is exact for |n| < 2^15.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let s = |v: f32| L::splat(token, v);
    let x = x.max(s(EXP_MIN)).min(s(EXP_MAX));
    let shifted = x.mul_add(s(LOG2_E), s(ROUND));
    let n = shifted - s(ROUND);
    let r = n.mul_add(s(-LN2_HI), x);
    let r = n.mul_add(s(-LN2_LO), r);
    let mut p = s(1.0 / 5040.0);
    for c in [
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p.mul_add(r, s(c));
    }
    // The low bits of `shifted` hold n + 0x400000; 2^n has the biased exponent n + 127.
    p * shifted.exponent_bits(ROUND.to_bits() - 127)
}

/// Bound on [`ln`]'s error on positive normal floats: relative to the exact value, or absolute
/// where that is below 1 (near `x = 1`, where `ln` crosses 0). The series below is truncated
/// after `s^9`; the first term left out is below `2 s^11 / 11 < 1.4e-9` relative to `2 s`
/// (`|s| <= 0.172`); the rest is the rounding of the division, of Horner's steps and of
/// `e ln 2`. The tests check it against f64 on a dense sweep.
pub const LN_MAX_ERROR: f32 = 3.0e-7;

/// The bits of an f32's mantissa, and of 1.0.
const MANTISSA_BITS: u32 = 0x007f_ffff;
const ONE_BITS: u32 = 0x3f80_0000;

/// `ln x` per lane, for positive normal `x` (other lanes give some finite value or NaN: callers
/// mask them out).
///
/// `x = m 2^e` with `m` in `[1, 2)`, moved to `[sqrt(1/2), sqrt(2))` (and `e` up by one) so that
/// `f = m - 1` is small and exact; then `ln m = 2 atanh(s)` with `s = f / (2 + f)`, `|s| <=
/// 0.172`, by its odd series `2 (s + s^3/3 + ... + s^9/9)`; and `ln x = e ln 2 + ln m`.
#[inline(always)]
pub fn ln<L: Lanes>(token: L::Token, x: L) -> L {
    let s = |v: f32| L::splat(token, v);
    let (m, e) = x.split_exponent();
    let high = m.gt(s(std::f32::consts::SQRT_2));
    let m = L::select(high, m * s(0.5), m);
    let e = L::select(high, e + s(1.0), e);
    let f = m - s(1.0);
    let z = f / (s(2.0) + f);
    let z2 = z * z;
    let mut p = s(2.0 / 9.0);
    for c in [2.0 / 7.0, 2.0 / 5.0, 2.0 / 3.0, 2.0] {
        p = p.mul_add(z2, s(c));
    }
    e.mul_add(s(std::f32::consts::LN_2), p * z)
}

/// Stored quaternions `q = (w, x, y, z)`, lane by lane: `|q|`, the unit quaternion `q / |q|`
/// and its rotation matrix `R` (rows). The projection's and the ray tracer's, one formula; a
/// zero `q` gives NaN, which callers refuse by `|q| > 0`.
#[inline(always)]
pub fn rotation<L: Lanes>(token: L::Token, q: [L; 4]) -> (L, [L; 4], [[L; 3]; 3]) {
    let (one, two) = (L::splat(token, 1.0), L::splat(token, 2.0));
    let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let (qw, qx, qy, qz) = (q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn);
    let r = [
        [
            one - two * (qy * qy + qz * qz),
            two * (qx * qy - qw * qz),
            two * (qx * qz + qw * qy),
        ],
        [
            two * (qx * qy + qw * qz),
            one - two * (qx * qx + qz * qz),
            two * (qy * qz - qw * qx),
        ],
        [
            two * (qx * qz - qw * qy),
            two * (qy * qz + qw * qx),
            one - two * (qx * qx + qy * qy),
        ],
    ];
    (qn, [qw, qx, qy, qz], r)
}

// ---------------------------------------------------------------------------------------------
// Portable: a plain array.

/// 4 lanes as a plain array: every target runs it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub struct Portable(pub [f32; 4]);

#[inline(always)]
fn zip4<T: Copy, U: Copy + Default>(a: [T; 4], b: [T; 4], f: impl Fn(T, T) -> U) -> [U; 4] {
    let mut r = [U::default(); 4];
    for i in 0..4 {
        r[i] = f(a[i], b[i]);
    }
    r
}

#[inline(always)]
fn cond(c: bool) -> u32 {
    if c { u32::MAX } else { 0 }
}

macro_rules! portable_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for Portable {
            type Output = Self;
            #[inline(always)]
            fn $f(self, b: Self) -> Self {
                Self(zip4(self.0, b.0, |x, y| x $op y))
            }
        }
    };
}
portable_op!(Add, add, +);
portable_op!(Sub, sub, -);
portable_op!(Mul, mul, *);
portable_op!(Div, div, /);

/// A [`Portable`] lane condition.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PortableMask(pub [u32; 4]);

impl BitAnd for PortableMask {
    type Output = Self;
    #[inline(always)]
    fn bitand(self, b: Self) -> Self {
        Self(zip4(self.0, b.0, |x, y| x & y))
    }
}

impl BitOr for PortableMask {
    type Output = Self;
    #[inline(always)]
    fn bitor(self, b: Self) -> Self {
        Self(zip4(self.0, b.0, |x, y| x | y))
    }
}

impl Lanes for Portable {
    type Mask = PortableMask;
    type Token = ();
    const N: usize = 4;
    const FUSED: bool = cfg!(target_arch = "aarch64");

    #[inline(always)]
    fn splat(_: (), x: f32) -> Self {
        Self([x; 4])
    }
    #[inline(always)]
    fn load(_: (), x: &[f32]) -> Self {
        Self([x[0], x[1], x[2], x[3]])
    }
    #[inline(always)]
    fn store(self, out: &mut [f32]) {
        out[..4].copy_from_slice(&self.0);
    }
    #[inline(always)]
    fn load_bits(_: (), x: &[u32]) -> Self {
        Self([x[0], x[1], x[2], x[3]].map(f32::from_bits))
    }
    #[inline(always)]
    fn store_bits(self, out: &mut [u32]) {
        out[..4].copy_from_slice(&self.0.map(f32::to_bits));
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        let mut r = [0.0; 4];
        for i in 0..4 {
            r[i] = if Self::FUSED {
                self.0[i].mul_add(b.0[i], c.0[i])
            } else {
                self.0[i] * b.0[i] + c.0[i]
            };
        }
        Self(r)
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        Self(zip4(self.0, b.0, |x, y| if x < y { x } else { y }))
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        Self(zip4(self.0, b.0, |x, y| if x > y { x } else { y }))
    }
    #[inline(always)]
    fn lt(self, b: Self) -> PortableMask {
        PortableMask(zip4(self.0, b.0, |x, y| cond(x < y)))
    }
    #[inline(always)]
    fn le(self, b: Self) -> PortableMask {
        PortableMask(zip4(self.0, b.0, |x, y| cond(x <= y)))
    }
    #[inline(always)]
    fn gt(self, b: Self) -> PortableMask {
        PortableMask(zip4(self.0, b.0, |x, y| cond(x > y)))
    }
    #[inline(always)]
    fn ge(self, b: Self) -> PortableMask {
        PortableMask(zip4(self.0, b.0, |x, y| cond(x >= y)))
    }
    #[inline(always)]
    fn bits_lt(self, b: Self) -> PortableMask {
        PortableMask(zip4(self.0, b.0, |x, y| {
            cond((x.to_bits() as i32) < (y.to_bits() as i32))
        }))
    }
    #[inline(always)]
    fn select(m: PortableMask, a: Self, b: Self) -> Self {
        Self(std::array::from_fn(|i| {
            f32::from_bits((a.0[i].to_bits() & m.0[i]) | (b.0[i].to_bits() & !m.0[i]))
        }))
    }
    #[inline(always)]
    fn keep(m: PortableMask, a: Self) -> Self {
        Self(std::array::from_fn(|i| {
            f32::from_bits(a.0[i].to_bits() & m.0[i])
        }))
    }
    #[inline(always)]
    fn and_not(m: PortableMask, n: PortableMask) -> PortableMask {
        PortableMask(zip4(m.0, n.0, |x, y| x & !y))
    }
    #[inline(always)]
    fn any(m: PortableMask) -> bool {
        (m.0[0] | m.0[1] | m.0[2] | m.0[3]) != 0
    }
    #[inline(always)]
    fn count(m: PortableMask) -> u32 {
        m.0.iter().map(|x| x & 1).sum()
    }
    #[inline(always)]
    fn bits(m: PortableMask) -> u32 {
        (0..4).map(|i| (m.0[i] & 1) << i).sum()
    }
    #[inline(always)]
    fn no_lanes(_: ()) -> PortableMask {
        PortableMask([0; 4])
    }
    #[inline(always)]
    fn mask_from_fn(_: (), f: impl Fn(usize) -> bool) -> PortableMask {
        PortableMask(std::array::from_fn(|i| cond(f(i))))
    }
    #[inline(always)]
    fn exponent_bits(self, k: u32) -> Self {
        Self(
            self.0
                .map(|x| f32::from_bits(x.to_bits().wrapping_sub(k) << 23)),
        )
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Self(self.0.map(f32::sqrt))
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        let m = self
            .0
            .map(|x| f32::from_bits(x.to_bits() & MANTISSA_BITS | ONE_BITS));
        let e = self
            .0
            .map(|x| ((x.to_bits() >> 23) & 0xff) as i32 as f32 - 127.0);
        (Self(m), Self(e))
    }
}

// ---------------------------------------------------------------------------------------------
// x86-64: SSE2 (baseline) and AVX2 + FMA.

#[cfg(target_arch = "x86_64")]
pub use x86::{Avx2, Avx2Mask, Avx2Token, Sse2, Sse2Mask};

/// The instruction set lane code runs with, with the proof that this CPU has it: the one
/// choice every crate's lane kernels dispatch on (the rasteriser's, the ray tracer's).
#[derive(Clone, Copy, Debug)]
pub enum Isa {
    /// The target's baseline ([`BaselineLanes`]): SSE2 on x86-64, plain arrays elsewhere
    /// (NEON on aarch64).
    Baseline,
    /// [`Avx2`]: 8 lanes with AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    Avx2Fma(Avx2Token),
}

impl Isa {
    /// AVX2 with FMA, if this CPU has them.
    pub fn avx2_fma() -> Option<Isa> {
        #[cfg(target_arch = "x86_64")]
        if let Some(token) = Avx2Token::detect() {
            return Some(Isa::Avx2Fma(token));
        }
        None
    }

    /// The best this CPU runs: AVX2 with FMA where it has them, else the baseline.
    pub fn detect() -> Isa {
        Isa::avx2_fma().unwrap_or(Isa::Baseline)
    }
}

/// The lanes every processor of the target runs ([`Isa::Baseline`]'s).
#[cfg(target_arch = "x86_64")]
pub type BaselineLanes = Sse2;
/// The lanes every processor of the target runs ([`Isa::Baseline`]'s).
#[cfg(not(target_arch = "x86_64"))]
pub type BaselineLanes = Portable;

/// The x86-64 lanes.
///
/// SAFETY (every `unsafe` block in this module, which is why clippy's
/// `undocumented_unsafe_blocks` is expected here rather than a copy of this proof on each):
/// the SSE2 intrinsics need only SSE2, which the x86-64 baseline guarantees. The AVX/AVX2/FMA intrinsics run only where an `Avx2` or
/// `Avx2Mask` value exists, and those are made only by functions that take an `Avx2Token`
/// (or from other such values), which `Avx2Token::detect` creates only after detecting AVX2
/// and FMA. Loads and stores index slices with bounds checks first (`x[..N]`), so they read
/// and write only inside them; the unaligned forms (`loadu`/`storeu`) need no alignment.
#[cfg(target_arch = "x86_64")]
#[expect(
    clippy::undocumented_unsafe_blocks,
    reason = "one proof, above, covers every intrinsic block of the module"
)]
mod x86 {
    use super::Lanes;
    use super::{MANTISSA_BITS, ONE_BITS};
    use std::arch::x86_64::*;
    use std::ops::{Add, BitAnd, BitOr, Div, Mul, Sub};

    /// 4 lanes with SSE2 (every x86-64 CPU).
    #[derive(Clone, Copy, Debug)]
    pub struct Sse2(__m128);
    /// An [`Sse2`] lane condition.
    #[derive(Clone, Copy, Debug)]
    pub struct Sse2Mask(__m128);

    /// Proof that this CPU has AVX2 and FMA: only [`Avx2Token::detect`] makes one.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx2Token(());

    impl Avx2Token {
        /// A token when this CPU has AVX2 and FMA.
        pub fn detect() -> Option<Self> {
            (is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
                .then_some(Avx2Token(()))
        }
    }

    /// 8 lanes with AVX2 and FMA; only made from an [`Avx2Token`].
    #[derive(Clone, Copy, Debug)]
    pub struct Avx2(__m256);
    /// An [`Avx2`] lane condition.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx2Mask(__m256);

    macro_rules! binop {
        ($ty:ident, $tr:ident, $f:ident, $intr:ident) => {
            impl $tr for $ty {
                type Output = Self;
                #[inline(always)]
                fn $f(self, b: Self) -> Self {
                    Self(unsafe { $intr(self.0, b.0) })
                }
            }
        };
    }
    binop!(Sse2, Add, add, _mm_add_ps);
    binop!(Sse2, Sub, sub, _mm_sub_ps);
    binop!(Sse2, Mul, mul, _mm_mul_ps);
    binop!(Sse2, Div, div, _mm_div_ps);
    binop!(Sse2Mask, BitAnd, bitand, _mm_and_ps);
    binop!(Sse2Mask, BitOr, bitor, _mm_or_ps);
    binop!(Avx2, Add, add, _mm256_add_ps);
    binop!(Avx2, Sub, sub, _mm256_sub_ps);
    binop!(Avx2, Mul, mul, _mm256_mul_ps);
    binop!(Avx2, Div, div, _mm256_div_ps);
    binop!(Avx2Mask, BitAnd, bitand, _mm256_and_ps);
    binop!(Avx2Mask, BitOr, bitor, _mm256_or_ps);

    impl Lanes for Sse2 {
        type Mask = Sse2Mask;
        type Token = ();
        const N: usize = 4;
        const FUSED: bool = false;

        #[inline(always)]
        fn splat(_: (), x: f32) -> Self {
            Self(unsafe { _mm_set1_ps(x) })
        }
        #[inline(always)]
        fn load(_: (), x: &[f32]) -> Self {
            let x = &x[..4];
            Self(unsafe { _mm_loadu_ps(x.as_ptr()) })
        }
        #[inline(always)]
        fn store(self, out: &mut [f32]) {
            let out = &mut out[..4];
            unsafe { _mm_storeu_ps(out.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn load_bits(_: (), x: &[u32]) -> Self {
            let x = &x[..4];
            Self(unsafe { _mm_castsi128_ps(_mm_loadu_si128(x.as_ptr().cast())) })
        }
        #[inline(always)]
        fn store_bits(self, out: &mut [u32]) {
            let out = &mut out[..4];
            unsafe { _mm_storeu_si128(out.as_mut_ptr().cast(), _mm_castps_si128(self.0)) }
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            self * b + c
        }
        #[inline(always)]
        fn min(self, b: Self) -> Self {
            Self(unsafe { _mm_min_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn max(self, b: Self) -> Self {
            Self(unsafe { _mm_max_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn lt(self, b: Self) -> Sse2Mask {
            Sse2Mask(unsafe { _mm_cmplt_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn le(self, b: Self) -> Sse2Mask {
            Sse2Mask(unsafe { _mm_cmple_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn gt(self, b: Self) -> Sse2Mask {
            Sse2Mask(unsafe { _mm_cmpgt_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn ge(self, b: Self) -> Sse2Mask {
            Sse2Mask(unsafe { _mm_cmpge_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn bits_lt(self, b: Self) -> Sse2Mask {
            Sse2Mask(unsafe {
                _mm_castsi128_ps(_mm_cmplt_epi32(
                    _mm_castps_si128(self.0),
                    _mm_castps_si128(b.0),
                ))
            })
        }
        #[inline(always)]
        fn select(m: Sse2Mask, a: Self, b: Self) -> Self {
            Self(unsafe { _mm_or_ps(_mm_and_ps(m.0, a.0), _mm_andnot_ps(m.0, b.0)) })
        }
        #[inline(always)]
        fn keep(m: Sse2Mask, a: Self) -> Self {
            Self(unsafe { _mm_and_ps(m.0, a.0) })
        }
        #[inline(always)]
        fn and_not(m: Sse2Mask, n: Sse2Mask) -> Sse2Mask {
            Sse2Mask(unsafe { _mm_andnot_ps(n.0, m.0) })
        }
        #[inline(always)]
        fn any(m: Sse2Mask) -> bool {
            unsafe { _mm_movemask_ps(m.0) != 0 }
        }
        #[inline(always)]
        fn count(m: Sse2Mask) -> u32 {
            unsafe { _mm_movemask_ps(m.0) }.count_ones()
        }
        #[inline(always)]
        fn bits(m: Sse2Mask) -> u32 {
            unsafe { _mm_movemask_ps(m.0) as u32 }
        }
        #[inline(always)]
        fn no_lanes(_: ()) -> Sse2Mask {
            Sse2Mask(unsafe { _mm_setzero_ps() })
        }
        #[inline(always)]
        fn mask_from_fn(_: (), f: impl Fn(usize) -> bool) -> Sse2Mask {
            let bits: [u32; 4] = std::array::from_fn(|i| if f(i) { u32::MAX } else { 0 });
            Sse2Mask(Self::load_bits((), &bits).0)
        }
        #[inline(always)]
        fn reduce_max(self) -> f32 {
            unsafe {
                let pairs = _mm_max_ps(self.0, _mm_movehl_ps(self.0, self.0));
                _mm_cvtss_f32(_mm_max_ss(pairs, _mm_shuffle_ps::<1>(pairs, pairs)))
            }
        }
        #[inline(always)]
        fn reduce8(v: [Self; 8]) -> [f32; 8] {
            // Two 4x4 transposes (columns become vectors), then three adds each.
            let quad = |a: __m128, b: __m128, c: __m128, d: __m128| unsafe {
                let ab_lo = _mm_unpacklo_ps(a, b); // a0 b0 a1 b1
                let ab_hi = _mm_unpackhi_ps(a, b); // a2 b2 a3 b3
                let cd_lo = _mm_unpacklo_ps(c, d);
                let cd_hi = _mm_unpackhi_ps(c, d);
                let col0 = _mm_movelh_ps(ab_lo, cd_lo); // a0 b0 c0 d0
                let col1 = _mm_movehl_ps(cd_lo, ab_lo); // a1 b1 c1 d1
                let col2 = _mm_movelh_ps(ab_hi, cd_hi);
                let col3 = _mm_movehl_ps(cd_hi, ab_hi);
                _mm_add_ps(_mm_add_ps(col0, col1), _mm_add_ps(col2, col3))
            };
            let mut out = [0.0f32; 8];
            Self(quad(v[0].0, v[1].0, v[2].0, v[3].0)).store(&mut out[..4]);
            Self(quad(v[4].0, v[5].0, v[6].0, v[7].0)).store(&mut out[4..]);
            out
        }
        #[inline(always)]
        fn exponent_bits(self, k: u32) -> Self {
            Self(unsafe {
                let i = _mm_sub_epi32(_mm_castps_si128(self.0), _mm_set1_epi32(k as i32));
                _mm_castsi128_ps(_mm_slli_epi32::<23>(i))
            })
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            Self(unsafe { _mm_sqrt_ps(self.0) })
        }
        #[inline(always)]
        fn split_exponent(self) -> (Self, Self) {
            unsafe {
                let bits = _mm_castps_si128(self.0);
                let m = _mm_or_si128(
                    _mm_and_si128(bits, _mm_set1_epi32(MANTISSA_BITS as i32)),
                    _mm_set1_epi32(ONE_BITS as i32),
                );
                let e = _mm_and_si128(_mm_srli_epi32::<23>(bits), _mm_set1_epi32(0xff));
                let e = _mm_sub_ps(_mm_cvtepi32_ps(e), _mm_set1_ps(127.0));
                (Self(_mm_castsi128_ps(m)), Self(e))
            }
        }
    }

    impl Lanes for Avx2 {
        type Mask = Avx2Mask;
        type Token = Avx2Token;
        const N: usize = 8;
        const FUSED: bool = true;

        #[inline(always)]
        fn splat(_: Avx2Token, x: f32) -> Self {
            Self(unsafe { _mm256_set1_ps(x) })
        }
        #[inline(always)]
        fn load(_: Avx2Token, x: &[f32]) -> Self {
            let x = &x[..8];
            Self(unsafe { _mm256_loadu_ps(x.as_ptr()) })
        }
        #[inline(always)]
        fn store(self, out: &mut [f32]) {
            let out = &mut out[..8];
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn load_bits(_: Avx2Token, x: &[u32]) -> Self {
            let x = &x[..8];
            Self(unsafe { _mm256_castsi256_ps(_mm256_loadu_si256(x.as_ptr().cast())) })
        }
        #[inline(always)]
        fn store_bits(self, out: &mut [u32]) {
            let out = &mut out[..8];
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), _mm256_castps_si256(self.0)) }
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            Self(unsafe { _mm256_fmadd_ps(self.0, b.0, c.0) })
        }
        #[inline(always)]
        fn min(self, b: Self) -> Self {
            Self(unsafe { _mm256_min_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn max(self, b: Self) -> Self {
            Self(unsafe { _mm256_max_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn lt(self, b: Self) -> Avx2Mask {
            Avx2Mask(unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, b.0) })
        }
        #[inline(always)]
        fn le(self, b: Self) -> Avx2Mask {
            Avx2Mask(unsafe { _mm256_cmp_ps::<_CMP_LE_OQ>(self.0, b.0) })
        }
        #[inline(always)]
        fn gt(self, b: Self) -> Avx2Mask {
            Avx2Mask(unsafe { _mm256_cmp_ps::<_CMP_GT_OQ>(self.0, b.0) })
        }
        #[inline(always)]
        fn ge(self, b: Self) -> Avx2Mask {
            Avx2Mask(unsafe { _mm256_cmp_ps::<_CMP_GE_OQ>(self.0, b.0) })
        }
        #[inline(always)]
        fn bits_lt(self, b: Self) -> Avx2Mask {
            Avx2Mask(unsafe {
                _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                    _mm256_castps_si256(b.0),
                    _mm256_castps_si256(self.0),
                ))
            })
        }
        #[inline(always)]
        fn select(m: Avx2Mask, a: Self, b: Self) -> Self {
            Self(unsafe { _mm256_blendv_ps(b.0, a.0, m.0) })
        }
        #[inline(always)]
        fn keep(m: Avx2Mask, a: Self) -> Self {
            Self(unsafe { _mm256_and_ps(m.0, a.0) })
        }
        #[inline(always)]
        fn and_not(m: Avx2Mask, n: Avx2Mask) -> Avx2Mask {
            Avx2Mask(unsafe { _mm256_andnot_ps(n.0, m.0) })
        }
        #[inline(always)]
        fn any(m: Avx2Mask) -> bool {
            unsafe { _mm256_movemask_ps(m.0) != 0 }
        }
        #[inline(always)]
        fn count(m: Avx2Mask) -> u32 {
            unsafe { _mm256_movemask_ps(m.0) }.count_ones()
        }
        #[inline(always)]
        fn bits(m: Avx2Mask) -> u32 {
            unsafe { _mm256_movemask_ps(m.0) as u32 }
        }
        #[inline(always)]
        fn no_lanes(_: Avx2Token) -> Avx2Mask {
            Avx2Mask(unsafe { _mm256_setzero_ps() })
        }
        #[inline(always)]
        fn mask_from_fn(t: Avx2Token, f: impl Fn(usize) -> bool) -> Avx2Mask {
            let bits: [u32; 8] = std::array::from_fn(|i| if f(i) { u32::MAX } else { 0 });
            Avx2Mask(Self::load_bits(t, &bits).0)
        }
        #[inline(always)]
        fn reduce_max(self) -> f32 {
            // The halves' larger lanes, then as SSE.
            let halves = unsafe {
                _mm_max_ps(
                    _mm256_castps256_ps128(self.0),
                    _mm256_extractf128_ps::<1>(self.0),
                )
            };
            Sse2(halves).reduce_max()
        }
        #[inline(always)]
        fn reduce8(v: [Self; 8]) -> [f32; 8] {
            // Pairwise horizontal adds within each 128-bit half, then the halves added.
            let mut out = [0.0f32; 8];
            unsafe {
                let h01 = _mm256_hadd_ps(v[0].0, v[1].0);
                let h23 = _mm256_hadd_ps(v[2].0, v[3].0);
                let h45 = _mm256_hadd_ps(v[4].0, v[5].0);
                let h67 = _mm256_hadd_ps(v[6].0, v[7].0);
                // Per half: the sums of v0..v3 (and v4..v7) over that half's four lanes.
                let q0 = _mm256_hadd_ps(h01, h23);
                let q1 = _mm256_hadd_ps(h45, h67);
                let low = _mm256_permute2f128_ps::<0x20>(q0, q1);
                let high = _mm256_permute2f128_ps::<0x31>(q0, q1);
                Self(_mm256_add_ps(low, high)).store(&mut out);
            }
            out
        }
        #[inline(always)]
        fn exponent_bits(self, k: u32) -> Self {
            Self(unsafe {
                let i = _mm256_sub_epi32(_mm256_castps_si256(self.0), _mm256_set1_epi32(k as i32));
                _mm256_castsi256_ps(_mm256_slli_epi32::<23>(i))
            })
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            Self(unsafe { _mm256_sqrt_ps(self.0) })
        }
        #[inline(always)]
        fn split_exponent(self) -> (Self, Self) {
            unsafe {
                let bits = _mm256_castps_si256(self.0);
                let m = _mm256_or_si256(
                    _mm256_and_si256(bits, _mm256_set1_epi32(MANTISSA_BITS as i32)),
                    _mm256_set1_epi32(ONE_BITS as i32),
                );
                let e = _mm256_and_si256(_mm256_srli_epi32::<23>(bits), _mm256_set1_epi32(0xff));
                let e = _mm256_sub_ps(_mm256_cvtepi32_ps(e), _mm256_set1_ps(127.0));
                (Self(_mm256_castsi256_ps(m)), Self(e))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The worst relative error of `exp` against f64 over `steps` points of `[lo, hi]`.
    fn worst<L: Lanes>(token: L::Token, lo: f32, hi: f32, steps: usize) -> (f64, f32) {
        let mut worst = (0.0, 0.0);
        let mut xs = [0.0f32; 16];
        let mut es = [0.0f32; 16];
        for k in 0..steps / L::N {
            for (i, x) in xs.iter_mut().enumerate().take(L::N) {
                *x = lo + (hi - lo) * ((L::N * k + i) as f32 / steps as f32);
            }
            exp(token, L::load(token, &xs)).store(&mut es);
            for i in 0..L::N {
                let want = (xs[i] as f64).exp();
                let r = ((es[i] as f64 - want) / want).abs();
                // Written so that a NaN result counts as the worst.
                if !(r <= worst.0) {
                    worst = (r, xs[i]);
                }
            }
        }
        worst
    }

    fn check_exp<L: Lanes>(token: L::Token, name: &str) {
        // The whole domain, and densely the range the alpha test uses (ln(1/255) to 0).
        for (lo, hi, steps) in [(EXP_MIN, EXP_MAX, 2_000_000), (-5.6, 0.0, 2_000_000)] {
            let (err, at) = worst::<L>(token, lo, hi, steps);
            assert!(
                err <= EXP_MAX_REL_ERROR as f64,
                "{name}: relative error {err:e} at x = {at} on [{lo}, {hi}]"
            );
        }
        // NaN and out-of-range inputs come out finite; 0 is exact.
        let mut out = [0.0f32; 16];
        let mut inputs = [0.0f32; 16];
        inputs[..4].copy_from_slice(&[0.0, f32::NAN, -1e30, 1e30]);
        exp(token, L::load(token, &inputs)).store(&mut out);
        assert_eq!(out[0], 1.0, "{name}");
        assert!(out[..4].iter().all(|v| v.is_finite()), "{name}: {out:?}");
    }

    /// `ln` against f64 on a geometric sweep of the positive normal floats and a dense one
    /// around 1 (where the error bound is absolute); `sqrt` against `f32::sqrt` exactly.
    fn check_ln_sqrt<L: Lanes>(token: L::Token, name: &str) {
        let geometric = (0..200_000).map(|k| 2f64.powf(-125.0 + 252.0 * k as f64 / 200_000.0));
        let near_one = (0..200_000).map(|k| 0.5 + 1.5 * k as f64 / 200_000.0);
        let xs: Vec<f32> = geometric
            .chain(near_one)
            .map(|x| x as f32)
            .chain([f32::MIN_POSITIVE, 1.0, std::f32::consts::SQRT_2, f32::MAX])
            .collect();
        let (mut worst, mut at) = (0.0f64, 0.0f32);
        let mut out = [0.0f32; 16];
        let mut roots = [0.0f32; 16];
        for chunk in xs.chunks_exact(L::N) {
            let x = L::load(token, chunk);
            ln(token, x).store(&mut out);
            x.sqrt().store(&mut roots);
            for (i, &v) in chunk.iter().enumerate() {
                let exact = (v as f64).ln();
                let err = (out[i] as f64 - exact).abs() / exact.abs().max(1.0);
                // Written so that a NaN result fails.
                if !(err <= worst) {
                    (worst, at) = (err, v);
                }
                assert_eq!(roots[i], v.sqrt(), "{name}: sqrt({v})");
            }
        }
        assert!(
            worst <= LN_MAX_ERROR as f64,
            "{name}: ln error {worst:e} at {at} over the bound {LN_MAX_ERROR:e}"
        );
        // The bound is not loose by orders of magnitude: the worst error is within 8x of it.
        assert!(worst > LN_MAX_ERROR as f64 / 8.0, "{name}: {worst:e}");
    }

    fn check_masks<L: Lanes>(token: L::Token, name: &str) {
        let a: Vec<f32> = (0..16).map(|i| i as f32).collect();
        let b: Vec<f32> = (0..16)
            .map(|i| (L::N - 1 - i.min(L::N - 1)) as f32)
            .collect();
        let (va, vb) = (L::load(token, &a), L::load(token, &b));
        let m = va.lt(vb);
        assert_eq!(L::count(m), (L::N / 2) as u32, "{name}");
        let mut out = [0.0f32; 16];
        L::select(m, va, vb).store(&mut out);
        for i in 0..L::N {
            assert_eq!(out[i], a[i].min(b[i]), "{name} lane {i}");
        }
        L::keep(m, va).store(&mut out);
        for i in 0..L::N {
            assert_eq!(
                out[i],
                if a[i] < b[i] { a[i] } else { 0.0 },
                "{name} lane {i}"
            );
        }
        assert!(!L::any(L::and_not(m, m)) && L::any(m) && !L::any(L::no_lanes(token)));
        // NaN fails every comparison.
        let n = L::splat(token, f32::NAN);
        assert!(!L::any(n.lt(va) | n.ge(va) | n.le(va) | n.gt(va)), "{name}");
        let ints: Vec<u32> = (0..16).collect();
        let idx = L::load_bits(token, &ints);
        assert_eq!(
            L::count(idx.bits_lt(L::load_bits(token, &[2; 16]))),
            2,
            "{name}"
        );
        let sum: f32 = a[..L::N].iter().sum();
        assert_eq!(va.reduce_sum(), sum, "{name}");
        // The largest lane wherever it is, negative lanes included.
        for top in 0..L::N {
            let lanes: Vec<f32> = (0..16)
                .map(|i| if i == top { 7.5 } else { -(i as f32) - 1.0 })
                .collect();
            assert_eq!(
                L::load(token, &lanes).reduce_max(),
                7.5,
                "{name}: lane {top}"
            );
        }
        assert_eq!(L::splat(token, -3.0).reduce_max(), -3.0, "{name}");
        // Eight vectors reduced at once: vector j holds j * 100 + lane, so sums are exact.
        let vs: [L; 8] = std::array::from_fn(|j| {
            let lanes: Vec<f32> = (0..16).map(|i| (j * 100 + i) as f32).collect();
            L::load(token, &lanes)
        });
        let sums = L::reduce8(vs);
        for (j, got) in sums.iter().enumerate() {
            let want: f32 = (0..L::N).map(|i| (j * 100 + i) as f32).sum();
            assert_eq!(*got, want, "{name}: reduce8 of vector {j}");
        }
        let m = L::mask_from_fn(token, |i| i == 1);
        assert_eq!(L::count(m), 1, "{name}");
        // Lanes 1 and the last hold: their bits, and none above the width.
        let m = L::mask_from_fn(token, |i| i == 1 || i == L::N - 1);
        assert_eq!(L::bits(m), 2 | 1 << (L::N - 1), "{name}");
    }

    #[test]
    fn portable_lanes() {
        check_exp::<Portable>((), "portable");
        check_masks::<Portable>((), "portable");
        check_ln_sqrt::<Portable>((), "portable");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sse2_lanes() {
        check_exp::<Sse2>((), "sse2");
        check_masks::<Sse2>((), "sse2");
        check_ln_sqrt::<Sse2>((), "sse2");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_lanes() {
        let Some(token) = Avx2Token::detect() else {
            eprintln!("note: this CPU has no AVX2 + FMA; the 8-lane check is skipped");
            return;
        };
        check_exp::<Avx2>(token, "avx2");
        check_masks::<Avx2>(token, "avx2");
        check_ln_sqrt::<Avx2>(token, "avx2");
    }
}
