//! The crate graph keeps its promises: `sartor-runtime` depends on the geometry core and a few
//! small crates only (so it builds for a game engine or the browser), and no library finds data
//! through a compile-time path.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `cargo tree` of `package` (normal dependencies, this platform): its direct dependencies and
/// everything it pulls in.
fn tree(package: &str) -> (BTreeSet<String>, BTreeSet<String>) {
    let out = Command::new(env!("CARGO"))
        .args(["tree", "-e", "normal", "--prefix", "depth", "-p", package])
        .current_dir(workspace())
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (mut direct, mut all) = (BTreeSet::new(), BTreeSet::new());
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let digits = line.chars().take_while(char::is_ascii_digit).count();
        let depth: usize = line[..digits].parse().unwrap_or(0);
        let name = line[digits..].split(' ').next().unwrap_or("").to_string();
        if depth == 1 {
            direct.insert(name.clone());
        }
        if depth >= 1 {
            all.insert(name);
        }
    }
    (direct, all)
}

#[test]
fn the_runtime_depends_on_the_geometry_core_only() {
    let (direct, all) = tree("sartor-runtime");
    let allowed: BTreeSet<String> = [
        "sartor-core",
        "nalgebra",
        "serde",
        "serde_json",
        "thiserror",
        "rayon",
        "half",
        "png",
    ]
    .map(String::from)
    .into();
    assert!(
        direct.is_subset(&allowed),
        "sartor-runtime depends on {:?}, beyond {allowed:?}",
        direct.difference(&allowed).collect::<Vec<_>>()
    );
    assert!(direct.contains("sartor-core"));
    for banned in [
        "burn",
        "sartor-motion",
        "sartor-import",
        "sartor-mcap",
        "sartor-cloth",
        "sartor-dataset",
        "sartor-model",
        "npyz",
        "flate2",
        "rand_chacha",
        "zstd",
        "mcap",
        "faer",
    ] {
        assert!(!all.contains(banned), "sartor-runtime pulls in {banned}");
    }
    // And the core itself stays free of importers, formats and compression.
    let (_, core) = tree("sartor-core");
    for banned in ["npyz", "flate2", "zstd", "mcap", "faer", "burn"] {
        assert!(!core.contains(banned), "sartor-core pulls in {banned}");
    }
}

#[test]
fn the_web_wrapper_carries_no_training_or_simulation() {
    let (_, all) = tree("sartor-web");
    assert!(all.contains("sartor-runtime") && all.contains("wasm-bindgen"));
    for banned in [
        "burn",
        "sartor-cloth",
        "sartor-dataset",
        "sartor-model",
        "sartor-mcap",
        "sartor-import",
        "faer",
        // sartor-motion without its `npz` feature: the page reads no NumPy archives.
        "npyz",
        "zip",
    ] {
        assert!(!all.contains(banned), "sartor-web pulls in {banned}");
    }
}

#[test]
fn no_library_finds_data_through_a_compile_time_path() {
    let mut offenders = Vec::new();
    let mut stack = vec![workspace().join("crates")];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("readable") {
            let path = entry.expect("entry").path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if path.is_dir() {
                // Tests and benchmarks may name the workspace's files.
                if !["tests", "benches", "target"].contains(&name) {
                    stack.push(path);
                }
            } else if name.ends_with(".rs") {
                let text = std::fs::read_to_string(&path).expect("utf-8");
                let in_test_module = text.find("#[cfg(test)]").map_or(text.len(), |i| i);
                if text[..in_test_module].contains("env!(\"CARGO_MANIFEST_DIR\")") {
                    offenders.push(path.display().to_string());
                }
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "compile-time paths in library code: {offenders:?}"
    );
}
