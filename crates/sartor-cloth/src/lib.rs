//! # sartor-cloth
//!
//! The physics core of sartor's ground-truth simulator (f64), following ARCSim — the simulator
//! that produced the data of "Learning-Based Animation of Clothing for Virtual Try-On":
//!
//! - [`Material`]: ARCSim's tabulated orthotropic membrane and bending models (Wang et al.
//!   2011) with their stiffness lookups reproduced from ARCSim's source, the gray-interlock
//!   T-shirt material as the default, a StVK membrane for tests, and JSON material files.
//! - [`energy`]: per-element energies with exact gradients and Hessians (membrane, bending,
//!   obstacle and self-contact penalties) and their PSD projections.
//! - [`Cloth`]: a validated cloth mesh with per-triangle material frames.
//! - [`Simulator`]: implicit Euler with one linearised Newton step per substep (more on
//!   request), sparse Cholesky ([`LinearSolver::Cholesky`]) or block-Jacobi CG, pins,
//!   obstacles ([`Collider`]: [`Plane`], [`Sphere`], [`MeshCollider`] for a deforming body),
//!   friction, self-collision, a projection fallback and failure detection ([`StepFailure`]).
//! - [`Garment`]: garment templates with their rest metric and file format, made by
//!   [`build_garment`] from a config: the procedural T-shirt ([`build_tshirt`]) or a user OBJ
//!   ([`import_obj_garment`]); isotropic remeshing to an exact triangle count
//!   ([`remesh_to_count`]); [`relax_on_body`] lets a template come to rest on the body.
//! - [`simulate_sequence`]: the simulator driven by a moving body through the paper's protocol
//!   (blend shape and pose from rest, settle, play the motion) with failure detection and
//!   retries ([`DriveConfig`]); its result, a [`ClothSequence`], is one MCAP file per (shape,
//!   motion) with a Foxglove preview ([`ClothSequence::write`], [`ClothSequence::read`]).
//!
//! ```
//! use nalgebra::Vector3;
//! use sartor_cloth::{Cloth, Collider, Material, Plane, SimConfig, Simulator, rectangle_sheet};
//!
//! // A 20 cm sheet, 1 cm above the floor.
//! let mesh = rectangle_sheet(
//!     Vector3::new(-0.1, 0.01, 0.1),
//!     Vector3::new(0.2, 0.0, 0.0),
//!     Vector3::new(0.0, 0.0, -0.2),
//!     6,
//!     6,
//! )?;
//! let cloth = Cloth::new(mesh, Material::gray_interlock(), None)?;
//! let mut sim = Simulator::new(cloth, SimConfig::default())?;
//! let floor = Plane::horizontal(0.0);
//! for _ in 0..30 {
//!     sim.step(1.0 / 300.0, &[&floor as &dyn Collider])?;
//! }
//! assert!(sim.positions().iter().all(|p| p.y > 0.0));
//! # Ok::<(), sartor_cloth::Error>(())
//! ```

#![warn(missing_docs)]

mod benchmark;
mod cloth;
mod collider;
mod drive;
pub mod energy;
mod error;
mod garment;
mod isa;
mod linsolve;
mod material;
mod mesh_collider;
mod prefetch;
mod relax;
mod self_collision;
mod sequence;
mod solver;

pub use benchmark::{SequenceBenchmark, benchmark_sequence, folded_hinge_percent};
pub use cloth::{Cloth, rectangle_sheet};
pub use collider::{Collider, Contact, MotionBound, Plane, Sphere};
pub use drive::{
    DriveConfig, IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M, IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME,
    LEFT_BODY_M, PreviewConfig, RegionConfig, RetryConfig, STABLE_STEP_PER_EDGE_S_PER_M,
    contact_region, simulate_sequence,
};
pub use energy::FrictionModel;
pub use error::{Error, Result, SequenceFailure, StepFailure};
pub use garment::{
    BodyFit, GARMENT_HEADER, GARMENT_OBJ, GARMENT_REPORT, GARMENT_TENSORS, Garment, GarmentBuild,
    GarmentConfig, GarmentProvenance, GarmentReport, LengthStatsMm, MATERIAL_FRAME_CONVENTION,
    MeshQuality, ObjGarmentConfig, ObjImportOptions, RemeshOptions, RestSource, SourceKind,
    TshirtRecipe, TshirtStats, TshirtSurface, build_garment, build_tshirt, import_obj_garment,
    material_u_axes, remesh_isotropic, remesh_to_count, segment_crosses_triangle,
    self_intersections, triangles_intersect,
};
pub use linsolve::{LinearSolveStats, LinearSolver};
pub use material::{
    BendingModel, BendingTable, GRAY_INTERLOCK_BENDING, GRAY_INTERLOCK_DENSITY_KG_PER_M2,
    GRAY_INTERLOCK_STRETCHING, Material, MaterialFile, MembraneModel, STRAIN_GRID_SAMPLES,
    StrainStiffness, StretchingTable, StvkMembrane, TabulatedMembrane,
};
pub use mesh_collider::MeshCollider;
pub use relax::{RelaxConfig, RelaxReport, relax_on_body};
pub use sartor_core::Parallelism;
pub use sequence::{
    BodyId, ClothSequence, FrameInfo, GarmentId, MotionId, Phase, PreviewFrame, RegionStats,
    SEQUENCE_FORMAT, SEQUENCE_METADATA, SequenceFrame, SequenceHeader, SequencePreview,
    SequenceTiming, SolverTotals, SubstepStats,
};
pub use solver::{EnergyReport, SimConfig, Simulator, StepStats};
