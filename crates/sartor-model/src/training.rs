//! The training loops: one custom loop for the three regressors, with truncated
//! backpropagation through time for the GRU, validation each epoch, and resumable checkpoints.
//!
//! A run of one model lives in its own folder (`runs/<exp>/train/<model>/`):
//!
//! - `config.json` — the module's config (sizes and hyper-parameters), what
//!   [`crate::load_trained`] rebuilds the module from;
//! - `ckpt-EEEEE-BBBBB/{model,optim}.bpk` — the weights and Adam's state after `E` whole epochs
//!   and `B` batches of the next (burnpack files);
//! - `best.bpk` — the weights of the epoch with the lowest validation error;
//! - `state.json` — written last, atomically: which checkpoint is current, the loss curve, the
//!   best epoch, the time spent. A checkpoint folder is complete before `state.json` names it,
//!   so a kill at any moment leaves the previous checkpoint valid.
//!
//! Resuming loads the checkpoint `state.json` names and continues with the next batch of the
//! same deterministic shuffle, so a resumed run takes the same steps an uninterrupted one
//! would.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use burn::config::Config;
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device, Tensor};
use sartor_core::io::{read_file, sha256_hex, write_atomic};
use sartor_dataset::{
    Split, TrainingData, gather_frames, gather_shapes, sequence_batches, shuffled, window,
    window_count,
};
use serde::{Deserialize, Serialize};

use crate::Error;
use crate::contact::{ContactTerm, RestContact};
use crate::data::{PcaTensors, frames_of, tensor, to_vec, vertex_error_mm};
use crate::model::{
    FitRegressor, FitRegressorConfig, LinearRegressor, LinearRegressorConfig, WrinkleRegressor,
    WrinkleRegressorConfig,
};

static INIT_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Run `draw` (a module's `init`) with burn's random numbers seeded by `seed` (`None`: left as
/// they are), under one lock, and draw its weights there. burn's generator may be one per
/// process, and burn initialises parameters lazily, at their first use: a draw in another
/// thread between a seed and the first forward pass changes the weights. So every module of
/// this crate and of its callers' tests is made here, its parameters drawn before the lock is
/// released (a record of the module reads every one), or two trainings at once (tests run in
/// parallel) are not reproducible.
pub fn seeded<M: Module + Clone>(
    device: &Device,
    seed: Option<u64>,
    draw: impl FnOnce() -> M,
) -> M {
    let _guard = INIT_LOCK
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(seed) = seed {
        device.seed(seed);
    }
    let module = draw();
    drop(module.clone().into_record());
    module
}

/// The models `train` knows, by name.
pub const MODEL_NAMES: [&str; 3] = ["fit", "wrinkle", "linear"];

/// File of the module config inside a model's run folder.
pub const CONFIG_FILE: &str = "config.json";
/// File of the best weights inside a model's run folder.
pub const BEST_FILE: &str = "best.bpk";
/// File of the training state inside a model's run folder.
pub const STATE_FILE: &str = "state.json";

/// One of the three regressors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// The garment fit MLP `R_G(β)`.
    Fit,
    /// The garment wrinkle GRU `R_L(β, θ)`.
    Wrinkle,
    /// The linear-regression baseline.
    Linear,
}

impl ModelKind {
    /// All three, in training order.
    pub const ALL: [ModelKind; 3] = [Self::Fit, Self::Wrinkle, Self::Linear];

    /// The name used in folders and reports (one of [`MODEL_NAMES`]).
    pub fn name(self) -> &'static str {
        match self {
            Self::Fit => "fit",
            Self::Wrinkle => "wrinkle",
            Self::Linear => "linear",
        }
    }

    /// The kind of a name in [`MODEL_NAMES`].
    pub fn from_name(name: &str) -> crate::Result<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| {
                Error::invalid(
                    "model name",
                    format!("{name:?} is not one of {MODEL_NAMES:?}"),
                )
            })
    }
}

/// How one model is optimised.
#[derive(Config, Debug)]
pub struct StageConfig {
    /// Passes over the training data.
    pub epochs: usize,
    /// Shapes (fit), sequences (wrinkle) or frames (linear) per batch.
    pub batch_size: usize,
    /// Adam's learning rate (1e-4 in the paper).
    #[config(default = 1e-4)]
    pub learning_rate: f64,
    /// With a value, the rate decays from `learning_rate` at the first batch to this at the last
    /// along a half cosine (per batch, so a resumed run continues the same curve); without one
    /// it stays constant.
    #[config(default = "None")]
    pub final_learning_rate: Option<f64>,
}

impl StageConfig {
    /// The learning rate after `done` of `total` batches of the whole run.
    pub fn learning_rate_at(&self, done: usize, total: usize) -> f64 {
        match self.final_learning_rate {
            None => self.learning_rate,
            Some(end) => {
                let t = done as f64 / total.max(1) as f64;
                end + 0.5 * (self.learning_rate - end) * (1.0 + (std::f64::consts::PI * t).cos())
            }
        }
    }
}

/// The `training` section of an experiment config: every hyper-parameter of the three models.
#[derive(Config, Debug)]
pub struct TrainingConfig {
    /// The fit MLP's optimisation.
    pub fit: StageConfig,
    /// The wrinkle GRU's optimisation.
    pub wrinkle: StageConfig,
    /// The linear baseline: fitted in closed form (ridge regression, weight decay picked on
    /// validation; see `ridge.rs`), so only `epochs` matters — 0 skips it, more is one solve.
    pub linear: StageConfig,
    /// Hidden units of the fit MLP (20 in the paper).
    #[config(default = 20)]
    pub fit_hidden: usize,
    /// Hidden units of the wrinkle GRU (1500 in the paper).
    #[config(default = 1500)]
    pub gru_hidden: usize,
    /// Dropout of both networks (0.2 in the paper).
    #[config(default = 0.2)]
    pub dropout: f64,
    /// Dropout of the wrinkle GRU's output alone, in place of `dropout` (the fit MLP, with
    /// 17 training shapes, and the GRU, with hundreds of sequences, may want different ones).
    #[config(default = "None")]
    pub wrinkle_dropout: Option<f64>,
    /// Wrinkle output through the dataset's first `k` PCA components (`None`: dense).
    #[config(default = "None")]
    pub pca_components: Option<usize>,
    /// Frames per truncated-backpropagation window (90 in the paper).
    #[config(default = 90)]
    pub window_frames: usize,
    /// Seed of the weights and of the shuffles.
    #[config(default = 2019)]
    pub seed: u64,
    /// Weight of the wrinkle GRU's contact term ([`RestContact`]: a prediction deeper into the
    /// body, in the rest pose, than the ground truth and the margin is penalised); `None` or 0,
    /// the default, trains on the paper's loss alone.
    #[config(default = "None")]
    pub contact_weight: Option<f64>,
    /// The margin above the body the contact term asks of the garment, metres (`None`: the
    /// post-process's, [`DEFAULT_CONTACT_MARGIN_M`]).
    #[config(default = "None")]
    pub contact_margin_m: Option<f64>,
}

