//! Matching BVH skeletons of other tools to the rig by their structure (`bvh_map.rs`), checked
//! against the match by name on CMU's own files: renamed as Mixamo, Biovision, Rigify, DAZ or
//! 3ds Max Biped name them, or with no names at all, they must retarget to the same poses.

use std::f64::consts::FRAC_PI_2;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use sartor_motion::{
    Bvh, BvhChannel, BvhJoint, BvhJointMatch, BvhRetargetOptions, RetargetBody, check_bvh_retarget,
    load_stored_clip, map_bvh_joints, map_bvh_joints_by_structure, retarget_bvh,
};

use crate::motion_sources::data;

fn motions_dir() -> PathBuf {
    crate::motion_sources::workspace_root().join("datasets/motions")
}

/// The CMU joints a structural match leaves to follow their parent: the hand's fingers and
/// thumb (no tool agrees on them).
const FINGERS: [&str; 6] = [
    "LeftFingerBase",
    "LeftHandIndex1",
    "LThumb",
    "RightFingerBase",
    "RightHandIndex1",
    "RThumb",
];

/// Every joint the structure matches, it matches to the rig joint of the same name; every
/// other joint is a finger.
fn assert_structure_agrees_with_names(bvh: &Bvh) {
    let by_name = map_bvh_joints(bvh).expect("names");
    assert_eq!(by_name.matched_by, BvhJointMatch::Names);
    let by_structure = map_bvh_joints_by_structure(bvh).expect("structure");
    for ((joint, name), structure) in bvh
        .joints()
        .iter()
        .zip(&by_name.rig_joints)
        .zip(&by_structure.rig_joints)
    {
        match structure {
            Some(s) => assert_eq!(Some(*s), *name, "{:?} in {:?}", joint.name, bvh.path()),
            None => assert!(
                FINGERS.contains(&joint.name.as_str()),
                "{:?} unmatched in {:?}",
                joint.name,
                bvh.path()
            ),
        }
    }
}

#[test]
fn cmu_skeletons_match_by_structure_as_by_name() {
    for clip in ["02_04", "05_11", "07_01", "09_01"] {
        let bvh = Bvh::load(&data(&format!("cmu/{clip}.bvh"))).expect("clip");
        assert_structure_agrees_with_names(&bvh);
    }
    // The 60 imported clips: their own skeletons (subjects differ in proportions).
    let mut n = 0;
    for entry in std::fs::read_dir(motions_dir().join("cmu")).expect("cmu clips") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "json") {
            let stem = path.file_stem().expect("stem").to_string_lossy();
            let bvh = load_stored_clip(&motions_dir(), &format!("cmu/{stem}")).expect("clip");
            assert_structure_agrees_with_names(&bvh);
            n += 1;
        }
    }
    assert_eq!(n, 60);
}

