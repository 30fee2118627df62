//! `model.safetensors` + `model.json`: round trip and every file fault.

use std::collections::BTreeMap;
use std::path::Path;

use sartor_core::io::{OwnedTensor, serialize_tensors, sha256_hex};
use sartor_runtime::{
    GarmentModel, GarmentNetwork, MODEL_JSON, MODEL_TENSORS, ModelHeader, OutputKind, Parallelism,
    Precision, TensorStorage,
};

use crate::common::{random_model, sizes};

fn tensors_of(model: &GarmentModel) -> BTreeMap<String, (Vec<usize>, Vec<f32>)> {
    model
        .header()
        .sizes
        .tensor_shapes()
        .into_iter()
        .map(|(name, shape)| {
            let values = model.weights().tensor(name).expect("present").to_vec();
            (name.to_string(), (shape, values))
        })
        .collect()
}

/// Write the given tensors and a header whose hash matches them.
fn write_raw(
    dir: &Path,
    header: &ModelHeader,
    tensors: &BTreeMap<String, (Vec<usize>, Vec<f32>)>,
) -> ModelHeader {
    let map: BTreeMap<String, OwnedTensor> = tensors
        .iter()
        .map(|(n, (s, v))| (n.clone(), OwnedTensor::f32(s, v.iter().copied())))
        .collect();
    let bytes = serialize_tensors(&map, None).expect("serialise");
    let mut header = header.clone();
    header.tensors_sha256 = sha256_hex(&bytes);
    std::fs::write(dir.join(MODEL_TENSORS), &bytes).expect("write");
    std::fs::write(
        dir.join(MODEL_JSON),
        serde_json::to_string_pretty(&header).expect("json"),
    )
    .expect("write");
    header
}

/// Load must fail with a message naming `file` and containing `needle`.
fn assert_fault(dir: &Path, file: &str, needle: &str) {
    let err = GarmentModel::load(dir).expect_err("a faulty model must not load");
    let msg = err.to_string();
    assert!(
        msg.contains(&dir.join(file).display().to_string()),
        "error does not name {file}: {msg}"
    );
    assert!(msg.contains(needle), "error lacks {needle:?}: {msg}");
}

#[test]
fn write_read_round_trip_is_identical() {
    for (output, lr) in [(OutputKind::Dense, false), (OutputKind::Pca(5), true)] {
        let model = random_model(1, sizes(output, lr));
        let dir = tempfile::tempdir().expect("tempdir");
        let written = model.save(dir.path()).expect("save");
        let loaded = GarmentModel::load(dir.path()).expect("load");
        assert_eq!(loaded.header(), &written);
        assert_eq!(loaded.weights(), model.weights());
        let (a, b) = (tensors_of(&loaded), tensors_of(&model));
        for (name, (shape, values)) in &a {
            assert_eq!(shape, &b[name].0, "{name}");
            let (x, y): (Vec<u32>, Vec<u32>) = (
                values.iter().map(|v| v.to_bits()).collect(),
                b[name].1.iter().map(|v| v.to_bits()).collect(),
            );
            assert_eq!(x, y, "{name}");
        }
        // Deterministic bytes: saving again gives the same hash.
        let again = tempfile::tempdir().expect("tempdir");
        assert_eq!(
            model.save(again.path()).expect("save").tensors_sha256,
            written.tensors_sha256
        );
        // The JSON names exactly the documented fields.
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(MODEL_JSON)).expect("read"),
        )
        .expect("json");
        let keys: Vec<&str> = json
            .as_object()
            .expect("object")
            .keys()
            .map(|k| k.as_str())
            .collect();
        assert_eq!(
            keys,
            [
                "body",
                "format",
                "garment",
                "sizes",
                "tensors_sha256",
                "version",
                "wrinkle_inputs"
            ]
        );
        assert_eq!(json["format"], "sartor-garment-model");
        let expected_output = match output {
            OutputKind::Dense => serde_json::json!("dense"),
            OutputKind::Pca(k) => serde_json::json!({ "pca": k }),
        };
        assert_eq!(json["sizes"]["output"], expected_output);
        GarmentNetwork::load(dir.path(), Precision::Int8).expect("loads as a network");
    }
}

