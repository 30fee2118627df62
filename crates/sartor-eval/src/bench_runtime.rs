//! `bench runtime`: the paper's Table 1 side by side. For T-shirts of 4,210 / 8,710
//! / 17,710 / 26,066 triangles, a model at the paper's sizes (fit MLP 20, GRU 1500, dense
//! output) with random weights, animated over a procedural clip on the built-in body: ms per
//! frame without and with the collision post-process, on one thread and on all, in f32, f16
//! and int8; model memory; the post-process query measured (BVH against candidate triangles:
//! time and misses); reduced models; crowds (`GarmentCrowd`: 1, 4 and 16 avatars sharing one
//! pass over the weights, at the reference size in f32 and int8, one thread and all). Writes
//! `bench-runtime.json`.
//!
//! The post-process's cost follows how much cloth lies within the margin of the body, which
//! random weights do not reproduce: with [`RuntimeBenchOptions::trained_models`] the report's
//! `trained` section times the default post-process of each trained export on its own garment
//! (int8, one thread, the nominal shape), on the clip and on
//! [`RuntimeBenchOptions::trained_motions`], with what the certified query did per frame and its
//! garment against the exact BVH query's.
//!
//! The random output layers are smooth over the garment (`W = Φ R`, `Φ` 16 low-frequency
//! functions of the vertex position, `R` random), so the wrinkles look like wrinkles (about
//! 5 mm, smooth) rather than per-vertex noise: that matters for the post-process, not for the
//! network's speed (the stored matrix is dense `3V × H`).
//!
//! With [`RuntimeBenchOptions::anchors`], the same run also times the shipped model and the
//! paper-size model at 8,710 triangles in PyTorch and ONNX Runtime, against a memory-bandwidth
//! floor (the `anchors` section; see `bench_anchors.rs`).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sartor_core::io::{read_file, sha256_hex};
use sartor_core::{BodyModel, MODEL_HEADER, Pose, PoseFeatureSpec, RootFeature};
use sartor_motion::cmu_mb_body_joints as feature_joints;
use sartor_runtime::{
    AnimatorOptions, AssetId, CollisionOptions, CollisionQuery, DenseWeights, FeatureBlock,
    GarmentAnimator, GarmentBinding, GarmentCrowd, GarmentModel, GarmentNetwork, GarmentRig,
    GruWeights, Interpenetration, MeanStd, ModelHeader, ModelSizes, ModelWeights, NetworkOptions,
    NormStats, OutputKind, Parallelism, PcaWeights, Precision, RotationEncoding, instruction_set,
};
use serde::Serialize;

use crate::bench_anchors::{AnchorModel, AnchorOptions, AnchorsReport, anchors, check_anchors};
use crate::bench_sim::{GarmentDirs, garment_of_size};
use crate::error::Context;
use crate::report::{Machine, load_average};
use crate::timing::{mean, median, time_calls, time_frames, time_stages};
use crate::{Progress, Result};

/// What `bench runtime` times.
#[derive(Clone, Debug)]
pub struct RuntimeBenchOptions {
    /// Garment sizes (triangles) to run; each needs `<recipes>/tshirt-<n>.json` or a committed
    /// `<garments>/tshirt-<n>`.
    pub triangles: Vec<usize>,
    /// Procedural clip to animate.
    pub clip: String,
    /// Frames run before timing (GRU state and caches warm up).
    pub warmup: usize,
    /// Frames timed per configuration.
    pub frames: usize,
    /// GRU hidden size of the paper-size model.
    pub gru_hidden: usize,
    /// Garment size (triangles) of the post-process comparison and the reduced models.
    pub reference_triangles: usize,
    /// Also time the shipped model and the paper-size model ([`ANCHOR_PAPER_TRIANGLES`]) in
    /// PyTorch and ONNX Runtime, against a memory-bandwidth floor (`None`: no anchors, the
    /// report as before).
    pub anchors: Option<AnchorOptions>,
    /// Trained exported models whose post-process is timed on their own garment (`trained` in
    /// the report): its cost follows how much cloth lies within the margin of the body, which
    /// the random weights do not reproduce.
    pub trained_models: Vec<PathBuf>,
    /// Motions the trained models are timed on besides the procedural `clip`: a name and its
    /// poses on the built-in body (e.g. retargeted CMU clips).
    pub trained_motions: Vec<(String, Vec<Pose>)>,
}

/// Garment size (triangles) of the paper-size model the anchors time: the paper's 8,710.
pub const ANCHOR_PAPER_TRIANGLES: usize = 8710;

/// The paper's Table 1 (Titan X + i7): triangles, ms per frame without / with post-process.
const PAPER: [(usize, f64, f64); 4] = [
    (4210, 1.47, 3.39),
    (8710, 1.51, 4.01),
    (17710, 2.12, 5.47),
    (26066, 2.40, 6.87),
];

const N_BETAS: usize = 10;
const FIT_HIDDEN: usize = 20;
/// Body region: faces with a vertex within this distance of the garment at rest.
const REGION_MARGIN_M: f64 = 0.03;
/// The template shape: the random fit displacement does not follow the body's shape change, so
/// another shape would put the garment inside a larger body.
const BETAS: [f32; N_BETAS] = [0.0; N_BETAS];

#[derive(Serialize)]
struct Paper {
    ms_per_frame: f64,
    ms_per_frame_pp: f64,
    device: &'static str,
}

#[derive(Serialize)]
struct Memory {
    precision: &'static str,
    fit_mb: f64,
    wrinkle_mb: f64,
}

