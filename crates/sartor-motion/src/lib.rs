//! # sartor-motion
//!
//! Motion for sartor: a [`Motion`] is a sequence of [`Pose`]s of the built-in 31-joint `cmu_mb`
//! rig ([`cmu_mb_skeleton`]) at [`FPS`] after resampling. Every source is retargeted onto a
//! [`RetargetBody`] by one rule (world orientations from the source's own rest pose,
//! [`SourceRest`]; see [`retarget`](crate::RetargetBody)) and BVH retargeting is checked against
//! the file's own forward kinematics ([`check_bvh_retarget`]):
//!
//! - the [`procedural`] clip library (seeded, 73 clips);
//! - CMU-style BVH files ([`Bvh`], [`retarget_bvh`]);
//! - AMASS-style `.npz` files ([`load_amass`]);
//! - saved JSON motions (the imported MakeHuman walk cycle, `datasets/motions/walk.json`);
//! - imported mocap clips ([`StoredClip`], `datasets/motions/cmu/05_02.json`), sets of them
//!   (`cmu/*`, [`expand_motion_set`]) and windows of any motion (`cmu/05_02@120+90`,
//!   [`MotionWindow`]).
//!
//! [`load_motion`] picks one from a command-line or config spec. Motion files are parsed here;
//! no physics, no learning.
//!
//! ```
//! use sartor_motion::{FPS, procedural};
//!
//! let walk = procedural::clip("walk_normal")?;
//! assert_eq!(walk.fps(), FPS);
//! assert_eq!(walk.frames()[0].local_rotations.len(), sartor_motion::CMU_MB_JOINTS.len());
//! # Ok::<(), sartor_motion::Error>(())
//! ```

mod amass;
mod bvh;
mod bvh_map;
mod bvh_tpose;
mod clearance;
mod fnv;
mod motion;
mod motion_library;
#[cfg(feature = "npz")]
pub mod npz;
pub mod procedural;
mod rest_pose;
mod retarget;
mod retarget_check;
mod rig;
mod sources;

#[cfg(feature = "npz")]
pub use amass::load_amass;
pub use amass::{
    AmassData, AmassOptions, SMPL_BODY_PARENTS, SMPL_TO_RIG, UpAxis, retarget_amass,
    retarget_amass_native_rate,
};
pub use bvh::{
    Bvh, BvhChannel, BvhJoint, BvhRetargetOptions, BvhRetargetReport, cmu_to_rig_name,
    load_bvh_motion, retarget_bvh, retarget_bvh_native_rate,
};
pub use bvh_map::{BvhJointMap, BvhJointMatch, map_bvh_joints, map_bvh_joints_by_structure};
pub use bvh_tpose::{
    LIMB_BONES, TPOSE_ARM_TOLERANCE_DEG, TPOSE_LEG_TOLERANCE_DEG, TPOSE_MIN_JUMP_DEG, TposeFrame,
    detect_tpose_frame, first_performance_frame, max_limb_step_deg,
};
pub use clearance::{
    ArmClearance, ClearanceJob, ClearanceOnDemand, ClearanceOptions, ClearanceProgress,
    ClearanceReport, LEG_CLEARANCE_M, UPPER_ARM_MIN_LEVER,
};
pub use motion::Motion;
pub use motion_library::{
    CMU_ACKNOWLEDGEMENT, MotionWindow, STORED_CLIP_FORMAT, StoredClip, StoredClipHeader,
    expand_motion_set, load_stored_clip, motion_file_stem, stored_clip_from_bytes,
};
pub use rest_pose::{POSTURE_BONES, SourceRest};
pub use retarget::{RetargetBody, TPOSE_FILE, load_tpose, pose_from_world, world_rotations};
pub use retarget_check::{
    BoneCheck, BvhFkFrame, CROSSING_MARGIN, ClipCheck, CrossingCheck, MAX_BONE_ANGLE_DEG,
    RetargetCheckOptions, SEPARATION_TOLERANCE, bvh_forward_kinematics, check_bvh_retarget,
};
pub use rig::{CMU_MB_JOINTS, cmu_mb_body_joints, cmu_mb_skeleton};
/// The error type is the core's: motion files fail in the same ways (file, line, format,
/// invalid value).
pub use sartor_core::{Error, FPS, Pose, Result, split_heading};
pub use sources::{MotionSourceOptions, WALK_NAME, load_motion};
