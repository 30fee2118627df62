//! The experiment config (`configs/*.json`): one file names the body, garment, material, shapes,
//! motions and splits, and holds the simulation, dataset, training and evaluation sections.
//! Every section is typed and the whole file is checked when it is loaded, before any stage
//! runs: a malformed value or an unknown key is an error naming the file, the line and the key
//! (a typo in `training` must not surface after hours of simulation). Every command that reads
//! it saves the config it used next to its outputs.
//!
//! ```json
//! {
//!   "name": "default",
//!   "body": "datasets/body/makehuman",
//!   "garment": "datasets/garments/tshirt-4210",
//!   "material": "gray_interlock",
//!   "shapes": { "train": [{"id": "s00", "betas": [0, 0, 0, 0]}, ...],
//!               "validation": [{"id": "v00", "betas": [1, 1, 0, 0]}, ...],
//!               "held_out": [{"id": "h00", "betas": [3, 0, 0, 0]}, ...] },
//!   "motions": { "train": ["walk_normal", ...], "validation": ["cmu/07_02", ...],
//!                "held_out": ["jump_forward", ...],
//!                "held_out_shapes": ["walk_normal", ...], "max_frames": 120,
//!                "shapes_per_motion": 4 },
//!   "simulation": { ... }, "dataset": { ... }, "training": { ... }, "evaluation": { ... }
//! }
//! ```
//!
//! - `simulation`: [`DriveConfig`] (sartor-cloth's driver and simulator settings);
//! - `dataset`: [`DatasetConfig`];
//! - `training`: [`TrainingConfig`] (sartor-model; optional, but `train` needs it);
//! - `evaluation`: [`EvaluationConfig`] (the defaults of `eval` and `tradeoff`).
//!
//! A motion is anything sartor-motion's `load_motion` reads — a procedural clip, an imported
//! clip (`cmu/05_02`), a `.bvh` / `.npz` / `.json` file — or a set of imported clips (`cmu/*`,
//! expanded once at load), each optionally cut to a window (`cmu/05_02@120+90`: 90 frames
//! from frame 120). Loading refuses two specs that would write the same files and any frame
//! of a clip that is in two of the training, validation and held-out motions.
//!
//! Three splits that never overlap: training picks its epochs and settings on the validation
//! motions (on the training shapes) and the validation shapes (their rest simulations, for the
//! fit network); evaluation reports the held-out motions and shapes, the test. A config without
//! validation motions (or shapes) validates on the held-out ones, as the first configs did; the
//! training report says which split it used.
//!
//! Paths are relative to the data folder ([`DataDir`]: the repository, or the data shipped with
//! the `sartor` binary). Outputs go to `<runs>/<name>/` (`sim/`, `dataset/`, `train/`,
//! `export/`, `eval/`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use sartor_cloth::DriveConfig;
use sartor_core::io::{read_file, sha256_hex};
use sartor_dataset::{DatasetConfig, DatasetPlan, REST_MOTION, SequencePlan, ShapePlan, Split};
use sartor_model::TrainingConfig;
use sartor_motion::{MotionWindow, expand_motion_set, motion_file_stem};
use serde::{Deserialize, Serialize};

use crate::error::bail;
use crate::{DataDir, Error, Result};

/// A named shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NamedShape {
    /// Identifier (used in file names: letters, digits, `-` and `_`).
    pub id: String,
    /// β (shorter vectors are padded with zeros).
    pub betas: Vec<f64>,
}

/// Training and held-out shapes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Shapes {
    /// Shapes every training motion is simulated on.
    pub train: Vec<NamedShape>,
    /// Shapes for the shape-generalisation test (some beyond the training range).
    #[serde(default)]
    pub held_out: Vec<NamedShape>,
    /// Shapes the fit network is validated on (rest simulations only; neither trained on nor
    /// reported).
    #[serde(default)]
    pub validation: Vec<NamedShape>,
}

/// Training and held-out motions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Motions {
    /// Motions for training (each on every training shape).
    pub train: Vec<String>,
    /// Held-out motions (each on every training shape; never trained on): the test.
    #[serde(default)]
    pub held_out: Vec<String>,
    /// Validation motions (each on every training shape; never trained on nor reported):
    /// training picks its epochs and settings on them.
    #[serde(default)]
    pub validation: Vec<String>,
    /// Motions simulated on the held-out shapes (any of the above).
    #[serde(default)]
    pub held_out_shapes: Vec<String>,
    /// Use at most this many frames of each motion (`None`: all).
    #[serde(default)]
    pub max_frames: Option<usize>,
    /// Simulate each training and validation motion on this many training shapes (`None`: on
    /// every one, the paper's protocol): the first training shape (the nominal body) and the
    /// next ones in turn, so that every other training shape gets the same share of the
    /// motions. Held-out motions, the test, always run on every training shape.
    #[serde(default)]
    pub shapes_per_motion: Option<usize>,
}

