//! PCA of bodies that are linear in target weights: `x_s = x_0 + Σ_t W[s, t] · a_t`.
//!
//! The centred sample matrix is `X = W_c · A` (`W_c`: N × T centred weights, `A`: T × D
//! stacked target displacements), so its covariance `Aᵀ C A` (`C = W_cᵀ W_c / N`) has the same
//! non-zero spectrum as `B C Bᵀ`, where `G = A Aᵀ = U Λ Uᵀ` and `B = Λ^½ Uᵀ` (r × T). Its
//! eigenvectors `y` give the principal directions `v = Aᵀ U Λ^-½ y`. Only T × T matrices are
//! decomposed; the D-sized work is the Gram matrix `G` and the T × D products. Every reduction
//! runs in a fixed order on one thread, so results are reproducible bit for bit.

use nalgebra::{DMatrix, SymmetricEigen};

use crate::{Error, Result};

/// Rows of `A`, dense, plus the non-zero columns of the sparse ones.
pub(crate) struct TargetRows {
    n_cols: usize,
    /// `T × n_cols`, row-major.
    data: Vec<f64>,
    /// For rows with few non-zeros: their column indices (sorted).
    nonzero_cols: Vec<Option<Vec<u32>>>,
}

impl TargetRows {
    /// Rows with fewer than a quarter non-zero entries are treated as sparse in the Gram matrix.
    pub fn new(n_cols: usize, data: Vec<f64>) -> Self {
        let n_rows = data.len().checked_div(n_cols).unwrap_or(0);
        let nonzero_cols = (0..n_rows)
            .map(|i| {
                let row = &data[i * n_cols..(i + 1) * n_cols];
                let nz: Vec<u32> = (0..n_cols)
                    .filter(|&c| row[c] != 0.0)
                    .map(|c| c as u32)
                    .collect();
                (nz.len() * 4 < n_cols).then_some(nz)
            })
            .collect();
        Self {
            n_cols,
            data,
            nonzero_cols,
        }
    }

    /// Number of rows (targets).
    pub fn n_rows(&self) -> usize {
        self.nonzero_cols.len()
    }

    /// Row `i`.
    pub fn row(&self, i: usize) -> &[f64] {
        &self.data[i * self.n_cols..(i + 1) * self.n_cols]
    }

    /// `G = A Aᵀ`.
    pub fn gram(&self) -> DMatrix<f64> {
        let t = self.n_rows();
        let mut g = DMatrix::<f64>::zeros(t, t);
        let dense: Vec<usize> = (0..t).filter(|&i| self.nonzero_cols[i].is_none()).collect();
        self.gram_dense_block(&dense, &mut g);
        // Pairs with a sparse row: sum over the non-zeros of the sparser row.
        for i in 0..t {
            for j in i..t {
                let nz = match (&self.nonzero_cols[i], &self.nonzero_cols[j]) {
                    (None, None) => continue,
                    (Some(a), None) => a,
                    (None, Some(b)) => b,
                    (Some(a), Some(b)) => {
                        if b.len() < a.len() {
                            b
                        } else {
                            a
                        }
                    }
                };
                let (ri, rj) = (self.row(i), self.row(j));
                let s: f64 = nz.iter().map(|&c| ri[c as usize] * rj[c as usize]).sum();
                g[(i, j)] = s;
                g[(j, i)] = s;
            }
        }
        g
    }

    /// `G[i, j]` for all pairs of the listed dense rows: 4 × 4 register blocks over column
    /// chunks that stay in cache.
    fn gram_dense_block(&self, rows: &[usize], g: &mut DMatrix<f64>) {
        const CHUNK: usize = 512;
        let n = rows.len();
        let zero = vec![0.0; self.n_cols];
        let row = |k: usize| -> &[f64] { if k < n { self.row(rows[k]) } else { &zero } };
        let mut partial = vec![0.0f64; n.div_ceil(4) * 4 * n.div_ceil(4) * 4];
        let stride = n.div_ceil(4) * 4;
        for c0 in (0..self.n_cols).step_by(CHUNK) {
            let c1 = (c0 + CHUNK).min(self.n_cols);
            for bi in (0..n).step_by(4) {
                let a: [&[f64]; 4] = [0, 1, 2, 3].map(|p| &row(bi + p)[c0..c1]);
                for bj in (0..=bi).step_by(4) {
                    let b: [&[f64]; 4] = [0, 1, 2, 3].map(|q| &row(bj + q)[c0..c1]);
                    let mut acc = [[0.0f64; 4]; 4];
                    for k in 0..c1 - c0 {
                        let av = [a[0][k], a[1][k], a[2][k], a[3][k]];
                        let bv = [b[0][k], b[1][k], b[2][k], b[3][k]];
                        for p in 0..4 {
                            for q in 0..4 {
                                acc[p][q] += av[p] * bv[q];
                            }
                        }
                    }
                    for p in 0..4 {
                        for q in 0..4 {
                            partial[(bi + p) * stride + bj + q] += acc[p][q];
                        }
                    }
                }
            }
        }
        for p in 0..n {
            for q in 0..=p {
                let s = partial[p * stride + q];
                g[(rows[p], rows[q])] = s;
                g[(rows[q], rows[p])] = s;
            }
        }
    }
}

