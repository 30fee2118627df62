//! Projection of small symmetric matrices onto the positive semi-definite cone (eigenvalues
//! clamped at zero), used to make element Hessians usable in the implicit solve.

use nalgebra::{Const, DimMin, Matrix2, SMatrix};

use super::lanes::Real;

/// The nearest (Frobenius) PSD matrix: eigen-decompose, clamp negative eigenvalues to 0.
/// Returns the (symmetrised) input when it is already PSD.
///
/// Entries below `1e-15 ×` the largest are flushed to zero first: nalgebra's symmetric eigen
/// solver returns NaNs on matrices mixing O(1) and ~1e-67 entries (seen on nearly flat hinges).
/// Should it still fail, the fallback shifts the matrix by its Gershgorin bound (PSD, never NaN).
pub fn project_psd<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N>
where
    Const<N>: DimMin<Const<N>, Output = Const<N>>,
    Const<N>: nalgebra::ToTypenum,
    Const<N>: nalgebra::DimSub<nalgebra::U1>,
    nalgebra::DefaultAllocator:
        nalgebra::allocator::Allocator<<Const<N> as nalgebra::DimSub<nalgebra::U1>>::Output>,
{
    let mut sym = (m + m.transpose()) * 0.5;
    let scale = sym.amax();
    if scale == 0.0 || !scale.is_finite() {
        return sym;
    }
    sym.iter_mut().for_each(|v| {
        if v.abs() < 1e-15 * scale {
            *v = 0.0;
        }
    });
    let eig = (sym / scale).symmetric_eigen();
    if eig.eigenvalues.iter().all(|l| l.is_finite())
        && eig.eigenvectors.iter().all(|v| v.is_finite())
    {
        if eig.eigenvalues.iter().all(|&l| l >= 0.0) {
            return sym;
        }
        let clamped = eig.eigenvalues.map(|l| l.max(0.0) * scale);
        return eig.eigenvectors
            * SMatrix::<f64, N, N>::from_diagonal(&clamped)
            * eig.eigenvectors.transpose();
    }
    // Gershgorin: every eigenvalue ≥ min_i (a_ii − Σ_{j≠i} |a_ij|).
    let lower = (0..N)
        .map(|i| {
            sym[(i, i)]
                - (0..N)
                    .filter(|&j| j != i)
                    .map(|j| sym[(i, j)].abs())
                    .sum::<f64>()
        })
        .fold(f64::INFINITY, f64::min);
    for i in 0..N {
        sym[(i, i)] += (-lower).max(0.0);
    }
    sym
}

/// Closed-form PSD projection of a symmetric 2 × 2 matrix (of each lane's, for
/// [`crate::energy::F64x4`]: branches as selects, see [`crate::energy::Real`]).
#[inline(always)]
pub fn project_psd2<T: Real>(m: &Matrix2<T>) -> Matrix2<T> {
    let (zero, one) = (T::zero(), T::one());
    let half = T::splat(0.5);
    let (a, b, d) = (m[(0, 0)], half * (m[(0, 1)] + m[(1, 0)]), m[(1, 1)]);
    let mean = half * (a + d);
    let radius = (T::splat(0.25) * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = (mean + radius, mean - radius);
    // Keep l1 only: l1 · v vᵀ with v the unit eigenvector of l1 (`normalize`'s arithmetic).
    let (v0, v1) = (l1 - d, b);
    let norm = (v0 * v0 + v1 * v1).sqrt();
    let b_nonzero = b.abs().gt(zero);
    let a_first = a.ge(d);
    let v = [
        T::select(b_nonzero, v0 / norm, T::select(a_first, one, zero)),
        T::select(b_nonzero, v1 / norm, T::select(a_first, zero, one)),
    ];
    // Both eigenvalues ≥ 0: the matrix itself; both ≤ 0: zero.
    let (keep, drop) = (l2.ge(zero), l1.le(zero));
    let pick =
        |i: usize, j: usize, own: T| T::select(keep, own, T::select(drop, zero, v[i] * v[j] * l1));
    Matrix2::new(pick(0, 0, a), pick(0, 1, b), pick(1, 0, b), pick(1, 1, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    #[test]
    fn projections_are_psd_and_idempotent() {
        let m = Matrix2::new(1.0, 3.0, 3.0, -2.0);
        let p = project_psd2(&m);
        let eig = p.symmetric_eigen();
        assert!(eig.eigenvalues.iter().all(|&l| l > -1e-12));
        assert!((project_psd2(&p) - p).norm() < 1e-12);
        let generic = project_psd(&m);
        assert!((generic - p).norm() < 1e-12, "{generic} vs {p}");
        let m3 = Matrix3::new(2.0, 1.0, 0.0, 1.0, -1.0, 0.5, 0.0, 0.5, 0.3);
        let p3 = project_psd(&m3);
        assert!(p3.symmetric_eigen().eigenvalues.iter().all(|&l| l > -1e-12));
        assert_eq!(
            project_psd(&Matrix3::<f64>::identity()),
            Matrix3::identity()
        );
        // Mixed magnitudes that make nalgebra's eigen solver return NaN without the flush.
        let mut tiny = SMatrix::<f64, 4, 4>::zeros();
        tiny[(0, 0)] = 9.356e-67;
        tiny[(0, 1)] = 2.97e-34;
        tiny[(1, 0)] = 2.97e-34;
        tiny[(1, 1)] = 9.4464e-2;
        tiny[(1, 2)] = -4.7232e-2;
        tiny[(2, 1)] = -4.7232e-2;
        tiny[(2, 2)] = 2.3616e-2;
        assert!(project_psd(&tiny).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn four_projections_at_once_are_bitwise_each_alone() {
        use crate::energy::F64x4;
        // Every branch: PSD, negative semi-definite, indefinite with a coupling, and
        // indefinite without one (either diagonal entry the larger).
        let cases = [
            Matrix2::new(2.0, 0.5, 0.5, 1.0),
            Matrix2::new(-2.0, 0.5, 0.5, -1.0),
            Matrix2::new(1.0, 3.0, 3.0, -2.0),
            Matrix2::new(3.0, 0.0, 0.0, -1.0),
            Matrix2::new(-1.0, 0.0, 0.0, 2.0),
            Matrix2::new(0.0, 0.0, 0.0, 0.0),
            Matrix2::new(-4.0, 1e-9, 1e-9, 1e-3),
            Matrix2::new(1e-3, -2.0, -2.0, 1e-3),
        ];
        assert_eq!(project_psd2(&cases[3]), Matrix2::new(3.0, 0.0, 0.0, 0.0));
        assert_eq!(project_psd2(&cases[4]), Matrix2::new(0.0, 0.0, 0.0, 2.0));
        assert_eq!(project_psd2(&cases[1]), Matrix2::zeros());
        for group in cases.chunks_exact(4) {
            let lanes = Matrix2::from_fn(|r, c| F64x4(std::array::from_fn(|l| group[l][(r, c)])));
            let projected = project_psd2(&lanes);
            for (l, m) in group.iter().enumerate() {
                let alone = project_psd2(m);
                for (a, b) in projected.iter().zip(alone.iter()) {
                    assert_eq!(a.0[l].to_bits(), b.to_bits(), "{m}");
                }
            }
        }
    }
}
