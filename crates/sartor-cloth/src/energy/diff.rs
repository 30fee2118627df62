//! Second-order derivatives of small closed-form scalars over three 3-vectors.
//!
//! The dihedral angle and the point–plane distance are both functions of three difference
//! vectors `z = (z0, z1, z2)` (9 variables). [`Scalar9`] carries a value with its exact
//! gradient and Hessian in `z`, and composes by the product, quotient and chain rules, so the
//! energies get exact Hessians without hand-expanded formulas. [`expand_to_vertices`] then maps
//! `z`-derivatives to the four vertices the differences come from (translation invariance).

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use super::lanes::Real;

/// 9-vector.
pub(crate) type V9 = SVector<f64, 9>;
/// 9 × 9 matrix.
pub(crate) type M9 = SMatrix<f64, 9, 9>;

/// A scalar with its gradient and Hessian in the 9 variables `z`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Scalar9 {
    pub v: f64,
    pub g: V9,
    pub h: M9,
}

fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

impl Scalar9 {
    fn set_block(h: &mut M9, i: usize, j: usize, m: &Matrix3<f64>) {
        h.fixed_view_mut::<3, 3>(3 * i, 3 * j).copy_from(m);
    }

    /// The value and gradient of `first` (the same arithmetic as [`Grad9`]) with Hessian `h`.
    fn with_hessian(first: Grad9, h: M9) -> Self {
        Self {
            v: first.v,
            g: V9::from(first.g),
            h,
        }
    }

    /// `z_i · z_j`.
    pub fn dot(z: &[Vector3<f64>; 3], i: usize, j: usize) -> Self {
        let mut h = M9::zeros();
        if i == j {
            Self::set_block(&mut h, i, i, &(2.0 * Matrix3::identity()));
        } else {
            Self::set_block(&mut h, i, j, &Matrix3::identity());
            Self::set_block(&mut h, j, i, &Matrix3::identity());
        }
        Self::with_hessian(Grad9::dot(z, i, j), h)
    }

    /// The triple product `z0 · (z1 × z2)`.
    pub fn triple(z: &[Vector3<f64>; 3]) -> Self {
        let [a, b, c] = z;
        // ∂²/∂a∂b = ∂(b × c)/∂b = −[c]×, ∂²/∂a∂c = [b]×, ∂²/∂b∂c = ∂(c × a)/∂c = −[a]×.
        let mut h = M9::zeros();
        let (hab, hac, hbc) = (-skew(c), skew(b), -skew(a));
        Self::set_block(&mut h, 0, 1, &hab);
        Self::set_block(&mut h, 1, 0, &hab.transpose());
        Self::set_block(&mut h, 0, 2, &hac);
        Self::set_block(&mut h, 2, 0, &hac.transpose());
        Self::set_block(&mut h, 1, 2, &hbc);
        Self::set_block(&mut h, 2, 1, &hbc.transpose());
        Self::with_hessian(Grad9::triple(z), h)
    }

    pub fn sub(&self, o: &Self) -> Self {
        Self {
            v: self.v - o.v,
            g: self.g - o.g,
            h: self.h - o.h,
        }
    }

    pub fn scale(&self, s: f64) -> Self {
        Self {
            v: self.v * s,
            g: self.g * s,
            h: self.h * s,
        }
    }

    pub fn mul(&self, o: &Self) -> Self {
        let cross = self.g * o.g.transpose();
        Self {
            v: self.v * o.v,
            g: self.g * o.v + o.g * self.v,
            h: self.h * o.v + o.h * self.v + cross + cross.transpose(),
        }
    }

    /// `f(self)` for a scalar function with value `f0`, derivative `f1`, second derivative `f2`.
    pub fn chain(&self, f0: f64, f1: f64, f2: f64) -> Self {
        Self {
            v: f0,
            g: self.g * f1,
            h: self.h * f1 + self.g * self.g.transpose() * f2,
        }
    }

    /// `√self` (self > 0).
    pub fn sqrt(&self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, 0.5 / r, -0.25 / (r * self.v))
    }

    /// `1 / self` (self ≠ 0).
    pub fn recip(&self) -> Self {
        let r = 1.0 / self.v;
        self.chain(r, -r * r, 2.0 * r * r * r)
    }

    /// `atan2(self, x)` (not both zero).
    pub fn atan2(&self, x: &Self) -> Self {
        let (s, c) = (self.v, x.v);
        let r2 = s * s + c * c;
        // ∂θ/∂s = c / r², ∂θ/∂c = −s / r²; second derivatives of atan2(s, c):
        // θ_ss = −2sc / r⁴, θ_cc = 2sc / r⁴, θ_sc = (s² − c²) / r⁴.
        let (ts, tc) = (c / r2, -s / r2);
        let r4 = r2 * r2;
        let (tss, tcc, tsc) = (-2.0 * s * c / r4, 2.0 * s * c / r4, (s * s - c * c) / r4);
        let gs_gc = self.g * x.g.transpose();
        Self {
            v: s.atan2(c),
            g: self.g * ts + x.g * tc,
            h: self.h * ts
                + x.h * tc
                + self.g * self.g.transpose() * tss
                + x.g * x.g.transpose() * tcc
                + (gs_gc + gs_gc.transpose()) * tsc,
        }
    }
}

