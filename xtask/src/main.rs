//! `cargo xtask <command>`: sartor's command line. Each subcommand parses its arguments, calls
//! one library function and prints or writes a report.

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};

mod animate;
mod bench;
mod bench_runtime;
mod body;
mod dataset;
mod demo;
mod eval;
mod experiment;
mod export;
mod garment;
mod import_body;
mod machine;
mod motions;
mod pipeline;
mod plot;
mod ship;
mod simulate;
mod tradeoff;
mod train;

#[derive(Parser)]
#[command(name = "xtask", about = "sartor: learning-based garment animation")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert the raw MakeHuman assets into datasets/body/makehuman (the built-in body).
    ImportBody(import_body::ImportBodyArgs),
    /// Write the posed body as one OBJ per frame (shape by β or phenotype, any motion).
    Body(body::BodyArgs),
    /// Import MakeHuman's walk cycle into datasets/motions/walk.json.
    ImportMotion(motions::ImportMotionArgs),
    /// Build a garment template (procedural T-shirt or user OBJ) into datasets/garments/<name>.
    Garment(garment::GarmentArgs),
    /// Benchmarks that write JSON reports (`bench sim`: the cloth simulator per garment size;
    /// `bench runtime`: the runtime against the paper's Table 1).
    Bench(bench::BenchArgs),
    /// Simulate every (shape, motion) pair of an experiment (resumable, shardable).
    Simulate(simulate::SimulateArgs),
    /// Build an experiment's training data from its simulations.
    Dataset(dataset::DatasetArgs),
    /// Animate the shipped T-shirt model on a few bodies and clips: frames per second, glTF,
    /// MCAP (Foxglove) and PNG files.
    Demo(demo::DemoArgs),
    /// Sweep the runtime's speed knobs (output rank, precision, post-process, fit-only, model
    /// size, garment resolution): error against ms per frame, tradeoff.json and a Pareto plot.
    Tradeoff(tradeoff::TradeoffArgs),
    /// Copy an experiment's export and eval.json into datasets/models/<name>, with a stored
    /// slice of held-out ground truth for the regression check.
    Ship(ship::ShipArgs),
    /// Recompute a shipped model's error on its stored slice; fail beyond 10 % of the record.
    CheckModel(ship::CheckModelArgs),
    /// Train the fit MLP, the wrinkle GRU and the linear baseline on an experiment's dataset
    /// (checkpoints every epoch and on Ctrl-C; --resume continues): train.json, loss plots.
    Train(train::TrainArgs),
    /// Export a run's trained models for the runtime (model + binding, no burn), with a
    /// preview animation (glTF, MCAP, OBJ).
    Export(export::ExportArgs),
    /// simulate → dataset → train → export → eval, end to end and resumable, with a summary.
    Pipeline(pipeline::PipelineArgs),
    /// Judge the exported model and the baselines on held-out ground truth: eval.json, plots.
    Eval(eval::EvalArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::ImportBody(args) => import_body::import_body(&args),
        Command::Body(args) => body::body(&args),
        Command::ImportMotion(args) => motions::import_motion(&args),
        Command::Garment(args) => garment::garment(&args),
        Command::Bench(args) => bench::bench(&args),
        Command::Simulate(args) => simulate::simulate(&args),
        Command::Dataset(args) => dataset::dataset(&args),
        Command::Eval(args) => eval::eval(&args),
        Command::Demo(args) => demo::demo(&args),
        Command::Tradeoff(args) => tradeoff::tradeoff(&args),
        Command::Ship(args) => ship::ship(&args),
        Command::Train(args) => train::train(&args),
        Command::Export(args) => export::export_run(&args),
        Command::Pipeline(args) => pipeline::pipeline(&args),
        Command::CheckModel(args) => ship::check_model(&args),
    }
}

/// The workspace root (this crate's parent folder).
pub(crate) fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The built-in body model folder, `<workspace>/datasets/body/makehuman`.
pub(crate) fn builtin_model_dir() -> PathBuf {
    workspace_root().join("datasets/body/makehuman")
}

/// `path` relative to the workspace root when it lies inside it (so reports do not depend on
/// where the checkout is), else as given.
pub(crate) fn workspace_relative(path: &Path) -> String {
    match (path.canonicalize(), workspace_root().canonicalize()) {
        (Ok(p), Ok(r)) => p.strip_prefix(&r).map_or_else(
            |_| path.display().to_string(),
            |rel| rel.display().to_string(),
        ),
        _ => path.display().to_string(),
    }
}
