//! # sartor-body
//!
//! The parametric human body of sartor: `M_b(β, θ) = W(T_b(β, θ), β, θ, W_b)`.
//!
//! - [`TriMesh`]: validated triangle meshes, OBJ I/O, normals, topology.
//! - [`BodyModel`]: template, shape basis, joint shape basis, [`Skeleton`], [`SkinWeights`];
//!   saved as safetensors + JSON; SMPL `.npz` files load into the same type.
//! - [`skin_points`] / [`unskin_points`]: linear blend skinning and its inverse, the one
//!   implementation every sartor crate uses.
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

mod error;
pub mod io;
mod mesh;
mod model;
mod motion;
pub mod npz;
mod obj;
mod rig;
mod skeleton;
mod skinning;
mod smpl;

pub use error::{Error, Result};
pub use mesh::{MeshTopology, TriMesh, bounding_box, face_normals, vertex_normals};
pub use model::{BodyModel, MODEL_HEADER, MODEL_TENSORS, Provenance};
pub use motion::{FPS, Motion, interpolate_pose};
pub use obj::{ObjData, obj_text, read_obj, write_obj};
pub use rig::{CMU_MB_JOINTS, cmu_mb_skeleton};
pub use skeleton::{Pose, PosedSkeleton, Skeleton};
pub use skinning::{BoneTransform, Par, SkinWeights, skin_points, unskin_points};
pub use smpl::{SMPL_JOINTS, load_smpl_npz, smpl_from_npz};
