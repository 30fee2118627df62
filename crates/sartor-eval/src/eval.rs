//! Judge an exported model against the simulator's held-out ground truth, next to the
//! baselines ([`evaluate_run`], behind `sartor eval`): `eval.json`, error plots and a rendered
//! comparison.
//!
//! # Methods (all through `sartor_runtime`, each with and without the collision post-process)
//!
//! | name | shaped garment ([`FitMode`]) | wrinkles ([`WrinkleMode`]) |
//! | --- | --- | --- |
//! | `ours` | fit MLP `T̄_c + R_G(β)` | wrinkle GRU `R_L(β, θ)` |
//! | `ours_strain_limit` | as `ours`; then no edge beyond 1.5× its rest length | as `ours` |
//! | `lr` | fit MLP | the linear baseline (one linear layer of the GRU's inputs) |
//! | `lbs` | the template `T̄_c` | none: the template skinned to the shaped, posed body |
//! | `retarget` | `T̄_c` moved with its closest template-body point's shape displacement | none |
//!
//! `ours_strain_limit` is `ours` with the runtime's strain limit
//! ([`sartor_runtime::StrainLimit`]) between the skinning and the post-process.
//!
//! # Test sets
//!
//! - `held_out_motions`: every held-out clip on every training shape (`--nominal-only`: on the
//!   training shape closest to β = 0 only, as the paper did); methods `ours`,
//!   `ours_strain_limit`, `lbs`, `lr`.
//! - `held_out_shapes`: every held-out shape with the config's `held_out_shapes` clips; methods
//!   `ours`, `ours_strain_limit`, `retarget`, `lbs`.
//!
//! # Metrics, per method
//!
//! - `mean_vertex_error_mm`: mean over frames and vertices of `|x − x_gt|` after the
//!   post-process (the runtime's default output); `mean_vertex_error_mm_before_pp` without it.
//! - `collision_percent_before_pp`, `collision_percent_after_pp`: the share of cloth vertices
//!   inside the posed body by the one collision measure ([`crate::PosedBody`]: the whole body,
//!   inside by its winding number; not the post-process's region, whose pseudo-normal sign is
//!   wrong behind its cut edges and where parts press together), over all frames.
//! - `ground_truth_collision_percent` and `ground_truth_signed_distance`: the same measure on
//!   the simulated cloth (share inside; percentiles, share below 0 and −1 mm).
//! - `edge_stretch` ([`StretchSummary`]): each garment edge's length over its length in the
//!   template, after the post-process, over edges × frames (quantiles, maximum, shares beyond
//!   1.5× and 2×); `edge_stretch_before_pp` without it; `ground_truth_edge_stretch`: the same
//!   of the simulated cloth, per test set and sequence, so that a model's stretch can be told
//!   from the physics', and on the training and validation sequences (`train`, `validation`),
//!   whence a strain limit may be taken without looking at the test.
//! - per sequence: the per-frame error curve (after the post-process), β and its distance to
//!   the nearest training shape, the edge stretch's 99th percentile and maximum.
//!
//! The frames are the motion frames of the simulation; each sequence starts from a zero GRU
//! state with the pose before its first frame as the previous pose, exactly as the dataset
//! built the training inputs.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{BodyModel, Pose};
use sartor_dataset::{
    DatasetPlan, REST_MOTION, ShapePlan, SimFolder, SimulatedMotion, SimulationSource, Split,
    failed_stems, sequence_stem,
};
use sartor_runtime::{
    AnimatorOptions, Camera, FitMode, GarmentAnimator, GarmentBinding, GarmentNetwork, GarmentRig,
    NetworkOptions, Panel, RenderMesh, StrainLimit, WrinkleMode, render_png,
};
use serde::Serialize;

use crate::error::{Context, ensure};
use crate::gt_distance::{DistanceHistogram, DistanceSummary, PosedBody};
use crate::plot::{Chart, Marker, Series, write_charts};
use crate::report::{Machine, write_json};
use crate::stretch::{GarmentEdges, StretchHistogram, StretchSummary};
use crate::timing::mean;
use crate::{Progress, Result};

/// A method: how the runtime shapes and wrinkles the garment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Fit MLP + wrinkle GRU.
    Ours,
    /// Fit MLP + wrinkle GRU, then the runtime's default strain limit before the
    /// post-process ([`sartor_runtime::StrainLimit`]: no edge beyond 1.5× its rest length).
    OursStrainLimit,
    /// The template skinned.
    Lbs,
    /// Fit MLP + linear wrinkles.
    Lr,
    /// The template moved with the body's shape change, skinned.
    Retarget,
}

