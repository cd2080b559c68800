//! The scalar type of the kernels, the gradient record they produce per splat, and the few
//! small matrix helpers they need.
//!
//! Kernels are generic over [`Real`] so that the same code runs in f32 (production) and f64
//! (the finite-difference reference that checks the hand-written gradients).

/// f32 or f64.
pub trait Real:
    num_traits::Float + Default + Send + Sync + std::fmt::Debug + std::iter::Sum + 'static
{
    /// Converts a constant.
    #[inline]
    fn c(x: f64) -> Self {
        <Self as num_traits::NumCast>::from(x).unwrap()
    }
    #[inline]
    fn as_f64(self) -> f64 {
        num_traits::ToPrimitive::to_f64(&self).unwrap()
    }
    /// The same records as f32 ones when `Self` is f32: how generic code hands its buffers to
    /// the f32-only SIMD kernels without `unsafe`.
    fn grads_as_f32(_: &mut [SplatGrad<Self>]) -> Option<&mut [SplatGrad<f32>]> {
        None
    }
}

impl Real for f32 {
    fn grads_as_f32(x: &mut [SplatGrad<f32>]) -> Option<&mut [SplatGrad<f32>]> {
        Some(x)
    }
}
impl Real for f64 {}

/// Gradients of the loss with respect to one splat's 2D quantities, summed over its pixels.
#[derive(Debug, Clone, Copy, Default)]
pub struct SplatGrad<F: Real> {
    pub xy: [F; 2],
    /// With respect to (a, b, c) of the conic, b counted once (as it appears in the exponent).
    pub conic: [F; 3],
    pub opacity: F,
    pub color: [F; 3],
    pub depth: F,
}

impl<F: Real> SplatGrad<F> {
    #[inline]
    pub fn add(&mut self, o: &SplatGrad<F>) {
        for i in 0..2 {
            self.xy[i] = self.xy[i] + o.xy[i];
        }
        for i in 0..3 {
            self.conic[i] = self.conic[i] + o.conic[i];
            self.color[i] = self.color[i] + o.color[i];
        }
        self.opacity = self.opacity + o.opacity;
        self.depth = self.depth + o.depth;
    }
}

pub type V3<F> = [F; 3];
/// Row-major 3x3 matrix.
pub type M3<F> = [[F; 3]; 3];

#[inline]
pub fn sub3<F: Real>(a: V3<F>, b: V3<F>) -> V3<F> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub fn dot3<F: Real>(a: V3<F>, b: V3<F>) -> F {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub fn mat_vec<F: Real>(m: &M3<F>, v: V3<F>) -> V3<F> {
    [dot3(m[0], v), dot3(m[1], v), dot3(m[2], v)]
}

#[inline]
pub fn mat_t_vec<F: Real>(m: &M3<F>, v: V3<F>) -> V3<F> {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

#[inline]
pub fn mat_mul<F: Real>(a: &M3<F>, b: &M3<F>) -> M3<F> {
    let mut r = [[F::zero(); 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    r
}

#[inline]
pub fn transpose<F: Real>(a: &M3<F>) -> M3<F> {
    [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ]
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
#[inline]
pub fn quat_to_mat<F: Real>(q: [F; 4]) -> M3<F> {
    let [w, x, y, z] = q;
    let one = F::one();
    let two = F::c(2.0);
    [
        [
            one - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            one - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

/// Gradient of a loss with respect to a unit quaternion, given its gradient with respect to the
/// rotation matrix (the adjoint of [`quat_to_mat`]).
#[inline]
pub fn quat_to_mat_backward<F: Real>(q: [F; 4], g: &M3<F>) -> [F; 4] {
    let [w, x, y, z] = q;
    let two = F::c(2.0);
    let dw =
        two * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] + x * g[2][1]);
    let dx = two
        * (y * g[0][1] + z * g[0][2] + y * g[1][0] - two * x * g[1][1] - w * g[1][2]
            + z * g[2][0]
            + w * g[2][1]
            - two * x * g[2][2]);
    let dy = two
        * (-two * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2]
            - w * g[2][0]
            + z * g[2][1]
            - two * y * g[2][2]);
    let dz = two
        * (-two * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] - two * z * g[1][1]
            + y * g[1][2]
            + x * g[2][0]
            + y * g[2][1]);
    [dw, dx, dy, dz]
}

#[inline]
pub fn sigmoid<F: Real>(x: F) -> F {
    if x >= F::zero() {
        F::one() / (F::one() + (-x).exp())
    } else {
        let e = x.exp();
        e / (F::one() + e)
    }
}
