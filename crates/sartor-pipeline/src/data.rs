//! Where sartor's data lives: a folder holding `datasets/` (the body model, motions, garments,
//! shipped models) and `configs/` (experiments, garment recipes) — the repository itself, or a
//! copy of those two folders shipped beside the `sartor` binary. Nothing is found through
//! compile-time paths: the command line passes a [`DataDir`] found by [`DataDir::locate`].

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// Environment variable naming the data folder.
pub const DATA_DIR_ENV: &str = "SARTOR_DATA_DIR";

/// The file whose presence marks a data folder (the built-in body model's header).
const MARKER: &str = "datasets/body/makehuman/model.json";

/// A data folder (see the module docs).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DataDir {
    root: PathBuf,
}

impl DataDir {
    /// `root` as a data folder, checked for the built-in body model.
    pub fn new(root: &Path) -> Result<Self> {
        if !root.join(MARKER).is_file() {
            return Err(Error::Invalid(format!(
                "{}: not a sartor data folder (no {MARKER})",
                root.display()
            )));
        }
        Ok(Self {
            root: root.to_path_buf(),
        })
    }

    /// Find the data folder: `flag` (`--data-dir`) if given, else the environment variable
    /// [`DATA_DIR_ENV`], else the binary's location — the first folder, from the binary's own
    /// upwards, that holds the data itself or in `share/sartor/` (an install prefix). The error
    /// lists what was tried.
    pub fn locate(flag: Option<&Path>, env: Option<OsString>, exe: Option<&Path>) -> Result<Self> {
        if let Some(dir) = flag {
            return Self::new(dir).map_err(|e| Error::Invalid(format!("--data-dir: {e}")));
        }
        if let Some(dir) = env.filter(|v| !v.is_empty()) {
            return Self::new(Path::new(&dir))
                .map_err(|e| Error::Invalid(format!("{DATA_DIR_ENV}: {e}")));
        }
        let mut tried = Vec::new();
        if let Some(exe) = exe {
            for dir in exe.ancestors().skip(1) {
                for candidate in [dir.to_path_buf(), dir.join("share/sartor")] {
                    if candidate.join(MARKER).is_file() {
                        return Self::new(&candidate);
                    }
                    tried.push(candidate.display().to_string());
                }
            }
        }
        Err(Error::Invalid(format!(
            "no sartor data folder found: pass --data-dir DIR or set {DATA_DIR_ENV} to a folder \
             holding datasets/ and configs/ (looked beside the binary in: {})",
            if tried.is_empty() {
                "nothing, the binary's location is unknown".to_string()
            } else {
                tried.join(", ")
            }
        )))
    }

    /// The folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `path` if absolute, else relative to the data folder (how configs name their assets).
    pub fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.root.join(path)
        }
    }

    /// The built-in body model, `datasets/body/makehuman`.
    pub fn body_dir(&self) -> PathBuf {
        self.root.join("datasets/body/makehuman")
    }

    /// Imported motions (`walk.json`, ...), `datasets/motions`.
    pub fn motions_dir(&self) -> PathBuf {
        self.root.join("datasets/motions")
    }

    /// Garment templates, `datasets/garments`.
    pub fn garments_dir(&self) -> PathBuf {
        self.root.join("datasets/garments")
    }

    /// Garment recipes, `configs/garments`.
    pub fn recipes_dir(&self) -> PathBuf {
        self.root.join("configs/garments")
    }

    /// Shipped models, `datasets/models`.
    pub fn models_dir(&self) -> PathBuf {
        self.root.join("datasets/models")
    }

    /// The shipped default model, `datasets/models/default`.
    pub fn default_model_dir(&self) -> PathBuf {
        self.models_dir().join("default")
    }

    /// Every shipped model: the folders of `datasets/models` that hold a `model.json`, by
    /// name (`default`, the 4,210-triangle T-shirt, first; `default-8710`, the same experiment
    /// on the 8,710-triangle one, where shipped).
    pub fn shipped_model_dirs(&self) -> std::io::Result<Vec<PathBuf>> {
        let mut dirs = Vec::new();
        for entry in std::fs::read_dir(self.models_dir())? {
            let dir = entry?.path();
            if dir.join("model.json").is_file() {
                dirs.push(dir);
            }
        }
        dirs.sort();
        Ok(dirs)
    }

    /// `path` relative to the data folder when it lies inside it (so reports do not depend on
    /// where the folder is), else as given.
    pub fn relative(&self, path: &Path) -> String {
        match (path.canonicalize(), self.root.canonicalize()) {
            (Ok(p), Ok(r)) => p.strip_prefix(&r).map_or_else(
                |_| path.display().to_string(),
                |rel| rel.display().to_string(),
            ),
            _ => path.display().to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data_folder(dir: &Path) {
        let marker = dir.join(MARKER);
        std::fs::create_dir_all(marker.parent().expect("parent")).expect("mkdir");
        std::fs::write(&marker, "{}").expect("write");
    }

    #[test]
    fn flag_then_environment_then_binary_location() {
        let tmp = tempfile::tempdir().expect("tmp");
        let (a, b, c) = (
            tmp.path().join("a"),
            tmp.path().join("b"),
            tmp.path().join("c"),
        );
        for d in [&a, &b] {
            data_folder(d);
        }
        // An install prefix: c/bin/sartor with the data in c/share/sartor.
        data_folder(&c.join("share/sartor"));
        let exe = c.join("bin/sartor");
        let env = Some(OsString::from(&b));
        assert_eq!(
            DataDir::locate(Some(&a), env.clone(), Some(&exe))
                .expect("flag")
                .root(),
            a
        );
        assert_eq!(
            DataDir::locate(None, env, Some(&exe)).expect("env").root(),
            b
        );
        assert_eq!(
            DataDir::locate(None, None, Some(&exe))
                .expect("beside")
                .root(),
            c.join("share/sartor")
        );
        // The data itself in an ancestor (a checkout's target/release/sartor).
        let exe = a.join("target/release/sartor");
        assert_eq!(
            DataDir::locate(None, None, Some(&exe)).expect("up").root(),
            a
        );
    }

    #[test]
    fn a_folder_without_data_is_refused_and_the_error_says_what_was_tried() {
        let tmp = tempfile::tempdir().expect("tmp");
        let e = DataDir::locate(Some(tmp.path()), None, None).expect_err("no data");
        assert!(e.to_string().contains("--data-dir"), "{e}");
        let e = DataDir::locate(None, Some(tmp.path().into()), None).expect_err("no data");
        assert!(e.to_string().contains(DATA_DIR_ENV), "{e}");
        let exe = tmp.path().join("bin/sartor");
        let e = DataDir::locate(None, None, Some(&exe)).expect_err("no data");
        assert!(e.to_string().contains("share/sartor"), "{e}");
    }
}
