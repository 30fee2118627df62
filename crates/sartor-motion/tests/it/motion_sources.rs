//! Motion sources: BVH import and retargeting, AMASS `.npz`, the imported walk cycle, the
//! procedural library and `load_motion`.

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Unit, UnitQuaternion, Vector3};
use npyz::WriterBuilder;
use rand::Rng;
use sartor_core::{FPS, Pose, Skeleton};
use sartor_motion::procedural::{
    HELD_OUT_CLIPS, JOINT_LIMITS_DEG, MAX_ANGULAR_SPEED_RAD_S, clip, clip_names, clip_seeded,
    hinge_axes,
};
use sartor_motion::{
    AmassOptions, Bvh, BvhJointMatch, BvhRetargetOptions, Motion, MotionSourceOptions,
    RetargetBody, UpAxis, cmu_mb_skeleton, load_amass, load_motion, retarget_bvh,
    retarget_bvh_native_rate,
};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub(crate) fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub(crate) fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

pub(crate) fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn deg(x: f64) -> f64 {
    x.to_radians()
}

/// A made-up A-pose layout of the 31 `cmu_mb` joints (arms 45° down, in the XY plane; the
/// forearm continues the upper arm), metres.
fn a_pose_joints(s: &Skeleton) -> Vec<Vector3<f64>> {
    let c = std::f64::consts::FRAC_1_SQRT_2;
    let mut p = vec![Vector3::zeros(); s.n_joints()];
    let mut set = |n: &str, x: f64, y: f64, z: f64| {
        p[s.index_of(n).expect(n)] = Vector3::new(x, y, z);
    };
    set("Hips", 0.0, 1.0, 0.0);
    set("LowerBack", 0.0, 1.08, -0.01);
    set("Spine", 0.0, 1.22, -0.01);
    set("Spine1", 0.0, 1.38, 0.0);
    set("Neck", 0.0, 1.55, 0.0);
    set("Neck1", 0.0, 1.6, 0.01);
    set("Head", 0.0, 1.66, 0.02);
    for (side, sx) in [("Left", 1.0), ("Right", -1.0)] {
        let h = if side == "Left" { "L" } else { "R" };
        set(&format!("{h}HipJoint"), 0.0, 1.0, 0.0);
        set(&format!("{side}UpLeg"), 0.1 * sx, 0.95, 0.0);
        set(&format!("{side}Leg"), 0.11 * sx, 0.52, 0.01);
        set(&format!("{side}Foot"), 0.12 * sx, 0.1, 0.0);
        set(&format!("{side}ToeBase"), 0.12 * sx, 0.02, 0.12);
        set(&format!("{side}Shoulder"), 0.03 * sx, 1.5, 0.0);
        let arm = Vector3::new(0.17 * sx, 1.48, 0.0);
        let dir = Vector3::new(c * sx, -c, 0.0);
        let at = |d: f64| arm + d * dir;
        set(&format!("{side}Arm"), arm.x, arm.y, arm.z);
        let e = at(0.28);
        set(&format!("{side}ForeArm"), e.x, e.y, e.z);
        let w = at(0.53);
        set(&format!("{side}Hand"), w.x, w.y, w.z);
        let f = at(0.6);
        set(&format!("{side}FingerBase"), f.x, f.y, f.z);
        let f1 = at(0.64);
        set(&format!("{side}HandFinger1"), f1.x, f1.y, f1.z);
        let t = at(0.56) + Vector3::new(0.0, 0.0, 0.02);
        set(&format!("{h}Thumb"), t.x, t.y, t.z);
    }
    p
}

/// A synthetic T-pose for that layout: arms raised 45° to horizontal, legs slightly together.
fn synthetic_tpose(s: &Skeleton) -> Pose {
    let mut pose = Pose::rest(s.n_joints());
    let z = |a: f64| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a);
    pose.local_rotations[s.index_of("LeftArm").expect("j")] = z(deg(45.0));
    pose.local_rotations[s.index_of("RightArm").expect("j")] = z(deg(-45.0));
    pose.local_rotations[s.index_of("LeftUpLeg").expect("j")] = z(deg(-2.0));
    pose.local_rotations[s.index_of("RightUpLeg").expect("j")] = z(deg(2.0));
    pose
}

pub fn synthetic_body() -> RetargetBody {
    let s = cmu_mb_skeleton();
    let joints = a_pose_joints(&s);
    let tpose = synthetic_tpose(&s);
    RetargetBody::new(s, joints, tpose).expect("valid body")
}

fn fixture_text() -> String {
    std::fs::read_to_string(data("cmu_tiny.bvh")).expect("fixture")
}

pub fn posed_joints(body: &RetargetBody, pose: &Pose) -> Vec<Vector3<f64>> {
    body.skeleton()
        .forward_kinematics(body.rest_joints_m(), pose)
        .expect("fk")
        .0
}

fn bone_dir(joints: &[Vector3<f64>], s: &Skeleton, from: &str, to: &str) -> Vector3<f64> {
    (joints[s.index_of(to).expect(to)] - joints[s.index_of(from).expect(from)]).normalize()
}

