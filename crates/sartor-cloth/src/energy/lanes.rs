//! Scalars for the element derivatives: `f64`, or [`F64x4`], four elements' values side by side.
//!
//! The membrane's derivatives are written once over [`Real`] and run on one triangle (`f64`) or
//! on four at once ([`F64x4`]: every operation lane by lane, which the assembly's AVX2 build
//! ([`crate::isa::widest`]) compiles to 256-bit instructions). Each lane does exactly the
//! floating-point operations of the `f64` version, in the same order, and IEEE arithmetic
//! (`+ − × ÷ √`) rounds the same in a vector register as in a scalar one: four triangles done
//! together give bitwise what each gives alone. Branches become selects ([`Real::select`]),
//! whose untaken side is computed and dropped; lookups (the material's tables) are made lane by
//! lane ([`Real::lane`], [`Real::from_fn`]).

use std::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

use nalgebra::{
    ClosedAddAssign, ClosedDivAssign, ClosedMulAssign, ClosedSubAssign, Scalar, Vector3,
};
use num_traits::{One, Zero};

/// A real scalar, or several side by side (see the module docs).
pub trait Real:
    Scalar
    + Copy
    + Zero
    + One
    + ClosedAddAssign
    + ClosedSubAssign
    + ClosedMulAssign
    + ClosedDivAssign
    + Neg<Output = Self>
{
    /// How many values side by side.
    const LANES: usize;
    /// The result of a comparison, one answer per lane.
    type Mask: Copy;

    /// `v` in every lane.
    fn splat(v: f64) -> Self;
    /// Lane `l` is `f(l)`.
    fn from_fn(f: impl FnMut(usize) -> f64) -> Self;
    /// The value of lane `l`.
    fn lane(self, l: usize) -> f64;
    /// `f64::sqrt` in every lane.
    fn sqrt(self) -> Self;
    /// `f64::max` in every lane (the other value where one is NaN).
    fn max(self, other: Self) -> Self;
    /// `f64::min` in every lane (the other value where one is NaN).
    fn min(self, other: Self) -> Self;
    /// `f64::abs` in every lane.
    fn abs(self) -> Self;
    /// `f64::atan2(self, x)` in every lane (libm's, one lane at a time).
    fn atan2(self, x: Self) -> Self;
    /// `f64::powi(self, 4)` in every lane.
    fn pow4(self) -> Self;
    /// `self < other`, lane by lane.
    fn lt(self, other: Self) -> Self::Mask;
    /// Whether each lane is finite.
    fn is_finite(self) -> Self::Mask;
    /// Both masks, lane by lane.
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// The mask's complement, lane by lane.
    fn not(a: Self::Mask) -> Self::Mask;
    /// `self >= other`, lane by lane.
    fn ge(self, other: Self) -> Self::Mask;
    /// `self <= other`, lane by lane.
    fn le(self, other: Self) -> Self::Mask;
    /// `self > other`, lane by lane.
    fn gt(self, other: Self) -> Self::Mask;
    /// `yes` where `mask` holds, `no` elsewhere.
    fn select(mask: Self::Mask, yes: Self, no: Self) -> Self;
}

impl Real for f64 {
    const LANES: usize = 1;
    type Mask = bool;

    #[inline(always)]
    fn splat(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn from_fn(mut f: impl FnMut(usize) -> f64) -> Self {
        f(0)
    }
    #[inline(always)]
    fn lane(self, _: usize) -> f64 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        f64::max(self, other)
    }
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        f64::min(self, other)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn atan2(self, x: Self) -> Self {
        f64::atan2(self, x)
    }
    #[inline(always)]
    fn pow4(self) -> Self {
        f64::powi(self, 4)
    }
    #[inline(always)]
    fn lt(self, other: Self) -> bool {
        self < other
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    #[inline(always)]
    fn and(a: bool, b: bool) -> bool {
        a && b
    }
    #[inline(always)]
    fn not(a: bool) -> bool {
        !a
    }
    #[inline(always)]
    fn ge(self, other: Self) -> bool {
        self >= other
    }
    #[inline(always)]
    fn le(self, other: Self) -> bool {
        self <= other
    }
    #[inline(always)]
    fn gt(self, other: Self) -> bool {
        self > other
    }
    #[inline(always)]
    fn select(mask: bool, yes: Self, no: Self) -> Self {
        if mask { yes } else { no }
    }
}

/// Four `f64` side by side, every operation lane by lane (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
pub struct F64x4(pub [f64; 4]);

// The lanes written out, not `std::array::from_fn` or `map`: their closures are not always
// inlined, and each operation must be one instruction in the assembly's loop.
impl F64x4 {
    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let a = self.0;
        Self([f(a[0]), f(a[1]), f(a[2]), f(a[3])])
    }

