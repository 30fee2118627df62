//! A library of procedural, seeded motion clips on the built-in 31-joint skeleton.
//!
//! Each clip is a smooth function of time (sums of sinusoids and C1 smoothstep/`sin²` windows)
//! giving a few anatomical angles per joint, turned into local rotations in our
//! convention (SMPL-like, rest = the A-pose, see [`crate::Skeleton`]). Every clip eases in from the
//! rest pose and out to it over [`EASE_SECS`], lasts at least 4 s at 30 fps, and is deterministic
//! under its seed ([`clip_seeded`]; [`clip`] uses a fixed seed per clip). The seed jitters the
//! clip's amplitude (±8 %), rate (±4 %) and phase.
//!
//! # Angle conventions (our axes: +X the body's left, +Y up, +Z forward)
//!
//! Raising the left arm sideways from the A-pose is a positive rotation about +Z (−Z for the right
//! arm): +45° brings it horizontal, +135° straight up. Knee flexion is a positive rotation about
//! +X (the shin swings back); hip flexion (thigh forward) is negative about +X; forward bending of
//! the spine and neck is positive about +X; a bend to the left is negative about +Z; turning the
//! torso or the heading to the left is positive about +Y. The elbow bends about
//! `(−1, −s, 0)/√2` (`s` = +1 left, −1 right), the axis perpendicular to the A-pose upper arm and
//! to the forward direction.
//!
//! # Joint limits (per local rotation, relative to the A-pose rest)
//!
//! | joint | limit |
//! | --- | --- |
//! | `Hips` tilt (`local_rotations[0]`) | 70° |
//! | `LHipJoint`, `RHipJoint`, fingers, thumbs | 0° (never rotated) |
//! | `LeftUpLeg`, `RightUpLeg` | 125° (flexion −30°…120°, abduction −15°…50°, rotation ±40°) |
//! | `LeftLeg`, `RightLeg` (knee) | hinge about +X, 0°…150°, no hyper-extension |
//! | `LeftFoot`, `RightFoot` (ankle) | 50° |
//! | `LeftToeBase`, `RightToeBase` | 45° |
//! | `LowerBack`, `Spine`, `Spine1` | 40° each |
//! | `Neck`, `Neck1` | 30° each |
//! | `Head` | 45° |
//! | `LeftShoulder`, `RightShoulder` (clavicle) | 30° |
//! | `LeftArm`, `RightArm` | 150° (abduction from the A-pose −40°…+130°, i.e. up to 175° anatomical) |
//! | `LeftForeArm`, `RightForeArm` (elbow) | hinge about the elbow axis, 0°…145° beyond the rest bend |
//! | `LeftHand`, `RightHand` (wrist) | 70° |
//!
//! [`JOINT_LIMITS_DEG`] holds the table; the tests check every frame of every clip against it,
//! and the angular speed of every joint against [`MAX_ANGULAR_SPEED_RAD_S`].
//!
//! Root motion: locomotion integrates a forward/sideways speed along a heading that turning clips
//! change; the pelvis height follows the legs (it drops as hips and knees bend so the lower foot
//! stays on the ground, a smooth maximum over the two legs) plus the clip's own lift for hops and
//! jumps.

mod clips;

use nalgebra::{Unit, UnitQuaternion, Vector3};

use sartor_core::{FPS, Pose, canonical, split_heading};

use crate::fnv::Fnv;
use crate::{CMU_MB_JOINTS, Error, Motion, Result};

pub use clips::HELD_OUT_CLIPS;

/// Seconds over which every clip eases in from rest and out to rest.
pub const EASE_SECS: f64 = 0.6;
/// No joint of any clip turns faster than this (radians per second, frame to frame).
pub const MAX_ANGULAR_SPEED_RAD_S: f64 = 25.0;
/// Thigh length used for the pelvis height, metres.
pub const THIGH_M: f64 = 0.40;
/// Shin length used for the pelvis height, metres.
pub const SHIN_M: f64 = 0.41;