fn assert_pose_close(a: &Pose, b: &Pose, tol: f64) {
    assert!(a.root_orientation.angle_to(&b.root_orientation) < tol);
    assert!((a.root_translation_m - b.root_translation_m).norm() < tol);
    for (j, (p, q)) in a.local_rotations.iter().zip(&b.local_rotations).enumerate() {
        assert!(p.angle_to(q) < tol, "joint {j}: {}", p.angle_to(q));
    }
}

/// Keep every frame (the fixture's frame 0 is a T-pose the detector would drop).
const KEEP: BvhRetargetOptions = BvhRetargetOptions {
    lenient: false,
    keep_tpose_frame: true,
};

#[test]
fn bvh_rest_frame_puts_posture_bones_along_the_offsets() {
    let body = synthetic_body();
    let bvh = Bvh::load(&data("cmu_tiny.bvh")).expect("parse fixture");
    assert_eq!(bvh.joints().len(), 23);
    let (m, report) = retarget_bvh_native_rate(&bvh, &body, &KEEP).expect("retarget");
    assert_eq!(m.n_frames(), 3);
    assert!(
        (report.source_fps - 30.0).abs() < 1e-9,
        "rate snapped to 30"
    );
    assert!(!report.turned_around);
    assert!(report.dropped_joints.is_empty());
    // The fixture's frame 0 (all zero) is a T-pose and jumps 90° to frame 1: detected, kept.
    let t = report.tpose_frame.as_ref().expect("measured");
    assert!(t.is_added_tpose && !report.tpose_frame_dropped, "{t:?}");
    // Rig joints the file lacks: toes, Neck1, fingers of the right hand, thumbs.
    assert!(report.undriven_joints.contains(&"Neck1".to_string()));
    assert!(
        !report
            .undriven_joints
            .contains(&"LeftHandFinger1".to_string())
    );
    // Frame 0 is the file's rest: every posture bone along the file's offset (arms along ±X,
    // legs straight down), whatever our rest and T-pose say.
    let s = body.skeleton();
    let j = posed_joints(&body, &m.frames()[0]);
    for (a, b, want) in [
        ("LeftArm", "LeftForeArm", Vector3::x()),
        ("LeftForeArm", "LeftHand", Vector3::x()),
        ("RightArm", "RightForeArm", -Vector3::x()),
        ("LeftUpLeg", "LeftLeg", -Vector3::y()),
        ("RightLeg", "RightFoot", -Vector3::y()),
        ("LowerBack", "Spine", Vector3::y()),
    ] {
        assert!((bone_dir(&j, s, a, b) - want).norm() < 1e-9, "{a}->{b}");
    }
    // Proportion joints keep their rest relation to their parent.
    for name in ["LHipJoint", "RHipJoint", "LeftShoulder", "Neck1", "Head"] {
        let q = m.frames()[0].local_rotations[s.index_of(name).expect("joint")];
        assert!(q.angle() < 1e-9, "{name}: {}", q.angle());
    }
    // By default the T-pose frame is dropped: the motion starts at the file's frame 1, at the
    // origin.
    let (d, report) =
        retarget_bvh_native_rate(&bvh, &body, &BvhRetargetOptions::default()).expect("drop");
    assert!(report.tpose_frame_dropped);
    assert_eq!(d.n_frames(), 2);
    assert_pose_close(
        &d.frames()[1],
        &Pose {
            root_translation_m: m.frames()[2].root_translation_m - m.frames()[1].root_translation_m,
            ..m.frames()[2].clone()
        },
        1e-9,
    );
    assert!(d.frames()[0].root_translation_m.norm() < 1e-12);
}

#[test]
fn a_take_that_starts_in_a_tpose_keeps_its_first_frame() {
    // Frame 1 equal to frame 0 (a T-pose held): no jump, nothing dropped.
    let body = synthetic_body();
    let text = fixture_text();
    let (head, frames) = text.split_once("Frame Time: 0.0333333\n").expect("frames");
    let lines: Vec<&str> = frames.lines().collect();
    let held = format!(
        "{}Frame Time: 0.0333333\n{}\n{}\n{}\n",
        head, lines[0], lines[0], lines[2]
    );
    let bvh = Bvh::parse(&held, Path::new("held.bvh")).expect("parse");
    let (m, report) =
        retarget_bvh_native_rate(&bvh, &body, &BvhRetargetOptions::default()).expect("retarget");
    let t = report.tpose_frame.expect("measured");
    assert!(t.legs_from_vertical_deg < 1e-6 && t.arms_from_horizontal_deg < 1e-6);
    assert!(t.jump_to_next_deg < 1e-6 && !t.is_added_tpose);
    assert!(!report.tpose_frame_dropped);
    assert_eq!(m.n_frames(), 3);
    // A first frame that is not a T-pose (the fixture's frame 1, elbow bent) is kept too.
    let bent = format!(
        "{}Frame Time: 0.0333333\n{}\n{}\n{}\n",
        head, lines[1], lines[0], lines[2]
    );
    let bvh = Bvh::parse(&bent, Path::new("bent.bvh")).expect("parse");
    let (m, report) =
        retarget_bvh_native_rate(&bvh, &body, &BvhRetargetOptions::default()).expect("retarget");
    let t = report.tpose_frame.expect("measured");
    assert!(
        t.arms_from_horizontal_deg > 80.0 && !t.is_added_tpose,
        "{t:?}"
    );
    assert_eq!(m.n_frames(), 3);
}

