//! The exported garment model: `model.safetensors` (f32 tensors) + `model.json` (sizes, input
//! layout, provenance, content hash). The training side writes exactly this; the runtime
//! validates all of it on load.
//!
//! # Tensors (f32, row-major; `V` vertices, `B` = `n_betas`, `I` = `n_betas +
//! n_pose_features`, `H_f` = `fit_hidden`, `H` = `gru_hidden`)
//!
//! Any tensor may also be stored as f16 (the reader widens it to f32 exactly):
//! [`TensorStorage::F16`] writes the 2-D weight matrices so, for a page that downloads the
//! model. The version stays 1: files written in f32 read as before.
//!
//! | name | shape | |
//! | --- | --- | --- |
//! | `fit.hidden.weight`, `fit.hidden.bias` | `[H_f, B]`, `[H_f]` | fit MLP, ReLU after |
//! | `fit.out.weight`, `fit.out.bias` | `[3V, H_f]`, `[3V]` | |
//! | `wrinkle.gru.weight_ih`, `wrinkle.gru.bias_ih` | `[3H, I]`, `[3H]` | gates `(r, z, n)` |
//! | `wrinkle.gru.weight_hh`, `wrinkle.gru.bias_hh` | `[3H, H]`, `[3H]` | PyTorch's GRU |
//! | `wrinkle.out.weight`, `wrinkle.out.bias` | `[O, H]`, `[O]` | `O = 3V` dense, `k` PCA |
//! | `wrinkle.pca.basis`, `wrinkle.pca.mean` | `[3V, k]`, `[3V]` | PCA output only |
//! | `lr.weight`, `lr.bias` | `[3V, I]`, `[3V]` | `linear_baseline` only |
//! | `norm.fit_in_mean`, `norm.fit_in_std` | `[B]` | |
//! | `norm.wrinkle_in_mean`, `norm.wrinkle_in_std` | `[I]` | |
//! | `norm.fit_out_mean`, `norm.fit_out_std` | `[3V]` | |
//! | `norm.wrinkle_out_mean`, `norm.wrinkle_out_std` | `[3V]` | |
//!
//! Displacements are ordered `(v·3 + c)` (vertex-major, xyz). Networks see normalised inputs
//! `(x − mean) / std` and produce normalised outputs; displacement `= out · std + mean` (for the
//! PCA variant, of the reconstructed `3V` vector `pca.mean + basis · out`). The linear
//! baseline maps the normalised wrinkle input to the normalised wrinkle output (it stands in
//! for the GRU). No other tensor may be present; every `std` must be positive.
//!
//! # JSON (`deny_unknown_fields` everywhere)
//!
//! ```json
//! {
//!   "format": "sartor-garment-model",
//!   "version": 1,
//!   "garment": { "id": "tshirt", "sha256": "<64 hex>" },
//!   "body": { "id": "makehuman", "sha256": "<64 hex>" },
//!   "sizes": {
//!     "n_vertices": 4424, "n_betas": 10, "n_pose_features": 136,
//!     "fit_hidden": 20, "gru_hidden": 1500,
//!     "output": "dense",
//!     "linear_baseline": false
//!   },
//!   "wrinkle_inputs": [
//!     { "name": "betas", "offset": 0, "len": 10, "feature": "betas" },
//!     { "name": "pose", "offset": 10, "len": 132, "feature":
//!       { "joint_rotations": { "encoding": "rot6d", "joints": ["Spine", "..."] } } },
//!     { "name": "root", "offset": 142, "len": 4, "feature":
//!       { "root": { "components": ["vel_x", "vel_y", "vel_z", "yaw_rate"] } } }
//!   ],
//!   "tensors_sha256": "<sha256 of model.safetensors>",
//!   "training_betas": [[0, 0, 0, 0, 0, 0, 0, 0, 0, 0], [-2, 0, 0, 0, 0, 0, 0, 0, 0, 0], "..."]
//! }
//! ```
//!
//! `training_betas` (optional; models exported before it have none) lists the β of the
//! training shapes: the networks were trained on their convex hull at best. Beyond it the
//! animator applies a [`crate::BetaOutOfRange`] rule.
//!
//! `output` is `"dense"` or `{ "pca": k }`; `encoding` is `"rot6d"` (6 values per joint),
//! `"quaternion"` (4) or `"axis_angle"` (3). The animator ([`crate::GarmentRig`]) computes each
//! pose block with `sartor_core::PoseFeatures`, so joint names must be the body's and root
//! components must be `sartor_core::RootFeature` names (`vel_x`, `vel_y`, `vel_z`,
//! `yaw_rate`); the format itself accepts any names. The blocks of `wrinkle_inputs` tile
//! `0..n_betas + n_pose_features` in order; exactly one is `"betas"` (of length `n_betas`).
//! The fit MLP's input is β itself (`n_betas` values).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use sartor_core::asset::AssetFiles;
use sartor_core::io::{OwnedTensor, read_file, serialize_tensors, sha256_hex};
use sartor_core::{GarmentBinding, PoseFeatureSpec};
pub use sartor_core::{MeanStd, NormStats};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The `format` string of `model.json`.
pub const MODEL_FORMAT: &str = "sartor-garment-model";
/// The `version` of `model.json` this crate reads and writes.
pub const MODEL_VERSION: u32 = 1;
/// File name of the JSON sidecar inside a model folder.
pub const MODEL_JSON: &str = "model.json";
/// File name of the tensors inside a model folder.
pub const MODEL_TENSORS: &str = "model.safetensors";

