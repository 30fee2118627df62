//! `cargo xtask bench <target>`: benchmarks that write JSON reports.
//!
//! - `sim`: the cloth simulator driven by the walk, per garment size → `bench-sim.json`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, Subcommand};
use sartor_cloth::{
    DriveConfig, Garment, GarmentConfig, LinearSolver, Material, RelaxConfig, SequenceBenchmark,
    benchmark_sequence, build_garment, relax_on_body,
};
use sartor_core::io::{read_file, write_atomic};
use sartor_core::{BodyModel, Par};
use sartor_motion::{Motion, MotionSourceOptions, load_motion};
use serde::Serialize;

use crate::machine::{Machine, load_average};
use crate::{workspace_relative, workspace_root};

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
    Runtime(crate::bench_runtime::BenchRuntimeArgs),
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
    /// Linear solver of the implicit step: block-Jacobi CG (1,000 iterations at most, relative
    /// tolerance 1e-5, as `configs/default.json`) or faer's sparse Cholesky.
    #[arg(long, value_enum, default_value_t = Solver::Cg)]
    pub solver: Solver,
}

/// The linear solvers `bench sim` can time.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Solver {
    /// Block-Jacobi preconditioned conjugate gradients.
    Cg,
    /// Sparse Cholesky (symbolic analysis reused).
    Cholesky,
}

impl Solver {
    fn linear_solver(self) -> LinearSolver {
        match self {
            Self::Cg => LinearSolver::ConjugateGradient {
                max_iterations: 1000,
                relative_tolerance: 1e-5,
                fallback_to_cholesky: true,
            },
            Self::Cholesky => LinearSolver::Cholesky,
        }
    }
}

#[derive(Serialize)]
struct SizeEntry {
    garment: String,
    garment_source: String,
    triangles: usize,
    vertices: usize,
    /// One thread (the driver's default, `Par::Seq`).
    ms_per_frame: f64,
    /// Rayon's pool over all cores.
    ms_per_frame_all_threads: Option<f64>,
    single_thread: SequenceBenchmark,
    all_threads: Option<SequenceBenchmark>,
}

#[derive(Serialize)]
struct SimBenchReport {
    solver: Solver,
    motion: String,
    motion_frames: std::ops::Range<usize>,
    blend_frames: usize,
    rest_frames: usize,
    drive_config_sha256: String,
    machine: Machine,
    load_average_before: Option<[f64; 3]>,
    load_average_after: Option<[f64; 3]>,
    wall_time_s: f64,
    sizes: Vec<SizeEntry>,
}

/// Run a benchmark.
pub fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    match &args.target {
        BenchTarget::Sim(a) => bench_sim(a),
        BenchTarget::Runtime(a) => crate::bench_runtime::bench_runtime(a),
    }
}

fn bench_sim(args: &SimBenchArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let load_average_before = load_average();
    let body = sartor_core::BodyModel::load(&crate::builtin_model_dir())?;
    let material = Material::gray_interlock();
    let motion = load_walk(args)?;
    let mut config = DriveConfig {
        blend_frames: args.blend_frames,
        rest_frames: args.rest_frames,
        ..DriveConfig::default()
    };
    config.sim.linear_solver = args.solver.linear_solver();
    let mut sizes = Vec::new();
    for &n in &args.sizes {
        let (garment, source) = garment_of_size(n, &body, &material, args)?;
        println!(
            "{}: {} triangles, {} vertices ({source})",
            garment.name(),
            garment.faces().len(),
            garment.positions().len()
        );
        let single = benchmark_sequence(&body, &garment, &material, &motion, &config)
            .with_context(|| format!("simulating {}", garment.name()))?;
        println!("  one thread:  {:.1} ms/frame", single.ms_per_frame);
        let all = if args.single_thread_only {
            None
        } else {
            let mut parallel = config.clone();
            parallel.sim.parallelism = Par::Rayon;
            let all = benchmark_sequence(&body, &garment, &material, &motion, &parallel)
                .with_context(|| format!("simulating {} on all threads", garment.name()))?;
            println!("  all threads: {:.1} ms/frame", all.ms_per_frame);
            Some(all)
        };
        sizes.push(SizeEntry {
            garment: garment.name().to_string(),
            garment_source: source,
            triangles: garment.faces().len(),
            vertices: garment.positions().len(),
            ms_per_frame: single.ms_per_frame,
            ms_per_frame_all_threads: all.as_ref().map(|a| a.ms_per_frame),
            single_thread: single,
            all_threads: all,
        });
    }
    let report = SimBenchReport {
        solver: args.solver,
        motion: motion.name().to_string(),
        motion_frames: args.start_frame..args.start_frame + motion.n_frames(),
        blend_frames: args.blend_frames,
        rest_frames: args.rest_frames,
        drive_config_sha256: config.sha256()?,
        machine: Machine::current(),
        load_average_before,
        load_average_after: load_average(),
        wall_time_s: started.elapsed().as_secs_f64(),
        sizes,
    };
    let mut json = serde_json::to_string_pretty(&report)?;
    json.push('\n');
    write_atomic(&args.out, json.as_bytes())?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The benchmark's motion: `args.frames` frames from `args.start_frame`.
fn load_walk(args: &SimBenchArgs) -> anyhow::Result<Motion> {
    let options = MotionSourceOptions {
        motions_dir: workspace_root().join("datasets/motions"),
        ..MotionSourceOptions::default()
    };
    let motion = load_motion(&args.motion, &options)?;
    let end = args.start_frame + args.frames;
    anyhow::ensure!(
        end <= motion.n_frames(),
        "{} has {} frames, {end} asked for",
        args.motion,
        motion.n_frames()
    );
    Ok(motion.slice(args.start_frame..end)?)
}

/// The T-shirt of `n` triangles and where it came from.
fn garment_of_size(
    n: usize,
    body: &BodyModel,
    material: &Material,
    args: &SimBenchArgs,
) -> anyhow::Result<(Garment, String)> {
    let name = format!("tshirt-{n}");
    let committed = workspace_root().join("datasets/garments").join(&name);
    let suffix = if args.no_relax { "-unrelaxed" } else { "" };
    let cached = args.garment_cache.join(format!("{name}{suffix}"));
    for dir in [&committed, &cached] {
        if dir.join(sartor_cloth::GARMENT_HEADER).exists() {
            let g = Garment::load(dir)?;
            return Ok((g, workspace_relative(dir)));
        }
    }
    let config_path = workspace_root()
        .join("configs/garments")
        .join(format!("{name}.json"));
    let bytes = read_file(&config_path)?;
    let config = GarmentConfig::from_json(&bytes, &config_path)?;
    println!("building {name} from {}", config_path.display());
    let garment = build_garment(&config, &config_path, &bytes, body, None)?.garment;
    let garment = if args.no_relax {
        garment
    } else {
        relax_on_body(&garment, body, material, &RelaxConfig::default())?.0
    };
    garment.save(&cached)?;
    Ok((
        garment,
        format!("built into {}", workspace_relative(&cached)),
    ))
}