#[test]
fn bvh_known_bend_and_root_motion_come_through() {
    let body = synthetic_body();
    let bvh = Bvh::load(&data("cmu_tiny.bvh")).expect("parse fixture");
    let (m, report) = retarget_bvh_native_rate(&bvh, &body, &KEEP).expect("retarget");
    let s = body.skeleton();
    // Frame 1: the left elbow bent 90° forward, the upper arm still horizontal.
    let j = posed_joints(&body, &m.frames()[1]);
    assert!((bone_dir(&j, s, "LeftArm", "LeftForeArm") - Vector3::x()).norm() < 1e-9);
    assert!((bone_dir(&j, s, "LeftForeArm", "LeftHand") - Vector3::z()).norm() < 1e-9);
    // The expected local rotation: θ = C_arm⁻¹ · Ry(−90°) · C_forearm, with C the world
    // rotations of the rest frame (frame 0).
    let c = sartor_motion::world_rotations(s, &m.frames()[0]);
    let (arm, fore) = (
        s.index_of("LeftArm").expect("j"),
        s.index_of("LeftForeArm").expect("j"),
    );
    let want = c[arm].inverse()
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg(-90.0))
        * c[fore];
    assert!(m.frames()[1].local_rotations[fore].angle_to(&want) < 1e-9);
    // Root translation scaled by the hip heights, both in the file's rest posture (15.5 file
    // units ↔ ours with the legs turned straight down like the file's).
    let scale = body.hip_height_in_m(&c).expect("hip height") / 15.5;
    assert!((report.translation_scale - scale).abs() < 1e-12);
    let t = m.frames()[1].root_translation_m;
    assert!(
        (t - Vector3::new(2.0, 0.5, 3.0) * scale).norm() < 1e-9,
        "{t:?}"
    );
    // Frame 2: heading 30° to the left, the left knee bent 45° (the foot goes back).
    let f2 = &m.frames()[2];
    let heading = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg(30.0));
    assert!(f2.root_orientation.angle_to(&heading) < 1e-9);
    assert!(f2.local_rotations[0].angle() < 1e-9);
    let g = sartor_motion::world_rotations(s, f2);
    let leg = s.index_of("LeftLeg").expect("j");
    let knee = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), deg(45.0));
    assert!(g[leg].angle_to(&(heading * knee * c[leg])).abs() < 1e-9);
    let j = posed_joints(&body, f2);
    let shin = bone_dir(&j, s, "LeftLeg", "LeftFoot");
    let fwd = heading * Vector3::z();
    assert!(shin.dot(&fwd) < -0.5, "the shin swings back");
    // Resampled to 30 fps: the same three frames.
    let (r, _) = retarget_bvh(&bvh, &body, &KEEP).expect("resampled");
    assert_eq!(r.fps(), FPS);
    assert_eq!(r.n_frames(), 3);
}

/// Euler angles (degrees) of `r` for BVH channel order `order` (e.g. `"ZXY"`: `R = Rz·Rx·Ry`).
fn euler_for_order(r: &UnitQuaternion<f64>, order: &str) -> [f64; 3] {
    let axis = |c: char| -> Vector3<f64> {
        match c {
            'X' => Vector3::x(),
            'Y' => Vector3::y(),
            _ => Vector3::z(),
        }
    };
    let o: Vec<char> = order.chars().collect();
    // P maps the order's axes (a, b, c) onto (z, y, x); P·R·Pᵀ = Rz·Ry·Rx with angles × det P.
    let p = nalgebra::Matrix3::from_rows(&[
        axis(o[2]).transpose(),
        axis(o[1]).transpose(),
        axis(o[0]).transpose(),
    ]);
    let sign = p.determinant();
    let m = p * r.to_rotation_matrix().into_inner() * p.transpose();
    let (roll, pitch, yaw) = Rotation3::from_matrix_unchecked(m).euler_angles();
    [yaw, pitch, roll].map(|a: f64| (sign * a).to_degrees())
}

/// The fixture's hierarchy with channel order `order` and the given per-joint rotations.
fn bvh_with_order(order: &str, frames: &[(Vector3<f64>, Vec<UnitQuaternion<f64>>)]) -> String {
    let text = fixture_text();
    let names: Vec<String> = order.chars().map(|c| format!("{c}rotation")).collect();
    let hierarchy: String = text
        .split("MOTION")
        .next()
        .expect("hierarchy")
        .replace("Zrotation Yrotation Xrotation", &names.join(" "));
    let mut out = format!(
        "{hierarchy}MOTION\nFrames: {}\nFrame Time: 0.0333333\n",
        frames.len()
    );
    for (root, rots) in frames {
        let mut v = vec![root.x, root.y, root.z];
        for q in rots {
            v.extend(euler_for_order(q, order));
        }
        let line: Vec<String> = v.iter().map(|x| format!("{x:.17e}")).collect();
        out.push_str(&line.join(" "));
        out.push('\n');
    }
    out
}

