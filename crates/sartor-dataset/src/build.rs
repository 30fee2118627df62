//! Building a dataset folder from simulations: bind the garment, extract `Δ_G` per shape and
//! `Δ_L` + network inputs per sequence (in parallel, resumably), then statistics, PCA, the
//! manifest and the report.
//!
//! The simulations are read through [`SimulationSource`], so this crate does not depend on the
//! simulator's file format (the command line adapts sartor-cloth's sequence files to it).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use sartor_core::io::{read_file, sha256_hex};
use sartor_core::{
    BINDING_JSON, BodyModel, FPS, Pose, PoseFeatureSpec, RootFeature, RotationEncoding,
};

use crate::extract::{WrinkleExtractor, bind_garment, fit_delta, select_joints};
use crate::smoothing::{Smoother, Smoothing};
use crate::stats::{PcaSettings, compute_pca, compute_stats};
use crate::store::{
    BINDING_FILE, Manifest, SHAPES_FILE, STATS_FILE, SequenceEntry, ShapeEntry, sequence_file,
    write_manifest, write_sequence, write_shapes, write_stats,
};
use crate::{
    DATASET_FORMAT, DATASET_VERSION, DataSource, Error, InputLayout, Result, SequenceSample,
    ShapeSample, Split,
};

/// The report's file name.
pub const REPORT_FILE: &str = "dataset.json";

/// The dataset section of an experiment config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DatasetConfig {
    /// ρ.
    pub smoothing: Smoothing,
    /// A joint enters the pose features if it carries at least this cloth skin weight on some
    /// garment vertex (its ancestors enter too; see [`select_joints`]). Default 0.1.
    pub joint_min_weight: f32,
    /// Rotation encoding of the pose features (default rot6d).
    pub encoding: RotationEncoding,
    /// Root features (default: velocity in the heading frame and yaw rate).
    pub root_features: Vec<RootFeature>,
    /// PCA of `Δ_L` (`None`: no basis).
    pub pca: Option<PcaSettings>,
}

impl Default for DatasetConfig {
    fn default() -> Self {
        Self {
            smoothing: Smoothing::default(),
            joint_min_weight: 0.1,
            encoding: RotationEncoding::Rot6d,
            root_features: RootFeature::ALL.to_vec(),
            pca: Some(PcaSettings {
                components: 128,
                max_frames: 6000,
                seed: 2019,
            }),
        }
    }
}

/// One shape of the plan.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapePlan {
    /// Identifier.
    pub id: String,
    /// β.
    pub betas: Vec<f64>,
    /// [`Split::Train`], [`Split::HeldOutShapes`] or [`Split::Validation`].
    pub split: Split,
}

/// One sequence of the plan.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequencePlan {
    /// Index into the shapes.
    pub shape: usize,
    /// Motion name.
    pub motion: String,
    /// Split: a training shape's sequences are [`Split::Train`], [`Split::HeldOutMotions`] or
    /// [`Split::Validation`]; a held-out shape's are [`Split::HeldOutShapes`]; a validation shape
    /// has none (only its rest simulation).
    pub split: Split,
}

impl SequencePlan {
    /// The sequence's identifier: `<shape>__<motion>`.
    pub fn id(&self, shapes: &[ShapePlan]) -> String {
        format!("{}__{}", shapes[self.shape].id, self.motion)
    }
}

/// What to build: shapes and sequences with their splits.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetPlan {
    /// Shapes.
    pub shapes: Vec<ShapePlan>,
    /// Sequences.
    pub sequences: Vec<SequencePlan>,
}

