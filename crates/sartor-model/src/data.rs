//! From `sartor_dataset`'s batches to tensors, and back.

use burn::tensor::{Device, Tensor, TensorData};
use sartor_dataset::{PcaBasis, TrainingData};

/// A tensor of `values` with `shape` on `device`.
pub(crate) fn tensor<const D: usize>(
    values: Vec<f32>,
    shape: [usize; D],
    device: &Device,
) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

/// The values of a tensor, row-major, as f32.
pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    let data = t.into_data_as::<f32>();
    data.as_slice::<f32>()
        .expect("into_data_as::<f32> yields f32 data")
        .to_vec()
}

/// The dataset's PCA basis as tensors: `basis [3V, k]` and `mean [1, 3V]` (normalised units).
#[derive(Clone, Debug)]
pub(crate) struct PcaTensors {
    pub basis: Tensor<2>,
    pub mean: Tensor<2>,
}

impl PcaTensors {
    /// The first `k` components of `pca` (all of them if `k` is larger).
    pub fn new(pca: &PcaBasis, k: usize, device: &Device) -> Self {
        let n3 = pca.mean.len();
        let all = pca.n_components();
        let basis = tensor(pca.basis.clone(), [n3, all], device);
        Self {
            basis: basis.slice([0..n3, 0..k.min(all)]),
            mean: tensor(pca.mean.clone(), [1, n3], device),
        }
    }

    /// Coefficients `(y − mean) · basis` of normalised displacements `y [N, 3V]` → `[N, k]`.
    pub fn project(&self, y: Tensor<2>) -> Tensor<2> {
        (y - self.mean.clone()).matmul(self.basis.clone())
    }

    /// Normalised displacements `mean + c · basisᵀ` of coefficients `c [N, k]` → `[N, 3V]`.
    pub fn reconstruct(&self, c: Tensor<2>) -> Tensor<2> {
        c.matmul(self.basis.clone().transpose()) + self.mean.clone()
    }
}

/// Mean per-vertex Euclidean error in millimetres between normalised predictions and targets
/// (`[N, 3V]` each, row-major), denormalised with `std` (`[3V]`), over the rows where `mask`
/// (`[N]`, if given) is positive. Returns `(sum of per-vertex errors in mm, vertices counted)`.
pub fn vertex_error_mm(
    prediction: &[f32],
    target: &[f32],
    std: &[f32],
    mask: Option<&[f32]>,
) -> (f64, usize) {
    let n3 = std.len();
    let mut sum = 0.0;
    let mut count = 0;
    for (row, (p, t)) in prediction
        .chunks_exact(n3)
        .zip(target.chunks_exact(n3))
        .enumerate()
    {
        if mask.is_some_and(|m| m[row] <= 0.0) {
            continue;
        }
        for v in 0..n3 / 3 {
            let mut d2 = 0.0f64;
            for c in 0..3 {
                let i = 3 * v + c;
                let d = f64::from((p[i] - t[i]) * std[i]);
                d2 += d * d;
            }
            sum += d2.sqrt() * 1000.0;
            count += 1;
        }
    }
    (sum, count)
}

/// Number of frames in `sequences`.
pub(crate) fn frames_of(data: &TrainingData, sequences: &[usize]) -> usize {
    sequences
        .iter()
        .map(|&s| data.sequences()[s].n_frames)
        .sum()
}