#[test]
fn bvh_channel_order_does_not_change_the_motion() {
    let body = synthetic_body();
    let mut r = rng(7);
    let frames: Vec<(Vector3<f64>, Vec<UnitQuaternion<f64>>)> = (0..4)
        .map(|_| {
            let root = Vector3::new(r.random_range(-1.0..1.0), 15.0, r.random_range(-1.0..1.0));
            let rots = (0..23)
                .map(|_| {
                    let axis = Vector3::new(
                        r.random_range(-1.0..1.0),
                        r.random_range(-1.0..1.0),
                        r.random_range(-1.0..1.0),
                    );
                    UnitQuaternion::from_axis_angle(
                        &Unit::new_normalize(axis),
                        r.random_range(-1.2..1.2),
                    )
                })
                .collect();
            (root, rots)
        })
        .collect();
    let motion = |order: &str| {
        let text = bvh_with_order(order, &frames);
        let bvh = Bvh::parse(&text, Path::new(&format!("{order}.bvh"))).expect("parse");
        // The file really encodes the rotations.
        for (i, (_, rots)) in frames.iter().enumerate() {
            for (j, q) in rots.iter().enumerate() {
                assert!(bvh.local_transform(i, j).1.angle_to(q) < 1e-9, "{order}");
            }
        }
        retarget_bvh_native_rate(&bvh, &body, &KEEP)
            .expect("retarget")
            .0
    };
    let reference = motion("ZYX");
    for order in ["ZXY", "XYZ", "YZX"] {
        let m = motion(order);
        for (a, b) in m.frames().iter().zip(reference.frames()) {
            assert_pose_close(a, b, 1e-9);
        }
    }
}

/// The 1-based line of the first line of `text` containing `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).expect(needle) + 1
}

#[test]
fn malformed_bvh_errors_name_file_and_line() {
    let good = fixture_text();
    let n_lines = good.lines().count();
    let frames_at = line_of(&good, "Frames:");
    let first_data = frames_at + 2;
    let mut cases: Vec<(&str, String, usize)> = Vec::new();
    // Truncated in the hierarchy.
    let cut: String = good.lines().take(40).collect::<Vec<_>>().join("\n");
    cases.push(("truncated hierarchy", cut, 40));
    // Truncated frames: the last frame line missing.
    let cut: String = good
        .lines()
        .take(n_lines - 1)
        .collect::<Vec<_>>()
        .join("\n");
    cases.push(("truncated frames", cut, n_lines - 1));
    // Frame count mismatch both ways.
    cases.push((
        "more frames declared",
        good.replace("Frames: 3", "Frames: 4"),
        n_lines,
    ));
    cases.push((
        "fewer frames declared",
        good.replace("Frames: 3", "Frames: 2"),
        first_data + 2,
    ));
    // Wrong channel counts.
    let lhip = line_of(&good, "JOINT LeftUpLeg") + 3;
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    lines[lhip - 1] = lines[lhip - 1].replace("CHANNELS 3", "CHANNELS 4");
    cases.push(("count too large", lines.join("\n"), lhip + 1));
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    lines[lhip - 1] = lines[lhip - 1].replace("CHANNELS 3", "CHANNELS 2");
    cases.push(("count too small", lines.join("\n"), lhip));
    // Unknown channel name.
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    lines[lhip - 1] = lines[lhip - 1].replace("Yrotation", "Wrotation");
    cases.push(("unknown channel", lines.join("\n"), lhip));
    // Duplicate joint name.
    let dup = line_of(&good, "JOINT RightShoulder");
    cases.push((
        "duplicate joint",
        good.replace("JOINT RightShoulder", "JOINT LeftShoulder"),
        dup,
    ));
    // Non-numeric and non-finite values, and a short frame line.
    for (what, bad) in [("non-numeric", "abc"), ("nan", "nan"), ("infinite", "inf")] {
        let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
        lines[first_data] = lines[first_data].replacen("16", bad, 1);
        cases.push((what, lines.join("\n"), first_data + 1));
    }
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    lines[first_data] = lines[first_data].replacen("2 16 3 ", "2 16 ", 1);
    cases.push(("short frame", lines.join("\n"), first_data + 1));
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    lines[line_of(&good, "OFFSET 0 -7 0") - 1] = "        OFFSET 0 x 0".into();
    cases.push((
        "bad offset",
        lines.join("\n"),
        line_of(&good, "OFFSET 0 -7 0"),
    ));
    for (what, text, line) in cases {
        let e = Bvh::parse(&text, Path::new("tiny.bvh")).expect_err(what);
        let msg = e.to_string();
        assert!(
            msg.starts_with(&format!("tiny.bvh:{line}:")),
            "{what}: expected line {line}: {msg}"
        );
    }
    // A missing file names it.
    let e = Bvh::load(Path::new("no/such.bvh")).expect_err("missing");
    assert!(e.to_string().contains("no/such.bvh"));
}