/// The contact term's margin where the config names none, metres: the post-process's.
pub const DEFAULT_CONTACT_MARGIN_M: f64 = 0.002;

impl TrainingConfig {
    /// The fit MLP's config for `data`.
    pub fn fit_config(&self, data: &TrainingData) -> FitRegressorConfig {
        FitRegressorConfig::new(data.n_betas(), data.n_outputs())
            .with_hidden(self.fit_hidden)
            .with_dropout(self.dropout)
    }

    /// The wrinkle GRU's config for `data`; the PCA size must not exceed the dataset's basis.
    pub fn wrinkle_config(&self, data: &TrainingData) -> crate::Result<WrinkleRegressorConfig> {
        if let Some(k) = self.pca_components {
            let have = data.pca().map_or(0, |p| p.n_components());
            if k == 0 || k > have {
                return Err(Error::invalid(
                    "training.pca_components",
                    format!("{k} components asked for, the dataset has a PCA basis of {have}"),
                ));
            }
        }
        Ok(
            WrinkleRegressorConfig::new(data.n_inputs(), data.n_outputs())
                .with_hidden(self.gru_hidden)
                .with_dropout(self.wrinkle_dropout.unwrap_or(self.dropout))
                .with_pca_components(self.pca_components),
        )
    }

    /// The linear baseline's config for `data`.
    pub fn linear_config(&self, data: &TrainingData) -> LinearRegressorConfig {
        LinearRegressorConfig::new(data.n_inputs(), data.n_outputs())
    }

    /// The contact term's weight (0: off, the paper's loss).
    pub fn contact_weight(&self) -> f64 {
        self.contact_weight.unwrap_or(0.0)
    }

    /// The contact term's margin, metres.
    pub fn contact_margin_m(&self) -> f64 {
        self.contact_margin_m.unwrap_or(DEFAULT_CONTACT_MARGIN_M)
    }

    /// The optimisation of `kind`.
    pub fn stage(&self, kind: ModelKind) -> &StageConfig {
        match kind {
            ModelKind::Fit => &self.fit,
            ModelKind::Wrinkle => &self.wrinkle,
            ModelKind::Linear => &self.linear,
        }
    }

    /// Check that every size is positive and every rate finite.
    pub fn validate(&self) -> crate::Result<()> {
        for kind in ModelKind::ALL {
            let s = self.stage(kind);
            if s.batch_size == 0 {
                return Err(Error::invalid(
                    "training",
                    format!("{}.batch_size is 0", kind.name()),
                ));
            }
            for (field, rate) in [
                ("learning_rate", Some(s.learning_rate)),
                ("final_learning_rate", s.final_learning_rate),
            ] {
                if let Some(rate) = rate
                    && !(rate.is_finite() && rate > 0.0)
                {
                    return Err(Error::invalid(
                        "training",
                        format!("{}.{field} {rate} is not positive", kind.name()),
                    ));
                }
            }
        }
        for (field, value) in [
            ("contact_weight", self.contact_weight()),
            ("contact_margin_m", self.contact_margin_m()),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(Error::invalid(
                    "training",
                    format!("{field} {value} is not a finite value of at least 0"),
                ));
            }
        }
        if self.fit_hidden == 0 || self.gru_hidden == 0 || self.window_frames == 0 {
            return Err(Error::invalid(
                "training",
                "fit_hidden, gru_hidden and window_frames must be positive",
            ));
        }
        if let Some(p) = self.wrinkle_dropout
            && !(0.0..1.0).contains(&p)
        {
            return Err(Error::invalid(
                "training",
                format!("wrinkle_dropout {p} is not in [0, 1)"),
            ));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(Error::invalid(
                "training",
                format!("dropout {} is not in [0, 1)", self.dropout),
            ));
        }
        Ok(())
    }
}

/// One finished epoch.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    /// 1-based.
    pub epoch: usize,
    /// Mean training loss (MSE in normalised units).
    pub train_loss: f64,
    /// Mean per-vertex error on the validation split, mm (`None` without one).
    pub val_error_mm: Option<f64>,
    /// Seconds since the run began (over all resumptions).
    pub elapsed_s: f64,
}

/// What a model's training reports (`train.json` holds one per model).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelReport {
    /// The model name.
    pub model: String,
    /// Epochs done.
    pub epochs: usize,
    /// Training frames (fit: shapes) per epoch.
    pub frames_per_epoch: usize,
    /// Trainable parameters.
    pub parameters: usize,
    /// Seconds of training (over all resumptions).
    pub wall_time_s: f64,
    /// Training frames processed per second.
    pub frames_per_s: f64,
    /// Lowest validation error, mm (`None` without a validation split).
    pub best_val_error_mm: Option<f64>,
    /// The epoch that reached it (its weights are `best.bpk`).
    pub best_epoch: Option<usize>,
    /// The last epoch's training loss.
    pub final_train_loss: Option<f64>,
    /// The validation split used: `held_out_shapes` (fit) or `held_out_motions`.
    pub validation: Split,
    /// Whether training stopped on request before its last epoch.
    pub interrupted: bool,
    /// Every epoch.
    pub curve: Vec<EpochRecord>,
}

/// The lowest validation error so far.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct Best {
    epoch: usize,
    val_error_mm: f64,
}