/// CMU's joint names as other tools write the same joints (SMPL's as its BVH exporters write
/// them).
const CONVENTIONS: [(&str, [(&str, &str); 25]); 6] = [
    (
        "mixamo",
        [
            ("Spine", "mixamorig:Spine1"),
            ("RightArm", "mixamorig:RightArm"),
            ("Hips", "mixamorig:Hips"),
            ("LHipJoint", "mixamorig:LeftHipJoint"),
            ("LeftUpLeg", "mixamorig:LeftUpLeg"),
            ("LeftLeg", "mixamorig:LeftLeg"),
            ("LeftFoot", "mixamorig:LeftFoot"),
            ("LeftToeBase", "mixamorig:LeftToeBase"),
            ("RHipJoint", "mixamorig:RightHipJoint"),
            ("RightUpLeg", "mixamorig:RightUpLeg"),
            ("RightLeg", "mixamorig:RightLeg"),
            ("RightFoot", "mixamorig:RightFoot"),
            ("RightToeBase", "mixamorig:RightToeBase"),
            ("LowerBack", "mixamorig:Spine"),
            ("Spine1", "mixamorig:Spine2"),
            ("Neck1", "mixamorig:Neck1"),
            ("Neck", "mixamorig:Neck"),
            ("Head", "mixamorig:Head"),
            ("LeftShoulder", "mixamorig:LeftShoulder"),
            ("LeftArm", "mixamorig:LeftArm"),
            ("LeftForeArm", "mixamorig:LeftForeArm"),
            ("LeftHand", "mixamorig:LeftHand"),
            ("RightShoulder", "mixamorig:RightShoulder"),
            ("RightForeArm", "mixamorig:RightForeArm"),
            ("RightHand", "mixamorig:RightHand"),
        ],
    ),
    (
        "biovision",
        [
            ("Spine", "Chest"),
            ("RightArm", "RightShoulder"),
            ("Hips", "Hips"),
            ("LHipJoint", "LeftHipJoint"),
            ("LeftUpLeg", "LeftHip"),
            ("LeftLeg", "LeftKnee"),
            ("LeftFoot", "LeftAnkle"),
            ("LeftToeBase", "LeftToe"),
            ("RHipJoint", "RightHipJoint"),
            ("RightUpLeg", "RightHip"),
            ("RightLeg", "RightKnee"),
            ("RightFoot", "RightAnkle"),
            ("RightToeBase", "RightToe"),
            ("LowerBack", "Abdomen"),
            ("Spine1", "Chest2"),
            ("Neck1", "Neck2"),
            ("Neck", "Neck"),
            ("Head", "Head"),
            ("LeftShoulder", "LeftCollar"),
            ("LeftArm", "LeftShoulder"),
            ("LeftForeArm", "LeftElbow"),
            ("LeftHand", "LeftWrist"),
            ("RightShoulder", "RightCollar"),
            ("RightForeArm", "RightElbow"),
            ("RightHand", "RightWrist"),
        ],
    ),
    (
        "rigify",
        [
            ("Spine", "spine.001"),
            ("RightArm", "upper_arm.R"),
            ("Hips", "pelvis"),
            ("LHipJoint", "pelvis.L"),
            ("LeftUpLeg", "thigh.L"),
            ("LeftLeg", "shin.L"),
            ("LeftFoot", "foot.L"),
            ("LeftToeBase", "toe.L"),
            ("RHipJoint", "pelvis.R"),
            ("RightUpLeg", "thigh.R"),
            ("RightLeg", "shin.R"),
            ("RightFoot", "foot.R"),
            ("RightToeBase", "toe.R"),
            ("LowerBack", "spine"),
            ("Spine1", "spine.002"),
            ("Neck1", "neck.001"),
            ("Neck", "neck"),
            ("Head", "head"),
            ("LeftShoulder", "shoulder.L"),
            ("LeftArm", "upper_arm.L"),
            ("LeftForeArm", "forearm.L"),
            ("LeftHand", "hand.L"),
            ("RightShoulder", "shoulder.R"),
            ("RightForeArm", "forearm.R"),
            ("RightHand", "hand.R"),
        ],
    ),
    (
        "daz",
        [
            ("Spine", "abdomen2"),
            ("RightArm", "rShldr"),
            ("Hips", "hip"),
            ("LHipJoint", "lButtock"),
            ("LeftUpLeg", "lThigh"),
            ("LeftLeg", "lShin"),
            ("LeftFoot", "lFoot"),
            ("LeftToeBase", "lToe"),
            ("RHipJoint", "rButtock"),
            ("RightUpLeg", "rThigh"),
            ("RightLeg", "rShin"),
            ("RightFoot", "rFoot"),
            ("RightToeBase", "rToe"),
            ("LowerBack", "abdomen"),
            ("Spine1", "chest"),
            ("Neck1", "neck2"),
            ("Neck", "neck"),
            ("Head", "head"),
            ("LeftShoulder", "lCollar"),
            ("LeftArm", "lShldr"),
            ("LeftForeArm", "lForeArm"),
            ("LeftHand", "lHand"),
            ("RightShoulder", "rCollar"),
            ("RightForeArm", "rForeArm"),
            ("RightHand", "rHand"),
        ],
    ),
    (
        "biped",
        [
            ("Spine", "Bip01 Spine1"),
            ("RightArm", "Bip01 R UpperArm"),
            ("Hips", "Bip01 Pelvis"),
            ("LHipJoint", "Bip01 L Hip"),
            ("LeftUpLeg", "Bip01 L Thigh"),
            ("LeftLeg", "Bip01 L Calf"),
            ("LeftFoot", "Bip01 L Foot"),
            ("LeftToeBase", "Bip01 L Toe0"),
            ("RHipJoint", "Bip01 R Hip"),
            ("RightUpLeg", "Bip01 R Thigh"),
            ("RightLeg", "Bip01 R Calf"),
            ("RightFoot", "Bip01 R Foot"),
            ("RightToeBase", "Bip01 R Toe0"),
            ("LowerBack", "Bip01 Spine"),
            ("Spine1", "Bip01 Spine2"),
            ("Neck1", "Bip01 Neck1"),
            ("Neck", "Bip01 Neck"),
            ("Head", "Bip01 Head"),
            ("LeftShoulder", "Bip01 L Clavicle"),
            ("LeftArm", "Bip01 L UpperArm"),
            ("LeftForeArm", "Bip01 L Forearm"),
            ("LeftHand", "Bip01 L Hand"),
            ("RightShoulder", "Bip01 R Clavicle"),
            ("RightForeArm", "Bip01 R Forearm"),
            ("RightHand", "Bip01 R Hand"),
        ],
    ),
    (
        "smpl",
        [
            ("Hips", "Pelvis"),
            ("LHipJoint", "L_Pelvis"),
            ("LeftUpLeg", "L_Hip"),
            ("LeftLeg", "L_Knee"),
            ("LeftFoot", "L_Ankle"),
            ("LeftToeBase", "L_Foot"),
            ("RHipJoint", "R_Pelvis"),
            ("RightUpLeg", "R_Hip"),
            ("RightLeg", "R_Knee"),
            ("RightFoot", "R_Ankle"),
            ("RightToeBase", "R_Foot"),
            ("LowerBack", "Spine1"),
            ("Spine", "Spine2"),
            ("Spine1", "Spine3"),
            ("Neck1", "Neck_2"),
            ("Neck", "Neck"),
            ("Head", "Head"),
            ("LeftShoulder", "L_Collar"),
            ("LeftArm", "L_Shoulder"),
            ("LeftForeArm", "L_Elbow"),
            ("LeftHand", "L_Wrist"),
            ("RightShoulder", "R_Collar"),
            ("RightArm", "R_Shoulder"),
            ("RightForeArm", "R_Elbow"),
            ("RightHand", "R_Wrist"),
        ],
    ),
];

