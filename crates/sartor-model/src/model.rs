//! The three regressors of Santesteban et al. 2019 as burn modules.
//!
//! Every module works on normalised values (see `sartor_dataset::NormStats`): the fit MLP maps
//! β to `Δ_G`, the wrinkle GRU maps per-frame `[β, pose features]` to `Δ_L` (dense, or as `k`
//! coefficients of the dataset's PCA basis), the linear baseline maps one frame's
//! `[β, pose features]` to `Δ_L`.

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::{Dropout, DropoutConfig, Initializer, Linear, LinearConfig, Relu};
use burn::tensor::activation::{sigmoid, tanh};
use burn::tensor::{Device, Tensor};

/// The garment fit regressor `R_G(β)`: one hidden layer with ReLU and dropout.
#[derive(Config, Debug)]
pub struct FitRegressorConfig {
    /// Shape coefficients β.
    pub n_betas: usize,
    /// Outputs `3V`.
    pub n_outputs: usize,
    /// Hidden units (20 in the paper).
    #[config(default = 20)]
    pub hidden: usize,
    /// Dropout after the hidden layer.
    #[config(default = 0.2)]
    pub dropout: f64,
}

/// `R_G`: β → `Δ_G`.
#[derive(Module, Debug)]
pub struct FitRegressor {
    hidden: Linear,
    activation: Relu,
    dropout: Dropout,
    out: Linear,
}

impl FitRegressorConfig {
    /// The module with fresh weights on `device`.
    pub fn init(&self, device: &Device) -> FitRegressor {
        FitRegressor {
            hidden: LinearConfig::new(self.n_betas, self.hidden).init(device),
            activation: Relu::new(),
            dropout: DropoutConfig::new(self.dropout).init(),
            out: LinearConfig::new(self.hidden, self.n_outputs).init(device),
        }
    }
}

impl FitRegressor {
    /// Normalised `Δ_G` of normalised β.
    ///
    /// # Shapes
    /// - `betas`: `[N, n_betas]`
    /// - output: `[N, n_outputs]`
    pub fn forward(&self, betas: Tensor<2>) -> Tensor<2> {
        let h = self.activation.forward(self.hidden.forward(betas));
        self.out.forward(self.dropout.forward(h))
    }

    /// `(hidden, out)` layers, for export.
    pub(crate) fn layers(&self) -> (&Linear, &Linear) {
        (&self.hidden, &self.out)
    }
}

/// A single-layer GRU with PyTorch's equations and parameter layout (gates `r, z, n` stacked),
/// one fused matrix per side:
///
/// ```text
/// r = σ(W_ir x + b_ir + W_hr h + b_hr)
/// z = σ(W_iz x + b_iz + W_hz h + b_hz)
/// n = tanh(W_in x + b_in + r ⊙ (W_hn h + b_hn))
/// h' = (1 − z) ⊙ n + z ⊙ h
/// ```
///
/// The input side of a whole window is one matrix product; each step costs one `[B, H] × [H,
/// 3H]` product. burn's own `Gru` does six products per step.
#[derive(Module, Debug)]
pub struct FusedGru {
    /// `[I, 3H]` (the transpose of PyTorch's `weight_ih`).
    weight_ih: Param<Tensor<2>>,
    /// `[H, 3H]`.
    weight_hh: Param<Tensor<2>>,
    /// `[3H]`.
    bias_ih: Param<Tensor<1>>,
    /// `[3H]`.
    bias_hh: Param<Tensor<1>>,
    hidden: usize,
}

impl FusedGru {
    /// PyTorch's initialisation: every parameter uniform in `±1/√H`.
    pub fn new(n_inputs: usize, hidden: usize, device: &Device) -> Self {
        let bound = 1.0 / (hidden as f64).sqrt();
        let init = Initializer::Uniform {
            min: -bound,
            max: bound,
        };
        Self {
            weight_ih: init.init([n_inputs, 3 * hidden], device),
            weight_hh: init.init([hidden, 3 * hidden], device),
            bias_ih: init.init([3 * hidden], device),
            bias_hh: init.init([3 * hidden], device),
            hidden,
        }
    }

    /// Hidden units `H`.
    pub fn hidden(&self) -> usize {
        self.hidden
    }

    /// Run the GRU over a window from `state`.
    ///
    /// # Shapes
    /// - `inputs`: `[B, T, I]`
    /// - `state`: `[B, H]`
    /// - output: every step's hidden state `[B, T, H]` and the last one `[B, H]`
    pub fn forward(&self, inputs: Tensor<3>, state: Tensor<2>) -> (Tensor<3>, Tensor<2>) {
        let [b, t, i] = inputs.dims();
        let h3 = 3 * self.hidden;
        let hh = self.hidden;
        let gates_x = inputs
            .reshape([b * t, i])
            .matmul(self.weight_ih.val())
            .add(self.bias_ih.val().unsqueeze::<2>())
            .reshape([b, t, h3]);
        let mut h = state;
        let mut outputs = Vec::with_capacity(t);
        for step in 0..t {
            let gx = gates_x
                .clone()
                .slice([0..b, step..step + 1, 0..h3])
                .reshape([b, h3]);
            let gh = h
                .clone()
                .matmul(self.weight_hh.val())
                .add(self.bias_hh.val().unsqueeze::<2>());
            let r = sigmoid(gx.clone().slice([0..b, 0..hh]) + gh.clone().slice([0..b, 0..hh]));
            let z = sigmoid(
                gx.clone().slice([0..b, hh..2 * hh]) + gh.clone().slice([0..b, hh..2 * hh]),
            );
            let n = tanh(gx.slice([0..b, 2 * hh..h3]) + r * gh.slice([0..b, 2 * hh..h3]));
            h = n.clone() + z * (h - n);
            outputs.push(h.clone());
        }
        (Tensor::stack::<3>(outputs, 1), h)
    }

