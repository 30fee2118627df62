//! # sartor-core
//!
//! The geometry core every sartor stage shares: the parametric body
//! `M_b(β, θ) = W(T_b(β, θ), β, θ, W_b)` and what later stages need of it. No importers, no
//! motion file formats, no compression, no physics, no learning: `sartor-runtime` depends on
//! this crate alone, so it builds anywhere (WebAssembly included).
//!
//! - [`TriMesh`]: validated triangle meshes, OBJ I/O, normals, topology.
//! - [`Skeleton`], [`Pose`]: joint hierarchy, forward kinematics, pose interpolation, the
//!   heading/tilt split of a root rotation; [`FPS`], the frame rate of every motion.
//! - [`BodyModel`]: template, shape basis, joint shape basis, skeleton, [`SkinWeights`]; saved
//!   as safetensors + JSON. [`PhenotypeSpace`] maps MakeHuman's sliders or a text request such
//!   as `"female, 1.70 m, heavy"` to the shape vector β; [`BodyMeasurer`] takes a body's
//!   size-chart measurements (height, chest, waist, hips, mass).
//! - [`skin_points`] (and [`skin_points_at`], a few points) / [`unskin_points`]: linear blend
//!   skinning and its inverse, the one implementation every sartor crate uses.
//! - [`MeshProximity`]: the one closest-point query (refittable BVH, signed distance).
//! - [`PoseFeatures`]: the per-frame network inputs, computed by the same code in the dataset
//!   and the runtime.
//! - [`transfer_skin_weights`], [`faces_near`]: binding a garment to the body.
//! - [`io`]: atomic writes, checked safetensors access, hashing.
//!
//! ```
//! use sartor_core::{Pose, Skeleton, SkinWeights, BoneTransform, Parallelism, skin_points, unskin_points};
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
//! skin_points(&rest, &weights, &transforms, &mut posed, Parallelism::Sequential)?;
//! let mut back = [Vector3::zeros()];
//! unskin_points(&posed, &weights, &transforms, &mut back, Parallelism::Sequential)?;
//! assert!((back[0] - rest[0]).norm() < 1e-12);
//! # Ok::<(), sartor_core::Error>(())
//! ```

pub mod asset;
pub mod awake;
mod binding;
mod body_distance;
pub mod bytes;
mod error;
mod features;
pub mod io;
mod measure;
mod mesh;
mod model;
mod norm;
mod obj;
mod phenotype;
mod proximity;
pub mod rsvd;
mod skeleton;
mod skinning;
pub mod tree;

pub use binding::{
    BINDING_FORMAT, BINDING_JSON, BINDING_TENSORS, BINDING_VERSION, BindingHeader,
    DEFAULT_REGION_MARGIN_MM, GarmentBinding, SurfaceAnchors, faces_near, transfer_skin_weights,
    transfer_skin_weights_on,
};
pub use body_distance::{BodyDistance, BodyPoint};
pub use error::{Error, Result};
pub use features::{PoseFeatureSpec, PoseFeatures, RootFeature, RotationEncoding};
pub use measure::{
    BODY_DENSITY_KG_PER_M3, BodyMeasurements, BodyMeasurer, FIT_BETA_LIMIT, MeasurementFit,
    MeasurementTargets, fit_measurements,
};
pub use mesh::{
    Hinge, MeshTopology, TriMesh, bounding_box, box_mesh, compact_faces, enclosed_volume,
    face_normals, vertex_normals,
};
pub use model::{BodyModel, BodyPoser, MODEL_HEADER, MODEL_TENSORS, PoseBuffers, Provenance};
pub use norm::{MeanStd, NormStats};
pub use obj::{ObjData, obj_text, read_obj, write_obj};
pub use phenotype::{
    MacroPart, MacroRule, MacroTarget, MacroVariable, PHENOTYPE_HEADER, PHENOTYPE_TENSORS,
    PartialPhenotype, Phenotype, PhenotypeRequest, PhenotypeSampling, PhenotypeSpace, SLIDERS,
};
pub use proximity::{ClosestFeature, ClosestPoint, MeshProximity, NearFaces, NearestFace};
pub use skeleton::{
    FPS, Pose, PosedSkeleton, Skeleton, canonical, interpolate_pose, split_heading,
};
pub use skinning::{
    BoneTransform, Parallelism, SkinWeights, skin_points, skin_points_at, unskin_points,
    unskin_points_damped,
};