/// `text` with every joint renamed by `rename` (joints it leaves out keep their names).
fn renamed(text: &str, rename: impl Fn(&str) -> Option<String>) -> String {
    text.lines()
        .map(|line| {
            let t = line.trim_start();
            for kw in ["ROOT ", "JOINT "] {
                if let Some(name) = t.strip_prefix(kw)
                    && let Some(new) = rename(name.trim())
                {
                    let indent = &line[..line.len() - t.len()];
                    return format!("{indent}{kw}{new}");
                }
            }
            line.to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn builtin_body() -> RetargetBody {
    RetargetBody::load(&crate::motion_sources::builtin_model_dir()).expect("built-in body")
}

/// The poses of `text` (named `name`), and how its joints were matched.
fn retarget_text(
    text: &str,
    name: &str,
    body: &RetargetBody,
) -> (Vec<sartor_core::Pose>, BvhJointMatch) {
    let bvh = Bvh::parse(text, Path::new(name)).expect("parses");
    let (motion, report) =
        retarget_bvh(&bvh, body, &BvhRetargetOptions::default()).expect("retargets");
    (motion.frames().to_vec(), report.joint_map.matched_by)
}

#[test]
fn a_cmu_clip_named_as_other_tools_name_it_retargets_to_the_same_poses() {
    let body = builtin_body();
    let text = std::fs::read_to_string(data("cmu/02_04.bvh")).expect("clip");
    let (want, by) = retarget_text(&text, "02_04.bvh", &body);
    assert_eq!(by, BvhJointMatch::Names);
    for (tool, names) in CONVENTIONS {
        let rename = |n: &str| {
            names
                .iter()
                .find(|(cmu, _)| *cmu == n)
                .map(|(_, other)| other.to_string())
        };
        let (got, by) = retarget_text(&renamed(&text, rename), &format!("{tool}.bvh"), &body);
        assert_eq!(by, BvhJointMatch::Structure, "{tool}");
        assert_eq!(got.len(), want.len(), "{tool}");
        // The fingers are matched to nothing: they follow the hand, where CMU's (whose
        // channels are zero in this clip) sat still on it. Every other joint the same bits.
        let s = body.skeleton();
        let fingers: Vec<usize> = FINGERS_RIG
            .iter()
            .map(|n| s.index_of(n).expect(n))
            .collect();
        for (k, (a, b)) in got.iter().zip(&want).enumerate() {
            assert_eq!(
                a.root_translation_m, b.root_translation_m,
                "{tool} frame {k}"
            );
            assert_eq!(a.root_orientation, b.root_orientation, "{tool} frame {k}");
            for (j, (p, q)) in a.local_rotations.iter().zip(&b.local_rotations).enumerate() {
                if !fingers.contains(&j) {
                    assert_eq!(p, q, "{tool} frame {k} joint {}", s.names()[j]);
                }
            }
        }
    }
}

#[test]
fn without_side_names_the_feet_tell_left_from_right() {
    let body = builtin_body();
    let text = std::fs::read_to_string(data("cmu/02_04.bvh")).expect("clip");
    let bvh = Bvh::parse(&text, Path::new("02_04.bvh")).expect("clip");
    let names: Vec<String> = bvh.joints().iter().map(|j| j.name.clone()).collect();
    // Joint names that say nothing of the side (nor of the neck and head).
    let anonymous = renamed(&text, |n| {
        names
            .iter()
            .position(|x| x == n)
            .map(|k| format!("joint{k:02}"))
    });
    let bvh = Bvh::parse(&anonymous, Path::new("anonymous.bvh")).expect("parses");
    let map = map_bvh_joints(&bvh).expect("matched");
    assert_eq!(map.matched_by, BvhJointMatch::Structure);
    let by_name =
        map_bvh_joints(&Bvh::parse(&text, Path::new("02_04.bvh")).expect("clip")).expect("names");
    for (k, (a, b)) in map.rig_joints.iter().zip(&by_name.rig_joints).enumerate() {
        if a.is_some() {
            assert_eq!(a, b, "joint {}", names[k]);
        }
    }
    // And its retarget follows the file's own forward kinematics.
    let check = check_bvh_retarget(&bvh, &body, &Default::default()).expect("checked");
    assert!(check.passed(), "{:?}", check.failures);
}

#[test]
fn a_skeleton_without_arms_is_an_error_unless_lenient() {
    let text = "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition \
                Zposition Zrotation Yrotation Xrotation\n  JOINT LeftUpLeg\n  {\n    OFFSET 1 \
                -1 0\n    CHANNELS 3 Zrotation Xrotation Yrotation\n    End Site\n    {\n      \
                OFFSET 0 -4 0\n    }\n  }\n  JOINT Tail\n  {\n    OFFSET 0 0 -1\n    CHANNELS 3 \
                Zrotation Xrotation Yrotation\n    End Site\n    {\n      OFFSET 0 0 -1\n    }\n  \
                }\n}\nMOTION\nFrames: 2\nFrame Time: 0.0333333\n0 0 0 0 0 0 0 0 0 0 0 0\n0 0 0 \
                0 0 0 0 0 0 0 0 0\n";
    let bvh = Bvh::parse(text, Path::new("tail.bvh")).expect("parses");
    let why = map_bvh_joints(&bvh).expect_err("no spine with arms");
    assert!(why.contains("arms"), "{why}");
    let body = crate::motion_sources::synthetic_body();
    let e = retarget_bvh(&bvh, &body, &BvhRetargetOptions::default()).expect_err("strict");
    let msg = e.to_string();
    assert!(
        msg.starts_with("tail.bvh:") && msg.contains("Tail") && msg.contains("arms"),
        "{msg}"
    );
    let lenient = BvhRetargetOptions {
        lenient: true,
        keep_tpose_frame: true,
    };
    let (m, report) = retarget_bvh(&bvh, &body, &lenient).expect("lenient");
    assert_eq!(report.dropped_joints, vec!["Tail".to_string()]);
    assert_eq!(report.joint_map.matched_by, BvhJointMatch::Names);
    assert!(m.n_frames() > 0);
}

/// `bvh`'s frames with every joint's local transform `(translation, rotation)` rewritten by
/// `rewrite(joint, …)`, over the hierarchy `joints` (the file's channels: Z, Y, X).
fn rewritten(
    bvh: &Bvh,
    joints: Vec<BvhJoint>,
    rewrite: impl Fn(
        &BvhJoint,
        (Vector3<f64>, UnitQuaternion<f64>),
    ) -> (Vector3<f64>, UnitQuaternion<f64>),
) -> Bvh {
    let mut values = Vec::with_capacity(bvh.values().len());
    for i in 0..bvh.n_frames() {
        for (j, joint) in joints.iter().enumerate() {
            assert!(joint.channels.ends_with(&[
                BvhChannel::Zrotation,
                BvhChannel::Yrotation,
                BvhChannel::Xrotation
            ]));
            let (t, r) = rewrite(joint, bvh.local_transform(i, j));
            if joint.channels.len() == 6 {
                values.extend((t - joint.offset).iter());
            }
            let (x, y, z) = r.euler_angles();
            values.extend([z, y, x].map(f64::to_degrees));
        }
    }
    Bvh::from_parts(
        bvh.path().to_path_buf(),
        joints,
        bvh.frame_time_secs(),
        values,
    )
    .expect("valid")
}

/// `bvh` with its rest pose turned by `turn` about the root and every frame's rotations made up
/// for it, so that every frame's world pose is the same.
fn with_rest_turned(bvh: &Bvh, turn: UnitQuaternion<f64>) -> Bvh {
    let joints: Vec<BvhJoint> = bvh
        .joints()
        .iter()
        .map(|j| {
            let mut j = j.clone();
            if j.parent.is_some() {
                j.offset = turn * j.offset;
            }
            j.end_site = j.end_site.map(|e| turn * e);
            j
        })
        .collect();
    rewritten(bvh, joints, |joint, (t, r)| match joint.parent {
        None => (t, r * turn.inverse()),
        Some(_) => (t, turn * r * turn.inverse()),
    })
}

/// `bvh` with its whole world (the root's rotation and path) turned by `turn`.
fn with_world_turned(bvh: &Bvh, turn: UnitQuaternion<f64>) -> Bvh {
    rewritten(bvh, bvh.joints().to_vec(), |joint, (t, r)| {
        match joint.parent {
            None => (turn * t, turn * r),
            Some(_) => (t, r),
        }
    })
}

#[test]
fn a_rest_pose_that_lies_down_is_stood_up_as_lafan1s_needs() {
    let body = builtin_body();
    let bvh = Bvh::load(&data("cmu/02_04.bvh")).expect("clip");
    // Every bone along +X at rest is how LAFAN1 writes it; here the whole body lies along +X,
    // its left along +Z.
    let turn = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -FRAC_PI_2)
        * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -FRAC_PI_2);
    let lying = with_rest_turned(&bvh, turn);
    // The same world pose in every frame, from other channels.
    for i in [0, bvh.n_frames() / 2, bvh.n_frames() - 1] {
        for (a, b) in lying.world_positions(i).iter().zip(bvh.world_positions(i)) {
            assert!((a - b).norm() < 1e-9, "frame {i}");
        }
    }
    let keep = BvhRetargetOptions {
        lenient: false,
        keep_tpose_frame: true,
    };
    let (_, standing) = retarget_bvh(&bvh, &body, &keep).expect("standing");
    let (_, report) = retarget_bvh(&lying, &body, &keep).expect("stood up");
    assert!(standing.rest_frame.is_none());
    // The rest frame found is the turn, but for CMU's own rest, which leans a little.
    let frame = report.rest_frame.expect("stood up");
    assert!(frame.angle_to(&turn).to_degrees() < 10.0, "{frame:?}");
    // Scaled by the legs' length (thigh and shin) instead of the hip height: the two
    // skeletons' hip sockets and CMU's splayed rest thighs make them differ by 11 % here.
    let ratio = report.translation_scale / standing.translation_scale;
    assert!((ratio - 1.0).abs() < 0.15, "{ratio}");
    // Every bone follows the file's own forward kinematics, the pelvis too (to the
    // precision of an angle from its cosine).
    let check = check_bvh_retarget(&lying, &body, &Default::default()).expect("checked");
    assert!(check.passed(), "{:?}", check.failures);
    assert!(
        check.pelvis_worst_deg < 1e-4 && check.worst_bone_angle_deg() < 1e-4,
        "{} {}",
        check.pelvis_worst_deg,
        check.worst_bone_angle_deg()
    );
    // A rest that lies with a world that does not stand (a Z-up file) is refused.
    let tipped = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2);
    let z_up = with_rest_turned(&with_world_turned(&bvh, tipped), tipped);
    let e = retarget_bvh(&z_up, &body, &keep).expect_err("Z-up");
    assert!(e.to_string().contains("expected a Y-up file"), "{e}");
}