impl DatasetPlan {
    /// Check indices, unique ids and the split rules (training, held-out-motion and validation
    /// sequences on training shapes only, held-out-shape sequences on held-out shapes only).
    pub fn validate(&self, n_betas: usize) -> Result<()> {
        let bad = |m: String| Err(Error::invalid("dataset plan", m));
        let mut ids = std::collections::BTreeSet::new();
        for s in &self.shapes {
            if !ids.insert(&s.id) {
                return bad(format!("shape id {} is used twice", s.id));
            }
            if s.betas.len() > n_betas || !s.betas.iter().all(|b| b.is_finite()) {
                return bad(format!(
                    "shape {}: {} betas (the body has {n_betas}) or a non-finite value",
                    s.id,
                    s.betas.len()
                ));
            }
            if s.split == Split::HeldOutMotions {
                return bad(format!(
                    "shape {} cannot be in the held-out-motions split",
                    s.id
                ));
            }
        }
        let mut seen = std::collections::BTreeSet::new();
        for q in &self.sequences {
            let Some(shape) = self.shapes.get(q.shape) else {
                return bad(format!(
                    "a sequence refers to shape {} of {}",
                    q.shape,
                    self.shapes.len()
                ));
            };
            if !seen.insert((q.shape, &q.motion)) {
                return bad(format!("sequence {} is listed twice", q.id(&self.shapes)));
            }
            let fits = match q.split {
                Split::Train | Split::HeldOutMotions | Split::Validation => {
                    shape.split == Split::Train
                }
                Split::HeldOutShapes => shape.split == Split::HeldOutShapes,
            };
            if !fits {
                return bad(format!(
                    "sequence {} is in split {:?} but its shape is in {:?}",
                    q.id(&self.shapes),
                    q.split,
                    shape.split
                ));
            }
        }
        if !self.sequences.iter().any(|q| q.split == Split::Train) {
            return bad("no training sequence".into());
        }
        Ok(())
    }
}

/// One simulated motion, motion frames only.
#[derive(Clone, Debug)]
pub struct SimulatedMotion {
    /// β it was simulated with.
    pub betas: Vec<f64>,
    /// The pose one frame before the first motion frame (the end of the settling), for the
    /// velocities of the first frame.
    pub previous_pose: Pose,
    /// Poses of the motion frames.
    pub poses: Vec<Pose>,
    /// Cloth vertices of the motion frames.
    pub cloth: Vec<Vec<Vector3<f64>>>,
}

/// Where the simulations come from.
pub trait SimulationSource: Sync {
    /// The cloth simulated on shape `shape` in the rest pose (its final, settled frame).
    fn rest(&self, shape: &ShapePlan) -> Result<Vec<Vector3<f64>>>;
    /// The motion `motion` simulated on shape `shape`.
    fn motion(&self, shape: &ShapePlan, motion: &str) -> Result<SimulatedMotion>;
}

/// Magnitudes of a displacement field, mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MagnitudeMm {
    /// Mean per-vertex displacement length.
    pub mean_mm: f64,
    /// 99th percentile of the per-vertex length.
    pub p99_mm: f64,
    /// Largest per-vertex length.
    pub max_mm: f64,
}

/// `dataset.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetReport {
    /// Garment vertices.
    pub n_vertices: usize,
    /// Wrinkle-network inputs per frame.
    pub n_inputs: usize,
    /// Joints in the pose features.
    pub joints: Vec<String>,
    /// Mean edge length of the template, mm, and ρ's iterations.
    pub mean_edge_mm: f64,
    /// ρ iterations.
    pub smoothing_iterations: usize,
    /// How far ρ moved the relaxed garment to make `T̄_c`.
    pub smoothing_change: MagnitudeMm,
    /// Shapes per split.
    pub shapes_per_split: BTreeMap<String, usize>,
    /// Sequences per split.
    pub sequences_per_split: BTreeMap<String, usize>,
    /// Frames per split.
    pub frames_per_split: BTreeMap<String, usize>,
    /// `Δ_G` over all shapes.
    pub fit_delta: MagnitudeMm,
    /// `Δ_L` per split.
    pub wrinkle_delta: BTreeMap<String, MagnitudeMm>,
    /// Cumulative explained variance of the PCA basis at 8, 16, 32, 64, … components.
    pub pca_cumulative_variance: BTreeMap<String, f64>,
    /// Components of the basis.
    pub pca_components: usize,
    /// Wall time, s.
    pub wall_secs: f64,
}

fn split_name(s: Split) -> String {
    match s {
        Split::Train => "train",
        Split::HeldOutMotions => "held_out_motions",
        Split::HeldOutShapes => "held_out_shapes",
        Split::Validation => "validation",
    }
    .to_string()
}