/// `state.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TrainState {
    model: String,
    fingerprint: String,
    checkpoint: String,
    epochs_done: usize,
    batches_done: usize,
    partial_loss_sum: f64,
    partial_loss_frames: f64,
    curve: Vec<EpochRecord>,
    best: Option<Best>,
    wall_time_s: f64,
    frames_seen: u64,
}

/// What the loop tells whoever shows progress.
pub trait Progress {
    /// Training of `model` (re)starts at `epoch` (1-based) of `epochs`, with `steps_per_epoch`
    /// optimiser steps per epoch, `steps_done` of them already done in this epoch.
    fn start(
        &mut self,
        model: &str,
        epoch: usize,
        epochs: usize,
        steps_per_epoch: usize,
        steps_done: usize,
    );
    /// One optimiser step with this batch loss.
    fn step(&mut self, loss: f64);
    /// An epoch ended.
    fn epoch(&mut self, record: &EpochRecord);
}

/// A [`Progress`] that shows nothing.
pub struct Silent;

impl Progress for Silent {
    fn start(&mut self, _: &str, _: usize, _: usize, _: usize, _: usize) {}
    fn step(&mut self, _: f64) {}
    fn epoch(&mut self, _: &EpochRecord) {}
}

/// Where and how a model is trained.
pub struct TrainOptions<'a> {
    /// The model's run folder (`runs/<exp>/train/<model>`).
    pub dir: PathBuf,
    /// An autodiff device (`Device::flex().autodiff()`).
    pub device: Device,
    /// Continue from the folder's checkpoint (refused when it was made with other settings);
    /// without it an existing checkpoint is an error, so nothing is overwritten by mistake.
    pub resume: bool,
    /// Set (e.g. on Ctrl-C) to checkpoint after the current batch and return.
    pub stop: &'a AtomicBool,
    /// The body under the training shapes' garments, for the wrinkle GRU's contact term
    /// (needed where [`TrainingConfig::contact_weight`] is above 0; unread otherwise).
    pub contact: Option<&'a RestContact>,
}

/// The three modules, for code that handles any of them.
#[derive(Debug, Clone)]
pub enum AnyModel {
    /// Fit MLP.
    Fit(FitRegressor),
    /// Wrinkle GRU.
    Wrinkle(WrinkleRegressor),
    /// Linear baseline.
    Linear(LinearRegressor),
}

/// A module, what it learns from and how its loss and validation are computed.
trait Task {
    type M: Module + Clone;
    fn init(&self, device: &Device) -> Self::M;
    /// Epochs to run when the config asks for `configured`.
    fn epochs(&self, configured: usize) -> usize {
        configured
    }
    /// Items (shapes, frames) per epoch.
    fn frames_per_epoch(&self) -> usize;
    /// Batches of epoch `epoch` (0-based), each a list of item indices in the task's own terms.
    fn batches(&self, epoch: usize) -> Vec<Vec<usize>>;
    /// Optimiser steps one batch takes.
    fn steps(&self, batch: &[usize]) -> usize;
    /// Train on one batch; calls `on_step(loss, frames)` after every optimiser step.
    fn train_batch(
        &self,
        model: Self::M,
        optim: &mut ModuleOptimizer,
        lr: f64,
        batch: &[usize],
        on_step: &mut dyn FnMut(f64, usize),
    ) -> Self::M;
    /// Mean per-vertex validation error in mm, if there is a validation split.
    fn validate(&self, model: &Self::M) -> Option<f64>;
    fn validation_split(&self) -> Split;
}

fn masked_mse(
    pred: Tensor<2>,
    target: Tensor<2>,
    weights: Option<Tensor<2>>,
    denominator: f64,
) -> Tensor<1> {
    let d = pred - target;
    let sq = d.clone() * d;
    let sq = match weights {
        Some(w) => sq * w,
        None => sq,
    };
    sq.sum().div_scalar(denominator)
}

/// [`window_losses`] without the contact term.
#[cfg(test)]
pub(crate) fn window_loss(
    model: &WrinkleRegressor,
    x: Tensor<3>,
    y: Tensor<2>,
    mask: Tensor<2>,
    state: Tensor<2>,
    denominator: f64,
) -> (Tensor<1>, Tensor<2>) {
    window_losses(model, (x, y, mask), state, denominator, None)
}

/// The contact term of one window ([`ContactTerm::window`]'s `a` `[B·L, 3V]` and floors
/// `[B·L, V]` as tensors), its weight, and the PCA basis that takes the network's output to
/// the displacements (`None`: dense output).
pub(crate) struct ContactWindow<'a> {
    a: Tensor<2>,
    floor: Tensor<2>,
    weight: f64,
    pca: Option<&'a PcaTensors>,
}

/// One window of truncated backpropagation through time: the masked loss of `model` on the
/// window `x` (`[B, L, I]`, targets `y` `[B·L, O]`, `mask` `[B·L, 1]`) from `state`, with
/// `contact` the contact term added, and the state to carry into the next window, detached:
/// the next window starts from its value, but its gradient stops at the boundary.
fn window_losses(
    model: &WrinkleRegressor,
    (x, y, mask): (Tensor<3>, Tensor<2>, Tensor<2>),
    state: Tensor<2>,
    denominator: f64,
    contact: Option<ContactWindow<'_>>,
) -> (Tensor<1>, Tensor<2>) {
    let [b, l, _] = x.dims();
    let rows = b * l;
    let (pred, last) = model.forward(x, state);
    let width = pred.dims()[2];
    let pred = pred.reshape([rows, width]);
    let mut loss = masked_mse(pred.clone(), y, Some(mask), denominator);
    if let Some(c) = contact {
        let p = match c.pca {
            Some(pca) => pca.reconstruct(pred),
            None => pred,
        };
        let n = c.floor.dims()[1];
        // Each vertex's prediction along the body's normal, and its depth below the floor.
        let along = (p * c.a)
            .reshape([rows, n, 3])
            .sum_dim(2)
            .reshape([rows, n]);
        let depth = (c.floor - along).clamp_min(0.0);
        // Per vertex of the real frames (the MSE's denominator is per component).
        loss = loss
            + (depth.clone() * depth)
                .sum()
                .mul_scalar(c.weight * 3.0 / denominator);
    }
    (loss, last.detach())
}

