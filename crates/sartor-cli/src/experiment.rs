//! The commands that run an experiment's stages: `simulate`, `dataset`, `train`, `export`,
//! `eval`, `pipeline`, `tradeoff`. Each parses its arguments, loads and checks the whole
//! experiment config, calls sartor-pipeline / sartor-eval, draws progress and prints a summary.

use std::path::PathBuf;

use anyhow::Context;
use sartor_eval::TradeoffOptions;
use sartor_model::{MODEL_NAMES, ModelKind};
use sartor_pipeline::{
    DEFAULT_REGION_MARGIN_MM, DataDir, EvalOverrides, Experiment, ExportOptions, PipelineOptions,
    PipelineProgress, SimulateOptions, SimulateOutcome, TradeoffRun, TrainStageOptions, evaluate,
    export_run, resolve_shard, run_pipeline, run_tradeoff, simulate, train,
};
use serde_json::Value;

use crate::Env;
use crate::progress::{Bar, TrainBar, stop_flag};

/// The `--config` / `--runs-dir` pair every experiment command takes.
#[derive(clap::Args, Clone, Debug)]
pub struct ExperimentArgs {
    /// The experiment config (e.g. configs/default.json).
    #[arg(long)]
    pub config: PathBuf,
    /// Folder of the runs (outputs go to <runs-dir>/<name>; default: `runs`, see `--help`).
    #[arg(long)]
    pub runs_dir: Option<PathBuf>,
}

impl ExperimentArgs {
    /// Load and check the whole config; outputs go to `<runs-dir>/<name>`.
    pub fn load(&self, env: &Env) -> anyhow::Result<Experiment> {
        let runs = self
            .runs_dir
            .clone()
            .unwrap_or_else(|| env.runs_dir.clone());
        let config = crate::in_data(&env.data, &self.config);
        Ok(Experiment::load(&config, &env.data, &runs)?)
    }

    /// The config file as reports name it (relative to the data folder when inside it).
    pub fn name(&self, data: &DataDir) -> String {
        data.relative(&crate::in_data(data, &self.config))
    }
}

/// Arguments of `simulate`.
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// The experiment.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// This machine's shard: `I/N` (0-based I).
    #[arg(long)]
    pub shard: Option<String>,
    /// The number of shards when the index comes from the environment.
    #[arg(long)]
    pub shard_count: Option<usize>,
    /// Sequences simulated at once (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Simulate again the jobs that failed before (by default they are skipped: a simulation
    /// is deterministic, so the same inputs fail the same way; retry after changing settings).
    #[arg(long)]
    pub retry_failed: bool,
    /// Only the jobs whose file stem (`<shape>__<motion>`) starts with this prefix (repeat for
    /// several), e.g. `--only s00__` for the nominal shape's sequences.
    #[arg(long, value_name = "PREFIX")]
    pub only: Vec<String>,
}

/// Run `simulate`.
pub fn simulate_cmd(args: &SimulateArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let shard = resolve_shard(args.shard.as_deref(), args.shard_count, &|k| {
        std::env::var(k).ok()
    })?;
    let options = SimulateOptions {
        shard,
        jobs: args.jobs,
        retry_failed: args.retry_failed,
        only: args.only.clone(),
    };
    let config = args.experiment.name(&env.data);
    match simulate(&e, &env.data, &options, &config, &Bar::new())? {
        SimulateOutcome::NothingToDo {
            done,
            failed_before,
            report,
        } => println!(
            "simulate: nothing to do ({done} done, {failed_before} failed before; \
             --retry-failed simulates those again) → {}",
            report.display()
        ),
        SimulateOutcome::Ran(r, path) => println!(
            "simulate: {} done, {} already there, {} failed; {} frames in {:.1} s \
             ({:.1} ms/frame/thread) → {}",
            r.jobs_done,
            r.jobs_skipped_existing,
            r.jobs_failed,
            r.frames_simulated,
            r.wall_time_s,
            r.ms_per_frame_per_thread,
            path.display()
        ),
    }
    Ok(())
}

/// Run `dataset`.
pub fn dataset_cmd(args: &ExperimentArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.load(env)?;
    let (report, _) = sartor_pipeline::dataset(&e, &args.name(&env.data), &Bar::new())?;
    println!(
        "dataset: {} vertices, {} inputs ({} joints), frames {:?}, Δ_G mean {:.1} mm, Δ_L mean \
         {:.1} mm (train) → {}",
        report.n_vertices,
        report.n_inputs,
        report.joints.len(),
        report.frames_per_split,
        report.fit_delta.mean_mm,
        report.wrinkle_delta.get("train").map_or(0.0, |m| m.mean_mm),
        e.dataset_dir().display()
    );
    Ok(())
}

