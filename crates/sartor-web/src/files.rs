//! [`FileSet`]: the files a page fetched, by name. A browser has no file system, so the assets
//! arrive as bytes; each is parsed by the same reader as on disk (`from_bytes`), with the
//! same checks (hashes, shapes, finiteness) and errors that name the file.

use std::collections::BTreeMap;

use crate::error::{Error, Result};

/// The model folder's files, as [`FileSet`] names them (`datasets/models/default`, or its
/// f16 copy in `web/dist/models/default`; any shipped model's alike).
pub const MODEL_FILES: [&str; 4] = [
    "model/model.json",
    "model/model.safetensors",
    "model/binding.json",
    "model/binding.safetensors",
];

/// The body folder's files, as [`FileSet`] names them (`datasets/body/makehuman`).
pub const BODY_FILES: [&str; 5] = [
    "body/model.json",
    "body/model.safetensors",
    "body/phenotype.json",
    "body/phenotype.safetensors",
    "body/tpose.json",
];

/// Named file contents.
#[derive(Clone, Debug, Default)]
pub struct FileSet {
    files: BTreeMap<String, Vec<u8>>,
}

impl FileSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Add (or replace) file `name`.
    pub fn insert(&mut self, name: &str, bytes: Vec<u8>) {
        self.files.insert(name.to_string(), bytes);
    }

    /// Names held, sorted.
    pub fn names(&self) -> Vec<String> {
        self.files.keys().cloned().collect()
    }

    /// Remove and return file `name`, or an error naming it and the expected names.
    pub fn take(&mut self, name: &str) -> Result<Vec<u8>> {
        self.files.remove(name).ok_or_else(|| Error::MissingFile {
            name: name.to_string(),
            expected: MODEL_FILES
                .iter()
                .chain(&BODY_FILES)
                .copied()
                .collect::<Vec<_>>()
                .join(", "),
        })
    }
}