/// Limits of each joint's local rotation angle, degrees, in skeleton order (see the module docs).
pub const JOINT_LIMITS_DEG: [(&str, f64); 31] = [
    ("Hips", 70.0),
    ("LHipJoint", 0.0),
    ("LeftUpLeg", 125.0),
    ("LeftLeg", 150.0),
    ("LeftFoot", 50.0),
    ("LeftToeBase", 45.0),
    ("RHipJoint", 0.0),
    ("RightUpLeg", 125.0),
    ("RightLeg", 150.0),
    ("RightFoot", 50.0),
    ("RightToeBase", 45.0),
    ("LowerBack", 40.0),
    ("Spine", 40.0),
    ("Spine1", 40.0),
    ("Neck", 30.0),
    ("Neck1", 30.0),
    ("Head", 45.0),
    ("LeftShoulder", 30.0),
    ("LeftArm", 150.0),
    ("LeftForeArm", 145.0),
    ("LeftHand", 70.0),
    ("LeftFingerBase", 0.0),
    ("LeftHandFinger1", 0.0),
    ("LThumb", 0.0),
    ("RightShoulder", 30.0),
    ("RightArm", 150.0),
    ("RightForeArm", 145.0),
    ("RightHand", 70.0),
    ("RightFingerBase", 0.0),
    ("RightHandFinger1", 0.0),
    ("RThumb", 0.0),
];

/// Hinge joints: `(joint, unit axis)`; their rotation is `angle ≥ 0` about the axis.
pub fn hinge_axes() -> [(&'static str, Vector3<f64>); 4] {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    [
        ("LeftLeg", Vector3::x()),
        ("RightLeg", Vector3::x()),
        ("LeftForeArm", Vector3::new(-h, -h, 0.0)),
        ("RightForeArm", Vector3::new(-h, h, 0.0)),
    ]
}

// Joint indices in `CMU_MB_JOINTS` order (checked by a test).
const HIPS: usize = 0;
const UPLEG: [usize; 2] = [2, 7];
const LEG: [usize; 2] = [3, 8];
const FOOT: [usize; 2] = [4, 9];
const TOE: [usize; 2] = [5, 10];
const SPINE: [usize; 3] = [11, 12, 13];
const NECK: [usize; 3] = [14, 15, 16];
const CLAVICLE: [usize; 2] = [17, 24];
const ARM: [usize; 2] = [18, 25];
const FOREARM: [usize; 2] = [19, 26];
const HAND: [usize; 2] = [20, 27];

/// Angles of one leg, radians.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Leg {
    /// Hip flexion: thigh forward (+) / backward (−).
    pub hip_flex: f64,
    /// Hip abduction: thigh outward (+).
    pub hip_abd: f64,
    /// Hip external rotation: toes outward (+).
    pub hip_rot: f64,
    /// Knee flexion (≥ 0).
    pub knee: f64,
    /// Ankle plantarflexion: toes down (+), dorsiflexion (−).
    pub ankle: f64,
    /// Toe extension: toes up (+).
    pub toe: f64,
}

/// Angles of one arm, radians.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Arm {
    /// Clavicle elevation (shrug, +).
    pub clav_elev: f64,
    /// Clavicle protraction (shoulder forward, +).
    pub clav_fwd: f64,
    /// Abduction from the A-pose: +45° horizontal, +135° straight up, −45° hanging.
    pub abd: f64,
    /// Flexion: the arm swings forward (+) / back (−) about the body's left–right axis.
    pub flex: f64,
    /// Horizontal adduction: a raised arm swings toward the front (+).
    pub horiz: f64,
    /// Twist about the upper arm.
    pub twist: f64,
    /// Elbow flexion beyond the rest bend (≥ 0).
    pub elbow: f64,
    /// Wrist flexion.
    pub wrist: f64,
}

