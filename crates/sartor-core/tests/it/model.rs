//! Skinning, inverse skinning, shape evaluation and the model file format.

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use sartor_core::{
    BodyModel, Parallelism, Pose, PoseBuffers, SurfaceAnchors, skin_points, transfer_skin_weights,
    transfer_skin_weights_on, unskin_points,
};

use crate::common::{builtin_body, model, random_pose, random_weights, rng};

#[test]
fn rest_pose_skins_to_the_shaped_template() {
    let m = model(1);
    let mut r = rng(2);
    for _ in 0..5 {
        let betas: Vec<f64> = (0..10).map(|_| 3.0 * (r.random::<f64>() - 0.5)).collect();
        let shaped = m.shaped_vertices(&betas).expect("valid betas");
        let posed = m
            .posed_vertices(&betas, &Pose::rest(5))
            .expect("valid pose");
        let err = shaped
            .iter()
            .zip(&posed)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(err < 1e-6, "θ = 0 moved a vertex by {err} m");
    }
}

#[test]
fn inverse_skinning_undoes_skinning() {
    let m = model(3);
    let mut r = rng(4);
    for trial in 0..20 {
        let n = 500;
        let weights = random_weights(&mut r, n, 5);
        let rest: Vec<Vector3<f64>> = (0..n)
            .map(|_| {
                Vector3::new(
                    r.random::<f64>() - 0.5,
                    0.5 + r.random::<f64>(),
                    r.random::<f64>() - 0.5,
                )
            })
            .collect();
        // Moderate rotations: blended transforms of weights split between joints rotated far apart
        // become singular (that case is tested as an error elsewhere).
        let pose = random_pose(&mut r, 5, 1.5);
        let betas: Vec<f64> = (0..10).map(|_| r.random::<f64>() - 0.5).collect();
        let transforms = m.skinning_transforms(&betas, &pose).expect("valid");
        let mut posed = vec![Vector3::zeros(); n];
        skin_points(
            &rest,
            &weights,
            &transforms,
            &mut posed,
            Parallelism::Sequential,
        )
        .expect("sizes");
        let mut back = vec![Vector3::zeros(); n];
        unskin_points(&posed, &weights, &transforms, &mut back, Parallelism::Rayon)
            .expect("invertible");
        let err = rest
            .iter()
            .zip(&back)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(err < 1e-5, "trial {trial}: round trip error {err} m");
        // f32 path through the same kernels.
        let t32: Vec<_> = transforms.iter().map(|t| t.to_f32()).collect();
        let rest32: Vec<Vector3<f32>> = rest.iter().map(|p| p.cast()).collect();
        let mut posed32 = vec![Vector3::zeros(); n];
        skin_points(
            &rest32,
            &weights,
            &t32,
            &mut posed32,
            Parallelism::Sequential,
        )
        .expect("sizes");
        let err32 = posed
            .iter()
            .zip(&posed32)
            .map(|(a, b)| (a - b.cast::<f64>()).norm())
            .fold(0.0, f64::max);
        assert!(err32 < 1e-5, "f32 skinning differs by {err32} m");
    }
}

#[test]
fn parallel_and_sequential_skinning_agree_bitwise() {
    let m = model(5);
    let mut r = rng(6);
    let n = 5000;
    let weights = random_weights(&mut r, n, 5);
    let rest: Vec<Vector3<f64>> = (0..n)
        .map(|_| Vector3::new(r.random(), r.random(), r.random()))
        .collect();
    let transforms = m
        .skinning_transforms(&[], &random_pose(&mut r, 5, 2.0))
        .expect("valid");
    let (mut a, mut b) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
    skin_points(
        &rest,
        &weights,
        &transforms,
        &mut a,
        Parallelism::Sequential,
    )
    .expect("sizes");
    skin_points(&rest, &weights, &transforms, &mut b, Parallelism::Rayon).expect("sizes");
    assert_eq!(a, b);
}