#[test]
fn f16_storage_halves_the_matrices_and_loads_as_the_f32_file_at_f16() {
    let model = random_model(3, sizes(OutputKind::Pca(5), true));
    let (f32_dir, f16_dir) = (
        tempfile::tempdir().expect("tempdir"),
        tempfile::tempdir().expect("tempdir"),
    );
    model.save(f32_dir.path()).expect("save");
    let header = model
        .save_as(f16_dir.path(), TensorStorage::F16)
        .expect("save f16");
    let size = |d: &Path| {
        std::fs::metadata(d.join(MODEL_TENSORS))
            .expect("file")
            .len()
    };
    let (full, half) = (size(f32_dir.path()), size(f16_dir.path()));
    assert!(half < full * 6 / 10, "{half} bytes in f16, {full} in f32");
    // From bytes as from the folder.
    let from_bytes = GarmentModel::from_bytes(
        f16_dir.path(),
        &std::fs::read(f16_dir.path().join(MODEL_JSON)).expect("json"),
        std::fs::read(f16_dir.path().join(MODEL_TENSORS)).expect("tensors"),
    )
    .expect("from bytes");
    let loaded = GarmentModel::load(f16_dir.path()).expect("load f16");
    assert_eq!(loaded, from_bytes);
    assert_eq!(loaded.header(), &header);
    // Matrices hold the f16-rounded values, vectors the f32 ones, bit for bit.
    let (a, b) = (tensors_of(&loaded), tensors_of(&model));
    for (name, (shape, values)) in &a {
        let expected: Vec<u32> = b[name]
            .1
            .iter()
            .map(|&v| match shape.len() {
                2 => half::f16::from_f32(v).to_f32().to_bits(),
                _ => v.to_bits(),
            })
            .collect();
        let got: Vec<u32> = values.iter().map(|v| v.to_bits()).collect();
        assert_eq!(got, expected, "{name}");
    }
    // At f16 precision the network is the f32 file's, bit for bit.
    let betas = [0.3f32, -1.0, 0.5, 0.0];
    let fit = |dir: &Path| {
        let net = GarmentNetwork::load(dir, Precision::F16).expect("network");
        let mut ws = net.workspace(1);
        let mut out = vec![0.0; net.output_size()];
        net.fit(
            &betas[..net.n_betas()],
            &mut out,
            &mut ws,
            Parallelism::Sequential,
        )
        .expect("fit");
        crate::common::bits(&out)
    };
    assert_eq!(fit(f32_dir.path()), fit(f16_dir.path()));
}

#[test]
fn f16_storage_refuses_weights_beyond_its_range() {
    let model = random_model(4, sizes(OutputKind::Dense, false));
    let (header, mut weights) = model.into_parts();
    weights.fit_out.weight[7] = 1e6;
    let model = GarmentModel::new(header, weights).expect("valid in f32");
    let err = model
        .tensor_bytes_as(TensorStorage::F16)
        .expect_err("too large for f16");
    assert!(err.to_string().contains("fit.out.weight"), "{err}");
}

#[test]
fn missing_tensor_is_an_error_naming_the_file() {
    let model = random_model(2, sizes(OutputKind::Dense, false));
    let dir = tempfile::tempdir().expect("tempdir");
    let mut t = tensors_of(&model);
    t.remove("wrinkle.gru.bias_hh");
    write_raw(dir.path(), model.header(), &t);
    assert_fault(dir.path(), MODEL_TENSORS, "wrinkle.gru.bias_hh");
}

#[test]
fn unexpected_tensor_is_an_error() {
    let model = random_model(3, sizes(OutputKind::Dense, false));
    let dir = tempfile::tempdir().expect("tempdir");
    let mut t = tensors_of(&model);
    t.insert("lr.weight".into(), (vec![1, 1], vec![0.0]));
    write_raw(dir.path(), model.header(), &t);
    assert_fault(dir.path(), MODEL_TENSORS, "unexpected tensor \"lr.weight\"");
}

#[test]
fn wrong_shape_is_an_error_naming_the_file() {
    let model = random_model(4, sizes(OutputKind::Pca(5), false));
    let dir = tempfile::tempdir().expect("tempdir");
    let mut t = tensors_of(&model);
    let basis = t.get_mut("wrinkle.pca.basis").expect("present");
    basis.0 = vec![basis.0[1], basis.0[0]]; // transposed
    write_raw(dir.path(), model.header(), &t);
    assert_fault(dir.path(), MODEL_TENSORS, "wrinkle.pca.basis");
}

#[test]
fn nan_weight_is_an_error_naming_the_file() {
    let model = random_model(5, sizes(OutputKind::Dense, false));
    let dir = tempfile::tempdir().expect("tempdir");
    let mut t = tensors_of(&model);
    t.get_mut("wrinkle.gru.weight_hh").expect("present").1[17] = f32::NAN;
    write_raw(dir.path(), model.header(), &t);
    assert_fault(dir.path(), MODEL_TENSORS, "non-finite");
}

