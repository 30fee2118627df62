//! Real CMU motion capture: small excerpts of four clips (`tests/data/cmu/`, see its README)
//! retargeted onto the built-in body and checked frame by frame against the files' own forward
//! kinematics ([`sartor_motion::check_bvh_retarget`]), and the converter's T-pose frame detected.

use std::path::{Path, PathBuf};

use sartor_motion::{
    Bvh, BvhRetargetOptions, RetargetBody, RetargetCheckOptions, check_bvh_retarget,
    retarget_bvh_native_rate,
};

/// `(clip, first frame, last frame, step)`: the excerpt keeps the header, frame 0 (the
/// converter's T-pose) and frames `first, first + step, …, ≤ last` of the original.
pub const EXCERPTS: [(&str, usize, usize, usize); 4] = [
    ("07_01", 1, 240, 4),   // walk
    ("02_04", 41, 280, 4),  // jump
    ("05_11", 161, 400, 4), // modern dance: a crossover step (ankles crossed)
    ("09_01", 1, 148, 4),   // run
];

fn excerpt_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cmu")
}

/// Cut an excerpt out of a BVH file's text: the hierarchy unchanged, `Frames:` and `Frame Time:`
/// rewritten (the frame time × `step`, written like the original with 7 decimals), then frame 0
/// and the chosen frame lines, byte for byte.
pub fn cut_excerpt(text: &str, first: usize, last: usize, step: usize) -> String {
    let (hierarchy, motion) = text.split_once("MOTION\n").expect("a MOTION section");
    let mut lines = motion.lines();
    let _frames = lines.next().expect("Frames:");
    let time_line = lines.next().expect("Frame Time:");
    let dt: f64 = time_line
        .trim_start_matches("Frame Time:")
        .trim()
        .parse()
        .expect("frame time");
    let frames: Vec<&str> = lines.collect();
    let picked: Vec<&str> = std::iter::once(frames[0])
        .chain(
            (first..=last.min(frames.len() - 1))
                .step_by(step)
                .map(|i| frames[i]),
        )
        .collect();
    let dt = format!("{:.7}", dt * step as f64);
    format!(
        "{hierarchy}MOTION\nFrames: {}\nFrame Time: {}\n{}\n",
        picked.len(),
        dt.trim_start_matches('0'),
        picked.join("\n")
    )
}

#[test]
fn excerpts_are_cut_from_the_shared_clips() {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/cmu");
    if !shared.join("07_01.bvh").exists() {
        println!("skipped: {} not found", shared.display());
        return;
    }
    for (clip, first, last, step) in EXCERPTS {
        let text = std::fs::read_to_string(shared.join(format!("{clip}.bvh"))).expect("clip");
        let cut = cut_excerpt(&text, first, last, step);
        let path = excerpt_dir().join(format!("{clip}.bvh"));
        if std::env::var_os("SARTOR_WRITE_EXCERPTS").is_some() {
            std::fs::write(&path, &cut).expect("write excerpt");
        }
        let committed = std::fs::read_to_string(&path).expect("committed excerpt");
        assert!(
            committed == cut,
            "{}: not the cut of ../shared/cmu/{clip}.bvh (re-cut with \
             SARTOR_WRITE_EXCERPTS=1 cargo test -p sartor-motion excerpts_are_cut)",
            path.display()
        );
    }
}

#[test]
fn cmu_excerpts_retarget_onto_the_builtin_body_like_their_own_fk() {
    let body =
        RetargetBody::load(&crate::motion_sources::builtin_model_dir()).expect("built-in body");
    let options = RetargetCheckOptions::default();
    for (clip, ..) in EXCERPTS {
        let bvh = Bvh::load(&excerpt_dir().join(format!("{clip}.bvh"))).expect("excerpt");
        let check = check_bvh_retarget(&bvh, &body, &options).expect("check");
        assert!(check.passed(), "{clip}: {:?}", check.failures);
        // Every posture bone of the legs and arms was compared.
        for bone in [
            "LeftUpLeg->LeftLeg",
            "RightLeg->RightFoot",
            "LeftArm->LeftForeArm",
            "RightForeArm->RightHand",
        ] {
            let b = check.bones.iter().find(|b| b.bone == bone).expect(bone);
            assert_eq!(b.kind, "posture");
            assert!(b.worst_angle_deg <= options.max_bone_angle_deg);
        }
        // The proportion bones turn with the file's joints but keep their own rest direction.
        let hip = check
            .bones
            .iter()
            .find(|b| b.bone == "LHipJoint->LeftUpLeg")
            .expect("hip socket");
        assert_eq!(hip.kind, "proportion");
        assert!(hip.worst_angle_to_file_bone_deg > 20.0, "{hip:?}");
        assert_eq!(check.crossing.crossed_frames, 0, "{clip}");
        // Frame 0 is the converter's T-pose: detected, and dropped by default.
        let t = check.tpose_frame.as_ref().expect("measured");
        assert!(t.is_added_tpose, "{clip}: {t:?}");
        let (m, report) =
            retarget_bvh_native_rate(&bvh, &body, &BvhRetargetOptions::default()).expect("m");
        assert!(report.tpose_frame_dropped);
        assert_eq!(m.n_frames(), bvh.n_frames() - 1);
        let keep = BvhRetargetOptions {
            keep_tpose_frame: true,
            ..BvhRetargetOptions::default()
        };
        let (all, _) = retarget_bvh_native_rate(&bvh, &body, &keep).expect("all");
        assert_eq!(all.n_frames(), bvh.n_frames());
    }
}

#[test]
fn the_dance_excerpt_crosses_its_own_ankles_and_ours_follow() {
    // 05_11's dancer crosses the ankles (frames 242–270): the check must not hold the data's own crossing
    // against the retarget, and ours must cross with it.
    let body =
        RetargetBody::load(&crate::motion_sources::builtin_model_dir()).expect("built-in body");
    let bvh = Bvh::load(&excerpt_dir().join("05_11.bvh")).expect("excerpt");
    let check = check_bvh_retarget(&bvh, &body, &RetargetCheckOptions::default()).expect("check");
    let [ours, file] = check.crossing.min_ankle_separation;
    assert!(file < -0.2 && ours < -0.2, "ours {ours}, file {file}");
    assert!(check.crossing.file_close_or_crossed_frames > 0);
    assert!(check.passed(), "{:?}", check.failures);
}
