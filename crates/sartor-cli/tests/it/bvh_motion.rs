//! `sartor demo` on a BVH file named as another tool names its joints: it animates it and says
//! which file joint drove which rig joint (`demo.json`'s `motion_joints`, and on stdout).

use std::path::Path;
use std::process::Command;

#[test]
fn demo_says_how_another_tools_bvh_was_matched() {
    let tmp = tempfile::tempdir().expect("tmp");
    let cmu = Path::new(env!("CARGO_MANIFEST_DIR")).join("../sartor-motion/tests/data/cmu");
    let text = std::fs::read_to_string(cmu.join("02_04.bvh")).expect("clip");
    // As Mixamo names them: a prefix on every joint.
    let mixamo = text
        .replace("ROOT ", "ROOT mixamorig:")
        .replace("JOINT ", "JOINT mixamorig:");
    let file = tmp.path().join("mixamo.bvh");
    std::fs::write(&file, mixamo).expect("write");
    let out_dir = tmp.path().join("out");
    let out = Command::new(env!("CARGO_BIN_EXE_sartor"))
        .args(["demo", "--phenotype", "male, 1.75 m, average", "--motion"])
        .arg(&file)
        .arg("--motion")
        .arg(cmu.join("02_04.bvh"))
        .args(["--frames", "3", "--formats", "png", "--out"])
        .arg(&out_dir)
        // The binary may be built outside the tree (CARGO_TARGET_DIR): name the data.
        .arg("--data-dir")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."))
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("joints matched by the skeleton's structure")
            && stdout.contains("mixamorig:LeftForeArm→LeftForeArm"),
        "{stdout}"
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("demo.json")).expect("demo.json"))
            .expect("json");
    // Only the file matched by structure is listed; CMU's own names need no saying.
    let listed = report["motion_joints"].as_array().expect("listed");
    assert_eq!(listed.len(), 1, "{listed:?}");
    let joints = listed[0]["joints"].as_array().expect("joints");
    assert!(joints.contains(&serde_json::json!(["mixamorig:LeftHand", "LeftHand"])));
    assert!(joints.contains(&serde_json::json!(["mixamorig:Spine1", "Spine1"])));
    let unused = listed[0]["unused"].as_array().expect("unused");
    assert!(
        unused.contains(&serde_json::json!("mixamorig:LThumb")),
        "{unused:?}"
    );
    assert_eq!(report["runs"].as_array().expect("runs").len(), 2);
}