#[derive(Serialize)]
struct Run {
    precision: &'static str,
    threads: usize,
    /// Median over the timed frames.
    ms_per_frame: f64,
    ms_per_frame_pp: f64,
    ms_per_frame_mean: f64,
    ms_per_frame_pp_mean: f64,
    /// Mean CPU time of the thread per frame (one thread only): robust to a loaded machine.
    cpu_ms_per_frame: Option<f64>,
    cpu_ms_per_frame_pp: Option<f64>,
    /// Ours over the paper's (below 1: faster than the paper's GPU).
    ratio_to_paper: Option<f64>,
    ratio_to_paper_pp: Option<f64>,
    cpu_ratio_to_paper: Option<f64>,
    cpu_ratio_to_paper_pp: Option<f64>,
}

#[derive(Serialize)]
struct GarmentResult {
    triangles: usize,
    vertices: usize,
    source: String,
    region_faces: usize,
    region_vertices: usize,
    paper: Option<Paper>,
    memory: Vec<Memory>,
    runs: Vec<Run>,
}

#[derive(Serialize)]
struct QueryResult {
    query: String,
    /// Mean CPU ms per frame of the whole frame with this post-process (int8 network, 1
    /// thread).
    cpu_ms_per_frame_pp: f64,
    /// The post-process's own share: `cpu_ms_per_frame_pp` minus the same frame without it
    /// (what it adds to the frame, the network's caches refilled included; two runs, so their
    /// noise too).
    cpu_ms_post_process: f64,
    /// The post-process stage's own CPU time per frame, read by the thread clock at its ends
    /// inside each frame (`time_stages`, a separate run of the same frames): the cleaner
    /// figure of its cost.
    cpu_ms_post_process_stage: Option<f64>,
    mean_candidates_per_vertex: f64,
    /// Over the clip, after the post-process: cloth vertices inside the body, and closer than
    /// the margin − 0.01 mm (exact query).
    inside_after: usize,
    within_margin_after: usize,
    /// Vertices whose final position differs from the BVH's by more than 1 µm.
    differing_from_bvh: usize,
}

#[derive(Serialize)]
struct PostProcess {
    triangles: usize,
    frames: usize,
    vertex_frames: usize,
    inside_before: usize,
    within_margin_before: usize,
    queries: Vec<QueryResult>,
    default_query: String,
}

/// The default post-process of a trained model on one motion: int8 network, one thread, the
/// nominal shape.
#[derive(Serialize)]
struct TrainedPostProcess {
    /// The exported model folder.
    model: String,
    triangles: usize,
    vertices: usize,
    gru_hidden: usize,
    output: String,
    motion: String,
    /// Frames of the motion the counts are over (at most the run's timed frames); the timing
    /// cycles through them.
    frames: usize,
    /// Median ms per frame (wall, one thread), without and with the post-process.
    ms_per_frame: f64,
    ms_per_frame_pp: f64,
    /// The post-process stage's own CPU time per frame (thread clock at its ends, mean), with
    /// the default (certified) query and with the exact BVH query.
    cpu_ms_post_process_stage: Option<f64>,
    cpu_ms_post_process_stage_bvh: Option<f64>,
    /// Per frame, mean: cloth vertices the certified query proved to need no push (of them
    /// swept from their last face), those answered exactly (within the margin or inside), and
    /// pushes over all passes.
    certified_per_frame: f64,
    swept_per_frame: f64,
    exact_per_frame: f64,
    pushed_per_frame: f64,
    /// Over the frames: cloth vertices inside the body and closer than the margin − 0.01 mm
    /// before the post-process, after it with the certified query and with the exact BVH.
    inside_before: usize,
    within_margin_before: usize,
    inside_after: usize,
    within_margin_after: usize,
    inside_after_bvh: usize,
    within_margin_after_bvh: usize,
    /// Vertex-frames whose position differs from the BVH query's by more than 1 µm.
    differing_from_bvh: usize,
}

#[derive(Serialize)]
struct Reduced {
    name: String,
    triangles: usize,
    gru_hidden: usize,
    output: String,
    precision: &'static str,
    threads: usize,
    ms_per_frame: f64,
    ms_per_frame_pp: f64,
    cpu_ms_per_frame: Option<f64>,
    cpu_ms_per_frame_pp: Option<f64>,
    wrinkle_mb: f64,
    load_s: f64,
}

/// A crowd: `avatars` avatars of one rig animated together by [`GarmentCrowd::frame`].
#[derive(Serialize)]
struct CrowdRun {
    triangles: usize,
    precision: &'static str,
    avatars: usize,
    threads: usize,
    /// Crowd frames timed (each `avatars` avatar frames): the run's frames over the avatars,
    /// at least [`CROWD_MIN_FRAMES`].
    frames: usize,
    /// Median ms per frame of the whole crowd, without and with the default post-process.
    ms_per_frame: f64,
    ms_per_frame_pp: f64,
    /// The same per avatar (`ms_per_frame_pp / avatars`).
    ms_per_avatar: f64,
    ms_per_avatar_pp: f64,
    /// A lone avatar's frame (the crowd of one, same precision and threads) over
    /// `ms_per_avatar`: what animating them together saves (above 1: cheaper per avatar).
    gain_per_avatar: f64,
    gain_per_avatar_pp: f64,
    /// Avatars whose frames with post-process fit in 16.7 ms (a 60 Hz display's frame) at this
    /// cost per avatar.
    avatars_per_60hz_frame_pp: f64,
}

/// Crowd sizes `bench runtime` times.
const CROWD_AVATARS: [usize; 3] = [1, 4, 16];
/// Crowd frames timed at least (and warm-up frames at least a sixth of it).
const CROWD_MIN_FRAMES: usize = 30;

