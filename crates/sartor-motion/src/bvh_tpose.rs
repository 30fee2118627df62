//! Detecting a T-pose frame that a BVH converter put in front of the performance.
//!
//! The CMU "MotionBuilder-friendly" conversion starts every file with a T-pose (frame 0) that is
//! not part of the capture; playing it snaps the body from a T-pose to the first real frame in
//! one frame. Other converters do not add one, and an actor may well start a take standing in a
//! T-pose, so the frame is recognised from the data, not by position alone: frame 0 is an added
//! T-pose when
//!
//! - it **is a T-pose**: every thigh and shin within [`TPOSE_LEG_TOLERANCE_DEG`] of straight down
//!   (−Y), every upper arm and forearm within [`TPOSE_ARM_TOLERANCE_DEG`] of the horizontal line
//!   through the hips (left limbs towards the left hip, right towards the right), and
//! - it **jumps** to frame 1: some limb bone turns by at least [`TPOSE_MIN_JUMP_DEG`] between the
//!   two frames (at 120 fps, 1,800°/s). A take that starts with the actor holding a T-pose
//!   moves on smoothly and keeps its first frame; CMU's added frames jump 21–175° to frame 1
//!   (`cargo xtask check-retarget` reports it per clip).
//!
//! The jump alone would not do: real takes have glitches of that size (limb bones turn up to
//! 92° between two frames in 03_02 and 07_12, 45–62° in several 05 dance clips), but not in a
//! frame that is also a clean T-pose.

use nalgebra::Vector3;
use serde::Serialize;

use crate::bvh::Bvh;
use crate::bvh_map::{BvhJointMap, map_bvh_joints};

/// Largest angle (degrees) of a T-pose's thighs and shins from straight down.
pub const TPOSE_LEG_TOLERANCE_DEG: f64 = 10.0;
/// Largest angle (degrees) of a T-pose's upper arms and forearms from the horizontal line
/// through the hips (CMU's added T-pose holds the arms 8° below it).
pub const TPOSE_ARM_TOLERANCE_DEG: f64 = 20.0;
/// Smallest turn (degrees) of some limb bone between frame 0 and frame 1 for frame 0 to count
/// as added (a T-pose held at the start of a take moves on more slowly).
pub const TPOSE_MIN_JUMP_DEG: f64 = 15.0;

/// The limb bones measured, as rig names `(joint, child)`.
pub const LIMB_BONES: [(&str, &str); 8] = [
    ("LeftUpLeg", "LeftLeg"),
    ("LeftLeg", "LeftFoot"),
    ("RightUpLeg", "RightLeg"),
    ("RightLeg", "RightFoot"),
    ("LeftArm", "LeftForeArm"),
    ("LeftForeArm", "LeftHand"),
    ("RightArm", "RightForeArm"),
    ("RightForeArm", "RightHand"),
];

/// What the detector measured on frame 0 of a file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TposeFrame {
    /// Largest angle of a thigh or shin from straight down, degrees.
    pub legs_from_vertical_deg: f64,
    /// Largest angle of an upper arm or forearm from the horizontal line through the hips,
    /// degrees.
    pub arms_from_horizontal_deg: f64,
    /// Largest turn of a limb bone from frame 0 to frame 1, degrees.
    pub jump_to_next_deg: f64,
    /// Whether frame 0 is an added T-pose (all three within their limits).
    pub is_added_tpose: bool,
}

/// The world direction of each of [`LIMB_BONES`] in frame `i` (`None` when the file lacks one
/// of the joints), and the hips' left-to-right line.
fn limb_directions(
    bvh: &Bvh,
    map: &BvhJointMap,
    i: usize,
) -> Option<([Vector3<f64>; 8], Vector3<f64>)> {
    let find = |n: &str| map.file_joint(n);
    let p = bvh.world_positions(i);
    let mut dirs = [Vector3::zeros(); 8];
    for (k, (a, b)) in LIMB_BONES.iter().enumerate() {
        dirs[k] = (p[find(b)?] - p[find(a)?]).try_normalize(1e-12)?;
    }
    let lateral = (p[find("LeftUpLeg")?] - p[find("RightUpLeg")?]).try_normalize(1e-12)?;
    Some((dirs, lateral))
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
}