/// The model's file pair.
const FILES: AssetFiles = AssetFiles {
    header: MODEL_JSON,
    tensors: MODEL_TENSORS,
    format: MODEL_FORMAT,
    version: MODEL_VERSION,
};

/// An asset the model was trained for, identified by name and content hash: sartor-core's
/// one asset identity.
pub use sartor_core::asset::AssetId;

/// The wrinkle regressor's output.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// `3V` values straight from the output layer (`"dense"`).
    Dense,
    /// `k` PCA coefficients (`{"pca": k}`).
    Pca(usize),
}

/// Rotation encoding of a joint-rotation feature block: sartor-core's, so the runtime computes
/// exactly the features the dataset trained on.
pub use sartor_core::RotationEncoding;

/// What a block of the wrinkle input holds.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Feature {
    /// The body shape β (`n_betas` values).
    Betas,
    /// Local joint rotations, one encoded rotation per named joint, in the order given.
    JointRotations {
        /// The encoding.
        encoding: RotationEncoding,
        /// Joint names (body model names), unique.
        joints: Vec<String>,
    },
    /// Root features, one scalar per named component (e.g. velocities in the root frame).
    Root {
        /// Component names, unique.
        components: Vec<String>,
    },
}

/// A named, contiguous block of the wrinkle input vector.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureBlock {
    /// Unique block name.
    pub name: String,
    /// First index in the input vector.
    pub offset: usize,
    /// Number of values.
    pub len: usize,
    /// What the values are.
    pub feature: Feature,
}

impl FeatureBlock {
    /// The wrinkle input layout of sartor's datasets as feature blocks: β (`n_betas` values),
    /// then the joint rotations of `pose`, then its root components (blocks without values
    /// left out).
    pub fn layout(n_betas: usize, pose: &PoseFeatureSpec) -> Vec<Self> {
        let mut blocks = vec![Self {
            name: "betas".into(),
            offset: 0,
            len: n_betas,
            feature: Feature::Betas,
        }];
        let mut offset = n_betas;
        if !pose.joints.is_empty() {
            let len = pose.joints.len() * pose.encoding.width();
            blocks.push(Self {
                name: "pose".into(),
                offset,
                len,
                feature: Feature::JointRotations {
                    encoding: pose.encoding,
                    joints: pose.joints.clone(),
                },
            });
            offset += len;
        }
        if !pose.root.is_empty() {
            blocks.push(Self {
                name: "root".into(),
                offset,
                len: pose.root.len(),
                feature: Feature::Root {
                    components: pose.root.iter().map(|r| r.name().to_string()).collect(),
                },
            });
        }
        blocks
    }
}

