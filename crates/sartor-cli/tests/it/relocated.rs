//! The built `sartor` binary, copied away from the source tree, finds its data from its own
//! location, `--data-dir` or `SARTOR_DATA_DIR` — never from where it was built — and says what it
//! tried when there is none.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("readable") {
        let path = entry.expect("entry").path();
        let dest = to.join(path.file_name().expect("name"));
        if path.is_dir() {
            copy_dir(&path, &dest);
        } else {
            std::fs::copy(&path, &dest).expect("copy");
        }
    }
}

/// The data a demo needs: the body, the imported motions, the shipped model.
fn copy_data(to: &Path) {
    for dir in [
        "datasets/body/makehuman",
        "datasets/motions",
        "datasets/models/default",
    ] {
        copy_dir(&workspace().join(dir), &to.join(dir));
    }
}

/// The binary copied to `dir/bin/sartor`.
fn install(dir: &Path) -> PathBuf {
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).expect("mkdir");
    let exe = bin.join("sartor");
    std::fs::copy(env!("CARGO_BIN_EXE_sartor"), &exe).expect("copy the binary");
    exe
}

fn demo(exe: &Path, cwd: &Path, out: &Path) -> Command {
    let mut c = Command::new(exe);
    c.current_dir(cwd)
        .env_remove("SARTOR_DATA_DIR")
        .env_remove("CARGO_MANIFEST_DIR")
        .args([
            "demo",
            "--phenotype",
            "female, 1.60 m, light",
            "--motion",
            "walk_normal",
            "--frames",
            "3",
            "--formats",
            "png",
            "--out",
        ])
        .arg(out);
    c
}

fn assert_ok(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_relocated_binary_finds_its_data_beside_it_by_flag_or_by_environment() {
    let tmp = tempfile::tempdir().expect("tmp");
    let prefix = tmp.path().join("prefix");
    let exe = install(&prefix);
    let elsewhere = tmp.path().join("cwd");
    std::fs::create_dir_all(&elsewhere).expect("mkdir");

    // No data anywhere: a clear error naming the ways to give it, and no output.
    let out = demo(&exe, &elsewhere, &tmp.path().join("none"))
        .output()
        .expect("runs");
    assert!(!out.status.success(), "ran without data");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--data-dir") && err.contains("SARTOR_DATA_DIR"),
        "{err}"
    );
    assert!(!tmp.path().join("none").exists(), "wrote output on failure");

    // Data in another folder, named by flag, then by the environment.
    let data = tmp.path().join("data");
    copy_data(&data);
    let by_flag = tmp.path().join("by-flag");
    let out = demo(&exe, &elsewhere, &by_flag)
        .arg("--data-dir")
        .arg(&data)
        .output()
        .expect("runs");
    assert_ok(&out, "demo --data-dir");
    assert!(by_flag.join("demo.json").is_file());
    assert!(by_flag.join("body0_walk_normal.png").is_file());

    let by_env = tmp.path().join("by-env");
    let out = demo(&exe, &elsewhere, &by_env)
        .env("SARTOR_DATA_DIR", &data)
        .args([
            "--precision",
            "int8",
            "--vertices-only",
            "--no-strain-limit",
        ])
        .output()
        .expect("runs");
    assert_ok(&out, "demo with SARTOR_DATA_DIR");
    let report = |dir: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(dir.join("demo.json")).expect("demo.json"))
            .expect("json")
    };
    assert_eq!(report(&by_env)["precision"], "int8");
    // Triangles are pushed out of the body unless asked not to.
    assert_eq!(report(&by_flag)["push_triangles"], true);
    assert_eq!(report(&by_env)["push_triangles"], false);
    // And the strain limit is on unless asked not to.
    assert_eq!(report(&by_flag)["strain_limit"], 1.5);
    assert_eq!(report(&by_env)["strain_limit"], serde_json::Value::Null);

    // Installed beside the binary: <prefix>/share/sartor.
    copy_data(&prefix.join("share/sartor"));
    let beside = tmp.path().join("beside");
    let out = demo(&exe, &elsewhere, &beside).output().expect("runs");
    assert_ok(&out, "demo with the data beside the binary");
    let report = report(&beside);
    assert_eq!(report["precision"], "f32");
    let model = report["model"].as_str().expect("model path");
    assert!(
        Path::new(model).starts_with(prefix.join("share/sartor")),
        "{model} is not the installed model"
    );
}
