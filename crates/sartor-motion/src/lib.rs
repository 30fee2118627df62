//! # sartor-motion
//!
//! Motion for sartor: a [`Motion`] is a sequence of [`Pose`]s of the built-in 31-joint `cmu_mb`
//! rig ([`cmu_mb_skeleton`]) at [`FPS`] after resampling. Every source is retargeted onto a
//! [`RetargetBody`] by one rule (world orientations, see [`retarget`](crate::RetargetBody)):
//!
//! - the [`procedural`] clip library (seeded, 73 clips);
//! - CMU-style BVH files ([`Bvh`], [`retarget_bvh`]);
//! - AMASS-style `.npz` files ([`load_amass`]);
//! - saved JSON motions (the imported MakeHuman walk cycle, `datasets/motions/walk.json`).
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
mod motion;
pub mod npz;
pub mod procedural;
mod retarget;
mod rig;
mod sources;

pub use amass::{
    AmassData, AmassOptions, SMPL_BODY_PARENTS, SMPL_TO_RIG, UpAxis, load_amass, retarget_amass,
    retarget_amass_native_rate,
};
pub use bvh::{
    Bvh, BvhChannel, BvhJoint, BvhRetargetOptions, BvhRetargetReport, cmu_to_rig_name,
    load_bvh_motion, retarget_bvh, retarget_bvh_native_rate,
};
pub use motion::Motion;
pub use retarget::{RetargetBody, TPOSE_FILE, load_tpose, pose_from_world, world_rotations};
pub use rig::{CMU_MB_JOINTS, cmu_mb_skeleton};
/// The error type is the core's: motion files fail in the same ways (file, line, format,
/// invalid value).
pub use sartor_core::{Error, FPS, Pose, Result, split_heading};
pub use sources::{MotionSourceOptions, WALK_NAME, load_motion};