#[test]
fn two_joints_named_for_one_rig_joint_are_an_error() {
    // CMU's `LeftHandIndex1` is the rig's `LeftHandFinger1`: a file with both names.
    let text = std::fs::read_to_string(data("cmu_tiny.bvh")).expect("fixture");
    let both = renamed(&text, |n| {
        (n == "LeftHand").then(|| "LeftHandFinger1".to_string())
    });
    let bvh = Bvh::parse(&both, Path::new("both.bvh")).expect("parses");
    let body = crate::motion_sources::synthetic_body();
    let e = retarget_bvh(&bvh, &body, &BvhRetargetOptions::default()).expect_err("ambiguous");
    let msg = e.to_string();
    assert!(
        msg.starts_with("both.bvh:") && msg.contains("both map onto rig joint"),
        "{msg}"
    );
}

#[test]
fn any_skeleton_is_matched_once_per_rig_joint_or_refused_without_a_panic() {
    use rand::Rng;
    let mut rng = crate::motion_sources::rng(37);
    let cmu = Bvh::load(&data("cmu/02_04.bvh")).expect("clip");
    let zyx = vec![
        BvhChannel::Zrotation,
        BvhChannel::Yrotation,
        BvhChannel::Xrotation,
    ];
    let (mut matched, mut refused) = (0, 0);
    for case in 0..2000 {
        // A random tree (parents before children), offsets often zero, names often sided.
        let n = rng.random_range(1..40);
        let offset = |rng: &mut rand_chacha::ChaCha8Rng| {
            if rng.random_bool(0.2) {
                Vector3::zeros()
            } else {
                Vector3::from_fn(|_, _| rng.random_range(-10.0..10.0))
            }
        };
        let sides = ["Left", "Right", "", "l", "R_", "Neck", "Head"];
        let mut joints = Vec::with_capacity(n);
        if case % 2 == 0 {
            // Any tree.
            for j in 0..n {
                let side = sides[rng.random_range(0..sides.len())];
                joints.push(BvhJoint {
                    name: format!("{side}j{j}"),
                    parent: (j > 0).then(|| rng.random_range(0..j)),
                    offset: offset(&mut rng),
                    channels: zyx.clone(),
                    end_site: rng.random_bool(0.5).then(|| offset(&mut rng)),
                });
            }
        } else {
            // CMU's skeleton with names dropped or changed, bones stretched or zeroed, and
            // extra joints hung anywhere.
            for (j, joint) in cmu.joints().iter().enumerate() {
                let mut joint = joint.clone();
                if rng.random_bool(0.5) {
                    joint.name = format!("{}j{j}", sides[rng.random_range(0..sides.len())]);
                }
                joint.offset *= if rng.random_bool(0.1) {
                    0.0
                } else {
                    rng.random_range(0.3..2.0)
                };
                joints.push(joint);
            }
            for k in 0..n % 6 {
                let parent = rng.random_range(0..joints.len());
                joints.push(BvhJoint {
                    name: format!("extra{k}"),
                    parent: Some(parent),
                    offset: offset(&mut rng),
                    channels: zyx.clone(),
                    end_site: None,
                });
            }
            // Parents before children: the extras hang off earlier joints, appended last.
        }
        let values = vec![0.0; joints.iter().map(|j| j.channels.len()).sum()];
        let bvh = Bvh::from_parts(PathBuf::from("random.bvh"), joints, 1.0 / 30.0, values)
            .expect("valid");
        match map_bvh_joints(&bvh) {
            Ok(map) => {
                matched += 1;
                assert!(map.rig_joints.contains(&Some("Hips")), "case {case}");
                let mut named: Vec<&str> = map.rig_joints.iter().flatten().copied().collect();
                let all = named.len();
                named.sort_unstable();
                named.dedup();
                assert_eq!(named.len(), all, "case {case}: a rig joint driven twice");
            }
            Err(why) => {
                refused += 1;
                assert!(!why.is_empty());
            }
        }
    }
    // Both outcomes are exercised.
    println!("{matched} matched, {refused} refused");
    assert!(
        matched > 200 && refused > 200,
        "{matched} matched, {refused} refused"
    );
}

