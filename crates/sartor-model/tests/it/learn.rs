//! The training loop learns, checkpoints, resumes and refuses what it must.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use sartor_model::burn::tensor::{Device, Tensor, TensorData};
use sartor_model::{
    FitRegressorConfig, ModelKind, ModelReport, Silent, StageConfig, TrainOptions, TrainingConfig,
    WrinkleRegressorConfig, load_weights, save_weights, seeded, to_vec, train_model,
};

use sartor_dataset::Split;

use crate::synthetic::{dataset, dataset_with_validation};

pub fn config(fit: usize, wrinkle: usize, linear: usize) -> TrainingConfig {
    TrainingConfig::new(
        StageConfig::new(fit, 5).with_learning_rate(1e-2),
        StageConfig::new(wrinkle, 4).with_learning_rate(5e-3),
        StageConfig::new(linear, 32).with_learning_rate(1e-2),
    )
    .with_fit_hidden(16)
    .with_gru_hidden(32)
    .with_dropout(0.0)
    .with_window_frames(8)
    .with_seed(11)
}

pub fn train(
    kind: ModelKind,
    data: &sartor_dataset::TrainingData,
    config: &TrainingConfig,
    dir: &Path,
    resume: bool,
    stop: bool,
) -> sartor_model::Result<ModelReport> {
    let stop = AtomicBool::new(stop);
    let options = TrainOptions {
        dir: dir.to_path_buf(),
        device: Device::flex().autodiff(),
        resume,
        stop: &stop,
        contact: None,
    };
    train_model(kind, data, config, &options, &mut Silent)
}

/// Train `kind` from scratch in a temporary folder.
fn learn(
    kind: ModelKind,
    data: &sartor_dataset::TrainingData,
    config: &TrainingConfig,
) -> ModelReport {
    let dir = tempfile::tempdir().expect("tempdir");
    train(kind, data, config, dir.path(), false, false).expect("training")
}

fn assert_learned(report: &ModelReport, ratio: f64) {
    let first = report.curve.first().expect("an epoch").train_loss;
    let last = report.curve.last().expect("an epoch").train_loss;
    eprintln!(
        "{}: loss {first} → {last}, val {:?} mm",
        report.model, report.best_val_error_mm
    );
    assert!(
        last < ratio * first,
        "{}: loss {first} → {last}, expected below {ratio} × the first",
        report.model
    );
    assert!(report.best_val_error_mm.is_some_and(f64::is_finite));
}

#[test]
fn fit_mlp_learns_the_shape_displacements() {
    let data = dataset(0.0, false, None);
    let report = learn(ModelKind::Fit, &data, &config(400, 0, 0));
    assert_eq!(report.epochs, 400);
    assert_learned(&report, 0.01);
}

#[test]
fn models_pick_their_epochs_on_the_validation_split_when_there_is_one() {
    // Without validation sequences or shapes (the first configs), the held-out ones validate;
    // with them, they do, and the validation error is measured on other frames.
    let plain = dataset(0.0, false, None);
    let with = dataset_with_validation(0.0, false, None);
    for (kind, cfg, held_out) in [
        (ModelKind::Fit, config(3, 0, 0), Split::HeldOutShapes),
        (ModelKind::Wrinkle, config(0, 2, 0), Split::HeldOutMotions),
        (ModelKind::Linear, config(0, 0, 1), Split::HeldOutMotions),
    ] {
        let a = learn(kind, &plain, &cfg);
        let b = learn(kind, &with, &cfg);
        assert_eq!((a.validation, b.validation), (held_out, Split::Validation));
        assert_ne!(a.best_val_error_mm, b.best_val_error_mm, "{kind:?}");
    }
}

#[test]
fn linear_baseline_is_the_least_squares_fit_in_one_solve() {
    // A target exactly linear in the current frame's inputs: the closed form finds it (the
    // weight decay picked on validation is the smallest, so the error is nearly zero).
    let data = dataset(0.0, false, None);
    let report = learn(ModelKind::Linear, &data, &config(0, 0, 150));
    assert_eq!(
        report.epochs, 1,
        "one solve, whatever the configured epochs"
    );
    let exact = report.best_val_error_mm.expect("a validation error");
    assert!(exact < 1e-3, "{exact} mm on an exactly linear target");
    // With memory the target is not linear in the current inputs: the best linear map leaves
    // an error, finite and far above the exact fit's.
    let data = dataset(0.8, true, None);
    let report = learn(ModelKind::Linear, &data, &config(0, 0, 150));
    let with_memory = report.best_val_error_mm.expect("a validation error");
    eprintln!("linear baseline: {exact} mm exact, {with_memory} mm with memory");
    assert!(
        with_memory.is_finite() && with_memory > 100.0 * exact,
        "{with_memory} mm"
    );
}

