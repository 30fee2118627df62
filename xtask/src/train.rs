//! `cargo xtask train --config C`: train the fit MLP, the wrinkle GRU and the linear baseline of
//! an experiment on its dataset (`runs/<name>/dataset`) with `sartor_model::train_model`, each in
//! `runs/<name>/train/<model>/` (checkpoints every epoch and on Ctrl-C; `--resume` continues).
//! Writes `train/train.json` (epochs, wall time, frames/s, `best_val_error_mm`, loss curves) and
//! the loss curves as `train/loss.png` and `train/loss.svg`.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use sartor_model::burn::tensor::Device;
use sartor_model::{
    EpochRecord, MODEL_NAMES, ModelKind, ModelReport, Progress, TrainOptions, TrainingConfig,
    train_model,
};
use serde::Serialize;

use crate::experiment::{Experiment, ExperimentArgs};
use crate::machine::{Machine, write_json};
use crate::plot::{Chart, Series, write_charts};

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

/// `train.json`.
#[derive(Serialize)]
struct TrainReport {
    experiment: String,
    /// SHA-256 of the training section.
    config_sha256: String,
    training: TrainingConfig,
    backend: String,
    wall_time_s: f64,
    models: BTreeMap<String, ModelReport>,
    machine: Machine,
}

/// The folder of an experiment's training runs.
pub fn train_dir(e: &Experiment) -> std::path::PathBuf {
    e.run_dir().join("train")
}

/// The training section of `e`.
pub fn training_config(e: &Experiment) -> anyhow::Result<TrainingConfig> {
    anyhow::ensure!(
        !e.training.is_null(),
        "experiment {}: the config has no \"training\" section",
        e.name
    );
    let config: TrainingConfig = serde_json::from_value(e.training.clone())
        .with_context(|| format!("experiment {}: the \"training\" section", e.name))?;
    config
        .validate()
        .with_context(|| format!("experiment {}: the \"training\" section", e.name))?;
    Ok(config)
}

fn device(backend: &str) -> anyhow::Result<Device> {
    match backend {
        "flex" => Ok(Device::flex().autodiff()),
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(Device::wgpu(Default::default()).autodiff()),
        #[cfg(not(feature = "wgpu"))]
        "wgpu" => bail!(
            "this xtask was built without the wgpu backend: \
             cargo run --release -p xtask --features wgpu -- train ..."
        ),
        other => bail!("unknown backend {other:?} (flex or wgpu)"),
    }
}

/// An indicatif bar per model: steps of the epoch, loss and validation error in the message.
struct Bar {
    bar: ProgressBar,
    model: String,
    epochs: usize,
    last_val: Option<f64>,
}

impl Progress for Bar {
    fn start(
        &mut self,
        model: &str,
        epoch: usize,
        epochs: usize,
        steps_per_epoch: usize,
        steps_done: usize,
    ) {
        self.model = model.into();
        self.epochs = epochs;
        self.bar.set_length(steps_per_epoch as u64);
        self.bar.set_position(steps_done as u64);
        self.bar.set_prefix(format!("{model} {epoch}/{epochs}"));
    }
    fn step(&mut self, loss: f64) {
        self.bar.inc(1);
        let val = self
            .last_val
            .map_or_else(|| "—".into(), |v| format!("{v:.2} mm"));
        self.bar.set_message(format!("loss {loss:.4}, val {val}"));
    }
    fn epoch(&mut self, record: &EpochRecord) {
        self.last_val = record.val_error_mm;
        if record.epoch == self.epochs || self.bar.is_hidden() && record.epoch.is_multiple_of(10) {
            self.bar.println(format!(
                "{} epoch {}/{}: loss {:.5}, validation {}",
                self.model,
                record.epoch,
                self.epochs,
                record.train_loss,
                record
                    .val_error_mm
                    .map_or_else(|| "—".into(), |v| format!("{v:.3} mm")),
            ));
        }
    }
}

/// Stop flag set by Ctrl-C (the loop checkpoints after the current batch and returns).
fn stop_flag() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // A handler may already be installed (the pipeline calls train once per process); then
    // Ctrl-C ends the process and the last epoch's checkpoint is what a resume starts from.
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("\nstopping after this batch (Ctrl-C again to quit at once)");
    });
    stop
}

