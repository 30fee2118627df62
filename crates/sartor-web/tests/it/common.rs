//! The shipped assets as the page fetches them.

use std::path::{Path, PathBuf};

use sartor_web::{BODY_FILES, FileSet, MODEL_FILES, TryOn, TryOnOptions};

pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The shipped model and body, by the page's file names.
pub fn shipped_files() -> FileSet {
    let mut files = FileSet::new();
    for (names, dir) in [
        (&MODEL_FILES[..], "datasets/models/default"),
        (&BODY_FILES[..], "datasets/body/makehuman"),
    ] {
        for name in names {
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
