//! # sartor-import
//!
//! The importers: raw assets into sartor's own formats, once. Only the command line uses them;
//! nothing downstream of the committed `datasets/` folder depends on this crate.
//!
//! - [`import_makehuman`]: MakeHuman's CC0 assets (`shared/makehuman`) into the built-in body
//!   model `datasets/body/makehuman` (mesh, macro targets, `cmu_mb` rig joints, skin weights, a
//!   10-component PCA shape space, the phenotype space, the T-pose, bone frames, a report);
//!   deterministic, so a rerun reproduces the files byte for byte.
//! - [`import_walk_cycle`]: MakeHuman's keyframed walk into a [`sartor_motion::Motion`].
//! - [`load_smpl_npz`]: an SMPL-layout `.npz` into a [`sartor_core::BodyModel`] (pose
//!   correctives ignored).

mod makehuman;
mod rig;
mod smpl;
mod walkcycle;

pub use makehuman::{
    BONE_FRAMES_FILE, BoneFrames, HeldOutReport, IMPORT_FILES, IMPORT_REPORT_FILE, ImportOptions,
    ImportReport, JointReport, MeshReport, PcaReport, SAMPLE_RANGES, ShapeSpaceReport,
    SkinWeightReport, TPoseReport, TopKReport, blender_euler_xyz, import_makehuman,
};
/// The error type is the core's: importers fail in the same ways (file, line, format, invalid
/// value).
pub use sartor_core::{Error, Result};
pub use smpl::{SMPL_JOINTS, load_smpl_npz, smpl_from_npz};
pub use walkcycle::{
    BLENDER_FPS, CMU_MB_RIG_FILE, DEFAULT_RIG_FILE, WALK_CYCLE_FILE, WALK_CYCLES,
    cmu_mb_rest_joints, import_walk_cycle,
};
