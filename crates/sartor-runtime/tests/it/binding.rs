//! `binding.safetensors` + `binding.json`: round trip, validation, every file fault, and the
//! checks against the model and the body.

use nalgebra::Vector3;
use sartor_core::SkinWeights;
use sartor_runtime::{BINDING_JSON, BINDING_TENSORS, GarmentBinding, OutputKind};

use crate::scene::{binding, body, body_id, garment_id, header};

#[test]
fn round_trip_is_exact_and_deterministic() {
    let b = binding();
    let dir = tempfile::tempdir().expect("tempdir");
    let h1 = b.save(dir.path()).expect("save");
    let back = GarmentBinding::load(dir.path()).expect("load");
    // Everything is stored exactly; `SkinWeights::new` renormalises the weights on load, which
    // may move their last bit.
    assert_eq!(back.template(), b.template());
    assert_eq!(back.faces(), b.faces());
    assert_eq!(back.region_faces(), b.region_faces());
    assert_eq!((back.garment(), back.body()), (b.garment(), b.body()));
    let (o1, j1, w1) = b.skin_weights().csr();
    let (o2, j2, w2) = back.skin_weights().csr();
    assert_eq!((o1, j1), (o2, j2));
    assert!(w1.iter().zip(w2).all(|(a, c)| (a - c).abs() <= 1e-7));
    let h2 = b.save(dir.path()).expect("save again");
    assert_eq!(h1, h2);
    assert_eq!(h1.n_vertices, b.n_vertices());
    assert_eq!(h1.body_joints, 31);
    // The region covers the torso, not the whole body.
    let n = b.region_faces().len();
    assert!(n > 100 && n < body().faces().len() / 2, "{n} region faces");
}

fn error_of(dir: &std::path::Path) -> String {
    GarmentBinding::load(dir)
        .expect_err("must fail")
        .to_string()
}

#[test]
fn file_faults_name_the_file_and_the_fault() {
    let dir = tempfile::tempdir().expect("tempdir");
    let b = binding();
    b.save(dir.path()).expect("save");
    let json_path = dir.path().join(BINDING_JSON);
    let tensors_path = dir.path().join(BINDING_TENSORS);
    let json = std::fs::read_to_string(&json_path).expect("read");

    std::fs::write(&json_path, json.replace("\"version\": 1", "\"version\": 2")).expect("w");
    let e = error_of(dir.path());
    assert!(e.contains(BINDING_JSON) && e.contains("version"), "{e}");

    std::fs::write(
        &json_path,
        json.replace("\"n_faces\"", "\"extra\": 1, \"n_faces\""),
    )
    .expect("w");
    let e = error_of(dir.path());
    assert!(e.contains(BINDING_JSON) && e.contains("extra"), "{e}");

    std::fs::write(&json_path, &json).expect("w");
    let mut bytes = std::fs::read(&tensors_path).expect("read");
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&tensors_path, &bytes).expect("w");
    let e = error_of(dir.path());
    assert!(e.contains(BINDING_TENSORS) && e.contains("SHA-256"), "{e}");

    // A consistent file whose header lies about the vertex count.
    b.save(dir.path()).expect("save");
    let json = std::fs::read_to_string(&json_path).expect("read");
    let wrong = json.replace(
        &format!("\"n_vertices\": {}", b.n_vertices()),
        &format!("\"n_vertices\": {}", b.n_vertices() + 1),
    );
    std::fs::write(&json_path, wrong).expect("w");
    let e = error_of(dir.path());
    assert!(e.contains(BINDING_TENSORS) && e.contains("template"), "{e}");

    std::fs::remove_file(&json_path).expect("rm");
    assert!(error_of(dir.path()).contains(BINDING_JSON));
}

#[test]
fn constructor_checks_every_invariant() {
    let b = binding();
    let parts = || {
        (
            b.template().to_vec(),
            b.faces().to_vec(),
            b.skin_weights().clone(),
            b.region_faces().to_vec(),
        )
    };
    let make = |t, f, w, r, n| GarmentBinding::new(garment_id(), body_id(), t, f, w, r, n);
    let n_body = b.body_faces();
    let (t, f, w, r) = parts();
    assert!(make(t, f, w, r, n_body).is_ok());

    let (mut t, f, w, r) = parts();
    t[3] = Vector3::new(f32::NAN, 0.0, 0.0);
    assert!(
        make(t, f, w, r, n_body)
            .unwrap_err()
            .to_string()
            .contains("vertex 3")
    );
    let (t, mut f, w, r) = parts();
    f[2][1] = t.len() as u32;
    assert!(
        make(t, f, w, r, n_body)
            .unwrap_err()
            .to_string()
            .contains("face 2")
    );
    let (t, mut f, w, r) = parts();
    f[2][1] = f[2][0];
    assert!(
        make(t, f, w, r, n_body)
            .unwrap_err()
            .to_string()
            .contains("repeats")
    );
    let (t, f, _, r) = parts();
    let w = SkinWeights::from_dense_top_k(&vec![1.0; 31 * 3], 31, 4).expect("w");
    assert!(
        make(t, f, w, r, n_body)
            .unwrap_err()
            .to_string()
            .contains("skin-weight rows")
    );
    let (t, f, w, mut r) = parts();
    r.swap(0, 1);
    assert!(
        make(t, f, w, r, n_body)
            .unwrap_err()
            .to_string()
            .contains("ascending")
    );
    let (t, f, w, r) = parts();
    assert!(
        make(t, f, w, r, 10)
            .unwrap_err()
            .to_string()
            .contains("past")
    );
    let (t, f, w, _) = parts();
    assert!(make(t, f, w, Vec::new(), n_body).is_err());
    let (t, f, w, r) = parts();
    let mut bad_id = garment_id();
    bad_id.sha256 = "xyz".into();
    assert!(GarmentBinding::new(bad_id, body_id(), t, f, w, r, n_body).is_err());
}

#[test]
fn checks_against_model_and_body() {
    let b = binding();
    let h = header(OutputKind::Dense, 8);
    h.check_binding(&b).expect("matches");
    b.check_body(&body()).expect("matches");
    let mut other = h.clone();
    other.garment.sha256 = "e".repeat(64);
    assert!(
        other
            .check_binding(&b)
            .unwrap_err()
            .to_string()
            .contains("garment")
    );
    let mut other = h.clone();
    other.body.id = "smpl".into();
    assert!(
        other
            .check_binding(&b)
            .unwrap_err()
            .to_string()
            .contains("body")
    );
    let mut other = h;
    other.sizes.n_vertices += 1;
    assert!(
        other
            .check_binding(&b)
            .unwrap_err()
            .to_string()
            .contains("vertices")
    );
}
