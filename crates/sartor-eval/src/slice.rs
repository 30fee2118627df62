//! The regression slice of a shipped model: a few frames of held-out ground truth stored
//! beside the model (`regression-slice.safetensors`), and the model's error on it recorded in
//! its `eval.json` as `regression_slice`. [`check_slice`] recomputes that error with the runtime
//! and fails beyond [`TOLERANCE`] of the record: the regression test of a shipped model.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use nalgebra::Vector3;
use sartor_core::{BodyModel, Pose};
use sartor_dataset::SimulatedMotion;
use sartor_runtime::{AnimatorOptions, GarmentBinding, NetworkOptions};
use serde::{Deserialize, Serialize};

use crate::error::{Context, bail};
use crate::eval::{Assets, EVAL_FILE, Method, TestSequence, run_sequence};
use crate::{Error, Result};

/// File name of the stored ground-truth slice.
pub const SLICE_FILE: &str = "regression-slice.safetensors";
/// Largest relative drift `check-model` accepts.
pub const TOLERANCE: f64 = 0.10;

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

/// Store the ground truth of `seq` as a slice file.
pub fn write_slice(path: &Path, seq: &TestSequence) -> Result<()> {
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

/// Read a slice file back (validated: sizes, finiteness).
pub fn read_slice(path: &Path) -> Result<TestSequence> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
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
pub fn slice_error_mm(assets: &Assets, seq: &TestSequence) -> Result<f64> {
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

/// What [`check_slice`] found.
#[derive(Clone, Debug)]
pub struct SliceCheck {
    /// The recorded slice.
    pub recorded: RegressionSlice,
    /// The error recomputed now, mm.
    pub error_mm: f64,
    /// Frames of the stored slice.
    pub frames: usize,
}

/// Recompute the error of the shipped model in `model_dir` (on the body in `body_dir`) on its
/// stored slice, and fail when it is more than [`TOLERANCE`] away from the recorded figure.
pub fn check_slice(model_dir: &Path, body_dir: &Path) -> Result<SliceCheck> {
    let eval_path = model_dir.join(EVAL_FILE);
    let eval: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&eval_path).map_err(|e| Error::io(&eval_path, e))?)
            .with_context(|| format!("parsing {}", eval_path.display()))?;
    let recorded: RegressionSlice =
        serde_json::from_value(eval.get("regression_slice").cloned().ok_or_else(|| {
            Error::Invalid(format!("{}: no `regression_slice`", eval_path.display()))
        })?)
        .with_context(|| format!("{}: bad `regression_slice`", eval_path.display()))?;
    let body = BodyModel::load(body_dir)?;
    let binding = GarmentBinding::load(model_dir)?;
    let assets = Assets {
        body: Arc::new(body),
        binding: Arc::new(binding),
        model_dir: model_dir.to_path_buf(),
    };
    let seq = read_slice(&model_dir.join(SLICE_FILE))?;
    let error_mm = slice_error_mm(&assets, &seq)?;
    let drift = (error_mm - recorded.mean_vertex_error_mm).abs() / recorded.mean_vertex_error_mm;
    if drift.is_nan() || drift > TOLERANCE {
        bail!(
            "{}: the slice error {error_mm:.3} mm is more than {:.0} % away from the recorded {:.3} mm",
            model_dir.display(),
            100.0 * TOLERANCE,
            recorded.mean_vertex_error_mm
        );
    }
    Ok(SliceCheck {
        recorded,
        error_mm,
        frames: seq.truth.poses.len(),
    })
}