/// One optimiser step of a frame-wise regressor on inputs `x` (`[N, n_in]`) and targets `y`
/// (`[N, O]`), both normalised; returns the model and the batch's MSE.
fn regression_step<M: Module>(
    model: M,
    forward: fn(&M, Tensor<2>) -> Tensor<2>,
    x: Vec<f32>,
    y: Vec<f32>,
    n_in: usize,
    device: &Device,
    optim: &mut ModuleOptimizer,
    lr: f64,
) -> (M, f64) {
    let n = x.len() / n_in;
    let n_out = y.len() / n.max(1);
    let x = tensor(x, [n, n_in], device);
    let y = tensor(y, [n, n_out], device);
    let loss = masked_mse(forward(&model, x), y, None, (n * n_out) as f64);
    backward_step(model, loss, optim, lr)
}

fn backward_step<M: Module>(
    model: M,
    loss: Tensor<1>,
    optim: &mut ModuleOptimizer,
    lr: f64,
) -> (M, f64) {
    let value = f64::from(loss.clone().into_scalar::<f32>());
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    (optim.step(lr, model, grads), value)
}

/// Normalised inputs `[N, n_in]` and targets `[N, 3V]` of some items.
type Gather<S> = fn(&TrainingData, &[S]) -> (Vec<f32>, Vec<f32>);

/// A frame-wise regressor, one optimiser step per batch: the fit MLP over shapes (`S` a shape
/// index) and the linear baseline over frames (`S` a `(sequence, frame)`).
struct RegressionTask<'a, M, S> {
    data: &'a TrainingData,
    init: Box<dyn Fn(&Device) -> M + 'a>,
    forward: fn(&M, Tensor<2>) -> Tensor<2>,
    gather: Gather<S>,
    n_in: usize,
    /// The targets' normalisation, to report validation error in mm.
    out_std: &'a [f32],
    split: Split,
    batch_size: usize,
    seed: u64,
    /// The training items; batches index into it.
    train: Vec<S>,
    val: Vec<S>,
    device: Device,
}

/// Validation items per forward pass.
const EVAL_FRAMES: usize = 512;

impl<M: Module + Clone, S: Copy> Task for RegressionTask<'_, M, S> {
    type M = M;
    fn init(&self, device: &Device) -> M {
        (self.init)(device)
    }
    fn frames_per_epoch(&self) -> usize {
        self.train.len()
    }
    fn batches(&self, epoch: usize) -> Vec<Vec<usize>> {
        let all: Vec<usize> = (0..self.train.len()).collect();
        shuffled(&all, self.seed, epoch as u64)
            .chunks(self.batch_size)
            .map(<[usize]>::to_vec)
            .collect()
    }
    fn steps(&self, _: &[usize]) -> usize {
        1
    }
    fn train_batch(
        &self,
        model: M,
        optim: &mut ModuleOptimizer,
        lr: f64,
        batch: &[usize],
        on_step: &mut dyn FnMut(f64, usize),
    ) -> M {
        let items: Vec<S> = batch.iter().map(|&i| self.train[i]).collect();
        let (x, y) = (self.gather)(self.data, &items);
        let (model, value) = regression_step(
            model,
            self.forward,
            x,
            y,
            self.n_in,
            &self.device,
            optim,
            lr,
        );
        on_step(value, items.len());
        model
    }
    fn validate(&self, model: &M) -> Option<f64> {
        if self.val.is_empty() {
            return None;
        }
        let model = model.valid();
        let device = self.device.clone().inner();
        let (mut sum, mut count) = (0.0, 0);
        for chunk in self.val.chunks(EVAL_FRAMES) {
            let (x, y) = (self.gather)(self.data, chunk);
            let x = tensor(x, [chunk.len(), self.n_in], &device);
            let pred = to_vec((self.forward)(&model, x));
            let (s, c) = vertex_error_mm(&pred, &y, self.out_std, None);
            sum += s;
            count += c;
        }
        Some(sum / count.max(1) as f64)
    }
    fn validation_split(&self) -> Split {
        self.split
    }
}

/// The linear baseline in closed form ([`crate::ridge`]): one "epoch" of one step, which
/// solves the normal equations and picks the weight decay on the validation motions. Batching,
/// validation and the rest are the frame-wise regression task's.
struct RidgeTask<'a> {
    frames: RegressionTask<'a, LinearRegressor, (usize, usize)>,
}

impl Task for RidgeTask<'_> {
    type M = LinearRegressor;
    fn init(&self, device: &Device) -> LinearRegressor {
        self.frames.init(device)
    }
    fn epochs(&self, configured: usize) -> usize {
        configured.min(1)
    }
    fn frames_per_epoch(&self) -> usize {
        self.frames.frames_per_epoch()
    }
    fn batches(&self, _: usize) -> Vec<Vec<usize>> {
        vec![Vec::new()]
    }
    fn steps(&self, _: &[usize]) -> usize {
        1
    }
    fn train_batch(
        &self,
        model: LinearRegressor,
        _: &mut ModuleOptimizer,
        _: f64,
        _: &[usize],
        on_step: &mut dyn FnMut(f64, usize),
    ) -> LinearRegressor {
        let f = &self.frames;
        let mut model = model;
        // Singular for every weight decay (cannot happen with λ > 0): a non-finite loss stops
        // the run as a divergence.
        let train_mse = crate::ridge::fit(f.data, &mut model, &f.train, &f.val, &f.device);
        on_step(train_mse.unwrap_or(f64::NAN), f.train.len());
        model
    }
    fn validate(&self, model: &LinearRegressor) -> Option<f64> {
        self.frames.validate(model)
    }
    fn validation_split(&self) -> Split {
        self.frames.validation_split()
    }
}

struct WrinkleTask<'a> {
    data: &'a TrainingData,
    config: WrinkleRegressorConfig,
    batch_size: usize,
    window_frames: usize,
    seed: u64,
    train: Vec<usize>,
    val: Vec<usize>,
    /// The split `val` comes from.
    split: Split,
    pca: Option<PcaTensors>,
    /// The contact term, where its weight is above 0.
    contact: Option<ContactTerm>,
    device: Device,
}

