//! Bending energy of one hinge (two triangles sharing an edge), ARCSim's form.
//!
//! Vertices: `x0, x1` the shared edge, `x2` opposite in face A = `(x0, x1, x2)`, `x3` opposite
//! in face B = `(x1, x0, x3)` (both counter-clockwise, so they agree on orientation).
//!
//! ARCSim (`physics.cpp`): `bending_coeff = ke · l² / (2 (A0 + A1))` and
//! `E = bending_coeff · (θ − θ̄)² / 4`, i.e.
//!
//! ```text
//! E = c (θ − θ̄)²,   c = ke · l² / (8 (A0 + A1))
//! ```
//!
//! with `l` the *current* edge length, `A0 + A1` the rest areas of the two faces and `ke` from
//! the bending table (which depends on θ and l). ARCSim evaluates `c` from the current state and
//! does not differentiate it; we freeze `c` for the step ([`BendingRest::coefficient`]) and the
//! energy, gradient and Hessian here are exact for `c` constant.
//!
//! The dihedral angle is ARCSim's signed one, `θ = atan2(e·(n0 × n1), n0·n1)` with
//! `e = (x0 − x1)/|x0 − x1|`, `n0, n1` the unit normals of A and B. In terms of
//! `e = x1 − x0, a = x2 − x0, b = x3 − x0` this is
//!
//! ```text
//! θ = atan2(|e| · e·(a × b),  (e·a)(e·b) − |e|² (a·b))
//! ```
//!
//! (both arguments are the true sine and cosine scaled by `|n_A| |n_B| > 0`), a closed form whose
//! exact gradient and Hessian follow from the product and chain rules (see `diff.rs`). This gives
//! the same gradient as the Bridson et al. 2003 formulas ARCSim uses and the exact Hessian
//! (cf. Tamstorf & Grinspun 2013) without hand-expanded terms.
//!
//! PSD projection ([`BendingHessian::ProjectedExact`]): the exact energy Hessian is built in the
//! 9 difference variables, projected there (9 × 9 eigenvalues clamped at zero; `Dᵀ H⁺ D` stays
//! PSD) and mapped to the 12 vertex coordinates. [`BendingHessian::GaussNewton`] is ARCSim's
//! `2c ∇θ ∇θᵀ`.

use nalgebra::{Matrix3, Vector3};

#[cfg(test)]
use super::diff::V9;
use super::diff::{Grad9, Scalar9, cross3, dot3, expand_to_vertices, norm3};
use super::lanes::{F64x4, Real};
use super::membrane::ElementDerivatives;
use super::psd::project_psd;
use crate::material::BendingModel;

/// How the bending Hessian enters the implicit solve.
///
/// Measured (0.15 s swing of a 441-vertex gray-interlock sheet, h = 1/300 s): the two choices
/// differ by 0.05 mm after one Newton step each, and both are 2.2 mm from an h/8 reference (the
/// time discretisation dominates); on a 4,356-vertex sheet the projection costs ~90 ms per
/// substep on top of ~30 ms for all other element work (12,700 9 × 9 eigen-decompositions).
/// Hence the default is ARCSim's Gauss–Newton.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum BendingHessian {
    /// ARCSim's Gauss–Newton `2c ∇θ ∇θᵀ` (PSD, cheap).
    #[default]
    GaussNewton,
    /// The exact Hessian, projected to PSD (9 × 9 eigen-clamp per hinge).
    ProjectedExact,
    /// The exact Hessian, unprojected (tests only: may be indefinite).
    Exact,
}

/// A hinge whose smaller face has less than this fraction of the mean rest face area is
/// [`BendingRest::crushed`].
pub const CRUSHED_AREA_FRACTION: f64 = 0.01;

/// A hinge's Gauss–Newton derivatives in factored form ([`BendingRest::gauss_newton`]); of four
/// hinges side by side for `T` = [`F64x4`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussNewtonHinge<T = f64> {
    /// Energy, J.
    pub energy_j: T,
    /// `∂E/∂x_i`, N.
    pub gradient: [Vector3<T>; 4],
    /// `∂θ/∂x_i`, 1/m.
    pub angle: [Vector3<T>; 4],
    /// `2c`, the factor of `∇θ ∇θᵀ`, J.
    pub curvature: T,
}