fn magnitudes<'a>(fields: impl Iterator<Item = &'a [f32]>) -> MagnitudeMm {
    let mut lengths: Vec<f64> = fields
        .flat_map(|f| {
            f.chunks_exact(3)
                .map(|c| ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) as f64).sqrt() * 1e3)
        })
        .collect();
    if lengths.is_empty() {
        return MagnitudeMm::default();
    }
    lengths.sort_by(f64::total_cmp);
    let n = lengths.len();
    MagnitudeMm {
        mean_mm: lengths.iter().sum::<f64>() / n as f64,
        p99_mm: lengths[((n - 1) as f64 * 0.99) as usize],
        max_mm: lengths[n - 1],
    }
}

/// Inputs `[T, I]` of a motion: β then the pose features.
fn motion_inputs(
    features: &sartor_core::PoseFeatures,
    betas: &[f32],
    motion: &SimulatedMotion,
) -> Result<Vec<f32>> {
    let (nb, nf) = (betas.len(), features.width());
    let mut inputs = vec![0.0f32; motion.poses.len() * (nb + nf)];
    for (t, row) in inputs.chunks_exact_mut(nb + nf).enumerate() {
        row[..nb].copy_from_slice(betas);
        let prev = if t == 0 {
            &motion.previous_pose
        } else {
            &motion.poses[t - 1]
        };
        features.compute(Some(prev), &motion.poses[t], 1.0 / FPS, &mut row[nb..])?;
    }
    Ok(inputs)
}

/// Everything `build_dataset` needs besides the simulations.
pub struct DatasetInputs<'a> {
    /// The body model the simulations used.
    pub body: &'a BodyModel,
    /// The garment relaxed on the template body (its template positions) and its faces.
    pub relaxed: &'a [Vector3<f64>],
    /// Garment faces.
    pub faces: &'a [[u32; 3]],
    /// Garment and body identity.
    pub source: DataSource,
    /// SHA-256 of the config parts the dataset depends on (a rebuild with another config
    /// starts over).
    pub config_sha256: String,
}