/// `bench-runtime.json`.
#[derive(Serialize)]
pub struct RuntimeBenchReport {
    command: String,
    machine: Machine,
    instruction_set: &'static str,
    threads_all: usize,
    load_average_start: Option<[f64; 3]>,
    load_average_end: Option<[f64; 3]>,
    clip: String,
    warmup_frames: usize,
    timed_frames: usize,
    model: ModelSizes,
    garments: Vec<GarmentResult>,
    post_process: Option<PostProcess>,
    reduced: Vec<Reduced>,
    /// Crowds at the reference size: avatars animated together, their network step batched.
    crowd: Vec<CrowdRun>,
    /// The post-process of trained models on their own garment.
    trained: Vec<TrainedPostProcess>,
    /// The same weights in PyTorch and ONNX Runtime (`--anchors` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    anchors: Option<AnchorsReport>,
    notes: Vec<&'static str>,
    wall_time_s: f64,
}

fn uniform(rng: &mut ChaCha8Rng, n: usize, amp: f32) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-amp..amp)).collect()
}

/// `[3V, cols]` weights smooth over the garment: `W[3v + c, j] = Σ_k φ_k(p_v) R[k, c, j]` with
/// 16 plane waves `φ_k` of wavelength 10–40 cm and `R` uniform; scaled so that `W x` has about
/// unit spread for inputs in [−1, 1].
fn smooth_weights(rng: &mut ChaCha8Rng, positions: &[Vector3<f64>], cols: usize) -> Vec<f32> {
    const K: usize = 16;
    let waves: Vec<(Vector3<f64>, f64)> = (0..K)
        .map(|_| {
            let dir = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .try_normalize(1e-9)
            .unwrap_or_else(Vector3::x);
            let wavelength = rng.random_range(0.1..0.4);
            (
                dir * (std::f64::consts::TAU / wavelength),
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        })
        .collect();
    let amp = 3.0 / ((cols * K) as f32 / 2.0).sqrt();
    let r = uniform(rng, K * 3 * cols, amp);
    let mut w = vec![0.0f32; positions.len() * 3 * cols];
    for (v, p) in positions.iter().enumerate() {
        let phi: Vec<f32> = waves
            .iter()
            .map(|(k, phase)| (k.dot(p) + phase).sin() as f32)
            .collect();
        for c in 0..3 {
            let row = &mut w[(3 * v + c) * cols..(3 * v + c + 1) * cols];
            for (k, &f) in phi.iter().enumerate() {
                let rk = &r[(k * 3 + c) * cols..(k * 3 + c + 1) * cols];
                for (o, &x) in row.iter_mut().zip(rk) {
                    *o += f * x;
                }
            }
        }
    }
    w
}

fn mean_std(n: usize, std: f32) -> MeanStd {
    MeanStd {
        mean: vec![0.0; n],
        std: vec![std; n],
    }
}

/// A random model of the garment with the real input layout.
fn model(
    garment: &AssetId,
    body: &AssetId,
    positions: &[Vector3<f64>],
    gru_hidden: usize,
    output: OutputKind,
    seed: u64,
) -> Result<GarmentModel> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let v = positions.len();
    let rot = feature_joints().len() * 6;
    let sizes = ModelSizes {
        n_vertices: v,
        n_betas: N_BETAS,
        n_pose_features: rot + RootFeature::ALL.len(),
        fit_hidden: FIT_HIDDEN,
        gru_hidden,
        output,
        linear_baseline: false,
    };
    let header = ModelHeader::new(
        garment.clone(),
        body.clone(),
        sizes,
        FeatureBlock::layout(
            N_BETAS,
            &PoseFeatureSpec {
                joints: feature_joints(),
                encoding: RotationEncoding::Rot6d,
                root: RootFeature::ALL.to_vec(),
            },
        ),
    );
    let (i, h, o3) = (sizes.wrinkle_inputs(), gru_hidden, 3 * v);
    let a = 1.0 / (h as f32).sqrt();
    let dense = |rng: &mut ChaCha8Rng, rows: usize, cols: usize| {
        let a = 1.0 / (cols as f32).sqrt();
        DenseWeights {
            weight: uniform(rng, rows * cols, a),
            bias: uniform(rng, rows, a),
        }
    };
    let fit_hidden = dense(&mut rng, FIT_HIDDEN, N_BETAS);
    let fit_out = DenseWeights {
        weight: smooth_weights(&mut rng, positions, FIT_HIDDEN),
        bias: vec![0.0; o3],
    };
    let gru = GruWeights {
        weight_ih: uniform(&mut rng, 3 * h * i, a),
        weight_hh: uniform(&mut rng, 3 * h * h, a),
        bias_ih: uniform(&mut rng, 3 * h, a),
        bias_hh: uniform(&mut rng, 3 * h, a),
    };
    let (wrinkle_out, pca) = match output {
        OutputKind::Dense => (
            DenseWeights {
                weight: smooth_weights(&mut rng, positions, h),
                bias: vec![0.0; o3],
            },
            None,
        ),
        OutputKind::Pca(k) => (
            dense(&mut rng, k, h),
            Some(PcaWeights {
                basis: smooth_weights(&mut rng, positions, k),
                mean: vec![0.0; o3],
            }),
        ),
    };
    let weights = ModelWeights {
        fit_hidden,
        fit_out,
        gru,
        wrinkle_out,
        pca,
        lr: None,
        norm: NormStats {
            fit_in: mean_std(N_BETAS, 1.0),
            wrinkle_in: mean_std(i, 1.0),
            fit_out: mean_std(o3, 0.002),
            wrinkle_out: mean_std(o3, 0.005),
        },
    };
    Ok(GarmentModel::new(header, weights)?)
}

/// The assets of one garment.
struct Scene {
    body: Arc<BodyModel>,
    binding: Arc<GarmentBinding>,
    positions: Vec<Vector3<f64>>,
    garment_id: AssetId,
    body_id: AssetId,
    source: String,
}

