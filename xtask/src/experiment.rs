//! The experiment config (`configs/*.json`): one file names the body, garment, material, shapes,
//! motions and splits, and holds the simulation, dataset, training and evaluation sections.
//! Every command that reads it saves the config it used next to its outputs.
//!
//! ```json
//! {
//!   "name": "default",
//!   "body": "datasets/body/makehuman",
//!   "garment": "datasets/garments/tshirt-4210",
//!   "material": "gray_interlock",
//!   "shapes": { "train": [{"id": "s00", "betas": [0, 0, 0, 0]}, ...],
//!               "held_out": [{"id": "h00", "betas": [3, 0, 0, 0]}, ...] },
//!   "motions": { "train": ["walk_normal", ...], "held_out": ["jump_forward", ...],
//!                "held_out_shapes": ["walk_normal", ...], "max_frames": 120 },
//!   "simulation": { ... }, "dataset": { ... }, "training": { ... }, "evaluation": { ... }
//! }
//! ```
//!
//! Paths are relative to the workspace root (where `cargo xtask` runs). Outputs go to
//! `runs/<name>/` (`sim/`, `dataset/`, training run, `eval/`).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use sartor_core::io::{read_file, sha256_hex};
use sartor_dataset::{DatasetConfig, DatasetPlan, SequencePlan, ShapePlan, Split};
use serde::{Deserialize, Serialize};

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
}

/// Training and held-out motions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Motions {
    /// Motions for training (each on every training shape).
    pub train: Vec<String>,
    /// Held-out motions (each on every training shape; never trained on).
    #[serde(default)]
    pub held_out: Vec<String>,
    /// Motions simulated on the held-out shapes (any of the above).
    #[serde(default)]
    pub held_out_shapes: Vec<String>,
    /// Use at most this many frames of each motion (`None`: all).
    #[serde(default)]
    pub max_frames: Option<usize>,
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
    pub simulation: serde_json::Value,
    /// The dataset section.
    #[serde(default)]
    pub dataset: DatasetConfig,
    /// The training section (sartor-model).
    #[serde(default)]
    pub training: serde_json::Value,
    /// The evaluation section.
    #[serde(default)]
    pub evaluation: serde_json::Value,
    /// Where runs go (not part of the file: `--runs-dir`, default `<workspace>/runs`).
    #[serde(skip)]
    pub runs_root: PathBuf,
}

/// The `--config` / `--runs-dir` pair every experiment command takes.
#[derive(clap::Args, Clone, Debug)]
pub struct ExperimentArgs {
    /// The experiment config (e.g. configs/default.json).
    #[arg(long)]
    pub config: PathBuf,
    /// Folder of the runs (outputs go to <runs-dir>/<name>).
    #[arg(long)]
    pub runs_dir: Option<PathBuf>,
}

impl ExperimentArgs {
    /// Load the config and set where its outputs go.
    pub fn load(&self) -> anyhow::Result<Experiment> {
        let mut e = Experiment::load(&self.config)?;
        e.runs_root = self
            .runs_dir
            .clone()
            .unwrap_or_else(|| crate::workspace_root().join("runs"));
        Ok(e)
    }
}

fn default_body() -> PathBuf {
    PathBuf::from("datasets/body/makehuman")
}

fn default_material() -> String {
    "gray_interlock".into()
}

/// The rest-pose simulation of a shape (for Δ_G) is stored under this motion name.
pub const REST_MOTION: &str = "rest";

fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        && !id.contains("__")
}

impl Experiment {
    /// Read and check a config file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let bytes = read_file(path)?;
        let mut e: Experiment = serde_json::from_slice(&bytes)
            .with_context(|| format!("{}: not a valid experiment config", path.display()))?;
        e.validate()
            .with_context(|| format!("{}: invalid experiment config", path.display()))?;
        // Relative paths are relative to the workspace root, wherever cargo runs from.
        let root = crate::workspace_root();
        for p in [&mut e.body, &mut e.garment] {
            if p.is_relative() {
                *p = root.join(&*p);
            }
        }
        if e.material != "gray_interlock" && Path::new(&e.material).is_relative() {
            e.material = root.join(&e.material).display().to_string();
        }
        e.runs_root = root.join("runs");
        Ok(e)
    }

    /// Check names, duplicates and that held-out motions are disjoint from training ones.
    pub fn validate(&self) -> anyhow::Result<()> {
        if !valid_id(&self.name) {
            bail!("name {:?}: use letters, digits, '-' and '_'", self.name);
        }
        let mut ids = BTreeSet::new();
        for s in self.shapes.train.iter().chain(&self.shapes.held_out) {
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
        if train.len() != self.motions.train.len() || held.len() != self.motions.held_out.len() {
            bail!("a motion is listed twice");
        }
        if let Some(m) = train.intersection(&held).next() {
            bail!("motion {m:?} is both a training and a held-out motion");
        }
        for m in train.iter().chain(&held) {
            if m.contains("__") || m.as_str() == REST_MOTION {
                bail!("motion name {m:?} is reserved or contains '__'");
            }
        }
        for m in &self.motions.held_out_shapes {
            if !train.contains(m) && !held.contains(m) {
                bail!("held-out-shape motion {m:?} is neither a training nor a held-out motion");
            }
        }
        if self.motions.max_frames == Some(0) {
            bail!("motions.max_frames must be at least 1");
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

    /// The plan: every shape with its split; every training shape × (training + held-out
    /// motions), every held-out shape × `held_out_shapes` motions.
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
        let mut sequences = Vec::new();
        for (i, _) in self.shapes.train.iter().enumerate() {
            for m in &self.motions.train {
                sequences.push(SequencePlan {
                    shape: i,
                    motion: m.clone(),
                    split: Split::Train,
                });
            }
            for m in &self.motions.held_out {
                sequences.push(SequencePlan {
                    shape: i,
                    motion: m.clone(),
                    split: Split::HeldOutMotions,
                });
            }
        }
        let n_train = self.shapes.train.len();
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
    pub fn section_sha256(value: &impl Serialize) -> anyhow::Result<String> {
        let v = serde_json::to_value(value)?;
        Ok(sha256_hex(serde_json::to_string(&v)?.as_bytes()))
    }
}

/// The file stem of a simulated sequence: `<shape>__<motion>`.
pub fn sequence_stem(shape_id: &str, motion: &str) -> String {
    format!("{shape_id}__{motion}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(name: &str) -> Experiment {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../configs")
            .join(format!("{name}.json"));
        Experiment::load(&path).expect("the committed config is valid")
    }

    #[test]
    fn committed_configs_are_valid_and_their_plans_do_not_leak() {
        for name in ["tiny", "default", "paper"] {
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
