//! `bench`: the benchmarks that write JSON reports (`bench sim` → `bench-sim.json`,
//! `bench runtime` → `bench-runtime.json`; see sartor-eval).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use sartor_cloth::{
    FrictionModel, IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M, IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME,
};
use sartor_core::BodyModel;
use sartor_eval::{
    AnchorOptions, GarmentDirs, RuntimeBenchOptions, SimBenchOptions, Solver, bench_runtime,
    bench_sim, write_json,
};
use sartor_motion::{ArmClearance, ClearanceOptions, UpAxis, load_motion};

use crate::Env;
use crate::progress::Bar;

/// Arguments of `bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// What to benchmark.
    #[command(subcommand)]
    pub target: BenchTarget,
}

/// The benchmarks.
#[derive(Subcommand, Debug)]
pub enum BenchTarget {
    /// Milliseconds per frame of the cloth simulator on a walk, per garment size.
    Sim(SimBenchArgs),
    /// Milliseconds per frame of the runtime against the paper's Table 1, per garment size.
    Runtime(RuntimeBenchArgs),
}

/// The linear solvers `bench sim` can time.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum SolverArg {
    /// Block-Jacobi preconditioned conjugate gradients (1,000 iterations at most, relative
    /// tolerance 1e-5, as `configs/default.json`).
    Cg,
    /// faer's sparse Cholesky (symbolic analysis reused).
    Cholesky,
}

/// How friction enters the substep ([`FrictionModel`]).
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum FrictionArg {
    /// ARCSim's damper in the solve.
    Implicit,
    /// A Coulomb impulse after the solve.
    Impulse,
}

/// Arguments of `bench sim`.
#[derive(Args, Debug)]
pub struct SimBenchArgs {
    /// Output JSON.
    #[arg(long, default_value = "bench-sim.json")]
    pub out: PathBuf,
    /// Garment sizes (triangles): `datasets/garments/tshirt-<n>` if present, else built from
    /// `configs/garments/tshirt-<n>.json`, relaxed, and kept in `--garment-cache`.
    #[arg(long, value_delimiter = ',', default_value = "4210,8710,17710,26066")]
    pub sizes: Vec<usize>,
    /// Motion frames timed (at least 30 for the figure).
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// The motion (`walk`: the imported MakeHuman walk; or any `load_motion` spec).
    #[arg(long, default_value = "walk")]
    pub motion: String,
    /// First motion frame used.
    #[arg(long, default_value_t = 0)]
    pub start_frame: usize,
    /// Blend frames before the motion (simulated, not timed).
    #[arg(long, default_value_t = 10)]
    pub blend_frames: usize,
    /// Rest frames before the motion (simulated, not timed).
    #[arg(long, default_value_t = 5)]
    pub rest_frames: usize,
    /// Skip the run on all threads (rayon).
    #[arg(long)]
    pub single_thread_only: bool,
    /// Do not relax garments built for the benchmark (faster; the cloth then starts off its
    /// equilibrium).
    #[arg(long)]
    pub no_relax: bool,
    /// Where garments built for the benchmark are kept between runs.
    #[arg(long, default_value = "target/bench-garments")]
    pub garment_cache: PathBuf,
    /// Linear solver of the implicit step.
    #[arg(long, value_enum, default_value_t = SolverArg::Cg)]
    pub solver: SolverArg,
    /// How friction enters the substep: `implicit` (ARCSim's damper in the solve) or
    /// `impulse` (after the solve only, as the shipped reference configs; their steps are
    /// `--max-step-per-edge-s-per-m 0.066 --substeps 10`).
    #[arg(long, value_enum, default_value_t = FrictionArg::Implicit)]
    pub friction: FrictionArg,
    /// The fewest substeps per frame.
    #[arg(long, default_value_t = IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME)]
    pub substeps: usize,
    /// The longest substep, seconds per metre of the garment's median rest edge: the
    /// substeps per frame rise with the resolution so that every size stays stable (20, 20,
    /// 28 and 34 at 4,210, 8,710, 17,710 and 26,066 triangles with the other defaults). 0:
    /// `--substeps` at every size.
    #[arg(long, default_value_t = IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M)]
    pub max_step_per_edge_s_per_m: f64,
    /// Hold the arms out of the torso as the reference configs do (`arm_clearance` with
    /// `upper_arm_clearance_m` 5 mm): for retargeted motion capture.
    #[arg(long)]
    pub arm_clearance: bool,
    /// Write a picture of each size's last frame (one thread), front and back, into this
    /// folder (`tshirt-<n>.png`): a benchmark of a crumpled cloth times the wrong thing.
    #[arg(long)]
    pub pictures: Option<PathBuf>,
}

