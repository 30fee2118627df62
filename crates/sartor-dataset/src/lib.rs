//! # sartor-dataset
//!
//! Turns simulated cloth into the training data of Santesteban et al. 2019: the garment
//! template `T̄_c`, the cloth skin weights `W_c`, the fit displacements
//! `Δ_G = ρ(S_c(β, 0)) − T̄_c` and the wrinkle displacements
//! `Δ_L = W⁻¹(S_c(β, θ), β, θ, W_c) − T̄_c − Δ_G`, the network inputs, splits, normalisation
//! statistics and an optional PCA basis; and cuts them into batches for training.
//!
//! - [`TrainingData`]: the data in memory ([`ShapeSample`], [`SequenceSample`],
//!   [`NormStats`], [`PcaBasis`], [`InputLayout`]), validated.
//! - Batching ([`sequence_batches`], [`window`], [`frame_batches`], [`gather_frames`],
//!   [`gather_shapes`]): deterministic under a seed, normalised.

#![warn(missing_docs)]

mod batching;
mod data;
mod error;

pub use batching::{
    Window, frame_batches, gather_frames, gather_shapes, sequence_batches, shuffled, window,
    window_count,
};
pub use data::{
    DataSource, InputLayout, MeanStd, NormStats, PcaBasis, SequenceSample, ShapeSample, Split,
    TrainingData,
};
pub use error::{Error, Result};