impl WrinkleTask<'_> {
    /// Targets of a window in the network's output space (`[B·L, O]`).
    fn targets(&self, targets: Vec<f32>, rows: usize, device: &Device) -> Tensor<2> {
        let y = tensor(targets, [rows, self.data.n_outputs()], device);
        match &self.pca {
            Some(pca) => pca.project(y),
            None => y,
        }
    }
}

impl Task for WrinkleTask<'_> {
    type M = WrinkleRegressor;
    fn init(&self, device: &Device) -> WrinkleRegressor {
        self.config.init(device)
    }
    fn frames_per_epoch(&self) -> usize {
        frames_of(self.data, &self.train)
    }
    fn batches(&self, epoch: usize) -> Vec<Vec<usize>> {
        sequence_batches(&self.train, self.batch_size, self.seed, epoch as u64)
    }
    fn steps(&self, batch: &[usize]) -> usize {
        window_count(self.data, batch, self.window_frames)
    }
    fn train_batch(
        &self,
        mut model: WrinkleRegressor,
        optim: &mut ModuleOptimizer,
        lr: f64,
        batch: &[usize],
        on_step: &mut dyn FnMut(f64, usize),
    ) -> WrinkleRegressor {
        let b = batch.len();
        let (n_in, n3) = (self.data.n_inputs(), self.data.n_outputs());
        let mut state = model.initial_state(b, &self.device);
        for index in 0..window_count(self.data, batch, self.window_frames) {
            let w = window(self.data, batch, self.window_frames, index);
            let rows = b * w.len;
            let real: f32 = w.mask.iter().sum();
            let x = tensor(w.inputs, [b, w.len, n_in], &self.device);
            let contact = self.contact.as_ref().map(|term| {
                let (a, floor) = term.window(self.data, batch, w.len, &w.targets, &w.mask);
                ContactWindow {
                    a: tensor(a, [rows, n3], &self.device),
                    floor: tensor(floor, [rows, n3 / 3], &self.device),
                    weight: term.weight,
                    pca: self.pca.as_ref(),
                }
            });
            let y = self.targets(w.targets, rows, &self.device);
            let mask = tensor(w.mask, [rows, 1], &self.device);
            // The mean squared error per displacement component: with a PCA output this is the
            // full-space MSE less the constant truncation residual (the basis is orthonormal).
            let (loss, carried) = window_losses(
                &model,
                (x, y, mask),
                state,
                f64::from(real) * n3 as f64,
                contact,
            );
            let value;
            (model, value) = backward_step(model, loss, optim, lr);
            state = carried;
            on_step(value, real as usize);
        }
        model
    }
    fn validate(&self, model: &WrinkleRegressor) -> Option<f64> {
        if self.val.is_empty() {
            return None;
        }
        let model = model.valid();
        let device = self.device.clone().inner();
        let pca = self.pca.as_ref().map(|p| PcaTensors {
            basis: p.basis.clone().inner(),
            mean: p.mean.clone().inner(),
        });
        let (n_in, n3) = (self.data.n_inputs(), self.data.n_outputs());
        let (mut sum, mut count) = (0.0, 0);
        for batch in self.val.chunks(self.batch_size) {
            let b = batch.len();
            let mut state = model.initial_state(b, &device);
            for index in 0..window_count(self.data, batch, self.window_frames) {
                let w = window(self.data, batch, self.window_frames, index);
                let rows = b * w.len;
                let x = tensor(w.inputs, [b, w.len, n_in], &device);
                let (pred, last) = model.forward(x, state);
                state = last;
                let width = pred.dims()[2];
                let pred = pred.reshape([rows, width]);
                let pred = match &pca {
                    Some(p) => p.reconstruct(pred),
                    None => pred,
                };
                debug_assert_eq!(pred.dims()[1], n3);
                let (s, c) = vertex_error_mm(
                    &to_vec(pred),
                    &w.targets,
                    &self.data.stats().wrinkle_out.std,
                    Some(&w.mask),
                );
                sum += s;
                count += c;
            }
        }
        Some(sum / count.max(1) as f64)
    }
    fn validation_split(&self) -> Split {
        self.split
    }
}

fn json_error(path: &Path, e: serde_json::Error) -> Error {
    Error::checkpoint(path, format!("malformed JSON: {e}"))
}

fn record_error(path: &Path, e: burn::store::RecordError) -> Error {
    Error::checkpoint(path, e.to_string())
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> crate::Result<()> {
    let text = serde_json::to_vec_pretty(value).map_err(|e| json_error(path, e))?;
    write_atomic(path, &text)?;
    Ok(())
}

/// Save a module's weights to a burnpack file, atomically.
pub fn save_weights<M: Module>(model: &M, path: &Path) -> crate::Result<()> {
    let bytes = model
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| record_error(path, e))?;
    write_atomic(path, &bytes)?;
    Ok(())
}

/// Load weights saved by [`save_weights`] (or training) into `model`; names and shapes are
/// checked, and a mismatch is an error naming the file.
pub fn load_weights<M: Module>(model: M, path: &Path) -> crate::Result<M> {
    let bytes = read_file(path)?;
    let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(bytes))
        .map_err(|e| record_error(path, e))?;
    model
        .try_load_record(record)
        .map_err(|e| record_error(path, e))
}

/// A stable hash of what determines a run: the module and stage configs, the window and seed,
/// and the data's identity (its garment, body, sizes and split sizes).
fn fingerprint(
    kind: ModelKind,
    module_config: &str,
    config: &TrainingConfig,
    data: &TrainingData,
) -> String {
    let s = config.stage(kind);
    let text = format!(
        "{}|{module_config}|{}|{}|{:?}|{}|{}|{}|{:?}|{}|{}|{}|{}",
        kind.name(),
        s.batch_size,
        s.learning_rate,
        s.final_learning_rate,
        config.window_frames,
        config.seed,
        data.n_outputs(),
        data.source(),
        data.n_inputs(),
        data.shapes().len(),
        data.sequences().len(),
        frames_of(data, &data.sequence_indices(Split::Train)),
    );
    // The contact term changes the wrinkle GRU's loss only (and the fingerprints of runs
    // without it stay as they were).
    let text = if kind == ModelKind::Wrinkle && config.contact_weight() > 0.0 {
        format!(
            "{text}|contact {}|{}",
            config.contact_weight(),
            config.contact_margin_m()
        )
    } else {
        text
    };
    sha256_hex(text.as_bytes())
}