impl Method {
    /// The report name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Ours => "ours",
            Self::OursStrainLimit => "ours_strain_limit",
            Self::Lbs => "lbs",
            Self::Lr => "lr",
            Self::Retarget => "retarget",
        }
    }

    /// The animator options of this method (post-process as given).
    pub fn options(self, base: AnimatorOptions) -> AnimatorOptions {
        let (fit, wrinkles) = match self {
            Self::Ours | Self::OursStrainLimit => (FitMode::Network, WrinkleMode::Gru),
            Self::Lbs => (FitMode::Template, WrinkleMode::None),
            Self::Lr => (FitMode::Network, WrinkleMode::Linear),
            Self::Retarget => (FitMode::Retarget, WrinkleMode::None),
        };
        let strain_limit = match self {
            Self::OursStrainLimit => Some(StrainLimit::default()),
            _ => base.strain_limit,
        };
        AnimatorOptions {
            fit,
            wrinkles,
            strain_limit,
            ..base
        }
    }
}

/// The loaded assets of an evaluation.
pub struct Assets {
    /// The body.
    pub body: Arc<BodyModel>,
    /// The binding.
    pub binding: Arc<GarmentBinding>,
    /// The exported model folder.
    pub model_dir: PathBuf,
}

impl Assets {
    /// Load the body model in `body_dir` and the binding of the model in `model_dir`.
    pub fn load(body_dir: &Path, model_dir: &Path) -> Result<Self> {
        let body = BodyModel::load(body_dir)
            .with_context(|| format!("loading the body model from {}", body_dir.display()))?;
        let binding = GarmentBinding::load(model_dir).with_context(|| {
            format!(
                "loading the garment binding from {} (run `sartor export` first)",
                model_dir.display()
            )
        })?;
        Ok(Self {
            body: Arc::new(body),
            binding: Arc::new(binding),
            model_dir: model_dir.to_path_buf(),
        })
    }

    /// A rig of `network` with `options`.
    pub fn rig(
        &self,
        network: &Arc<GarmentNetwork>,
        options: AnimatorOptions,
    ) -> Result<Arc<GarmentRig>> {
        Ok(Arc::new(GarmentRig::new(
            network.clone(),
            self.binding.clone(),
            self.body.clone(),
            options,
        )?))
    }

    /// The network loaded with `options`.
    pub fn network(&self, options: NetworkOptions) -> Result<Arc<GarmentNetwork>> {
        Ok(Arc::new(
            GarmentNetwork::load_with(&self.model_dir, options).with_context(|| {
                format!(
                    "loading the garment model from {}",
                    self.model_dir.display()
                )
            })?,
        ))
    }
}

/// One ground-truth sequence of a test set.
pub struct TestSequence {
    /// Shape id.
    pub shape: String,
    /// Motion name.
    pub motion: String,
    /// Distance of β to the nearest training shape.
    pub shape_distance: f64,
    /// The simulation.
    pub truth: SimulatedMotion,
}

/// Error and collisions of one method on one sequence.
#[derive(Clone, Debug, Default)]
pub struct SequenceMetrics {
    /// Mean vertex error per frame after the post-process, metres.
    pub per_frame_m: Vec<f64>,
    /// The same before the post-process.
    pub per_frame_before_pp_m: Vec<f64>,
    /// Vertices inside the body, summed over frames, before and after the post-process.
    pub inside_before: usize,
    /// See `inside_before`.
    pub inside_after: usize,
    /// Vertices × frames.
    pub vertex_frames: usize,
    /// Edge stretch after the post-process.
    pub stretch: StretchHistogram,
    /// The same before it.
    pub stretch_before: StretchHistogram,
}

fn mean_distance(a: &[Vector3<f32>], b: &[Vector3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p.cast::<f64>() - q).norm())
        .sum::<f64>()
        / a.len().max(1) as f64
}

/// Run `pp` (with the post-process) and `raw` (without) rigs of one method over `seq`.
/// `keep` lists frames whose post-processed vertices are returned (for pictures).
pub fn run_sequence(
    pp: &Arc<GarmentRig>,
    raw: &Arc<GarmentRig>,
    seq: &TestSequence,
    keep: &[usize],
) -> Result<(SequenceMetrics, Vec<Vec<Vector3<f32>>>)> {
    let betas: Vec<f32> = seq.truth.betas.iter().map(|&b| b as f32).collect();
    let n_betas = pp.network().n_betas();
    ensure!(
        betas.len() >= n_betas,
        "{}: β has {} components, the model takes {n_betas}",
        sequence_stem(&seq.shape, &seq.motion),
        betas.len()
    );
    let mut a = GarmentAnimator::new(pp.clone())?;
    let mut b = GarmentAnimator::new(raw.clone())?;
    for anim in [&mut a, &mut b] {
        anim.set_shape(&betas[..n_betas])?;
        anim.reset_from(&seq.truth.previous_pose)?;
    }
    let n = a.rig().n_vertices();
    let binding = pp.binding();
    let edges = GarmentEdges::new(binding.template(), binding.faces())?;
    let mut m = SequenceMetrics::default();
    let mut kept = Vec::new();
    let mut posed = PosedBody::new(pp.body().clone());
    let mut histogram = DistanceHistogram::default();
    for (t, (pose, truth)) in seq.truth.poses.iter().zip(&seq.truth.cloth).enumerate() {
        ensure!(
            truth.len() == n,
            "{}: the ground truth has {} vertices, the model's garment {n}",
            sequence_stem(&seq.shape, &seq.motion),
            truth.len()
        );
        let before = b.frame(pose)?;
        a.frame(pose)?;
        let after = a.vertices();
        m.per_frame_before_pp_m.push(mean_distance(before, truth));
        m.per_frame_m.push(mean_distance(after, truth));
        posed.pose(&seq.truth.betas, pose)?;
        m.inside_before += posed.measure(before.iter().map(|p| p.cast()), &mut histogram)?;
        m.inside_after += posed.measure(after.iter().map(|p| p.cast()), &mut histogram)?;
        m.vertex_frames += n;
        edges.add_frame(before, &mut m.stretch_before)?;
        edges.add_frame(after, &mut m.stretch)?;
        if keep.contains(&t) {
            kept.push(after.to_vec());
        }
    }
    Ok((m, kept))
}

