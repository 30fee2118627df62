//! # sartor-body
//!
//! The parametric human body of sartor: `M_b(β, θ) = W(T_b(β, θ), β, θ, W_b)`.
//!
//! - [`TriMesh`]: validated triangle meshes, OBJ I/O, normals, topology.
//! - [`BodyModel`]: template, shape basis, joint shape basis, [`Skeleton`], [`SkinWeights`];
//!   saved as safetensors + JSON; SMPL `.npz` files load into the same type.
//! - [`load_builtin`]: the built-in CC0 MakeHuman body (`datasets/body/makehuman`, made by
//!   [`import_makehuman`]); [`PhenotypeSpace`] maps MakeHuman's sliders or a text request
//!   such as `"female, 1.70 m, heavy"` to its shape vector β.
//! - [`skin_points`] / [`unskin_points`]: linear blend skinning and its inverse, the one
//!   implementation every sartor crate uses.
//! - [`Motion`]s on the built-in skeleton: the [`procedural`] clip library, the imported
//!   MakeHuman walk ([`import_walk_cycle`]), CMU-style BVH ([`Bvh`], [`retarget_bvh`]) and
//!   AMASS-style `.npz` ([`load_amass`]), retargeted by world orientation onto a
//!   [`RetargetBody`]; [`load_motion`] picks one from a command-line spec.
//! - With the `mcap` feature: [`McapWriter`] / [`read_mcap`], deterministic MCAP files with
//!   `foxglove.SceneUpdate` triangle-list previews (opens in Foxglove).
//!
//! ```
//! use sartor_body::{Pose, Skeleton, SkinWeights, BoneTransform, Par, skin_points, unskin_points};
//! use nalgebra::{UnitQuaternion, Vector3};
//!
//! let skeleton = Skeleton::new(vec!["root".into(), "arm".into()], vec![None, Some(0)])?;
//! let rest_joints = [Vector3::zeros(), Vector3::new(1.0, 0.0, 0.0)];
//! let mut pose = Pose::rest(2);
//! pose.local_rotations[1] = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5);
//! let (_, transforms) = skeleton.forward_kinematics(&rest_joints, &pose)?;
//! let weights = SkinWeights::from_dense_top_k(&[0.3, 0.7], 2, 4)?;
//! let rest = [Vector3::new(1.5, 0.1, 0.0)];
//! let mut posed = [Vector3::zeros()];
//! skin_points(&rest, &weights, &transforms, &mut posed, Par::Seq)?;
//! let mut back = [Vector3::zeros()];
//! unskin_points(&posed, &weights, &transforms, &mut back, Par::Seq)?;
//! assert!((back[0] - rest[0]).norm() < 1e-12);
//! # Ok::<(), sartor_body::Error>(())
//! ```

mod amass;
mod binding;
mod bvh;
mod error;
mod features;
pub mod io;
mod makehuman;
#[cfg(feature = "mcap")]
mod mcap_file;
mod mesh;
mod model;
mod motion;
mod motion_sources;
pub mod npz;
mod obj;
mod phenotype;
pub mod procedural;
mod proximity;
mod rig;
mod skeleton;
mod skinning;
mod smpl;
mod walkcycle;

pub use amass::{
    AmassData, AmassOptions, SMPL_BODY_PARENTS, SMPL_TO_RIG, load_amass, retarget_amass,
    retarget_amass_native_rate,
};
pub use binding::{faces_near, transfer_skin_weights};
pub use bvh::{
    Bvh, BvhChannel, BvhJoint, BvhRetargetOptions, BvhRetargetReport, cmu_to_rig_name,
    load_bvh_motion, retarget_bvh, retarget_bvh_native_rate,
};
pub use error::{Error, Result};
pub use features::{PoseFeatureSpec, PoseFeatures, RootFeature, RotationEncoding};
pub use makehuman::{
    BONE_FRAMES_FILE, BoneFrames, HeldOutReport, IMPORT_REPORT_FILE, ImportOptions, ImportReport,
    JointReport, MeshReport, PcaReport, SAMPLE_RANGES, ShapeSpaceReport, SkinWeightReport,
    TPOSE_FILE, TPoseReport, TopKReport, blender_euler_xyz, builtin_model_dir, import_makehuman,
    load_builtin, load_tpose,
};
#[cfg(feature = "mcap")]
pub use mcap_file::{
    McapContents, McapMessage, McapWriter, OwnedSceneMesh, SCENE_FRAME_ID, SCENE_UPDATE_SCHEMA,
    SceneMesh, decode_scene, read_mcap,
};
pub use mesh::{Hinge, MeshTopology, TriMesh, bounding_box, face_normals, vertex_normals};
pub use model::{BodyModel, MODEL_HEADER, MODEL_TENSORS, Provenance};
pub use motion::{FPS, Motion, interpolate_pose};
pub use motion_sources::{
    MotionSourceOptions, RetargetBody, UpAxis, WALK_NAME, load_motion, pose_from_world,
    split_heading, world_rotations,
};
pub use obj::{ObjData, obj_text, read_obj, write_obj};
pub use phenotype::{
    PHENOTYPE_HEADER, PHENOTYPE_TENSORS, PartialPhenotype, Phenotype, PhenotypeRequest,
    PhenotypeSampling, PhenotypeSpace, SLIDERS,
};
pub use proximity::{ClosestPoint, MeshProximity};
pub use rig::{CMU_MB_JOINTS, cmu_mb_skeleton};
pub use skeleton::{Pose, PosedSkeleton, Skeleton};
pub use skinning::{BoneTransform, Par, SkinWeights, skin_points, unskin_points};
pub use smpl::{SMPL_JOINTS, load_smpl_npz, smpl_from_npz};
pub use walkcycle::{
    BLENDER_FPS, CMU_MB_RIG_FILE, DEFAULT_RIG_FILE, WALK_CYCLE_FILE, WALK_CYCLES,
    cmu_mb_rest_joints, import_walk_cycle,
};