fn scene(
    triangles: usize,
    body: &Arc<BodyModel>,
    body_id: &AssetId,
    dirs: &GarmentDirs,
    progress: &dyn Progress,
) -> Result<Scene> {
    // The template as built (unrelaxed) unless a committed one exists: the timing does not
    // depend on the drape.
    let material = sartor_cloth::Material::gray_interlock();
    let (garment, source) = garment_of_size(triangles, body, &material, dirs, true, progress)?;
    let mesh = garment.mesh();
    let garment_id = AssetId {
        id: format!("tshirt-{triangles}"),
        sha256: sha256_hex(sartor_core::obj_text(mesh.positions(), mesh.faces()).as_bytes()),
    };
    let binding = GarmentBinding::from_body(
        garment_id.clone(),
        mesh.positions(),
        mesh.faces(),
        body_id.clone(),
        body,
        REGION_MARGIN_M,
        0.0,
    )?;
    Ok(Scene {
        body: body.clone(),
        binding: Arc::new(binding),
        positions: mesh.positions().to_vec(),
        garment_id,
        body_id: body_id.clone(),
        source,
    })
}

fn avatar(
    scene: &Scene,
    network: &Arc<GarmentNetwork>,
    options: AnimatorOptions,
) -> Result<GarmentAnimator> {
    let rig = GarmentRig::new(
        network.clone(),
        scene.binding.clone(),
        scene.body.clone(),
        options,
    )?;
    let mut a = GarmentAnimator::new(Arc::new(rig))?;
    a.set_shape(&BETAS)?;
    Ok(a)
}

fn options(parallelism: Parallelism, collision: Option<CollisionOptions>) -> AnimatorOptions {
    AnimatorOptions {
        collision,
        parallelism,
        ..AnimatorOptions::default()
    }
}

const PRECISIONS: [Precision; 3] = [Precision::F32, Precision::F16, Precision::Int8];

/// Time one network at both thread counts, with and without the default post-process.
fn runs(
    scene: &Scene,
    network: &Arc<GarmentNetwork>,
    poses: &[Pose],
    args: &RuntimeBenchOptions,
    paper: Option<(f64, f64)>,
    progress: &dyn Progress,
) -> Result<Vec<Run>> {
    let threads_all = rayon::current_num_threads();
    let mut out = Vec::new();
    for (par, threads) in [
        (Parallelism::Sequential, 1),
        (Parallelism::Rayon, threads_all),
    ] {
        let mut plain = avatar(scene, network, options(par, None))?;
        let mut pp = avatar(
            scene,
            network,
            options(par, Some(CollisionOptions::default())),
        )?;
        let t = time_frames(&mut plain, poses, args.warmup, args.frames)?;
        let t_pp = time_frames(&mut pp, poses, args.warmup, args.frames)?;
        let (ms, ms_pp) = (median(&t.wall_ms), median(&t_pp.wall_ms));
        let single = threads == 1;
        let (cpu, cpu_pp) = (t.cpu_ms.filter(|_| single), t_pp.cpu_ms.filter(|_| single));
        progress.println(&format!(
            "  {:>4} {threads} thread(s): {ms:7.3} ms/frame, {ms_pp:7.3} with post-process \
             (CPU {:.3} / {:.3})",
            network.precision().name(),
            cpu.unwrap_or(f64::NAN),
            cpu_pp.unwrap_or(f64::NAN)
        ));
        out.push(Run {
            precision: network.precision().name(),
            threads,
            ms_per_frame: ms,
            ms_per_frame_pp: ms_pp,
            ms_per_frame_mean: mean(&t.wall_ms),
            ms_per_frame_pp_mean: mean(&t_pp.wall_ms),
            cpu_ms_per_frame: cpu,
            cpu_ms_per_frame_pp: cpu_pp,
            ratio_to_paper: paper.map(|p| ms / p.0),
            ratio_to_paper_pp: paper.map(|p| ms_pp / p.1),
            cpu_ratio_to_paper: paper.zip(cpu).map(|(p, c)| c / p.0),
            cpu_ratio_to_paper_pp: paper.zip(cpu_pp).map(|(p, c)| c / p.1),
        });
    }
    Ok(out)
}

