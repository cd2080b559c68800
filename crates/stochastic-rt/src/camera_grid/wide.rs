//! Four f64s as one value, for placing four Gaussians at once ([`super::Screen::place4`]).
//!
//! Each operation is the scalar one lane by lane, in the same order, so a lane's result has
//! the bits the scalar code gives (Rust fuses no multiply-add unasked). Written as arrays: in
//! the AVX2 build the compiler makes each operation one 256-bit instruction.

use glam::{DVec3, Vec3};
use std::ops::{Add, Div, Mul, Neg, Sub};

/// Four f64 lanes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Wide(pub(super) [f64; 4]);

impl Wide {
    #[inline(always)]
    pub(super) fn splat(v: f64) -> Self {
        Self([v; 4])
    }

    /// Lane `l` from `f(l)`. Written out, as every operation here: `array::from_fn` and
    /// `array::map` are not always inlined, and a call leaves the AVX2 build.
    #[inline(always)]
    pub(super) fn from_fn(f: impl Fn(usize) -> f64) -> Self {
        Self([f(0), f(1), f(2), f(3)])
    }

    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let v = self.0;
        Self([f(v[0]), f(v[1]), f(v[2]), f(v[3])])
    }

    /// Each lane rounded to f32.
    #[inline(always)]
    pub(super) fn to_f32(self) -> [f32; 4] {
        let v = self.0;
        [v[0] as f32, v[1] as f32, v[2] as f32, v[3] as f32]
    }

    #[inline(always)]
    pub(super) fn sqrt(self) -> Self {
        self.map(f64::sqrt)
    }
}

macro_rules! lanewise {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for Wide {
            type Output = Self;
            #[inline(always)]
            fn $method(self, rhs: Self) -> Self {
                let (a, b) = (self.0, rhs.0);
                Self([a[0] $op b[0], a[1] $op b[1], a[2] $op b[2], a[3] $op b[3]])
            }
        }
        impl $trait<f64> for Wide {
            type Output = Self;
            #[inline(always)]
            fn $method(self, rhs: f64) -> Self {
                self.map(|v| v $op rhs)
            }
        }
        impl $trait<Wide> for f64 {
            type Output = Wide;
            #[inline(always)]
            fn $method(self, rhs: Wide) -> Wide {
                rhs.map(|v| self $op v)
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);
lanewise!(Div, div, /);

impl Neg for Wide {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|v| -v)
    }
}

/// Four 3-vectors, [`DVec3`]'s arithmetic in each lane.
#[derive(Clone, Copy, Debug)]
pub(super) struct Wide3 {
    pub(super) x: Wide,
    pub(super) y: Wide,
    pub(super) z: Wide,
}

impl Wide3 {
    /// Lane `l` from `f(l)`, an f32 vector widened.
    #[inline(always)]
    pub(super) fn from_fn(f: impl Fn(usize) -> Vec3) -> Self {
        Self {
            x: Wide::from_fn(|l| f(l).x as f64),
            y: Wide::from_fn(|l| f(l).y as f64),
            z: Wide::from_fn(|l| f(l).z as f64),
        }
    }

    #[inline(always)]
    pub(super) fn splat(v: DVec3) -> Self {
        Self {
            x: Wide::splat(v.x),
            y: Wide::splat(v.y),
            z: Wide::splat(v.z),
        }
    }

    /// Each lane rounded to f32: [`Wide3F32::lane`] gives lane `l`.
    #[inline(always)]
    pub(super) fn to_f32(self) -> Wide3F32 {
        Wide3F32([self.x.to_f32(), self.y.to_f32(), self.z.to_f32()])
    }

    /// Lane `l` as a [`DVec3`].
    #[inline(always)]
    pub(super) fn lane(&self, l: usize) -> DVec3 {
        DVec3::new(self.x.0[l], self.y.0[l], self.z.0[l])
    }

    /// [`DVec3::dot`]: `(x x') + (y y') + (z z')`.
    #[inline(always)]
    pub(super) fn dot(self, rhs: Self) -> Wide {
        self.x * rhs.x + self.y * rhs.y + self.z * rhs.z
    }

