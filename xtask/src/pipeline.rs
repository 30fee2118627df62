//! `cargo xtask pipeline --config C`: simulate → dataset → train → export → eval, end to end.
//!
//! Every stage is itself resumable (finished simulations are skipped, the dataset keeps
//! sequences built under the same config hash, training continues from its checkpoints), so a
//! killed pipeline is rerun with the same command. Each stage shows its own progress bar under
//! a `[i/5]` header; the pipeline ends with a summary read from the stages' reports and writes
//! it to `runs/<name>/pipeline.json`.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;
use serde_json::Value;

use crate::experiment::ExperimentArgs;
use crate::machine::{Machine, write_json};

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

#[derive(Serialize)]
struct StageTime {
    stage: &'static str,
    wall_time_s: f64,
}

#[derive(Serialize)]
struct PipelineReport {
    config: String,
    stages: Vec<StageTime>,
    summary: Vec<(String, Value)>,
    wall_time_s: f64,
    machine: Machine,
}

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// Run the pipeline.
pub fn pipeline(args: &PipelineArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let e = args.experiment.load()?;
    let experiment = || ExperimentArgs {
        config: args.experiment.config.clone(),
        runs_dir: args.experiment.runs_dir.clone(),
    };
    let mut stages = Vec::new();
    let mut stage = |i: usize, name: &'static str, f: &dyn Fn() -> anyhow::Result<()>| {
        println!("[{i}/5] {name}");
        let t = Instant::now();
        let r = f();
        stages.push(StageTime {
            stage: name,
            wall_time_s: t.elapsed().as_secs_f64(),
        });
        r.map_err(|err| err.context(format!("pipeline stage {name} of {}", e.name)))
    };
    stage(1, "simulate", &|| {
        crate::simulate::simulate(&crate::simulate::SimulateArgs {
            experiment: experiment(),
            shard: None,
            shard_count: None,
            jobs: args.jobs,
            retry_failed: false,
        })
    })?;
    stage(2, "dataset", &|| {
        crate::dataset::dataset(&crate::dataset::DatasetArgs {
            experiment: experiment(),
        })
    })?;
    stage(3, "train", &|| {
        crate::train::train(&crate::train::TrainArgs {
            experiment: experiment(),
            resume: true,
            backend: args.backend.clone(),
            models: sartor_model::MODEL_NAMES
                .iter()
                .map(|m| m.to_string())
                .collect(),
        })
    })?;
    stage(4, "export", &|| {
        crate::export::export_run(&crate::export::ExportArgs {
            run: e.run_dir(),
            out: None,
            region_margin_mm: crate::export::DEFAULT_REGION_MARGIN_MM,
            preview_motion: "walk_normal".into(),
            preview_frames: 60,
        })
    })?;
    stage(5, "eval", &|| {
        crate::eval::eval(&crate::eval::EvalArgs {
            experiment: experiment(),
            model: None,
            nominal_only: false,
            render_frames: 4,
        })
    })?;

    // The summary, from the stages' own reports.
    let run = e.run_dir();
    let sim = read_json(&run.join("sim/simulate.json"));
    let data = read_json(&run.join("dataset/dataset.json"));
    let train = read_json(&run.join("train/train.json"));
    let eval = read_json(&run.join("eval/eval.json"));
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
    for m in sartor_model::MODEL_NAMES {
        summary.push((
            format!("{m}: best validation error mm"),
            get(&train, &format!("/models/{m}/best_val_error_mm")),
        ));
    }
    for (set, methods) in [
        ("held_out_motions", &["ours", "lr", "lbs"][..]),
        ("held_out_shapes", &["ours", "retarget", "lbs"][..]),
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
    println!("\n{} — summary", e.name);
    for (k, v) in &summary {
        let text = match v {
            Value::Number(n) => n
                .as_f64()
                .map_or_else(|| n.to_string(), |x| format!("{x:.3}")),
            Value::Null => "—".into(),
            other => other.to_string(),
        };
        println!("  {k:<58} {text}");
    }
    let report = PipelineReport {
        config: args.experiment.config.display().to_string(),
        stages,
        summary,
        wall_time_s: start.elapsed().as_secs_f64(),
        machine: Machine::current(),
    };
    let path = run.join("pipeline.json");
    write_json(&path, &report)?;
    println!("wrote {}", path.display());
    Ok(())
}