#[test]
fn non_positive_std_is_an_error_naming_the_file() {
    let model = random_model(6, sizes(OutputKind::Dense, false));
    let dir = tempfile::tempdir().expect("tempdir");
    let mut t = tensors_of(&model);
    t.get_mut("norm.wrinkle_in_std").expect("present").1[2] = 0.0;
    write_raw(dir.path(), model.header(), &t);
    assert_fault(dir.path(), MODEL_TENSORS, "norm.wrinkle_in_std");
}

#[test]
fn hash_mismatch_is_an_error_naming_the_file() {
    let model = random_model(7, sizes(OutputKind::Dense, false));
    let dir = tempfile::tempdir().expect("tempdir");
    model.save(dir.path()).expect("save");
    let path = dir.path().join(MODEL_TENSORS);
    let mut bytes = std::fs::read(&path).expect("read");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x01; // still a valid f32, different content
    std::fs::write(&path, bytes).expect("write");
    assert_fault(dir.path(), MODEL_TENSORS, "SHA-256");
}

#[test]
fn truncated_file_is_an_error_naming_the_file() {
    let model = random_model(8, sizes(OutputKind::Dense, false));
    let dir = tempfile::tempdir().expect("tempdir");
    model.save(dir.path()).expect("save");
    let path = dir.path().join(MODEL_TENSORS);
    let bytes = std::fs::read(&path).expect("read");
    std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("write");
    assert_fault(dir.path(), MODEL_TENSORS, "safetensors");
    std::fs::remove_file(&path).expect("remove");
    assert_fault(dir.path(), MODEL_TENSORS, "");
}

fn edit_json(dir: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = dir.join(MODEL_JSON);
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
    edit(&mut json);
    std::fs::write(&path, serde_json::to_string(&json).expect("json")).expect("write");
}

#[test]
fn json_faults_are_errors_naming_the_sidecar() {
    let model = random_model(9, sizes(OutputKind::Dense, false));
    type Edit = fn(&mut serde_json::Value);
    let cases: &[(Edit, &str)] = &[
        (|j| j["extra"] = 1.into(), "unknown field `extra`"),
        (
            |j| j["sizes"]["n_layers"] = 2.into(),
            "unknown field `n_layers`",
        ),
        (
            |j| j["wrinkle_inputs"][1]["feature"]["joint_rotations"]["scale"] = 1.into(),
            "unknown field `scale`",
        ),
        (
            |j| j["sizes"]["output"] = "sparse".into(),
            "unknown variant `sparse`",
        ),
        (|j| j["format"] = "other".into(), "format"),
        (|j| j["version"] = 2.into(), "version"),
        (|j| j["body"]["sha256"] = "xyz".into(), "body.sha256"),
        (|j| j["tensors_sha256"] = "00".into(), "tensors_sha256"),
        (
            |j| j["wrinkle_inputs"][2]["offset"] = 12.into(),
            "offset 12",
        ),
        (|j| j["wrinkle_inputs"][1]["len"] = 8.into(), "len 8"),
        (
            |j| j["sizes"]["n_pose_features"] = 11.into(),
            "n_pose_features",
        ),
        (
            |j| j["sizes"]["output"] = serde_json::json!({"pca": 0}),
            "pca k = 0",
        ),
        (
            |j| {
                j["wrinkle_inputs"][0]["feature"] =
                    serde_json::json!({"root": {"components": ["a", "b", "c", "d"]}})
            },
            "\"betas\" blocks",
        ),
    ];
    for (edit, needle) in cases {
        let dir = tempfile::tempdir().expect("tempdir");
        model.save(dir.path()).expect("save");
        edit_json(dir.path(), *edit);
        assert_fault(dir.path(), MODEL_JSON, needle);
    }
    let dir = tempfile::tempdir().expect("tempdir");
    model.save(dir.path()).expect("save");
    std::fs::write(dir.path().join(MODEL_JSON), "{ not json").expect("write");
    assert_fault(dir.path(), MODEL_JSON, "line 1");
}

#[test]
fn in_memory_models_are_validated() {
    let model = random_model(10, sizes(OutputKind::Dense, true));
    let (header, weights) = model.clone().into_parts();
    let mut w = weights.clone();
    w.fit_out.bias.pop();
    assert!(GarmentModel::new(header.clone(), w).is_err());
    let mut w = weights.clone();
    w.lr = None;
    assert!(GarmentModel::new(header.clone(), w).is_err());
    let mut w = weights.clone();
    w.norm.fit_out.std[0] = -1.0;
    assert!(GarmentModel::new(header.clone(), w).is_err());
    let mut w = weights;
    w.gru.bias_ih[0] = f32::INFINITY;
    assert!(GarmentModel::new(header, w).is_err());
}
