//! Shipping a run's model ([`ship_model`], `cargo xtask ship`): the export (model + binding)
//! and its `eval.json` copied into a folder under `datasets/models/`, with a small slice of
//! held-out ground truth (`sartor_eval::write_slice`: the first frames of the first held-out
//! clip on the nominal shape) and the model's error on it, recorded in the copied `eval.json` as
//! `regression_slice`. The run's reports (`simulate.json`, `dataset.json`, `train.json`,
//! `pipeline.json`) go with it where the run has them, so the folder says how the model was
//! made. `sartor_eval::check_slice` is the regression check on it.

use std::path::{Path, PathBuf};

use sartor_dataset::SimFolder;
use sartor_eval::{
    Assets, EVAL_FILE, RegressionSlice, SLICE_FILE, TestSets, load_truth, slice_error_mm,
    test_sets, write_json, write_slice,
};

use crate::Result;
use crate::error::{Context, ensure};
use crate::experiment::Experiment;

/// What [`ship_model`] shipped.
#[derive(Clone, Debug)]
pub struct ShipSummary {
    /// The export shipped.
    pub from: PathBuf,
    /// The recorded slice.
    pub slice: RegressionSlice,
}

/// The files of an export folder that are shipped.
fn export_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry
            .with_context(|| format!("reading {}", dir.display()))?
            .path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let model_file = name.ends_with(".json") || name.ends_with(".safetensors");
        if path.is_file() && model_file && !name.starts_with('.') {
            files.push(path);
        }
    }
    files.sort();
    ensure!(!files.is_empty(), "{}: no exported files", dir.display());
    Ok(files)
}

/// Ship the export and evaluation of `e` into `out` with a slice of `slice_frames` frames (see
/// the module docs). The folder is staged beside `out` and swapped in.
pub fn ship_model(e: &Experiment, out: &Path, slice_frames: usize) -> Result<ShipSummary> {
    let from = e.export_dir();
    let eval_path = e.eval_dir().join(EVAL_FILE);
    let mut eval: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&eval_path)
            .with_context(|| format!("reading {} (run the eval stage)", eval_path.display()))?,
    )
    .with_context(|| format!("parsing {}", eval_path.display()))?;
    let assets = Assets::load(&e.body, &from)?;
    let plan = e.plan();
    let TestSets { motions, .. } = test_sets(&plan, &e.sim_dir(), true)?;
    let first = motions
        .first()
        .context("no held-out motion was simulated on the nominal shape")?;
    let files = SimFolder::new(
        &e.sim_dir(),
        assets.binding.garment().sha256.clone(),
        assets.body.n_betas(),
    );
    let mut seq = load_truth(&plan, &files, std::slice::from_ref(first))?
        .pop()
        .context("no sequence loaded")?;
    let n = slice_frames.clamp(1, seq.truth.poses.len());
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
        std::fs::remove_dir_all(out).with_context(|| format!("removing {}", out.display()))?;
    }
    std::fs::rename(&staging, out)
        .with_context(|| format!("moving {} to {}", staging.display(), out.display()))?;
    Ok(ShipSummary { from, slice })
}
