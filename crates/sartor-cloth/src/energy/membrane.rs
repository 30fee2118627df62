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

use nalgebra::{Matrix2, Matrix3, Matrix3x2, Vector3};

use super::diff::dot3;
use super::lanes::{F64x4, Real};
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

/// Energy, gradient and Hessian (3 × 3 blocks) of one element with `N` vertices (of four
/// elements side by side for `T` = [`F64x4`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElementDerivatives<const N: usize, T = f64> {
    /// Energy, J.
    pub energy_j: T,
    /// `∂E/∂x_i`, N.
    pub gradient: [Vector3<T>; N],
    /// `∂²E/∂x_i∂x_j`, N/m.
    pub hessian: [[Matrix3<T>; N]; N],
}

impl<const N: usize, T: Real> Default for ElementDerivatives<N, T> {
    fn default() -> Self {
        Self {
            energy_j: T::zero(),
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

    /// Deformation gradient (3 × 2).
    pub fn deformation_gradient(&self, x: &[Vector3<f64>; 3]) -> Matrix3x2<f64> {
        let [fu, fv] = deformation_gradient(&weights(&self.inv_dm), x);
        Matrix3x2::from_columns(&[fu, fv])
    }

    /// Green strain `G = ½ (FᵀF − I)` in the material frame.
    pub fn green_strain(&self, x: &[Vector3<f64>; 3]) -> Matrix2<f64> {
        let [fu, fv] = deformation_gradient(&weights(&self.inv_dm), x);
        green_strain(&fu, &fv)
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
        self.derivatives_with(x, Stiffness::Frozen(*k), projection)
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
        stiffness: Stiffness<'_, f64>,
        projection: Projection,
    ) -> ElementDerivatives<3> {
        let mut out = ElementDerivatives::default();
        derivatives_with(
            &self.inv_dm,
            self.area_m2,
            x,
            stiffness,
            projection,
            &mut out,
        );
        out
    }

    /// [`Self::derivatives_frozen_here`] (`frozen` = `None`) or [`Self::derivatives`]
    /// (`frozen` = the four stiffnesses) of four triangles at once, each lane bitwise what
    /// its triangle gives alone (see [`crate::energy::Real`]).
    #[inline(always)]
    pub fn derivatives_lanes(
        rests: [&Self; 4],
        x: &[Vector3<F64x4>; 3],
        model: &MembraneModel,
        frozen: Option<[&StrainStiffness; 4]>,
        projection: Projection,
        out: &mut ElementDerivatives<3, F64x4>,
    ) {
        let entry = |r: usize, c: usize| F64x4(rests.map(|m| m.inv_dm[(r, c)]));
        let inv_dm = Matrix2::new(entry(0, 0), entry(0, 1), entry(1, 0), entry(1, 1));
        let area = F64x4(rests.map(|m| m.area_m2));
        let stiffness = match frozen {
            Some(k) => Stiffness::Frozen(StrainStiffness::lanes(k)),
            None => Stiffness::Model(model),
        };
        derivatives_with(&inv_dm, area, x, stiffness, projection, out);
    }
}

/// Shape-function gradients `w_i` (rows of `[−1ᵀ Dm⁻¹; Dm⁻¹]`): `F = Σ_i x_i w_iᵀ`.
#[inline(always)]
fn weights<T: Real>(inv_dm: &Matrix2<T>) -> [[T; 2]; 3] {
    let p = inv_dm;
    let (w1, w2) = ([p[(0, 0)], p[(0, 1)]], [p[(1, 0)], p[(1, 1)]]);
    [[-(w1[0] + w2[0]), -(w1[1] + w2[1])], w1, w2]
}

/// Deformation gradient (3 × 2) for the shape-function gradients `w`: its columns `fu`, `fv`.
///
/// The arithmetic below is written out, in the order nalgebra's products take (`Σ_k` from
/// `k = 0`, a sum starting from `0`), rather than left to nalgebra: on [`F64x4`] its generic
/// products and temporaries are not inlined into the assembly's AVX2 build.
#[inline(always)]
fn deformation_gradient<T: Real>(w: &[[T; 2]; 3], x: &[Vector3<T>; 3]) -> [Vector3<T>; 2] {
    let mut f = [Vector3::zeros(); 2];
    for (c, column) in f.iter_mut().enumerate() {
        for r in 0..3 {
            for i in 0..3 {
                column[r] += x[i][r] * w[i][c];
            }
        }
    }
    f
}

/// Green strain `G = ½ (FᵀF − I)` from the columns `fu`, `fv` of `F` (nalgebra's order; the one
/// formula of [`MembraneRest::green_strain`] and the derivatives).
#[inline(always)]
fn green_strain<T: Real>(fu: &Vector3<T>, fv: &Vector3<T>) -> Matrix2<T> {
    let (one, half) = (T::one(), T::splat(0.5));
    let (ff00, ff01, ff11) = (dot3(fu, fu), dot3(fu, fv), dot3(fv, fv));
    // `FᵀF − I` subtracts 0 off the diagonal, which changes nothing.
    let off = ff01 * half;
    Matrix2::new((ff00 - one) * half, off, off, (ff11 - one) * half)
}

/// Energy, gradient and Hessian of a triangle with rest data `inv_dm`, `area` at `x` (of four
/// side by side for [`F64x4`]), into `out`.
#[inline(always)]
fn derivatives_with<T: Real>(
    inv_dm: &Matrix2<T>,
    area: T,
    x: &[Vector3<T>; 3],
    stiffness: Stiffness<'_, T>,
    projection: Projection,
    out: &mut ElementDerivatives<3, T>,
) {
    let (zero, half) = (T::zero(), T::splat(0.5));
    let w = weights(inv_dm);
    let [fu, fv] = deformation_gradient(&w, x);
    let g = green_strain(&fu, &fv);
    let k = &match stiffness {
        Stiffness::Frozen(k) => k,
        Stiffness::Model(model) => model.stiffness_lanes(&g),
    };
    let a = area;
    let s = k.stress(&g);
    // ∂g_m/∂x_i for g = (G00, G11, G01).
    let mut dg = [[[zero; 3]; 3]; 3];
    for i in 0..3 {
        let [wu, wv] = w[i];
        for r in 0..3 {
            dg[i][0][r] = fu[r] * wu;
            dg[i][1][r] = fv[r] * wv;
            dg[i][2][r] = (fv[r] * wu + fu[r] * wv) * half;
        }
    }
    out.energy_j = a * k.energy_density(&g);
    // ∂ψ/∂g = (S00, S11, 2 S01) (G01 appears once in g but twice in G).
    let dpsi = [s[(0, 0)], s[(1, 1)], T::splat(2.0) * s[(0, 1)]];
    for i in 0..3 {
        let d = &dg[i];
        for r in 0..3 {
            out.gradient[i][r] = (d[0][r] * dpsi[0] + d[1][r] * dpsi[1] + d[2][r] * dpsi[2]) * a;
        }
    }
    // Stiffness of g: [[k_uu, k_uv, 0], [k_uv, k_vv, 0], [0, 0, k_shear]].
    let mut kblock = Matrix2::new(k.k_uu, k.k_uv, k.k_uv, k.k_vv);
    let mut k_shear = k.k_shear;
    let mut stress = s;
    if projection == Projection::Psd {
        kblock = project_psd2(&kblock);
        k_shear = k_shear.max(zero);
        stress = project_psd2(&s);
    }
    // The blocks on and above the diagonal; those below are their transposes, so that
    // the assembled system is symmetric bit for bit (the CG loop stores one triangle).
    for i in 0..3 {
        for j in i..3 {
            let (di, dj) = (&dg[i], &dg[j]);
            let (mut u, mut v) = ([zero; 3], [zero; 3]);
            for c in 0..3 {
                u[c] = dj[0][c] * kblock[(0, 0)] + dj[1][c] * kblock[(0, 1)];
                v[c] = dj[0][c] * kblock[(1, 0)] + dj[1][c] * kblock[(1, 1)];
            }
            // wᵢ · (S wⱼ).
            let sw = [
                stress[(0, 0)] * w[j][0] + stress[(0, 1)] * w[j][1],
                stress[(1, 0)] * w[j][0] + stress[(1, 1)] * w[j][1],
            ];
            let geometric = w[i][0] * sw[0] + w[i][1] * sw[1];
            // `I · geometric` adds `0 · geometric` off the diagonal (a signed zero).
            let off = zero * geometric;
            // Entry by entry into place (nalgebra's constructors from closures are not
            // inlined on `F64x4`): block (i, j), and its transpose as block (j, i), which for
            // a diagonal block replaces it (the blocks' symmetry exact, as the sum is not).
            for r in 0..3 {
                for c in 0..3 {
                    let sum = di[0][r] * u[c] + di[1][r] * v[c] + di[2][r] * dj[2][c] * k_shear;
                    let h = (sum + if r == c { geometric } else { off }) * a;
                    if i != j {
                        out.hessian[i][j][(r, c)] = h;
                    }
                    out.hessian[j][i][(c, r)] = h;
                }
            }
        }
    }
}

/// Where [`derivatives_with`] takes the stiffness from (an enum, not a closure: a closure's
/// body is compiled apart, and the step's assembly wants it inlined into its AVX2 build; see
/// `crate::isa`).
#[derive(Clone, Copy)]
enum Stiffness<'a, T> {
    /// Frozen at these values.
    Frozen(StrainStiffness<T>),
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
            assert_eq!(bits(&frozen), bits(&here), "triangle {k}");
        }
    }

    /// Every bit of an element's energy, gradient and Hessian.
    fn bits(d: &ElementDerivatives<3>) -> Vec<u64> {
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
    }

    #[test]
    fn four_triangles_at_once_are_bitwise_each_alone() {
        // Rest shapes and deformations from crushed and inverted to stretched, sheared and
        // axis-aligned (G01 = 0 exactly: the projections' zero off-diagonal branch), with the
        // tabulated membrane looked up per lane and frozen stiffnesses given per lane.
        let material = Material::gray_interlock();
        let model = material.membrane();
        let mut next = crate::energy::uniform(0x9E37_79B9_7F4A_7C15);
        let mut cases = Vec::new();
        for k in 0..400 {
            let rest_x = [
                Vector3::zeros(),
                Vector3::new(0.012 + 0.008 * next(), 0.0, 0.0),
                Vector3::new(0.004 * next(), 0.011 + 0.008 * next(), 0.0),
            ];
            let rest = MembraneRest::new(&rest_x, &Vector3::x(), &Vector3::y())
                .expect("a proper triangle");
            let x = match k % 4 {
                // Axis-aligned stretch or compression.
                0 => {
                    let (su, sv) = (1.0 + 0.6 * next(), 1.0 + 0.6 * next());
                    rest_x.map(|p| Vector3::new(p.x * su, p.y * sv, 0.0))
                }
                // Inverted (mirrored across u).
                1 => rest_x.map(|p| Vector3::new(p.x, -p.y * (1.0 + next()), next() * 0.002)),
                // Crushed to nearly a segment.
                2 => rest_x.map(|p| Vector3::new(p.x, p.y * 0.01 * next(), p.y * 0.01 * next())),
                _ => rest_x.map(|p| {
                    p * (1.0 + 0.5 * next()) + Vector3::new(next(), next(), next()) * 0.004
                }),
            };
            cases.push((rest, x));
        }
        for projection in [Projection::Psd, Projection::Exact] {
            for group in cases.chunks_exact(4) {
                let x: [Vector3<F64x4>; 3] = std::array::from_fn(|v| {
                    Vector3::from_fn(|c, _| F64x4(std::array::from_fn(|l| group[l].1[v][c])))
                });
                let rests = std::array::from_fn(|l| &group[l].0);
                let frozen: [StrainStiffness; 4] =
                    std::array::from_fn(|l| model.stiffness(&group[l].0.green_strain(&group[l].1)));
                let (mut here, mut given) = Default::default();
                MembraneRest::derivatives_lanes(rests, &x, model, None, projection, &mut here);
                MembraneRest::derivatives_lanes(
                    rests,
                    &x,
                    model,
                    Some(std::array::from_fn(|l| &frozen[l])),
                    projection,
                    &mut given,
                );
                for (l, (rest, x)) in group.iter().enumerate() {
                    let lane = |d: &ElementDerivatives<3, F64x4>| ElementDerivatives::<3> {
                        energy_j: d.energy_j.0[l],
                        gradient: d.gradient.map(|g| g.map(|c| c.0[l])),
                        hessian: d.hessian.map(|r| r.map(|h| h.map(|c| c.0[l]))),
                    };
                    let alone = rest.derivatives_frozen_here(x, model, projection);
                    assert_eq!(bits(&lane(&here)), bits(&alone), "{projection:?} lane {l}");
                    let alone = rest.derivatives(x, &frozen[l], projection);
                    assert_eq!(bits(&lane(&given)), bits(&alone), "{projection:?} lane {l}");
                }
            }
        }
    }
}