/// Train one model on `data`, checkpointing into `options.dir`.
pub fn train_model(
    kind: ModelKind,
    data: &TrainingData,
    config: &TrainingConfig,
    options: &TrainOptions<'_>,
    progress: &mut dyn Progress,
) -> crate::Result<ModelReport> {
    config.validate()?;
    let stage = config.stage(kind);
    let device = options.device.clone();
    let cx = RunContext {
        kind,
        config,
        data,
        options,
    };
    let train = |split| match kind {
        ModelKind::Fit => data.shape_indices(split),
        _ => data.sequence_indices(split),
    };
    // The validation split, else (a config without one) the held-out one.
    let validation = |held_out| {
        if train(Split::Validation).is_empty() {
            held_out
        } else {
            Split::Validation
        }
    };
    match kind {
        ModelKind::Fit => {
            let module = config.fit_config(data);
            let init = module.clone();
            let task = RegressionTask {
                data,
                init: Box::new(move |device| init.init(device)),
                forward: FitRegressor::forward,
                gather: gather_shapes,
                n_in: data.n_betas(),
                out_std: &data.stats().fit_out.std,
                split: validation(Split::HeldOutShapes),
                batch_size: stage.batch_size,
                seed: config.seed,
                train: train(Split::Train),
                val: train(validation(Split::HeldOutShapes)),
                device,
            };
            run(&task, &module.to_string(), &cx, progress)
        }
        ModelKind::Linear => {
            let module = config.linear_config(data);
            let init = module.clone();
            let frames = |split| -> Vec<(usize, usize)> {
                train(split)
                    .into_iter()
                    .flat_map(|s| (0..data.sequences()[s].n_frames).map(move |t| (s, t)))
                    .collect()
            };
            let frames = RegressionTask {
                data,
                init: Box::new(move |device| init.init(device)),
                forward: LinearRegressor::forward,
                gather: gather_frames,
                n_in: data.n_inputs(),
                out_std: &data.stats().wrinkle_out.std,
                split: validation(Split::HeldOutMotions),
                batch_size: stage.batch_size,
                seed: config.seed,
                train: frames(Split::Train),
                val: frames(validation(Split::HeldOutMotions)),
                device,
            };
            let task = RidgeTask { frames };
            run(&task, &module.to_string(), &cx, progress)
        }
        ModelKind::Wrinkle => {
            let module = config.wrinkle_config(data)?;
            let pca = match (module.pca_components, data.pca()) {
                (Some(k), Some(basis)) => Some(PcaTensors::new(basis, k, &device)),
                _ => None,
            };
            let contact = if config.contact_weight() > 0.0 {
                let rest = options.contact.ok_or_else(|| {
                    Error::invalid(
                        "training.contact_weight",
                        "the contact term needs the body and the garment's template \
                         (TrainOptions::contact)",
                    )
                })?;
                if (rest.n_vertices(), rest.n_shapes()) != (data.n_vertices(), data.shapes().len())
                {
                    return Err(Error::invalid(
                        "contact term",
                        format!(
                            "made for {} garment vertices and {} shapes, the training data has \
                             {} and {}",
                            rest.n_vertices(),
                            rest.n_shapes(),
                            data.n_vertices(),
                            data.shapes().len()
                        ),
                    ));
                }
                Some(ContactTerm::new(
                    rest,
                    data,
                    config.contact_weight(),
                    config.contact_margin_m(),
                ))
            } else {
                None
            };
            let task = WrinkleTask {
                data,
                contact,
                batch_size: stage.batch_size,
                window_frames: config.window_frames,
                seed: config.seed,
                train: train(Split::Train),
                val: train(validation(Split::HeldOutMotions)),
                split: validation(Split::HeldOutMotions),
                pca,
                device,
                config: module.clone(),
            };
            run(&task, &module.to_string(), &cx, progress)
        }
    }
}

/// What every task's run shares: the model, the settings, the data and the run's options.
#[derive(Clone, Copy)]
struct RunContext<'a> {
    kind: ModelKind,
    config: &'a TrainingConfig,
    data: &'a TrainingData,
    options: &'a TrainOptions<'a>,
}

