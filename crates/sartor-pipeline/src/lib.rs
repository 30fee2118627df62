//! # sartor-pipeline
//!
//! An experiment from config to evaluated model. One typed config ([`Experiment`], checked
//! whole when it is loaded: unknown keys are errors naming file, line and key) drives the
//! stages, each resumable and each writing a JSON report next to its outputs:
//!
//! - [`simulate`] (`sim/`, `simulate.json`): every (shape, motion) pair, sharded, in parallel;
//! - [`dataset`] (`dataset/`): the training data (sartor-dataset);
//! - [`train`] (`train/`, `train.json`): the fit MLP, wrinkle GRU and linear baseline (burn);
//! - [`export_run`] (`export/`): the runtime's model folder with a preview animation;
//! - evaluation through sartor-eval; [`run_pipeline`] runs them all (`pipeline.json`);
//! - [`run_tradeoff`] and [`ship_model`]: the trade-off sweep of experiments, and shipping a
//!   run's model with its regression slice.
//!
//! [`DataDir`] says where the data lives (the repository or a copy shipped beside the binary);
//! nothing here uses compile-time paths. The command line (`sartor`, `cargo xtask`) parses
//! arguments and draws progress; this crate does the work.

mod data;
mod dataset;
mod error;
mod experiment;
mod export;
mod pipeline;
mod preview;
mod ship;
mod simulate;
mod tradeoff;
mod train;

pub use data::{DATA_DIR_ENV, DataDir};
pub use dataset::dataset;
pub use error::{Context, Error, Result};
pub use experiment::{EvaluationConfig, Experiment, Motions, NamedShape, Shapes};
pub use export::{
    DEFAULT_REGION_MARGIN_MM, ExportOptions, ExportSummary, export_run, run_experiment,
};
pub use pipeline::{
    EvalOverrides, PipelineOptions, PipelineProgress, PipelineReport, STAGES, StageTime, evaluate,
    pipeline_report_path, run_pipeline, summary,
};
pub use preview::{
    Animation, BODY_COLOR, ClothCheck, Format, GARMENT_COLOR, animate, model_betas,
    write_animation, write_png,
};
pub use ship::{ShipSummary, ship_model};
pub use simulate::{
    FailedJob, Job, SimInputs, SimulateOptions, SimulateOutcome, SimulateReport, jobs,
    resolve_shard, simulate,
};
pub use tradeoff::{TradeoffRun, run_tradeoff};
pub use train::{TrainReport, TrainStageOptions, device, train};