/// Network sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSizes {
    /// Garment vertices `V` (outputs are `3V`).
    pub n_vertices: usize,
    /// Shape coefficients β (the fit MLP's input).
    pub n_betas: usize,
    /// Wrinkle inputs besides β.
    pub n_pose_features: usize,
    /// Hidden units of the fit MLP.
    pub fit_hidden: usize,
    /// Hidden units of the wrinkle GRU.
    pub gru_hidden: usize,
    /// Dense or PCA output.
    pub output: OutputKind,
    /// Whether the `lr.*` baseline tensors are present.
    pub linear_baseline: bool,
}

impl ModelSizes {
    /// Wrinkle input size `I = n_betas + n_pose_features`.
    pub fn wrinkle_inputs(&self) -> usize {
        self.n_betas + self.n_pose_features
    }

    /// Output size `3V`.
    pub fn n_outputs(&self) -> usize {
        3 * self.n_vertices
    }

    /// Rows of `wrinkle.out.weight`: `3V` (dense) or `k` (PCA).
    pub fn wrinkle_out_rows(&self) -> usize {
        match self.output {
            OutputKind::Dense => self.n_outputs(),
            OutputKind::Pca(k) => k,
        }
    }

    /// Every tensor this model must hold, with its shape, sorted by name.
    pub fn tensor_shapes(&self) -> BTreeMap<&'static str, Vec<usize>> {
        let (b, i, hf, h, o3) = (
            self.n_betas,
            self.wrinkle_inputs(),
            self.fit_hidden,
            self.gru_hidden,
            self.n_outputs(),
        );
        let out = self.wrinkle_out_rows();
        let mut t = BTreeMap::from([
            ("fit.hidden.weight", vec![hf, b]),
            ("fit.hidden.bias", vec![hf]),
            ("fit.out.weight", vec![o3, hf]),
            ("fit.out.bias", vec![o3]),
            ("wrinkle.gru.weight_ih", vec![3 * h, i]),
            ("wrinkle.gru.weight_hh", vec![3 * h, h]),
            ("wrinkle.gru.bias_ih", vec![3 * h]),
            ("wrinkle.gru.bias_hh", vec![3 * h]),
            ("wrinkle.out.weight", vec![out, h]),
            ("wrinkle.out.bias", vec![out]),
            ("norm.fit_in_mean", vec![b]),
            ("norm.fit_in_std", vec![b]),
            ("norm.wrinkle_in_mean", vec![i]),
            ("norm.wrinkle_in_std", vec![i]),
            ("norm.fit_out_mean", vec![o3]),
            ("norm.fit_out_std", vec![o3]),
            ("norm.wrinkle_out_mean", vec![o3]),
            ("norm.wrinkle_out_std", vec![o3]),
        ]);
        if let OutputKind::Pca(k) = self.output {
            t.insert("wrinkle.pca.basis", vec![o3, k]);
            t.insert("wrinkle.pca.mean", vec![o3]);
        }
        if self.linear_baseline {
            t.insert("lr.weight", vec![o3, i]);
            t.insert("lr.bias", vec![o3]);
        }
        t
    }
}

/// The contents of `model.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelHeader {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// Always [`MODEL_VERSION`].
    pub version: u32,
    /// The garment the model animates.
    pub garment: AssetId,
    /// The body model it was trained on.
    pub body: AssetId,
    /// Network sizes.
    pub sizes: ModelSizes,
    /// Layout of the wrinkle input vector.
    pub wrinkle_inputs: Vec<FeatureBlock>,
    /// SHA-256 of `model.safetensors`; [`GarmentModel::save`] fills it in.
    pub tensors_sha256: String,
    /// The β of the training shapes (`None` in models exported before the field existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training_betas: Option<TrainingBetas>,
}

/// The body shapes a model was trained on (`model.json`'s `training_betas`): the networks are
/// trained on the convex hull of these β at best.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct TrainingBetas(pub Vec<Vec<f32>>);