/// A frame of a procedural clip: anatomical angles (radians) and root motion rates.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Params {
    /// Speed along the heading, m/s.
    pub forward_speed: f64,
    /// Speed toward the body's left, m/s.
    pub left_speed: f64,
    /// Heading rate, rad/s (+ turns left).
    pub turn_rate: f64,
    /// Extra pelvis lift (hops, jumps), metres.
    pub lift: f64,
    /// Pelvis: forward tilt (about +X), roll (about +Z), yaw (about +Y).
    pub pelvis: [f64; 3],
    /// Spine total: forward flexion, bend to the left, twist to the left.
    pub spine: [f64; 3],
    /// Neck and head total: flexion, bend to the left, twist to the left.
    pub neck: [f64; 3],
    /// Left, right.
    pub legs: [Leg; 2],
    /// Left, right.
    pub arms: [Arm; 2],
}

impl Params {
    /// `self · s` on every field (the ease-in/out envelope: 0 gives the rest pose, standing still).
    fn scaled(&self, s: f64) -> Self {
        let leg = |l: &Leg| Leg {
            hip_flex: l.hip_flex * s,
            hip_abd: l.hip_abd * s,
            hip_rot: l.hip_rot * s,
            knee: l.knee * s,
            ankle: l.ankle * s,
            toe: l.toe * s,
        };
        let arm = |a: &Arm| Arm {
            clav_elev: a.clav_elev * s,
            clav_fwd: a.clav_fwd * s,
            abd: a.abd * s,
            flex: a.flex * s,
            horiz: a.horiz * s,
            twist: a.twist * s,
            elbow: a.elbow * s,
            wrist: a.wrist * s,
        };
        Self {
            forward_speed: self.forward_speed * s,
            left_speed: self.left_speed * s,
            turn_rate: self.turn_rate * s,
            lift: self.lift * s,
            pelvis: self.pelvis.map(|x| x * s),
            spine: self.spine.map(|x| x * s),
            neck: self.neck.map(|x| x * s),
            legs: [leg(&self.legs[0]), leg(&self.legs[1])],
            arms: [arm(&self.arms[0]), arm(&self.arms[1])],
        }
    }
}

fn rot(axis: Vector3<f64>, angle: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), angle)
}

fn rx(a: f64) -> UnitQuaternion<f64> {
    rot(Vector3::x(), a)
}

fn ry(a: f64) -> UnitQuaternion<f64> {
    rot(Vector3::y(), a)
}

fn rz(a: f64) -> UnitQuaternion<f64> {
    rot(Vector3::z(), a)
}

/// Smooth maximum (C∞), within `eps` of `max(a, b)`.
fn smooth_max(a: f64, b: f64, eps: f64) -> f64 {
    0.5 * (a + b) + ((0.5 * (a - b)).powi(2) + eps * eps).sqrt()
}

/// Vertical hip-to-ankle distance of a leg, metres.
fn leg_height(leg: &Leg, pelvis_tilt: f64) -> f64 {
    let thigh = leg.hip_flex - pelvis_tilt;
    let shin = thigh - leg.knee;
    (THIGH_M * thigh.cos() + SHIN_M * shin.cos()) * leg.hip_abd.cos()
}

