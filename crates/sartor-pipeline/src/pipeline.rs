//! The whole pipeline ([`run_pipeline`], `sartor pipeline --config C`): simulate → dataset →
//! train → export → eval, end to end.
//!
//! Every stage is itself resumable (finished simulations are skipped, the dataset keeps
//! sequences built under the same config hash, training continues from its checkpoints), so a
//! killed pipeline is rerun with the same command. The pipeline ends with a summary read from
//! the stages' reports and writes it to `runs/<name>/pipeline.json`.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use sartor_eval::{
    EVAL_FILE, EvalReport, EvalRun, Machine, Progress, evaluate_run, read_json, write_json,
};
use sartor_model::{MODEL_NAMES, ModelKind};
use serde::Serialize;
use serde_json::Value;

use crate::error::Context;
use crate::experiment::Experiment;
use crate::export::{ExportOptions, export_run};
use crate::simulate::{SimulateOptions, simulate};
use crate::train::{TrainStageOptions, train};
use crate::{DataDir, Result};

/// Stages of the pipeline, in order.
pub const STAGES: [&str; 5] = ["simulate", "dataset", "train", "export", "eval"];

/// How [`run_pipeline`] runs.
#[derive(Clone, Debug)]
pub struct PipelineOptions {
    /// Sequences simulated at once (default: all cores).
    pub jobs: Option<usize>,
    /// Tensor backend of training: `flex` (CPU) or `wgpu`.
    pub backend: String,
}

/// One stage's wall time.
#[derive(Clone, Debug, Serialize)]
pub struct StageTime {
    /// The stage.
    pub stage: &'static str,
    /// Wall time, seconds.
    pub wall_time_s: f64,
}

/// `pipeline.json`.
#[derive(Clone, Debug, Serialize)]
pub struct PipelineReport {
    /// The config file.
    pub config: String,
    /// Wall time per stage.
    pub stages: Vec<StageTime>,
    /// The headline figures, read from the stages' reports.
    pub summary: Vec<(String, Value)>,
    /// Wall time, seconds.
    pub wall_time_s: f64,
    /// Where it ran.
    pub machine: Machine,
}

/// What a run of the eval stage changes of the experiment's `evaluation` section.
#[derive(Clone, Debug, Default)]
pub struct EvalOverrides {
    /// Evaluate this exported model instead of the experiment's own.
    pub model_dir: Option<PathBuf>,
    /// Only the nominal shape, whatever the config says.
    pub nominal_only: bool,
    /// Frames shown in the rendered comparison.
    pub render_frames: Option<usize>,
}

/// The eval stage: the experiment's exported model (or `overrides.model_dir`) on its test
/// sequences, written into its eval folder; `config` names the config file in the report.
pub fn evaluate(
    e: &Experiment,
    config: &str,
    overrides: &EvalOverrides,
    progress: &dyn Progress,
) -> Result<EvalReport> {
    let plan = e.plan();
    let model_dir = overrides
        .model_dir
        .clone()
        .unwrap_or_else(|| e.export_dir());
    let run = EvalRun {
        plan: &plan,
        sim_dir: &e.sim_dir(),
        body_dir: &e.body,
        model_dir: &model_dir,
        nominal_only: overrides.nominal_only || e.evaluation.nominal_only,
        render_frames: overrides
            .render_frames
            .unwrap_or(e.evaluation.render_frames),
        out_dir: &e.eval_dir(),
        config: config.to_string(),
    };
    Ok(evaluate_run(&run, progress)?)
}

/// What the caller sees of a running pipeline.
pub trait PipelineProgress {
    /// Stage `index` (1-based) of [`STAGES`] starts.
    fn stage(&mut self, index: usize, name: &str);
    /// Progress of the simulate, dataset and eval stages.
    fn steps(&self) -> &dyn Progress;
    /// Progress of the train stage.
    fn training(&mut self) -> &mut dyn sartor_model::Progress;
}