/// Iterations of the hull projection (Frank–Wolfe; a few hundred reach 1e-6 on a few dozen
/// shapes).
const HULL_ITERATIONS: usize = 2000;
/// A β within this distance of the hull counts as inside it (and is left as it is).
const HULL_TOLERANCE: f64 = 1e-4;
/// The most β components [`TrainingBetas::project`] handles (on the stack).
const MAX_BETAS: usize = 32;

impl TrainingBetas {
    /// The point of the training shapes' convex hull nearest `betas` (`betas` itself when it
    /// lies in the hull, within 1e-4), into `out` (same length). Frank–Wolfe with exact line
    /// search from the nearest training shape, in f64: deterministic, no allocation.
    pub fn project(&self, betas: &[f32], out: &mut [f32]) {
        out.copy_from_slice(betas);
        let n = betas.len();
        let mut x = [0.0f64; MAX_BETAS];
        if n > MAX_BETAS || self.0.iter().any(|s| s.len() != n) {
            return;
        }
        let b = |k: usize| f64::from(betas[k]);
        let dist2 = |s: &[f32]| {
            (0..n)
                .map(|k| (f64::from(s[k]) - b(k)).powi(2))
                .sum::<f64>()
        };
        let Some(first) = self.0.iter().min_by(|p, q| dist2(p).total_cmp(&dist2(q))) else {
            return;
        };
        for k in 0..n {
            x[k] = f64::from(first[k]);
        }
        for _ in 0..HULL_ITERATIONS {
            // The training shape along which |x − β|² falls fastest, and the best step to it.
            let slope = |s: &[f32]| (0..n).map(|k| (x[k] - b(k)) * f64::from(s[k])).sum::<f64>();
            let Some(s) = self.0.iter().min_by(|p, q| slope(p).total_cmp(&slope(q))) else {
                break;
            };
            let (mut gd, mut dd) = (0.0, 0.0);
            for k in 0..n {
                let d = f64::from(s[k]) - x[k];
                gd += (x[k] - b(k)) * d;
                dd += d * d;
            }
            if gd >= 0.0 || dd == 0.0 {
                break;
            }
            let step = (-gd / dd).min(1.0);
            for k in 0..n {
                x[k] += step * (f64::from(s[k]) - x[k]);
            }
        }
        let d2: f64 = (0..n).map(|k| (x[k] - b(k)).powi(2)).sum();
        if d2.sqrt() > HULL_TOLERANCE {
            for k in 0..n {
                out[k] = x[k] as f32;
            }
        }
    }

    fn check(&self, n_betas: usize) -> std::result::Result<(), String> {
        if self.0.is_empty() {
            return Err("training_betas is empty".into());
        }
        if n_betas > MAX_BETAS {
            return Err(format!(
                "training_betas: at most {MAX_BETAS} betas are supported, the model has {n_betas}"
            ));
        }
        for (i, b) in self.0.iter().enumerate() {
            if b.len() != n_betas {
                return Err(format!(
                    "training_betas[{i}] has {} values, expected n_betas = {n_betas}",
                    b.len()
                ));
            }
            if !b.iter().all(|v| v.is_finite()) {
                return Err(format!("training_betas[{i}] is not finite"));
            }
        }
        Ok(())
    }
}

sartor_core::asset_header!(ModelHeader);

fn unique(what: &str, names: &[String]) -> std::result::Result<(), String> {
    let mut seen = BTreeSet::new();
    for n in names {
        if n.is_empty() {
            return Err(format!("{what}: empty name"));
        }
        if !seen.insert(n) {
            return Err(format!("{what}: duplicate name {n:?}"));
        }
    }
    Ok(())
}

