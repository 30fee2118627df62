//! Garment templates: isotropic remeshing to an exact triangle count, the procedural T-shirt
//! built from the template body, import of user garments (OBJ, optionally with a 2D sewing
//! pattern in `vt`), the [`Garment`] type with its rest metric, and its file format.
//!
//! The pipeline of `cargo xtask garment`: recipe or OBJ → surface → [`Garment`] →
//! (relaxation on the body by the simulator, via [`Garment::with_template_positions`]) →
//! [`Garment::save`] + [`GarmentReport`].

mod config;
mod frame;
mod halfedge;
mod import;
mod intersect;
mod quality;
mod remesh;
mod report;
mod template;
mod tshirt;

pub use config::{GarmentBuild, GarmentConfig, ObjGarmentConfig, build_garment};
pub use frame::material_u_axes;
pub use import::{ObjImportOptions, import_obj_garment};
pub use intersect::{segment_crosses_triangle, self_intersections, triangles_intersect};
pub use quality::{LengthStatsMm, MeshQuality};
pub use remesh::{RemeshOptions, remesh_isotropic, remesh_to_count};
pub use report::{BodyFit, GarmentReport};
pub use template::{
    GARMENT_HEADER, GARMENT_OBJ, GARMENT_REPORT, GARMENT_TENSORS, Garment, GarmentProvenance,
    MATERIAL_FRAME_CONVENTION, RestSource, SourceKind,
};
pub use tshirt::{TshirtRecipe, TshirtStats, TshirtSurface, build_tshirt};
