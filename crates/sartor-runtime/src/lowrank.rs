//! Truncated SVD of a dense output layer, computed once at load for a reduced level of detail:
//! `W ≈ A·B` with `A = U_r Σ_r` (`rows × r`) and `B = V_rᵀ` (`r × cols`), so the `3V × H`
//! product becomes `3V × r` + `r × H` multiply–adds.
//!
//! The factorisation is sartor-core's one randomized SVD ([`sartor_core::rsvd`]); its large
//! products run on this crate's own batched kernels (every column of the random block is an
//! "avatar" sharing one pass over the weights). For a matrix whose spectrum decays (a trained
//! output layer) the result is within a few per cent of the optimal rank-`r` error; the unit
//! test checks it against a full SVD.

use nalgebra::DMatrix;
use sartor_core::rsvd::{LinearOperator, randomized_svd};

use crate::error::{Error, Result};
use crate::kernels::{Matrix, Parallelism, Precision};

/// Seed of the random test matrix (fixed: the same weights give the same factors).
const SEED: u64 = 0x5a17_0e5e_ed00_0001;

/// A rank-`r` factorisation `W ≈ left · right`.
#[derive(Clone, Debug, PartialEq)]
pub struct LowRank {
    /// Rank `r`.
    pub rank: usize,
    /// `U_r Σ_r`, row-major `[rows, r]`.
    pub left: Vec<f32>,
    /// `V_rᵀ`, row-major `[r, cols]`.
    pub right: Vec<f32>,
    /// The `r` largest singular values (estimates), descending.
    pub singular_values: Vec<f64>,
}

/// `W` and `Wᵀ` on the batched f32 kernels: the SVD's operator.
struct Kernels {
    forward: Matrix,
    backward: Matrix,
}

/// `matrix · x` for a block `x` of column vectors, on the batched kernels.
fn product(matrix: &Matrix, x: &DMatrix<f64>) -> sartor_core::Result<DMatrix<f64>> {
    let (batch, n_out) = (x.ncols(), matrix.rows());
    // One input vector per row: the kernels' "avatar" layout.
    // (nalgebra stores columns contiguously, so `x`'s storage is exactly that.)
    let xs: Vec<f32> = x.iter().map(|&v| v as f32).collect();
    let mut ys = vec![0.0f32; n_out * batch];
    matrix
        .matmul_t(&xs, batch, None, &mut ys, Parallelism::Rayon)
        .map_err(|e| sartor_core::Error::invalid("low-rank product", e.to_string()))?;
    Ok(DMatrix::from_fn(n_out, batch, |r, c| {
        ys[r * batch + c] as f64
    }))
}

impl LinearOperator for Kernels {
    fn rows(&self) -> usize {
        self.forward.rows()
    }
    fn cols(&self) -> usize {
        self.forward.cols()
    }
    fn apply(&self, x: &DMatrix<f64>) -> sartor_core::Result<DMatrix<f64>> {
        product(&self.forward, x)
    }
    fn apply_transpose(&self, y: &DMatrix<f64>) -> sartor_core::Result<DMatrix<f64>> {
        product(&self.backward, y)
    }
}

