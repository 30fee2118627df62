//! Trained modules in use: predictions in metres (what the runtime must reproduce) and the
//! export to the runtime's burn-free format (`sartor_runtime::GarmentModel`).

use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::{Device, Tensor};
use sartor_dataset::{MeanStd, Split, TrainingData};
use sartor_runtime::{
    DenseWeights, FeatureBlock, GarmentModel, GruWeights, ModelHeader, ModelSizes, ModelWeights,
    OutputKind, PcaWeights, TrainingBetas,
};

use crate::data::{PcaTensors, tensor, to_vec};
use crate::model::{FitRegressor, LinearRegressor, WrinkleRegressor};
use crate::{Error, Result};

/// The first `k` columns of a row-major `[rows, cols]` matrix.
fn first_columns(values: &[f32], cols: usize, k: usize) -> Vec<f32> {
    values
        .chunks_exact(cols)
        .flat_map(|row| row[..k].iter().copied())
        .collect()
}

/// Row-major transpose of a `[rows, cols]` matrix.
fn transpose(values: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut out = vec![0.0; values.len()];
    for r in 0..rows {
        for c in 0..cols {
            out[c * rows + r] = values[r * cols + c];
        }
    }
    out
}

/// A burn `Linear` (`x·W + b`, `W` `[in, out]`) as the runtime's `W x + b` (`[out, in]`).
fn dense(layer: &Linear) -> DenseWeights {
    let [d_in, d_out] = layer.weight.val().dims();
    let weight = transpose(&to_vec(layer.weight.val()), d_in, d_out);
    let bias = layer
        .bias
        .as_ref()
        .map_or_else(|| vec![0.0; d_out], |b| to_vec(b.val()));
    DenseWeights { weight, bias }
}

fn mean_std(m: &MeanStd) -> sartor_runtime::MeanStd {
    sartor_runtime::MeanStd {
        mean: m.mean.clone(),
        std: m.std.clone(),
    }
}

/// The three trained modules as one runtime model (f32 tensors + header): the fit MLP, the
/// wrinkle GRU (PyTorch's gate layout) with its dense or PCA output, the linear baseline if
/// given, the dataset's normalisation, the garment's and body's identity and the β of the
/// training shapes (`training_betas`).
pub fn export_model(
    data: &TrainingData,
    fit: &FitRegressor,
    wrinkle: &WrinkleRegressor,
    linear: Option<&LinearRegressor>,
) -> Result<GarmentModel> {
    let (fit_hidden, fit_out) = fit.layers();
    let (gru, out) = wrinkle.parts();
    let [w_ih, w_hh] = gru.params();
    let [b_ih, b_hh] = gru.biases();
    let [n_in, h3] = w_ih.dims();
    let h = h3 / 3;
    let gru_weights = GruWeights {
        weight_ih: transpose(&to_vec(w_ih), n_in, h3),
        weight_hh: transpose(&to_vec(w_hh), h, h3),
        bias_ih: to_vec(b_ih),
        bias_hh: to_vec(b_hh),
    };
    let wrinkle_out = dense(out);
    let out_rows = wrinkle_out.bias.len();
    let n3 = data.n_outputs();
    let (output, pca) = if out_rows == n3 {
        (OutputKind::Dense, None)
    } else {
        let basis = data.pca().ok_or_else(|| {
            Error::invalid(
                "export",
                format!("the wrinkle output has {out_rows} rows but the dataset has no PCA basis"),
            )
        })?;
        let k_all = basis.n_components();
        if out_rows > k_all {
            return Err(Error::invalid(
                "export",
                format!("the wrinkle output has {out_rows} rows, the PCA basis {k_all}"),
            ));
        }
        (
            OutputKind::Pca(out_rows),
            Some(PcaWeights {
                basis: first_columns(&basis.basis, k_all, out_rows),
                mean: basis.mean.clone(),
            }),
        )
    };
    let fit_hidden = dense(fit_hidden);
    let sizes = ModelSizes {
        n_vertices: data.n_vertices(),
        n_betas: data.n_betas(),
        n_pose_features: data.n_inputs() - data.n_betas(),
        fit_hidden: fit_hidden.bias.len(),
        gru_hidden: h,
        output,
        linear_baseline: linear.is_some(),
    };
    let (garment, body) = (data.source().garment.clone(), data.source().body.clone());
    let mut header = ModelHeader::new(
        garment,
        body,
        sizes,
        FeatureBlock::layout(data.layout().n_betas, &data.layout().pose),
    );
    // The shapes the networks were trained on, for the animator's rule beyond them.
    header.training_betas = Some(TrainingBetas(
        data.shape_indices(Split::Train)
            .into_iter()
            .map(|i| data.shapes()[i].betas.clone())
            .collect(),
    ));
    let stats = data.stats();
    let weights = ModelWeights {
        fit_hidden,
        fit_out: dense(fit_out),
        gru: gru_weights,
        wrinkle_out,
        pca,
        lr: linear.map(|l| dense(l.layer())),
        norm: sartor_runtime::NormStats {
            fit_in: mean_std(&stats.fit_in),
            wrinkle_in: mean_std(&stats.wrinkle_in),
            fit_out: mean_std(&stats.fit_out),
            wrinkle_out: mean_std(&stats.wrinkle_out),
        },
    };
    Ok(GarmentModel::new(header, weights)?)
}