/// BVH against candidate triangles at one garment size: time and misses over the clip.
fn post_process(
    scene: &Scene,
    network: &Arc<GarmentNetwork>,
    poses: &[Pose],
    args: &RuntimeBenchOptions,
    progress: &dyn Progress,
) -> Result<PostProcess> {
    let par = Parallelism::Sequential;
    let mut plain = avatar(scene, network, options(par, None))?;
    let base = time_frames(&mut plain, poses, args.warmup, args.frames)?
        .cpu_ms
        .unwrap_or(f64::NAN);
    let queries = [
        (
            "none: pose and refit the region only (passes 0)".to_string(),
            CollisionQuery::EXACT_BVH,
        ),
        ("bvh exact".to_string(), CollisionQuery::EXACT_BVH),
        (
            "certified (exact; far vertices skipped by proof)".to_string(),
            CollisionQuery::Certified,
        ),
        (
            "bvh r=3cm".to_string(),
            CollisionQuery::Bvh { radius_m: 0.03 },
        ),
        (
            "bvh r=1cm".to_string(),
            CollisionQuery::Bvh { radius_m: 0.01 },
        ),
        (
            "bvh band 5mm refresh 16".to_string(),
            CollisionQuery::BvhBand {
                band_m: 0.005,
                refresh_every: 16,
            },
        ),
        (
            "bvh band 1cm refresh 8".to_string(),
            CollisionQuery::BvhBand {
                band_m: 0.01,
                refresh_every: 8,
            },
        ),
        (
            "guarded candidates r=2cm k=8".to_string(),
            CollisionQuery::GuardedCandidates {
                radius_m: 0.02,
                max_per_vertex: 8,
            },
        ),
        (
            "guarded candidates r=3cm k=16".to_string(),
            CollisionQuery::GuardedCandidates {
                radius_m: 0.03,
                max_per_vertex: 16,
            },
        ),
        (
            "candidates r=2cm k=8".to_string(),
            CollisionQuery::Candidates {
                radius_m: 0.02,
                max_per_vertex: 8,
            },
        ),
        (
            "candidates r=4cm k=32".to_string(),
            CollisionQuery::Candidates {
                radius_m: 0.04,
                max_per_vertex: 32,
            },
        ),
    ];
    let within = CollisionOptions::default().interpenetration;
    let collision = |query, passes, (faces, interpenetration)| CollisionOptions {
        query,
        passes,
        faces,
        interpenetration,
        ..CollisionOptions::default()
    };
    // Every query as the vertex passes alone, then the default one with the triangles pushed
    // out too (`CollisionOptions::faces`, off by default), and as a body beyond the training
    // shapes gets it (the faces buried inside another part sought every frame).
    let queries = queries
        .into_iter()
        .map(|(name, query)| (name, query, (false, within)))
        .chain([
            (
                "certified, triangles pushed too (faces)".to_string(),
                CollisionQuery::Certified,
                (true, within),
            ),
            (
                "certified, buried faces sought (a body beyond the training shapes)".to_string(),
                CollisionQuery::Certified,
                (false, Interpenetration::Always),
            ),
        ]);
    let passes_on = CollisionOptions::default().passes;
    // Collisions before the post-process (detect only), and the BVH's result per frame.
    let mut detect = avatar(
        scene,
        network,
        options(
            par,
            Some(collision(CollisionQuery::EXACT_BVH, 0, (false, within))),
        ),
    )?;
    let mut bvh = avatar(
        scene,
        network,
        options(
            par,
            Some(collision(
                CollisionQuery::EXACT_BVH,
                passes_on,
                (false, within),
            )),
        ),
    )?;
    let before = collisions(&mut detect, poses, args.frames, None, false)?;
    let (inside_before, near_before) = (before.inside, before.near);
    let reference = collisions(&mut bvh, poses, args.frames, None, true)?.garments;
    let mut results = Vec::new();
    for (k, (name, query, variant)) in queries.enumerate() {
        let passes = if k == 0 { 0 } else { passes_on };
        let mut timed = avatar(
            scene,
            network,
            options(par, Some(collision(query, passes, variant))),
        )?;
        let ms = time_frames(&mut timed, poses, args.warmup, args.frames)?
            .cpu_ms
            .unwrap_or(f64::NAN);
        let mut staged = avatar(
            scene,
            network,
            options(par, Some(collision(query, passes, variant))),
        )?;
        let (_, stages) = time_stages(&mut staged, poses, args.warmup, args.frames)?;
        let stage_ms = stages.map(|t| t.post_process_ms);
        let mut a = avatar(
            scene,
            network,
            options(par, Some(collision(query, passes, variant))),
        )?;
        let Collisions {
            inside,
            near,
            differing,
            ..
        } = collisions(&mut a, poses, args.frames, Some(&reference), false)?;
        progress.println(&format!(
            "  post-process {name}: {ms:.3} ms/frame ({:.3} ms pp, {:.3} ms the stage), inside \
             after {inside}, within margin {near}, differing from the BVH {differing}",
            ms - base,
            stage_ms.unwrap_or(f64::NAN)
        ));
        results.push(QueryResult {
            query: name,
            cpu_ms_per_frame_pp: ms,
            cpu_ms_post_process: ms - base,
            cpu_ms_post_process_stage: stage_ms,
            mean_candidates_per_vertex: a.mean_candidates().unwrap_or(0.0),
            inside_after: inside,
            within_margin_after: near,
            differing_from_bvh: differing,
        });
    }
    let n = poses.len().min(args.frames);
    Ok(PostProcess {
        triangles: scene.binding.faces().len(),
        frames: n,
        vertex_frames: n * scene.binding.n_vertices(),
        inside_before,
        within_margin_before: near_before,
        queries: results,
        default_query: format!("{:?}", CollisionOptions::default().query),
    })
}

/// What [`collisions`] counts over a run of frames.
struct Collisions {
    /// Vertex-frames inside the body, and within the margin less 0.01 mm.
    inside: usize,
    near: usize,
    /// Vertex-frames more than 1 µm from the reference's garment of the same frame.
    differing: usize,
    /// The garment of each frame (when kept).
    garments: Vec<Vec<Vector3<f32>>>,
}

/// Over the first `frames` frames of `poses`: the vertex-frames inside the body and within the
/// margin after `a`'s post-process (before it, for one of 0 passes), those more than 1 µm from
/// `reference`'s garment of the same frame (0 without one), and (`keep`) each frame's garment.
fn collisions(
    a: &mut GarmentAnimator,
    poses: &[Pose],
    frames: usize,
    reference: Option<&[Vec<Vector3<f32>>]>,
    keep: bool,
) -> Result<Collisions> {
    let mut out = Collisions {
        inside: 0,
        near: 0,
        differing: 0,
        garments: Vec::new(),
    };
    for (t, pose) in poses.iter().take(frames).enumerate() {
        let got = a.frame(pose)?;
        if let Some(want) = reference.and_then(|r| r.get(t)) {
            out.differing += got
                .iter()
                .zip(want)
                .filter(|(p, q)| (*p - *q).norm() > 1e-6)
                .count();
        }
        if keep {
            out.garments.push(got.to_vec());
        }
        let c = a.collision_count(1e-5).context("post-process on")?;
        out.inside += c.inside;
        out.near += c.within_margin;
    }
    Ok(out)
}