impl ModelHeader {
    /// Check that `binding` is of the garment and body this model was trained for: same garment
    /// and body ids and hashes, same vertex count.
    pub fn check_binding(&self, binding: &GarmentBinding) -> Result<()> {
        let bad = |m: String| Err(Error::invalid("garment binding", m));
        if self.sizes.n_vertices != binding.n_vertices() {
            return bad(format!(
                "the model has {} garment vertices, the binding {}",
                self.sizes.n_vertices,
                binding.n_vertices()
            ));
        }
        let (g, b) = (binding.garment(), binding.body());
        if self.garment != *g {
            return bad(format!(
                "the model is for garment {:?} ({}), the binding for {:?} ({})",
                self.garment.id, self.garment.sha256, g.id, g.sha256
            ));
        }
        if self.body != *b {
            return bad(format!(
                "the model is for body {:?} ({}), the binding for {:?} ({})",
                self.body.id, self.body.sha256, b.id, b.sha256
            ));
        }
        Ok(())
    }

    /// A header with [`MODEL_FORMAT`], [`MODEL_VERSION`] and an empty hash.
    pub fn new(
        garment: AssetId,
        body: AssetId,
        sizes: ModelSizes,
        wrinkle_inputs: Vec<FeatureBlock>,
    ) -> Self {
        Self {
            format: MODEL_FORMAT.into(),
            version: MODEL_VERSION,
            garment,
            body,
            sizes,
            wrinkle_inputs,
            tensors_sha256: String::new(),
            training_betas: None,
        }
    }

    /// Check everything but the tensor hash: format, version, asset hashes, sizes and the
    /// input layout. The message names the field at fault.
    pub fn validate(&self) -> Result<()> {
        self.check().map_err(|m| Error::invalid("model header", m))
    }

    fn check(&self) -> std::result::Result<(), String> {
        if self.format != MODEL_FORMAT {
            return Err(format!(
                "format is {:?}, expected {MODEL_FORMAT:?}",
                self.format
            ));
        }
        if self.version != MODEL_VERSION {
            return Err(format!(
                "version is {}, expected {MODEL_VERSION}",
                self.version
            ));
        }
        for (field, asset) in [("garment", &self.garment), ("body", &self.body)] {
            asset.check(field)?;
        }
        let s = &self.sizes;
        for (field, v) in [
            ("n_vertices", s.n_vertices),
            ("n_betas", s.n_betas),
            ("fit_hidden", s.fit_hidden),
            ("gru_hidden", s.gru_hidden),
        ] {
            if v == 0 {
                return Err(format!("sizes.{field} is 0"));
            }
        }
        if let OutputKind::Pca(k) = s.output
            && (k == 0 || k > s.n_outputs())
        {
            return Err(format!(
                "sizes.output: pca k = {k} must be in 1..={}",
                s.n_outputs()
            ));
        }
        let names: Vec<String> = self.wrinkle_inputs.iter().map(|b| b.name.clone()).collect();
        unique("wrinkle_inputs", &names)?;
        let mut next = 0;
        let mut betas_blocks = 0;
        for block in &self.wrinkle_inputs {
            let at = format!("wrinkle_inputs[{:?}]", block.name);
            if block.offset != next {
                return Err(format!(
                    "{at}: offset {} but the previous block ends at {next}",
                    block.offset
                ));
            }
            let width = match &block.feature {
                Feature::Betas => {
                    betas_blocks += 1;
                    s.n_betas
                }
                Feature::JointRotations { encoding, joints } => {
                    if joints.is_empty() {
                        return Err(format!("{at}: no joints"));
                    }
                    unique(&format!("{at}.joints"), joints)?;
                    joints.len() * encoding.width()
                }
                Feature::Root { components } => {
                    if components.is_empty() {
                        return Err(format!("{at}: no components"));
                    }
                    unique(&format!("{at}.components"), components)?;
                    components.len()
                }
            };
            if block.len != width {
                return Err(format!(
                    "{at}: len {} but its feature has {width} values",
                    block.len
                ));
            }
            next += block.len;
        }
        if betas_blocks != 1 {
            return Err(format!(
                "wrinkle_inputs: {betas_blocks} \"betas\" blocks, expected exactly 1"
            ));
        }
        if next != s.wrinkle_inputs() {
            return Err(format!(
                "wrinkle_inputs cover {next} values, expected n_betas + n_pose_features = {}",
                s.wrinkle_inputs()
            ));
        }
        if let Some(shapes) = &self.training_betas {
            shapes.check(s.n_betas)?;
        }
        Ok(())
    }
}

