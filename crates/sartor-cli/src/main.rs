//! `sartor`: learning-based garment animation from the command line. See `sartor --help`.

use std::path::PathBuf;

use clap::Parser;
use sartor_cli::{Command, Env, run};
use sartor_pipeline::{DATA_DIR_ENV, DataDir};

#[derive(Parser)]
#[command(
    name = "sartor",
    version,
    about = "sartor: animate garments on bodies of any shape and motion, learned from physics",
    after_help = "Data (the body model, motions, garments, the shipped model, configs) is found \
                  with --data-dir, the SARTOR_DATA_DIR environment variable, or beside the \
                  binary (a folder holding datasets/ and configs/, or <prefix>/share/sartor). \
                  Experiment runs go to ./runs unless --runs-dir says otherwise."
)]
struct Cli {
    /// The data folder (holding datasets/ and configs/).
    #[arg(long, global = true)]
    data_dir: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let exe = std::env::current_exe().ok();
    let data = DataDir::locate(
        cli.data_dir.as_deref(),
        std::env::var_os(DATA_DIR_ENV),
        exe.as_deref(),
    )?;
    let env = Env {
        data,
        runs_dir: PathBuf::from("runs"),
    };
    run(&cli.command, &env)
}
