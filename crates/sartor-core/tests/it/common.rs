//! Shared fixtures: a small synthetic body model with random shape basis and weights.

use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sartor_core::{BodyModel, Pose, Provenance, Skeleton, SkinWeights, TriMesh};

/// The built-in MakeHuman body (`datasets/body/makehuman`).
pub fn builtin_body() -> BodyModel {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman");
    BodyModel::load(&dir).expect("built-in body")
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A UV sphere of radius 0.3 m centred 1 m up (a stand-in body), `n` rings.
pub fn sphere(n: usize) -> TriMesh {
    TriMesh::uv_sphere(Vector3::new(0.0, 1.0, 0.0), 0.3, n).expect("valid sphere")
}

/// A 5-joint chain-and-branch skeleton.
pub fn skeleton() -> Skeleton {
    let names = ["root", "spine", "head", "l_arm", "r_arm"]
        .map(String::from)
        .to_vec();
    Skeleton::new(names, vec![None, Some(0), Some(1), Some(1), Some(1)]).expect("valid")
}

pub fn random_weights(rng: &mut ChaCha8Rng, n_points: usize, n_joints: usize) -> SkinWeights {
    let dense: Vec<f32> = (0..n_points * n_joints)
        .map(|_| rng.random::<f32>().powi(3))
        .collect();
    SkinWeights::from_dense_top_k(&dense, n_joints, 4).expect("positive rows")
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

/// A synthetic body model on the sphere with 10 random shape components.
pub fn model(seed: u64) -> BodyModel {
    let mut r = rng(seed);
    let template = sphere(8);
    let nb = 10;
    let v = template.n_vertices();
    let shape_basis: Vec<f64> = (0..v * 3 * nb)
        .map(|_| 0.01 * (r.random::<f64>() - 0.5))
        .collect();
    let joints = vec![
        Vector3::new(0.0, 0.8, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(0.0, 1.2, 0.0),
        Vector3::new(0.2, 1.1, 0.0),
        Vector3::new(-0.2, 1.1, 0.0),
    ];
    let joint_shape_basis: Vec<f64> = (0..joints.len() * 3 * nb)
        .map(|_| 0.01 * (r.random::<f64>() - 0.5))
        .collect();
    let weights = random_weights(&mut r, v, joints.len());
    BodyModel::new(
        "synthetic".into(),
        template,
        nb,
        shape_basis,
        joints,
        joint_shape_basis,
        skeleton(),
        weights,
        Provenance {
            source: "test".into(),
            licence: "CC0".into(),
            notes: String::new(),
        },
    )
    .expect("valid model")
}
