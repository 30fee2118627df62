//! The one randomized SVD of sartor (Halko, Martinsson & Tropp 2011, Algorithms 4.4 and 5.1),
//! used for the dataset's PCA of the wrinkle displacements and for the runtime's low-rank
//! output layer.
//!
//! The matrix is never formed here: the caller gives it as a [`LinearOperator`] that multiplies
//! a block of vectors, so each side runs its products on its own kernels (nalgebra in the
//! dataset, the runtime's batched f32 kernels). Steps: `Y = A Ω` for a seeded uniform `Ω` with
//! `rank + OVERSAMPLE` columns, [`POWER_ITERATIONS`] rounds of `Q = qr(A qr(Aᵀ Q))`, then the
//! exact SVD of the small `B = Qᵀ A` (in f64). Deterministic for a given operator and seed.

use nalgebra::DMatrix;

use crate::{Error, Result};

/// Extra columns of the random test matrix beyond the rank asked for.
pub const OVERSAMPLE: usize = 10;
/// Power iterations (each one product with `Aᵀ` and one with `A`).
pub const POWER_ITERATIONS: usize = 2;

/// A `rows × cols` matrix `A`, known by its products with blocks of vectors.
pub trait LinearOperator {
    /// Rows of `A`.
    fn rows(&self) -> usize;
    /// Columns of `A`.
    fn cols(&self) -> usize;
    /// `A X` for `X` of `cols × l`; returns `rows × l`.
    fn apply(&self, x: &DMatrix<f64>) -> Result<DMatrix<f64>>;
    /// `Aᵀ Y` for `Y` of `rows × l`; returns `cols × l`.
    fn apply_transpose(&self, y: &DMatrix<f64>) -> Result<DMatrix<f64>>;
}

/// The leading singular triplets of `A`: `A ≈ U diag(σ) Vᵀ`.
#[derive(Clone, Debug, PartialEq)]
pub struct TruncatedSvd {
    /// Left singular vectors, `rows × rank`, orthonormal columns.
    pub u: DMatrix<f64>,
    /// Singular values, descending.
    pub singular_values: Vec<f64>,
    /// Right singular vectors transposed, `rank × cols`, orthonormal rows.
    pub v_t: DMatrix<f64>,
}

/// SplitMix64: a seeded, dependency-free source of uniform numbers in `[-1, 1)`.
struct SplitMix(u64);

impl SplitMix {
    fn next_unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

fn orthonormal(m: DMatrix<f64>) -> DMatrix<f64> {
    m.qr().q()
}

/// The best rank-`rank` approximation of `op` (see the module docs), with the random test
/// matrix drawn from `seed`. Errors when `rank` is 0 or above `min(rows, cols)`, when a product
/// has the wrong size, or when the result is not finite.
pub fn randomized_svd(op: &dyn LinearOperator, rank: usize, seed: u64) -> Result<TruncatedSvd> {
    let (rows, cols) = (op.rows(), op.cols());
    let full = rows.min(cols);
    if rank == 0 || rank > full {
        return Err(Error::invalid(
            "truncated SVD",
            format!("rank {rank} is not in 1..={full} for a {rows} × {cols} matrix"),
        ));
    }
    let l = (rank + OVERSAMPLE).min(full);
    let checked = |m: DMatrix<f64>, r: usize| {
        if m.nrows() != r || m.ncols() != l {
            return Err(Error::invalid(
                "truncated SVD",
                format!(
                    "a product has {} × {}, expected {r} × {l}",
                    m.nrows(),
                    m.ncols()
                ),
            ));
        }
        Ok(m)
    };
    let mut rng = SplitMix(seed);
    let omega = DMatrix::<f64>::from_fn(cols, l, |_, _| rng.next_unit());
    let mut q = orthonormal(checked(op.apply(&omega)?, rows)?);
    for _ in 0..POWER_ITERATIONS {
        let p = orthonormal(checked(op.apply_transpose(&q)?, cols)?);
        q = orthonormal(checked(op.apply(&p)?, rows)?);
    }
    // B = Qᵀ A = (Aᵀ Q)ᵀ, `l × cols`.
    let b = checked(op.apply_transpose(&q)?, cols)?.transpose();
    let svd = b.svd(true, true);
    let (Some(u_b), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(Error::invalid(
            "truncated SVD",
            "the small SVD did not converge",
        ));
    };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    order.truncate(rank);
    let u = &q * DMatrix::from_fn(u_b.nrows(), rank, |r, k| u_b[(r, order[k])]);
    let v_t = DMatrix::from_fn(rank, cols, |k, c| v_t[(order[k], c)]);
    let singular_values: Vec<f64> = order.iter().map(|&o| svd.singular_values[o]).collect();
    if u.iter().chain(v_t.iter()).any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "truncated SVD",
            "the result has a non-finite value",
        ));
    }
    Ok(TruncatedSvd {
        u,
        singular_values,
        v_t,
    })
}

/// A dense matrix as an operator (tests and small problems).
impl LinearOperator for DMatrix<f64> {
    fn rows(&self) -> usize {
        self.nrows()
    }
    fn cols(&self) -> usize {
        self.ncols()
    }
    fn apply(&self, x: &DMatrix<f64>) -> Result<DMatrix<f64>> {
        Ok(self * x)
    }
    fn apply_transpose(&self, y: &DMatrix<f64>) -> Result<DMatrix<f64>> {
        Ok(self.tr_mul(y))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix with singular values 1, 0.7, 0.49, … and random-looking singular vectors.
    fn decaying(rows: usize, cols: usize) -> DMatrix<f64> {
        let mut rng = SplitMix(7);
        let a = DMatrix::<f64>::from_fn(rows, rows, |_, _| rng.next_unit());
        let b = DMatrix::<f64>::from_fn(cols, cols, |_, _| rng.next_unit());
        let (u, v) = (a.qr().q(), b.qr().q());
        let k = rows.min(cols);
        let s = DMatrix::<f64>::from_fn(
            k,
            k,
            |i, j| if i == j { 0.7f64.powi(i as i32) } else { 0.0 },
        );
        u.columns(0, k) * s * v.columns(0, k).transpose()
    }

    #[test]
    fn matches_the_exact_svd_on_a_decaying_spectrum() {
        let a = decaying(60, 40);
        let exact = a.clone().svd(false, false).singular_values;
        let got = randomized_svd(&a, 8, 1).expect("svd");
        for (k, s) in got.singular_values.iter().enumerate() {
            assert!(
                (s - exact[k]).abs() < 1e-9 * exact[0],
                "σ{k}: {s} vs {}",
                exact[k]
            );
        }
        // The rank-8 reconstruction is as good as the optimal one.
        let approx =
            &got.u * DMatrix::from_diagonal(&got.singular_values.clone().into()) * &got.v_t;
        let err = (&a - approx).norm();
        let optimal: f64 = exact.iter().skip(8).map(|s| s * s).sum::<f64>().sqrt();
        assert!(err <= optimal * (1.0 + 1e-6), "{err} vs optimal {optimal}");
        // Orthonormal factors.
        let utu = got.u.tr_mul(&got.u);
        assert!((utu - DMatrix::identity(8, 8)).norm() < 1e-10);
    }

    #[test]
    fn is_deterministic_and_rejects_bad_ranks() {
        let a = decaying(20, 30);
        assert_eq!(
            randomized_svd(&a, 3, 5).unwrap(),
            randomized_svd(&a, 3, 5).unwrap()
        );
        assert!(randomized_svd(&a, 0, 5).is_err());
        assert!(randomized_svd(&a, 21, 5).is_err());
    }
}