/// Principal components of the sample.
pub(crate) struct Pca {
    /// Unit principal directions (length `n_cols`), largest variance first.
    pub components: Vec<Vec<f64>>,
    /// Variance of the sample along each component (divided by N).
    pub variances: Vec<f64>,
    /// Total variance of the sample (trace of the covariance).
    pub total_variance: f64,
    /// Rank kept from the Gram matrix.
    pub rank: usize,
}

/// Eigen-decomposition sorted by decreasing eigenvalue (ties by index, so deterministic).
fn sorted_eigen(m: DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
    let eig = SymmetricEigen::new(m);
    let mut order: Vec<usize> = (0..eig.eigenvalues.len()).collect();
    order.sort_by(|&a, &b| {
        eig.eigenvalues[b]
            .total_cmp(&eig.eigenvalues[a])
            .then(a.cmp(&b))
    });
    let values = order.iter().map(|&i| eig.eigenvalues[i]).collect();
    let vectors = DMatrix::from_fn(eig.eigenvectors.nrows(), order.len(), |r, c| {
        eig.eigenvectors[(r, order[c])]
    });
    (values, vectors)
}

/// Covariance `C = W_cᵀ W_c / N` of the target weights (`weights`: N × T, row-major).
pub(crate) fn weight_covariance(weights: &[f64], n_samples: usize, t: usize) -> DMatrix<f64> {
    let mut mean = vec![0.0; t];
    for s in 0..n_samples {
        for (m, w) in mean.iter_mut().zip(&weights[s * t..(s + 1) * t]) {
            *m += w;
        }
    }
    for m in &mut mean {
        *m /= n_samples as f64;
    }
    let mut c = DMatrix::<f64>::zeros(t, t);
    let mut centred = vec![0.0; t];
    for s in 0..n_samples {
        for ((x, w), m) in centred
            .iter_mut()
            .zip(&weights[s * t..(s + 1) * t])
            .zip(&mean)
        {
            *x = w - m;
        }
        for i in 0..t {
            if centred[i] == 0.0 {
                continue;
            }
            for j in 0..=i {
                c[(i, j)] += centred[i] * centred[j];
            }
        }
    }
    for i in 0..t {
        for j in 0..=i {
            let v = c[(i, j)] / n_samples as f64;
            c[(i, j)] = v;
            c[(j, i)] = v;
        }
    }
    c
}

/// `a · b` for column-major nalgebra matrices, in a fixed loop order (no BLAS, no FMA).
fn matmul(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let (n, k, m) = (a.nrows(), a.ncols(), b.ncols());
    let mut out = DMatrix::<f64>::zeros(n, m);
    for j in 0..m {
        for p in 0..k {
            let bpj = b[(p, j)];
            if bpj == 0.0 {
                continue;
            }
            for i in 0..n {
                out[(i, j)] += a[(i, p)] * bpj;
            }
        }
    }
    out
}