/// Arguments of `bench runtime`.
#[derive(Args, Debug)]
pub struct RuntimeBenchArgs {
    /// Output file.
    #[arg(long, default_value = "bench-runtime.json")]
    pub out: PathBuf,
    /// Garment sizes (triangles) to run; each needs `configs/garments/tshirt-<n>.json` or
    /// `datasets/garments/tshirt-<n>`.
    #[arg(long, value_delimiter = ',', default_values_t = [4210usize, 8710, 17710, 26066])]
    pub triangles: Vec<usize>,
    /// Procedural clip to animate.
    #[arg(long, default_value = "walk_normal")]
    pub clip: String,
    /// Frames run before timing (GRU state and caches warm up).
    #[arg(long, default_value_t = 20)]
    pub warmup: usize,
    /// Frames timed per configuration.
    #[arg(long, default_value_t = 120)]
    pub frames: usize,
    /// GRU hidden size of the paper-size model.
    #[arg(long, default_value_t = 1500)]
    pub gru_hidden: usize,
    /// Garment size (triangles) of the post-process comparison and the reduced models.
    #[arg(long, default_value_t = 8710)]
    pub reference_triangles: usize,
    /// Where garments built for the benchmark are kept between runs.
    #[arg(long, default_value = "target/bench-garments")]
    pub garment_cache: PathBuf,
    /// Also time the shipped model and the paper-size model (8,710 triangles) in PyTorch
    /// (eager and compiled) and ONNX Runtime with `--anchors-script`, batch 1, on 1 and 2
    /// threads, against a memory-bandwidth floor measured in the same run; adds `anchors` to
    /// the report. Needs Python with torch, onnx, onnxruntime, numpy and safetensors (see the
    /// README); fails, saying how to install them, when they are missing.
    #[arg(long)]
    pub anchors: bool,
    /// Python for the anchors [default: $SARTOR_PYTHON, else python3].
    #[arg(long)]
    pub anchors_python: Option<PathBuf>,
    /// The anchors script (relative paths: in the data folder).
    #[arg(long, default_value = "bench/anchors.py")]
    pub anchors_script: PathBuf,
    /// The shipped-size model the anchors time [default: the data folder's shipped model].
    #[arg(long)]
    pub anchors_model: Option<PathBuf>,
    /// Frames before timing, for every anchor and sartor's network step.
    #[arg(long, default_value_t = 50)]
    pub anchors_warmup: usize,
    /// Frames timed, for every anchor and sartor's network step, per round.
    #[arg(long, default_value_t = 500)]
    pub anchors_frames: usize,
    /// Rounds of the anchors' comparison: in each, sartor, the floor and every anchor are
    /// timed seconds apart, and the report's ratios are medians over the rounds of the ratios
    /// within a round (a machine whose speed drifts over minutes then tilts them less).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub anchors_rounds: u64,
    /// Trained exported models whose post-process is timed on their own garment, on the clip
    /// and on `--trained-motion`s (`trained` in the report) [default: the data folder's shipped
    /// models, `datasets/models/*`]: its cost follows how much cloth lies within the margin,
    /// which random weights do not reproduce.
    #[arg(long = "trained-model")]
    pub trained_models: Vec<PathBuf>,
    /// Motions the trained models are timed on besides the clip (stored motion capture is
    /// retargeted onto the body and its arms held out of the torso as the reference configs
    /// do) [default: the default experiment's four held-out CMU clips].
    #[arg(long = "trained-motion")]
    pub trained_motions: Vec<String>,
    /// Skip the trained models.
    #[arg(long, conflicts_with_all = ["trained_models", "trained_motions"])]
    pub no_trained: bool,
}

/// The default experiment's held-out CMU clips (`configs/default.json`), which
/// `bench runtime` times the trained models on.
const HELD_OUT_MOTIONS: [&str; 4] = [
    "cmu/02_02@8+60",
    "cmu/05_10@72+60",
    "cmu/06_06@20+60",
    "cmu/09_05",
];

/// Environment variable naming the anchors' Python (`--anchors-python` overrides it).
pub const PYTHON_ENV: &str = "SARTOR_PYTHON";

impl RuntimeBenchArgs {
    /// The anchors' options (`None` without `--anchors`).
    fn anchor_options(&self, env: &Env) -> Option<AnchorOptions> {
        self.anchors.then(|| AnchorOptions {
            python: self
                .anchors_python
                .clone()
                .or_else(|| std::env::var_os(PYTHON_ENV).map(PathBuf::from))
                .unwrap_or_else(|| PathBuf::from("python3")),
            script: env.data.resolve(&self.anchors_script),
            shipped_model: self
                .anchors_model
                .as_ref()
                .map_or_else(|| env.data.default_model_dir(), |m| env.data.resolve(m)),
            threads: vec![1, 2],
            warmup: self.anchors_warmup,
            frames: self.anchors_frames,
            rounds: usize::try_from(self.anchors_rounds).unwrap_or(1),
            check_frames: 60,
        })
    }
}

fn garment_dirs(env: &Env, cache: &Path) -> GarmentDirs {
    GarmentDirs {
        garments: env.data.garments_dir(),
        recipes: env.data.recipes_dir(),
        cache: env.data.resolve(cache),
    }
}

