//! The fit MLP (one ReLU hidden layer) and the wrinkle output layer (dense or PCA).

use crate::error::{Error, Result, check_finite, check_len};

use super::matrix::{Linear, Matrix, Parallelism};

/// Copy a `[rows, batch]` array into `[batch, rows]`.
pub(crate) fn transpose(src_t: &[f32], batch: usize, dst: &mut [f32]) {
    let rows = src_t.len() / batch;
    for (b, d) in dst.chunks_exact_mut(rows).enumerate() {
        for (i, v) in d.iter_mut().enumerate() {
            *v = src_t[i * batch + b];
        }
    }
}

fn check_batch(batch: usize, capacity: usize) -> Result<()> {
    if batch == 0 || batch > capacity {
        return Err(Error::invalid(
            "batch",
            format!("{batch} inputs, scratch holds 1 to {capacity}"),
        ));
    }
    Ok(())
}

/// A two-layer perceptron `y = W₂ relu(W₁ x + b₁) + b₂`.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    hidden: Linear,
    out: Linear,
}

/// Work buffers for [`Mlp`], sized for up to `capacity` inputs at once.
#[derive(Clone, Debug)]
pub struct MlpScratch {
    capacity: usize,
    hidden_t: Vec<f32>,
    hidden: Vec<f32>,
}

impl Mlp {
    /// Check that the output layer takes the hidden layer's outputs.
    pub fn new(hidden: Linear, out: Linear) -> Result<Self> {
        check_len("MLP output layer inputs", out.n_in(), hidden.n_out())?;
        Ok(Self { hidden, out })
    }

    /// Input size.
    pub fn n_in(&self) -> usize {
        self.hidden.n_in()
    }

    /// Whether one of its products of `batch` inputs under `par` runs on more than one thread.
    pub(crate) fn splits(&self, batch: usize, par: Parallelism) -> bool {
        self.hidden.splits(batch, par) || self.out.splits(batch, par)
    }

    /// Hidden size.
    pub fn n_hidden(&self) -> usize {
        self.hidden.n_out()
    }

    /// Output size.
    pub fn n_out(&self) -> usize {
        self.out.n_out()
    }

    /// Bytes held by the weight matrices.
    pub fn weight_bytes(&self) -> usize {
        self.hidden.weight().weight_bytes() + self.out.weight().weight_bytes()
    }

    /// Work buffers for up to `capacity` inputs (at least 1).
    pub fn scratch(&self, capacity: usize) -> MlpScratch {
        let capacity = capacity.max(1);
        MlpScratch {
            capacity,
            hidden_t: vec![0.0; self.n_hidden() * capacity],
            hidden: vec![0.0; self.n_hidden() * capacity],
        }
    }

    /// `y = W₂ relu(W₁ x + b₁) + b₂` for one input. Allocates nothing.
    pub fn forward(
        &self,
        x: &[f32],
        y: &mut [f32],
        scratch: &mut MlpScratch,
        par: Parallelism,
    ) -> Result<()> {
        self.forward_batch_t(x, 1, y, scratch, par)
    }

    /// The MLP on `batch` inputs sharing one pass over the weights.
    ///
    /// # Shapes
    /// - `xs`: `[batch, n_in]`, `ys_t`: `[n_out, batch]` (see [`Matrix::matmul_t`]).
    pub fn forward_batch_t(
        &self,
        xs: &[f32],
        batch: usize,
        ys_t: &mut [f32],
        scratch: &mut MlpScratch,
        par: Parallelism,
    ) -> Result<()> {
        check_batch(batch, scratch.capacity)?;
        check_len(
            "MLP scratch",
            scratch.hidden.len(),
            self.n_hidden() * scratch.capacity,
        )?;
        let n = self.n_hidden() * batch;
        let hidden_t = &mut scratch.hidden_t[..n];
        self.hidden.forward_batch_t(xs, batch, hidden_t, par)?;
        for v in hidden_t.iter_mut() {
            *v = v.max(0.0);
        }
        let hidden = if batch == 1 {
            &scratch.hidden_t[..n]
        } else {
            transpose(hidden_t, batch, &mut scratch.hidden[..n]);
            &scratch.hidden[..n]
        };
        self.out.forward_batch_t(hidden, batch, ys_t, par)
    }
}

