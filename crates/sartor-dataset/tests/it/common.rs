//! Shared fixtures: the built-in body and the tiny T-shirt.

use std::path::Path;

use sartor_core::{BodyModel, TriMesh, read_obj};

pub fn body() -> BodyModel {
    load_builtin().expect("the built-in body is committed")
}

/// The committed 500-triangle T-shirt (as relaxed on the template body).
pub fn tiny_tshirt() -> TriMesh {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../datasets/garments/tshirt-tiny/garment.obj");
    read_obj(&path).expect("the tiny T-shirt is committed")
}

/// The built-in body model folder of the workspace (`datasets/body/makehuman`).
pub fn builtin_model_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman")
}

/// The built-in body model.
pub fn load_builtin() -> sartor_core::Result<sartor_core::BodyModel> {
    sartor_core::BodyModel::load(&builtin_model_dir())
}