/// Measure frame 0 of `bvh` against the rules of the module docs. `None` when the file has
/// fewer than two frames or lacks a limb joint (nothing is then dropped).
pub fn detect_tpose_frame(bvh: &Bvh) -> Option<TposeFrame> {
    detect_tpose_frame_mapped(bvh, &map_bvh_joints(bvh).ok()?)
}

/// [`detect_tpose_frame`] with the file's joints matched to the rig's by `map`.
pub(crate) fn detect_tpose_frame_mapped(bvh: &Bvh, map: &BvhJointMap) -> Option<TposeFrame> {
    if bvh.n_frames() < 2 {
        return None;
    }
    let (d0, lateral) = limb_directions(bvh, map, 0)?;
    let (d1, _) = limb_directions(bvh, map, 1)?;
    let down = -Vector3::y();
    let legs = d0[..4]
        .iter()
        .map(|d| angle_deg(d, &down))
        .fold(0.0, f64::max);
    let arms = d0[4..]
        .iter()
        .enumerate()
        .map(|(k, d)| {
            let side = if k < 2 { lateral } else { -lateral };
            angle_deg(d, &side)
        })
        .fold(0.0, f64::max);
    let jump = d0
        .iter()
        .zip(&d1)
        .map(|(a, b)| angle_deg(a, b))
        .fold(0.0, f64::max);
    Some(TposeFrame {
        legs_from_vertical_deg: legs,
        arms_from_horizontal_deg: arms,
        jump_to_next_deg: jump,
        is_added_tpose: legs <= TPOSE_LEG_TOLERANCE_DEG
            && arms <= TPOSE_ARM_TOLERANCE_DEG
            && jump >= TPOSE_MIN_JUMP_DEG,
    })
}

/// The first frame of the performance: after the converter's T-pose frame when
/// `drop_tpose` and it is one ([`detect_tpose_frame`]), and after any frames that follow whose
/// channels are all exactly zero (the root at the file's origin in its rest pose: a blank a
/// converter wrote, not a performer; CMU `07_12` has one after its T-pose, and playing it makes
/// the body jump metres in one frame). The last frame is always kept.
pub fn first_performance_frame(bvh: &Bvh, drop_tpose: bool) -> usize {
    match map_bvh_joints(bvh) {
        Ok(map) => first_performance_frame_mapped(bvh, &map, drop_tpose),
        // No limbs matched: no T-pose detected, only blank frames skipped.
        Err(_) => first_performance_frame_mapped(bvh, &BvhJointMap::none(bvh), drop_tpose),
    }
}

/// [`first_performance_frame`] with the file's joints matched to the rig's by `map`.
pub(crate) fn first_performance_frame_mapped(
    bvh: &Bvh,
    map: &BvhJointMap,
    drop_tpose: bool,
) -> usize {
    let tpose = drop_tpose && detect_tpose_frame_mapped(bvh, map).is_some_and(|t| t.is_added_tpose);
    let mut first = usize::from(tpose);
    if drop_tpose {
        let c = bvh.n_channels();
        while first + 1 < bvh.n_frames()
            && bvh.values()[first * c..(first + 1) * c]
                .iter()
                .all(|&v| v == 0.0)
        {
            first += 1;
        }
    }
    first
}

/// The largest turn (degrees) of any of [`LIMB_BONES`] between consecutive frames from frame
/// `first` on: how fast the file's limbs move (glitches included).
pub fn max_limb_step_deg(bvh: &Bvh, first: usize) -> Option<f64> {
    let map = map_bvh_joints(bvh).ok()?;
    let mut worst: f64 = 0.0;
    let mut prev = limb_directions(bvh, &map, first)?.0;
    for i in first + 1..bvh.n_frames() {
        let cur = limb_directions(bvh, &map, i)?.0;
        for (a, b) in prev.iter().zip(&cur) {
            worst = worst.max(angle_deg(a, b));
        }
        prev = cur;
    }
    Some(worst)
}
