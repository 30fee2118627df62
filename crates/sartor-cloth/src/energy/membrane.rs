//! Membrane (in-plane) energy of one triangle.
//!
//! `E = A · ψ(G)` with `A` the rest area, `F = Ds Dm⁻¹` (3 × 2: `Ds = [x1 − x0, x2 − x0]`,
//! `Dm` the rest edge vectors in the triangle's material frame), `G = ½ (FᵀF − I)` and ψ the
//! quadratic form of [`StrainStiffness`] (frozen for the step; see [`crate::material`]).
//!
//! With `fu, fv` the columns of `F` and `F = Σ_i x_i w_iᵀ` (`w_i` = row `i` of
//! `[−1ᵀ Dm⁻¹; Dm⁻¹]`): `∂G00/∂x_i = w_i0 fu`, `∂G11/∂x_i = w_i1 fv`,
//! `∂G01/∂x_i = ½ (w_i0 fv + w_i1 fu)`, and the exact Hessian is
//!
//! ```text
//! H_ij = A [ Σ_mn K_mn ∂g_m/∂x_i ∂g_n/∂x_jᵀ  +  (w_iᵀ S w_j) I ]
//! ```
//!
//! (`K` the 3 × 3 stiffness of `g = (G00, G11, G01)`, `S` the 2 × 2 stress). Its PSD projection
//! ([`Projection::Psd`]) replaces `K` and `S` by their PSD projections (eigenvalues clamped at
//! zero): both terms are then PSD. This is exact whenever the triangle is in tension (`S ⪰ 0`)
//! and costs two 2 × 2 eigen-decompositions, instead of a 9 × 9 one. (ARCSim keeps the
//! `max(G00, 0)`, `max(G11, 0)` diagonal terms and drops the `G01` term, a cruder version of
//! the same idea.)

use nalgebra::{Matrix2, Matrix3, Matrix3x2, Vector2, Vector3};

use super::psd::project_psd2;
use crate::material::{MembraneModel, StrainStiffness};

/// Rest data of one triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MembraneRest {
    /// Inverse of the rest edge matrix `Dm = [x1 − x0, x2 − x0]` in the material frame.
    pub inv_dm: Matrix2<f64>,
    /// Rest area, m².
    pub area_m2: f64,
}

/// Whether a Hessian is exact or projected to be positive semi-definite.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Projection {
    /// The exact Hessian of the (frozen-stiffness) energy.
    Exact,
    /// A PSD approximation, for the implicit solve.
    #[default]
    Psd,
}

/// Energy, gradient and Hessian (3 × 3 blocks) of one element with `N` vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElementDerivatives<const N: usize> {
    /// Energy, J.
    pub energy_j: f64,
    /// `∂E/∂x_i`, N.
    pub gradient: [Vector3<f64>; N],
    /// `∂²E/∂x_i∂x_j`, N/m.
    pub hessian: [[Matrix3<f64>; N]; N],
}

impl<const N: usize> Default for ElementDerivatives<N> {
    fn default() -> Self {
        Self {
            energy_j: 0.0,
            gradient: [Vector3::zeros(); N],
            hessian: [[Matrix3::zeros(); N]; N],
        }
    }
}

impl MembraneRest {
    /// Rest data from the rest positions and the material frame (`u_axis`, `v_axis`: orthonormal
    /// tangents of the rest triangle). `None` if the triangle is degenerate in that frame.
    pub fn new(
        rest: &[Vector3<f64>; 3],
        u_axis: &Vector3<f64>,
        v_axis: &Vector3<f64>,
    ) -> Option<Self> {
        let (e1, e2) = (rest[1] - rest[0], rest[2] - rest[0]);
        let dm = Matrix2::new(
            u_axis.dot(&e1),
            u_axis.dot(&e2),
            v_axis.dot(&e1),
            v_axis.dot(&e2),
        );
        let area_m2 = 0.5 * dm.determinant().abs();
        let inv_dm = dm.try_inverse()?;
        (area_m2 > 0.0 && inv_dm.iter().all(|v| v.is_finite())).then_some(Self { inv_dm, area_m2 })
    }

