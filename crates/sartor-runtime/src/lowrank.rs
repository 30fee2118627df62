//! Truncated SVD of a dense output layer, computed once at load for a reduced level of detail:
//! `W ≈ A·B` with `A = U_r Σ_r` (`rows × r`) and `B = V_rᵀ` (`r × cols`), so the `3V × H`
//! product becomes `3V × r` + `r × H` multiply–adds.
//!
//! Randomised subspace iteration (Halko, Martinsson & Tropp 2011, Algorithms 4.4 and 5.1):
//! `Y = W Ω` for a seeded random `Ω` with `r + 10` columns, two power iterations with
//! re-orthonormalisation (`Q = qr(W qr(Wᵀ Q))`), then the exact SVD of the small `Qᵀ W`. The
//! large products run on the crate's own batched kernels (every column of `Ω` is an "avatar"
//! sharing one pass over the weights); the small QR and SVD use nalgebra in f64. For a matrix
//! whose spectrum decays (a trained output layer) the result is within a few per cent of the
//! optimal rank-`r` error; the unit test checks it against a full SVD.

use nalgebra::DMatrix;

use crate::error::{Error, Result};
use crate::kernels::{Matrix, Parallelism, Precision};

/// Extra columns of the random test matrix beyond the rank asked for.
const OVERSAMPLE: usize = 10;
/// Power iterations (each one pass over `Wᵀ` and one over `W`).
const POWER_ITERATIONS: usize = 2;

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

/// SplitMix64: a seeded, dependency-free source of uniform numbers in `[-1, 1)`.
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

/// Orthonormal columns spanning the `[n, l]` row-major `y` (thin Householder QR), returned
/// transposed: `[l, n]` row-major, i.e. one basis vector per row (the layout the batched
/// kernels take as inputs).
fn orthonormal_t(y: &[f32], n: usize, l: usize) -> Vec<f32> {
    let m = DMatrix::<f64>::from_row_slice(n, l, &y.iter().map(|&v| v as f64).collect::<Vec<_>>());
    let q = m.qr().q();
    let mut out = vec![0.0f32; l * n];
    for c in 0..l {
        for r in 0..n {
            out[c * n + r] = q[(r, c)] as f32;
        }
    }
    out
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
    let par = Parallelism::Rayon;
    let l = (rank + OVERSAMPLE).min(full);
    let forward = Matrix::from_f32(rows, cols, w.to_vec(), Precision::F32)?;
    let mut wt = vec![0.0f32; w.len()];
    for r in 0..rows {
        for c in 0..cols {
            wt[c * rows + r] = w[r * cols + c];
        }
    }
    let backward = Matrix::from_f32(cols, rows, wt, Precision::F32)?;

    let mut rng = SplitMix(0x5a17_0e5e_ed00_0001);
    let omega_t: Vec<f32> = (0..l * cols).map(|_| rng.next_unit()).collect();
    let mut y = vec![0.0f32; rows * l];
    let mut z = vec![0.0f32; cols * l];
    forward.matmul_t(&omega_t, l, None, &mut y, par)?;
    let mut q_t = orthonormal_t(&y, rows, l);
    for _ in 0..POWER_ITERATIONS {
        backward.matmul_t(&q_t, l, None, &mut z, par)?;
        let p_t = orthonormal_t(&z, cols, l);
        forward.matmul_t(&p_t, l, None, &mut y, par)?;
        q_t = orthonormal_t(&y, rows, l);
    }
    // Z = Wᵀ Q is `[cols, l]`; the small matrix is B = Qᵀ W = Zᵀ (`l × cols`).
    backward.matmul_t(&q_t, l, None, &mut z, par)?;
    let b = DMatrix::<f64>::from_fn(l, cols, |i, j| z[j * l + i] as f64);
    let svd = b.svd(true, true);
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => {
            return Err(Error::invalid(
                "output rank",
                "the small SVD did not converge",
            ));
        }
    };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    order.truncate(rank);

    // left = Q · U_b[:, order] · Σ, right = V_bᵀ[order, :].
    let mut left = vec![0.0f32; rows * rank];
    for (k, &o) in order.iter().enumerate() {
        let s = svd.singular_values[o];
        for r in 0..rows {
            let mut acc = 0.0f64;
            for c in 0..l {
                acc += q_t[c * rows + r] as f64 * u[(c, o)];
            }
            left[r * rank + k] = (acc * s) as f32;
        }
    }
    let mut right = vec![0.0f32; rank * cols];
    for (k, &o) in order.iter().enumerate() {
        for j in 0..cols {
            right[k * cols + j] = vt[(o, j)] as f32;
        }
    }
    let singular_values = order.iter().map(|&o| svd.singular_values[o]).collect();
    if left.iter().chain(&right).any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "output rank",
            "the truncated SVD produced a non-finite value",
        ));
    }
    Ok(LowRank {
        rank,
        left,
        right,
        singular_values,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