    #[inline(always)]
    fn zip(self, other: Self, f: impl Fn(f64, f64) -> f64) -> Self {
        let (a, b) = (self.0, other.0);
        Self([f(a[0], b[0]), f(a[1], b[1]), f(a[2], b[2]), f(a[3], b[3])])
    }

    #[inline(always)]
    fn test(self, other: Self, f: impl Fn(f64, f64) -> bool) -> [bool; 4] {
        let (a, b) = (self.0, other.0);
        [f(a[0], b[0]), f(a[1], b[1]), f(a[2], b[2]), f(a[3], b[3])]
    }
}

/// The arithmetic operators, lane by lane, with their assigning forms.
macro_rules! lane_ops {
    ($($op:ident $f:ident $op_assign:ident $f_assign:ident),*) => {$(
        impl $op for F64x4 {
            type Output = Self;
            #[inline(always)]
            fn $f(self, other: Self) -> Self {
                self.zip(other, $op::$f)
            }
        }
        impl $op_assign for F64x4 {
            #[inline(always)]
            fn $f_assign(&mut self, other: Self) {
                *self = $op::$f(*self, other);
            }
        }
    )*};
}

lane_ops!(
    Add add AddAssign add_assign,
    Sub sub SubAssign sub_assign,
    Mul mul MulAssign mul_assign,
    Div div DivAssign div_assign
);

impl Neg for F64x4 {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(Neg::neg)
    }
}

impl Zero for F64x4 {
    #[inline(always)]
    fn zero() -> Self {
        Self([0.0; 4])
    }
    #[inline(always)]
    fn is_zero(&self) -> bool {
        self.0.iter().all(|v| *v == 0.0)
    }
}

impl One for F64x4 {
    #[inline(always)]
    fn one() -> Self {
        Self([1.0; 4])
    }
}

impl Real for F64x4 {
    const LANES: usize = 4;
    type Mask = [bool; 4];

    #[inline(always)]
    fn splat(v: f64) -> Self {
        Self([v; 4])
    }
    #[inline(always)]
    fn from_fn(mut f: impl FnMut(usize) -> f64) -> Self {
        Self([f(0), f(1), f(2), f(3)])
    }
    #[inline(always)]
    fn lane(self, l: usize) -> f64 {
        self.0[l]
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.map(f64::sqrt)
    }
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        self.zip(other, f64::max)
    }
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        self.zip(other, f64::min)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        self.map(f64::abs)
    }
    #[inline(always)]
    fn atan2(self, x: Self) -> Self {
        self.zip(x, f64::atan2)
    }
    #[inline(always)]
    fn pow4(self) -> Self {
        self.map(|v| v.powi(4))
    }
    #[inline(always)]
    fn lt(self, other: Self) -> [bool; 4] {
        self.test(other, |a, b| a < b)
    }
    #[inline(always)]
    fn is_finite(self) -> [bool; 4] {
        self.test(self, |a, _| a.is_finite())
    }
    #[inline(always)]
    fn and(a: [bool; 4], b: [bool; 4]) -> [bool; 4] {
        [a[0] && b[0], a[1] && b[1], a[2] && b[2], a[3] && b[3]]
    }
    #[inline(always)]
    fn not(a: [bool; 4]) -> [bool; 4] {
        [!a[0], !a[1], !a[2], !a[3]]
    }
    #[inline(always)]
    fn ge(self, other: Self) -> [bool; 4] {
        self.test(other, |a, b| a >= b)
    }
    #[inline(always)]
    fn le(self, other: Self) -> [bool; 4] {
        self.test(other, |a, b| a <= b)
    }
    #[inline(always)]
    fn gt(self, other: Self) -> [bool; 4] {
        self.test(other, |a, b| a > b)
    }
    #[inline(always)]
    fn select(mask: [bool; 4], yes: Self, no: Self) -> Self {
        let (m, y, n) = (mask, yes.0, no.0);
        let pick = |l: usize| if m[l] { y[l] } else { n[l] };
        Self([pick(0), pick(1), pick(2), pick(3)])
    }
}

/// The corners `idx` of four elements at positions `x`, side by side into `out` (lane `l` the
/// corners of `idx[l]`). Written out, no closures: in the assembly's AVX2 loop a closure's body
/// is compiled apart, for the baseline, and called.
#[inline(always)]
pub fn gather_lanes<const N: usize>(
    x: &[Vector3<f64>],
    idx: [&[u32; N]; 4],
    out: &mut [Vector3<F64x4>; N],
) {
    for (l, idx) in idx.iter().enumerate() {
        for (v, &i) in idx.iter().enumerate() {
            let p = &x[i as usize];
            for c in 0..3 {
                out[v][c].0[l] = p[c];
            }
        }
    }
}