/// Arguments of `train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// The experiment.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// Continue from the checkpoints of an earlier (interrupted) run.
    #[arg(long)]
    pub resume: bool,
    /// Tensor backend: `flex` (CPU) or `wgpu` (needs `--features wgpu`).
    #[arg(long, default_value = "flex")]
    pub backend: String,
    /// Models to train, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = MODEL_NAMES.map(String::from))]
    pub models: Vec<String>,
}

/// Run `train` (Ctrl-C checkpoints and stops; `--resume` continues).
pub fn train_cmd(args: &TrainArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let models = args
        .models
        .iter()
        .map(|m| ModelKind::from_name(m))
        .collect::<sartor_model::Result<Vec<_>>>()?;
    let options = TrainStageOptions {
        models,
        resume: args.resume,
        backend: args.backend.clone(),
    };
    let stop = stop_flag();
    let mut bar = TrainBar::new();
    let result = train(&e, &options, &stop, &mut bar);
    bar.finish();
    let report = result?;
    for (name, r) in &report.models {
        println!(
            "{name}: {} epochs, best validation error {}, {:.0} frames/s",
            r.epochs,
            r.best_val_error_mm
                .map_or_else(|| "—".into(), |v| format!("{v:.3} mm")),
            r.frames_per_s
        );
    }
    println!("wrote {}", e.train_dir().join("train.json").display());
    Ok(())
}

/// Arguments of `export`.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The run folder (`runs/<exp>`), holding `sim/config.json`, `dataset/` and `train/`.
    #[arg(long)]
    pub run: PathBuf,
    /// Output folder (default `<run>/export`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Body region margin, mm: body triangles farther than this from the garment template never
    /// take part in the collision post-process.
    #[arg(long, default_value_t = DEFAULT_REGION_MARGIN_MM)]
    pub region_margin_mm: f64,
    /// Clip of the preview animation (`none` for no preview).
    #[arg(long, default_value = "walk_normal")]
    pub preview_motion: String,
    /// Frames of the preview.
    #[arg(long, default_value_t = 60)]
    pub preview_frames: usize,
}

/// Run `export`.
pub fn export_cmd(args: &ExportArgs, env: &Env) -> anyhow::Result<()> {
    let options = ExportOptions {
        out: args.out.clone(),
        region_margin_mm: args.region_margin_mm,
        preview_motion: args.preview_motion.clone(),
        preview_frames: args.preview_frames,
    };
    let s = export_run(&args.run, &env.data, &options)?;
    println!(
        "exported {} ({} vertices, fit {} / GRU {} units, {:?} output{}) to {}",
        s.experiment,
        s.sizes.n_vertices,
        s.sizes.fit_hidden,
        s.sizes.gru_hidden,
        s.sizes.output,
        if s.sizes.linear_baseline {
            ", linear baseline"
        } else {
            ""
        },
        s.out.display()
    );
    Ok(())
}

/// Arguments of `eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// The experiment.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// The exported model folder (default: `runs/<name>/export`).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Held-out motions on the nominal shape only (the training shape closest to β = 0);
    /// default: the config's `evaluation.nominal_only`.
    #[arg(long)]
    pub nominal_only: bool,
    /// Frames shown in the rendered comparison (default: the config's
    /// `evaluation.render_frames`).
    #[arg(long)]
    pub render_frames: Option<usize>,
}

/// Run `eval`.
pub fn eval_cmd(args: &EvalArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let overrides = EvalOverrides {
        model_dir: args.model.clone(),
        nominal_only: args.nominal_only,
        render_frames: args.render_frames,
    };
    let config = args.experiment.name(&env.data);
    let report = evaluate(&e, &config, &overrides, &Bar::new())?;
    for line in report.summary_lines() {
        println!("{line}");
    }
    println!(
        "wrote {}",
        e.eval_dir().join(sartor_eval::EVAL_FILE).display()
    );
    Ok(())
}

/// Arguments of `pipeline`.
#[derive(clap::Args, Debug)]
pub struct PipelineArgs {
    /// The experiment.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// Sequences simulated at once (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Tensor backend of training: flex (CPU) or wgpu.
    #[arg(long, default_value = "flex")]
    pub backend: String,
}

struct Stages {
    bar: Bar,
    train: TrainBar,
}