/// The `n_components` leading principal components of `x_s = x_0 + Σ_t W[s, t] a_t`, given
/// the rows `a_t` and the weight covariance `C`.
pub(crate) fn pca(rows: &TargetRows, cov: &DMatrix<f64>, n_components: usize) -> Result<Pca> {
    let t = rows.n_rows();
    if cov.nrows() != t || cov.ncols() != t {
        return Err(Error::invalid(
            "pca",
            format!(
                "{t} targets but a {}×{} covariance",
                cov.nrows(),
                cov.ncols()
            ),
        ));
    }
    let g = rows.gram();
    let total_variance: f64 = (0..t)
        .flat_map(|i| (0..t).map(move |j| (i, j)))
        .map(|(i, j)| cov[(i, j)] * g[(i, j)])
        .sum();
    let (lambda, u) = sorted_eigen(g);
    let lambda_max = lambda.first().copied().unwrap_or(0.0);
    let rank = lambda
        .iter()
        .take_while(|&&l| l > 1e-12 * lambda_max)
        .count();
    if rank < n_components {
        return Err(Error::invalid(
            "pca",
            format!("the targets span {rank} dimensions, fewer than {n_components} components"),
        ));
    }
    // B = Λ^½ Uᵀ (rank × t); M = B C Bᵀ.
    let b = DMatrix::from_fn(rank, t, |r, c| lambda[r].sqrt() * u[(c, r)]);
    let m = matmul(&matmul(&b, cov), &b.transpose());
    let m = (&m + m.transpose()) * 0.5;
    let (_, y) = sorted_eigen(m);
    let mut components = Vec::with_capacity(n_components);
    for k in 0..n_components {
        // a = U Λ^-½ y_k; v = Aᵀ a.
        let coeff: Vec<f64> = (0..t)
            .map(|i| {
                (0..rank)
                    .map(|r| u[(i, r)] * y[(r, k)] / lambda[r].sqrt())
                    .sum()
            })
            .collect();
        let mut v = vec![0.0; rows.n_cols];
        for (i, a) in coeff.iter().enumerate() {
            if *a == 0.0 {
                continue;
            }
            for (x, r) in v.iter_mut().zip(rows.row(i)) {
                *x += a * r;
            }
        }
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm <= 0.0 || !norm.is_finite() {
            return Err(Error::invalid("pca", format!("component {k} vanished")));
        }
        for x in &mut v {
            *x /= norm;
        }
        // Deterministic sign: the largest-magnitude entry (first on ties) is positive.
        let mut arg = 0;
        for (i, x) in v.iter().enumerate() {
            if x.abs() > v[arg].abs() {
                arg = i;
            }
        }
        if v[arg] < 0.0 {
            for x in &mut v {
                *x = -*x;
            }
        }
        components.push(v);
    }
    // Variance along each normalised component, from the projections q_t = a_t · v.
    let variances = components
        .iter()
        .map(|v| {
            let q: Vec<f64> = (0..t)
                .map(|i| rows.row(i).iter().zip(v).map(|(a, b)| a * b).sum())
                .collect();
            (0..t)
                .map(|i| (0..t).map(|j| q[i] * cov[(i, j)] * q[j]).sum::<f64>())
                .sum::<f64>()
        })
        .collect();
    Ok(Pca {
        components,
        variances,
        total_variance,
        rank,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn gram_matches_naive_for_dense_and_sparse_rows() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (t, d) = (11, 1100);
        let mut data = vec![0.0; t * d];
        for i in 0..t {
            let density = if i % 3 == 0 { 0.05 } else { 1.0 };
            for c in 0..d {
                if rng.random::<f64>() < density {
                    data[i * d + c] = rng.random::<f64>() - 0.5;
                }
            }
        }
        let rows = TargetRows::new(d, data.clone());
        assert!(rows.nonzero_cols[0].is_some() && rows.nonzero_cols[1].is_none());
        let g = rows.gram();
        for i in 0..t {
            for j in 0..t {
                let naive: f64 = (0..d).map(|c| data[i * d + c] * data[j * d + c]).sum();
                assert!((g[(i, j)] - naive).abs() < 1e-10, "{i} {j}");
            }
        }
    }

    #[test]
    fn pca_matches_explicit_covariance() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (t, d, n) = (6, 40, 300);
        let data: Vec<f64> = (0..t * d).map(|_| rng.random::<f64>() - 0.5).collect();
        let weights: Vec<f64> = (0..n * t).map(|_| rng.random::<f64>()).collect();
        let rows = TargetRows::new(d, data.clone());
        let cov = weight_covariance(&weights, n, t);
        let p = pca(&rows, &cov, 3).expect("rank 6");
        // Explicit samples and covariance.
        let x = DMatrix::from_fn(n, d, |s, c| {
            (0..t)
                .map(|i| weights[s * t + i] * data[i * d + c])
                .sum::<f64>()
        });
        let mean = x.row_mean();
        let xc = DMatrix::from_fn(n, d, |s, c| x[(s, c)] - mean[c]);
        let sigma = xc.transpose() * &xc / n as f64;
        let eig = SymmetricEigen::new(sigma.clone());
        let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
        ev.sort_by(|a, b| b.total_cmp(a));
        assert!((p.total_variance - sigma.trace()).abs() < 1e-9 * sigma.trace());
        for k in 0..3 {
            assert!((p.variances[k] - ev[k]).abs() < 1e-9 * ev[0], "{k}");
            let v = nalgebra::DVector::from_vec(p.components[k].clone());
            let sv = &sigma * &v;
            assert!((sv - &v * ev[k]).norm() < 1e-8 * ev[0], "eigenvector {k}");
        }
    }
}