/// `y = W x + b` weights: `weight` row-major `[rows, cols]`, `bias` `[rows]`.
#[derive(Clone, Debug, PartialEq)]
pub struct DenseWeights {
    /// Row-major weights.
    pub weight: Vec<f32>,
    /// Bias.
    pub bias: Vec<f32>,
}

/// GRU parameters in PyTorch's layout (gates `r, z, n` stacked).
#[derive(Clone, Debug, PartialEq)]
pub struct GruWeights {
    /// `[3H, I]`.
    pub weight_ih: Vec<f32>,
    /// `[3H, H]`.
    pub weight_hh: Vec<f32>,
    /// `[3H]`.
    pub bias_ih: Vec<f32>,
    /// `[3H]`.
    pub bias_hh: Vec<f32>,
}

/// PCA output basis.
#[derive(Clone, Debug, PartialEq)]
pub struct PcaWeights {
    /// `[3V, k]`.
    pub basis: Vec<f32>,
    /// `[3V]`.
    pub mean: Vec<f32>,
}

/// Every tensor of a model, in f32.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelWeights {
    /// `fit.hidden.*`.
    pub fit_hidden: DenseWeights,
    /// `fit.out.*`.
    pub fit_out: DenseWeights,
    /// `wrinkle.gru.*`.
    pub gru: GruWeights,
    /// `wrinkle.out.*`.
    pub wrinkle_out: DenseWeights,
    /// `wrinkle.pca.*` (PCA output only).
    pub pca: Option<PcaWeights>,
    /// `lr.*` (linear baseline only).
    pub lr: Option<DenseWeights>,
    /// `norm.*`.
    pub norm: NormStats,
}

impl ModelWeights {
    /// The tensor stored under `name`, if this model has it.
    pub fn tensor(&self, name: &str) -> Option<&[f32]> {
        let n = &self.norm;
        Some(match name {
            "fit.hidden.weight" => &self.fit_hidden.weight,
            "fit.hidden.bias" => &self.fit_hidden.bias,
            "fit.out.weight" => &self.fit_out.weight,
            "fit.out.bias" => &self.fit_out.bias,
            "wrinkle.gru.weight_ih" => &self.gru.weight_ih,
            "wrinkle.gru.weight_hh" => &self.gru.weight_hh,
            "wrinkle.gru.bias_ih" => &self.gru.bias_ih,
            "wrinkle.gru.bias_hh" => &self.gru.bias_hh,
            "wrinkle.out.weight" => &self.wrinkle_out.weight,
            "wrinkle.out.bias" => &self.wrinkle_out.bias,
            "wrinkle.pca.basis" => &self.pca.as_ref()?.basis,
            "wrinkle.pca.mean" => &self.pca.as_ref()?.mean,
            "lr.weight" => &self.lr.as_ref()?.weight,
            "lr.bias" => &self.lr.as_ref()?.bias,
            "norm.fit_in_mean" => &n.fit_in.mean,
            "norm.fit_in_std" => &n.fit_in.std,
            "norm.wrinkle_in_mean" => &n.wrinkle_in.mean,
            "norm.wrinkle_in_std" => &n.wrinkle_in.std,
            "norm.fit_out_mean" => &n.fit_out.mean,
            "norm.fit_out_std" => &n.fit_out.std,
            "norm.wrinkle_out_mean" => &n.wrinkle_out.mean,
            "norm.wrinkle_out_std" => &n.wrinkle_out.std,
            _ => return None,
        })
    }