/// The pose for `p`, at `heading` with the horizontal root position `ground`.
fn pose_from_params(p: &Params, heading: f64, ground: Vector3<f64>) -> Pose {
    let n = CMU_MB_JOINTS.len();
    let mut q = vec![UnitQuaternion::identity(); n];
    let root = ry(heading) * ry(p.pelvis[2]) * rx(p.pelvis[0]) * rz(p.pelvis[1]);
    let (heading_q, tilt) = split_heading(&root);
    q[HIPS] = tilt;
    const SPINE_SHARE: [f64; 3] = [0.3, 0.35, 0.35];
    for (k, j) in SPINE.iter().enumerate() {
        let s = SPINE_SHARE[k];
        q[*j] = ry(s * p.spine[2]) * rx(s * p.spine[0]) * rz(-s * p.spine[1]);
    }
    const NECK_SHARE: [f64; 3] = [0.35, 0.25, 0.4];
    for (k, j) in NECK.iter().enumerate() {
        let s = NECK_SHARE[k];
        q[*j] = ry(s * p.neck[2]) * rx(s * p.neck[0]) * rz(-s * p.neck[1]);
    }
    let hinges = hinge_axes();
    for side in 0..2 {
        let s = if side == 0 { 1.0 } else { -1.0 };
        let l = &p.legs[side];
        q[UPLEG[side]] = rx(-l.hip_flex) * rz(s * l.hip_abd) * ry(s * l.hip_rot);
        q[LEG[side]] = rx(l.knee);
        q[FOOT[side]] = rx(l.ankle);
        q[TOE[side]] = rx(-l.toe);
        let a = &p.arms[side];
        q[CLAVICLE[side]] = ry(-s * a.clav_fwd) * rz(s * a.clav_elev);
        let rest_dir = Vector3::new(s, -1.0, 0.0);
        q[ARM[side]] = ry(-s * a.horiz) * rx(-a.flex) * rz(s * a.abd) * rot(rest_dir, s * a.twist);
        let elbow_axis = hinges[2 + side].1;
        q[FOREARM[side]] = rot(elbow_axis, a.elbow);
        q[HAND[side]] = rot(elbow_axis, a.wrist);
    }
    let heights = [
        leg_height(&p.legs[0], p.pelvis[0]),
        leg_height(&p.legs[1], p.pelvis[0]),
    ];
    // Zero at rest: smooth_max(L, L, eps) = L + eps.
    const EPS_M: f64 = 0.02;
    let drop = THIGH_M + SHIN_M + EPS_M - smooth_max(heights[0], heights[1], EPS_M);
    Pose {
        root_translation_m: Vector3::new(ground.x, p.lift - drop, ground.z),
        root_orientation: heading_q,
        local_rotations: q.into_iter().map(canonical).collect(),
    }
}

/// The seeded jitter of a clip.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Jitter {
    /// Amplitude factor, 0.92…1.08.
    pub amp: f64,
    /// Rate (frequency) factor, 0.96…1.04.
    pub rate: f64,
    /// Phase, radians, 0…2π.
    pub phase: f64,
}

impl Jitter {
    fn from_seed(seed: u64) -> Self {
        // SplitMix64: small, portable, deterministic.
        let mut state = seed;
        let mut next = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        Self {
            amp: 0.92 + 0.16 * next(),
            rate: 0.96 + 0.08 * next(),
            phase: std::f64::consts::TAU * next(),
        }
    }
}

/// A clip: name, duration, default seed, generator.
pub(crate) struct ClipDef {
    pub name: &'static str,
    pub secs: f64,
    pub build: fn(f64, &Jitter) -> Params,
}

/// Names of all clips, in library order.
pub fn clip_names() -> Vec<String> {
    clips::CLIPS.iter().map(|c| c.name.to_string()).collect()
}

/// The default seed of a clip: a hash of its name (FNV-1a), so renaming reorders nothing else.
fn default_seed(name: &str) -> u64 {
    let mut h = Fnv::default();
    h.bytes(name.as_bytes());
    h.0
}

/// The clip `name` with its default seed.
pub fn clip(name: &str) -> Result<Motion> {
    clip_seeded(name, default_seed(name))
}

/// The clip `name` with the given seed (same seed, same motion).
pub fn clip_seeded(name: &str, seed: u64) -> Result<Motion> {
    let def = clips::CLIPS
        .iter()
        .find(|c| c.name == name)
        .ok_or_else(|| {
            Error::invalid(
                "procedural clip",
                format!("unknown clip {name:?}; known: {}", clip_names().join(", ")),
            )
        })?;
    let jitter = Jitter::from_seed(seed);
    let n = (def.secs * FPS).round() as usize + 1;
    let envelope =
        |t: f64| smoothstep(0.0, EASE_SECS, t) * smoothstep(0.0, EASE_SECS, def.secs - t);
    let params = |t: f64| (def.build)(t * jitter.rate, &jitter).scaled(envelope(t));
    const SUBSTEPS: usize = 8;
    let (mut heading, mut ground) = (0.0_f64, Vector3::zeros());
    let mut frames = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 / FPS;
        if k > 0 {
            let dt = 1.0 / FPS / SUBSTEPS as f64;
            for i in 0..SUBSTEPS {
                let tm = (k - 1) as f64 / FPS + (i as f64 + 0.5) * dt;
                let p = params(tm);
                let h = heading + 0.5 * dt * p.turn_rate;
                let forward = Vector3::new(h.sin(), 0.0, h.cos());
                let left = Vector3::new(h.cos(), 0.0, -h.sin());
                ground += (p.forward_speed * forward + p.left_speed * left) * dt;
                heading += p.turn_rate * dt;
            }
        }
        frames.push(pose_from_params(&params(t), heading, ground));
    }
    let names = CMU_MB_JOINTS.iter().map(|(n, _)| n.to_string()).collect();
    Motion::new(name.to_string(), FPS, names, frames)
}