/// The best rank-`rank` approximation of the row-major `rows × cols` matrix `w` (see the module
/// docs). Deterministic. Errors when `rank` is 0 or above `min(rows, cols)`, or `w` has the wrong
/// length or a non-finite value.
pub fn truncated_svd(w: &[f32], rows: usize, cols: usize, rank: usize) -> Result<LowRank> {
    let full = rows.min(cols);
    if rank == 0 || rank > full {
        return Err(Error::invalid(
            "output rank",
            format!("{rank} is not in 1..={full} for a {rows} × {cols} matrix"),
        ));
    }
    let forward = Matrix::from_f32(rows, cols, w.to_vec(), Precision::F32)?;
    let mut wt = vec![0.0f32; w.len()];
    for r in 0..rows {
        for c in 0..cols {
            wt[c * rows + r] = w[r * cols + c];
        }
    }
    let backward = Matrix::from_f32(cols, rows, wt, Precision::F32)?;
    let svd = randomized_svd(&Kernels { forward, backward }, rank, SEED)?;
    let left = (0..rows * rank)
        .map(|i| (svd.u[(i / rank, i % rank)] * svd.singular_values[i % rank]) as f32)
        .collect();
    let right = (0..rank * cols)
        .map(|i| svd.v_t[(i / cols, i % cols)] as f32)
        .collect();
    Ok(LowRank {
        rank,
        left,
        right,
        singular_values: svd.singular_values,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded uniform source in `[-1, 1)` for the test matrix.
    struct SplitMix(u64);

    impl SplitMix {
        fn next_unit(&mut self) -> f32 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^= z >> 31;
            ((z >> 40) as f32 / (1u64 << 23) as f32) - 1.0
        }
    }

    /// A `rows × cols` matrix with singular values `0.7^k` (plus a little noise).
    fn decaying(rows: usize, cols: usize) -> Vec<f32> {
        let mut rng = SplitMix(7);
        let mut u = DMatrix::<f64>::from_fn(rows, cols.min(rows), |_, _| rng.next_unit() as f64);
        u = u.qr().q();
        let mut v = DMatrix::<f64>::from_fn(cols, cols.min(rows), |_, _| rng.next_unit() as f64);
        v = v.qr().q();
        let n = cols.min(rows);
        let s = DMatrix::<f64>::from_diagonal(&nalgebra::DVector::from_fn(n, |k, _| {
            0.7f64.powi(k as i32)
        }));
        let m = u * s * v.transpose();
        (0..rows * cols)
            .map(|i| (m[(i / cols, i % cols)] + 1e-4 * rng.next_unit() as f64) as f32)
            .collect()
    }

    #[test]
    fn close_to_the_optimal_rank_r_error() {
        let (rows, cols, rank) = (300, 80, 12);
        let w = decaying(rows, cols);
        let lr = truncated_svd(&w, rows, cols, rank).expect("valid");
        let m = DMatrix::<f64>::from_row_slice(
            rows,
            cols,
            &w.iter().map(|&v| v as f64).collect::<Vec<_>>(),
        );
        let mut sv: Vec<f64> = m.singular_values().iter().copied().collect();
        sv.sort_by(|a, b| b.total_cmp(a));
        let optimal: f64 = sv[rank..].iter().map(|s| s * s).sum::<f64>().sqrt();
        let mut err2 = 0.0f64;
        for r in 0..rows {
            for c in 0..cols {
                let approx: f64 = (0..rank)
                    .map(|k| lr.left[r * rank + k] as f64 * lr.right[k * cols + c] as f64)
                    .sum();
                err2 += (approx - w[r * cols + c] as f64).powi(2);
            }
        }
        let err = err2.sqrt();
        assert!(err <= 1.02 * optimal + 1e-5, "{err} vs optimal {optimal}");
        for k in 0..rank {
            assert!(
                (lr.singular_values[k] - sv[k]).abs() < 1e-3 * sv[0],
                "σ_{k}"
            );
        }
        // Full rank reproduces the matrix.
        let exact = truncated_svd(&w, rows, cols, cols).expect("valid");
        let max_err = (0..rows * cols)
            .map(|i| {
                let (r, c) = (i / cols, i % cols);
                let a: f64 = (0..cols)
                    .map(|k| exact.left[r * cols + k] as f64 * exact.right[k * cols + c] as f64)
                    .sum();
                (a - w[i] as f64).abs()
            })
            .fold(0.0, f64::max);
        assert!(max_err < 1e-5, "{max_err}");
    }

    #[test]
    fn bad_ranks_are_errors() {
        let w = vec![1.0f32; 12];
        assert!(truncated_svd(&w, 3, 4, 0).is_err());
        assert!(truncated_svd(&w, 3, 4, 4).is_err());
        assert!(truncated_svd(&w[..11], 3, 4, 2).is_err());
    }
}
