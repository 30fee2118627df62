//! `cargo xtask <command>`: the developer's entry point. Every command of the `sartor` binary
//! (`sartor_cli::Command`), with the repository as the data folder and `runs/` inside it, plus
//! the developer's own: importing the raw assets once, shipping and checking the reference model.

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use sartor_cli::Env;
use sartor_pipeline::DataDir;

mod arm_clearance;
mod check_retarget;
mod gt_collisions;
mod import_body;
mod limits;
mod motions;
mod ship;
mod web;

#[derive(Parser)]
#[command(
    name = "xtask",
    about = "sartor's developer commands (and every `sartor` command)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert the raw MakeHuman assets into datasets/body/makehuman (the built-in body).
    ImportBody(import_body::ImportBodyArgs),
    /// Import MakeHuman's walk cycle into datasets/motions/walk.json.
    ImportMotion(motions::ImportMotionArgs),
    /// Import the CMU BVH clips (../shared/cmu) into datasets/motions/cmu: each file's own
    /// skeleton and channels at 30 fps, T-pose frame dropped, with CMU's acknowledgement and a
    /// provenance table (deterministic).
    ImportMotions(motions::ImportMotionsArgs),
    /// Retarget every BVH of a folder onto the built-in body and check every frame against the
    /// file's own forward kinematics (bone directions, pelvis, root path, crossed legs): JSON
    /// report, fails when a clip fails.
    CheckRetarget(check_retarget::CheckRetargetArgs),
    /// Copy an experiment's export and eval.json into datasets/models/<name>, with a stored
    /// slice of held-out ground truth for the regression check.
    Ship(ship::ShipArgs),
    /// Recompute a shipped model's error on its stored slice; fail beyond 10 % of the record.
    CheckModel(ship::CheckModelArgs),
    /// The ground truth's signed distance to the posed body (the one collision measure) of a
    /// sim folder or a shipped model's slice: percentiles, the share below 0 and -1 mm.
    GtCollisions(gt_collisions::GtCollisionsArgs),
    /// How deep the posed body's forearms and hands pass into the rest of it, per sequence of
    /// an experiment, beside whether its simulation failed.
    ArmClearance(arm_clearance::ArmClearanceArgs),
    /// What limits the wrinkle GRU, measured on the validation split: learning curve over the
    /// training motions, GRU size, the PCA output's floor, and the ground truth's dependence
    /// on where a simulation starts: limits.json, limits.png.
    Limits(limits::LimitsArgs),
    /// Build the try-on page into web/dist (WebAssembly runtime, f16 model, body, clips);
    /// `--serve` serves it on 127.0.0.1.
    Web(web::WebArgs),
    #[command(flatten)]
    Sartor(sartor_cli::Command),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let root = workspace_root()?;
    let env = Env {
        data: DataDir::new(&root)?,
        runs_dir: root.join("runs"),
    };
    match cli.command {
        Command::ImportBody(args) => import_body::import_body(&args),
        Command::ImportMotion(args) => motions::import_motion(&args),
        Command::ImportMotions(args) => motions::import_motions(&args),
        Command::CheckRetarget(args) => check_retarget::check_retarget(&args, &env),
        Command::Ship(args) => ship::ship(&args, &env),
        Command::CheckModel(args) => ship::check_model(&args, &env),
        Command::GtCollisions(args) => gt_collisions::gt_collisions(&args, &env),
        Command::ArmClearance(args) => arm_clearance::arm_clearance(&args, &env),
        Command::Limits(args) => limits::limits(&args, &env),
        Command::Web(args) => web::web(&args, &root),
        Command::Sartor(command) => sartor_cli::run(&command, &env),
    }
}

/// The workspace root: the parent of this crate's folder, which `cargo run` names in
/// `CARGO_MANIFEST_DIR` at run time; else the first ancestor of the current directory with a
/// `Cargo.toml` and `datasets/` (a prebuilt xtask run by hand).
fn workspace_root() -> anyhow::Result<PathBuf> {
    if let Some(dir) = std::env::var_os("CARGO_MANIFEST_DIR") {
        let root = Path::new(&dir).join("..");
        if root.join("datasets").is_dir() {
            return Ok(root);
        }
    }
    let cwd = std::env::current_dir()?;
    cwd.ancestors()
        .find(|d| d.join("Cargo.toml").is_file() && d.join("datasets").is_dir())
        .map(Path::to_path_buf)
        .ok_or_else(|| anyhow::anyhow!("run `cargo xtask` inside the sartor repository"))
}
