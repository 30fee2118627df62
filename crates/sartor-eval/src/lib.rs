//! # sartor-eval
//!
//! How good and how fast: sartor's models judged against the simulator's held-out ground truth,
//! and its runtime and simulator timed. A library: the `sartor` command line and the developer's
//! `cargo xtask` parse arguments and draw progress; the `pipeline`, `eval`, `tradeoff`, `bench`,
//! `ship` and `check-model` commands all call this crate. No experiment config here: callers pass
//! the plan, folders and options.
//!
//! - [`evaluate_run`] (`eval.json`): `ours`, `ours_strain_limit`, `lbs`, `lr`, `retarget`
//!   ([`Method`]) on the held-out
//!   motions and shapes of a [`sartor_dataset::DatasetPlan`], with and without the collision
//!   post-process, edge stretch beside the ground truth's ([`StretchSummary`]), error plots and a
//!   rendered comparison. The pieces ([`Assets`],
//!   [`test_sets`], [`load_truth`], [`evaluate_with`]) serve the trade-off and the model check.
//! - [`sweep_model`], [`mark_pareto`], [`plot_tradeoff`] (`tradeoff.json`): what each speed
//!   knob of the runtime costs in accuracy.
//! - [`bench_runtime()`] (`bench-runtime.json`): the runtime against the paper's Table 1;
//!   [`bench_sim()`] (`bench-sim.json`): the simulator per garment size; with [`AnchorOptions`],
//!   the same weights in PyTorch and ONNX Runtime beside a memory-bandwidth floor
//!   ([`AnchorsReport`]).
//! - [`write_slice`], [`check_slice`]: the stored ground-truth slice of a shipped model and the
//!   regression check on it.
//! - Reports: [`Machine`], [`write_json`]; [`median`], the one median of every speed figure;
//!   [`write_charts`] (plotters, PNG + SVG, embedded font).

mod bench_anchors;
mod bench_runtime;
mod bench_sim;
mod context;
mod error;
mod eval;
mod gt_distance;
mod plot;
mod progress;
mod report;
mod slice;
mod stretch;
mod timing;
mod tradeoff;

pub use bench_anchors::{
    ANCHORS_INSTALL, AnchorOptions, AnchorsReport, ModelAnchors, check_anchors, stream_floor_ms,
};
pub use bench_runtime::{
    ANCHOR_PAPER_TRIANGLES, RuntimeBenchOptions, RuntimeBenchReport, bench_runtime,
};
pub use bench_sim::{
    GarmentDirs, SimBenchOptions, SimBenchReport, SizeEntry, Solver, bench_sim, garment_of_size,
};
pub use error::{Context, Error, Result};
pub use eval::{
    Assets, EVAL_FILE, EvalReport, EvalRun, GroundTruthStretch, Method, MethodReport,
    SequenceMetrics, SequenceReport, SequenceStretch, TestSequence, TestSets, evaluate,
    evaluate_run, evaluate_with, ground_truth_signed_distance, ground_truth_stretch,
    ground_truth_stretch_of, load_truth, run_sequence, shape_distance, split_sequences, test_sets,
};
pub use gt_distance::{
    DistanceHistogram, DistanceSummary, PosedBody, sequence_files_signed_distance,
};
pub use plot::{Chart, Marker, Series, write_charts};
pub use progress::{NoProgress, Progress};
pub use report::{Machine, load_average, read_json, write_json};
pub use slice::{
    RegressionSlice, SLICE_FILE, SliceCheck, TOLERANCE, check_slice, read_slice, slice_error_mm,
    write_slice,
};
pub use stretch::{GarmentEdges, StretchHistogram, StretchSummary};
pub use timing::{FrameTiming, mean, median, thread_cpu_ns, time_frames, time_stages};
pub use tradeoff::{
    SweptPoint, TradeoffOptions, TradeoffPoint, TradeoffReport, mark_pareto, plot_tradeoff,
    sweep_model, time_points,
};