/// Build (or finish building) a dataset in `out_dir`. Per-sequence files already present with
/// the same config hash are kept (resume). `progress(done, total)` is called as sequences
/// finish. Returns the report (also written as `dataset.json`).
pub fn build_dataset(
    inputs: &DatasetInputs<'_>,
    plan: &DatasetPlan,
    config: &DatasetConfig,
    simulations: &dyn SimulationSource,
    out_dir: &Path,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<DatasetReport> {
    let start = Instant::now();
    let body = inputs.body;
    plan.validate(body.n_betas())?;
    let n_betas = body.n_betas();
    let smoother = Smoother::new(inputs.relaxed, inputs.faces, config.smoothing)?;
    let binding = bind_garment(
        body,
        &inputs.source,
        inputs.relaxed,
        inputs.faces,
        &smoother,
    )?;
    let n = binding.n_vertices();
    let joints = select_joints(body, binding.skin_weights(), config.joint_min_weight);
    let spec = PoseFeatureSpec {
        joints: joints.clone(),
        encoding: config.encoding,
        root: config.root_features.clone(),
    };
    let features = spec.bind(body.skeleton())?;
    let layout = InputLayout {
        n_betas,
        pose: spec,
    };
    let (n_in, n3) = (layout.width(), 3 * n);
    // A resume is only valid for the same config: remember it in a stamp file.
    let stamp_path = out_dir.join(".config_sha256");
    let same_config = read_file(&stamp_path)
        .map(|b| b == inputs.config_sha256.as_bytes())
        .unwrap_or(false);
    if !same_config {
        let seq_dir = out_dir.join(crate::SEQUENCES_DIR);
        if seq_dir.exists() {
            std::fs::remove_dir_all(&seq_dir).map_err(|e| Error::io(&seq_dir, e))?;
        }
        sartor_core::io::write_atomic(&stamp_path, inputs.config_sha256.as_bytes())?;
    }
    let _ = std::fs::remove_file(out_dir.join(crate::MANIFEST_FILE));

    let mut files = BTreeMap::new();
    let header = binding.save(out_dir)?;
    files.insert(BINDING_FILE.to_string(), header.tensors_sha256);
    files.insert(
        BINDING_JSON.to_string(),
        sha256_hex(&read_file(&out_dir.join(BINDING_JSON))?),
    );

    // Δ_G per shape (in parallel).
    let pad = |b: &[f64]| {
        let mut v = vec![0.0f64; n_betas];
        v[..b.len()].copy_from_slice(b);
        v
    };
    let shapes: Vec<ShapeSample> = plan
        .shapes
        .par_iter()
        .map(|s| {
            let rest = simulations.rest(s)?;
            let delta = fit_delta(&binding, &smoother, &rest)?;
            Ok(ShapeSample {
                id: s.id.clone(),
                betas: pad(&s.betas).iter().map(|&b| b as f32).collect(),
                fit_delta: delta,
                split: s.split,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    files.insert(
        SHAPES_FILE.to_string(),
        write_shapes(out_dir, &shapes, n_betas, n3)?,
    );

    // Δ_L and inputs per sequence (in parallel; existing files are kept).
    let total = plan.sequences.len();
    let done = Mutex::new(0usize);
    let sequences: Vec<(SequenceSample, String)> = plan
        .sequences
        .par_iter()
        .map(|q| {
            let id = q.id(&plan.shapes);
            let path = out_dir.join(sequence_file(&id));
            let shape = &plan.shapes[q.shape];
            let sample = if path.exists() {
                let file = sartor_core::io::TensorFile::open(&path)?;
                let (shape_dims, inputs) = file.f32("inputs", &[None, Some(n_in)])?;
                let (_, delta) = file.f32("wrinkle_delta", &[Some(shape_dims[0]), Some(n3)])?;
                SequenceSample {
                    id: id.clone(),
                    shape: q.shape,
                    motion: q.motion.clone(),
                    split: q.split,
                    n_frames: shape_dims[0],
                    inputs,
                    wrinkle_delta: delta,
                }
            } else {
                let motion = simulations.motion(shape, &q.motion)?;
                if motion.poses.len() != motion.cloth.len() || motion.poses.is_empty() {
                    return Err(Error::invalid(
                        "simulated motion",
                        format!(
                            "{id}: {} poses and {} cloth frames",
                            motion.poses.len(),
                            motion.cloth.len()
                        ),
                    ));
                }
                let betas = pad(&shape.betas);
                if motion.betas.len() > n_betas
                    || motion
                        .betas
                        .iter()
                        .zip(&betas)
                        .any(|(a, b)| (a - b).abs() > 1e-6)
                {
                    return Err(Error::invalid(
                        "simulated motion",
                        format!(
                            "{id} was simulated with β {:?}, the plan says {:?}",
                            motion.betas, shape.betas
                        ),
                    ));
                }
                let betas32: Vec<f32> = betas.iter().map(|&b| b as f32).collect();
                let fit = &shapes[q.shape].fit_delta;
                let mut extractor = WrinkleExtractor::new(body, &binding, &betas, fit)?;
                let mut delta = Vec::with_capacity(motion.poses.len() * n3);
                for (pose, cloth) in motion.poses.iter().zip(&motion.cloth) {
                    extractor.push_frame(pose, cloth, &mut delta)?;
                }
                SequenceSample {
                    id: id.clone(),
                    shape: q.shape,
                    motion: q.motion.clone(),
                    split: q.split,
                    n_frames: motion.poses.len(),
                    inputs: motion_inputs(&features, &betas32, &motion)?,
                    wrinkle_delta: delta,
                }
            };
            let hash = if path.exists() {
                sha256_hex(&read_file(&path)?)
            } else {
                write_sequence(out_dir, &sample, n_in, n3)?
            };
            let mut d = done
                .lock()
                .map_err(|_| Error::invalid("progress", "poisoned lock"))?;
            *d += 1;
            progress(*d, total);
            Ok((sample, hash))
        })
        .collect::<Result<Vec<_>>>()?;
    for (s, hash) in &sequences {
        files.insert(sequence_file(&s.id), hash.clone());
    }
    let sequences: Vec<SequenceSample> = sequences.into_iter().map(|(s, _)| s).collect();

    // Statistics and PCA from the training split only.
    let train_shapes: Vec<&ShapeSample> =
        shapes.iter().filter(|s| s.split == Split::Train).collect();
    let train_seqs: Vec<&SequenceSample> = sequences
        .iter()
        .filter(|s| s.split == Split::Train)
        .collect();
    let stats = compute_stats(&train_shapes, &train_seqs, n_betas, n_in, n3)?;
    let pca = match &config.pca {
        Some(settings) => Some(compute_pca(&train_seqs, &stats, settings)?),
        None => None,
    };
    files.insert(
        STATS_FILE.to_string(),
        write_stats(out_dir, &stats, pca.as_ref())?,
    );

    let manifest = Manifest {
        format: DATASET_FORMAT.into(),
        version: DATASET_VERSION,
        source: inputs.source.clone(),
        config_sha256: inputs.config_sha256.clone(),
        n_vertices: n,
        layout: layout.clone(),
        smoothing: config.smoothing,
        shapes: shapes
            .iter()
            .map(|s| ShapeEntry {
                id: s.id.clone(),
                split: s.split,
            })
            .collect(),
        sequences: sequences
            .iter()
            .map(|s| SequenceEntry {
                id: s.id.clone(),
                shape: s.shape,
                motion: s.motion.clone(),
                split: s.split,
                n_frames: s.n_frames,
            })
            .collect(),
        files,
    };

    let mut report = DatasetReport {
        n_vertices: n,
        n_inputs: n_in,
        joints,
        mean_edge_mm: smoother.mean_edge_m() * 1e3,
        smoothing_iterations: smoother.iterations(),
        smoothing_change: magnitudes(std::iter::once(
            inputs
                .relaxed
                .iter()
                .zip(binding.template())
                .flat_map(|(r, t)| {
                    let d = r - t.cast::<f64>();
                    [d.x as f32, d.y as f32, d.z as f32]
                })
                .collect::<Vec<f32>>()
                .as_slice(),
        )),
        shapes_per_split: BTreeMap::new(),
        sequences_per_split: BTreeMap::new(),
        frames_per_split: BTreeMap::new(),
        fit_delta: magnitudes(shapes.iter().map(|s| s.fit_delta.as_slice())),
        wrinkle_delta: BTreeMap::new(),
        pca_cumulative_variance: BTreeMap::new(),
        pca_components: pca.as_ref().map_or(0, |p| p.n_components()),
        wall_secs: 0.0,
    };
    for s in &shapes {
        *report
            .shapes_per_split
            .entry(split_name(s.split))
            .or_default() += 1;
    }
    for split in [
        Split::Train,
        Split::Validation,
        Split::HeldOutMotions,
        Split::HeldOutShapes,
    ] {
        let qs: Vec<&SequenceSample> = sequences.iter().filter(|q| q.split == split).collect();
        if qs.is_empty() {
            continue;
        }
        report
            .sequences_per_split
            .insert(split_name(split), qs.len());
        report
            .frames_per_split
            .insert(split_name(split), qs.iter().map(|q| q.n_frames).sum());
        report.wrinkle_delta.insert(
            split_name(split),
            magnitudes(qs.iter().map(|q| q.wrinkle_delta.as_slice())),
        );
    }
    if let Some(p) = &pca {
        let mut k = 8;
        while k <= p.n_components() {
            let c: f64 = p.explained_variance_ratio[..k].iter().sum();
            report.pca_cumulative_variance.insert(k.to_string(), c);
            k *= 2;
        }
        let all: f64 = p.explained_variance_ratio.iter().sum();
        report
            .pca_cumulative_variance
            .insert(p.n_components().to_string(), all);
    }
    report.wall_secs = start.elapsed().as_secs_f64();
    let json = serde_json::to_vec_pretty(&report)
        .map_err(|e| Error::format(out_dir.join(REPORT_FILE), format!("cannot serialise: {e}")))?;
    sartor_core::io::write_atomic(&out_dir.join(REPORT_FILE), &json)?;
    // Last: the manifest marks the folder complete.
    write_manifest(out_dir, &manifest)?;
    Ok(report)
}