impl Motions {
    /// The training shapes (indices among `n_shapes`) that the `k`-th motion of a list that
    /// [`Motions::shapes_per_motion`] applies to is simulated on: shape 0, then
    /// `shapes_per_motion - 1` of the others, continuing where the motion before left off.
    pub fn shapes_of(&self, k: usize, n_shapes: usize) -> Vec<usize> {
        match self.shapes_per_motion {
            Some(n) if n < n_shapes => {
                let others = n_shapes - 1;
                let mut shapes: Vec<usize> = std::iter::once(0)
                    .chain((0..n - 1).map(|j| 1 + (k * (n - 1) + j) % others))
                    .collect();
                shapes.sort_unstable();
                shapes
            }
            _ => (0..n_shapes).collect(),
        }
    }
}

/// The whole experiment config.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    /// Name; outputs go to `runs/<name>`.
    pub name: String,
    /// Body model folder.
    #[serde(default = "default_body")]
    pub body: PathBuf,
    /// Garment template folder (made by `cargo xtask garment`).
    pub garment: PathBuf,
    /// `"gray_interlock"` or a path to an ARCSim-style material JSON.
    #[serde(default = "default_material")]
    pub material: String,
    /// Shapes.
    pub shapes: Shapes,
    /// Motions.
    pub motions: Motions,
    /// The simulation section (sartor-cloth's driver settings).
    #[serde(default)]
    pub simulation: DriveConfig,
    /// The dataset section.
    #[serde(default)]
    pub dataset: DatasetConfig,
    /// The training section (sartor-model); `train` needs it.
    #[serde(default)]
    pub training: Option<TrainingConfig>,
    /// The evaluation section.
    #[serde(default)]
    pub evaluation: EvaluationConfig,
    /// Where runs go (not part of the file: set by whoever loads it).
    #[serde(skip)]
    pub runs_root: PathBuf,
}

/// The `evaluation` section: what `eval` and `tradeoff` do unless told otherwise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvaluationConfig {
    /// Held-out motions on the nominal shape only (the training shape closest to β = 0, as the
    /// paper did); default false: on every training shape.
    pub nominal_only: bool,
    /// Frames shown in eval's rendered comparison (`compare.png`); default 4.
    pub render_frames: usize,
    /// Output ranks the trade-off sweeps (those below a model's own width); default
    /// 4, 8, 16, 32, 64.
    pub tradeoff_ranks: Vec<usize>,
    /// Frames timed per trade-off point and round; default 120.
    pub tradeoff_timed_frames: usize,
    /// Timing rounds of the trade-off (every point timed once per round); default 15.
    pub tradeoff_rounds: usize,
}

impl Default for EvaluationConfig {
    fn default() -> Self {
        Self {
            nominal_only: false,
            render_frames: 4,
            tradeoff_ranks: vec![4, 8, 16, 32, 64],
            tradeoff_timed_frames: 120,
            tradeoff_rounds: 15,
        }
    }
}

fn default_body() -> PathBuf {
    PathBuf::from("datasets/body/makehuman")
}

fn default_material() -> String {
    "gray_interlock".into()
}

/// A frame two motion specs both use, if they are windows of (or the whole of) one clip whose
/// frames overlap; `None` for different clips. A whole clip overlaps any window of it.
fn shared_frame(a: &str, b: &str) -> Result<Option<usize>> {
    let range = |spec: &str| -> Result<(String, usize, usize)> {
        Ok(match MotionWindow::parse(spec)? {
            Some(w) => (w.motion, w.start, w.start + w.frames),
            None => (spec.to_string(), 0, usize::MAX),
        })
    };
    let ((ma, a0, a1), (mb, b0, b1)) = (range(a)?, range(b)?);
    let start = a0.max(b0);
    Ok((ma == mb && start < a1.min(b1)).then_some(start))
}

/// `spec` with a relative file path (`.bvh`, `.npz`, `.json`, a window suffix kept) resolved
/// against the data folder, as configs name their assets; any other spec unchanged.
pub fn resolve_motion_spec(spec: &str, data: &DataDir) -> String {
    let (motion, window) = match spec.rsplit_once('@') {
        Some((m, w)) if MotionWindow::parse(spec).is_ok_and(|w| w.is_some()) => {
            (m, format!("@{w}"))
        }
        _ => (spec, String::new()),
    };
    let lower = motion.to_ascii_lowercase();
    if [".bvh", ".npz", ".json"].iter().any(|e| lower.ends_with(e)) {
        format!("{}{window}", data.resolve(Path::new(motion)).display())
    } else {
        spec.to_string()
    }
}

fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        && !id.contains("__")
}

impl Experiment {
    /// Read and check a config file (every section, unknown keys included; see the module
    /// docs). Relative asset paths are resolved against `data`; outputs go to
    /// `<runs_root>/<name>`.
    pub fn load(path: &Path, data: &DataDir, runs_root: &Path) -> Result<Self> {
        let bytes = read_file(path)?;
        let mut e = Self::parse(path, &bytes)?;
        for p in [&mut e.body, &mut e.garment] {
            *p = data.resolve(p);
        }
        if e.material != "gray_interlock" {
            e.material = data.resolve(Path::new(&e.material)).display().to_string();
        }
        // Sets (`cmu/*`) become their clips, once, here: the plan, the simulation's files and
        // the saved config all see the same list of motions.
        let motions_dir = data.motions_dir();
        let m = &mut e.motions;
        for list in [
            &mut m.train,
            &mut m.validation,
            &mut m.held_out,
            &mut m.held_out_shapes,
        ] {
            let mut expanded = Vec::with_capacity(list.len());
            for spec in list.iter() {
                if spec.ends_with("/*") {
                    expanded.extend(expand_motion_set(&motions_dir, spec).map_err(|err| {
                        Error::Config {
                            path: path.to_path_buf(),
                            line: 0,
                            message: format!("motion set {spec:?}: {err}"),
                        }
                    })?);
                } else {
                    expanded.push(spec.clone());
                }
            }
            *list = expanded;
        }
        e.validate().map_err(|err| Error::Config {
            path: path.to_path_buf(),
            line: 0,
            message: format!("invalid experiment config (motion sets expanded): {err}"),
        })?;
        e.runs_root = runs_root.to_path_buf();
        Ok(e)
    }