#[test]
fn wrinkle_gru_learns_a_target_with_memory() {
    let data = dataset(0.8, true, None);
    let report = learn(ModelKind::Wrinkle, &data, &config(0, 120, 0));
    assert_learned(&report, 0.03);
}

#[test]
fn wrinkle_gru_learns_through_a_pca_output() {
    let data = dataset(0.8, true, Some(12));
    let report = learn(
        ModelKind::Wrinkle,
        &data,
        &config(0, 120, 0).with_pca_components(Some(12)),
    );
    assert_learned(&report, 0.05);
}

#[test]
fn a_resumed_run_takes_the_same_steps_as_an_uninterrupted_one() {
    let data = dataset(0.8, true, None);
    let c = config(0, 3, 0);
    let whole = tempfile::tempdir().expect("tempdir");
    let full = train(ModelKind::Wrinkle, &data, &c, whole.path(), false, false).expect("training");
    let split = tempfile::tempdir().expect("tempdir");
    // Stop after the first batch, then resume twice more (the second resume finds it done).
    let first = train(ModelKind::Wrinkle, &data, &c, split.path(), false, true).expect("part");
    assert!(first.interrupted);
    assert_eq!(first.epochs, 0);
    let rest = train(ModelKind::Wrinkle, &data, &c, split.path(), true, false).expect("rest");
    assert!(!rest.interrupted);
    assert_eq!(rest.epochs, 3);
    let again = train(ModelKind::Wrinkle, &data, &c, split.path(), true, false).expect("done");
    assert_eq!(again.curve, rest.curve);
    for (a, b) in full.curve.iter().zip(&rest.curve) {
        assert!(
            (a.train_loss - b.train_loss).abs() <= 1e-6 * a.train_loss,
            "{a:?} vs {b:?}"
        );
    }
    assert_eq!(full.best_epoch, rest.best_epoch);
}

#[test]
fn an_existing_run_is_not_overwritten_and_other_settings_are_refused() {
    let data = dataset(0.0, false, None);
    let dir = tempfile::tempdir().expect("tempdir");
    let fresh = || {
        train(
            ModelKind::Fit,
            &data,
            &config(2, 0, 0),
            dir.path(),
            false,
            false,
        )
    };
    fresh().expect("training");
    let again = fresh();
    assert!(
        again.is_err(),
        "a second run without resume must not overwrite the first"
    );
    let other = config(2, 0, 0).with_fit_hidden(7);
    let err = train(ModelKind::Fit, &data, &other, dir.path(), true, false)
        .expect_err("other settings must be refused");
    assert!(err.to_string().contains("state.json"), "{err}");
}

#[test]
fn saved_weights_load_back_to_identical_outputs() {
    let device = Device::flex();
    let config = WrinkleRegressorConfig::new(9, 15)
        .with_hidden(12)
        .with_dropout(0.0);
    let model = seeded(&device, Some(1), || config.init(&device));
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("w.bpk");
    save_weights(&model, &path).expect("save");
    let other = seeded(&device, Some(2), || config.init(&device));
    let loaded = load_weights(other, &path).expect("load");
    let x: Tensor<3> = Tensor::from_data(
        TensorData::new(
            (0..2 * 5 * 9).map(|i| (i as f32 * 0.1).sin()).collect(),
            [2, 5, 9],
        ),
        &device,
    );
    let s = model.initial_state(2, &device);
    let (a, _) = model.forward(x.clone(), s.clone());
    let (b, _) = loaded.forward(x, s);
    assert_eq!(to_vec(a), to_vec(b));
    // A file for another architecture is an error naming it, not a panic.
    let fit = seeded(&device, None, || {
        FitRegressorConfig::new(2, 15).init(&device)
    });
    let err = load_weights(fit, &path).expect_err("mismatched weights");
    assert!(err.to_string().contains("w.bpk"), "{err}");
    std::fs::write(&path, b"not a burnpack").expect("write");
    let err =
        load_weights(seeded(&device, None, || config.init(&device)), &path).expect_err("garbage");
    assert!(err.to_string().contains("w.bpk"), "{err}");
}
