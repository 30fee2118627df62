//! Checking a BVH retarget against the file's own forward kinematics.
//!
//! [`check_bvh_retarget`] retargets a parsed [`Bvh`] onto a [`RetargetBody`] at the file's rate
//! with every frame kept (the added T-pose too), poses our skeleton frame by frame, and compares
//! it with the file's own forward kinematics, computed here independently of the retargeting
//! code ([`bvh_forward_kinematics`]: rotation matrices from the Euler channels in file order,
//! positions from the offsets).
//!
//! # What is compared
//!
//! A **rig bone with a BVH counterpart** is a rig joint `j` and its child `c` whose BVH joints
//! are parent and child in the file, with a non-zero offset. For each, in every frame:
//!
//! - **posture bones** ([`crate::POSTURE_BONES`]): the angle between our bone's world
//!   direction (`J_c − J_j` after our forward kinematics) and the BVH bone's (from the file's
//!   FK) — the bone points where the file's does;
//! - **proportion bones** (the rest; CMU: the hip sockets `*HipJoint → *UpLeg` and `Neck1 →
//!   Head`), whose rest direction differs from the file's because the skeletons put their joints
//!   differently: the angle between our bone's direction and `R_b · r`, with `R_b` the file's
//!   world rotation of the bone's joint and `r` our bone's direction in our body turned into the
//!   file's rest pose (the retarget of an all-zero frame) — the bone turns with the file's
//!   joint. The constant angle to the file's own bone (the proportion difference) is reported.
//!
//! Also checked: the **reference pose** (the retarget of an all-zero frame) has every posture
//! bone along the file's rest offset and every proportion joint at its rest relation to its
//! parent; the **pelvis** (our `Hips` world rotation against the file's); the **root path**
//! (our root translation against the file's, scaled by the reported factor, from the first
//! frame).
//!
//! # Crossed legs
//!
//! In the pelvis frame (our `Hips` world rotation; the file's own for the file), the lateral
//! separation of the knees and of the ankles, `(left − right) · x_pelvis`, divided by the leg
//! length (thigh + shin, mean of both legs) of the same skeleton. The file's legs may
//! legitimately cross (a crossover step, modern dance: 05_16's own ankles reach −0.47 leg
//! lengths), so ours are compared with the file's: the check fails when our knees or ankles are
//! on the wrong side (separation < 0) while the file's are clearly apart (separation ≥
//! [`CROSSING_MARGIN`]), or when the two separations differ by more than
//! [`SEPARATION_TOLERANCE`]. Measured on the 60 CMU clips: the retarget that took the files'
//! rest for a T-pose (thighs turned 21° inwards) differs from the files by 0.65–0.71 leg
//! lengths in every clip and crosses the knees in 13,055 frames; the correct one differs by at
//! most 0.10 (what the two skeletons' proportions leave) and never crosses.

use std::path::Path;

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::bvh::{Bvh, BvhChannel, BvhRetargetOptions, retarget_bvh_native_rate};
use crate::bvh_map::BvhJointMatch;
use crate::bvh_tpose::{TposeFrame, max_limb_step_deg};
use crate::rest_pose::POSTURE_BONES;
use crate::retarget::{RetargetBody, world_rotations};
use crate::{Error, Pose, Result};

/// Default largest angle (degrees) between our bone and the file's.
pub const MAX_BONE_ANGLE_DEG: f64 = 5.0;
/// A file's knees or ankles are "clearly apart" when their lateral separation is at least this
/// fraction of a leg length (about 4 cm; see the module docs).
pub const CROSSING_MARGIN: f64 = 0.05;
/// Largest difference between our and the file's lateral separation of the knees and of the
/// ankles, in leg lengths (see the module docs for the measured values it sits between).
pub const SEPARATION_TOLERANCE: f64 = 0.25;

/// The file's own forward kinematics for one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhFkFrame {
    /// World position of every joint, file units.
    pub positions: Vec<Vector3<f64>>,
    /// World rotation of every joint (identity at rest).
    pub rotations: Vec<Matrix3<f64>>,
}