    /// Shape-function gradients `w_i` (rows of `[−1ᵀ Dm⁻¹; Dm⁻¹]`): `F = Σ_i x_i w_iᵀ`.
    fn weights(&self) -> [Vector2<f64>; 3] {
        let p = &self.inv_dm;
        let w1 = Vector2::new(p[(0, 0)], p[(0, 1)]);
        let w2 = Vector2::new(p[(1, 0)], p[(1, 1)]);
        [-(w1 + w2), w1, w2]
    }

    /// Deformation gradient (3 × 2).
    pub fn deformation_gradient(&self, x: &[Vector3<f64>; 3]) -> Matrix3x2<f64> {
        let w = self.weights();
        let mut f = Matrix3x2::zeros();
        for i in 0..3 {
            f += x[i] * w[i].transpose();
        }
        f
    }

    /// Green strain `G = ½ (FᵀF − I)` in the material frame.
    pub fn green_strain(&self, x: &[Vector3<f64>; 3]) -> Matrix2<f64> {
        let f = self.deformation_gradient(x);
        (f.transpose() * f - Matrix2::identity()) * 0.5
    }

    /// Energy `A ψ(G)` for a given (frozen) stiffness, J.
    pub fn energy(&self, x: &[Vector3<f64>; 3], k: &StrainStiffness) -> f64 {
        self.area_m2 * k.energy_density(&self.green_strain(x))
    }

    /// Energy, gradient and Hessian for a given (frozen) stiffness.
    #[inline(always)]
    pub fn derivatives(
        &self,
        x: &[Vector3<f64>; 3],
        k: &StrainStiffness,
        projection: Projection,
    ) -> ElementDerivatives<3> {
        self.derivatives_with(x, Stiffness::Frozen(k), projection)
    }

    /// [`Self::derivatives`] with the stiffness frozen at `x` itself, bitwise
    /// `derivatives(x, &model.stiffness(&green_strain(x)), projection)`: the strain is computed
    /// once for both. For the first Newton iteration of a step, whose linearisation point is
    /// the state the stiffness is frozen at.
    #[inline(always)]
    pub fn derivatives_frozen_here(
        &self,
        x: &[Vector3<f64>; 3],
        model: &MembraneModel,
        projection: Projection,
    ) -> ElementDerivatives<3> {
        self.derivatives_with(x, Stiffness::Model(model), projection)
    }