/// A method's numbers on a test set, as written to eval.json.
#[derive(Clone, Debug, Serialize)]
pub struct MethodReport {
    /// Mean over frames and vertices, after the post-process, mm.
    pub mean_vertex_error_mm: f64,
    /// The same before the post-process, mm.
    pub mean_vertex_error_mm_before_pp: f64,
    /// The worst frame's mean error, mm.
    pub max_frame_error_mm: f64,
    /// Share of cloth vertices inside the body before the post-process, %.
    pub collision_percent_before_pp: f64,
    /// The same after it, %.
    pub collision_percent_after_pp: f64,
    /// Frames evaluated.
    pub frames: usize,
    /// Edge stretch after the post-process, over edges × frames.
    pub edge_stretch: StretchSummary,
    /// The same before it.
    pub edge_stretch_before_pp: StretchSummary,
    /// Per sequence.
    pub sequences: Vec<SequenceReport>,
}

/// One sequence of a [`MethodReport`].
#[derive(Clone, Debug, Serialize)]
pub struct SequenceReport {
    /// Shape id.
    pub shape: String,
    /// Motion.
    pub motion: String,
    /// Distance of β to the nearest training shape.
    pub shape_distance: f64,
    /// Mean vertex error, mm.
    pub mean_vertex_error_mm: f64,
    /// Per frame, mm.
    pub per_frame_error_mm: Vec<f64>,
    /// Inside the body after the post-process, %.
    pub collision_percent_after_pp: f64,
    /// Edge stretch after the post-process: 99th percentile and maximum.
    pub edge_stretch_p99: f64,
    /// See `edge_stretch_p99`.
    pub edge_stretch_max: f64,
}

/// The edge stretch of every sequence's `histogram`, merged.
fn merged(
    metrics: &[SequenceMetrics],
    histogram: fn(&SequenceMetrics) -> &StretchHistogram,
) -> StretchSummary {
    let mut all = StretchHistogram::default();
    metrics.iter().for_each(|m| all.merge(histogram(m)));
    all.summary()
}

fn summarise(seqs: &[TestSequence], metrics: &[SequenceMetrics]) -> MethodReport {
    let all = |f: fn(&SequenceMetrics) -> &Vec<f64>| {
        mean(&metrics.iter().flat_map(f).copied().collect::<Vec<_>>())
    };
    let vf: usize = metrics.iter().map(|m| m.vertex_frames).sum();
    let pct = |x: usize| 100.0 * x as f64 / vf.max(1) as f64;
    MethodReport {
        mean_vertex_error_mm: 1e3 * all(|m| &m.per_frame_m),
        mean_vertex_error_mm_before_pp: 1e3 * all(|m| &m.per_frame_before_pp_m),
        max_frame_error_mm: 1e3
            * metrics
                .iter()
                .flat_map(|m| m.per_frame_m.iter().copied())
                .fold(0.0, f64::max),
        collision_percent_before_pp: pct(metrics.iter().map(|m| m.inside_before).sum()),
        collision_percent_after_pp: pct(metrics.iter().map(|m| m.inside_after).sum()),
        frames: metrics.iter().map(|m| m.per_frame_m.len()).sum(),
        edge_stretch: merged(metrics, |m| &m.stretch),
        edge_stretch_before_pp: merged(metrics, |m| &m.stretch_before),
        sequences: seqs
            .iter()
            .zip(metrics)
            .map(|(s, m)| SequenceReport {
                shape: s.shape.clone(),
                motion: s.motion.clone(),
                shape_distance: s.shape_distance,
                mean_vertex_error_mm: 1e3 * mean(&m.per_frame_m),
                per_frame_error_mm: m.per_frame_m.iter().map(|e| 1e3 * e).collect(),
                collision_percent_after_pp: 100.0 * m.inside_after as f64
                    / m.vertex_frames.max(1) as f64,
                edge_stretch_p99: m.stretch.quantile(0.99),
                edge_stretch_max: m.stretch.max(),
            })
            .collect(),
    }
}

