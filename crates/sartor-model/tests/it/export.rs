//! Export → the runtime: identical tensors, and the runtime's kernels reproduce burn's outputs.

use sartor_dataset::{Split, TrainingData};
use sartor_model::burn::tensor::Device;
use sartor_model::{AnyModel, ModelKind, Predictor, export_model, load_trained};
use sartor_runtime::{
    GarmentModel, GarmentNetwork, NetworkOptions, OutputKind, Parallelism, Precision,
};

use crate::learn::{config, train};
use crate::synthetic::dataset;

struct Trained {
    data: TrainingData,
    fit: sartor_model::FitRegressor,
    wrinkle: sartor_model::WrinkleRegressor,
    linear: sartor_model::LinearRegressor,
    _dir: tempfile::TempDir,
}

fn trained(pca: Option<usize>) -> Trained {
    let data = dataset(0.8, true, pca.map(|k| k + 2));
    let dir = tempfile::tempdir().expect("tempdir");
    let c = config(20, 4, 3).with_pca_components(pca);
    let device = Device::flex();
    let load = |kind: ModelKind| {
        let d = dir.path().join(kind.name());
        train(kind, &data, &c, &d, false, false).expect("training");
        load_trained(kind, &d, &device).expect("load")
    };
    let (AnyModel::Fit(fit), AnyModel::Wrinkle(wrinkle), AnyModel::Linear(linear)) = (
        load(ModelKind::Fit),
        load(ModelKind::Wrinkle),
        load(ModelKind::Linear),
    ) else {
        panic!("load_trained returned another kind")
    };
    Trained {
        data,
        fit,
        wrinkle,
        linear,
        _dir: dir,
    }
}

use crate::reference::max_abs_diff;

/// Runtime outputs for one held-out sequence: `(Δ_G, Δ_L per frame, LR per frame)`.
fn runtime_outputs(
    model: &GarmentModel,
    data: &TrainingData,
    seq: usize,
    precision: Precision,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let net = GarmentNetwork::with_options(
        model.clone(),
        NetworkOptions {
            precision,
            ..NetworkOptions::default()
        },
    )
    .expect("network");
    let q = &data.sequences()[seq];
    let betas = &data.shapes()[q.shape].betas;
    let n3 = data.n_outputs();
    let n_in = data.n_inputs();
    let mut ws = net.workspace(1);
    let par = Parallelism::Sequential;
    let mut fit = vec![0.0; n3];
    net.fit(betas, &mut fit, &mut ws, par).expect("fit");
    let mut state = net.initial_state();
    let (mut wrinkle, mut lr) = (Vec::new(), Vec::new());
    let mut out = vec![0.0; n3];
    for t in 0..q.n_frames {
        let x = &q.inputs[t * n_in..(t + 1) * n_in];
        net.wrinkle_step(x, &mut state, &mut out, &mut ws, par)
            .expect("step");
        wrinkle.extend_from_slice(&out);
        net.linear_baseline(x, &mut out, &mut ws, par).expect("lr");
        lr.extend_from_slice(&out);
    }
    (fit, wrinkle, lr)
}

fn check_runtime_matches_burn(pca: Option<usize>) {
    let t = trained(pca);
    let model = export_model(&t.data, &t.fit, &t.wrinkle, Some(&t.linear)).expect("export");
    let expected_output = pca.map_or(OutputKind::Dense, OutputKind::Pca);
    assert_eq!(model.header().sizes.output, expected_output);
    let predictor = Predictor::new(&t.data, Device::flex());
    let seq = t.data.sequence_indices(Split::HeldOutMotions)[0];
    let q = &t.data.sequences()[seq];
    let fit = predictor.fit(&t.fit, &t.data.shapes()[q.shape].betas);
    let wrinkle = predictor.wrinkle(&t.wrinkle, &q.inputs);
    let lr = predictor.linear(&t.linear, &q.inputs);
    // The outputs are not trivially small: a tolerance of 1e-4 m means something.
    assert!(wrinkle.iter().any(|v| v.abs() > 1e-3));
    for (precision, tolerance_m) in [
        (Precision::F32, 1e-4),
        (Precision::F16, 1e-4),
        (Precision::Int8, 1e-3),
    ] {
        let (rf, rw, rl) = runtime_outputs(&model, &t.data, seq, precision);
        for (what, a, b) in [
            ("fit", &rf, &fit),
            ("wrinkle", &rw, &wrinkle),
            ("lr", &rl, &lr),
        ] {
            let d = max_abs_diff(a, b);
            assert!(
                d <= tolerance_m,
                "{what} {precision:?}: runtime differs from burn by {d} m (tolerance {tolerance_m})"
            );
        }
    }
}