    /// `(weight_ih [I, 3H], weight_hh [H, 3H], bias_ih, bias_hh)`, for export.
    pub(crate) fn params(&self) -> [Tensor<2>; 2] {
        [self.weight_ih.val(), self.weight_hh.val()]
    }

    /// `(bias_ih, bias_hh)`, for export.
    pub(crate) fn biases(&self) -> [Tensor<1>; 2] {
        [self.bias_ih.val(), self.bias_hh.val()]
    }
}

/// The garment wrinkle regressor `R_L(β, θ)`: a GRU over frames, dropout, a linear output.
#[derive(Config, Debug)]
pub struct WrinkleRegressorConfig {
    /// Per-frame inputs `[β, pose features]`.
    pub n_inputs: usize,
    /// Displacement outputs `3V`.
    pub n_outputs: usize,
    /// GRU hidden units (1500 in the paper).
    #[config(default = 1500)]
    pub hidden: usize,
    /// Dropout on the GRU's output.
    #[config(default = 0.2)]
    pub dropout: f64,
    /// Output through the dataset's PCA basis with this many components (`None`: dense `3V`
    /// outputs, as in the paper).
    #[config(default = "None")]
    pub pca_components: Option<usize>,
}

impl WrinkleRegressorConfig {
    /// Rows of the output layer: `k` or `3V`.
    pub fn output_width(&self) -> usize {
        self.pca_components.unwrap_or(self.n_outputs)
    }

    /// The module with fresh weights on `device`.
    pub fn init(&self, device: &Device) -> WrinkleRegressor {
        WrinkleRegressor {
            gru: FusedGru::new(self.n_inputs, self.hidden, device),
            dropout: DropoutConfig::new(self.dropout).init(),
            out: LinearConfig::new(self.hidden, self.output_width()).init(device),
        }
    }
}

/// `R_L`: per-frame `[β, pose]` → `Δ_L` (or its PCA coefficients).
#[derive(Module, Debug)]
pub struct WrinkleRegressor {
    gru: FusedGru,
    dropout: Dropout,
    out: Linear,
}

impl WrinkleRegressor {
    /// A zero hidden state for `batch` sequences.
    pub fn initial_state(&self, batch: usize, device: &Device) -> Tensor<2> {
        Tensor::zeros([batch, self.gru.hidden()], device)
    }

    /// Normalised outputs of a window, continuing from `state`.
    ///
    /// # Shapes
    /// - `inputs`: `[B, T, n_inputs]`
    /// - `state`: `[B, H]`
    /// - output: `[B, T, output_width]` and the last hidden state `[B, H]`
    pub fn forward(&self, inputs: Tensor<3>, state: Tensor<2>) -> (Tensor<3>, Tensor<2>) {
        let (hidden, last) = self.gru.forward(inputs, state);
        (self.out.forward(self.dropout.forward(hidden)), last)
    }

    pub(crate) fn parts(&self) -> (&FusedGru, &Linear) {
        (&self.gru, &self.out)
    }
}

/// The linear-regression baseline: one linear layer, no activation.
#[derive(Config, Debug)]
pub struct LinearRegressorConfig {
    /// Per-frame inputs `[β, pose features]`.
    pub n_inputs: usize,
    /// Displacement outputs `3V`.
    pub n_outputs: usize,
}

impl LinearRegressorConfig {
    /// The module with fresh weights on `device`.
    pub fn init(&self, device: &Device) -> LinearRegressor {
        LinearRegressor {
            linear: LinearConfig::new(self.n_inputs, self.n_outputs).init(device),
        }
    }
}

/// LR: one frame's `[β, pose]` → `Δ_L`.
#[derive(Module, Debug)]
pub struct LinearRegressor {
    linear: Linear,
}

impl LinearRegressor {
    /// Normalised `Δ_L` of normalised inputs.
    ///
    /// # Shapes
    /// - `inputs`: `[N, n_inputs]`
    /// - output: `[N, n_outputs]`
    pub fn forward(&self, inputs: Tensor<2>) -> Tensor<2> {
        self.linear.forward(inputs)
    }

    pub(crate) fn layer(&self) -> &Linear {
        &self.linear
    }

    /// Replace the weights (`[n_inputs, n_outputs]`, burn's row layout) and the bias.
    pub(crate) fn set_weights(&mut self, weight: Param<Tensor<2>>, bias: Param<Tensor<1>>) {
        self.linear.weight = weight;
        self.linear.bias = Some(bias);
    }
}