/// The test sequences of a plan, without those whose simulation failed.
pub struct TestSets {
    /// Held-out motions on training shapes.
    pub motions: Vec<(ShapePlan, String)>,
    /// Held-out shapes.
    pub shapes: Vec<(ShapePlan, String)>,
    /// Stems of test sequences skipped because their simulation failed.
    pub skipped: Vec<String>,
}

/// The two test sets of a plan whose simulations are in `sim_dir`: held-out motions (on the
/// nominal shape only, the training shape closest to β = 0, with `nominal_only`) and held-out
/// shapes.
pub fn test_sets(plan: &DatasetPlan, sim_dir: &Path, nominal_only: bool) -> Result<TestSets> {
    let failed = failed_stems(sim_dir)?;
    let train: Vec<&ShapePlan> = plan
        .shapes
        .iter()
        .filter(|s| s.split == Split::Train)
        .collect();
    let norm = |b: &[f64]| b.iter().map(|x| x * x).sum::<f64>();
    let nominal = train
        .iter()
        .min_by(|a, b| norm(&a.betas).total_cmp(&norm(&b.betas)))
        .map(|s| s.id.clone());
    let mut motions = Vec::new();
    let mut shapes = Vec::new();
    let mut skipped = Vec::new();
    for q in &plan.sequences {
        let shape = &plan.shapes[q.shape];
        let stem = sequence_stem(&shape.id, &q.motion);
        let set = match q.split {
            Split::HeldOutMotions => {
                if nominal_only && Some(&shape.id) != nominal.as_ref() {
                    continue;
                }
                &mut motions
            }
            Split::HeldOutShapes => &mut shapes,
            _ => continue,
        };
        if failed.contains(&stem) || failed.contains(&sequence_stem(&shape.id, REST_MOTION)) {
            skipped.push(stem);
        } else {
            set.push((shape.clone(), q.motion.clone()));
        }
    }
    Ok(TestSets {
        motions,
        shapes,
        skipped,
    })
}