/// Motions by name.
type NamedMotions = Vec<(String, Vec<sartor_core::Pose>)>;

/// The trained models (`--trained-model`, else every shipped model) and the motions
/// (`--trained-motion`, else [`HELD_OUT_MOTIONS`]) of `bench runtime`'s `trained` section, each
/// motion retargeted onto the built-in body and its arms held out of the torso (5 mm, at the
/// nominal shape) as the reference configs hold them.
fn trained_inputs(a: &RuntimeBenchArgs, env: &Env) -> anyhow::Result<(Vec<PathBuf>, NamedMotions)> {
    let models = if a.trained_models.is_empty() {
        let dir = env.data.models_dir();
        env.data
            .shipped_model_dirs()
            .map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?
    } else {
        a.trained_models
            .iter()
            .map(|m| crate::in_data(&env.data, m))
            .collect()
    };
    let specs: Vec<String> = if a.trained_motions.is_empty() {
        HELD_OUT_MOTIONS.iter().map(|m| m.to_string()).collect()
    } else {
        a.trained_motions.clone()
    };
    // A folder that is no exported model fails here, before minutes of timing.
    for m in &models {
        sartor_eval::Assets::load(&env.data.body_dir(), m)?;
        sartor_runtime::GarmentModel::load(m)
            .with_context(|| format!("loading the trained model {}", m.display()))?;
    }
    let body = BodyModel::load(&env.data.body_dir())?;
    let clearance = ArmClearance::new(&body)?;
    let held = ClearanceOptions {
        upper_arm_clearance_m: Some(0.005),
        ..ClearanceOptions::default()
    };
    let options = crate::motion_options(&env.data, UpAxis::default())?;
    let betas = vec![0.0; body.n_betas()];
    let mut motions = Vec::new();
    for spec in specs {
        let motion = load_motion(&spec, &options)?;
        let (poses, _) = clearance
            .apply(&body, &betas, motion.frames(), &held)
            .map_err(|e| anyhow::anyhow!("{spec}: holding the arms out: {e}"))?;
        motions.push((spec, poses));
    }
    Ok((models, motions))
}

/// Run a benchmark.
pub fn bench_cmd(args: &BenchArgs, env: &Env) -> anyhow::Result<()> {
    let progress = Bar::new();
    let (out, report) = match &args.target {
        BenchTarget::Sim(a) => {
            // Stored motion capture (`cmu/02_04`) is retargeted onto the body, as `simulate`
            // does.
            let options = crate::motion_options(&env.data, UpAxis::default())?;
            let motion = load_motion(&a.motion, &options)?;
            let end = a.start_frame + a.frames;
            anyhow::ensure!(
                end <= motion.n_frames(),
                "{} has {} frames, {end} asked for",
                a.motion,
                motion.n_frames()
            );
            let options = SimBenchOptions {
                sizes: a.sizes.clone(),
                motion: motion.slice(a.start_frame..end)?,
                motion_frames: a.start_frame..end,
                blend_frames: a.blend_frames,
                rest_frames: a.rest_frames,
                single_thread_only: a.single_thread_only,
                no_relax: a.no_relax,
                pictures: a.pictures.clone(),
                arm_clearance: a.arm_clearance.then(|| ClearanceOptions {
                    upper_arm_clearance_m: Some(0.005),
                    ..ClearanceOptions::default()
                }),
                max_step_per_edge_s_per_m: (a.max_step_per_edge_s_per_m > 0.0)
                    .then_some(a.max_step_per_edge_s_per_m),
                substeps_per_frame: a.substeps,
                friction: match a.friction {
                    FrictionArg::Implicit => FrictionModel::Implicit,
                    FrictionArg::Impulse => FrictionModel::Impulse,
                },
                solver: match a.solver {
                    SolverArg::Cg => Solver::Cg,
                    SolverArg::Cholesky => Solver::Cholesky,
                },
            };
            let body = BodyModel::load(&env.data.body_dir())?;
            let dirs = garment_dirs(env, &a.garment_cache);
            let report = bench_sim(&options, &body, &dirs, &progress)?;
            (a.out.clone(), serde_json::to_value(&report)?)
        }
        BenchTarget::Runtime(a) => {
            let (trained_models, trained_motions) = if a.no_trained {
                (Vec::new(), Vec::new())
            } else {
                trained_inputs(a, env)?
            };
            let options = RuntimeBenchOptions {
                trained_models,
                trained_motions,
                triangles: a.triangles.clone(),
                clip: a.clip.clone(),
                warmup: a.warmup,
                frames: a.frames,
                gru_hidden: a.gru_hidden,
                reference_triangles: a.reference_triangles,
                anchors: a.anchor_options(env),
            };
            let dirs = garment_dirs(env, &a.garment_cache);
            let report = bench_runtime(&options, &env.data.body_dir(), &dirs, &progress)?;
            (a.out.clone(), serde_json::to_value(&report)?)
        }
    };
    write_json(&out, &report)?;
    println!("wrote {}", out.display());
    Ok(())
}