/// The file's forward kinematics of frame `i`, computed from the offsets and channel values
/// only: a joint's local transform is `T(offset + position channels) · R_1 · R_2 · R_3` with the
/// rotation channels as elementary rotation matrices in the order listed.
pub fn bvh_forward_kinematics(bvh: &Bvh, i: usize) -> BvhFkFrame {
    let values = &bvh.values()[i * bvh.n_channels()..(i + 1) * bvh.n_channels()];
    let mut k = 0;
    let n = bvh.joints().len();
    let mut positions: Vec<Vector3<f64>> = Vec::with_capacity(n);
    let mut rotations: Vec<Matrix3<f64>> = Vec::with_capacity(n);
    for joint in bvh.joints() {
        let mut local = Matrix3::identity();
        let mut t = joint.offset;
        for c in &joint.channels {
            let v = values[k];
            k += 1;
            let a = v.to_radians();
            match c {
                BvhChannel::Xposition => t.x += v,
                BvhChannel::Yposition => t.y += v,
                BvhChannel::Zposition => t.z += v,
                BvhChannel::Xrotation => local *= elementary(0, a),
                BvhChannel::Yrotation => local *= elementary(1, a),
                BvhChannel::Zrotation => local *= elementary(2, a),
            }
        }
        let (p, r) = match joint.parent {
            None => (t, local),
            Some(q) => (positions[q] + rotations[q] * t, rotations[q] * local),
        };
        positions.push(p);
        rotations.push(r);
    }
    BvhFkFrame {
        positions,
        rotations,
    }
}

/// The rotation matrix by `a` radians about axis `axis` (0 = X, 1 = Y, 2 = Z).
fn elementary(axis: usize, a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    match axis {
        0 => Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
        1 => Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
        _ => Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
    }
}

/// Options of [`check_bvh_retarget`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RetargetCheckOptions {
    /// Largest angle between our bone and the file's, degrees.
    pub max_bone_angle_deg: f64,
    /// Largest root path error, metres.
    pub max_root_error_m: f64,
}

impl Default for RetargetCheckOptions {
    fn default() -> Self {
        Self {
            max_bone_angle_deg: MAX_BONE_ANGLE_DEG,
            max_root_error_m: 1e-3,
        }
    }
}

/// The worst frame of one bone.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BoneCheck {
    /// `joint->child` (rig names).
    pub bone: String,
    /// `posture` or `proportion` (see the module docs).
    pub kind: &'static str,
    /// Worst angle of the checked quantity over all frames, degrees.
    pub worst_angle_deg: f64,
    /// The frame where it happens (file frame index).
    pub worst_frame: usize,
    /// Proportion bones: the largest angle between our bone and the file's own bone over all
    /// frames (the constant proportion difference); posture bones: equal to
    /// `worst_angle_deg`.
    pub worst_angle_to_file_bone_deg: f64,
}

/// Knee and ankle separations, in leg lengths (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CrossingCheck {
    /// Smallest normalised knee separation of ours, and of the file's, over all frames.
    pub min_knee_separation: [f64; 2],
    /// Smallest normalised ankle separation of ours, and of the file's.
    pub min_ankle_separation: [f64; 2],
    /// Frames where the file's own knees or ankles are less than [`CROSSING_MARGIN`] apart
    /// (close together or crossed in the data itself; not held against us).
    pub file_close_or_crossed_frames: usize,
    /// Frames where ours cross while the file's are clearly apart.
    pub crossed_frames: usize,
    /// Largest difference between our and the file's separations (knees and ankles).
    pub max_separation_difference: f64,
    /// The frame of that difference.
    pub worst_frame: usize,
}

/// The result of [`check_bvh_retarget`] for one file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ClipCheck {
    /// The file's stem.
    pub clip: String,
    /// Frames checked (all of the file's).
    pub frames: usize,
    /// How the file's joints were matched to the rig's.
    pub matched_by: BvhJointMatch,
    /// `[file joint, rig joint]` for every file joint that drives one, in file order.
    pub joints: Vec<[String; 2]>,
    /// What the T-pose detector found on frame 0.
    pub tpose_frame: Option<TposeFrame>,
    /// The largest turn of a limb bone between consecutive frames after frame 0, degrees.
    pub max_limb_step_deg: Option<f64>,
    /// Every rig bone with a counterpart, in skeleton order.
    pub bones: Vec<BoneCheck>,
    /// Reference pose: worst angle of a posture bone from the file's rest offset, degrees.
    pub reference_posture_deg: f64,
    /// Reference pose: worst local rotation of a proportion joint, degrees.
    pub reference_proportion_deg: f64,
    /// Worst angle between our pelvis world rotation and the file's, degrees.
    pub pelvis_worst_deg: f64,
    /// Worst root path error, metres.
    pub root_worst_m: f64,
    /// Crossed legs.
    pub crossing: CrossingCheck,
    /// What failed (empty when the clip passes).
    pub failures: Vec<String>,
}