    /// [`Self::derivatives`] with the stiffness given by `stiffness` (at `G`).
    #[inline(always)]
    fn derivatives_with(
        &self,
        x: &[Vector3<f64>; 3],
        stiffness: Stiffness<'_>,
        projection: Projection,
    ) -> ElementDerivatives<3> {
        let w = self.weights();
        let f = self.deformation_gradient(x);
        let (fu, fv) = (f.column(0).into_owned(), f.column(1).into_owned());
        let g = (f.transpose() * f - Matrix2::identity()) * 0.5;
        let k = &match stiffness {
            Stiffness::Frozen(k) => *k,
            Stiffness::Model(model) => model.stiffness(&g),
        };
        let a = self.area_m2;
        let s = k.stress(&g);
        // ∂g_m/∂x_i for g = (G00, G11, G01).
        let dg: [[Vector3<f64>; 3]; 3] =
            std::array::from_fn(|i| [fu * w[i].x, fv * w[i].y, (fv * w[i].x + fu * w[i].y) * 0.5]);
        let mut out = ElementDerivatives::<3> {
            energy_j: a * k.energy_density(&g),
            ..Default::default()
        };
        // ∂ψ/∂g = (S00, S11, 2 S01) (G01 appears once in g but twice in G).
        let dpsi = [s[(0, 0)], s[(1, 1)], 2.0 * s[(0, 1)]];
        for i in 0..3 {
            out.gradient[i] = (dg[i][0] * dpsi[0] + dg[i][1] * dpsi[1] + dg[i][2] * dpsi[2]) * a;
        }
        // Stiffness of g: [[k_uu, k_uv, 0], [k_uv, k_vv, 0], [0, 0, k_shear]].
        let mut kblock = Matrix2::new(k.k_uu, k.k_uv, k.k_uv, k.k_vv);
        let mut k_shear = k.k_shear;
        let mut stress = s;
        if projection == Projection::Psd {
            kblock = project_psd2(&kblock);
            k_shear = k_shear.max(0.0);
            stress = project_psd2(&s);
        }
        // The blocks on and above the diagonal; those below are their transposes, so that
        // the assembled system is symmetric bit for bit (the CG loop stores one triangle).
        for i in 0..3 {
            for j in i..3 {
                let mut h = dg[i][0]
                    * (dg[j][0] * kblock[(0, 0)] + dg[j][1] * kblock[(0, 1)]).transpose()
                    + dg[i][1]
                        * (dg[j][0] * kblock[(1, 0)] + dg[j][1] * kblock[(1, 1)]).transpose()
                    + dg[i][2] * dg[j][2].transpose() * k_shear;
                let geometric = w[i].dot(&(stress * w[j]));
                h += Matrix3::identity() * geometric;
                out.hessian[i][j] = h * a;
                out.hessian[j][i] = out.hessian[i][j].transpose();
            }
        }
        out
    }
}

/// Where [`MembraneRest::derivatives_with`] takes the stiffness from (an enum, not a closure:
/// a closure's body is compiled apart, and the step's assembly wants it inlined into its
/// AVX2 build; see `crate::isa`).
#[derive(Clone, Copy)]
enum Stiffness<'a> {
    /// Frozen at these values.
    Frozen(&'a StrainStiffness),
    /// The model's at the element's strain `G`.
    Model(&'a MembraneModel),
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Material;

    #[test]
    fn the_step_s_first_triangle_is_bitwise_the_frozen_one() {
        // Gray interlock's tabulated membrane (stiffness depends on the strain), triangles from
        // compressed to stretched and sheared: stiffness frozen at x and used at x, against the
        // two calls the frozen path makes.
        let material = Material::gray_interlock();
        let model = material.membrane();
        let rest = MembraneRest::new(
            &[
                Vector3::zeros(),
                Vector3::new(0.012, 0.0, 0.0),
                Vector3::new(0.004, 0.011, 0.0),
            ],
            &Vector3::x(),
            &Vector3::y(),
        )
        .expect("a proper triangle");
        let mut next = crate::energy::uniform(0xD1B5_4A32_D192_ED03);
        for k in 0..300 {
            let stretch = 0.8 + 0.5 * (next() + 0.5);
            let x = [
                Vector3::new(next(), next(), next()) * 0.002,
                Vector3::new(0.012 * stretch, next() * 0.003, next() * 0.003),
                Vector3::new(0.004 + next() * 0.004, 0.011 * stretch, next() * 0.003),
            ];
            let frozen = rest.derivatives(
                &x,
                &model.stiffness(&rest.green_strain(&x)),
                Projection::Psd,
            );
            let here = rest.derivatives_frozen_here(&x, model, Projection::Psd);
            let bits = |d: &ElementDerivatives<3>| {
                let mut v = vec![d.energy_j.to_bits()];
                v.extend(
                    d.gradient
                        .iter()
                        .flat_map(|g| g.iter().map(|c| c.to_bits())),
                );
                v.extend(
                    d.hessian
                        .iter()
                        .flatten()
                        .flat_map(|h| h.iter().map(|c| c.to_bits())),
                );
                v
            };
            assert_eq!(bits(&frozen), bits(&here), "triangle {k}");
        }
    }
}
