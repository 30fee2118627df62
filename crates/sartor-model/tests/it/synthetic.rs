//! A tiny synthetic dataset with known structure: `Δ_G` a smooth function of β, `Δ_L` a
//! function of the current frame's inputs plus (optionally) the previous frame's.

use sartor_core::{PoseFeatureSpec, RootFeature, RotationEncoding};
use sartor_dataset::{
    DataSource, InputLayout, PcaSettings, SequenceSample, ShapeSample, Split, TrainingData,
    compute_pca, compute_stats,
};

pub const N_VERTICES: usize = 5;
pub const N_BETAS: usize = 2;
pub const FRAMES: usize = 24;

fn weight(i: usize, j: usize) -> f32 {
    (((i * 31 + j * 17) % 23) as f32 / 11.0 - 1.0) * 0.6
}

/// `memory`: weight of the previous frame's inputs in `Δ_L` (0: a memoryless target, which a
/// linear layer can fit exactly when `nonlinear` is false too).
pub fn dataset(memory: f32, nonlinear: bool, pca: Option<usize>) -> TrainingData {
    build(memory, nonlinear, pca, false)
}

/// [`dataset`] with a validation split: the third motion of every training shape, and one
/// validation shape (no sequence).
pub fn dataset_with_validation(memory: f32, nonlinear: bool, pca: Option<usize>) -> TrainingData {
    build(memory, nonlinear, pca, true)
}

/// The inputs' layout: `N_BETAS` betas, one joint, one root feature.
fn layout() -> InputLayout {
    InputLayout {
        n_betas: N_BETAS,
        pose: PoseFeatureSpec {
            joints: vec!["Spine".into()],
            encoding: RotationEncoding::Rot6d,
            root: vec![RootFeature::VelX],
        },
    }
}

/// Motion `m`'s inputs over `FRAMES` frames at shape `betas`: the betas, then sinusoids of the
/// frame of a frequency and phase per input and motion.
pub fn inputs(betas: &[f32], m: usize) -> Vec<f32> {
    let n_in = layout().width();
    let mut inputs = Vec::with_capacity(FRAMES * n_in);
    for t in 0..FRAMES {
        inputs.extend_from_slice(betas);
        for k in 0..n_in - N_BETAS {
            let w = 0.3 + 0.11 * (k + m) as f32;
            inputs.push((w * t as f32 + 0.7 * k as f32 + m as f32).sin());
        }
    }
    inputs
}

fn build(memory: f32, nonlinear: bool, pca: Option<usize>, validation: bool) -> TrainingData {
    let n_in = layout().width();
    let n3 = 3 * N_VERTICES;
    let train_betas = [[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]];
    let mut shapes: Vec<ShapeSample> = train_betas
        .iter()
        .enumerate()
        .map(|(i, b)| (format!("s{i}"), b, Split::Train))
        .chain(std::iter::once((
            "h0".to_string(),
            &[0.5, 0.5],
            Split::HeldOutShapes,
        )))
        .chain(validation.then(|| ("v0".to_string(), &[-0.5, 0.5], Split::Validation)))
        .map(|(id, b, split)| ShapeSample {
            id,
            betas: b.to_vec(),
            fit_delta: (0..n3)
                .map(|k| 0.01 * (b[0] * weight(k, 0) + b[1] * b[1] * weight(k, 1)))
                .collect(),
            split,
        })
        .collect();
    let mut sequences = Vec::new();
    for (s, shape) in shapes.iter_mut().enumerate() {
        if shape.split == Split::Validation {
            continue;
        }
        for m in 0..4 {
            let split = match (shape.split, m) {
                (Split::HeldOutShapes, _) => Split::HeldOutShapes,
                (_, 3) => Split::HeldOutMotions,
                (_, 2) if validation => Split::Validation,
                _ => Split::Train,
            };
            let inputs = inputs(&shape.betas, m);
            let mut delta = Vec::with_capacity(FRAMES * n3);
            for t in 0..FRAMES {
                for o in 0..n3 {
                    let lin = |tt: usize| -> f32 {
                        (0..n_in)
                            .map(|i| inputs[tt * n_in + i] * weight(o, i + 2))
                            .sum()
                    };
                    let mut v = lin(t) + if t > 0 { memory * lin(t - 1) } else { 0.0 };
                    if nonlinear {
                        v = v.tanh();
                    }
                    delta.push(0.005 * v);
                }
            }
            sequences.push(SequenceSample {
                id: format!("{}__m{m}", shape.id),
                shape: s,
                motion: format!("m{m}"),
                split,
                n_frames: FRAMES,
                inputs,
                wrinkle_delta: delta,
            });
        }
    }
    training_data(N_VERTICES, shapes, sequences, pca)
}

/// The training data of `shapes` and `sequences` (of [`layout`]'s inputs) of a garment of
/// `n_vertices`: statistics and `pca` components from their training split.
pub fn training_data(
    n_vertices: usize,
    shapes: Vec<ShapeSample>,
    sequences: Vec<SequenceSample>,
    pca: Option<usize>,
) -> TrainingData {
    let layout = layout();
    let (n_in, n3) = (layout.width(), 3 * n_vertices);
    let train_shapes: Vec<&ShapeSample> =
        shapes.iter().filter(|s| s.split == Split::Train).collect();
    let train_seqs: Vec<&SequenceSample> = sequences
        .iter()
        .filter(|q| q.split == Split::Train)
        .collect();
    let stats = compute_stats(&train_shapes, &train_seqs, N_BETAS, n_in, n3).expect("stats");
    let basis = pca.map(|k| {
        compute_pca(
            &train_seqs,
            &stats,
            &PcaSettings {
                components: k,
                max_frames: 10_000,
                seed: 1,
            },
        )
        .expect("pca")
    });
    TrainingData::new(
        DataSource {
            garment: sartor_runtime::AssetId {
                id: "synthetic".into(),
                sha256: "a".repeat(64),
            },
            body: sartor_runtime::AssetId {
                id: "makehuman".into(),
                sha256: "b".repeat(64),
            },
        },
        n_vertices,
        layout,
        shapes,
        sequences,
        stats,
        basis,
    )
    .expect("a valid synthetic dataset")
}
