//! Eight f32 values per operation, for per-Gaussian formulas run on eight Gaussians at a
//! time (`project_batch`, `project_backward_batch`). Plain element-wise arithmetic on
//! arrays, which the compiler turns into SIMD instructions on any x86-64 (SSE2) or AArch64
//! CPU; each lane performs exactly the scalar operation, so a formula written with the same
//! operands in the same order gives the same bits as its scalar form. Also 3-vectors and
//! 3x3 matrices of lanes whose products add their terms in glam's order (`Mat3 * Vec3` is
//! `(x_axis * v.x + y_axis * v.y) + z_axis * v.z`, `dot` is `(x x' + y y') + z z'`), so a
//! formula written with glam types can be mirrored bit for bit. The 3-vector and matrix
//! operations list their entries: `map` and `from_fn` over them were left as out-of-line
//! calls, which also lose the caller's target features (AVX).

use std::ops::{Add, Div, Mul, Neg, Sub};

pub(super) const N: usize = 8;

/// Eight f32 values; element-wise arithmetic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Lanes(pub [f32; N]);

impl Lanes {
    #[inline(always)]
    pub fn splat(v: f32) -> Self {
        Self([v; N])
    }

    #[inline(always)]
    pub fn map(self, f: impl Fn(f32) -> f32) -> Self {
        Self(std::array::from_fn(|l| f(self.0[l])))
    }

    #[inline(always)]
    pub fn zip(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        let mut r = self.0;
        for (a, b) in r.iter_mut().zip(o.0) {
            *a = f(*a, b);
        }
        Self(r)
    }

    #[inline(always)]
    pub fn sqrt(self) -> Self {
        self.map(f32::sqrt)
    }

    /// `self` where `mask`, else `other`.
    #[inline(always)]
    pub fn select(self, mask: [bool; N], other: Self) -> Self {
        Self(std::array::from_fn(|l| {
            if mask[l] {
                self.0[l]
            } else {
                other.0[l]
            }
        }))
    }

    #[inline(always)]
    pub fn mask(self, f: impl Fn(f32) -> bool) -> [bool; N] {
        std::array::from_fn(|l| f(self.0[l]))
    }
}

macro_rules! lane_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for Lanes {
            type Output = Lanes;
            #[inline(always)]
            fn $f(self, o: Lanes) -> Lanes {
                self.zip(o, |a, b| a $op b)
            }
        }
        impl $tr<f32> for Lanes {
            type Output = Lanes;
            #[inline(always)]
            fn $f(self, o: f32) -> Lanes {
                self.map(|a| a $op o)
            }
        }
        impl $tr<Lanes> for f32 {
            type Output = Lanes;
            #[inline(always)]
            fn $f(self, o: Lanes) -> Lanes {
                o.map(|b| self $op b)
            }
        }
    };
}
lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

impl Neg for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn neg(self) -> Lanes {
        self.map(|a| -a)
    }
}

/// A 3-vector of lanes (glam's `Vec3` per lane).
#[derive(Debug, Clone, Copy)]
pub(super) struct V3(pub [Lanes; 3]);

impl V3 {
    #[inline(always)]
    pub fn dot(self, o: Self) -> Lanes {
        (self.0[0] * o.0[0] + self.0[1] * o.0[1]) + self.0[2] * o.0[2]
    }

    #[inline(always)]
    pub fn scale(self, s: Lanes) -> Self {
        Self([self.0[0] * s, self.0[1] * s, self.0[2] * s])
    }

    #[inline(always)]
    pub fn add(self, o: Self) -> Self {
        Self([self.0[0] + o.0[0], self.0[1] + o.0[1], self.0[2] + o.0[2]])
    }
}

/// A 3x3 matrix of lanes stored by columns (glam's `Mat3` per lane).
#[derive(Debug, Clone, Copy)]
pub(super) struct M3(pub [V3; 3]);

impl M3 {
    /// From a constant matrix (the same in every lane), columns as glam stores them.
    #[inline(always)]
    pub fn splat(cols: [[f32; 3]; 3]) -> Self {
        Self(std::array::from_fn(|j| {
            V3(std::array::from_fn(|i| Lanes::splat(cols[j][i])))
        }))
    }

    /// `Mat3 * Vec3`: the columns weighted by v's entries, added in order.
    #[inline(always)]
    pub fn mul_vec(&self, v: V3) -> V3 {
        let [c0, c1, c2] = self.0;
        c0.scale(v.0[0]).add(c1.scale(v.0[1])).add(c2.scale(v.0[2]))
    }

    #[inline(always)]
    pub fn mul(&self, o: &Self) -> Self {
        let [a, b, c] = o.0;
        Self([self.mul_vec(a), self.mul_vec(b), self.mul_vec(c)])
    }

    #[inline(always)]
    pub fn transpose(&self) -> Self {
        let [[a, b, c], [d, e, f], [g, h, i]] = self.0.map(|v| v.0);
        Self([V3([a, d, g]), V3([b, e, h]), V3([c, f, i])])
    }

    #[inline(always)]
    pub fn add(&self, o: &Self) -> Self {
        Self([
            self.0[0].add(o.0[0]),
            self.0[1].add(o.0[1]),
            self.0[2].add(o.0[2]),
        ])
    }

    /// `Mat3::from_diagonal(d)`, zeros included: a product with it is computed in full,
    /// as glam does, so that the bits match.
    #[inline(always)]
    pub fn diagonal(d: V3) -> Self {
        let z = Lanes::splat(0.0);
        Self([V3([d.0[0], z, z]), V3([z, d.0[1], z]), V3([z, z, d.0[2]])])
    }
}