impl<T: Real> Default for GaussNewtonHinge<T> {
    fn default() -> Self {
        Self {
            energy_j: T::zero(),
            gradient: [Vector3::zeros(); 4],
            angle: [Vector3::zeros(); 4],
            curvature: T::zero(),
        }
    }
}

impl GaussNewtonHinge {
    /// The Hessian's block `(a, b)`, N/m.
    #[inline]
    pub fn block(&self, a: usize, b: usize) -> Matrix3<f64> {
        self.angle[a] * self.angle[b].transpose() * self.curvature
    }
}

/// Rest data of one hinge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BendingRest {
    /// `[x0, x1, x2, x3]` as in the module docs.
    pub vertices: [u32; 4],
    /// Rest dihedral angle θ̄, rad.
    pub rest_angle_rad: f64,
    /// Sum of the rest areas of the two faces, m².
    pub area_sum_m2: f64,
    /// The edge's direction in each face's material frame, `atan2(v, u)`, rad.
    pub edge_angle_rad: [f64; 2],
}

/// The three difference vectors `(x1 − x0, x2 − x0, x3 − x0)`.
#[inline(always)]
fn differences<T: Real>(x: &[Vector3<T>; 4]) -> [Vector3<T>; 3] {
    let d = |k: usize| Vector3::new(x[k][0] - x[0][0], x[k][1] - x[0][1], x[k][2] - x[0][2]);
    [d(1), d(2), d(3)]
}

/// ARCSim's signed dihedral angle of a hinge (0 when flat), rad.
pub fn dihedral_angle(x: &[Vector3<f64>; 4]) -> f64 {
    let [e, a, b] = differences(x);
    let sine = e.norm() * e.dot(&a.cross(&b));
    let cosine = e.dot(&a) * e.dot(&b) - e.norm_squared() * a.dot(&b);
    sine.atan2(cosine)
}

/// The dihedral angle with its exact gradient and Hessian in the difference variables, or
/// `None` for a degenerate hinge (zero-length edge or zero-area face).
fn dihedral_angle_derivatives(x: &[Vector3<f64>; 4]) -> Option<Scalar9> {
    let z = differences(x);
    let ee = Scalar9::dot(&z, 0, 0);
    let scale = ee.v.max(z[1].norm_squared()).max(z[2].norm_squared());
    if !(ee.v > 1e-20 * scale && scale > 0.0) {
        return None;
    }
    let len = ee.sqrt();
    let sine = len.mul(&Scalar9::triple(&z));
    let cosine = Scalar9::dot(&z, 0, 1)
        .mul(&Scalar9::dot(&z, 0, 2))
        .sub(&ee.mul(&Scalar9::dot(&z, 1, 2)));
    // sine² + cosine² = |e|² |n_A|² |n_B|² (unnormalised normals): zero iff a face is degenerate.
    let r2 = sine.v * sine.v + cosine.v * cosine.v;
    if !(r2 > 1e-30 * scale.powi(4) && r2.is_finite()) {
        return None;
    }
    Some(sine.atan2(&cosine))
}

/// [`dihedral_angle_derivatives`] without the Hessian: the angle and its gradient (bitwise
/// the same), for the Gauss–Newton Hessian.
#[cfg(test)]
fn dihedral_angle_gradient(x: &[Vector3<f64>; 4]) -> Option<(f64, V9)> {
    let (proper, theta) = angle_gradient(&differences(x));
    proper.then(|| (theta.v, V9::from(theta.g)))
}

/// The angle and its gradient in the differences `z`, and whether the hinge is proper (lane
/// by lane: a degenerate lane's values are computed and meaningless).
#[inline(always)]
fn angle_gradient<T: Real>(z: &[Vector3<T>; 3]) -> (T::Mask, Grad9<T>) {
    let ee = Grad9::dot(z, 0, 0);
    let scale = ee.v.max(dot3(&z[1], &z[1])).max(dot3(&z[2], &z[2]));
    let proper = T::and(ee.v.gt(T::splat(1e-20) * scale), scale.gt(T::zero()));
    let len = ee.sqrt();
    let sine = len.mul(&Grad9::triple(z));
    let cosine = Grad9::dot(z, 0, 1)
        .mul(&Grad9::dot(z, 0, 2))
        .sub(&ee.mul(&Grad9::dot(z, 1, 2)));
    let r2 = sine.v * sine.v + cosine.v * cosine.v;
    let proper = T::and(
        proper,
        T::and(r2.gt(T::splat(1e-30) * scale.pow4()), r2.is_finite()),
    );
    (proper, sine.atan2(&cosine))
}