impl PipelineProgress for Stages {
    fn stage(&mut self, index: usize, name: &str) {
        self.train.finish();
        println!("[{index}/{}] {name}", sartor_pipeline::STAGES.len());
    }
    fn steps(&self) -> &dyn sartor_eval::Progress {
        &self.bar
    }
    fn training(&mut self) -> &mut dyn sartor_model::Progress {
        &mut self.train
    }
}

/// Run `pipeline`.
pub fn pipeline_cmd(args: &PipelineArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let options = PipelineOptions {
        jobs: args.jobs,
        backend: args.backend.clone(),
    };
    let stop = stop_flag();
    let mut stages = Stages {
        bar: Bar::new(),
        train: TrainBar::new(),
    };
    let config = args.experiment.name(&env.data);
    let report = run_pipeline(&e, &env.data, &config, &options, &stop, &mut stages)?;
    stages.train.finish();
    println!("\n{} — summary", e.name);
    for (k, v) in &report.summary {
        let text = match v {
            Value::Number(n) => n
                .as_f64()
                .map_or_else(|| n.to_string(), |x| format!("{x:.3}")),
            Value::Null => "—".into(),
            other => other.to_string(),
        };
        println!("  {k:<58} {text}");
    }
    println!(
        "wrote {}",
        sartor_pipeline::pipeline_report_path(&e).display()
    );
    Ok(())
}

/// Arguments of `tradeoff`.
#[derive(clap::Args, Debug)]
pub struct TradeoffArgs {
    /// The experiment (its held-out motions are the test set).
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// Further exported models of the same garment (e.g. other hidden sizes); the experiment's
    /// own export is always included.
    #[arg(long, value_delimiter = ',')]
    pub model: Vec<PathBuf>,
    /// Further experiment configs (other garment resolutions), each with its own export and
    /// held-out motions.
    #[arg(long, value_delimiter = ',')]
    pub extra_config: Vec<PathBuf>,
    /// Output ranks swept (default: the config's `evaluation.tradeoff_ranks`).
    #[arg(long, value_delimiter = ',')]
    pub ranks: Vec<usize>,
    /// Evaluate on every training shape (default: the nominal shape only, as the paper did).
    #[arg(long)]
    pub all_shapes: bool,
    /// Frames timed per point and round (default: the config's
    /// `evaluation.tradeoff_timed_frames`).
    #[arg(long)]
    pub timed_frames: Option<usize>,
    /// Timing rounds: every point is timed once per round, so that a machine whose speed
    /// drifts over seconds moves every point alike; a point's time is its median over the
    /// rounds (default: the config's `evaluation.tradeoff_rounds`).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub rounds: Option<u32>,
}

/// Run `tradeoff`.
pub fn tradeoff_cmd(args: &TradeoffArgs, env: &Env) -> anyhow::Result<()> {
    let first = args.experiment.load(env)?;
    let options = TradeoffOptions {
        ranks: if args.ranks.is_empty() {
            first.evaluation.tradeoff_ranks.clone()
        } else {
            args.ranks.clone()
        },
        timed_frames: args
            .timed_frames
            .unwrap_or(first.evaluation.tradeoff_timed_frames),
        rounds: args
            .rounds
            .map_or(first.evaluation.tradeoff_rounds, |r| r as usize),
    };
    let mut experiments = vec![first];
    for c in &args.extra_config {
        let extra = ExperimentArgs {
            config: c.clone(),
            runs_dir: args.experiment.runs_dir.clone(),
        };
        experiments.push(
            extra
                .load(env)
                .with_context(|| format!("--extra-config {}", c.display()))?,
        );
    }
    let run = TradeoffRun {
        experiments,
        extra_models: args.model.clone(),
        all_shapes: args.all_shapes,
        options,
    };
    let (report, path) = run_tradeoff(&run, &Bar::new())?;
    println!(
        "{:<34} {:>9} {:>9} {:>9} {:>8}  pareto (3 axes, with stretch)",
        "variant", "error mm", "inside %", "p99.9 ×", "ms/frame"
    );
    for p in &report.points {
        println!(
            "{:<34} {:>9.2} {:>9.3} {:>9.2} {:>8.3}  {} {}",
            p.label,
            p.mean_vertex_error_mm,
            p.collision_percent,
            p.edge_stretch_p999,
            p.ms_per_frame,
            if p.pareto { "*" } else { " " },
            if p.pareto_with_stretch { "+" } else { " " }
        );
    }
    println!("wrote {}", path.display());
    Ok(())
}