/// Predictions of trained modules in metres, computed by burn (inference mode): the reference
/// the runtime's kernels are checked against.
pub struct Predictor<'a> {
    data: &'a TrainingData,
    device: Device,
}

impl<'a> Predictor<'a> {
    /// Raw wrinkle inputs `[T, I]`, normalised, and `T`.
    fn normalised_inputs(&self, inputs: &[f32]) -> (Vec<f32>, usize) {
        let n_in = self.data.n_inputs();
        let mut x = inputs.to_vec();
        for row in x.chunks_exact_mut(n_in) {
            self.data.stats().wrinkle_in.normalize(row);
        }
        (x, inputs.len() / n_in)
    }

    /// Normalised `Δ_L` rows `[T, 3V]` in metres.
    fn wrinkle_metres(&self, mut y: Vec<f32>) -> Vec<f32> {
        for row in y.chunks_exact_mut(self.data.n_outputs()) {
            self.data.stats().wrinkle_out.denormalize(row);
        }
        y
    }

    /// Predictions on `device` (a plain, non-autodiff device) with `data`'s statistics and PCA.
    pub fn new(data: &'a TrainingData, device: Device) -> Self {
        Self { data, device }
    }

    /// `Δ_G(β)` in metres (`[3V]`) for raw β.
    pub fn fit(&self, fit: &FitRegressor, betas: &[f32]) -> Vec<f32> {
        let stats = self.data.stats();
        let mut x = betas.to_vec();
        stats.fit_in.normalize(&mut x);
        let y = fit
            .valid()
            .forward(tensor(x, [1, betas.len()], &self.device));
        let mut y = to_vec(y);
        stats.fit_out.denormalize(&mut y);
        y
    }

    /// `Δ_L` per frame in metres (`[T, 3V]`) for raw wrinkle inputs `[T, I]`, from a zero state.
    pub fn wrinkle(&self, wrinkle: &WrinkleRegressor, inputs: &[f32]) -> Vec<f32> {
        let (x, t) = self.normalised_inputs(inputs);
        let n_in = self.data.n_inputs();
        let model = wrinkle.valid();
        let state = model.initial_state(1, &self.device);
        let (y, _) = model.forward(tensor(x, [1, t, n_in], &self.device), state);
        let width = y.dims()[2];
        let y: Tensor<2> = y.reshape([t, width]);
        let y = match self.data.pca() {
            Some(basis) if width != self.data.n_outputs() => {
                PcaTensors::new(basis, width, &self.device).reconstruct(y)
            }
            _ => y,
        };
        self.wrinkle_metres(to_vec(y))
    }

    /// The linear baseline's `Δ_L` per frame in metres (`[T, 3V]`) for raw inputs `[T, I]`.
    pub fn linear(&self, linear: &LinearRegressor, inputs: &[f32]) -> Vec<f32> {
        let (x, t) = self.normalised_inputs(inputs);
        let n_in = self.data.n_inputs();
        let y = linear.valid().forward(tensor(x, [t, n_in], &self.device));
        self.wrinkle_metres(to_vec(y))
    }
}