    /// Parse and check config bytes read from `path` (named in errors).
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Self> {
        let config_error = |line: usize, message: String| Error::Config {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut unknown = Vec::new();
        let mut de = serde_json::Deserializer::from_slice(bytes);
        let e: Experiment = serde_ignored::deserialize(&mut de, |key| {
            // `?` stands for an `Option`'s value in serde_ignored's paths: not a key.
            let parts: Vec<String> = key
                .to_string()
                .split('.')
                .filter(|p| *p != "?")
                .map(String::from)
                .collect();
            unknown.push(parts.join("."));
        })
        .map_err(|err| config_error(err.line(), err.to_string()))?;
        de.end()
            .map_err(|err| config_error(err.line(), err.to_string()))?;
        if let Some(key) = unknown.first() {
            let text = String::from_utf8_lossy(bytes);
            return Err(config_error(
                line_of_key(&text, key),
                format!("unknown key `{key}`"),
            ));
        }
        e.validate()
            .map_err(|err| config_error(0, format!("invalid experiment config: {err}")))?;
        Ok(e)
    }

    /// Check names, duplicates, that held-out motions are disjoint from training ones, and the
    /// sections' own invariants.
    pub fn validate(&self) -> Result<()> {
        if !valid_id(&self.name) {
            bail!("name {:?}: use letters, digits, '-' and '_'", self.name);
        }
        let mut ids = BTreeSet::new();
        for s in self
            .shapes
            .train
            .iter()
            .chain(&self.shapes.held_out)
            .chain(&self.shapes.validation)
        {
            if !valid_id(&s.id) {
                bail!(
                    "shape id {:?}: use letters, digits, '-' and '_' (no '__')",
                    s.id
                );
            }
            if !ids.insert(&s.id) {
                bail!("shape id {:?} is used twice", s.id);
            }
            if !s.betas.iter().all(|b| b.is_finite()) {
                bail!("shape {:?} has a non-finite β", s.id);
            }
        }
        if self.shapes.train.is_empty() || self.motions.train.is_empty() {
            bail!("at least one training shape and one training motion are needed");
        }
        let train: BTreeSet<&String> = self.motions.train.iter().collect();
        let held: BTreeSet<&String> = self.motions.held_out.iter().collect();
        let val: BTreeSet<&String> = self.motions.validation.iter().collect();
        if train.len() != self.motions.train.len()
            || held.len() != self.motions.held_out.len()
            || val.len() != self.motions.validation.len()
        {
            bail!("a motion is listed twice");
        }
        let splits = [
            ("training", &train),
            ("validation", &val),
            ("held-out", &held),
        ];
        for (i, (a_name, a)) in splits.iter().enumerate() {
            for (b_name, b) in &splits[i + 1..] {
                if let Some(m) = a.intersection(b).next() {
                    bail!("motion {m:?} is both a {a_name} and a {b_name} motion");
                }
            }
        }
        for m in train.iter().chain(&held).chain(&val) {
            if m.contains("__") || m.as_str() == REST_MOTION {
                bail!("motion name {m:?} is reserved or contains '__'");
            }
        }
        // Every sequence gets its own files: no two motions may share a file stem.
        let mut stems: BTreeMap<String, &String> = BTreeMap::new();
        for m in train.iter().chain(&held).chain(&val) {
            if let Some(other) = stems.insert(motion_file_stem(m), m) {
                bail!(
                    "motions {other:?} and {m:?} would share the file stem {:?}",
                    motion_file_stem(m)
                );
            }
        }
        // No frame of a held-out motion may be trained on or validated on, nor a validation
        // frame trained on: two windows of one clip (or a window and the whole clip) in two
        // splits must not overlap.
        for (i, (a_name, a)) in splits.iter().enumerate() {
            for (b_name, b) in &splits[i + 1..] {
                for t in a.iter() {
                    for h in b.iter() {
                        if let Some(frame) = shared_frame(t, h)? {
                            bail!(
                                "{b_name} motion {h:?} and {a_name} motion {t:?} share frame \
                                 {frame} of the same clip"
                            );
                        }
                    }
                }
            }
        }
        // (Before sets are expanded, a clip of a listed set counts as listed.)
        let in_a_set = |m: &str| {
            train.iter().chain(&held).any(|t| {
                t.strip_suffix("/*")
                    .is_some_and(|set| m.strip_prefix(set).is_some_and(|r| r.starts_with('/')))
            })
        };
        for m in &self.motions.held_out_shapes {
            if !train.contains(m) && !held.contains(m) && !in_a_set(m) {
                bail!("held-out-shape motion {m:?} is neither a training nor a held-out motion");
            }
        }
        if self.motions.max_frames == Some(0) {
            bail!("motions.max_frames must be at least 1");
        }
        if self.motions.shapes_per_motion == Some(0) {
            bail!("motions.shapes_per_motion must be at least 1");
        }
        if let Some(training) = &self.training {
            training.validate()?;
        }
        if self.evaluation.tradeoff_timed_frames == 0 {
            bail!("evaluation.tradeoff_timed_frames must be at least 1");
        }
        if self.evaluation.tradeoff_rounds == 0 {
            bail!("evaluation.tradeoff_rounds must be at least 1");
        }
        Ok(())
    }

    /// The run folder `<runs>/<name>`.
    pub fn run_dir(&self) -> PathBuf {
        self.runs_root.join(&self.name)
    }

    /// Folder of the simulated sequences.
    pub fn sim_dir(&self) -> PathBuf {
        self.run_dir().join("sim")
    }

    /// Folder of the dataset.
    pub fn dataset_dir(&self) -> PathBuf {
        self.run_dir().join("dataset")
    }

    /// Folder of the training runs.
    pub fn train_dir(&self) -> PathBuf {
        self.run_dir().join("train")
    }

    /// The exported model folder.
    pub fn export_dir(&self) -> PathBuf {
        self.run_dir().join("export")
    }

    /// Folder of the evaluation.
    pub fn eval_dir(&self) -> PathBuf {
        self.run_dir().join("eval")
    }

    /// The training section, which `train` needs.
    pub fn training(&self) -> Result<&TrainingConfig> {
        self.training.as_ref().ok_or_else(|| {
            Error::Invalid(format!(
                "experiment {}: the config has no \"training\" section",
                self.name
            ))
        })
    }

    /// The plan: every shape with its split (training, held-out, then validation shapes); every
    /// training shape × (training + held-out + validation motions; training and validation
    /// motions on [`Motions::shapes_of`] only), every held-out shape × `held_out_shapes`
    /// motions. Validation shapes get their rest simulation only.
    pub fn plan(&self) -> DatasetPlan {
        let mut shapes = Vec::new();
        for s in &self.shapes.train {
            shapes.push(ShapePlan {
                id: s.id.clone(),
                betas: s.betas.clone(),
                split: Split::Train,
            });
        }
        for s in &self.shapes.held_out {
            shapes.push(ShapePlan {
                id: s.id.clone(),
                betas: s.betas.clone(),
                split: Split::HeldOutShapes,
            });
        }
        for s in &self.shapes.validation {
            shapes.push(ShapePlan {
                id: s.id.clone(),
                betas: s.betas.clone(),
                split: Split::Validation,
            });
        }
        // Shape-major, as before: a shape's sequences follow each other in the plan.
        let n_train = self.shapes.train.len();
        let on_shape = |list: &[String], i: usize| -> Vec<String> {
            list.iter()
                .enumerate()
                .filter(|(k, _)| self.motions.shapes_of(*k, n_train).contains(&i))
                .map(|(_, m)| m.clone())
                .collect()
        };
        let mut sequences = Vec::new();
        for i in 0..n_train {
            let lists = [
                (on_shape(&self.motions.train, i), Split::Train),
                (self.motions.held_out.clone(), Split::HeldOutMotions),
                (on_shape(&self.motions.validation, i), Split::Validation),
            ];
            for (motions, split) in lists {
                for motion in motions {
                    sequences.push(SequencePlan {
                        shape: i,
                        motion,
                        split,
                    });
                }
            }
        }
        for (i, _) in self.shapes.held_out.iter().enumerate() {
            for m in &self.motions.held_out_shapes {
                sequences.push(SequencePlan {
                    shape: n_train + i,
                    motion: m.clone(),
                    split: Split::HeldOutShapes,
                });
            }
        }
        DatasetPlan { shapes, sequences }
    }

    /// SHA-256 of a section serialised canonically (sorted keys).
    pub fn section_sha256(value: &impl Serialize) -> Result<String> {
        let v = serde_json::to_value(value)?;
        Ok(sha256_hex(serde_json::to_string(&v)?.as_bytes()))
    }
}

/// The 1-based line of `key` (a dotted path such as `training.wrinkle.learning_rte`) in a JSON
/// text: each component is looked up as `"component"` after the previous one.
fn line_of_key(text: &str, key: &str) -> usize {
    let mut at = 0;
    for part in key.split('.') {
        let needle = format!("\"{part}\"");
        match text[at..].find(&needle) {
            Some(i) => at += i,
            None => break,
        }
    }
    text[..at].matches('\n').count() + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    fn config_path(name: &str) -> PathBuf {
        root().join("configs").join(format!("{name}.json"))
    }

    fn config(name: &str) -> Experiment {
        let data = DataDir::new(&root()).expect("the workspace is a data folder");
        Experiment::load(&config_path(name), &data, Path::new("runs"))
            .expect("the committed config is valid")
    }

    /// The tiny config with `edit` applied to its JSON text.
    fn edited(edit: impl Fn(&mut serde_json::Value)) -> Result<Experiment> {
        let path = config_path("tiny");
        let mut v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).expect("read")).expect("json");
        edit(&mut v);
        let text = serde_json::to_string_pretty(&v).expect("json");
        Experiment::parse(Path::new("configs/edited.json"), text.as_bytes())
    }

    /// The tiny config with `edit` applied, loaded (motion sets expanded) from a file.
    fn loaded(edit: impl Fn(&mut serde_json::Value)) -> Result<Experiment> {
        let mut v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(config_path("tiny")).expect("read"))
                .expect("json");
        edit(&mut v);
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("edited.json");
        std::fs::write(&path, serde_json::to_vec_pretty(&v).expect("json")).expect("write");
        let data = DataDir::new(&root()).expect("the workspace is a data folder");
        Experiment::load(&path, &data, Path::new("runs"))
    }

    #[test]
    fn motion_sets_expand_and_clips_never_leak_across_splits() {
        // `cmu/*` becomes every imported CMU clip, in name order, and each gets its own files.
        let e = loaded(|v| {
            v["motions"]["train"] = serde_json::json!(["cmu/*"]);
            v["motions"]["held_out"] = serde_json::json!(["jump_forward"]);
            v["motions"]["held_out_shapes"] = serde_json::json!(["cmu/07_01"]);
        })
        .expect("a set of training motions");
        let all = expand_motion_set(&root().join("datasets/motions"), "cmu/*").expect("set");
        assert_eq!(e.motions.train, all);
        assert!(all.len() >= 10 && all.iter().all(|m| m.starts_with("cmu/")));
        let plan = e.plan();
        let stems: BTreeSet<String> = plan
            .sequences
            .iter()
            .map(|q| sartor_dataset::sequence_stem(&plan.shapes[q.shape].id, &q.motion))
            .collect();
        assert_eq!(stems.len(), plan.sequences.len(), "one file per sequence");
        assert!(stems.iter().all(|s| !s.contains('/')), "{stems:?}");

        // A held-out clip inside a training set, or overlapping windows of one clip, are refused;
        // disjoint windows of one clip are fine.
        let clip = all[0].clone();
        let leak = loaded(|v| {
            v["motions"]["train"] = serde_json::json!(["cmu/*"]);
            v["motions"]["held_out"] = serde_json::json!([clip.clone()]);
            v["motions"]["held_out_shapes"] = serde_json::json!([clip.clone()]);
        })
        .expect_err("a held-out clip in the training set");
        assert!(leak.to_string().contains(&clip), "{leak}");
        let overlap = loaded(|v| {
            v["motions"]["train"] = serde_json::json!([format!("{clip}@0+60")]);
            v["motions"]["held_out"] = serde_json::json!([format!("{clip}@59+30")]);
            v["motions"]["held_out_shapes"] = serde_json::json!([]);
        })
        .expect_err("overlapping windows");
        assert!(overlap.to_string().contains("share frame 59"), "{overlap}");
        loaded(|v| {
            v["motions"]["train"] = serde_json::json!([format!("{clip}@0+60")]);
            v["motions"]["held_out"] = serde_json::json!([format!("{clip}@60+30")]);
            v["motions"]["held_out_shapes"] = serde_json::json!([format!("{clip}@0+60")]);
        })
        .expect("disjoint windows of one clip");
        // Two specs that would write the same files.
        let same = loaded(|v| {
            v["motions"]["train"] = serde_json::json!(["cmu/05_02", "cmu-05_02.json"]);
            v["motions"]["held_out_shapes"] = serde_json::json!([]);
        })
        .expect_err("one file stem for two motions");
        assert!(same.to_string().contains("file stem"), "{same}");
    }

    #[test]
    fn motion_paths_resolve_against_the_data_folder() {
        let data = DataDir::new(&root()).expect("data folder");
        let spec = "crates/sartor-motion/tests/data/cmu/07_01.bvh@10+20";
        let resolved = resolve_motion_spec(spec, &data);
        assert!(resolved.ends_with("07_01.bvh@10+20"), "{resolved}");
        let path = resolved.trim_end_matches("@10+20");
        assert!(
            Path::new(path).is_absolute() && Path::new(path).is_file(),
            "{path}"
        );
        assert_eq!(resolve_motion_spec("cmu/05_02@1+2", &data), "cmu/05_02@1+2");
        assert_eq!(resolve_motion_spec("walk_normal", &data), "walk_normal");
    }

    #[test]
    fn unknown_keys_are_rejected_with_file_line_and_key() {
        // A typo in a burn `Config` section (which serde alone would ignore).
        let e = edited(|v| v["training"]["wrinkle"]["learning_rte"] = 0.1.into())
            .expect_err("typo in training");
        let msg = e.to_string();
        assert!(msg.contains("configs/edited.json:"), "{msg}");
        assert!(msg.contains("training.wrinkle.learning_rte"), "{msg}");
        match e {
            Error::Config { line, .. } => assert!(line > 1, "line {line}"),
            other => panic!("not a config error: {other}"),
        }
        // A typo in the simulation section, in the top level, in evaluation.
        for (section, key) in [("simulation", "substeps"), ("evaluation", "nominal")] {
            let e = edited(|v| v[section][key] = 1.into()).expect_err("unknown key");
            assert!(e.to_string().contains(key), "{e}");
            assert!(matches!(e, Error::Config { line, .. } if line > 1), "{e}");
        }
        let e = edited(|v| v["trainig"] = serde_json::json!({})).expect_err("top-level typo");
        assert!(e.to_string().contains("trainig"), "{e}");
        // A bad value in the training section is caught at load, not at the train stage.
        let e =
            edited(|v| v["training"]["wrinkle"]["batch_size"] = 0.into()).expect_err("zero batch");
        assert!(e.to_string().contains("batch"), "{e}");
        // The untouched config parses.
        edited(|_| {}).expect("tiny parses");
    }

    #[test]
    fn line_of_key_follows_the_path() {
        let text = "{\n  \"a\": {\n    \"x\": 1\n  },\n  \"b\": {\n    \"x\": 2\n  }\n}\n";
        assert_eq!(line_of_key(text, "a.x"), 3);
        assert_eq!(line_of_key(text, "b.x"), 6);
        assert_eq!(line_of_key(text, "b"), 5);
    }

    #[test]
    fn committed_configs_are_valid_and_their_plans_do_not_leak() {
        for name in [
            "tiny",
            "default",
            "default-8710",
            "default-implicit-friction",
            "default-contact",
            "procedural",
            "paper",
        ] {
            let e = config(name);
            let plan = e.plan();
            plan.validate(10).expect("a valid plan");
            let held: BTreeSet<&String> = e.motions.held_out.iter().collect();
            for q in &plan.sequences {
                let shape = &plan.shapes[q.shape];
                // No frame of a held-out clip or shape is in the training split.
                if q.split == Split::Train {
                    assert!(!held.contains(&q.motion), "{name}: {}", q.motion);
                    assert_eq!(shape.split, Split::Train, "{name}: {}", shape.id);
                }
            }
            assert!(
                !e.shapes.held_out.is_empty(),
                "{name} tests shape generalisation"
            );
        }
        // The experiments on real motion: at least four test clips that no other split sees
        // any frame of, a validation split, and training shapes that vary all ten β.
        let clip = |m: &String| m.split('@').next().unwrap_or(m).to_string();
        for name in ["default", "paper"] {
            let e = config(name);
            let test: BTreeSet<String> = e.motions.held_out.iter().map(clip).collect();
            assert!(test.len() >= 4, "{name}: {test:?}");
            assert!(
                test.iter().all(|c| c.starts_with("cmu/")),
                "{name}: {test:?}"
            );
            assert!(!e.motions.validation.is_empty(), "{name}");
            for m in e.motions.train.iter().chain(&e.motions.validation) {
                assert!(!test.contains(&clip(m)), "{name}: {m} is a test clip");
            }
        }
        // The garment-resolution axis: the same experiment on another garment, so that the two
        // models see the same shapes, motions, simulation and training.
        let (a, b) = (config("default"), config("default-8710"));
        let ids = |e: &Experiment| {
            let plan = e.plan();
            plan.sequences
                .iter()
                .map(|q| (q.id(&plan.shapes), q.split))
                .collect::<Vec<_>>()
        };
        assert_eq!(ids(&a), ids(&b));
        assert_eq!(
            serde_json::to_value(&a.training).expect("json"),
            serde_json::to_value(&b.training).expect("json")
        );
        assert_ne!(a.garment, b.garment);
        // Both simulate with the same settings, each at a step its garment's resolution keeps
        // smooth (at 10 substeps per frame the shirts crumple on fast motion).
        assert_eq!(a.simulation, b.simulation);
        // The reference experiment with ARCSim's friction in the solve: the same plan and
        // training, the simulation different only in its friction model and step.
        let c = config("default-implicit-friction");
        assert_eq!(ids(&a), ids(&c));
        assert_eq!(
            serde_json::to_value(&a.training).expect("json"),
            serde_json::to_value(&c.training).expect("json")
        );
        assert_eq!(a.garment, c.garment);
        assert_eq!(
            c.simulation.sim.friction_model,
            sartor_cloth::FrictionModel::Implicit
        );
        // The reference experiment with the GRU's contact term: the same but for its weight.
        let d = config("default-contact");
        assert_eq!(ids(&a), ids(&d));
        assert_eq!((&a.garment, &a.simulation), (&d.garment, &d.simulation));
        let weight = |e: &Experiment| e.training().expect("training").contact_weight();
        assert_eq!(weight(&a), 0.0);
        assert!(weight(&d) > 0.0);
        let mut paper = d.training.clone();
        if let Some(t) = &mut paper {
            t.contact_weight = None;
        }
        assert_eq!(
            serde_json::to_value(&a.training).expect("json"),
            serde_json::to_value(&paper).expect("json")
        );
        let mut back = c.simulation.clone();
        back.sim.friction_model = sartor_cloth::FrictionModel::Impulse;
        back.substeps_per_frame = a.simulation.substeps_per_frame;
        back.max_step_per_edge_s_per_m = a.simulation.max_step_per_edge_s_per_m;
        assert_eq!(back, a.simulation);
        for e in [&a, &b, &c] {
            let garment = sartor_cloth::Garment::load(&e.garment).expect("the config's garment");
            let edge = sartor_cloth::Cloth::from_garment(
                &garment,
                sartor_cloth::Material::gray_interlock(),
            )
            .expect("cloth")
            .median_rest_edge_m();
            let step = e.simulation.step_per_edge_s_per_m(edge, sartor_core::FPS);
            assert!(
                step <= e.simulation.stable_step_per_edge_s_per_m() * (1.0 + 1e-9),
                "{}: {step} s per metre of edge",
                e.garment.display()
            );
        }
        let e = config("default");
        for k in 0..10 {
            assert!(
                e.shapes
                    .train
                    .iter()
                    .any(|s| s.betas.get(k).is_some_and(|b| *b != 0.0)),
                "no training shape varies β{k}"
            );
        }
    }

    #[test]
    fn validation_motions_and_shapes_are_a_split_of_their_own() {
        let clip = "cmu/07_01";
        let e = loaded(|v| {
            v["motions"]["train"] = serde_json::json!([format!("{clip}@0+40"), "walk_normal"]);
            v["motions"]["validation"] = serde_json::json!([format!("{clip}@40+20")]);
            v["motions"]["held_out"] = serde_json::json!([format!("{clip}@60+20")]);
            v["motions"]["held_out_shapes"] = serde_json::json!(["walk_normal"]);
            v["shapes"]["validation"] = serde_json::json!([{"id": "v00", "betas": [0.7]}]);
        })
        .expect("three disjoint windows of one clip");
        let plan = e.plan();
        plan.validate(10).expect("a valid plan");
        let n_train = e.shapes.train.len();
        // Every training shape gets the validation window; the validation shape gets none.
        let val: Vec<_> = plan
            .sequences
            .iter()
            .filter(|q| q.split == Split::Validation)
            .collect();
        assert_eq!(val.len(), n_train);
        for q in &val {
            assert_eq!(q.motion, format!("{clip}@40+20"));
            assert_eq!(plan.shapes[q.shape].split, Split::Train);
        }
        let v00 = plan.shapes.iter().position(|s| s.id == "v00").expect("v00");
        assert_eq!(plan.shapes[v00].split, Split::Validation);
        assert!(plan.sequences.iter().all(|q| q.shape != v00));
        // A validation frame in the training or the held-out set is refused.
        for (other, window) in [("train", "@30+20"), ("held_out", "@55+20")] {
            let err = loaded(|v| {
                v["motions"]["train"] = serde_json::json!(["walk_normal"]);
                v["motions"]["held_out"] = serde_json::json!([]);
                v["motions"]["held_out_shapes"] = serde_json::json!([]);
                v["motions"]["validation"] = serde_json::json!([format!("{clip}@40+20")]);
                v["motions"][other] = serde_json::json!([format!("{clip}{window}")]);
            })
            .expect_err("overlapping validation window");
            assert!(err.to_string().contains("validation motion"), "{err}");
        }
        let err = loaded(|v| {
            v["motions"]["validation"] = serde_json::json!(["walk_normal"]);
        })
        .expect_err("a training motion listed for validation");
        assert!(err.to_string().contains("walk_normal"), "{err}");
        // A validation shape id may not repeat a training one.
        let mut e = config("tiny");
        e.shapes.validation.push(e.shapes.train[0].clone());
        assert!(e.validate().is_err());
    }

    #[test]
    fn shapes_per_motion_spreads_motions_evenly_over_the_shapes() {
        let e = edited(|v| {
            v["shapes"]["train"] = serde_json::json!(
                (0..7)
                    .map(|i| serde_json::json!({"id": format!("s{i}"), "betas": [i]}))
                    .collect::<Vec<_>>()
            );
            v["motions"]["train"] = serde_json::json!(["walk_normal", "walk_fast", "run_jog"]);
            v["motions"]["validation"] = serde_json::json!(["squat_deep", "torso_twist"]);
            v["motions"]["shapes_per_motion"] = serde_json::json!(3);
        })
        .expect("valid");
        let plan = e.plan();
        plan.validate(10).expect("a valid plan");
        let of = |split: Split| -> Vec<(String, usize)> {
            plan.sequences
                .iter()
                .filter(|q| q.split == split)
                .map(|q| (q.motion.clone(), q.shape))
                .collect()
        };
        let train = of(Split::Train);
        // Each motion on the nominal shape and two others; the six others once each.
        assert_eq!(train.len(), 3 * 3);
        for m in &e.motions.train {
            let shapes: Vec<usize> = train
                .iter()
                .filter(|(n, _)| n == m)
                .map(|(_, s)| *s)
                .collect();
            assert_eq!(shapes.len(), 3, "{m}: {shapes:?}");
            assert!(shapes.contains(&0), "{m} runs on the nominal shape");
        }
        for s in 1..7 {
            assert_eq!(
                train.iter().filter(|(_, t)| *t == s).count(),
                1,
                "shape {s}"
            );
        }
        assert_eq!(of(Split::Validation).len(), 2 * 3);
        // The test split stays on every training shape.
        assert_eq!(
            of(Split::HeldOutMotions).len(),
            7 * e.motions.held_out.len()
        );
        // At least every shape: the paper's protocol.
        let all = edited(|v| v["motions"]["shapes_per_motion"] = serde_json::json!(9));
        let n = all.expect("valid").shapes.train.len();
        assert_eq!(e.motions.shapes_of(0, 2), vec![0, 1]);
        assert_eq!(
            Motions {
                shapes_per_motion: None,
                ..e.motions.clone()
            }
            .shapes_of(4, n)
            .len(),
            n
        );
        assert!(edited(|v| v["motions"]["shapes_per_motion"] = serde_json::json!(0)).is_err());
    }

    #[test]
    fn bad_configs_are_rejected() {
        let mut e = config("tiny");
        e.motions.held_out.push(e.motions.train[0].clone());
        assert!(e.validate().is_err());
        let mut e = config("tiny");
        e.shapes.held_out.push(e.shapes.train[0].clone());
        assert!(e.validate().is_err());
        let mut e = config("tiny");
        e.shapes.train[0].id = "a__b".into();
        assert!(e.validate().is_err());
        let mut e = config("tiny");
        e.motions.held_out_shapes.push("not_listed".into());
        assert!(e.validate().is_err());
    }
}