#[test]
fn a_joint_the_rig_lacks_is_matched_to_nothing_and_reported() {
    let body = synthetic_body();
    let good = fixture_text();
    let (hier, motion) = good.split_once("MOTION").expect("sections");
    let hier = hier.trim_end().strip_suffix('}').expect("closing brace");
    let extra = "  JOINT LeftWing\n  {\n    OFFSET 1 0 0\n    CHANNELS 3 Zrotation Yrotation \
                 Xrotation\n    End Site\n    {\n      OFFSET 1 0 0\n    }\n  }\n}\n";
    let frames: Vec<String> = motion
        .lines()
        .map(|l| {
            if l.starts_with(|c: char| c.is_ascii_digit() || c == '-') {
                format!("{l} 0 0 10")
            } else {
                l.to_string()
            }
        })
        .collect();
    let text = format!("{hier}{extra}MOTION{}\n", frames.join("\n"));
    let bvh = Bvh::parse(&text, Path::new("wing.bvh")).expect("parses");
    // Not every joint has a rig joint's name: matched by the skeleton's structure, the wing
    // drives nothing and the poses are the file's without it, bit for bit.
    let (m, report) = retarget_bvh(&bvh, &body, &KEEP).expect("by structure");
    assert_eq!(report.joint_map.matched_by, BvhJointMatch::Structure);
    // The wing, and the finger no tool names alike.
    assert_eq!(report.dropped_joints, ["LeftHandIndex1", "LeftWing"]);
    let plain = Bvh::parse(&good, Path::new("plain.bvh")).expect("parses");
    let (want, _) = retarget_bvh(&plain, &body, &KEEP).expect("by name");
    assert_eq!(m.n_frames(), 3);
    let finger = body.skeleton().index_of("LeftHandFinger1").expect("finger");
    for (a, b) in m.frames().iter().zip(want.frames()) {
        assert_eq!(a.root_translation_m, b.root_translation_m);
        assert_eq!(a.root_orientation, b.root_orientation);
        for (j, (p, q)) in a.local_rotations.iter().zip(&b.local_rotations).enumerate() {
            if j != finger {
                assert_eq!(p, q, "joint {j}");
            }
        }
    }
}

#[test]
fn bvh_facing_minus_z_is_turned_around() {
    // Mirror the fixture's X offsets: the left side on −X means the subject faces −Z.
    let body = synthetic_body();
    let text = fixture_text();
    let (hier, motion) = text.split_once("MOTION").expect("sections");
    let mirrored: Vec<String> = hier
        .lines()
        .map(|l| {
            let t = l.trim_start();
            if let Some(rest) = t.strip_prefix("OFFSET ") {
                let v: Vec<f64> = rest
                    .split_whitespace()
                    .map(|x| x.parse().expect("number"))
                    .collect();
                format!("OFFSET {} {} {}", -v[0], v[1], -v[2])
            } else {
                l.to_string()
            }
        })
        .collect();
    let text = format!("{}\nMOTION{motion}", mirrored.join("\n"));
    let bvh = Bvh::parse(&text, Path::new("mirrored.bvh")).expect("parse");
    let (m, report) = retarget_bvh_native_rate(&bvh, &body, &KEEP).expect("retarget");
    assert!(report.turned_around);
    // The mirrored file's rest is the original's turned 180° about +Y: turned back, frame 0
    // (all zero) is the same pose.
    let original = Bvh::load(&data("cmu_tiny.bvh")).expect("parse fixture");
    let (o, _) = retarget_bvh_native_rate(&original, &body, &KEEP).expect("retarget");
    assert_pose_close(&m.frames()[0], &o.frames()[0], 1e-9);
}

// ---------------------------------------------------------------------------------------------
// AMASS

/// Named arrays to write into an `.npz`: name, shape, values.
type NpzArrays = Vec<(&'static str, Vec<u64>, Vec<f64>)>;

pub fn write_npz(path: &Path, arrays: &[(&str, Vec<u64>, Vec<f64>)]) {
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).expect("create"));
    for (name, shape, values) in arrays {
        zip.start_file(format!("{name}.npy"), zip::write::FileOptions::default())
            .expect("entry");
        let mut w = npyz::WriteOptions::<f64>::new()
            .default_dtype()
            .shape(shape)
            .writer(&mut zip)
            .begin_nd()
            .expect("begin");
        w.extend(values.iter().copied()).expect("write");
        w.finish().expect("finish");
    }
    zip.finish().expect("the archive's directory");
}

/// Three SMPL frames: T-pose; left elbow bent 90° forward + translation; a turned root.
fn amass_arrays(width: usize, root: UnitQuaternion<f64>) -> NpzArrays {
    let n = 3;
    let mut poses = vec![0.0; n * width];
    let mut set = |frame: usize, joint: usize, q: UnitQuaternion<f64>| {
        let v = q.scaled_axis();
        poses[frame * width + 3 * joint..frame * width + 3 * joint + 3]
            .copy_from_slice(v.as_slice());
    };
    for f in 0..n {
        set(f, 0, root);
    }
    set(
        1,
        18,
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg(-90.0)),
    );
    set(
        2,
        0,
        root * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg(40.0)),
    );
    let mut trans = Vec::new();
    for f in 0..n {
        let t = Vector3::new(0.1 * f as f64, 0.9 + 0.05 * f as f64, 0.0);
        trans.extend([t.x, t.y, t.z]);
    }
    vec![
        ("poses", vec![n as u64, width as u64], poses),
        ("trans", vec![n as u64, 3], trans),
        ("mocap_framerate", vec![], vec![60.0]),
        ("betas", vec![16], vec![0.1; 16]),
    ]
}

