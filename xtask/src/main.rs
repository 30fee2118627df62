//! `cargo xtask <command>`: sartor's command line. Each subcommand parses its arguments, calls
//! one library function and prints or writes a report.

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "xtask", about = "sartor: learning-based garment animation")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {}
}
