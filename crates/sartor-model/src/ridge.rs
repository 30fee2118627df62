//! The linear baseline in closed form: ridge regression of the normalised `Δ_L` on the
//! normalised per-frame inputs `[β, pose features]`.
//!
//! A linear map trained by stochastic gradient descent is only as good as its stopping point:
//! with inputs far outside what it saw, the earlier SGD-trained baseline diverged (metres of
//! error on real motion capture). Here it is the best linear map for the training frames in the
//! least-squares sense, with a weight decay `λ` on the weights (not the bias):
//!
//! `W = argmin Σ_t |x̃_t W − y_t|² + λ N |W_x|²`, `x̃ = [x, 1]`, `N` training frames,
//!
//! solved from the normal equations `(X̃ᵀX̃ + λ N D) W = X̃ᵀY` (`D` the identity without the
//! bias's entry) by Cholesky in f64. The inputs are normalised (unit variance per feature), so
//! one `λ` grid fits every dataset: [`LAMBDAS`]. `λ` is picked by the mean vertex error on the
//! validation motions (model selection, never the test set); without a validation split the
//! smallest non-zero `λ` is used.

use burn::module::Param;
use burn::tensor::{Device, Tensor, TensorData};
use nalgebra::DMatrix;
use sartor_dataset::{TrainingData, gather_frames};

use crate::data::vertex_error_mm;
use crate::model::LinearRegressor;

/// The weight decays tried, relative to the number of training frames (inputs have unit
/// variance, so `λ = 1` is as strong as the data itself).
pub const LAMBDAS: [f64; 7] = [1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0];

/// Frames gathered at once.
const CHUNK: usize = 512;

/// The normal equations of some frames: `X̃ᵀX̃` and `X̃ᵀY`, `X̃` with a column of ones.
struct Normal {
    gram: DMatrix<f64>,
    cross: DMatrix<f64>,
    frames: usize,
}

/// The normal equations of `frames` (`(sequence, frame)` pairs of `data`).
fn normal_equations(data: &TrainingData, frames: &[(usize, usize)]) -> Normal {
    let (n_in, n_out) = (data.n_inputs() + 1, data.n_outputs());
    let mut gram = DMatrix::<f64>::zeros(n_in, n_in);
    let mut cross = DMatrix::<f64>::zeros(n_in, n_out);
    for chunk in frames.chunks(CHUNK) {
        let (x, y) = gather_frames(data, chunk);
        let x = augmented(&x, chunk.len(), data.n_inputs());
        let y = DMatrix::from_row_iterator(chunk.len(), n_out, y.iter().map(|&v| f64::from(v)));
        gram += x.tr_mul(&x);
        cross += x.tr_mul(&y);
    }
    Normal {
        gram,
        cross,
        frames: frames.len(),
    }
}

/// Row-major `[n, width]` values as an f64 matrix with a last column of ones.
fn augmented(x: &[f32], n: usize, width: usize) -> DMatrix<f64> {
    DMatrix::from_fn(n, width + 1, |r, c| {
        if c < width {
            f64::from(x[r * width + c])
        } else {
            1.0
        }
    })
}

/// The ridge solution `[(n_in + 1), n_out]` (last row: the bias) for weight decay `lambda`;
/// `None` when the system is singular even so (λ = 0 on collinear inputs).
fn solve(normal: &Normal, lambda: f64) -> Option<DMatrix<f64>> {
    let mut a = normal.gram.clone();
    let n = a.nrows();
    for i in 0..n - 1 {
        a[(i, i)] += lambda * normal.frames as f64;
    }
    let cholesky = a.cholesky()?;
    let w = cholesky.solve(&normal.cross);
    w.iter().all(|v| v.is_finite()).then_some(w)
}

/// Mean vertex error (mm) of `w` on `frames`, and the mean squared error in normalised units.
fn errors(data: &TrainingData, w: &DMatrix<f64>, frames: &[(usize, usize)]) -> (f64, f64) {
    let std = &data.stats().wrinkle_out.std;
    let (mut sum_mm, mut count, mut sum_sq, mut values) = (0.0, 0usize, 0.0, 0usize);
    for chunk in frames.chunks(CHUNK) {
        let (x, y) = gather_frames(data, chunk);
        let prediction = augmented(&x, chunk.len(), data.n_inputs()) * w;
        // Row-major f32, as the networks' outputs.
        let pred: Vec<f32> = (0..chunk.len())
            .flat_map(|r| (0..w.ncols()).map(move |c| (r, c)))
            .map(|(r, c)| prediction[(r, c)] as f32)
            .collect();
        let (s, c) = vertex_error_mm(&pred, &y, std, None);
        sum_mm += s;
        count += c;
        sum_sq += pred
            .iter()
            .zip(&y)
            .map(|(p, t)| f64::from(p - t).powi(2))
            .sum::<f64>();
        values += y.len();
    }
    (sum_mm / count.max(1) as f64, sum_sq / values.max(1) as f64)
}

/// Fit the linear baseline in closed form on `train`, picking `λ` on `val`: the weights of `module`
/// are replaced (on `device`, `[in, out]` as burn's `Linear`; no random draw, so trainings that
/// run at once stay reproducible). Returns the mean squared error on `train` (normalised
/// units); `None`, with `module` untouched, when no `λ` gives a solution.
pub(crate) fn fit(
    data: &TrainingData,
    module: &mut LinearRegressor,
    train: &[(usize, usize)],
    val: &[(usize, usize)],
    device: &Device,
) -> Option<f64> {
    let normal = normal_equations(data, train);
    let mut best: Option<(f64, DMatrix<f64>)> = None;
    for &lambda in &LAMBDAS {
        let Some(w) = solve(&normal, lambda) else {
            continue;
        };
        if val.is_empty() {
            best = Some((0.0, w));
            break;
        }
        let (mm, _) = errors(data, &w, val);
        if best.as_ref().is_none_or(|b| mm < b.0) {
            best = Some((mm, w));
        }
    }
    let (_, w) = best?;
    let (_, train_mse) = errors(data, &w, train);
    let (n_in, n_out) = (data.n_inputs(), data.n_outputs());
    let weight: Vec<f32> = (0..n_in)
        .flat_map(|i| (0..n_out).map(move |o| (i, o)))
        .map(|(i, o)| w[(i, o)] as f32)
        .collect();
    let bias: Vec<f32> = (0..n_out).map(|o| w[(n_in, o)] as f32).collect();
    module.set_weights(
        Param::from_tensor(Tensor::from_data(
            TensorData::new(weight, [n_in, n_out]),
            device,
        )),
        Param::from_tensor(Tensor::from_data(TensorData::new(bias, [n_out]), device)),
    );
    Some(train_mse)
}