fn run<T: Task>(
    task: &T,
    module_config: &str,
    cx: &RunContext<'_>,
    progress: &mut dyn Progress,
) -> crate::Result<ModelReport> {
    let RunContext {
        kind,
        config,
        data,
        options,
    } = *cx;
    let dir = &options.dir;
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.clone(),
        source,
    })?;
    let stage = config.stage(kind);
    let name = kind.name();
    if task.frames_per_epoch() == 0 {
        return Err(Error::invalid(
            "training data",
            format!("{name}: no training samples"),
        ));
    }
    let fingerprint = fingerprint(kind, module_config, config, data);
    let state_path = dir.join(STATE_FILE);
    let device = &options.device;
    let seed = config.seed ^ (kind as u64 + 1).wrapping_mul(0x9E37_79B9);
    let mut model = seeded(device, Some(seed), || task.init(device));
    let mut optim = AdamConfig::new().init();
    let mut state = if state_path.exists() {
        let state: TrainState = serde_json::from_slice(&read_file(&state_path)?)
            .map_err(|e| json_error(&state_path, e))?;
        if !options.resume {
            return Err(Error::checkpoint(
                &state_path,
                "a training run is already here: resume it, or remove the folder to start over",
            ));
        }
        if state.fingerprint != fingerprint || state.model != name {
            return Err(Error::checkpoint(
                &state_path,
                "the checkpoint was made with other settings or data; remove the folder to start over",
            ));
        }
        let ckpt = dir.join(&state.checkpoint);
        model = load_weights(model, &ckpt.join("model.bpk"))?;
        let optim_path = ckpt.join("optim.bpk");
        optim = optim
            .from_bytes(Bytes::from_bytes_vec(read_file(&optim_path)?))
            .map_err(|e| record_error(&optim_path, e))?;
        state
    } else {
        write_atomic(&dir.join(CONFIG_FILE), module_config.as_bytes())?;
        TrainState {
            model: name.into(),
            fingerprint,
            checkpoint: String::new(),
            epochs_done: 0,
            batches_done: 0,
            partial_loss_sum: 0.0,
            partial_loss_frames: 0.0,
            curve: Vec::new(),
            best: None,
            wall_time_s: 0.0,
            frames_seen: 0,
        }
    };

    let start = Instant::now();
    let base_time = state.wall_time_s;
    let elapsed = |start: &Instant| base_time + start.elapsed().as_secs_f64();
    let mut interrupted = false;
    let epochs = task.epochs(stage.epochs);
    while state.epochs_done < epochs {
        let epoch = state.epochs_done;
        let batches = task.batches(epoch);
        let steps: usize = batches.iter().map(|b| task.steps(b)).sum();
        let steps_done: usize = batches[..state.batches_done.min(batches.len())]
            .iter()
            .map(|b| task.steps(b))
            .sum();
        progress.start(name, epoch + 1, epochs, steps, steps_done);
        for batch in &batches[state.batches_done.min(batches.len())..] {
            let mut diverged = None;
            let (mut loss_sum, mut loss_frames) = (0.0, 0.0);
            // Every epoch has the same number of batches (a shuffle of the same split).
            let rate = stage.learning_rate_at(
                epoch * batches.len() + state.batches_done,
                stage.epochs * batches.len(),
            );
            model = task.train_batch(model, &mut optim, rate, batch, &mut |loss, frames| {
                if !loss.is_finite() {
                    diverged = Some(loss);
                }
                loss_sum += loss * frames as f64;
                loss_frames += frames as f64;
                progress.step(loss);
            });
            if let Some(loss) = diverged {
                return Err(Error::Diverged {
                    model: name.into(),
                    epoch: epoch + 1,
                    loss,
                });
            }
            state.partial_loss_sum += loss_sum;
            state.partial_loss_frames += loss_frames;
            state.frames_seen += loss_frames as u64;
            state.batches_done += 1;
            if options.stop.load(Ordering::SeqCst) {
                interrupted = true;
                break;
            }
        }
        if interrupted {
            state.wall_time_s = elapsed(&start);
            checkpoint(dir, &mut state, &model, &optim)?;
            break;
        }
        let train_loss = state.partial_loss_sum / state.partial_loss_frames.max(1.0);
        let val = task.validate(&model);
        let record = EpochRecord {
            epoch: epoch + 1,
            train_loss,
            val_error_mm: val,
            elapsed_s: elapsed(&start),
        };
        progress.epoch(&record);
        state.curve.push(record);
        state.epochs_done += 1;
        state.batches_done = 0;
        state.partial_loss_sum = 0.0;
        state.partial_loss_frames = 0.0;
        let improved = match (val, state.best) {
            (Some(v), Some(b)) => v < b.val_error_mm,
            (Some(_), None) => true,
            (None, _) => true,
        };
        if improved {
            save_weights(&model, &dir.join(BEST_FILE))?;
            if let Some(v) = val {
                state.best = Some(Best {
                    epoch: epoch + 1,
                    val_error_mm: v,
                });
            }
        }
        state.wall_time_s = elapsed(&start);
        checkpoint(dir, &mut state, &model, &optim)?;
    }
    if state.curve.is_empty() && !dir.join(BEST_FILE).exists() {
        // Stopped inside the first epoch: the current weights are the best there are.
        save_weights(&model, &dir.join(BEST_FILE))?;
    }
    let train_seconds = state.wall_time_s.max(1e-9);
    Ok(ModelReport {
        model: name.into(),
        epochs: state.epochs_done,
        frames_per_epoch: task.frames_per_epoch(),
        parameters: model.num_params(),
        wall_time_s: state.wall_time_s,
        frames_per_s: state.frames_seen as f64 / train_seconds,
        best_val_error_mm: state.best.map(|b| b.val_error_mm),
        best_epoch: state.best.map(|b| b.epoch),
        final_train_loss: state.curve.last().map(|r| r.train_loss),
        validation: task.validation_split(),
        interrupted,
        curve: state.curve,
    })
}

/// Write a new checkpoint folder, then `state.json` naming it, then remove the old folder.
fn checkpoint<M: Module>(
    dir: &Path,
    state: &mut TrainState,
    model: &M,
    optim: &ModuleOptimizer,
) -> crate::Result<()> {
    let name = format!("ckpt-{:05}-{:05}", state.epochs_done, state.batches_done);
    let ckpt = dir.join(&name);
    std::fs::create_dir_all(&ckpt).map_err(|source| Error::Io {
        path: ckpt.clone(),
        source,
    })?;
    save_weights(model, &ckpt.join("model.bpk"))?;
    let optim_path = ckpt.join("optim.bpk");
    let bytes = optim
        .into_bytes()
        .map_err(|e| record_error(&optim_path, e))?;
    write_atomic(&optim_path, &bytes)?;
    let old = std::mem::replace(&mut state.checkpoint, name);
    write_json(&dir.join(STATE_FILE), state)?;
    if !old.is_empty() && old != state.checkpoint {
        // The old checkpoint is no longer named anywhere; failing to remove it loses nothing.
        let _ = std::fs::remove_dir_all(dir.join(old));
    }
    Ok(())
}