/// The wrinkle regressor's output layer: hidden state → `3V` values, either directly or
/// through `k` PCA coefficients (`mean + basis · (W h + b)`).
#[derive(Clone, Debug, PartialEq)]
pub enum OutputLayer {
    /// `y = W h + b`, `W`: `[3V, H]`.
    Dense(Linear),
    /// `c = W h + b` (`W`: `[k, H]`), then `y = mean + basis · c` (`basis`: `[3V, k]`).
    Pca {
        /// The coefficient layer.
        coefficients: Linear,
        /// The `[3V, k]` basis.
        basis: Matrix,
        /// The `[3V]` mean.
        mean: Vec<f32>,
    },
}

/// Work buffers for [`OutputLayer`] (PCA coefficients), sized for up to `capacity` inputs.
#[derive(Clone, Debug)]
pub struct OutputScratch {
    capacity: usize,
    coefficients_t: Vec<f32>,
    coefficients: Vec<f32>,
}

impl OutputLayer {
    /// A PCA output, checking `basis` is `[mean.len(), k]` and `mean` is finite.
    pub fn pca(coefficients: Linear, basis: Matrix, mean: Vec<f32>) -> Result<Self> {
        check_len("PCA basis columns", basis.cols(), coefficients.n_out())?;
        check_len("PCA mean", mean.len(), basis.rows())?;
        check_finite("PCA mean", &mean)?;
        Ok(Self::Pca {
            coefficients,
            basis,
            mean,
        })
    }

    /// Input (hidden) size.
    pub fn n_in(&self) -> usize {
        match self {
            Self::Dense(l) => l.n_in(),
            Self::Pca { coefficients, .. } => coefficients.n_in(),
        }
    }

    /// Output size (3V).
    pub fn n_out(&self) -> usize {
        match self {
            Self::Dense(l) => l.n_out(),
            Self::Pca { basis, .. } => basis.rows(),
        }
    }

    /// Whether one of its products of `batch` inputs under `par` runs on more than one thread.
    pub(crate) fn splits(&self, batch: usize, par: Parallelism) -> bool {
        match self {
            Self::Dense(l) => l.splits(batch, par),
            Self::Pca {
                coefficients,
                basis,
                ..
            } => coefficients.splits(batch, par) || basis.splits(batch, par),
        }
    }

    /// Bytes held by the weight matrices.
    pub fn weight_bytes(&self) -> usize {
        match self {
            Self::Dense(l) => l.weight().weight_bytes(),
            Self::Pca {
                coefficients,
                basis,
                ..
            } => coefficients.weight().weight_bytes() + basis.weight_bytes(),
        }
    }

    /// Work buffers for up to `capacity` inputs (at least 1).
    pub fn scratch(&self, capacity: usize) -> OutputScratch {
        let capacity = capacity.max(1);
        let k = match self {
            Self::Dense(_) => 0,
            Self::Pca { coefficients, .. } => coefficients.n_out(),
        };
        OutputScratch {
            capacity,
            coefficients_t: vec![0.0; k * capacity],
            coefficients: vec![0.0; k * capacity],
        }
    }

    /// The output layer on `batch` hidden states.
    ///
    /// # Shapes
    /// - `hs`: `[batch, H]`, `ys_t`: `[3V, batch]` (see [`Matrix::matmul_t`]).
    pub fn forward_batch_t(
        &self,
        hs: &[f32],
        batch: usize,
        ys_t: &mut [f32],
        scratch: &mut OutputScratch,
        par: Parallelism,
    ) -> Result<()> {
        check_batch(batch, scratch.capacity)?;
        match self {
            Self::Dense(l) => l.forward_batch_t(hs, batch, ys_t, par),
            Self::Pca {
                coefficients,
                basis,
                mean,
            } => {
                let n = coefficients.n_out() * batch;
                check_len(
                    "output scratch",
                    scratch.coefficients.len(),
                    coefficients.n_out() * scratch.capacity,
                )?;
                coefficients.forward_batch_t(hs, batch, &mut scratch.coefficients_t[..n], par)?;
                let c = if batch == 1 {
                    &scratch.coefficients_t[..n]
                } else {
                    transpose(
                        &scratch.coefficients_t[..n],
                        batch,
                        &mut scratch.coefficients[..n],
                    );
                    &scratch.coefficients[..n]
                };
                basis.matmul_t(c, batch, Some(mean), ys_t, par)
            }
        }
    }
}

