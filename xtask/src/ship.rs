//! `cargo xtask ship` and `cargo xtask check-model`: the committed reference model (the work is
//! `sartor_pipeline::ship_model` and `sartor_eval::check_slice`).
//!
//! `ship` copies an experiment's export (model + binding) and its `eval.json` into a folder under
//! `datasets/models/`, with a small slice of held-out ground truth (`regression-slice.safetensors`:
//! the first frames of the first held-out clip on the nominal shape) and the model's error on it,
//! recorded in the copied `eval.json` as `regression_slice`. The run's reports
//! (`simulate.json`, `dataset.json`, `train.json`, `pipeline.json`) go with it where the run has
//! them, so the folder says how the model was made.
//!
//! `check-model` recomputes that error with the runtime and fails when it is more than 10 % away
//! from the recorded figure: the regression test of the shipped model.

use std::path::PathBuf;

use sartor_cli::{Env, ExperimentArgs, in_data};
use sartor_eval::check_slice;
use sartor_pipeline::ship_model;

/// Arguments of `ship`.
#[derive(clap::Args, Debug)]
pub struct ShipArgs {
    /// The experiment whose export and evaluation are shipped.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// Destination (default: `datasets/models/<name>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Frames of the stored ground-truth slice.
    #[arg(long, default_value_t = 30)]
    pub slice_frames: usize,
}

/// Arguments of `check-model`.
#[derive(clap::Args, Debug)]
pub struct CheckModelArgs {
    /// A shipped model folder.
    #[arg(long, default_value = "datasets/models/default")]
    pub model: PathBuf,
}

/// Run `ship`.
pub fn ship(args: &ShipArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| env.data.models_dir().join(&e.name));
    let s = ship_model(&e, &out, args.slice_frames)?;
    println!(
        "shipped {} to {} (slice {} / {}, {} frames: {:.2} mm)",
        s.from.display(),
        out.display(),
        s.slice.shape,
        s.slice.motion,
        s.slice.frames,
        s.slice.mean_vertex_error_mm
    );
    Ok(())
}

/// Run `check-model`: the slice's error against the recorded one.
pub fn check_model(args: &CheckModelArgs, env: &Env) -> anyhow::Result<()> {
    let dir = in_data(&env.data, &args.model);
    let c = check_slice(&dir, &env.data.body_dir())?;
    println!(
        "{}: slice {} / {} ({} frames): {:.3} mm, recorded {:.3} mm ({:+.2} %)",
        dir.display(),
        c.recorded.shape,
        c.recorded.motion,
        c.frames,
        c.error_mm,
        c.recorded.mean_vertex_error_mm,
        100.0 * (c.error_mm - c.recorded.mean_vertex_error_mm) / c.recorded.mean_vertex_error_mm
    );
    Ok(())
}
