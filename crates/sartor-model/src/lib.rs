//! # sartor-model
//!
//! The learned part of Santesteban et al. 2019 in burn (`=0.22.1`): the garment fit MLP
//! `R_G(β)`, the garment wrinkle GRU `R_L(β, θ)` and the linear-regression baseline, their
//! training loops and the export to `sartor-runtime`'s burn-free model format.
//!
//! - Modules ([`FitRegressor`], [`WrinkleRegressor`] over a [`FusedGru`], [`LinearRegressor`]),
//!   each built from a `#[derive(Config)]` struct.
//! - Training ([`train_model`] with a [`TrainingConfig`]): Adam on the mean squared error of
//!   normalised displacements; the GRU on whole sequences with truncated backpropagation every
//!   `window_frames` frames; validation error in mm each epoch; resumable checkpoints
//!   ([`load_trained`] reads the best weights back).
//! - Inference and export ([`Predictor`], [`export_model`]).
//!
//! ```no_run
//! use std::sync::atomic::AtomicBool;
//! use burn::tensor::Device;
//! use sartor_model::{ModelKind, Silent, StageConfig, TrainOptions, TrainingConfig, train_model};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let data = sartor_dataset::load_dataset("runs/tiny/dataset".as_ref())?;
//! let config = TrainingConfig::new(
//!     StageConfig::new(500, 17),
//!     StageConfig::new(20, 8),
//!     StageConfig::new(20, 256),
//! )
//! .with_gru_hidden(64);
//! let stop = AtomicBool::new(false);
//! let options = TrainOptions {
//!     dir: "runs/tiny/train/wrinkle".into(),
//!     device: Device::flex().autodiff(),
//!     resume: true,
//!     stop: &stop,
//!     contact: None,
//! };
//! let report = train_model(ModelKind::Wrinkle, &data, &config, &options, &mut Silent)?;
//! println!("{:?} mm", report.best_val_error_mm);
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

mod contact;
mod data;
mod error;
mod inference;
mod model;
mod ridge;
mod training;

pub use contact::RestContact;
pub use data::{to_vec, vertex_error_mm};
pub use error::{Error, Result};
pub use inference::{Predictor, export_model};
pub use model::{
    FitRegressor, FitRegressorConfig, FusedGru, LinearRegressor, LinearRegressorConfig,
    WrinkleRegressor, WrinkleRegressorConfig,
};
pub use training::{
    AnyModel, BEST_FILE, CONFIG_FILE, DEFAULT_CONTACT_MARGIN_M, EpochRecord, MODEL_NAMES,
    ModelKind, ModelReport, Progress, STATE_FILE, Silent, StageConfig, TrainOptions,
    TrainingConfig, load_trained, load_weights, save_weights, seeded, train_model,
};

/// burn itself, so callers name devices and tensors with the same version.
pub use burn;