/// [`BendingRest::crushed`] for the differences `z`, lane by lane.
#[inline(always)]
fn crushed<T: Real>(z: &[Vector3<T>; 3], area_sum: T) -> T::Mask {
    let twice_min_area = norm3(&cross3(&z[0], &z[1])).min(norm3(&cross3(&z[0], &z[2])));
    // Twice a face's area against twice the mean rest face area (= the rest area sum).
    twice_min_area.lt(T::splat(CRUSHED_AREA_FRACTION) * area_sum)
}

/// Where a hinge's coefficient comes from (an enum, not a closure, to be inlined into the
/// assembly's AVX2 build; see `crate::isa`).
#[derive(Clone, Copy)]
pub(crate) enum HingeCoefficient<'a, T> {
    /// Frozen at these values.
    Frozen(T),
    /// The model's at the hinge's angle and edge length.
    Model(&'a BendingModel),
}

/// The hinges' coefficients `c = ke · l² / (8 (A0 + A1))` (`rests`: one per lane) for the
/// edges `e = x1 − x0` and angles `theta`; the table is looked up lane by lane.
#[inline(always)]
fn coefficient_lanes<T: Real>(
    rests: &[&BendingRest],
    e: &Vector3<T>,
    theta: T,
    model: &BendingModel,
) -> T {
    let l = norm3(e);
    // A loop, not a closure given to `from_fn`: that closure was compiled apart, for the
    // baseline instruction set, and called.
    let (mut ke, mut area) = ([0.0; 4], [0.0; 4]);
    for lane in 0..T::LANES {
        let (rest, theta, l) = (rests[lane], theta.lane(lane), l.lane(lane));
        let a = rest.area_sum_m2;
        ke[lane] = model
            .stiffness(theta, l, a, rest.edge_angle_rad[0])
            .min(model.stiffness(theta, l, a, rest.edge_angle_rad[1]));
        area[lane] = a;
    }
    let (ke, area) = (T::from_fn(|lane| ke[lane]), T::from_fn(|lane| area[lane]));
    ke * l * l / (T::splat(8.0) * area)
}

/// [`BendingRest::gauss_newton`] of one hinge per lane (`rests`: one per lane) into `out`;
/// returns the lanes that have one (not [`BendingRest::crushed`], not degenerate).
#[inline(always)]
fn gauss_newton_into<T: Real>(
    rests: &[&BendingRest],
    x: &[Vector3<T>; 4],
    coefficient: HingeCoefficient<'_, T>,
    out: &mut GaussNewtonHinge<T>,
) -> T::Mask {
    let area = T::from_fn(|lane| rests[lane].area_sum_m2);
    let z = differences(x);
    let crushed = crushed(&z, area);
    // First derivatives of θ suffice: no 9 × 9 second derivatives (same numbers). The
    // angle's gradient per vertex (z = x1 − x0, x2 − x0, x3 − x0), and the Gauss–Newton
    // Hessian 2c ∇θ ∇θᵀ block by block: the same matrix as mapping the 9 × 9 one of z to
    // the vertices, at a third of the work. `∇θ_b ∇θ_aᵀ` is bitwise the transpose of
    // `∇θ_a ∇θ_bᵀ` (each entry one product), so every block is computed the same way.
    let (proper, theta) = angle_gradient(&z);
    let coefficient = match coefficient {
        HingeCoefficient::Frozen(c) => c,
        HingeCoefficient::Model(model) => coefficient_lanes(rests, &z[0], theta.v, model),
    };
    let rest_angle = T::from_fn(|lane| rests[lane].rest_angle_rad);
    let d = theta.v - rest_angle;
    let g = |k: usize| Vector3::new(theta.g[3 * k], theta.g[3 * k + 1], theta.g[3 * k + 2]);
    let (g1, g2, g3) = (g(0), g(1), g(2));
    let first = Vector3::new(
        -g1[0] - g2[0] - g3[0],
        -g1[1] - g2[1] - g3[1],
        -g1[2] - g2[2] - g3[2],
    );
    out.angle = [first, g1, g2, g3];
    let slope = T::splat(2.0) * coefficient * d;
    for (gradient, angle) in out.gradient.iter_mut().zip(&out.angle) {
        *gradient = Vector3::new(angle[0] * slope, angle[1] * slope, angle[2] * slope);
    }
    out.energy_j = coefficient * d * d;
    out.curvature = T::splat(2.0) * coefficient;
    T::and(T::not(crushed), proper)
}