/// A scalar with its gradient only in the 9 variables `z`: [`Scalar9`] without the Hessian,
/// for the energies whose solve needs only first derivatives (the Gauss–Newton bending
/// Hessian `2c ∇θ ∇θᵀ`). Every operation computes its value and gradient with exactly the
/// floating-point operations of its [`Scalar9`] twin, so the two give bitwise equal gradients
/// (tested) at a fraction of the cost (no 9 × 9 products).
///
/// Generic over [`Real`]: four hinges' angles side by side on [`crate::energy::F64x4`], each
/// lane bitwise the `f64` one. The gradient is a plain array and every operation is written
/// out entry by entry, in the order nalgebra's `f64` operations take.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Grad9<T = f64> {
    pub v: T,
    pub g: [T; 9],
}

/// `a · b`, nalgebra's order.
#[inline(always)]
pub(crate) fn dot3<T: Real>(a: &Vector3<T>, b: &Vector3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`, nalgebra's arithmetic.
#[inline(always)]
pub(crate) fn cross3<T: Real>(a: &Vector3<T>, b: &Vector3<T>) -> Vector3<T> {
    Vector3::new(
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )
}

/// `|a|`, nalgebra's arithmetic (its sum of squares starts from zero, which changes nothing).
#[inline(always)]
pub(crate) fn norm3<T: Real>(a: &Vector3<T>) -> T {
    dot3(a, a).sqrt()
}

impl<T: Real> Grad9<T> {
    /// `z_i · z_j`.
    #[inline(always)]
    pub fn dot(z: &[Vector3<T>; 3], i: usize, j: usize) -> Self {
        let mut g = [T::zero(); 9];
        for k in 0..3 {
            if i == j {
                g[3 * i + k] = T::splat(2.0) * z[i][k];
            } else {
                g[3 * i + k] = z[j][k];
                g[3 * j + k] = z[i][k];
            }
        }
        Self {
            v: dot3(&z[i], &z[j]),
            g,
        }
    }

    /// The triple product `z0 · (z1 × z2)`.
    #[inline(always)]
    pub fn triple(z: &[Vector3<T>; 3]) -> Self {
        let [a, b, c] = z;
        let bc = cross3(b, c);
        let parts = [bc, cross3(c, a), cross3(a, b)];
        let mut g = [T::zero(); 9];
        for (n, part) in parts.iter().enumerate() {
            for k in 0..3 {
                g[3 * n + k] = part[k];
            }
        }
        Self { v: dot3(a, &bc), g }
    }

    #[inline(always)]
    pub fn sub(&self, o: &Self) -> Self {
        let mut g = self.g;
        for (g, o) in g.iter_mut().zip(&o.g) {
            *g -= *o;
        }
        Self { v: self.v - o.v, g }
    }

    #[inline(always)]
    pub fn mul(&self, o: &Self) -> Self {
        let mut g = self.g;
        for (g, og) in g.iter_mut().zip(&o.g) {
            *g = *g * o.v + *og * self.v;
        }
        Self { v: self.v * o.v, g }
    }

    /// `f(self)` for a scalar function with value `f0` and derivative `f1`.
    #[inline(always)]
    pub fn chain(&self, f0: T, f1: T) -> Self {
        let mut g = self.g;
        for g in &mut g {
            *g *= f1;
        }
        Self { v: f0, g }
    }

    /// `√self` (self > 0).
    #[inline(always)]
    pub fn sqrt(&self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, T::splat(0.5) / r)
    }

    /// `atan2(self, x)` (not both zero).
    #[inline(always)]
    pub fn atan2(&self, x: &Self) -> Self {
        let (s, c) = (self.v, x.v);
        let r2 = s * s + c * c;
        let (ts, tc) = (c / r2, -s / r2);
        let mut g = self.g;
        for (g, xg) in g.iter_mut().zip(&x.g) {
            *g = *g * ts + *xg * tc;
        }
        Self { v: s.atan2(c), g }
    }
}

/// Map a gradient and Hessian in `z = (x[plus[0]] − x[base], x[plus[1]] − x[base],
/// x[plus[2]] − x[base])` to the four vertices `x[0..4]` (`base` and `plus` a permutation of
/// 0..4). Returns the 4 gradient blocks and the 4 × 4 Hessian blocks.
pub(crate) fn expand_to_vertices(
    g: &V9,
    h: &M9,
    base: usize,
    plus: [usize; 3],
) -> ([Vector3<f64>; 4], [[Matrix3<f64>; 4]; 4]) {
    // x-derivative = Dᵀ (z-derivative) with D = ∂z/∂x: +I at (slot, plus[slot]), −I at (slot, base).
    let mut grad = [Vector3::zeros(); 4];
    for (slot, &p) in plus.iter().enumerate() {
        let gs = g.fixed_rows::<3>(3 * slot).into_owned();
        grad[p] += gs;
        grad[base] -= gs;
    }
    let mut hess = [[Matrix3::zeros(); 4]; 4];
    for (si, &pi) in plus.iter().enumerate() {
        for (sj, &pj) in plus.iter().enumerate() {
            let b = h.fixed_view::<3, 3>(3 * si, 3 * sj).into_owned();
            hess[pi][pj] += b;
            hess[pi][base] -= b;
            hess[base][pj] -= b;
            hess[base][base] += b;
        }
    }
    (grad, hess)
}