    /// [`DVec3::dot`] with one vector for every lane.
    #[inline(always)]
    pub(super) fn dot_one(self, rhs: DVec3) -> Wide {
        self.x * rhs.x + self.y * rhs.y + self.z * rhs.z
    }

    /// [`DVec3::cross`], its terms in its order.
    #[inline(always)]
    pub(super) fn cross(self, rhs: Self) -> Self {
        Self {
            x: self.y * rhs.z - rhs.y * self.z,
            y: self.z * rhs.x - rhs.z * self.x,
            z: self.x * rhs.y - rhs.x * self.y,
        }
    }
}

/// [`Wide3`] rounded to f32, by component.
#[derive(Clone, Copy, Debug)]
pub(super) struct Wide3F32([[f32; 4]; 3]);

impl Wide3F32 {
    #[inline(always)]
    pub(super) fn lane(&self, l: usize) -> Vec3 {
        Vec3::new(self.0[0][l], self.0[1][l], self.0[2][l])
    }
}

impl Add for Wide3 {
    type Output = Self;
    #[inline(always)]
    fn add(self, rhs: Self) -> Self {
        Self {
            x: self.x + rhs.x,
            y: self.y + rhs.y,
            z: self.z + rhs.z,
        }
    }
}

impl Sub for Wide3 {
    type Output = Self;
    #[inline(always)]
    fn sub(self, rhs: Self) -> Self {
        Self {
            x: self.x - rhs.x,
            y: self.y - rhs.y,
            z: self.z - rhs.z,
        }
    }
}

impl Mul<Wide3> for f64 {
    type Output = Wide3;
    #[inline(always)]
    fn mul(self, rhs: Wide3) -> Wide3 {
        Wide3 {
            x: self * rhs.x,
            y: self * rhs.y,
            z: self * rhs.z,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each lane of every operation has the scalar operation's bits ([`DVec3`]'s for the
    /// vectors), on numbers spread over many magnitudes and signs.
    #[test]
    fn lanes_give_the_scalar_bits() {
        let value = |k: u32| {
            let h = render_base::hash::hash32(&[k]);
            let m = (h & 0xffff) as f64 / 65536.0 - 0.5;
            m * 2f64.powi(((h >> 16) % 40) as i32 - 20)
        };
        for round in 0..200u32 {
            let v = |k: u32| Wide::from_fn(|l| value(round * 64 + k * 4 + l as u32));
            let (a, b) = (v(0), v(1));
            for l in 0..4 {
                let (x, y) = (a.0[l], b.0[l]);
                assert_eq!((a + b).0[l].to_bits(), (x + y).to_bits());
                assert_eq!((a - b).0[l].to_bits(), (x - y).to_bits());
                assert_eq!((a * b).0[l].to_bits(), (x * y).to_bits());
                assert_eq!((a / b).0[l].to_bits(), (x / y).to_bits());
                assert_eq!((-a).0[l].to_bits(), (-x).to_bits());
                assert_eq!(a.sqrt().0[l].to_bits(), x.sqrt().to_bits());
                assert_eq!(a.to_f32()[l].to_bits(), (x as f32).to_bits());
                assert_eq!((0.5 * a).0[l].to_bits(), (0.5 * x).to_bits());
            }
            let w3 = |k: u32| Wide3 {
                x: v(k),
                y: v(k + 1),
                z: v(k + 2),
            };
            let (p, q) = (w3(2), w3(5));
            let one = DVec3::new(value(round), value(round + 1), value(round + 2));
            for l in 0..4 {
                let (s, t) = (p.lane(l), q.lane(l));
                assert_eq!(p.dot(q).0[l].to_bits(), s.dot(t).to_bits());
                assert_eq!(p.dot_one(one).0[l].to_bits(), s.dot(one).to_bits());
                assert_eq!(
                    p.cross(q).lane(l).to_array().map(f64::to_bits),
                    s.cross(t).to_array().map(f64::to_bits)
                );
                assert_eq!((p - q).lane(l), s - t);
                assert_eq!(p.to_f32().lane(l), s.as_vec3());
                assert_eq!((0.5 * (p + q)).lane(l), 0.5 * (s + t));
            }
        }
    }
}
