//! Shared fixtures: sheets, simulators and seeded random numbers.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sartor_cloth::{Cloth, Material, SimConfig, Simulator, rectangle_sheet};

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A horizontal square sheet of side `size_m` centred at `(0, height_m, 0)`, `n × n` quads,
/// normal +Y.
pub fn horizontal_sheet(size_m: f64, n: usize, height_m: f64, material: Material) -> Cloth {
    let mesh = rectangle_sheet(
        Vector3::new(-0.5 * size_m, height_m, 0.5 * size_m),
        Vector3::new(size_m, 0.0, 0.0),
        Vector3::new(0.0, 0.0, -size_m),
        n,
        n,
    )
    .expect("valid sheet");
    Cloth::new(mesh, material, None).expect("valid cloth")
}

/// A StVK sheet material (about the gray-interlock small-strain stiffness) with constant bending.
pub fn stvk() -> Material {
    Material::stvk(0.187, 10.0, 20.0, 2e-5).expect("valid material")
}

pub fn simulator(cloth: Cloth, config: SimConfig) -> Simulator {
    Simulator::new(cloth, config).expect("valid simulator")
}

/// A UV sphere (closed, outward-oriented) of radius `radius_m` at `center`, `n` rings.
pub fn uv_sphere(
    center: Vector3<f64>,
    radius_m: f64,
    n: usize,
) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
    let mesh = sartor_core::TriMesh::uv_sphere(center, radius_m, n).expect("valid sphere");
    (mesh.positions().to_vec(), mesh.faces().to_vec())
}

/// The built-in body model folder of the workspace (`datasets/body/makehuman`).
pub fn builtin_model_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman")
}

/// The built-in body model.
pub fn load_builtin() -> sartor_core::Result<sartor_core::BodyModel> {
    sartor_core::BodyModel::load(&builtin_model_dir())
}