/// The default post-process of the trained model in `model_dir` on its own garment, on each of
/// `motions` ([`TrainedPostProcess`]): int8, one thread, the nominal shape.
fn trained_post_process(
    model_dir: &Path,
    body_dir: &Path,
    motions: &[(String, Vec<Pose>)],
    args: &RuntimeBenchOptions,
    progress: &dyn Progress,
) -> Result<Vec<TrainedPostProcess>> {
    let assets = crate::eval::Assets::load(body_dir, model_dir)?;
    let network = assets.network(NetworkOptions {
        precision: Precision::Int8,
        output_rank: None,
    })?;
    let sizes = network.header().sizes;
    let betas = vec![0.0f32; network.n_betas()];
    let par = Parallelism::Sequential;
    let with = |collision| -> Result<GarmentAnimator> {
        let mut a = GarmentAnimator::new(assets.rig(&network, options(par, collision))?)?;
        a.set_shape(&betas)?;
        Ok(a)
    };
    let exact = CollisionOptions {
        query: CollisionQuery::EXACT_BVH,
        ..CollisionOptions::default()
    };
    let detect_only = CollisionOptions { passes: 0, ..exact };
    let mut out = Vec::new();
    for (motion, poses) in motions {
        let frames = poses.len().min(args.frames);
        let plain = time_frames(&mut with(None)?, poses, args.warmup, args.frames)?;
        let pp = time_frames(
            &mut with(Some(CollisionOptions::default()))?,
            poses,
            args.warmup,
            args.frames,
        )?;
        let stage = |collision| -> Result<Option<f64>> {
            let (_, t) = time_stages(&mut with(Some(collision))?, poses, args.warmup, args.frames)?;
            Ok(t.map(|t| t.post_process_ms))
        };
        let (stage_ms, stage_bvh_ms) = (stage(CollisionOptions::default())?, stage(exact)?);
        // What the certified query did, frame by frame, from the motion's start.
        let mut a = with(Some(CollisionOptions::default()))?;
        let (mut certified, mut swept, mut answered, mut pushed) = (0, 0, 0, 0);
        for pose in poses.iter().take(frames) {
            a.frame(pose)?;
            let c = a.certify_stats().unwrap_or_default();
            (certified, swept, answered) =
                (certified + c.certified, swept + c.swept, answered + c.exact);
            pushed += a.last_frame_pushed();
        }
        let before = collisions(&mut with(Some(detect_only))?, poses, frames, None, false)?;
        let bvh = collisions(&mut with(Some(exact))?, poses, frames, None, true)?;
        let after = collisions(
            &mut with(Some(CollisionOptions::default()))?,
            poses,
            frames,
            Some(&bvh.garments),
            false,
        )?;
        let per_frame = |n: usize| n as f64 / frames.max(1) as f64;
        let result = TrainedPostProcess {
            model: model_dir.display().to_string(),
            triangles: assets.binding.faces().len(),
            vertices: assets.binding.n_vertices(),
            gru_hidden: sizes.gru_hidden,
            output: match sizes.output {
                OutputKind::Dense => "dense".into(),
                OutputKind::Pca(k) => format!("pca {k}"),
            },
            motion: motion.clone(),
            frames,
            ms_per_frame: median(&plain.wall_ms),
            ms_per_frame_pp: median(&pp.wall_ms),
            cpu_ms_post_process_stage: stage_ms,
            cpu_ms_post_process_stage_bvh: stage_bvh_ms,
            certified_per_frame: per_frame(certified),
            swept_per_frame: per_frame(swept),
            exact_per_frame: per_frame(answered),
            pushed_per_frame: per_frame(pushed),
            inside_before: before.inside,
            within_margin_before: before.near,
            inside_after: after.inside,
            within_margin_after: after.near,
            inside_after_bvh: bvh.inside,
            within_margin_after_bvh: bvh.near,
            differing_from_bvh: after.differing,
        };
        progress.println(&format!(
            "  trained {} ({} triangles) on {motion}: {:.3} / {:.3} ms/frame, post-process \
             stage {:.3} ms (BVH {:.3}), {:.0} vertices answered exactly and {:.0} pushes per \
             frame, inside {} → {} (BVH {}), differing from the BVH {}",
            result.model,
            result.triangles,
            result.ms_per_frame,
            result.ms_per_frame_pp,
            stage_ms.unwrap_or(f64::NAN),
            stage_bvh_ms.unwrap_or(f64::NAN),
            result.exact_per_frame,
            result.pushed_per_frame,
            result.inside_before,
            result.inside_after,
            result.inside_after_bvh,
            result.differing_from_bvh
        ));
        out.push(result);
    }
    Ok(out)
}