    /// Build from a map of named tensors holding the names of `sizes` (a missing one comes
    /// out empty and fails [`GarmentModel::new`]).
    fn from_map(sizes: &ModelSizes, mut t: BTreeMap<String, Vec<f32>>) -> Self {
        let mut take = |name: &str| t.remove(name).unwrap_or_default();
        let fit_hidden = DenseWeights {
            weight: take("fit.hidden.weight"),
            bias: take("fit.hidden.bias"),
        };
        let fit_out = DenseWeights {
            weight: take("fit.out.weight"),
            bias: take("fit.out.bias"),
        };
        let gru = GruWeights {
            weight_ih: take("wrinkle.gru.weight_ih"),
            weight_hh: take("wrinkle.gru.weight_hh"),
            bias_ih: take("wrinkle.gru.bias_ih"),
            bias_hh: take("wrinkle.gru.bias_hh"),
        };
        let wrinkle_out = DenseWeights {
            weight: take("wrinkle.out.weight"),
            bias: take("wrinkle.out.bias"),
        };
        let pca = matches!(sizes.output, OutputKind::Pca(_)).then(|| PcaWeights {
            basis: take("wrinkle.pca.basis"),
            mean: take("wrinkle.pca.mean"),
        });
        let lr = sizes.linear_baseline.then(|| DenseWeights {
            weight: take("lr.weight"),
            bias: take("lr.bias"),
        });
        let mut ms = |m: &str, s: &str| MeanStd {
            mean: take(m),
            std: take(s),
        };
        let norm = NormStats {
            fit_in: ms("norm.fit_in_mean", "norm.fit_in_std"),
            wrinkle_in: ms("norm.wrinkle_in_mean", "norm.wrinkle_in_std"),
            fit_out: ms("norm.fit_out_mean", "norm.fit_out_std"),
            wrinkle_out: ms("norm.wrinkle_out_mean", "norm.wrinkle_out_std"),
        };
        Self {
            fit_hidden,
            fit_out,
            gru,
            wrinkle_out,
            pca,
            lr,
            norm,
        }
    }
}

/// How [`GarmentModel::save_as`] stores the tensors. Readers take either.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TensorStorage {
    /// Every tensor in f32 (what the exporter writes).
    #[default]
    F32,
    /// The weight matrices (every 2-D tensor) in f16, rounded to nearest; vectors (biases,
    /// normalisation) in f32. Half the bytes, for a model sent over the network to a web page.
    /// The loaded model holds the rounded values: loading it at [`crate::Precision::F16`] gives
    /// the same network as loading the f32 file at that precision.
    F16,
}

/// A validated model: header and f32 tensors whose shapes agree with it, all finite, every
/// `std` positive.
#[derive(Clone, Debug, PartialEq)]
pub struct GarmentModel {
    header: ModelHeader,
    weights: ModelWeights,
}

impl GarmentModel {
    /// Validate `header` (not its hash) and `weights` against it.
    pub fn new(header: ModelHeader, weights: ModelWeights) -> Result<Self> {
        header.validate()?;
        let sizes = header.sizes;
        if weights.pca.is_some() != matches!(sizes.output, OutputKind::Pca(_)) {
            return Err(Error::invalid(
                "model weights",
                "PCA tensors present iff sizes.output is pca",
            ));
        }
        if weights.lr.is_some() != sizes.linear_baseline {
            return Err(Error::invalid(
                "model weights",
                "lr tensors present iff sizes.linear_baseline",
            ));
        }
        for (name, shape) in sizes.tensor_shapes() {
            let t = weights
                .tensor(name)
                .ok_or_else(|| Error::invalid("model weights", format!("missing {name:?}")))?;
            let n: usize = shape.iter().product();
            if t.len() != n {
                return Err(Error::invalid(
                    "model weights",
                    format!("{name:?} has {} values, expected {shape:?} = {n}", t.len()),
                ));
            }
            if let Some(i) = t.iter().position(|v| !v.is_finite()) {
                return Err(Error::invalid(
                    "model weights",
                    format!("{name:?} has a non-finite value at {i}"),
                ));
            }
            if name.ends_with("_std")
                && let Some(i) = t.iter().position(|&v| v <= 0.0)
            {
                return Err(Error::invalid(
                    "model weights",
                    format!("{name:?} has a non-positive value {} at {i}", t[i]),
                ));
            }
        }
        Ok(Self { header, weights })
    }

    /// The header.
    pub fn header(&self) -> &ModelHeader {
        &self.header
    }

    /// The tensors.
    pub fn weights(&self) -> &ModelWeights {
        &self.weights
    }

