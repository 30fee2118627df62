//! # sartor-cli
//!
//! The `sartor` command line: simulate, learn, evaluate and animate garments. Each command parses
//! its arguments, calls one library function (sartor-pipeline, sartor-eval, sartor-cloth, the
//! runtime), draws progress and prints a summary; the work is done in the libraries. The
//! developer's `cargo xtask` runs the same commands ([`Command`], [`run`]) with the repository as
//! the data folder.
//!
//! The data (`datasets/`, `configs/`) is found from `--data-dir`, `SARTOR_DATA_DIR` or the
//! binary's location ([`sartor_pipeline::DataDir::locate`]), never from where it was built.

use std::path::{Path, PathBuf};

use clap::Subcommand;
use sartor_motion::{MotionSourceOptions, RetargetBody, UpAxis};
use sartor_pipeline::DataDir;

mod bench;
mod body;
mod demo;
mod experiment;
mod garment;
mod progress;

pub use bench::{BenchArgs, BenchTarget, RuntimeBenchArgs, SimBenchArgs};
pub use body::BodyArgs;
pub use demo::{DEFAULT_MOTIONS, DEFAULT_PHENOTYPES, DemoArgs};
pub use experiment::{
    EvalArgs, ExperimentArgs, ExportArgs, PipelineArgs, SimulateArgs, TradeoffArgs, TrainArgs,
};
pub use garment::GarmentArgs;
pub use progress::{Bar, TrainBar, stop_flag};

/// Where a command finds its data and puts its runs.
#[derive(Clone, Debug)]
pub struct Env {
    /// The data folder.
    pub data: DataDir,
    /// Default folder of experiment runs (`--runs-dir` overrides it).
    pub runs_dir: PathBuf,
}

/// The commands of `sartor` (and of `cargo xtask`, which adds developer commands).
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Animate the shipped T-shirt model on a few bodies and clips: frames per second, glTF,
    /// MCAP (Foxglove) and PNG files.
    Demo(DemoArgs),
    /// Write the posed body as one OBJ per frame (shape by β or phenotype, any motion).
    Body(BodyArgs),
    /// Build a garment template (procedural T-shirt or user OBJ) into datasets/garments/<name>.
    Garment(GarmentArgs),
    /// Simulate every (shape, motion) pair of an experiment (resumable, shardable).
    Simulate(SimulateArgs),
    /// Build an experiment's training data from its simulations.
    Dataset(ExperimentArgs),
    /// Train the fit MLP, the wrinkle GRU and the linear baseline on an experiment's dataset
    /// (checkpoints every epoch and on Ctrl-C; --resume continues): train.json, loss plots.
    Train(TrainArgs),
    /// Export a run's trained models for the runtime (model + binding, no burn), with a
    /// preview animation (glTF, MCAP, OBJ).
    Export(ExportArgs),
    /// Judge the exported model and the baselines on held-out ground truth: eval.json, plots.
    Eval(EvalArgs),
    /// simulate → dataset → train → export → eval, end to end and resumable, with a summary.
    Pipeline(PipelineArgs),
    /// Sweep the runtime's speed knobs (output rank, precision, post-process and strain limit,
    /// fit-only, model size, garment resolution): error, collisions and stretch against ms per
    /// frame, tradeoff.json and a Pareto plot.
    Tradeoff(TradeoffArgs),
    /// Benchmarks that write JSON reports (`bench sim`: the cloth simulator per garment size;
    /// `bench runtime`: the runtime against the paper's Table 1).
    Bench(BenchArgs),
}

/// Run `command`.
pub fn run(command: &Command, env: &Env) -> anyhow::Result<()> {
    match command {
        Command::Demo(a) => demo::demo(a, &env.data),
        Command::Body(a) => body::body(a, &env.data),
        Command::Garment(a) => garment::garment(a, &env.data),
        Command::Simulate(a) => experiment::simulate_cmd(a, env),
        Command::Dataset(a) => experiment::dataset_cmd(a, env),
        Command::Train(a) => experiment::train_cmd(a, env),
        Command::Export(a) => experiment::export_cmd(a, env),
        Command::Eval(a) => experiment::eval_cmd(a, env),
        Command::Pipeline(a) => experiment::pipeline_cmd(a, env),
        Command::Tradeoff(a) => experiment::tradeoff_cmd(a, env),
        Command::Bench(a) => bench::bench_cmd(a, env),
    }
}

/// Where motions come from: imported ones in the data folder, mocap retargeted onto the
/// built-in body.
pub fn motion_options(data: &DataDir, up_axis: UpAxis) -> anyhow::Result<MotionSourceOptions> {
    Ok(MotionSourceOptions {
        motions_dir: data.motions_dir(),
        body: Some(RetargetBody::load(&data.body_dir())?),
        lenient: false,
        keep_tpose_frame: false,
        up_axis,
    })
}

/// `path` as given when it exists, else relative to the data folder (so `--config
/// configs/tiny.json` works from any directory).
pub fn in_data(data: &DataDir, path: &Path) -> PathBuf {
    if path.is_relative() && !path.exists() {
        data.resolve(path)
    } else {
        path.to_path_buf()
    }
}