impl BendingRest {
    /// The frozen stiffness coefficient `c = ke · l² / (8 (A0 + A1))` at the current positions
    /// (ARCSim's `bending_coeff / 4`); `ke = min` over the two faces as in ARCSim.
    pub fn coefficient(&self, x: &[Vector3<f64>; 4], model: &BendingModel) -> f64 {
        self.coefficient_at(x, dihedral_angle(x), model)
    }

    /// [`Self::coefficient`] for the hinge's dihedral angle `theta` at `x`, already known.
    #[inline(always)]
    fn coefficient_at(&self, x: &[Vector3<f64>; 4], theta: f64, model: &BendingModel) -> f64 {
        coefficient_lanes(&[self], &differences(x)[0], theta, model)
    }

    /// Whether a face of the hinge is crushed below [`CRUSHED_AREA_FRACTION`] of the mean rest
    /// face area: its dihedral angle is then ill-defined and the angle's derivatives grow as
    /// the inverse of the face's height (a face pressed to 1e-19 m² in a fast run made the
    /// bending Hessian so large that the step's system lost positive definiteness to rounding).
    /// Such a hinge is left out of the energy until the membrane reopens the face.
    #[inline(always)]
    pub fn crushed(&self, x: &[Vector3<f64>; 4]) -> bool {
        crushed(&differences(x), self.area_sum_m2)
    }

    /// Energy `c (θ − θ̄)²`, J (0 for a [`Self::crushed`] hinge).
    pub fn energy(&self, x: &[Vector3<f64>; 4], coefficient: f64) -> f64 {
        if self.crushed(x) {
            return 0.0;
        }
        let d = dihedral_angle(x) - self.rest_angle_rad;
        coefficient * d * d
    }

    /// The Gauss–Newton derivatives in factored form: the gradient per vertex and the angle's
    /// gradient `∇θ` per vertex with the curvature `2c`, so that the Hessian's block `(a, b)`
    /// is `∇θ_a ∇θ_bᵀ · 2c`, bitwise the block [`Self::derivatives`] gives for
    /// [`BendingHessian::GaussNewton`]. For callers that add the blocks where they go without
    /// holding the sixteen of them. `None` where `derivatives` gives zeros (a crushed or
    /// degenerate hinge).
    #[inline(always)]
    pub fn gauss_newton(
        &self,
        x: &[Vector3<f64>; 4],
        coefficient: f64,
    ) -> Option<GaussNewtonHinge> {
        self.gauss_newton_with(x, HingeCoefficient::Frozen(coefficient))
    }

    /// [`Self::gauss_newton`] with the coefficient frozen at `x` itself, bitwise
    /// `gauss_newton(x, coefficient(x, model))`: the dihedral angle (an `atan2`) is computed
    /// once for both. For the first Newton iteration of a step, whose linearisation point is
    /// the state the coefficients are frozen at.
    #[inline(always)]
    pub fn gauss_newton_frozen_here(
        &self,
        x: &[Vector3<f64>; 4],
        model: &BendingModel,
    ) -> Option<GaussNewtonHinge> {
        self.gauss_newton_with(x, HingeCoefficient::Model(model))
    }

    /// [`Self::gauss_newton`] with the coefficient from `coefficient`.
    #[inline(always)]
    fn gauss_newton_with(
        &self,
        x: &[Vector3<f64>; 4],
        coefficient: HingeCoefficient<'_, f64>,
    ) -> Option<GaussNewtonHinge> {
        let mut out = GaussNewtonHinge::default();
        gauss_newton_into(&[self], x, coefficient, &mut out).then_some(out)
    }

    /// [`Self::gauss_newton_frozen_here`] (`frozen` = `None`) or [`Self::gauss_newton`]
    /// (`frozen` = the four coefficients) of four hinges at once into `out`, each lane bitwise
    /// what its hinge gives alone; returns the lanes that have one.
    #[inline(always)]
    pub fn gauss_newton_lanes(
        rests: [&Self; 4],
        x: &[Vector3<F64x4>; 4],
        model: &BendingModel,
        frozen: Option<[f64; 4]>,
        out: &mut GaussNewtonHinge<F64x4>,
    ) -> [bool; 4] {
        let coefficient = match frozen {
            Some(c) => HingeCoefficient::Frozen(F64x4(c)),
            None => HingeCoefficient::Model(model),
        };
        gauss_newton_into(&rests, x, coefficient, out)
    }

