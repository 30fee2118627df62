//! Shared fixtures: a small synthetic body model with random shape basis and weights.

use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sartor_core::{Pose, TriMesh};

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A UV sphere of radius 0.3 m centred 1 m up (a stand-in body), `n` rings.
pub fn sphere(n: usize) -> TriMesh {
    TriMesh::uv_sphere(Vector3::new(0.0, 1.0, 0.0), 0.3, n).expect("valid sphere")
}

pub fn random_rotation(rng: &mut ChaCha8Rng, max_angle: f64) -> UnitQuaternion<f64> {
    let axis = Vector3::new(
        rng.random::<f64>() - 0.5,
        rng.random::<f64>() - 0.5,
        rng.random::<f64>() - 0.5,
    );
    UnitQuaternion::from_scaled_axis(axis.normalize() * max_angle * rng.random::<f64>())
}

pub fn random_pose(rng: &mut ChaCha8Rng, n_joints: usize, max_angle: f64) -> Pose {
    Pose {
        root_translation_m: Vector3::new(
            rng.random::<f64>() - 0.5,
            0.1 * rng.random::<f64>(),
            rng.random::<f64>(),
        ),
        root_orientation: random_rotation(rng, max_angle),
        local_rotations: (0..n_joints)
            .map(|_| random_rotation(rng, max_angle))
            .collect(),
    }
}

/// Where two JSON documents differ beyond `tol` in any number (or at all elsewhere), the path of
/// the first difference. Committed imports are compared this way: libm's transcendental
/// functions may round the last bit differently on another CPU.
pub fn json_difference(a: &serde_json::Value, b: &serde_json::Value, tol: f64) -> Option<String> {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64()?, y.as_f64()?);
            let scale = x.abs().max(y.abs()).max(1.0);
            ((x - y).abs() > tol * scale).then(|| format!(": {x} vs {y}"))
        }
        (Value::Array(x), Value::Array(y)) => {
            if x.len() != y.len() {
                return Some(format!(": {} vs {} items", x.len(), y.len()));
            }
            x.iter()
                .zip(y)
                .enumerate()
                .find_map(|(i, (x, y))| json_difference(x, y, tol).map(|d| format!("[{i}]{d}")))
        }
        (Value::Object(x), Value::Object(y)) => {
            if x.len() != y.len() || x.keys().any(|k| !y.contains_key(k)) {
                return Some(": different keys".to_owned());
            }
            x.iter()
                .find_map(|(k, v)| json_difference(v, &y[k], tol).map(|d| format!(".{k}{d}")))
        }
        _ => (a != b).then(|| format!(": {a} vs {b}")),
    }
}

/// The built-in body model folder of the workspace (`datasets/body/makehuman`).
pub fn builtin_model_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman")
}

/// The built-in body model.
pub fn load_builtin() -> sartor_core::Result<sartor_core::BodyModel> {
    sartor_core::BodyModel::load(&builtin_model_dir())
}