/// The best weights of a trained model, rebuilt from its run folder on `device`.
pub fn load_trained(kind: ModelKind, dir: &Path, device: &Device) -> crate::Result<AnyModel> {
    let config_path = dir.join(CONFIG_FILE);
    let text = read_file(&config_path)?;
    let best = dir.join(BEST_FILE);
    let bad = |e: serde_json::Error| json_error(&config_path, e);
    Ok(match kind {
        ModelKind::Fit => {
            let c: FitRegressorConfig = serde_json::from_slice(&text).map_err(bad)?;
            AnyModel::Fit(load_weights(
                seeded(device, None, || c.init(device)),
                &best,
            )?)
        }
        ModelKind::Wrinkle => {
            let c: WrinkleRegressorConfig = serde_json::from_slice(&text).map_err(bad)?;
            AnyModel::Wrinkle(load_weights(
                seeded(device, None, || c.init(device)),
                &best,
            )?)
        }
        ModelKind::Linear => {
            let c: LinearRegressorConfig = serde_json::from_slice(&text).map_err(bad)?;
            AnyModel::Linear(load_weights(
                seeded(device, None, || c.init(device)),
                &best,
            )?)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::FusedGru;

    #[test]
    fn cosine_rate_runs_from_the_first_rate_to_the_final_one() {
        let constant = StageConfig::new(10, 4).with_learning_rate(1e-3);
        assert_eq!(constant.learning_rate_at(7, 40), 1e-3);
        let decayed = constant.with_final_learning_rate(Some(1e-5));
        assert_eq!(decayed.learning_rate_at(0, 40), 1e-3);
        assert!((decayed.learning_rate_at(40, 40) - 1e-5).abs() < 1e-18);
        assert!((decayed.learning_rate_at(20, 40) - 0.5 * (1e-3 + 1e-5)).abs() < 1e-15);
        let rates: Vec<f64> = (0..=40).map(|b| decayed.learning_rate_at(b, 40)).collect();
        assert!(rates.windows(2).all(|w| w[1] < w[0]), "{rates:?}");
    }

    fn ramp(shape: [usize; 3], scale: f32, device: &Device) -> Tensor<3> {
        let n = shape.iter().product::<usize>();
        tensor(
            (0..n).map(|i| scale * ((i as f32) * 0.37).sin()).collect(),
            shape,
            device,
        )
    }

    /// The state carried into the next window holds the previous window's value (the second
    /// window's output depends on the first window's inputs) but not its gradient (the second
    /// window's loss has no gradient with respect to the first window's inputs).
    #[test]
    fn tbptt_carries_the_state_but_not_the_gradient() {
        let device = Device::flex().autodiff();
        let model = seeded(&device, Some(7), || {
            WrinkleRegressorConfig::new(3, 6)
                .with_hidden(8)
                .with_dropout(0.0)
                .init(&device)
        });
        let (b, l) = (2, 4);
        let x1 = ramp([b, l, 3], 1.0, &device).require_grad();
        let x2 = ramp([b, l, 3], -0.5, &device).require_grad();
        let y = Tensor::<2>::zeros([b * l, 6], &device);
        let mask = Tensor::<2>::ones([b * l, 1], &device);
        let zero = model.initial_state(b, &device);
        let (_, carried) = window_loss(
            &model,
            x1.clone(),
            y.clone(),
            mask.clone(),
            zero.clone(),
            1.0,
        );
        assert!(
            !carried.is_require_grad(),
            "the carried state must be detached"
        );
        let (loss, _) = window_loss(
            &model,
            x2.clone(),
            y.clone(),
            mask.clone(),
            carried.clone(),
            1.0,
        );
        let grads = loss.backward();
        assert!(
            x1.grad(&grads).is_none(),
            "gradient leaked through the window boundary"
        );
        let g2 = x2
            .grad(&grads)
            .expect("the second window's inputs get a gradient");
        assert!(to_vec(g2).iter().any(|v| v.abs() > 0.0));
        // The state did carry: starting the second window from zero gives another loss.
        let (fresh, _) = window_loss(&model, x2, y, mask, zero, 1.0);
        let (a, c) = (loss.into_scalar::<f32>(), fresh.into_scalar::<f32>());
        assert!((a - c).abs() > 1e-6 * a.abs().max(1e-6), "{a} vs {c}");
        // Without the detach, the gradient would have reached the first window.
        let (pred1, last) = model.forward(x1.clone(), model.initial_state(b, &device));
        drop(pred1);
        let (pred2, _) = model.forward(ramp([b, l, 3], -0.5, &device), last);
        let grads = pred2.sum().backward();
        assert!(
            x1.grad(&grads).is_some(),
            "the test's control must see the gradient"
        );
    }

    #[test]
    fn fused_gru_matches_the_equations_step_by_step() {
        let device = Device::flex();
        let gru = seeded(&device, Some(3), || FusedGru::new(2, 3, &device));
        let x = ramp([1, 2, 2], 0.8, &device);
        let (out, last) = gru.forward(x.clone(), Tensor::zeros([1, 3], &device));
        let [w_ih, w_hh] = gru.params();
        let [b_ih, b_hh] = gru.biases();
        let (w_ih, w_hh, b_ih, b_hh) = (to_vec(w_ih), to_vec(w_hh), to_vec(b_ih), to_vec(b_hh));
        let xs = to_vec(x);
        let sig = |v: f32| 1.0 / (1.0 + (-v).exp());
        let mut h = [0.0f32; 3];
        let mut expect = Vec::new();
        for t in 0..2 {
            let xt = &xs[2 * t..2 * t + 2];
            let gate = |col: usize| -> (f32, f32) {
                let gx = b_ih[col] + (0..2).map(|i| xt[i] * w_ih[i * 9 + col]).sum::<f32>();
                let gh = b_hh[col] + (0..3).map(|i| h[i] * w_hh[i * 9 + col]).sum::<f32>();
                (gx, gh)
            };
            let mut next = [0.0; 3];
            for j in 0..3 {
                let (rx, rh) = gate(j);
                let (zx, zh) = gate(3 + j);
                let (nx, nh) = gate(6 + j);
                let r = sig(rx + rh);
                let z = sig(zx + zh);
                let n = (nx + r * nh).tanh();
                next[j] = (1.0 - z) * n + z * h[j];
            }
            h = next;
            expect.extend_from_slice(&h);
        }
        let got = to_vec(out);
        for (g, e) in got.iter().zip(&expect) {
            assert!((g - e).abs() < 1e-6, "{got:?} vs {expect:?}");
        }
        for (g, e) in to_vec(last).iter().zip(&expect[3..]) {
            assert!((g - e).abs() < 1e-6);
        }
    }
}
