//! Projection of small symmetric matrices onto the positive semi-definite cone (eigenvalues
//! clamped at zero), used to make element Hessians usable in the implicit solve.

use nalgebra::{Const, DimMin, Matrix2, SMatrix};

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

/// Closed-form PSD projection of a symmetric 2 × 2 matrix.
#[inline(always)]
pub fn project_psd2(m: &Matrix2<f64>) -> Matrix2<f64> {
    let (a, b, d) = (m[(0, 0)], 0.5 * (m[(0, 1)] + m[(1, 0)]), m[(1, 1)]);
    let mean = 0.5 * (a + d);
    let radius = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = (mean + radius, mean - radius);
    if l2 >= 0.0 {
        return Matrix2::new(a, b, b, d);
    }
    if l1 <= 0.0 {
        return Matrix2::zeros();
    }
    // Keep l1 only: l1 · v vᵀ with v the unit eigenvector of l1.
    let v = if b.abs() > 0.0 {
        nalgebra::Vector2::new(l1 - d, b).normalize()
    } else if a >= d {
        nalgebra::Vector2::new(1.0, 0.0)
    } else {
        nalgebra::Vector2::new(0.0, 1.0)
    };
    v * v.transpose() * l1
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
}