#[test]
fn posing_some_vertices_gives_their_bits_and_leaves_the_rest() {
    let body = builtin_body();
    let n = body.n_vertices();
    let mut r = rng(9);
    let betas: Vec<f64> = (0..body.n_betas())
        .map(|_| r.random_range(-2.0..2.0))
        .collect();
    let pose = random_pose(&mut r, body.skeleton().n_joints(), 0.8);
    let mut all = vec![Vector3::zeros(); n];
    PoseBuffers::default()
        .pose_into(&body, &betas, &pose, &mut all)
        .expect("pose");
    // Every seventh vertex, into a buffer of sentinels.
    let some: Vec<u32> = (0..n as u32).step_by(7).collect();
    let sentinel = Vector3::repeat(-7.0);
    let mut part = vec![sentinel; n];
    let mut buffers = PoseBuffers::default();
    buffers
        .pose_vertices_into(&body, &betas, &pose, &some, &mut part)
        .expect("pose");
    for (v, (a, b)) in all.iter().zip(&part).enumerate() {
        if v % 7 == 0 {
            assert_eq!(a, b, "vertex {v}");
        } else {
            assert_eq!(*b, sentinel, "vertex {v} was not asked for");
        }
    }
    // The joints and transforms are the whole pose's.
    let mut whole = PoseBuffers::default();
    whole
        .pose_into(&body, &betas, &pose, &mut all)
        .expect("pose");
    assert_eq!(buffers.posed_joints(), whole.posed_joints());
    // A vertex past the body, or a buffer of another size: errors naming the fault.
    let past = buffers.pose_vertices_into(&body, &betas, &pose, &[n as u32], &mut part);
    assert!(
        past.expect_err("past the body")
            .to_string()
            .contains("vertex")
    );
    let short = buffers.pose_vertices_into(&body, &betas, &pose, &some, &mut part[1..]);
    assert!(short.expect_err("short").to_string().contains("outputs"));
}

#[test]
fn joints_move_with_shape() {
    let m = model(7);
    let j0 = m.shaped_joints(&[]).expect("valid");
    let mut e0 = vec![0.0; 10];
    e0[0] = 1.0;
    let j1 = m.shaped_joints(&e0).expect("valid");
    assert!(j0.iter().zip(&j1).any(|(a, b)| (a - b).norm() > 1e-4));
}

#[test]
fn extremes_stay_finite_and_bad_input_is_an_error() {
    let m = model(8);
    for b in 0..10 {
        for s in [-5.0, 5.0] {
            let mut betas = vec![0.0; 10];
            betas[b] = s;
            let mut pose = Pose::rest(5);
            for q in &mut pose.local_rotations {
                *q = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 179f64.to_radians());
            }
            pose.root_orientation =
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 179.9f64.to_radians());
            let v = m.posed_vertices(&betas, &pose).expect("finite input");
            assert!(v.iter().all(|p| p.iter().all(|c| c.is_finite())));
        }
    }
    assert!(m.shaped_vertices(&[f64::NAN]).is_err());
    assert!(m.shaped_vertices(&[f64::INFINITY]).is_err());
    assert!(m.shaped_vertices(&[0.0; 11]).is_err());
    let mut pose = Pose::rest(5);
    pose.root_translation_m.x = f64::NAN;
    assert!(m.posed_vertices(&[], &pose).is_err());
}

#[test]
fn save_load_round_trip_is_exact_and_deterministic() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Round to f32 first: the file stores f32.
    let m = model(9);
    m.save(dir.path()).expect("save");
    let loaded = BodyModel::load(dir.path()).expect("load");
    loaded.save(&dir.path().join("again")).expect("save again");
    let again = BodyModel::load(&dir.path().join("again")).expect("load again");
    assert_eq!(loaded, again);
    for f in ["model.safetensors", "model.json"] {
        let a = std::fs::read(dir.path().join(f)).expect("read");
        let b = std::fs::read(dir.path().join("again").join(f)).expect("read");
        assert_eq!(a, b, "{f} differs between two saves");
    }
    let err = m.shaped_vertices(&[0.5; 10]).expect("ok");
    let err2 = loaded.shaped_vertices(&[0.5; 10]).expect("ok");
    let d = err
        .iter()
        .zip(&err2)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(d < 1e-6, "f32 storage changed a vertex by {d} m");
}

