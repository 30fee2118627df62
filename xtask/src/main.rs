//! `cargo xtask <command>`: sartor's command line. Each subcommand parses its arguments, calls
//! one library function and prints or writes a report.

use clap::{Parser, Subcommand};

mod bench_runtime;
mod body;
mod garment;
mod import_body;
mod motions;

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
    /// Benchmarks that write bench-<name>.json.
    Bench {
        /// Which benchmark.
        #[command(subcommand)]
        which: BenchCommand,
    },
}

/// The benchmarks of `cargo xtask bench`.
#[derive(Subcommand)]
enum BenchCommand {
    /// The runtime against the paper's Table 1 (bench-runtime.json).
    Runtime(bench_runtime::BenchRuntimeArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::ImportBody(args) => import_body::import_body(&args),
        Command::Body(args) => body::body(&args),
        Command::ImportMotion(args) => motions::import_motion(&args),
        Command::Garment(args) => garment::garment(&args),
        Command::Bench { which } => match which {
            BenchCommand::Runtime(args) => bench_runtime::bench_runtime(&args),
        },
    }
}
