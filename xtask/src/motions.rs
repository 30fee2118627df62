//! `cargo xtask import-motion`: convert MakeHuman's keyframed walk cycle into
//! `datasets/motions/walk.json` (a 30 fps [`sartor_motion::Motion`] on the built-in skeleton).

use std::path::PathBuf;

use anyhow::Context;

/// Arguments of `import-motion`.
#[derive(clap::Args, Debug)]
pub struct ImportMotionArgs {
    /// The MakeHuman assets folder (holding `walkcycles/` and `rigs/`).
    #[arg(long, default_value = "../shared/makehuman")]
    pub from: PathBuf,
    /// Output folder; the motion is written to `<out>/walk.json`.
    #[arg(long, default_value = "datasets/motions")]
    pub out: PathBuf,
}

/// Import the walk cycle and write it.
pub fn import_motion(args: &ImportMotionArgs) -> anyhow::Result<()> {
    let motion = sartor_import::import_walk_cycle(&args.from)
        .with_context(|| format!("importing the walk cycle from {}", args.from.display()))?;
    let path = args.out.join(format!("{}.json", sartor_motion::WALK_NAME));
    motion.save_json(&path)?;
    let last = &motion.frames()[motion.n_frames() - 1];
    println!(
        "wrote {}: {} frames at {} fps ({:.2} s), root travels {:.2} m forward",
        path.display(),
        motion.n_frames(),
        motion.fps(),
        motion.duration_secs(),
        last.root_translation_m.z - motion.frames()[0].root_translation_m.z,
    );
    Ok(())
}