    /// Energy, gradient and Hessian for a frozen coefficient (zero for a [`Self::crushed`]
    /// hinge).
    pub fn derivatives(
        &self,
        x: &[Vector3<f64>; 4],
        coefficient: f64,
        hessian: BendingHessian,
    ) -> ElementDerivatives<4> {
        if self.crushed(x) {
            return ElementDerivatives::default();
        }
        if hessian == BendingHessian::GaussNewton {
            return self.gauss_newton(x, coefficient).map_or_else(
                ElementDerivatives::default,
                |gn| ElementDerivatives {
                    energy_j: gn.energy_j,
                    gradient: gn.gradient,
                    hessian: std::array::from_fn(|a| std::array::from_fn(|b| gn.block(a, b))),
                },
            );
        }
        let Some(theta) = dihedral_angle_derivatives(x) else {
            return ElementDerivatives::default();
        };
        let d = theta.v - self.rest_angle_rad;
        let g = theta.g * (2.0 * coefficient * d);
        let h = match hessian {
            BendingHessian::GaussNewton => theta.g * theta.g.transpose() * (2.0 * coefficient),
            BendingHessian::Exact | BendingHessian::ProjectedExact => {
                let exact = (theta.g * theta.g.transpose() + theta.h * d) * (2.0 * coefficient);
                if hessian == BendingHessian::ProjectedExact {
                    project_psd(&exact)
                } else {
                    exact
                }
            }
        };
        let (gradient, mut hess): ([Vector3<f64>; 4], [[Matrix3<f64>; 4]; 4]) =
            expand_to_vertices(&g, &h, 0, [1, 2, 3]);
        // The blocks below the diagonal as the transposes of those above (they differ in the
        // last bits otherwise): the assembled system is symmetric bit for bit.
        for a in 0..4 {
            for b in 0..a {
                hess[a][b] = hess[b][a].transpose();
            }
        }
        ElementDerivatives {
            energy_j: coefficient * d * d,
            gradient,
            hessian: hess,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gradient_only_angle_is_bitwise_the_full_one() {
        // Hinges from flat to folded, regular to sliver, seeded by a simple LCG.
        let mut next = crate::energy::uniform(0x2545_F491_4F6C_DD1D);
        for _ in 0..500 {
            let x: [Vector3<f64>; 4] =
                std::array::from_fn(|_| Vector3::new(next(), next(), next()) * 0.02);
            let full = dihedral_angle_derivatives(&x);
            let fast = dihedral_angle_gradient(&x);
            if let Some((v, _)) = fast {
                // The angle `coefficient` freezes is the one the Gauss–Newton step uses.
                assert_eq!(dihedral_angle(&x).to_bits(), v.to_bits());
            }
            match (full, fast) {
                (Some(full), Some((v, g))) => {
                    assert_eq!(full.v.to_bits(), v.to_bits());
                    assert!(
                        full.g
                            .iter()
                            .zip(g.iter())
                            .all(|(a, b)| a.to_bits() == b.to_bits())
                    );
                }
                (None, None) => {}
                _ => panic!("one of the two gave up on {x:?}"),
            }
        }
    }

    #[test]
    fn the_step_s_first_hinge_is_bitwise_the_frozen_one() {
        // Gray interlock's tabulated bending (ke depends on θ and l): coefficient frozen at x
        // and used at x, against the two calls the frozen path makes.
        let material = crate::material::Material::gray_interlock();
        let model = material.bending();
        let mut next = crate::energy::uniform(0x9E37_79B9_7F4A_7C15);
        let mut compared = 0;
        for k in 0..500 {
            let x: [Vector3<f64>; 4] =
                std::array::from_fn(|_| Vector3::new(next(), next(), next()) * 0.02);
            let hinge = BendingRest {
                vertices: [0, 1, 2, 3],
                rest_angle_rad: next(),
                area_sum_m2: 2e-4 * (1.0 + next()),
                edge_angle_rad: [next() * 7.0, next() * 7.0],
            };
            // Flat-ish hinges too, where θ is small and the table's lower rows are used.
            let x = if k % 2 == 0 {
                x.map(|p| Vector3::new(p.x, p.y, p.z * 0.01))
            } else {
                x
            };
            let frozen = hinge.gauss_newton(&x, hinge.coefficient(&x, model));
            let here = hinge.gauss_newton_frozen_here(&x, model);
            match (frozen, here) {
                (Some(a), Some(b)) => {
                    assert_eq!(bits(&a), bits(&b), "hinge {k}");
                    compared += 1;
                }
                (None, None) => {}
                _ => panic!("one of the two gave up on {x:?}"),
            }
        }
        assert!(compared > 400, "{compared}");
    }

    /// Every bit of a hinge's Gauss–Newton derivatives.
    fn bits(h: &GaussNewtonHinge) -> Vec<u64> {
        let mut v = vec![h.energy_j.to_bits(), h.curvature.to_bits()];
        for g in h.gradient.iter().chain(&h.angle) {
            v.extend(g.iter().map(|c| c.to_bits()));
        }
        v
    }

    #[test]
    fn four_hinges_at_once_are_bitwise_each_alone() {
        // Random hinges, flat-ish ones, crushed ones (a tip on the edge's line) and degenerate
        // ones (a zero-length edge) mixed within each group of four; the tabulated bending
        // looked up per lane, and frozen coefficients given per lane.
        let material = crate::material::Material::gray_interlock();
        let model = material.bending();
        let mut next = crate::energy::uniform(0xD1B5_4A32_D192_ED03);
        let mut cases = Vec::new();
        for k in 0..600 {
            let mut x: [Vector3<f64>; 4] =
                std::array::from_fn(|_| Vector3::new(next(), next(), next()) * 0.02);
            match k % 5 {
                0 => x = x.map(|p| Vector3::new(p.x, p.y, p.z * 0.01)),
                1 => x[2] = x[0] + (x[1] - x[0]) * (0.5 + next()),
                2 if k % 3 == 0 => x[1] = x[0],
                _ => {}
            }
            let hinge = BendingRest {
                vertices: [0, 1, 2, 3],
                rest_angle_rad: next(),
                area_sum_m2: 2e-4 * (1.0 + next()),
                edge_angle_rad: [next() * 7.0, next() * 7.0],
            };
            cases.push((hinge, x));
        }
        let (mut missing, mut compared) = (0, 0);
        for group in cases.chunks_exact(4) {
            let x: [Vector3<F64x4>; 4] = std::array::from_fn(|v| {
                Vector3::from_fn(|c, _| F64x4(std::array::from_fn(|l| group[l].1[v][c])))
            });
            let rests = std::array::from_fn(|l| &group[l].0);
            let frozen: [f64; 4] =
                std::array::from_fn(|l| group[l].0.coefficient(&group[l].1, model));
            let (mut here, mut given) = Default::default();
            let has_here = BendingRest::gauss_newton_lanes(rests, &x, model, None, &mut here);
            let has_given =
                BendingRest::gauss_newton_lanes(rests, &x, model, Some(frozen), &mut given);
            for (l, (hinge, x)) in group.iter().enumerate() {
                let lane = |d: &GaussNewtonHinge<F64x4>| GaussNewtonHinge {
                    energy_j: d.energy_j.0[l],
                    gradient: d.gradient.map(|g| g.map(|c| c.0[l])),
                    angle: d.angle.map(|g| g.map(|c| c.0[l])),
                    curvature: d.curvature.0[l],
                };
                let alone = hinge.gauss_newton_frozen_here(x, model);
                assert_eq!(alone.is_some(), has_here[l], "lane {l} of {x:?}");
                if let Some(alone) = alone {
                    assert_eq!(bits(&lane(&here)), bits(&alone), "lane {l} of {x:?}");
                    compared += 1;
                } else {
                    missing += 1;
                }
                let alone = hinge.gauss_newton(x, frozen[l]);
                assert_eq!(alone.is_some(), has_given[l], "lane {l} of {x:?}");
                if let Some(alone) = alone {
                    assert_eq!(bits(&lane(&given)), bits(&alone), "lane {l} of {x:?}");
                }
            }
        }
        assert!(
            compared > 400 && missing > 50,
            "{compared} compared, {missing} missing"
        );
    }
}