    /// Split into header and tensors.
    pub fn into_parts(self) -> (ModelHeader, ModelWeights) {
        (self.header, self.weights)
    }

    /// The safetensors bytes of this model (names sorted, no metadata; deterministic), every
    /// tensor in f32.
    pub fn tensor_bytes(&self) -> Result<Vec<u8>> {
        self.tensor_bytes_as(TensorStorage::F32)
    }

    /// The safetensors bytes of this model with the given storage. [`TensorStorage::F16`]
    /// fails, naming the tensor, when a weight does not fit in half precision (beyond ±65504).
    pub fn tensor_bytes_as(&self, storage: TensorStorage) -> Result<Vec<u8>> {
        let mut map = BTreeMap::new();
        for (name, shape) in self.header.sizes.tensor_shapes() {
            let t = self
                .weights
                .tensor(name)
                .expect("GarmentModel::new checked that every tensor is present");
            let tensor = if storage == TensorStorage::F16 && shape.len() == 2 {
                let bits: Vec<u16> = t
                    .iter()
                    .map(|&v| half::f16::from_f32(v).to_bits())
                    .collect();
                if let Some(i) = bits.iter().position(|&b| b & 0x7c00 == 0x7c00) {
                    return Err(Error::invalid(
                        "model weights",
                        format!("{name:?} value {} at {i} does not fit in f16", t[i]),
                    ));
                }
                OwnedTensor::f16_bits(&shape, bits)
            } else {
                OwnedTensor::f32(&shape, t.iter().copied())
            };
            map.insert(name.to_string(), tensor);
        }
        Ok(serialize_tensors(&map, None)?)
    }

    /// Write `dir/model.safetensors` and `dir/model.json` (with the tensors' SHA-256), each
    /// atomically. Returns the header as written.
    pub fn save(&self, dir: &Path) -> Result<ModelHeader> {
        self.save_as(dir, TensorStorage::F32)
    }

    /// [`Self::save`] with the given tensor storage (see [`TensorStorage`]).
    pub fn save_as(&self, dir: &Path, storage: TensorStorage) -> Result<ModelHeader> {
        let bytes = self.tensor_bytes_as(storage)?;
        let mut header = self.header.clone();
        header.tensors_sha256 = sha256_hex(&bytes);
        FILES.write(dir, &header, &bytes)?;
        Ok(header)
    }

    /// Read and validate `dir/model.json` and `dir/model.safetensors`: JSON fields, sizes and
    /// layout, the tensors' hash, the exact set of tensor names, every dtype and shape,
    /// finiteness and positive standard deviations. Errors name the file and the fault.
    pub fn load(dir: &Path) -> Result<Self> {
        let header = read_file(&dir.join(MODEL_JSON))?;
        let tensors = read_file(&dir.join(MODEL_TENSORS))?;
        Self::from_bytes(dir, &header, tensors)
    }

    /// [`Self::load`] from the two files' bytes, read from folder `dir` (named in errors
    /// only): how a web page, which has no file system, loads the model it fetched.
    pub fn from_bytes(dir: &Path, header_bytes: &[u8], tensor_bytes: Vec<u8>) -> Result<Self> {
        let (header, file): (ModelHeader, _) = FILES.parse(dir, header_bytes, tensor_bytes)?;
        let (json_path, path) = (dir.join(MODEL_JSON), dir.join(MODEL_TENSORS));
        header.validate().map_err(|e| e.in_file(&json_path))?;
        let shapes = header.sizes.tensor_shapes();
        for name in file.names() {
            if !shapes.contains_key(name.as_str()) {
                return Err(Error::format(&path, format!("unexpected tensor {name:?}")));
            }
        }
        let mut tensors = BTreeMap::new();
        for (name, shape) in &shapes {
            let want: Vec<Option<usize>> = shape.iter().map(|&d| Some(d)).collect();
            let (_, values) = file.f32_or_f16(name, &want)?;
            tensors.insert(name.to_string(), values);
        }
        let weights = ModelWeights::from_map(&header.sizes, tensors);
        Self::new(header, weights).map_err(|e| e.in_file(&path))
    }
}
