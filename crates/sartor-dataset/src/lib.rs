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
//! - Ground truth ([`bind_garment`], which makes sartor-core's `GarmentBinding`, [`Smoother`]
//!   (ρ), [`fit_delta`], [`WrinkleExtractor`], [`select_joints`]), statistics and PCA ([`compute_stats`], [`compute_pca`]).
//! - Files ([`load_dataset`], [`Manifest`], `write_*`): safetensors + a manifest with hashes.
//! - The simulation folder of a run ([`SimFolder`], [`sequence_stem`], [`failed_stems`]): the
//!   simulator's sequence files read back as ground truth.
//! - Batching ([`sequence_batches`], [`window`], [`frame_batches`], [`gather_frames`],
//!   [`gather_shapes`]): deterministic under a seed, normalised.

#![warn(missing_docs)]

mod batching;
mod build;
mod data;
mod error;
mod extract;
mod simfolder;
mod smoothing;
mod stats;
mod store;

pub use batching::{
    Window, frame_batches, gather_frames, gather_shapes, sequence_batches, shuffled, window,
    window_count,
};
pub use build::{
    DatasetConfig, DatasetInputs, DatasetPlan, DatasetReport, MagnitudeMm, REPORT_FILE,
    SequencePlan, ShapePlan, SimulatedMotion, SimulationSource, build_dataset,
};
pub use data::{
    DataSource, InputLayout, PcaBasis, SequenceSample, ShapeSample, Split, TrainingData,
};
pub use error::{Error, Result};
pub use extract::{CLOTH_WEIGHT_CUTOFF, WrinkleExtractor, bind_garment, fit_delta, select_joints};
/// The normalisation statistics are the geometry core's (the runtime reads the same type).
pub use sartor_core::{MeanStd, NormStats};
pub use simfolder::{
    FAILED_DIR, REST_MOTION, SimFolder, failed_stems, sequence_stem, simulated_plan,
};
pub use smoothing::{Smoother, Smoothing};
pub use stats::{MIN_STD, PcaSettings, compute_pca, compute_stats};
pub use store::{
    BINDING_FILE, DATASET_FORMAT, DATASET_VERSION, MANIFEST_FILE, Manifest, SEQUENCES_DIR,
    SHAPES_FILE, STATS_FILE, SequenceEntry, ShapeEntry, load_dataset, read_binding, read_manifest,
    read_sequence, sequence_file, write_manifest, write_sequence, write_shapes, write_stats,
};