/// Run every stage of `e` (see the module docs); `config` names the config file in the reports,
/// `stop` (e.g. Ctrl-C) checkpoints training and stops.
pub fn run_pipeline(
    e: &Experiment,
    data: &DataDir,
    config: &str,
    options: &PipelineOptions,
    stop: &AtomicBool,
    progress: &mut dyn PipelineProgress,
) -> Result<PipelineReport> {
    let start = Instant::now();
    let mut stages = Vec::new();
    let timed = |stages: &mut Vec<StageTime>, index: usize, t: Instant| {
        stages.push(StageTime {
            stage: STAGES[index - 1],
            wall_time_s: t.elapsed().as_secs_f64(),
        });
    };
    let context = |i: usize| format!("pipeline stage {} of {}", STAGES[i - 1], e.name);

    progress.stage(1, STAGES[0]);
    let t = Instant::now();
    let sim = SimulateOptions {
        jobs: options.jobs,
        ..SimulateOptions::default()
    };
    simulate(e, data, &sim, config, progress.steps()).with_context(|| context(1))?;
    timed(&mut stages, 1, t);

    progress.stage(2, STAGES[1]);
    let t = Instant::now();
    crate::dataset::dataset(e, config, progress.steps()).with_context(|| context(2))?;
    timed(&mut stages, 2, t);

    progress.stage(3, STAGES[2]);
    let t = Instant::now();
    let train_options = TrainStageOptions {
        models: ModelKind::ALL.to_vec(),
        resume: true,
        backend: options.backend.clone(),
    };
    train(e, &train_options, stop, progress.training()).with_context(|| context(3))?;
    timed(&mut stages, 3, t);

    progress.stage(4, STAGES[3]);
    let t = Instant::now();
    export_run(&e.run_dir(), data, &ExportOptions::default()).with_context(|| context(4))?;
    timed(&mut stages, 4, t);

    progress.stage(5, STAGES[4]);
    let t = Instant::now();
    evaluate(e, config, &EvalOverrides::default(), progress.steps()).with_context(|| context(5))?;
    timed(&mut stages, 5, t);

    let report = PipelineReport {
        config: config.to_string(),
        stages,
        summary: summary(e),
        wall_time_s: start.elapsed().as_secs_f64(),
        machine: Machine::current(),
    };
    write_json(&pipeline_report_path(e), &report)?;
    Ok(report)
}

/// Where [`run_pipeline`] writes its report.
pub fn pipeline_report_path(e: &Experiment) -> PathBuf {
    e.run_dir().join("pipeline.json")
}

/// The headline figures of a run, from its stages' reports (`null` where a report is missing).
pub fn summary(e: &Experiment) -> Vec<(String, Value)> {
    let sim = read_json(&e.sim_dir().join("simulate.json"));
    let data = read_json(&e.dataset_dir().join("dataset.json"));
    let train = read_json(&e.train_dir().join("train.json"));
    let eval = read_json(&e.eval_dir().join(EVAL_FILE));
    let get = |v: &Option<Value>, pointer: &str| {
        v.as_ref()
            .and_then(|v| v.pointer(pointer))
            .cloned()
            .unwrap_or(Value::Null)
    };
    let mut summary: Vec<(String, Value)> = vec![
        ("simulated sequences".into(), get(&sim, "/jobs_done")),
        ("failed simulations".into(), get(&sim, "/jobs_failed")),
        (
            "simulator ms per frame".into(),
            get(&sim, "/ms_per_frame_per_thread"),
        ),
        (
            "dataset training frames".into(),
            get(&data, "/frames_per_split/train"),
        ),
    ];
    for m in MODEL_NAMES {
        summary.push((
            format!("{m}: best validation error mm"),
            get(&train, &format!("/models/{m}/best_val_error_mm")),
        ));
    }
    for (set, methods) in [
        (
            "held_out_motions",
            &["ours", "ours_strain_limit", "lr", "lbs"][..],
        ),
        (
            "held_out_shapes",
            &["ours", "ours_strain_limit", "retarget", "lbs"][..],
        ),
    ] {
        for m in methods {
            summary.push((
                format!("{set}: {m} mm"),
                get(&eval, &format!("/{set}/{m}/mean_vertex_error_mm")),
            ));
        }
    }
    summary.push((
        "ours: collision % after post-process (held-out motions)".into(),
        get(&eval, "/held_out_motions/ours/collision_percent_after_pp"),
    ));
    summary
}
