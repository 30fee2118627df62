//! The `train` stage ([`train`], `sartor train --config C`): train the fit MLP, the wrinkle GRU and the linear baseline of
//! an experiment on its dataset (`runs/<name>/dataset`) with `sartor_model::train_model`, each in
//! `runs/<name>/train/<model>/` (checkpoints every epoch and when the stop flag is raised;
//! `resume` continues).
//! Writes `train/train.json` (epochs, wall time, frames/s, `best_val_error_mm`, loss curves) and
//! the loss curves as `train/loss.png` and `train/loss.svg`.

use std::collections::BTreeMap;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use sartor_core::BodyModel;
use sartor_eval::{Chart, Machine, Series, write_charts, write_json};
use sartor_model::burn::tensor::Device;
use sartor_model::{
    EpochRecord, ModelKind, ModelReport, Progress, RestContact, TrainOptions, TrainingConfig,
    train_model,
};
use serde::Serialize;

use crate::error::{Context, bail};
use crate::experiment::Experiment;
use crate::{Error, Result};

/// `train.json`.
#[derive(Clone, Debug, Serialize)]
pub struct TrainReport {
    /// The experiment.
    pub experiment: String,
    /// SHA-256 of the training section.
    pub config_sha256: String,
    /// The training section.
    pub training: TrainingConfig,
    /// `flex` or `wgpu`.
    pub backend: String,
    /// Wall time, seconds.
    pub wall_time_s: f64,
    /// Per model (models trained earlier and not now are kept).
    pub models: BTreeMap<String, ModelReport>,
    /// Where it ran.
    pub machine: Machine,
}

/// How [`train`] runs.
#[derive(Clone, Debug)]
pub struct TrainStageOptions {
    /// The models to train, in order.
    pub models: Vec<ModelKind>,
    /// Continue from the checkpoints of an earlier (interrupted) run.
    pub resume: bool,
    /// Tensor backend: `flex` (CPU) or `wgpu` (with the `wgpu` feature).
    pub backend: String,
}

/// The burn device of a backend name.
pub fn device(backend: &str) -> Result<Device> {
    match backend {
        "flex" => Ok(Device::flex().autodiff()),
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(Device::wgpu(Default::default()).autodiff()),
        #[cfg(not(feature = "wgpu"))]
        "wgpu" => bail!(
            "built without the wgpu backend: build with `--features wgpu` \
             (cargo run --release -p xtask --features wgpu -- train ...)"
        ),
        other => bail!("unknown backend {other:?} (flex or wgpu)"),
    }
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
                marker: None,
                color: None,
            }],
            log_x: false,
            legend_at_bottom: false,
            ranges: None,
        });
        charts.push(Chart {
            title: format!("{name}: validation error"),
            x_label: "epoch".into(),
            y_label: "mean vertex error (mm)".into(),
            series: vec![Series {
                name: format!("{:?}", r.validation).to_lowercase(),
                points: points(&|e| e.val_error_mm),
                marker: None,
                color: None,
            }],
            log_x: false,
            legend_at_bottom: false,
            ranges: None,
        });
    }
    charts
}

/// Train the models of `e` on its dataset (see the module docs); `stop` (e.g. set by Ctrl-C)
/// checkpoints after the current batch and stops, which is an error telling to resume.
pub fn train(
    e: &Experiment,
    options: &TrainStageOptions,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
) -> Result<TrainReport> {
    let args = options;
    let start = Instant::now();
    let config = e.training()?.clone();
    let kinds = options.models.clone();
    let data_dir = e.dataset_dir();
    let data = sartor_dataset::load_dataset(&data_dir).with_context(|| {
        format!(
            "loading the dataset from {} (run the dataset stage first)",
            data_dir.display()
        )
    })?;
    let device = device(&args.backend)?;
    // The body under the garments, for the wrinkle GRU's contact term (where it is on).
    let contact = if config.contact_weight() > 0.0 && kinds.contains(&ModelKind::Wrinkle) {
        let body = BodyModel::load(&e.body)
            .with_context(|| format!("loading the body model from {}", e.body.display()))?;
        let binding = sartor_dataset::read_binding(&data_dir, &body)
            .with_context(|| format!("reading the garment binding in {}", data_dir.display()))?;
        Some(
            RestContact::new(&data, binding.template(), &body)
                .context("the contact term's body normals")?,
        )
    } else {
        None
    };
    let dir = e.train_dir();
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
        let options = TrainOptions {
            dir: dir.join(kind.name()),
            device: device.clone(),
            resume: args.resume,
            stop,
            contact: contact.as_ref(),
        };
        let report = train_model(kind, &data, &config, &options, progress)
            .with_context(|| format!("training {} of {}", kind.name(), e.name))?;
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
    if interrupted {
        return Err(Error::Invalid(format!(
            "training of {} was interrupted; its checkpoint is saved: rerun with --resume",
            e.name
        )));
    }
    Ok(report)
}
