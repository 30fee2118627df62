//! `cargo xtask ship` and `cargo xtask check-model`: the committed reference model.
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

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use nalgebra::Vector3;
use sartor_core::{BodyModel, Pose};

use crate::builtin_model_dir;
use sartor_dataset::SimulatedMotion;
use sartor_runtime::{AnimatorOptions, NetworkOptions};
use serde::{Deserialize, Serialize};

use crate::dataset::SequenceFiles;
use crate::eval::{Assets, Method, TestSequence, TestSets, export_dir, run_sequence};
use crate::experiment::ExperimentArgs;
use crate::machine::write_json;
use crate::workspace_root;

/// File name of the stored ground-truth slice.
pub const SLICE_FILE: &str = "regression-slice.safetensors";
/// Largest relative drift `check-model` accepts.
pub const TOLERANCE: f64 = 0.10;

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

/// What the slice's safetensors metadata holds besides the cloth tensor.
#[derive(Serialize, Deserialize)]
struct SliceHeader {
    shape: String,
    motion: String,
    betas: Vec<f64>,
    previous_pose: Pose,
    poses: Vec<Pose>,
}

/// The slice's entry in the shipped eval.json.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RegressionSlice {
    /// Shape id.
    pub shape: String,
    /// Clip.
    pub motion: String,
    /// Frames stored.
    pub frames: usize,
    /// Mean vertex error of `ours` (after the post-process) on the slice, mm.
    pub mean_vertex_error_mm: f64,
}

fn write_slice(path: &Path, seq: &TestSequence) -> anyhow::Result<()> {
    let header = SliceHeader {
        shape: seq.shape.clone(),
        motion: seq.motion.clone(),
        betas: seq.truth.betas.clone(),
        previous_pose: seq.truth.previous_pose.clone(),
        poses: seq.truth.poses.clone(),
    };
    let n = seq.truth.cloth.first().map_or(0, Vec::len);
    let data: Vec<u8> = seq
        .truth
        .cloth
        .iter()
        .flatten()
        .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
        .flat_map(f32::to_le_bytes)
        .collect();
    let view = safetensors::tensor::TensorView::new(
        safetensors::Dtype::F32,
        vec![seq.truth.cloth.len(), n, 3],
        &data,
    )?;
    let metadata = HashMap::from([("slice".to_owned(), serde_json::to_string(&header)?)]);
    let bytes = safetensors::serialize([("cloth", view)], Some(metadata))?;
    sartor_core::io::write_atomic(path, &bytes)?;
    Ok(())
}

fn read_slice(path: &Path) -> anyhow::Result<TestSequence> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let bad = |m: String| anyhow::anyhow!("{}: {m}", path.display());
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)
        .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
    let header: SliceHeader = meta
        .metadata()
        .as_ref()
        .and_then(|m| m.get("slice"))
        .ok_or_else(|| bad("no `slice` metadata".into()))
        .and_then(|s| serde_json::from_str(s).map_err(|e| bad(format!("bad `slice`: {e}"))))?;
    let tensors = safetensors::SafeTensors::deserialize(&bytes)
        .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
    let cloth = tensors
        .tensor("cloth")
        .map_err(|e| bad(format!("no `cloth` tensor ({e})")))?;
    let shape = cloth.shape();
    if cloth.dtype() != safetensors::Dtype::F32
        || shape.len() != 3
        || shape[2] != 3
        || shape[0] != header.poses.len()
    {
        bail!(
            "{}: `cloth` must be f32 [{} frames, V, 3], is {:?} {shape:?}",
            path.display(),
            header.poses.len(),
            cloth.dtype()
        );
    }
    let values: Vec<f64> = cloth
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64)
        .collect();
    if values.iter().any(|v| !v.is_finite()) {
        bail!("{}: `cloth` holds non-finite values", path.display());
    }
    let frames = values
        .chunks_exact(3 * shape[1])
        .map(|f| {
            f.chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2]))
                .collect()
        })
        .collect();
    Ok(TestSequence {
        shape: header.shape,
        motion: header.motion,
        shape_distance: 0.0,
        truth: SimulatedMotion {
            betas: header.betas,
            previous_pose: header.previous_pose,
            poses: header.poses,
            cloth: frames,
        },
    })
}

/// Mean vertex error (mm) of `ours` with the post-process on `seq`.
fn slice_error_mm(assets: &Assets, seq: &TestSequence) -> anyhow::Result<f64> {
    let network = assets.network(NetworkOptions::default())?;
    let options = Method::Ours.options(AnimatorOptions::default());
    let pp = assets.rig(&network, options)?;
    let raw = assets.rig(
        &network,
        AnimatorOptions {
            collision: None,
            ..options
        },
    )?;
    let (m, _) = run_sequence(&pp, &raw, seq, &[])?;
    Ok(1e3 * m.per_frame_m.iter().sum::<f64>() / m.per_frame_m.len().max(1) as f64)
}

/// The files of an export folder that are shipped.
fn export_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let model_file = name.ends_with(".json") || name.ends_with(".safetensors");
        if path.is_file() && model_file && !name.starts_with('.') {
            files.push(path);
        }
    }
    files.sort();
    anyhow::ensure!(!files.is_empty(), "{}: no exported files", dir.display());
    Ok(files)
}