impl ClipCheck {
    /// Whether every check passed.
    pub fn passed(&self) -> bool {
        self.failures.is_empty()
    }

    /// The worst bone angle of the clip, degrees.
    pub fn worst_bone_angle_deg(&self) -> f64 {
        self.bones
            .iter()
            .map(|b| b.worst_angle_deg)
            .fold(0.0, f64::max)
    }
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    match (a.try_normalize(1e-12), b.try_normalize(1e-12)) {
        (Some(a), Some(b)) => a.dot(&b).clamp(-1.0, 1.0).acos().to_degrees(),
        _ => 180.0,
    }
}

/// Our posed joints and world rotations.
type PosedWorld = (Vec<Vector3<f64>>, Vec<UnitQuaternion<f64>>);

/// One compared bone: rig joint and child, BVH joint and child, posture or proportion.
struct Pair {
    rig: (usize, usize),
    bvh: (usize, usize),
    posture: bool,
}

/// Normalised lateral separations `[knee, ankle]` from world positions of the hip joints, knees
/// and ankles `[l_hip, r_hip, l_knee, r_knee, l_ankle, r_ankle]` and the pelvis' world
/// rotation: `(left − right) · x_pelvis / leg length`, the leg length being the mean over both
/// legs of thigh + shin.
fn separations(p: [Vector3<f64>; 6], pelvis: &Matrix3<f64>) -> [f64; 2] {
    let x = pelvis.column(0).into_owned();
    let leg = 0.5
        * ((p[2] - p[0]).norm()
            + (p[4] - p[2]).norm()
            + (p[3] - p[1]).norm()
            + (p[5] - p[3]).norm());
    let s = |l: usize, r: usize| (p[l] - p[r]).dot(&x) / leg;
    [s(2, 3), s(4, 5)]
}