fn loss_charts(models: &BTreeMap<String, ModelReport>) -> Vec<Chart> {
    let mut charts = Vec::new();
    for (name, r) in models {
        let points = |f: &dyn Fn(&EpochRecord) -> Option<f64>| -> Vec<(f64, f64)> {
            r.curve
                .iter()
                .filter_map(|e| f(e).map(|v| (e.epoch as f64, v)))
                .collect()
        };
        charts.push(Chart {
            title: format!("{name}: training loss"),
            x_label: "epoch".into(),
            y_label: "MSE (normalised), log10".into(),
            series: vec![Series {
                name: "train".into(),
                points: points(&|e| (e.train_loss > 0.0).then(|| e.train_loss.log10())),
                markers: false,
            }],
        });
        charts.push(Chart {
            title: format!("{name}: validation error"),
            x_label: "epoch".into(),
            y_label: "mean vertex error (mm)".into(),
            series: vec![Series {
                name: format!("{:?}", r.validation).to_lowercase(),
                points: points(&|e| e.val_error_mm),
                markers: false,
            }],
        });
    }
    charts
}

/// Run `train`.
pub fn train(args: &TrainArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let e = args.experiment.load()?;
    let config = training_config(&e)?;
    let kinds = args
        .models
        .iter()
        .map(|m| ModelKind::from_name(m))
        .collect::<sartor_model::Result<Vec<_>>>()?;
    let data_dir = e.dataset_dir();
    let data = sartor_dataset::load_dataset(&data_dir).with_context(|| {
        format!(
            "loading the dataset from {} (run `cargo xtask dataset` first)",
            data_dir.display()
        )
    })?;
    let device = device(&args.backend)?;
    let dir = train_dir(&e);
    let stop = stop_flag();
    let mut models = BTreeMap::new();
    let report_path = dir.join("train.json");
    // Reports of models trained earlier (and not retrained now) are kept.
    if let Ok(bytes) = std::fs::read(&report_path)
        && let Ok(old) = serde_json::from_slice::<serde_json::Value>(&bytes)
        && let Some(old) = old.get("models")
        && let Ok(old) = serde_json::from_value::<BTreeMap<String, ModelReport>>(old.clone())
    {
        models = old;
    }
    let mut interrupted = false;
    for kind in kinds {
        let bar = ProgressBar::new(1).with_style(
            ProgressStyle::with_template(
                "{prefix:>14} {bar:30} {pos}/{len} {msg} [{elapsed_precise}, eta {eta}]",
            )
            .expect("the template is valid"),
        );
        let mut progress = Bar {
            bar,
            model: kind.name().into(),
            epochs: 0,
            last_val: None,
        };
        let options = TrainOptions {
            dir: dir.join(kind.name()),
            device: device.clone(),
            resume: args.resume,
            stop: &stop,
        };
        let report = train_model(kind, &data, &config, &options, &mut progress)
            .with_context(|| format!("training {} of {}", kind.name(), e.name))?;
        progress.bar.finish_and_clear();
        println!(
            "{}: {} epochs, best validation error {}, {:.0} frames/s",
            kind.name(),
            report.epochs,
            report
                .best_val_error_mm
                .map_or_else(|| "—".into(), |v| format!("{v:.3} mm")),
            report.frames_per_s
        );
        interrupted |= report.interrupted;
        models.insert(kind.name().to_string(), report);
        if interrupted {
            break;
        }
    }
    let report = TrainReport {
        experiment: e.name.clone(),
        config_sha256: Experiment::section_sha256(&config)?,
        training: config,
        backend: args.backend.clone(),
        wall_time_s: start.elapsed().as_secs_f64(),
        models,
        machine: Machine::current(),
    };
    write_json(&report_path, &report)?;
    let charts = loss_charts(&report.models);
    if !charts.is_empty() {
        write_charts(&dir.join("loss"), &charts, 2, (520, 340))?;
    }
    println!("wrote {}", report_path.display());
    if interrupted {
        bail!(
            "training of {} was interrupted; its checkpoint is saved: rerun with --resume",
            e.name
        );
    }
    Ok(())
}