#[test]
fn corrupt_model_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    model(10).save(dir.path()).expect("save");
    let tensors = dir.path().join("model.safetensors");
    let header = dir.path().join("model.json");
    let good_t = std::fs::read(&tensors).expect("read");
    let good_h = std::fs::read_to_string(&header).expect("read");

    // Truncated tensors.
    std::fs::write(&tensors, &good_t[..good_t.len() / 2]).expect("write");
    let e = BodyModel::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("model.safetensors"), "{e}");
    std::fs::write(&tensors, &good_t).expect("write");

    // Header faults.
    for (from, to, needle) in [
        ("\"units\": \"m\"", "\"units\": \"dm\"", "units"),
        ("\"n_betas\": 10", "\"n_betas\": 11", "model"),
        (
            "\"format\": \"sartor-body\"",
            "\"format\": \"other\"",
            "format",
        ),
        ("\"name\"", "\"nmae\"", "model.json"),
    ] {
        std::fs::write(&header, good_h.replace(from, to)).expect("write");
        let e = BodyModel::load(dir.path()).unwrap_err().to_string();
        assert!(e.contains(needle), "{from} → {to}: {e}");
    }
    std::fs::write(&header, &good_h[..good_h.len() - 20]).expect("write");
    let e = BodyModel::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("model.json"), "{e}");
    std::fs::remove_file(&header).expect("rm");
    let e = BodyModel::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("model.json"), "{e}");
}

/// Replays inputs the fuzzer found, the way `fuzz/fuzz_targets/model_safetensors.rs` feeds them:
/// each must give an error, not a panic.
#[test]
fn fuzz_regressions_are_errors() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).expect("fuzz regression folder") {
        let path = entry.expect("entry").path();
        let data = std::fs::read(&path).expect("read");
        let names: Vec<String> = ["Hips", "LHipJoint", "LeftUpLeg"]
            .iter()
            .map(|n| format!("{n:?}"))
            .collect();
        let header = format!(
            r#"{{"format":"sartor-body","version":1,"name":"f","units":"m","axes":"","n_vertices":4,"n_faces":4,
               "n_betas":2,"joint_names":[{}],"parents":[null,0,1],
               "provenance":{{"source":"","licence":"","notes":""}},"tensors_sha256":"{}"}}"#,
            names.join(","),
            sartor_core::io::sha256_hex(&data)
        );
        let result = BodyModel::from_bytes(std::path::Path::new("fuzz"), header.as_bytes(), data);
        assert!(
            result.is_err(),
            "{} loaded as a valid model",
            path.display()
        );
        n += 1;
    }
    assert!(n > 0, "no fuzz regressions found in {}", dir.display());
}

#[test]
fn the_template_proximity_is_built_once_and_answers_as_a_new_one() {
    let body = builtin_body();
    let before = body.clone();
    let cached = body.template_proximity().expect("a closed template");
    // Built once: the second call and a clone made after it give the same structure.
    assert!(std::ptr::eq(
        cached,
        body.template_proximity().expect("built")
    ));
    let clone = body.clone();
    assert!(std::ptr::eq(
        cached,
        clone.template_proximity().expect("shared")
    ));
    // A cache only: the model equals one whose structure is not built yet.
    assert_eq!(body, before);
    // Anchors through it are those of a structure built from the template's own arrays, on
    // points around the body (the template's vertices pushed 3 cm along random directions).
    let mut r = rng(21);
    let points: Vec<Vector3<f64>> = body
        .template()
        .positions()
        .iter()
        .step_by(13)
        .map(|p| {
            let d = Vector3::new(r.random(), r.random(), r.random()) - Vector3::repeat(0.5);
            p + d.normalize() * 0.03
        })
        .collect();
    let fresh = SurfaceAnchors::new(
        body.template().positions(),
        body.faces(),
        points.iter().copied(),
    )
    .expect("anchors");
    let on = SurfaceAnchors::on(cached, points.iter().copied());
    // And so are the skin weights transferred through it.
    let weights = |w: sartor_core::SkinWeights| w.to_dense();
    assert_eq!(
        weights(transfer_skin_weights_on(cached, body.skin_weights(), &points, 0.01).expect("on")),
        weights(
            transfer_skin_weights(
                body.template().positions(),
                body.faces(),
                body.skin_weights(),
                &points,
                0.01
            )
            .expect("fresh")
        )
    );
    assert_eq!(on.len(), points.len());
    let (from, to) = (
        body.template().positions(),
        body.shaped_vertices(&[1.0; 4]).expect("β"),
    );
    for i in 0..points.len() {
        assert_eq!(
            on.displacement(i, &to, from),
            fresh.displacement(i, &to, from),
            "point {i}"
        );
    }
}