#[test]
fn runtime_matches_burn_dense() {
    check_runtime_matches_burn(None);
}

#[test]
fn runtime_matches_burn_pca() {
    check_runtime_matches_burn(Some(6));
}

#[test]
fn exported_tensors_read_back_identically_and_open_as_plain_safetensors() {
    let t = trained(None);
    let model = export_model(&t.data, &t.fit, &t.wrinkle, Some(&t.linear)).expect("export");
    let dir = tempfile::tempdir().expect("tempdir");
    model.save(dir.path()).expect("save");
    let loaded = GarmentModel::load(dir.path()).expect("load");
    assert_eq!(loaded.header().sizes, model.header().sizes);
    assert_eq!(loaded.weights(), model.weights());
    // Every tensor is a plain little-endian f32 safetensors entry (what PyTorch's loader reads),
    // named and shaped as the format documents.
    let bytes = std::fs::read(dir.path().join(sartor_runtime::MODEL_TENSORS)).expect("read");
    let st = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    let shapes = model.header().sizes.tensor_shapes();
    assert_eq!(st.len(), shapes.len());
    for (name, shape) in shapes {
        let view = st.tensor(name).expect("tensor present");
        assert_eq!(view.dtype(), safetensors::Dtype::F32, "{name}");
        assert_eq!(view.shape(), shape.as_slice(), "{name}");
        let values: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(
            Some(values.as_slice()),
            model.weights().tensor(name),
            "{name}"
        );
    }
    // The GRU is stored in PyTorch's layout: weight_ih [3H, I] with gate rows r, z, n.
    let h = model.header().sizes.gru_hidden;
    let i = t.data.n_inputs();
    assert_eq!(model.weights().gru.weight_ih.len(), 3 * h * i);
}

/// A 100,000-frame rollout of the exported GRU on a looping clip stays finite and within the
/// bound its weights allow (`|h| ≤ 1`, so `|out| ≤ Σ|W| + |b|`, denormalised).
#[test]
fn a_100k_frame_rollout_stays_finite_and_bounded() {
    let t = trained(None);
    let model = export_model(&t.data, &t.fit, &t.wrinkle, None).expect("export");
    let net = GarmentNetwork::new(model.clone(), Precision::F32).expect("network");
    let w = model.weights();
    let h = model.header().sizes.gru_hidden;
    let norm = &w.norm.wrinkle_out;
    let bound: Vec<f32> = (0..t.data.n_outputs())
        .map(|o| {
            let row = &w.wrinkle_out.weight[o * h..(o + 1) * h];
            let s: f32 = row.iter().map(|v| v.abs()).sum::<f32>() + w.wrinkle_out.bias[o].abs();
            s * norm.std[o] + norm.mean[o].abs()
        })
        .collect();
    let q = &t.data.sequences()[0];
    let n_in = t.data.n_inputs();
    let mut ws = net.workspace(1);
    let mut state = net.initial_state();
    let mut out = vec![0.0; t.data.n_outputs()];
    for frame in 0..100_000 {
        let f = frame % q.n_frames;
        net.wrinkle_step(
            &q.inputs[f * n_in..(f + 1) * n_in],
            &mut state,
            &mut out,
            &mut ws,
            Parallelism::Sequential,
        )
        .expect("step");
        if frame % 997 == 0 || frame == 99_999 {
            for (o, (v, b)) in out.iter().zip(&bound).enumerate() {
                assert!(
                    v.is_finite() && v.abs() <= b * 1.0001,
                    "frame {frame}, output {o}: {v}"
                );
            }
            assert!(
                state.iter().all(|s| s.abs() <= 1.0),
                "frame {frame}: state left [-1, 1]"
            );
        }
    }
}