#[test]
fn amass_retargets_tpose_bend_and_up_axis() {
    let dir = tempfile::tempdir().expect("tmp");
    let body = synthetic_body();
    let s = body.skeleton();
    let y_path = dir.path().join("y_up.npz");
    write_npz(&y_path, &amass_arrays(156, UnitQuaternion::identity()));
    let data = sartor_motion::AmassData::read(&y_path).expect("read");
    assert_eq!(data.n_pose_joints, 52);
    assert_eq!(data.betas.as_ref().map(Vec::len), Some(16));
    let m = sartor_motion::retarget_amass_native_rate(&data, "y", &body, &AmassOptions::default())
        .expect("retarget");
    assert_pose_close(&m.frames()[0], body.tpose(), 1e-6);
    let j = posed_joints(&body, &m.frames()[1]);
    assert!((bone_dir(&j, s, "LeftArm", "LeftForeArm") - Vector3::x()).norm() < 1e-9);
    assert!((bone_dir(&j, s, "LeftForeArm", "LeftHand") - Vector3::z()).norm() < 1e-9);
    assert!((m.frames()[1].root_translation_m - Vector3::new(0.1, 0.05, 0.0)).norm() < 1e-9);
    let heading = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg(40.0));
    assert!(m.frames()[2].root_orientation.angle_to(&heading) < 1e-9);
    // Resampled from 60 to 30 fps.
    let r = load_amass(&y_path, &body, &AmassOptions::default()).expect("load");
    assert_eq!((r.fps(), r.n_frames()), (FPS, 2));
    // The same motion stored Z-up (AMASS style) and read with UpAxis::Z, as SMPL (72 values).
    let z_path = dir.path().join("z_up.npz");
    let to_z = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), deg(90.0));
    let mut arrays = amass_arrays(72, to_z);
    // AMASS Z-up translations: rotate ours by +90° about X.
    let t = &mut arrays[1].2;
    for c in t.chunks_exact_mut(3) {
        let v = to_z * Vector3::new(c[0], c[1], c[2]);
        c.copy_from_slice(v.as_slice());
    }
    write_npz(&z_path, &arrays);
    let opts = AmassOptions {
        up_axis: UpAxis::Z,
        ..AmassOptions::default()
    };
    let data = sartor_motion::AmassData::read(&z_path).expect("read z");
    let mz = sartor_motion::retarget_amass_native_rate(&data, "z", &body, &opts).expect("z");
    for (a, b) in mz.frames().iter().zip(m.frames()) {
        assert_pose_close(a, b, 1e-9);
    }
}

