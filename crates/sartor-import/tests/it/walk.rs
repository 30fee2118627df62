//! The walk-cycle import and the procedural clips on MakeHuman's own rest pose (both need the
//! raw assets beside the workspace, `../shared/makehuman`; skipped without them).

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use sartor_core::Skeleton;
use sartor_motion::procedural::clip;
use sartor_motion::{Motion, cmu_mb_skeleton};

use crate::common::json_difference;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn bone_dir(joints: &[Vector3<f64>], s: &Skeleton, from: &str, to: &str) -> Vector3<f64> {
    (joints[s.index_of(to).expect(to)] - joints[s.index_of(from).expect(from)]).normalize()
}

#[test]
fn walk_import_reproduces_the_committed_file() {
    let assets = workspace_root().join("../shared/makehuman");
    if !assets.join(sartor_import::WALK_CYCLE_FILE).exists() {
        println!("skipped: {} not found", assets.display());
        return;
    }
    let m = sartor_import::import_walk_cycle(&assets).expect("import");
    let committed = workspace_root().join("datasets/motions/walk.json");
    let bytes = serde_json::to_vec(&m).expect("json");
    let on_disk = std::fs::read(&committed).expect("datasets/motions/walk.json is committed");
    let on_disk: serde_json::Value = serde_json::from_slice(&on_disk).expect("walk.json parses");
    let fresh: serde_json::Value = serde_json::from_slice(&bytes).expect("json");
    // Not byte equality: sin/cos may differ in the last bit between CPUs (glibc picks FMA
    // variants at run time), which CI showed. 1e-9 relative is far below anything that matters
    // and far above rounding.
    if let Some(diff) = json_difference(&fresh, &on_disk, 1e-9) {
        panic!(
            "re-run `cargo xtask import-motion`: the import differs from {} at {diff}",
            committed.display()
        );
    }
    // Deterministic.
    let again = sartor_import::import_walk_cycle(&assets).expect("import");
    assert_eq!(serde_json::to_vec(&again).expect("json"), bytes);
}

fn frame_where(
    m: &Motion,
    rest: &[Vector3<f64>],
    key: impl Fn(&[Vector3<f64>]) -> f64,
) -> Vec<Vector3<f64>> {
    let s = cmu_mb_skeleton();
    let mut best: Option<(f64, Vec<Vector3<f64>>)> = None;
    for f in m.frames() {
        let (j, _) = s.forward_kinematics(rest, f).expect("fk");
        let k = key(&j);
        if best.as_ref().is_none_or(|(b, _)| k > *b) {
            best = Some((k, j));
        }
    }
    best.expect("frames").1
}

#[test]
fn procedural_conventions_hold_on_the_makehuman_rest_pose() {
    let rig = workspace_root()
        .join("../shared/makehuman")
        .join(sartor_import::CMU_MB_RIG_FILE);
    if !rig.exists() {
        println!("skipped: {} not found", rig.display());
        return;
    }
    let rest = sartor_import::cmu_mb_rest_joints(&rig).expect("rig joints");
    let s = cmu_mb_skeleton();
    let ix = |n: &str| s.index_of(n).expect(n);
    let ground = 0.5 * (rest[ix("LeftFoot")].y + rest[ix("RightFoot")].y);
    // +45° abduction brings the A-pose arm near horizontal.
    let m = clip("reach_side_both").expect("clip");
    let j = frame_where(&m, &rest, |j| j[ix("LeftHand")].y);
    let arm = bone_dir(&j, &s, "LeftArm", "LeftForeArm");
    assert!(
        arm.y.abs() < 0.2 && arm.x > 0.9,
        "left arm sideways: {arm:?}"
    );
    // Reaching up: both hands above the head.
    let m = clip("reach_up_both").expect("clip");
    let j = frame_where(&m, &rest, |j| j[ix("LeftHand")].y);
    assert!(j[ix("LeftHand")].y > j[ix("Head")].y && j[ix("RightHand")].y > j[ix("Head")].y);
    // Squatting and lunging keep a foot on the ground.
    for name in [
        "squat_deep",
        "lunge_left",
        "walk_normal",
        "run_jog",
        "march_in_place",
    ] {
        let m = clip(name).expect("clip");
        for f in m.frames() {
            let (j, _) = s.forward_kinematics(&rest, f).expect("fk");
            let low = j[ix("LeftFoot")].y.min(j[ix("RightFoot")].y);
            assert!(
                (low - ground).abs() < 0.08,
                "{name}: the lower ankle is {:.3} m off the ground",
                low - ground
            );
        }
    }
    // The deepest squat brings the pelvis well down.
    let m = clip("squat_deep").expect("clip");
    let j = frame_where(&m, &rest, |j| -j[ix("Hips")].y);
    assert!(j[ix("Hips")].y < rest[ix("Hips")].y - 0.3);
}