/// Crowds of [`CROWD_AVATARS`] avatars of one network, on one thread and on all, without and
/// with the default post-process. Every avatar has the template shape (the random fit does not
/// follow shape, see [`BETAS`]) and its own phase of the clip, evenly spread, so the
/// post-process meets different poses. A crowd of `n` times `1/n` of the run's frames (at
/// least [`CROWD_MIN_FRAMES`]), so each size times about as many avatar frames.
fn crowd(
    scene: &Scene,
    network: &Arc<GarmentNetwork>,
    poses: &[Pose],
    args: &RuntimeBenchOptions,
    progress: &dyn Progress,
) -> Result<Vec<CrowdRun>> {
    let threads_all = rayon::current_num_threads();
    let mut out: Vec<CrowdRun> = Vec::new();
    for (par, threads) in [
        (Parallelism::Sequential, 1),
        (Parallelism::Rayon, threads_all),
    ] {
        let mut alone = None;
        for n in CROWD_AVATARS {
            let frames = (args.frames / n).max(CROWD_MIN_FRAMES);
            let warmup = (args.warmup / n).max(CROWD_MIN_FRAMES / 6);
            // Per frame of the clip, every avatar's pose (made before the timing).
            let sets: Vec<Vec<Pose>> = (0..poses.len())
                .map(|t| {
                    (0..n)
                        .map(|i| poses[(t + i * poses.len() / n) % poses.len()].clone())
                        .collect()
                })
                .collect();
            let mut ms = [0.0; 2];
            for (k, collision) in [None, Some(CollisionOptions::default())]
                .into_iter()
                .enumerate()
            {
                let rig = GarmentRig::new(
                    network.clone(),
                    scene.binding.clone(),
                    scene.body.clone(),
                    options(par, collision),
                )?;
                let mut crowd = GarmentCrowd::new(Arc::new(rig), n)?;
                for i in 0..n {
                    crowd.set_shape(i, &BETAS)?;
                }
                let frame = |c: &mut GarmentCrowd, t: usize| Ok(c.frame(&sets[t % sets.len()])?);
                let timing = time_calls(&mut crowd, warmup, frames, frame, |_| {})?;
                ms[k] = median(&timing.wall_ms);
            }
            let per = [ms[0] / n as f64, ms[1] / n as f64];
            let one = *alone.get_or_insert(ms);
            let run = CrowdRun {
                triangles: scene.binding.faces().len(),
                precision: network.precision().name(),
                avatars: n,
                threads,
                frames,
                ms_per_frame: ms[0],
                ms_per_frame_pp: ms[1],
                ms_per_avatar: per[0],
                ms_per_avatar_pp: per[1],
                gain_per_avatar: one[0] / per[0],
                gain_per_avatar_pp: one[1] / per[1],
                avatars_per_60hz_frame_pp: (1e3 / 60.0) / per[1],
            };
            progress.println(&format!(
                "  crowd {:>4} {threads} thread(s) {n:>2} avatars: {:7.3} ms/frame, {:7.3} with \
                 post-process ({:.3} / {:.3} per avatar, {:.2}× / {:.2}× a lone avatar's)",
                run.precision,
                run.ms_per_frame,
                run.ms_per_frame_pp,
                run.ms_per_avatar,
                run.ms_per_avatar_pp,
                run.gain_per_avatar,
                run.gain_per_avatar_pp
            ));
            out.push(run);
        }
    }
    Ok(out)
}

/// Reduced models at one garment size, int8, one thread.
fn reduced(
    scene: &Scene,
    poses: &[Pose],
    args: &RuntimeBenchOptions,
    progress: &dyn Progress,
) -> Result<Vec<Reduced>> {
    let mut out = Vec::new();
    let variants = [
        ("gru256-pca64", 256, OutputKind::Pca(64), None),
        ("gru256-dense-rank64", 256, OutputKind::Dense, Some(64)),
        (
            "gru1500-dense-rank64",
            args.gru_hidden,
            OutputKind::Dense,
            Some(64),
        ),
    ];
    for (name, hidden, output, rank) in variants {
        let m = model(
            &scene.garment_id,
            &scene.body_id,
            &scene.positions,
            hidden,
            output,
            11,
        )?;
        let start = Instant::now();
        let network = Arc::new(GarmentNetwork::with_options(
            m,
            NetworkOptions {
                precision: Precision::Int8,
                output_rank: rank,
            },
        )?);
        let load_s = start.elapsed().as_secs_f64();
        let par = Parallelism::Sequential;
        let mut plain = avatar(scene, &network, options(par, None))?;
        let mut pp = avatar(
            scene,
            &network,
            options(par, Some(CollisionOptions::default())),
        )?;
        let t = time_frames(&mut plain, poses, args.warmup, args.frames)?;
        let t_pp = time_frames(&mut pp, poses, args.warmup, args.frames)?;
        let (ms, ms_pp) = (median(&t.wall_ms), median(&t_pp.wall_ms));
        let (cpu, cpu_pp) = (t.cpu_ms, t_pp.cpu_ms);
        progress.println(&format!(
            "  reduced {name} int8: {ms:.3} ms/frame, {ms_pp:.3} with post-process (CPU {:.3} / \
             {:.3}; load {load_s:.2} s)",
            cpu.unwrap_or(f64::NAN),
            cpu_pp.unwrap_or(f64::NAN)
        ));
        out.push(Reduced {
            name: name.into(),
            triangles: scene.binding.faces().len(),
            gru_hidden: hidden,
            output: match (output, rank) {
                (OutputKind::Pca(k), _) => format!("pca {k}"),
                (OutputKind::Dense, Some(r)) => format!("dense, truncated SVD rank {r}"),
                (OutputKind::Dense, None) => "dense".into(),
            },
            precision: "int8",
            threads: 1,
            ms_per_frame: ms,
            ms_per_frame_pp: ms_pp,
            cpu_ms_per_frame: cpu,
            cpu_ms_per_frame_pp: cpu_pp,
            wrinkle_mb: network.wrinkle_weight_bytes() as f64 / 1e6,
            load_s,
        });
    }
    Ok(out)
}