#[test]
fn malformed_amass_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().expect("tmp");
    let body = synthetic_body();
    let good = amass_arrays(72, UnitQuaternion::identity());
    let variant = |name: &str, f: &dyn Fn(&mut NpzArrays)| {
        let mut a = good.clone();
        f(&mut a);
        let path = dir.path().join(format!("{name}.npz"));
        write_npz(&path, &a);
        let e = load_amass(&path, &body, &AmassOptions::default()).expect_err(name);
        let msg = e.to_string();
        assert!(msg.contains(&format!("{name}.npz")), "{name}: {msg}");
        msg
    };
    let m = variant("no_trans", &|a| a.retain(|(n, _, _)| *n != "trans"));
    assert!(m.contains("trans"), "{m}");
    let m = variant("no_rate", &|a| {
        a.retain(|(n, _, _)| *n != "mocap_framerate")
    });
    assert!(m.contains("mocap_framerate"), "{m}");
    let m = variant("bad_width", &|a| {
        a[0].1 = vec![3, 24];
        a[0].2.truncate(72);
    });
    assert!(m.contains("poses"), "{m}");
    let m = variant("bad_trans", &|a| {
        a[1].1 = vec![3, 2];
        a[1].2.truncate(6);
    });
    assert!(m.contains("trans"), "{m}");
    let m = variant("nan_pose", &|a| a[0].2[5] = f64::NAN);
    assert!(m.contains("non-finite"), "{m}");
    let m = variant("zero_rate", &|a| a[2].2[0] = 0.0);
    assert!(m.contains("frame rate"), "{m}");
    // The alternative frame-rate key is accepted.
    let path = dir.path().join("alt_key.npz");
    let mut a = good.clone();
    a[2].0 = "mocap_frame_rate";
    write_npz(&path, &a);
    load_amass(&path, &body, &AmassOptions::default()).expect("mocap_frame_rate");
    // Truncated archive.
    let full = dir.path().join("full.npz");
    write_npz(&full, &good);
    let bytes = std::fs::read(&full).expect("read");
    let cut = dir.path().join("cut.npz");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).expect("write");
    let e = load_amass(&cut, &body, &AmassOptions::default()).expect_err("truncated");
    assert!(e.to_string().contains("cut.npz"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// The walk cycle

#[test]
fn walk_moves_forward_with_alternating_feet() {
    let committed = workspace_root().join("datasets/motions/walk.json");
    let m = Motion::load_json(&committed).expect("walk.json");
    assert_eq!(m.fps(), FPS);
    assert!(m.duration_secs() >= 4.0);
    let s = cmu_mb_skeleton();
    let rest = a_pose_joints(&s);
    let (lf, rf) = (
        s.index_of("LeftFoot").expect("j"),
        s.index_of("RightFoot").expect("j"),
    );
    let mut ahead = Vec::new();
    let mut last_z = f64::NEG_INFINITY;
    for (i, f) in m.frames().iter().enumerate() {
        let z = f.root_translation_m.z;
        if i % 15 == 0 {
            assert!(z > last_z - 1e-3, "the root moves forward: frame {i}");
            last_z = z;
        }
        let (j, _) = s.forward_kinematics(&rest, f).expect("fk");
        ahead.push(j[lf].z - j[rf].z);
    }
    let total = m.frames()[m.n_frames() - 1].root_translation_m.z;
    assert!(total > 2.0, "travels {total} m");
    let sign_changes = ahead
        .windows(2)
        .filter(|w| w[0].signum() != w[1].signum())
        .count();
    assert!(
        sign_changes >= 6,
        "feet alternate: {sign_changes} crossings"
    );
    let amp = ahead.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
    assert!(amp > 0.2, "steps of {amp} m");
}

// ---------------------------------------------------------------------------------------------
// The procedural library

#[test]
fn procedural_library_is_complete_and_named() {
    let names = clip_names();
    assert!(names.len() >= 56, "{} clips", names.len());
    let mut sorted = names.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted.len(), names.len(), "names are unique");
    for h in HELD_OUT_CLIPS {
        assert!(names.iter().any(|n| n == h), "held-out clip {h} exists");
    }
    let e = clip("no_such_clip").expect_err("unknown");
    assert!(e.to_string().contains("no_such_clip"));
}

#[test]
fn procedural_clips_are_long_smooth_deterministic_and_within_limits() {
    let s = cmu_mb_skeleton();
    let hinges = hinge_axes();
    for name in clip_names() {
        let m = clip(&name).expect("clip");
        assert_eq!(m.fps(), FPS);
        assert!(
            m.duration_secs() >= 4.0 - 1e-9,
            "{name}: {} s",
            m.duration_secs()
        );
        assert_eq!(m.joint_names(), s.names());
        assert_eq!(m, clip(&name).expect("again"), "{name} is deterministic");
        let other = clip_seeded(&name, 12345).expect("seeded");
        assert_ne!(m, other, "{name}: the seed matters");
        assert_eq!(other, clip_seeded(&name, 12345).expect("seeded"));
        for (k, f) in m.frames().iter().enumerate() {
            assert!(f.root_translation_m.iter().all(|x| x.is_finite()));
            for (j, q) in f.local_rotations.iter().enumerate() {
                assert!((q.as_ref().norm() - 1.0).abs() < 1e-9);
                let limit = JOINT_LIMITS_DEG[j].1.to_radians() + 1e-9;
                assert!(
                    q.angle() <= limit,
                    "{name} frame {k}: {} at {:.1}° > {}°",
                    JOINT_LIMITS_DEG[j].0,
                    q.angle().to_degrees(),
                    JOINT_LIMITS_DEG[j].1
                );
            }
            for (joint, axis) in &hinges {
                let q = f.local_rotations[s.index_of(joint).expect("hinge")];
                let v = q.scaled_axis();
                let angle = v.dot(axis);
                assert!(angle >= -1e-9, "{name} frame {k}: {joint} hyper-extends");
                assert!(
                    (v - angle * axis).norm() < 1e-9,
                    "{name}: {joint} is a hinge"
                );
            }
            // Feet stay near the ground: the pelvis never drops below a deep squat.
            assert!(
                f.root_translation_m.y > -0.7,
                "{name}: pelvis at {}",
                f.root_translation_m.y
            );
        }
        // Angular speed and acceleration (C1: no velocity jumps).
        let dt = 1.0 / m.fps();
        let speed = |a: &Pose, b: &Pose, j: usize| -> f64 {
            let (p, q) = if j == usize::MAX {
                (a.root_orientation, b.root_orientation)
            } else {
                (a.local_rotations[j], b.local_rotations[j])
            };
            p.angle_to(&q) / dt
        };
        let mut max_acc = 0.0_f64;
        let mut max_speed = 0.0_f64;
        let mut max_lin_acc = 0.0_f64;
        for w in m.frames().windows(3) {
            for j in (0..s.n_joints()).chain([usize::MAX]) {
                let v0 = speed(&w[0], &w[1], j);
                let v1 = speed(&w[1], &w[2], j);
                max_speed = max_speed.max(v1);
                // A lower bound of |Δω|; a velocity jump shows up as a spike.
                max_acc = max_acc.max((v1 - v0).abs() / dt);
            }
            let a = (w[2].root_translation_m - 2.0 * w[1].root_translation_m
                + w[0].root_translation_m)
                / (dt * dt);
            max_lin_acc = max_lin_acc.max(a.norm());
        }
        assert!(
            max_speed < MAX_ANGULAR_SPEED_RAD_S,
            "{name}: {max_speed} rad/s"
        );
        assert!(
            max_acc < 400.0,
            "{name}: angular acceleration {max_acc} rad/s²"
        );
        assert!(
            max_lin_acc < 40.0,
            "{name}: root acceleration {max_lin_acc} m/s²"
        );
    }
}

#[test]
fn a_ten_minute_concatenation_samples_and_resamples_finite() {
    let names = clip_names();
    let mut frames: Vec<Pose> = Vec::new();
    let mut offset = Vector3::zeros();
    let mut k = 0;
    while frames.len() < 10 * 60 * 30 + 1 {
        let m = clip(&names[k % names.len()]).expect("clip");
        let last = m.frames()[m.n_frames() - 1].root_translation_m;
        for f in m.frames() {
            let mut f = f.clone();
            f.root_translation_m += offset;
            frames.push(f);
        }
        offset += Vector3::new(last.x, 0.0, last.z);
        k += 1;
    }
    let long = Motion::new(
        "long".into(),
        FPS,
        cmu_mb_skeleton().names().to_vec(),
        frames,
    )
    .expect("valid");
    assert!(long.duration_secs() >= 600.0);
    for fps in [24.0, 60.0, 120.0] {
        let r = long.resample(fps).expect("resample");
        assert!((r.duration_secs() - long.duration_secs()).abs() <= 1.0 / fps);
        for f in r.frames() {
            f.validate(31).expect("finite unit rotations");
        }
    }
    let mut r = rng(3);
    for _ in 0..2000 {
        let t = r.random_range(-1.0..long.duration_secs() + 1.0);
        long.sample(t).validate(31).expect("finite sample");
    }
}

#[test]
fn load_motion_understands_every_kind_of_spec() {
    let body = synthetic_body();
    let opts = MotionSourceOptions {
        motions_dir: workspace_root().join("datasets/motions"),
        body: Some(body.clone()),
        lenient: false,
        up_axis: UpAxis::Y,
        keep_tpose_frame: false,
    };
    let m = load_motion("squat_deep", &opts).expect("procedural");
    assert_eq!(m.name(), "squat_deep");
    let m = load_motion(data("cmu_tiny.bvh").to_str().expect("utf8"), &opts).expect("bvh");
    assert_eq!((m.name(), m.fps()), ("cmu_tiny", FPS));
    let walk = workspace_root().join("datasets/motions/walk.json");
    if walk.exists() {
        let m = load_motion("walk", &opts).expect("walk");
        assert_eq!(m.name(), "walk");
    }
    let dir = tempfile::tempdir().expect("tmp");
    let npz = dir.path().join("clip.npz");
    write_npz(&npz, &amass_arrays(72, UnitQuaternion::identity()));
    let m = load_motion(npz.to_str().expect("utf8"), &opts).expect("npz");
    assert_eq!(m.fps(), FPS);
    let json = dir.path().join("saved.json");
    clip("idle").expect("idle").save_json(&json).expect("save");
    // (serde_json parses floats to within an ulp, not always bit for bit.)
    let loaded = load_motion(json.to_str().expect("utf8"), &opts).expect("json");
    for (a, b) in loaded
        .frames()
        .iter()
        .zip(clip("idle").expect("idle").frames())
    {
        assert_pose_close(a, b, 1e-12);
    }
    let e = load_motion("x.npz", &MotionSourceOptions::default()).expect_err("no body");
    assert!(e.to_string().contains("needs a body"));
}

// ---------------------------------------------------------------------------------------------
// On the real MakeHuman skeleton (when the assets or the built-in model are beside the workspace)

#[test]
fn bvh_on_the_builtin_body_gives_horizontal_arms() {
    let dir = workspace_root().join("datasets/body/makehuman");
    if !dir.join(sartor_core::MODEL_HEADER).exists() {
        println!("skipped: {} not found", dir.display());
        return;
    }
    let body = RetargetBody::load(&dir).expect("built-in body");
    let bvh = Bvh::load(&data("cmu_tiny.bvh")).expect("fixture");
    let (m, _) = retarget_bvh_native_rate(&bvh, &body, &KEEP).expect("retarget");
    let s = body.skeleton();
    let j = posed_joints(&body, &m.frames()[0]);
    for (arm, hand, x) in [
        ("LeftArm", "LeftHand", 1.0),
        ("RightArm", "RightHand", -1.0),
    ] {
        let d = bone_dir(&j, s, arm, hand);
        assert!(d.x * x > 0.95, "{arm} horizontal in the T-pose: {d:?}");
    }
    let j = posed_joints(&body, &m.frames()[1]);
    let fore = bone_dir(&j, s, "LeftForeArm", "LeftHand");
    assert!(fore.z > 0.9, "the bent forearm points forward: {fore:?}");
}

/// The built-in body model folder of the workspace (`datasets/body/makehuman`).
pub(crate) fn builtin_model_dir() -> PathBuf {
    workspace_root().join("datasets/body/makehuman")
}