#[test]
fn hips_under_a_reference_node_and_twist_bones_retarget_as_without_them() {
    // As Unreal's skeletons have: the hips under a static root, and twist bones halfway along
    // the upper arms and forearms (leaves, two children where a hand has fingers).
    let body = builtin_body();
    let bvh = Bvh::load(&data("cmu/02_04.bvh")).expect("clip");
    let zyx = vec![
        BvhChannel::Zrotation,
        BvhChannel::Yrotation,
        BvhChannel::Xrotation,
    ];
    let mut joints = vec![BvhJoint {
        name: "Reference".into(),
        parent: None,
        offset: Vector3::zeros(),
        channels: vec![
            BvhChannel::Xposition,
            BvhChannel::Yposition,
            BvhChannel::Zposition,
            BvhChannel::Zrotation,
            BvhChannel::Yrotation,
            BvhChannel::Xrotation,
        ],
        end_site: None,
    }];
    joints.extend(bvh.joints().iter().map(|j| BvhJoint {
        parent: Some(j.parent.map_or(0, |p| p + 1)),
        ..j.clone()
    }));
    let find = |n: &str| 1 + bvh.joints().iter().position(|j| j.name == n).expect(n);
    let twists = [
        ("LeftArm", "LeftForeArm"),
        ("LeftForeArm", "LeftHand"),
        ("RightArm", "RightForeArm"),
        ("RightForeArm", "RightHand"),
    ];
    for (joint, next) in twists {
        joints.push(BvhJoint {
            name: format!("{joint}Twist"),
            parent: Some(find(joint)),
            offset: 0.5 * joints[find(next)].offset,
            channels: zyx.clone(),
            end_site: Some(Vector3::new(0.1, 0.0, 0.0)),
        });
    }
    let mut values = Vec::new();
    for i in 0..bvh.n_frames() {
        values.extend([0.0; 6]);
        values.extend_from_slice(bvh.frame(i));
        values.extend([0.0; 12]);
    }
    let wrapped = Bvh::from_parts(
        PathBuf::from("reference.bvh"),
        joints,
        bvh.frame_time_secs(),
        values,
    )
    .expect("valid");
    let map = map_bvh_joints(&wrapped).expect("matched");
    assert_eq!(map.matched_by, BvhJointMatch::Structure);
    assert_eq!(map.rig_joints[0], None, "the reference node drives nothing");
    assert_eq!(map.file_joint("Hips"), Some(1));
    assert_eq!(map.file_joint("LeftHand"), Some(find("LeftHand")));
    assert_eq!(map.file_joint("RightForeArm"), Some(find("RightForeArm")));
    let keep = BvhRetargetOptions {
        lenient: false,
        keep_tpose_frame: true,
    };
    let (want, _) = retarget_bvh(&bvh, &body, &keep).expect("plain");
    let (got, _) = retarget_bvh(&wrapped, &body, &keep).expect("wrapped");
    let s = body.skeleton();
    for (a, b) in got.frames().iter().zip(want.frames()) {
        assert_eq!(a.root_translation_m, b.root_translation_m);
        assert_eq!(a.root_orientation, b.root_orientation);
        for (j, (p, q)) in a.local_rotations.iter().zip(&b.local_rotations).enumerate() {
            if !FINGERS_RIG.contains(&s.names()[j].as_str()) {
                assert_eq!(p, q, "joint {}", s.names()[j]);
            }
        }
    }
    let check = check_bvh_retarget(&wrapped, &body, &Default::default()).expect("checked");
    assert!(check.passed(), "{:?}", check.failures);
}

/// The rig's finger joints (no tool's fingers are matched to them).
const FINGERS_RIG: [&str; 6] = [
    "LeftFingerBase",
    "LeftHandFinger1",
    "LThumb",
    "RightFingerBase",
    "RightHandFinger1",
    "RThumb",
];