/// Run the benchmark on the body in `body_dir` (see the module docs).
pub fn bench_runtime(
    args: &RuntimeBenchOptions,
    body_dir: &Path,
    dirs: &GarmentDirs,
    progress: &dyn Progress,
) -> Result<RuntimeBenchReport> {
    let start = Instant::now();
    // Fail before minutes of timing when the anchors' Python packages are missing.
    let anchor_versions = match &args.anchors {
        Some(a) => Some(check_anchors(a)?),
        None => None,
    };
    let load_average_start = load_average();
    let body = Arc::new(BodyModel::load(body_dir)?);
    let body_id = AssetId {
        id: body.name().to_string(),
        sha256: sha256_hex(&read_file(&body_dir.join(MODEL_HEADER))?),
    };
    let motion = sartor_motion::procedural::clip(&args.clip)?;
    let poses = motion.frames().to_vec();
    let mut garments = Vec::new();
    let mut post = None;
    let mut reduced_models = Vec::new();
    let mut crowds = Vec::new();
    let mut model_sizes = None;
    let mut paper_model = None;
    for &triangles in &args.triangles {
        let t = Instant::now();
        let scene = scene(triangles, &body, &body_id, dirs, progress)?;
        let m = model(
            &scene.garment_id,
            &scene.body_id,
            &scene.positions,
            args.gru_hidden,
            OutputKind::Dense,
            7,
        )?;
        model_sizes = Some(m.header().sizes);
        if args.anchors.is_some() && triangles == ANCHOR_PAPER_TRIANGLES {
            paper_model = Some(m.clone());
        }
        progress.println(&format!(
            "tshirt-{triangles}: {} vertices, {} region faces (set up in {:.1} s)",
            scene.positions.len(),
            scene.binding.region_faces().len(),
            t.elapsed().as_secs_f64()
        ));
        let paper = PAPER.iter().find(|p| p.0 == triangles).map(|p| (p.1, p.2));
        let mut memory = Vec::new();
        let mut runs_all = Vec::new();
        for precision in PRECISIONS {
            let network = Arc::new(GarmentNetwork::new(m.clone(), precision)?);
            memory.push(Memory {
                precision: precision.name(),
                fit_mb: network.fit_weight_bytes() as f64 / 1e6,
                wrinkle_mb: network.wrinkle_weight_bytes() as f64 / 1e6,
            });
            runs_all.extend(runs(&scene, &network, &poses, args, paper, progress)?);
            if triangles == args.reference_triangles && precision == Precision::Int8 {
                post = Some(post_process(&scene, &network, &poses, args, progress)?);
            }
            if triangles == args.reference_triangles && precision != Precision::F16 {
                crowds.extend(crowd(&scene, &network, &poses, args, progress)?);
            }
        }
        if triangles == args.reference_triangles {
            reduced_models = reduced(&scene, &poses, args, progress)?;
        }
        let region = sartor_runtime::BodyRegion::new(&body, scene.binding.region_faces())?;
        garments.push(GarmentResult {
            triangles: scene.binding.faces().len(),
            vertices: scene.positions.len(),
            source: scene.source.clone(),
            region_faces: region.faces().len(),
            region_vertices: region.vertices().len(),
            paper: paper.map(|(a, b)| Paper {
                ms_per_frame: a,
                ms_per_frame_pp: b,
                device: "NVIDIA Titan X + Intel i7 (Santesteban et al. 2019, Table 1)",
            }),
            memory,
            runs: runs_all,
        });
    }
    let mut trained = Vec::new();
    if !args.trained_models.is_empty() {
        let mut motions = vec![(args.clip.clone(), poses.clone())];
        motions.extend(args.trained_motions.iter().cloned());
        for model_dir in &args.trained_models {
            trained.extend(trained_post_process(
                model_dir, body_dir, &motions, args, progress,
            )?);
        }
    }
    let anchors_report = match (&args.anchors, anchor_versions) {
        (Some(options), Some(versions)) => {
            let paper = match paper_model {
                Some(m) => m,
                None => {
                    let scene = scene(ANCHOR_PAPER_TRIANGLES, &body, &body_id, dirs, progress)?;
                    model(
                        &scene.garment_id,
                        &scene.body_id,
                        &scene.positions,
                        args.gru_hidden,
                        OutputKind::Dense,
                        7,
                    )?
                }
            };
            let shipped = GarmentModel::load(&options.shipped_model)?;
            let models = vec![
                AnchorModel {
                    name: "shipped",
                    source: options.shipped_model.display().to_string(),
                    model: shipped,
                },
                AnchorModel {
                    name: "paper",
                    source: format!(
                        "this benchmark's model at {ANCHOR_PAPER_TRIANGLES} triangles (random \
                         weights, GRU {}, dense output)",
                        args.gru_hidden
                    ),
                    model: paper,
                },
            ];
            Some(anchors(models, options, versions, progress)?)
        }
        _ => None,
    };
    let report = RuntimeBenchReport {
        command: std::env::args().collect::<Vec<_>>().join(" "),
        machine: Machine::current(),
        instruction_set: instruction_set(),
        threads_all: rayon::current_num_threads(),
        load_average_start,
        load_average_end: load_average(),
        clip: args.clip.clone(),
        warmup_frames: args.warmup,
        timed_frames: args.frames,
        model: model_sizes.context("no garment size given")?,
        garments,
        post_process: post,
        reduced: reduced_models,
        crowd: crowds,
        trained,
        anchors: anchors_report,
        notes: vec![
            "ms_per_frame is the median over the timed frames of one avatar's whole frame: pose \
             features, GRU step and output layer, T̄_c + Δ_G + Δ_L, skinning with W_c, and (for \
             ms_per_frame_pp) posing the body region and the collision post-process (2 mm \
             margin, default query and passes).",
            "Weights are random (timing only). memory is in MB of 10^6 bytes; wrinkle_mb is \
             the GRU plus the output layer (the paper's 'GRU' figure).",
            "The paper's figures are on an NVIDIA Titan X GPU; ours on the CPU listed.",
            "crowd: GarmentCrowd::frame over every avatar, the network step batched (one pass \
             over the weights for all), each avatar's skinning and post-process its own; \
             ms_per_frame is the whole crowd's median.",
        ],
        wall_time_s: start.elapsed().as_secs_f64(),
    };
    Ok(report)
}
