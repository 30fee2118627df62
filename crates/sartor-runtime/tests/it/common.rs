//! Random models and an f64 reference implementation of the whole network.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sartor_runtime::{
    AssetId, DenseWeights, Feature, FeatureBlock, GarmentModel, GruWeights, MeanStd, ModelHeader,
    ModelSizes, ModelWeights, NormStats, OutputKind, PcaWeights, RotationEncoding,
};

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub fn random(rng: &mut ChaCha8Rng, n: usize, amp: f32) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-amp..amp)).collect()
}

/// Small odd sizes: 37 vertices, 4 betas, 3 axis-angle joints + 1 root component.
pub fn sizes(output: OutputKind, linear_baseline: bool) -> ModelSizes {
    ModelSizes {
        n_vertices: 37,
        n_betas: 4,
        n_pose_features: 10,
        fit_hidden: 7,
        gru_hidden: 29,
        output,
        linear_baseline,
    }
}

pub fn header(sizes: ModelSizes) -> ModelHeader {
    let hash = |c: char| std::iter::repeat_n(c, 64).collect::<String>();
    ModelHeader::new(
        AssetId {
            id: "tshirt".into(),
            sha256: hash('a'),
        },
        AssetId {
            id: "makehuman".into(),
            sha256: hash('b'),
        },
        sizes,
        vec![
            FeatureBlock {
                name: "betas".into(),
                offset: 0,
                len: 4,
                feature: Feature::Betas,
            },
            FeatureBlock {
                name: "pose".into(),
                offset: 4,
                len: 9,
                feature: Feature::JointRotations {
                    encoding: RotationEncoding::AxisAngle,
                    joints: vec!["spine".into(), "l_arm".into(), "r_arm".into()],
                },
            },
            FeatureBlock {
                name: "root".into(),
                offset: 13,
                len: 1,
                feature: Feature::Root {
                    components: vec!["height".into()],
                },
            },
        ],
    )
}

fn mean_std(rng: &mut ChaCha8Rng, n: usize, scale: f32) -> MeanStd {
    MeanStd {
        mean: random(rng, n, scale),
        std: (0..n).map(|_| rng.random_range(0.5..2.0) * scale).collect(),
    }
}

fn dense(rng: &mut ChaCha8Rng, rows: usize, cols: usize) -> DenseWeights {
    let a = 1.0 / (cols as f32).sqrt();
    DenseWeights {
        weight: random(rng, rows * cols, a),
        bias: random(rng, rows, a),
    }
}

pub fn random_model(seed: u64, sizes: ModelSizes) -> GarmentModel {
    random_model_with(seed, header(sizes), 0.01)
}

/// A random model for `header`, with displacement statistics of about `scale_m` metres.
pub fn random_model_with(seed: u64, header: ModelHeader, scale_m: f32) -> GarmentModel {
    let sizes = header.sizes;
    let mut r = rng(seed);
    let (b, i, hf, h, o3) = (
        sizes.n_betas,
        sizes.wrinkle_inputs(),
        sizes.fit_hidden,
        sizes.gru_hidden,
        sizes.n_outputs(),
    );
    let a = 1.0 / (h as f32).sqrt();
    let weights = ModelWeights {
        fit_hidden: dense(&mut r, hf, b),
        fit_out: dense(&mut r, o3, hf),
        gru: GruWeights {
            weight_ih: random(&mut r, 3 * h * i, a),
            weight_hh: random(&mut r, 3 * h * h, a),
            bias_ih: random(&mut r, 3 * h, a),
            bias_hh: random(&mut r, 3 * h, a),
        },
        wrinkle_out: dense(&mut r, sizes.wrinkle_out_rows(), h),
        pca: match sizes.output {
            OutputKind::Pca(k) => Some(PcaWeights {
                basis: random(&mut r, o3 * k, 0.3),
                mean: random(&mut r, o3, 0.1),
            }),
            OutputKind::Dense => None,
        },
        lr: sizes.linear_baseline.then(|| dense(&mut r, o3, i)),
        norm: NormStats {
            fit_in: mean_std(&mut r, b, 1.0),
            wrinkle_in: mean_std(&mut r, i, 1.0),
            fit_out: mean_std(&mut r, o3, scale_m),
            wrinkle_out: mean_std(&mut r, o3, scale_m),
        },
    };
    GarmentModel::new(header, weights).expect("a valid random model")
}

use crate::reference::affine;

fn normalise(x: &[f32], s: &MeanStd) -> Vec<f64> {
    x.iter()
        .zip(s.mean.iter().zip(&s.std))
        .map(|(&v, (&m, &sd))| (v as f64 - m as f64) / sd as f64)
        .collect()
}

fn denormalise(y: &[f64], s: &MeanStd) -> Vec<f64> {
    y.iter()
        .zip(s.mean.iter().zip(&s.std))
        .map(|(&v, (&m, &sd))| v * sd as f64 + m as f64)
        .collect()
}

/// The fit MLP in f64.
pub fn reference_fit(model: &GarmentModel, betas: &[f32]) -> Vec<f64> {
    let w = model.weights();
    let x = normalise(betas, &w.norm.fit_in);
    let h: Vec<f64> = affine(&w.fit_hidden.weight, &w.fit_hidden.bias, &x)
        .into_iter()
        .map(|v| v.max(0.0))
        .collect();
    denormalise(
        &affine(&w.fit_out.weight, &w.fit_out.bias, &h),
        &w.norm.fit_out,
    )
}

/// PyTorch's GRU equations + output layer in f64; advances `h`.
pub fn reference_wrinkle_step(model: &GarmentModel, x_t: &[f32], h: &mut [f64]) -> Vec<f64> {
    let w = model.weights();
    let hid = h.len();
    let x = normalise(x_t, &w.norm.wrinkle_in);
    let gi = affine(&w.gru.weight_ih, &w.gru.bias_ih, &x);
    let gh = affine(&w.gru.weight_hh, &w.gru.bias_hh, h);
    let sig = |a: f64| 1.0 / (1.0 + (-a).exp());
    for j in 0..hid {
        let r = sig(gi[j] + gh[j]);
        let z = sig(gi[hid + j] + gh[hid + j]);
        let n = (gi[2 * hid + j] + r * gh[2 * hid + j]).tanh();
        h[j] = (1.0 - z) * n + z * h[j];
    }
    let y = affine(&w.wrinkle_out.weight, &w.wrinkle_out.bias, h);
    let y = match &w.pca {
        Some(p) => affine(&p.basis, &p.mean, &y),
        None => y,
    };
    denormalise(&y, &w.norm.wrinkle_out)
}

/// The linear baseline in f64.
pub fn reference_linear(model: &GarmentModel, x_t: &[f32]) -> Vec<f64> {
    let w = model.weights();
    let lr = w.lr.as_ref().expect("model with baseline");
    let x = normalise(x_t, &w.norm.wrinkle_in);
    denormalise(&affine(&lr.weight, &lr.bias, &x), &w.norm.wrinkle_out)
}

/// max |a − b| / max |b|.
pub fn rel_err(a: &[f32], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = a
        .iter()
        .zip(b)
        .fold(0.0f64, |m, (&x, &y)| m.max((x as f64 - y).abs()));
    err / scale
}

pub fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// The built-in body model folder of the workspace (`datasets/body/makehuman`).
pub fn builtin_model_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman")
}

/// The built-in body model.
pub fn load_builtin() -> sartor_core::Result<sartor_core::BodyModel> {
    sartor_core::BodyModel::load(&builtin_model_dir())
}
