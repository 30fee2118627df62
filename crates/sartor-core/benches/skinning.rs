//! Skinning the built-in 13,380-vertex body: one frame of forward kinematics + linear blend
//! skinning (f64 and f32), sequential and on rayon's pool, and inverse skinning.

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{UnitQuaternion, Vector3};
use sartor_core::{BodyModel, Parallelism, Pose, skin_points, unskin_points};

fn load() -> BodyModel {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman");
    BodyModel::load(&dir).expect("the built-in model (run `cargo xtask import-body` first)")
}

fn bench(c: &mut Criterion) {
    let model = load();
    let betas = [0.5, -1.0, 0.3, 0.0, 0.2, 0.0, 0.0, 0.1, 0.0, -0.4];
    let rest = model.shaped_vertices(&betas).expect("valid");
    let joints = model.shaped_joints(&betas).expect("valid");
    let n_j = model.skeleton().n_joints();
    let mut pose = Pose::rest(n_j);
    for (j, q) in pose.local_rotations.iter_mut().enumerate() {
        *q = UnitQuaternion::from_scaled_axis(
            Vector3::new(0.1, 0.05 * j as f64, -0.07).map(|x| x.sin()),
        );
    }
    let weights = model.skin_weights();
    let mut out = vec![Vector3::zeros(); rest.len()];
    let mut posed_joints = vec![Vector3::zeros(); n_j];
    let mut transforms = vec![sartor_core::BoneTransform::identity(); n_j];
    let mut group = c.benchmark_group(format!("skin_body_{}_vertices", rest.len()));
    group.bench_function("fk+lbs f64 seq", |b| {
        b.iter(|| {
            model
                .skeleton()
                .forward_kinematics_into(&joints, &pose, &mut posed_joints, &mut transforms)
                .expect("valid");
            skin_points(
                black_box(&rest),
                weights,
                &transforms,
                &mut out,
                Parallelism::Sequential,
            )
            .expect("sizes");
        })
    });
    group.bench_function("lbs f64 rayon", |b| {
        b.iter(|| {
            skin_points(
                black_box(&rest),
                weights,
                &transforms,
                &mut out,
                Parallelism::Rayon,
            )
            .expect("sizes")
        })
    });
    let rest32: Vec<Vector3<f32>> = rest.iter().map(|p| p.cast()).collect();
    let t32: Vec<_> = transforms.iter().map(|t| t.to_f32()).collect();
    let mut out32 = vec![Vector3::zeros(); rest.len()];
    group.bench_function("lbs f32 seq", |b| {
        b.iter(|| {
            skin_points(
                black_box(&rest32),
                weights,
                &t32,
                &mut out32,
                Parallelism::Sequential,
            )
            .expect("sizes")
        })
    });
    let posed = out.clone();
    let mut back = vec![Vector3::zeros(); rest.len()];
    group.bench_function("inverse lbs f64 seq", |b| {
        b.iter(|| {
            unskin_points(
                black_box(&posed),
                weights,
                &transforms,
                &mut back,
                Parallelism::Sequential,
            )
            .expect("invertible")
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
