//! The committed models (`datasets/models/default`, the reference, and every other folder of
//! `datasets/models`): each one's error on its stored slice of held-out ground truth stays
//! within 10 % of the figure in its committed eval.json, and `check-model` does fail when the
//! record and the model disagree.

use std::path::{Path, PathBuf};
use std::process::Command;

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../datasets/models/default")
}

fn check_model(dir: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(["check-model", "--model"])
        .arg(dir)
        .output()
        .expect("xtask runs")
}

#[test]
fn every_shipped_model_keeps_its_recorded_error() {
    // The list `bench runtime` times by default.
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let data = sartor_pipeline::DataDir::new(&root).expect("the repository's data folder");
    let dirs = data.shipped_model_dirs().expect("datasets/models");
    assert!(dirs.contains(&shipped()), "no reference model in {dirs:?}");
    for dir in dirs {
        let out = check_model(&dir);
        assert!(
            out.status.success(),
            "check-model of {} failed:\n{}{}",
            dir.display(),
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn a_record_the_model_does_not_reach_fails_the_check() {
    let dir = tempfile::tempdir().expect("tempdir");
    for entry in std::fs::read_dir(shipped()).expect("the shipped model") {
        let path = entry.expect("entry").path();
        if path.is_file() {
            std::fs::copy(&path, dir.path().join(path.file_name().expect("name"))).expect("copy");
        }
    }
    let eval_path = dir.path().join("eval.json");
    let mut eval: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&eval_path).expect("eval.json")).expect("json");
    let recorded = eval["regression_slice"]["mean_vertex_error_mm"]
        .as_f64()
        .expect("a recorded error");
    eval["regression_slice"]["mean_vertex_error_mm"] = serde_json::json!(recorded * 0.8);
    std::fs::write(&eval_path, serde_json::to_vec(&eval).expect("json")).expect("write");
    let out = check_model(dir.path());
    assert!(!out.status.success(), "a 25 % drift passed the 10 % check");
}