/// Run `ship`.
pub fn ship(args: &ShipArgs) -> anyhow::Result<()> {
    let e = args.experiment.load()?;
    let from = export_dir(&e);
    let eval_path = crate::eval::eval_dir(&e).join("eval.json");
    let mut eval: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&eval_path).with_context(|| {
            format!("reading {} (run `cargo xtask eval`)", eval_path.display())
        })?)
        .with_context(|| format!("parsing {}", eval_path.display()))?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| workspace_root().join("datasets/models").join(&e.name));
    let assets = Assets::load(&e, &from)?;
    let TestSets { motions, .. } = crate::eval::test_sets(&e, true)?;
    let first = motions
        .first()
        .context("no held-out motion was simulated on the nominal shape")?;
    let files = SequenceFiles::new(
        &e.sim_dir(),
        assets.binding.garment().sha256.clone(),
        assets.body.n_betas(),
    );
    let mut seq = crate::eval::load_truth(&e, &files, std::slice::from_ref(first))?
        .pop()
        .context("no sequence loaded")?;
    let n = args.slice_frames.clamp(1, seq.truth.poses.len());
    seq.truth.poses.truncate(n);
    seq.truth.cloth.truncate(n);
    let error = slice_error_mm(&assets, &seq)?;

    // Stage everything next to the destination, then swap it in.
    let staging = out.with_extension("staging");
    if staging.exists() {
        std::fs::remove_dir_all(&staging)
            .with_context(|| format!("removing {}", staging.display()))?;
    }
    std::fs::create_dir_all(&staging).with_context(|| format!("creating {}", staging.display()))?;
    // The export, and the run's reports where the run has them: how the model was made.
    let run = e.run_dir();
    let reports = [
        e.sim_dir().join("simulate.json"),
        e.dataset_dir().join("dataset.json"),
        run.join("train/train.json"),
        run.join("pipeline.json"),
    ];
    let reports = reports.into_iter().filter(|r| r.exists());
    for f in export_files(&from)?.into_iter().chain(reports) {
        let name = f.file_name().context("file name")?;
        std::fs::copy(&f, staging.join(name))
            .with_context(|| format!("copying {}", f.display()))?;
    }
    write_slice(&staging.join(SLICE_FILE), &seq)?;
    let slice = RegressionSlice {
        shape: seq.shape.clone(),
        motion: seq.motion.clone(),
        frames: n,
        mean_vertex_error_mm: error,
    };
    eval.as_object_mut()
        .context("eval.json is not an object")?
        .insert("regression_slice".into(), serde_json::to_value(&slice)?);
    write_json(&staging.join("eval.json"), &eval)?;
    if out.exists() {
        std::fs::remove_dir_all(&out).with_context(|| format!("removing {}", out.display()))?;
    }
    std::fs::rename(&staging, &out)
        .with_context(|| format!("moving {} to {}", staging.display(), out.display()))?;
    println!(
        "shipped {} to {} (slice {} / {}, {n} frames: {error:.2} mm)",
        from.display(),
        out.display(),
        slice.shape,
        slice.motion
    );
    Ok(())
}

/// Run `check-model`: the slice's error against the recorded one.
pub fn check_model(args: &CheckModelArgs) -> anyhow::Result<()> {
    let dir = if args.model.is_relative() && !args.model.exists() {
        workspace_root().join(&args.model)
    } else {
        args.model.clone()
    };
    let eval_path = dir.join("eval.json");
    let eval: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&eval_path).with_context(|| format!("reading {}", eval_path.display()))?,
    )
    .with_context(|| format!("parsing {}", eval_path.display()))?;
    let recorded: RegressionSlice = serde_json::from_value(
        eval.get("regression_slice")
            .cloned()
            .with_context(|| format!("{}: no `regression_slice`", eval_path.display()))?,
    )
    .with_context(|| format!("{}: bad `regression_slice`", eval_path.display()))?;
    let body_dir = builtin_model_dir();
    let body = BodyModel::load(&body_dir)?;
    let binding = sartor_runtime::GarmentBinding::load(&dir)?;
    let assets = Assets {
        body: std::sync::Arc::new(body),
        binding: std::sync::Arc::new(binding),
        model_dir: dir.clone(),
    };
    let seq = read_slice(&dir.join(SLICE_FILE))?;
    let error = slice_error_mm(&assets, &seq)?;
    let drift = (error - recorded.mean_vertex_error_mm).abs() / recorded.mean_vertex_error_mm;
    println!(
        "{}: slice {} / {} ({} frames): {error:.3} mm, recorded {:.3} mm ({:+.2} %)",
        dir.display(),
        recorded.shape,
        recorded.motion,
        seq.truth.poses.len(),
        recorded.mean_vertex_error_mm,
        100.0 * (error - recorded.mean_vertex_error_mm) / recorded.mean_vertex_error_mm
    );
    if drift.is_nan() || drift > TOLERANCE {
        bail!(
            "{}: the slice error {error:.3} mm is more than {:.0} % away from the recorded {:.3} mm",
            dir.display(),
            100.0 * TOLERANCE,
            recorded.mean_vertex_error_mm
        );
    }
    Ok(())
}
