//! Shared fixtures: the built-in body and the tiny T-shirt.

use std::path::Path;

use sartor_core::asset::AssetId;
use sartor_core::{BodyModel, GarmentBinding, TriMesh, read_obj};
use sartor_dataset::{DataSource, Smoother, bind_garment};

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

/// Garment and body ids for tests (any well-formed ids).
pub fn source() -> DataSource {
    DataSource {
        garment: AssetId {
            id: "tshirt-tiny".into(),
            sha256: "a".repeat(64),
        },
        body: AssetId {
            id: "makehuman".into(),
            sha256: "b".repeat(64),
        },
    }
}

/// `garment` (relaxed on the template body) bound to `body` with the smoother `rho`.
pub fn bind(body: &BodyModel, garment: &TriMesh, rho: &Smoother) -> GarmentBinding {
    bind_garment(body, &source(), garment.positions(), garment.faces(), rho).expect("binds")
}