/// The f64 reference arithmetic of the runtime's integration tests.
#[cfg(test)]
#[allow(dead_code)]
#[path = "../../tests/it/reference.rs"]
mod reference;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::Precision;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
        (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
    }

    fn linear(rng: &mut ChaCha8Rng, rows: usize, cols: usize) -> (Linear, Vec<f32>, Vec<f32>) {
        let w = random(rng, rows * cols);
        let b = random(rng, rows);
        let l = Linear::new(
            Matrix::from_f32(rows, cols, w.clone(), Precision::F32).expect("ok"),
            b.clone(),
        )
        .expect("ok");
        (l, w, b)
    }

    use super::reference::affine;

    /// Output `y` of input `b` alone matches the f64 reference and, bit for bit, column `b` of
    /// the batched (transposed) output.
    fn assert_column(y: &[f32], want: &[f64], ys_t: &[f32], batch: usize, b: usize) {
        assert_eq!(y.len(), want.len());
        for (i, (&y, &want)) in y.iter().zip(want).enumerate() {
            assert!((y as f64 - want).abs() < 1e-5 * (1.0 + want.abs()));
            assert_eq!(y.to_bits(), ys_t[i * batch + b].to_bits());
        }
    }

    #[test]
    fn mlp_matches_f64_reference_and_batches_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        let (n_in, n_hid, n_out, batch) = (10, 21, 37, 4);
        let (l1, w1, b1) = linear(&mut rng, n_hid, n_in);
        let (l2, w2, b2) = linear(&mut rng, n_out, n_hid);
        let mlp = Mlp::new(l1, l2).expect("ok");
        let mut s = mlp.scratch(batch);
        let xs = random(&mut rng, batch * n_in);
        let mut ys_t = vec![0.0; n_out * batch];
        mlp.forward_batch_t(&xs, batch, &mut ys_t, &mut s, Parallelism::Sequential)
            .expect("sizes");
        for b in 0..batch {
            let x: Vec<f64> = xs[b * n_in..(b + 1) * n_in]
                .iter()
                .map(|&v| v as f64)
                .collect();
            let h: Vec<f64> = affine(&w1, &b1, &x)
                .into_iter()
                .map(|v| v.max(0.0))
                .collect();
            let want = affine(&w2, &b2, &h);
            let mut y = vec![0.0; n_out];
            mlp.forward(
                &xs[b * n_in..(b + 1) * n_in],
                &mut y,
                &mut s,
                Parallelism::Sequential,
            )
            .expect("sizes");
            assert_column(&y, &want, &ys_t, batch, b);
        }
    }

    #[test]
    fn pca_output_matches_f64_reference_and_batches_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(32);
        let (hid, k, n_out, batch) = (23, 7, 45, 3);
        let (coef, wc, bc) = linear(&mut rng, k, hid);
        let basis_w = random(&mut rng, n_out * k);
        let mean = random(&mut rng, n_out);
        let basis = Matrix::from_f32(n_out, k, basis_w.clone(), Precision::F32).expect("ok");
        let layer = OutputLayer::pca(coef, basis, mean.clone()).expect("ok");
        assert_eq!((layer.n_in(), layer.n_out()), (hid, n_out));
        let mut s = layer.scratch(batch);
        let hs = random(&mut rng, batch * hid);
        let mut ys_t = vec![0.0; n_out * batch];
        layer
            .forward_batch_t(&hs, batch, &mut ys_t, &mut s, Parallelism::Sequential)
            .expect("sizes");
        for b in 0..batch {
            let h: Vec<f64> = hs[b * hid..(b + 1) * hid]
                .iter()
                .map(|&v| v as f64)
                .collect();
            let c = affine(&wc, &bc, &h);
            let want = affine(&basis_w, &mean, &c);
            let mut y = vec![0.0; n_out];
            layer
                .forward_batch_t(
                    &hs[b * hid..(b + 1) * hid],
                    1,
                    &mut y,
                    &mut s,
                    Parallelism::Sequential,
                )
                .expect("sizes");
            assert_column(&y, &want, &ys_t, batch, b);
        }
        assert!(
            layer
                .forward_batch_t(&hs, batch + 1, &mut ys_t, &mut s, Parallelism::Sequential)
                .is_err()
        );
    }
}