/// Check the retarget of `bvh` onto `body` against the file's forward kinematics (see the
/// module docs). Errors when the file cannot be retargeted at all.
pub fn check_bvh_retarget(
    bvh: &Bvh,
    body: &RetargetBody,
    options: &RetargetCheckOptions,
) -> Result<ClipCheck> {
    let path = bvh.path();
    let skeleton = body.skeleton();
    let keep = BvhRetargetOptions {
        lenient: true,
        keep_tpose_frame: true,
    };
    let (motion, report) = retarget_bvh_native_rate(bvh, body, &keep)?;
    if motion.n_frames() != bvh.n_frames() {
        return Err(Error::format(
            path,
            format!(
                "retarget kept {} of {} frames",
                motion.n_frames(),
                bvh.n_frames()
            ),
        ));
    }
    // The all-zero frame after the file's first (which tells the retarget which way is up
    // where the rest pose does not stand).
    let mut values = bvh.frame(0).to_vec();
    values.resize(2 * bvh.n_channels(), 0.0);
    let rest_bvh = bvh.with_values(values)?;
    let (reference, _) = retarget_bvh_native_rate(&rest_bvh, body, &keep)?;
    let reference = &reference.frames()[1];

    // Rig joint → BVH joint, as the retarget matched them.
    let bvh_index = |rig_name: &str| report.joint_map.file_joint(rig_name);
    let bvh_of_rig: Vec<Option<usize>> = skeleton.names().iter().map(|n| bvh_index(n)).collect();
    let mut pairs = Vec::new();
    for (c, parent) in skeleton.parents().iter().enumerate() {
        let Some(j) = *parent else { continue };
        let (Some(bj), Some(bc)) = (bvh_of_rig[j], bvh_of_rig[c]) else {
            continue;
        };
        if bvh.joints()[bc].parent != Some(bj) || bvh.joints()[bc].offset.norm() < 1e-9 {
            continue;
        }
        let names = (&skeleton.names()[j], &skeleton.names()[c]);
        let posture = POSTURE_BONES
            .iter()
            .any(|(a, b)| a == names.0 && b == names.1);
        pairs.push(Pair {
            rig: (j, c),
            bvh: (bj, bc),
            posture,
        });
    }
    let rig_name =
        |(j, c): (usize, usize)| format!("{}->{}", skeleton.names()[j], skeleton.names()[c]);

    // The file's axes in ours.
    let turn = if report.turned_around {
        Rotation3::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI).into_inner()
    } else {
        Matrix3::identity()
    };
    let rest_frame = report
        .rest_frame
        .map_or_else(Matrix3::identity, |r| r.to_rotation_matrix().into_inner());
    let fk = |pose: &Pose| -> Result<PosedWorld> {
        let (joints, _) = skeleton.forward_kinematics(body.rest_joints_m(), pose)?;
        Ok((joints, world_rotations(skeleton, pose)))
    };

    let mut failures = Vec::new();
    // The reference pose.
    let (ref_joints, _) = fk(reference)?;
    let mut reference_posture_deg: f64 = 0.0;
    let mut reference_proportion_deg: f64 = 0.0;
    let mut reference_dirs = Vec::with_capacity(pairs.len());
    // A joint that starts a posture bone is turned to the file's rest by it, whatever other
    // bones start there (Mixamo's chest starts the neck's posture bone and the collars').
    let posture_start = |j: usize| pairs.iter().any(|q| q.posture && q.rig.0 == j);
    for p in &pairs {
        let ours = ref_joints[p.rig.1] - ref_joints[p.rig.0];
        if p.posture {
            let file = turn * bvh.joints()[p.bvh.1].offset;
            reference_posture_deg = reference_posture_deg.max(angle_deg(&ours, &file));
        } else if !posture_start(p.rig.0) {
            // The root's "parent" is the rest it was stood up from, where it did not stand.
            let local = match (p.rig.0, &report.rest_frame) {
                (0, Some(frame)) => {
                    let root = reference.root_orientation * reference.local_rotations[0];
                    root.angle_to(frame)
                }
                (j, _) => reference.local_rotations[j].angle(),
            };
            reference_proportion_deg = reference_proportion_deg.max(local.to_degrees());
        }
        reference_dirs.push(ours);
    }
    if reference_posture_deg > 0.01 || reference_proportion_deg > 0.01 {
        failures.push(format!(
            "reference pose: posture bones {reference_posture_deg:.3}° from the file's rest, \
             proportion joints turned {reference_proportion_deg:.3}° from their parents"
        ));
    }

    // Every frame.
    let mut bones: Vec<BoneCheck> = pairs
        .iter()
        .map(|p| BoneCheck {
            bone: rig_name(p.rig),
            kind: if p.posture { "posture" } else { "proportion" },
            worst_angle_deg: 0.0,
            worst_frame: 0,
            worst_angle_to_file_bone_deg: 0.0,
        })
        .collect();
    let legs: Option<Vec<(usize, usize)>> = [
        "LeftUpLeg",
        "RightUpLeg",
        "LeftLeg",
        "RightLeg",
        "LeftFoot",
        "RightFoot",
    ]
    .iter()
    .map(|n| Some((skeleton.index_of(n)?, bvh_index(n)?)))
    .collect();
    let mut crossing = CrossingCheck {
        min_knee_separation: [f64::INFINITY; 2],
        min_ankle_separation: [f64::INFINITY; 2],
        file_close_or_crossed_frames: 0,
        crossed_frames: 0,
        max_separation_difference: 0.0,
        worst_frame: 0,
    };
    let mut pelvis_worst_deg: f64 = 0.0;
    let mut root_worst_m: f64 = 0.0;
    let first_root = bvh_forward_kinematics(bvh, 0).positions[bvh_of_rig[0].unwrap_or(0)];
    for (i, pose) in motion.frames().iter().enumerate() {
        let file = bvh_forward_kinematics(bvh, i);
        let (joints, world) = fk(pose)?;
        let file_rot = |b: usize| turn * file.rotations[b] * turn.transpose();
        // The file's pelvis frame: its rotation from a standing rest (the file's own, or the
        // one its lying rest was stood up from).
        let file_pelvis = |b: usize| file_rot(b) * rest_frame;
        for ((p, check), r) in pairs.iter().zip(&mut bones).zip(&reference_dirs) {
            let ours = joints[p.rig.1] - joints[p.rig.0];
            let file_bone = turn * (file.positions[p.bvh.1] - file.positions[p.bvh.0]);
            let to_file = angle_deg(&ours, &file_bone);
            let angle = if p.posture {
                to_file
            } else {
                angle_deg(&ours, &(file_rot(p.bvh.0) * r))
            };
            if angle > check.worst_angle_deg {
                check.worst_angle_deg = angle;
                check.worst_frame = i;
            }
            check.worst_angle_to_file_bone_deg = check.worst_angle_to_file_bone_deg.max(to_file);
        }
        // Pelvis and root.
        if let Some(b0) = bvh_of_rig[0] {
            let ours = world[0].to_rotation_matrix().into_inner();
            let theirs = file_pelvis(b0);
            let rel = Rotation3::from_matrix_unchecked(ours.transpose() * theirs);
            pelvis_worst_deg = pelvis_worst_deg.max(rel.angle().to_degrees());
            let want = turn * (file.positions[b0] - first_root) * report.translation_scale;
            root_worst_m = root_worst_m.max((pose.root_translation_m - want).norm());
        }
        // Crossing.
        if let Some(legs) = &legs {
            let ours_p = [0, 1, 2, 3, 4, 5].map(|k| joints[legs[k].0]);
            let file_p = [0, 1, 2, 3, 4, 5].map(|k| turn * file.positions[legs[k].1]);
            let ours_s = separations(ours_p, &world[0].to_rotation_matrix().into_inner());
            let file_s = match bvh_of_rig[0] {
                Some(b0) => separations(file_p, &file_pelvis(b0)),
                None => ours_s,
            };
            crossing.min_knee_separation[0] = crossing.min_knee_separation[0].min(ours_s[0]);
            crossing.min_knee_separation[1] = crossing.min_knee_separation[1].min(file_s[0]);
            crossing.min_ankle_separation[0] = crossing.min_ankle_separation[0].min(ours_s[1]);
            crossing.min_ankle_separation[1] = crossing.min_ankle_separation[1].min(file_s[1]);
            if file_s.iter().any(|s| *s < CROSSING_MARGIN) {
                crossing.file_close_or_crossed_frames += 1;
            }
            if (0..2).any(|k| ours_s[k] < 0.0 && file_s[k] >= CROSSING_MARGIN) {
                crossing.crossed_frames += 1;
            }
            let diff = (0..2)
                .map(|k| (ours_s[k] - file_s[k]).abs())
                .fold(0.0, f64::max);
            if diff > crossing.max_separation_difference {
                crossing.max_separation_difference = diff;
                crossing.worst_frame = i;
            }
        }
    }
    for b in &bones {
        if b.worst_angle_deg > options.max_bone_angle_deg {
            failures.push(format!(
                "{} ({}) is {:.2}° off in frame {}",
                b.bone, b.kind, b.worst_angle_deg, b.worst_frame
            ));
        }
    }
    if pelvis_worst_deg > options.max_bone_angle_deg {
        failures.push(format!("the pelvis is {pelvis_worst_deg:.2}° off"));
    }
    if root_worst_m > options.max_root_error_m {
        failures.push(format!("the root path is {root_worst_m:.4} m off"));
    }
    if legs.is_none() {
        failures.push("the file or the rig lacks a hip, knee or ankle joint".into());
    }
    if crossing.crossed_frames > 0 {
        failures.push(format!(
            "legs cross in {} frames where the file's do not",
            crossing.crossed_frames
        ));
    }
    if crossing.max_separation_difference > SEPARATION_TOLERANCE {
        failures.push(format!(
            "knee/ankle separation differs from the file's by {:.2} hip widths in frame {}",
            crossing.max_separation_difference, crossing.worst_frame
        ));
    }
    let (joints, _) = report.joint_map.pairs(bvh);
    Ok(ClipCheck {
        clip: clip_name(path),
        frames: bvh.n_frames(),
        matched_by: report.joint_map.matched_by,
        joints,
        tpose_frame: report.tpose_frame,
        max_limb_step_deg: max_limb_step_deg(bvh, 1),
        bones,
        reference_posture_deg,
        reference_proportion_deg,
        pelvis_worst_deg,
        root_worst_m,
        crossing,
        failures,
    })
}

fn clip_name(path: &Path) -> String {
    path.file_stem()
        .map_or_else(|| "bvh".to_string(), |s| s.to_string_lossy().into_owned())
}
