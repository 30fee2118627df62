//! The shipped assets as the page fetches them.

use std::path::{Path, PathBuf};

use sartor_motion::{ClearanceOptions, Motion};
use sartor_web::{BODY_FILES, FileSet, MODEL_FILES, TryOn, TryOnOptions};

pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The shipped model and body, by the page's file names.
pub fn shipped_files() -> FileSet {
    files_of(&[
        (&MODEL_FILES[..], "datasets/models/default"),
        (&BODY_FILES[..], "datasets/body/makehuman"),
    ])
}

/// The files of each pair's folder (relative to the repository), by the page's names.
pub fn files_of(folders: &[(&[&str], &str)]) -> FileSet {
    let mut files = FileSet::new();
    for (names, dir) in folders {
        for name in names.iter() {
            let (_, file) = name.split_once('/').expect("folder/file");
            let bytes = std::fs::read(repo().join(dir).join(file)).expect("shipped file");
            files.insert(name, bytes);
        }
    }
    files
}

pub fn load() -> TryOn {
    TryOn::load(
        shipped_files(),
        TryOnOptions {
            clock: Some(sartor_web::now_ms),
            ..TryOnOptions::default()
        },
    )
    .expect("the shipped assets load")
}

/// The limbs held out as the page holds them (`manifest.json`, which `cargo xtask web` writes):
/// the arms as the shipped model's experiment held them in its training motions
/// (`configs/default.json`), and the legs (`ClearanceOptions::with_player_legs`).
pub fn shipped_arm_clearance() -> ClearanceOptions {
    let config: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(repo().join("configs/default.json")).expect("config"),
    )
    .expect("JSON");
    let arms: ClearanceOptions =
        serde_json::from_value(config["simulation"]["arm_clearance"].clone())
            .expect("the shipped experiment holds the arms out");
    arms.with_player_legs()
}

/// The page's session with the limbs held as the page holds them, playing CMU 02_02 (a walk
/// whose every frame needs the arms held) from its first frame.
pub fn playing_02_02() -> TryOn {
    playing_02_02_with(shipped_files())
}

/// [`playing_02_02`] with the model and body in `files`.
pub fn playing_02_02_with(files: FileSet) -> TryOn {
    let mut t = TryOn::load(
        files,
        TryOnOptions {
            arm_clearance: Some(shipped_arm_clearance()),
            ..TryOnOptions::default()
        },
    )
    .expect("the shipped assets load");
    let clip = stored_clip(&t, "02_02");
    t.set_motion(clip).expect("play");
    t
}

/// The stored CMU clip `id` (`02_02`) as the page fetches and loads it, retargeted onto `t`'s
/// body.
pub fn stored_clip(t: &TryOn, id: &str) -> Motion {
    let dir = repo().join("datasets/motions/cmu");
    t.motion_stored(
        &format!("cmu/{id}"),
        &std::fs::read(dir.join(format!("{id}.json"))).expect("json"),
        std::fs::read(dir.join(format!("{id}.safetensors"))).expect("tensors"),
    )
    .expect("stored clip")
}