/// `0` before `e0`, `1` after `e1`, cubic in between (C1).
pub(crate) fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let u = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    u * u * (3.0 - 2.0 * u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_constants_match_the_rig() {
        let names: Vec<&str> = CMU_MB_JOINTS.iter().map(|(n, _)| *n).collect();
        for (i, (n, _)) in JOINT_LIMITS_DEG.iter().enumerate() {
            assert_eq!(names[i], *n);
        }
        assert_eq!(names[HIPS], "Hips");
        assert_eq!(names[UPLEG[1]], "RightUpLeg");
        assert_eq!(names[LEG[0]], "LeftLeg");
        assert_eq!(names[FOOT[1]], "RightFoot");
        assert_eq!(names[TOE[0]], "LeftToeBase");
        assert_eq!(names[SPINE[2]], "Spine1");
        assert_eq!(names[NECK[2]], "Head");
        assert_eq!(names[CLAVICLE[1]], "RightShoulder");
        assert_eq!(names[ARM[0]], "LeftArm");
        assert_eq!(names[FOREARM[1]], "RightForeArm");
        assert_eq!(names[HAND[0]], "LeftHand");
    }

    /// FK with a made-up A-pose layout: +45° about +Z raises the left arm to horizontal,
    /// positive knee flexion moves the foot backward, hip flexion moves the knee forward.
    #[test]
    fn angle_signs_with_forward_kinematics() {
        let s = crate::cmu_mb_skeleton();
        let mut rest = vec![Vector3::zeros(); 31];
        let set = |rest: &mut Vec<Vector3<f64>>, n: &str, p: [f64; 3]| {
            rest[s.index_of(n).expect("joint")] = Vector3::new(p[0], p[1], p[2]);
        };
        set(&mut rest, "Hips", [0.0, 1.0, 0.0]);
        set(&mut rest, "LeftUpLeg", [0.1, 0.95, 0.0]);
        set(&mut rest, "LeftLeg", [0.1, 0.55, 0.0]);
        set(&mut rest, "LeftFoot", [0.1, 0.14, 0.0]);
        set(&mut rest, "Spine1", [0.0, 1.4, 0.0]);
        set(&mut rest, "LeftShoulder", [0.05, 1.45, 0.0]);
        set(&mut rest, "LeftArm", [0.18, 1.45, 0.0]);
        set(&mut rest, "LeftForeArm", [0.38, 1.25, 0.0]);
        set(&mut rest, "LeftHand", [0.58, 1.05, 0.0]);
        let mut p = Params::default();
        p.arms[0].abd = 45f64.to_radians();
        let pose = pose_from_params(&p, 0.0, Vector3::zeros());
        let (j, _) = s.forward_kinematics(&rest, &pose).expect("fk");
        let arm = j[FOREARM[0]] - j[ARM[0]];
        assert!(arm.y.abs() < 1e-9 && arm.x > 0.0, "{arm:?}");
        let mut p = Params::default();
        p.legs[0].knee = 1.0;
        p.legs[0].hip_flex = 0.5;
        p.arms[0].elbow = 1.0;
        let pose = pose_from_params(&p, 0.0, Vector3::zeros());
        let (j, _) = s.forward_kinematics(&rest, &pose).expect("fk");
        assert!(j[LEG[0]].z > 0.05, "knee forward");
        assert!(j[FOOT[0]].z < j[LEG[0]].z, "shin swings back");
        assert!(j[HAND[0]].z > 0.1, "elbow flexion brings the hand forward");
    }
}