/// Distance of `betas` to the nearest training shape of `plan` (components beyond a shape's
/// list are 0).
pub fn shape_distance(plan: &DatasetPlan, betas: &[f64]) -> f64 {
    plan.shapes
        .iter()
        .filter(|s| s.split == Split::Train)
        .map(|s| {
            let n = betas.len().max(s.betas.len());
            (0..n)
                .map(|i| {
                    let d = betas.get(i).copied().unwrap_or(0.0)
                        - s.betas.get(i).copied().unwrap_or(0.0);
                    d * d
                })
                .sum::<f64>()
                .sqrt()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The simulated motion sequences of `split` in `plan` (not the rest simulations, not those
/// whose simulation failed).
pub fn split_sequences(
    plan: &DatasetPlan,
    sim_dir: &Path,
    split: Split,
) -> Result<Vec<(ShapePlan, String)>> {
    let failed = failed_stems(sim_dir)?;
    Ok(plan
        .sequences
        .iter()
        .filter(|q| q.split == split && q.motion != REST_MOTION)
        .map(|q| (plan.shapes[q.shape].clone(), q.motion.clone()))
        .filter(|(shape, motion)| {
            !failed.contains(&sequence_stem(&shape.id, motion))
                && !failed.contains(&sequence_stem(&shape.id, REST_MOTION))
        })
        .collect())
}

/// Load the ground truth of `set` (sequences of `plan`).
pub fn load_truth(
    plan: &DatasetPlan,
    files: &SimFolder,
    set: &[(ShapePlan, String)],
) -> Result<Vec<TestSequence>> {
    set.par_iter()
        .map(|(shape, motion)| {
            let truth = files.motion(shape, motion)?;
            Ok(TestSequence {
                shape: shape.id.clone(),
                motion: motion.clone(),
                shape_distance: shape_distance(plan, &shape.betas),
                truth,
            })
        })
        .collect()
}

/// Evaluate `method` on `seqs` (sequences in parallel).
pub fn evaluate(
    assets: &Assets,
    network: &Arc<GarmentNetwork>,
    method: Method,
    seqs: &[TestSequence],
    progress: &dyn Progress,
) -> Result<MethodReport> {
    evaluate_with(
        assets,
        network,
        method.options(AnimatorOptions::default()),
        seqs,
        progress,
    )
}

/// Evaluate the runtime with `options` (its post-process, if any, gives the "after" numbers;
/// the same options without it the "before" ones) on `seqs`.
pub fn evaluate_with(
    assets: &Assets,
    network: &Arc<GarmentNetwork>,
    options: AnimatorOptions,
    seqs: &[TestSequence],
    progress: &dyn Progress,
) -> Result<MethodReport> {
    let pp = assets.rig(network, options)?;
    let raw = assets.rig(
        network,
        AnimatorOptions {
            collision: None,
            ..options
        },
    )?;
    let metrics = seqs
        .par_iter()
        .map(|s| {
            let r = run_sequence(&pp, &raw, s, &[]).map(|(m, _)| m);
            progress.inc(s.truth.poses.len() as u64);
            r
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(summarise(seqs, &metrics))
}

/// `eval.json`.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// The experiment config (as the caller names it).
    pub config: String,
    /// The exported model folder.
    pub model: String,
    /// Held-out motions on the nominal shape only.
    pub nominal_only: bool,
    /// Per method on the held-out motions.
    pub held_out_motions: serde_json::Map<String, serde_json::Value>,
    /// Per method on the held-out shapes.
    pub held_out_shapes: serde_json::Map<String, serde_json::Value>,
    /// Share of the simulated (ground-truth) cloth vertex-frames inside the body, %.
    pub ground_truth_collision_percent: f64,
    /// The ground truth's signed distance to the posed body: percentiles, share below 0 and
    /// −1 mm (the simulator promises none below −1 mm).
    pub ground_truth_signed_distance: DistanceSummary,
    /// The simulated cloth's edge stretch, per test set (the methods' `edge_stretch` beside it),
    /// and on the training and validation sequences (`train`, `validation`).
    pub ground_truth_edge_stretch: serde_json::Map<String, serde_json::Value>,
    /// Test sequences left out because their simulation failed.
    pub skipped_failed_simulations: Vec<String>,
    /// What was not evaluated and why.
    pub notes: Vec<String>,
    /// Wall time, seconds.
    pub wall_time_s: f64,
    /// Where it ran.
    pub machine: Machine,
}

/// What [`evaluate_run`] evaluates.
#[derive(Clone, Debug)]
pub struct EvalRun<'a> {
    /// The experiment's plan (shapes with their splits, sequences).
    pub plan: &'a DatasetPlan,
    /// Its simulation folder.
    pub sim_dir: &'a Path,
    /// The body model folder.
    pub body_dir: &'a Path,
    /// The exported model folder.
    pub model_dir: &'a Path,
    /// Held-out motions on the nominal shape only.
    pub nominal_only: bool,
    /// Frames shown in the rendered comparison.
    pub render_frames: usize,
    /// Where `eval.json`, the plots and `compare.png` go.
    pub out_dir: &'a Path,
    /// The config's name for the report.
    pub config: String,
}

/// Evaluate an exported model on a run's held-out sets (see the module docs); write
/// `eval.json`, `error_per_frame.{png,svg}`, `error_vs_shape.{png,svg}` and `compare.png` into
/// `run.out_dir`, and return the report.
pub fn evaluate_run(run: &EvalRun<'_>, progress: &dyn Progress) -> Result<EvalReport> {
    let start = Instant::now();
    let assets = Assets::load(run.body_dir, run.model_dir)?;
    let network = assets.network(NetworkOptions::default())?;
    let TestSets {
        motions: motion_set,
        shapes: shape_set,
        skipped,
    } = test_sets(run.plan, run.sim_dir, run.nominal_only)?;
    ensure!(
        !motion_set.is_empty() || !shape_set.is_empty(),
        "{}: nothing to evaluate (no held-out sequence was simulated)",
        run.config
    );
    let files = SimFolder::new(
        run.sim_dir,
        assets.binding.garment().sha256.clone(),
        assets.body.n_betas(),
    );
    let motions = load_truth(run.plan, &files, &motion_set)?;
    let shapes = load_truth(run.plan, &files, &shape_set)?;

    let mut notes = Vec::new();
    let mut motion_methods = vec![Method::Ours, Method::OursStrainLimit, Method::Lbs];
    if network.has_linear_baseline() {
        motion_methods.push(Method::Lr);
    } else {
        notes.push("the model carries no linear baseline: `lr` was not evaluated".to_owned());
    }
    let shape_methods = [
        Method::Ours,
        Method::OursStrainLimit,
        Method::Retarget,
        Method::Lbs,
    ];
    let frames = |s: &[TestSequence]| s.iter().map(|q| q.truth.poses.len()).sum::<usize>();
    let total = motion_methods.len() * frames(&motions) + shape_methods.len() * frames(&shapes);
    progress.start("eval", total as u64, "frames");
    let mut reports = Vec::new();
    for (set, methods, seqs) in [
        ("held_out_motions", &motion_methods[..], &motions),
        ("held_out_shapes", &shape_methods[..], &shapes),
    ] {
        let mut map = serde_json::Map::new();
        if seqs.is_empty() {
            notes.push(format!("{set}: no sequences"));
        } else {
            for &m in methods {
                progress.message(m.name());
                let r = evaluate(&assets, &network, m, seqs, progress)?;
                map.insert(m.name().to_owned(), serde_json::to_value(&r)?);
            }
        }
        reports.push(map);
    }
    progress.finish();
    let shapes_map = reports.pop().unwrap_or_default();
    let motions_map = reports.pop().unwrap_or_default();

    // The simulator's own contacts, by the same measure, and its own stretch.
    let gt = ground_truth_collisions(&assets, &motions, &shapes)?;
    let edges = GarmentEdges::new(assets.binding.template(), assets.binding.faces())?;
    let mut gt_stretch = serde_json::Map::new();
    for (set, seqs) in [("held_out_motions", &motions), ("held_out_shapes", &shapes)] {
        if !seqs.is_empty() {
            let value = serde_json::to_value(ground_truth_stretch(&edges, seqs)?)?;
            gt_stretch.insert(set.to_owned(), value);
        }
    }
    // And on the sequences the model learnt and was selected on: what a strain limit may take
    // from the physics without looking at the test.
    for (name, split) in [("train", Split::Train), ("validation", Split::Validation)] {
        let set = split_sequences(run.plan, run.sim_dir, split)?;
        if !set.is_empty() {
            let value = serde_json::to_value(ground_truth_stretch_of(&edges, &files, &set)?)?;
            gt_stretch.insert(name.to_owned(), value);
        }
    }

    let dir = run.out_dir;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    plot_errors(dir, &motions_map, &shapes_map)?;
    render_comparison(dir, &assets, &network, &motions, run.render_frames)?;
    let report = EvalReport {
        config: run.config.clone(),
        model: run.model_dir.display().to_string(),
        nominal_only: run.nominal_only,
        held_out_motions: motions_map,
        held_out_shapes: shapes_map,
        ground_truth_collision_percent: gt.below_0_mm_percent,
        ground_truth_signed_distance: gt,
        ground_truth_edge_stretch: gt_stretch,
        skipped_failed_simulations: skipped,
        notes,
        wall_time_s: start.elapsed().as_secs_f64(),
        machine: Machine::current(),
    };
    write_json(&dir.join(EVAL_FILE), &report)?;
    Ok(report)
}

/// File name of the evaluation report.
pub const EVAL_FILE: &str = "eval.json";

fn ground_truth_collisions(
    assets: &Assets,
    motions: &[TestSequence],
    shapes: &[TestSequence],
) -> Result<DistanceSummary> {
    let seqs: Vec<&TestSequence> = motions.iter().chain(shapes).collect();
    Ok(ground_truth_signed_distance(&assets.body, &seqs)?.summary())
}

/// The edge stretch of a test set's simulated cloth, as `eval.json` reports it.
#[derive(Clone, Debug, Serialize)]
pub struct GroundTruthStretch {
    /// Over the set's edges × frames.
    #[serde(flatten)]
    pub all: StretchSummary,
    /// Per sequence.
    pub sequences: Vec<SequenceStretch>,
}

/// One sequence of a [`GroundTruthStretch`].
#[derive(Clone, Debug, Serialize)]
pub struct SequenceStretch {
    /// Shape id.
    pub shape: String,
    /// Motion.
    pub motion: String,
    /// 99th percentile of the edge stretch.
    pub edge_stretch_p99: f64,
    /// Its maximum.
    pub edge_stretch_max: f64,
}

/// The edge stretch of `seqs`' simulated cloth (every frame; sequences in parallel).
pub fn ground_truth_stretch(
    edges: &GarmentEdges,
    seqs: &[TestSequence],
) -> Result<GroundTruthStretch> {
    let parts = seqs
        .par_iter()
        .map(|s| cloth_stretch(edges, &s.truth.cloth, &s.shape, &s.motion))
        .collect::<Result<Vec<_>>>()?;
    let ids = seqs.iter().map(|s| (s.shape.clone(), s.motion.clone()));
    Ok(stretch_report(ids, &parts))
}

/// The edge stretch of the simulated cloth of `set` (the motion frames of each sequence read
/// from `files`, one at a time per thread: a training split does not fit in memory at once).
pub fn ground_truth_stretch_of(
    edges: &GarmentEdges,
    files: &SimFolder,
    set: &[(ShapePlan, String)],
) -> Result<GroundTruthStretch> {
    let parts = set
        .par_iter()
        .map(|(shape, motion)| {
            cloth_stretch(
                edges,
                &files.motion(shape, motion)?.cloth,
                &shape.id,
                motion,
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let ids = set.iter().map(|(s, m)| (s.id.clone(), m.clone()));
    Ok(stretch_report(ids, &parts))
}

/// The edge stretch of one sequence's simulated cloth (`frames`), errors naming it.
fn cloth_stretch(
    edges: &GarmentEdges,
    frames: &[Vec<Vector3<f64>>],
    shape: &str,
    motion: &str,
) -> Result<StretchHistogram> {
    let mut h = StretchHistogram::default();
    for cloth in frames {
        edges
            .add_frame(cloth, &mut h)
            .with_context(|| format!("the ground truth of {}", sequence_stem(shape, motion)))?;
    }
    Ok(h)
}

/// A [`GroundTruthStretch`] from each sequence's `(shape, motion)` and histogram.
fn stretch_report(
    ids: impl Iterator<Item = (String, String)>,
    parts: &[StretchHistogram],
) -> GroundTruthStretch {
    let mut all = StretchHistogram::default();
    parts.iter().for_each(|h| all.merge(h));
    GroundTruthStretch {
        all: all.summary(),
        sequences: ids
            .zip(parts)
            .map(|((shape, motion), h)| SequenceStretch {
                shape,
                motion,
                edge_stretch_p99: h.quantile(0.99),
                edge_stretch_max: h.max(),
            })
            .collect(),
    }
}

/// The signed distance of every ground-truth cloth vertex of `seqs` (every frame) to the posed
/// body, by the one collision measure; sequences in parallel on rayon's pool (the histogram is
/// the same on any thread count: counts are integers).
pub fn ground_truth_signed_distance(
    body: &Arc<BodyModel>,
    seqs: &[&TestSequence],
) -> Result<DistanceHistogram> {
    let parts = seqs
        .par_iter()
        .map(|s| -> Result<DistanceHistogram> {
            let mut posed = PosedBody::new(body.clone());
            let mut histogram = DistanceHistogram::default();
            for (pose, truth) in s.truth.poses.iter().zip(&s.truth.cloth) {
                posed.pose(&s.truth.betas, pose)?;
                posed.measure(truth.iter().copied(), &mut histogram)?;
            }
            Ok(histogram)
        })
        .collect::<Result<Vec<_>>>()?;
    let mut total = DistanceHistogram::default();
    parts.iter().for_each(|h| total.merge(h));
    Ok(total)
}

impl EvalReport {
    /// One line per set and method: error after (before) the post-process, collisions.
    pub fn summary_lines(&self) -> Vec<String> {
        let mut lines = Vec::new();
        for (set, key, map) in [
            (
                "held-out motions",
                "held_out_motions",
                &self.held_out_motions,
            ),
            ("held-out shapes", "held_out_shapes", &self.held_out_shapes),
        ] {
            for (name, v) in map {
                let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
                let e = |k: &str| v["edge_stretch"][k].as_f64().unwrap_or(f64::NAN);
                lines.push(format!(
                    "{set:>16} {name:>17}: {:7.2} mm ({:7.2} before pp), \
                     inside {:5.2} % → {:5.2} %, edges p99 {:.2}× max {:.1}×",
                    f("mean_vertex_error_mm"),
                    f("mean_vertex_error_mm_before_pp"),
                    f("collision_percent_before_pp"),
                    f("collision_percent_after_pp"),
                    e("edge_stretch_p99"),
                    e("edge_stretch_max"),
                ));
            }
            lines.extend(self.truth_stretch_line(set, key));
        }
        lines.extend(self.truth_stretch_line("training", "train"));
        lines.extend(self.truth_stretch_line("validation", "validation"));
        lines
    }

    /// The simulated cloth's edge stretch on the set `key` of `ground_truth_edge_stretch`.
    fn truth_stretch_line(&self, set: &str, key: &str) -> Option<String> {
        let gt = self.ground_truth_edge_stretch.get(key)?;
        let e = |k: &str| gt[k].as_f64().unwrap_or(f64::NAN);
        Some(format!(
            "{set:>16} {:>17}: edges p99 {:.2}× p99.9 {:.2}× max {:.1}×",
            "truth",
            e("edge_stretch_p99"),
            e("edge_stretch_p999"),
            e("edge_stretch_max"),
        ))
    }
}

/// Per-frame error of each held-out clip (averaged over its shapes, frame by frame) for each
/// method (the paper's Fig. 7), and error against shape distance (Fig. 8).
fn plot_errors(
    dir: &Path,
    motions: &serde_json::Map<String, serde_json::Value>,
    shapes: &serde_json::Map<String, serde_json::Value>,
) -> Result<()> {
    let seqs = |v: &serde_json::Value| -> Vec<SequenceReport> {
        serde_json::from_value::<Vec<SeqIn>>(v["sequences"].clone())
            .unwrap_or_default()
            .into_iter()
            .map(SeqIn::into_report)
            .collect()
    };
    let mut clips: Vec<String> = Vec::new();
    for v in motions.values() {
        for s in seqs(v) {
            if !clips.contains(&s.motion) {
                clips.push(s.motion);
            }
        }
    }
    let mut charts = Vec::new();
    for clip in &clips {
        let mut series = Vec::new();
        for (name, v) in motions {
            let curves: Vec<Vec<f64>> = seqs(v)
                .into_iter()
                .filter(|s| &s.motion == clip)
                .map(|s| s.per_frame_error_mm)
                .collect();
            let len = curves.iter().map(Vec::len).min().unwrap_or(0);
            let points = (0..len)
                .map(|t| {
                    (
                        t as f64,
                        mean(&curves.iter().map(|c| c[t]).collect::<Vec<_>>()),
                    )
                })
                .collect();
            series.push(Series {
                name: name.clone(),
                points,
                marker: None,
                color: None,
            });
        }
        charts.push(Chart {
            title: format!("held-out motion: {clip}"),
            x_label: "frame".into(),
            y_label: "mean vertex error (mm)".into(),
            series,
            log_x: false,
            legend_at_bottom: false,
            ranges: None,
        });
    }
    if !charts.is_empty() {
        write_charts(&dir.join("error_per_frame"), &charts, 2, (560, 360))?;
    }
    let series: Vec<Series> = shapes
        .iter()
        .map(|(name, v)| Series {
            name: name.clone(),
            points: seqs(v)
                .iter()
                .map(|s| (s.shape_distance, s.mean_vertex_error_mm))
                .collect(),
            marker: Some(Marker::Circle),
            color: None,
        })
        .collect();
    if !series.is_empty() {
        let chart = Chart {
            title: "held-out shapes".into(),
            x_label: "β distance to the nearest training shape".into(),
            y_label: "mean vertex error (mm)".into(),
            series,
            log_x: false,
            legend_at_bottom: false,
            ranges: None,
        };
        write_charts(&dir.join("error_vs_shape"), &[chart], 1, (640, 420))?;
    }
    Ok(())
}

/// `SequenceReport` read back from the JSON value (the report is built once, as JSON).
#[derive(serde::Deserialize)]
struct SeqIn {
    shape: String,
    motion: String,
    shape_distance: f64,
    mean_vertex_error_mm: f64,
    per_frame_error_mm: Vec<f64>,
    collision_percent_after_pp: f64,
    edge_stretch_p99: f64,
    edge_stretch_max: f64,
}

impl SeqIn {
    fn into_report(self) -> SequenceReport {
        SequenceReport {
            shape: self.shape,
            motion: self.motion,
            shape_distance: self.shape_distance,
            mean_vertex_error_mm: self.mean_vertex_error_mm,
            per_frame_error_mm: self.per_frame_error_mm,
            collision_percent_after_pp: self.collision_percent_after_pp,
            edge_stretch_p99: self.edge_stretch_p99,
            edge_stretch_max: self.edge_stretch_max,
        }
    }
}

/// Colours of the rendered comparison (linear RGB).
const BODY_COLOR: [f32; 3] = [0.55, 0.45, 0.40];
const TRUTH_COLOR: [f32; 3] = [0.20, 0.45, 0.20];
const OURS_COLOR: [f32; 3] = [0.15, 0.30, 0.60];
const LBS_COLOR: [f32; 3] = [0.60, 0.20, 0.15];

/// `compare.png`: a few frames of the first held-out clip on its first shape, each as ground
/// truth | ours | LBS on the posed body.
fn render_comparison(
    dir: &Path,
    assets: &Assets,
    network: &Arc<GarmentNetwork>,
    motions: &[TestSequence],
    n_frames: usize,
) -> Result<()> {
    let Some(seq) = motions.first() else {
        return Ok(());
    };
    let len = seq.truth.poses.len();
    if n_frames == 0 || len == 0 {
        return Ok(());
    }
    let keep: Vec<usize> = (0..n_frames.min(len))
        .map(|k| (k + 1) * len / (n_frames.min(len) + 1))
        .collect();
    let mut outputs = Vec::new();
    for m in [Method::Ours, Method::Lbs] {
        let pp = assets.rig(network, m.options(AnimatorOptions::default()))?;
        let raw = assets.rig(
            network,
            m.options(AnimatorOptions {
                collision: None,
                ..AnimatorOptions::default()
            }),
        )?;
        outputs.push(run_sequence(&pp, &raw, seq, &keep)?.1);
    }
    let body = &assets.body;
    let faces = assets.binding.faces();
    let bodies: Vec<Vec<Vector3<f32>>> = keep
        .iter()
        .map(|&t| posed_body(body, &seq.truth.betas, &seq.truth.poses[t]))
        .collect::<Result<_>>()?;
    let truths: Vec<Vec<Vector3<f32>>> = keep
        .iter()
        .map(|&t| seq.truth.cloth[t].iter().map(|p| p.cast::<f32>()).collect())
        .collect();
    let mut panels = Vec::new();
    for (k, body_k) in bodies.iter().enumerate() {
        let cloths = [
            (&truths[k], TRUTH_COLOR),
            (&outputs[0][k], OURS_COLOR),
            (&outputs[1][k], LBS_COLOR),
        ];
        let body_mesh = RenderMesh {
            positions: body_k,
            faces: body.faces(),
            color: BODY_COLOR,
        };
        let first = [
            body_mesh,
            RenderMesh {
                positions: cloths[0].0,
                faces,
                color: cloths[0].1,
            },
        ];
        let camera = Camera::framing(&first[1..], Vector3::new(0.35, 0.15, 1.0), true);
        for (cloth, color) in cloths {
            panels.push(Panel {
                meshes: vec![
                    body_mesh,
                    RenderMesh {
                        positions: cloth,
                        faces,
                        color,
                    },
                ],
                camera,
            });
        }
    }
    let path = dir.join("compare.png");
    render_png(&path, &panels, 240, 300, [1.0, 1.0, 1.0])?;
    Ok(())
}

pub(crate) fn posed_body(
    body: &BodyModel,
    betas: &[f64],
    pose: &Pose,
) -> Result<Vec<Vector3<f32>>> {
    let mut b = betas.to_vec();
    b.resize(body.n_betas(), 0.0);
    Ok(body
        .posed_vertices(&b, pose)?
        .iter()
        .map(|p| p.cast::<f32>())
        .collect())
}
