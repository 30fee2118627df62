//! Building a dataset folder from (synthetic) simulations: contents, resume, hashes, splits.

use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::Vector3;
use sartor_core::{BodyModel, GarmentBinding, Parallelism, Pose, skin_points};
use sartor_dataset::{
    DatasetConfig, DatasetInputs, DatasetPlan, PcaSettings, Result, SequencePlan, ShapePlan,
    SimulatedMotion, SimulationSource, Smoother, Split, build_dataset, fit_delta, load_dataset,
    sequence_file,
};
use sartor_motion::procedural;

use crate::common::{bind, body, source, tiny_tshirt};

/// Simulations made by skinning known displacements: the rest cloth is the relaxed garment
/// grown by 2 % per unit of β₀, each motion frame adds a known wrinkle field `f_t`.
struct Synthetic {
    body: BodyModel,
    relaxed: Vec<Vector3<f64>>,
    binding: GarmentBinding,
    smoother: Smoother,
    motion_calls: AtomicUsize,
    frames: usize,
}

fn wrinkle(p: &Vector3<f64>, t: usize) -> Vector3<f64> {
    Vector3::new((9.0 * p.y + t as f64 * 0.3).sin(), 0.0, (7.0 * p.x).cos()) * 0.01
}

impl Synthetic {
    fn rest_cloth(&self, shape: &ShapePlan) -> Vec<Vector3<f64>> {
        let centre = self.relaxed.iter().sum::<Vector3<f64>>() / self.relaxed.len() as f64;
        let s = 1.0 + 0.02 * shape.betas[0];
        self.relaxed
            .iter()
            .map(|p| centre + (p - centre) * s)
            .collect()
    }

    fn poses(&self) -> Vec<Pose> {
        let clip = procedural::clip("arm_swing_large").expect("clip exists");
        clip.frames()[..=self.frames].to_vec()
    }
}

impl SimulationSource for Synthetic {
    fn rest(&self, shape: &ShapePlan) -> Result<Vec<Vector3<f64>>> {
        Ok(self.rest_cloth(shape))
    }

    fn motion(&self, shape: &ShapePlan, _motion: &str) -> Result<SimulatedMotion> {
        self.motion_calls.fetch_add(1, Ordering::SeqCst);
        let mut betas = shape.betas.clone();
        betas.resize(self.body.n_betas(), 0.0);
        let delta_g = fit_delta(&self.binding, &self.smoother, &self.rest_cloth(shape))?;
        let joints = self.body.shaped_joints(&betas)?;
        let poses = self.poses();
        let mut cloth = Vec::new();
        for (t, pose) in poses[1..].iter().enumerate() {
            let rest: Vec<Vector3<f64>> = (0..self.binding.n_vertices())
                .map(|v| {
                    let g = Vector3::new(
                        delta_g[3 * v] as f64,
                        delta_g[3 * v + 1] as f64,
                        delta_g[3 * v + 2] as f64,
                    );
                    let t_c = self.binding.template()[v].cast::<f64>();
                    t_c + g + wrinkle(&t_c, t)
                })
                .collect();
            let (_, transforms) = self.body.skeleton().forward_kinematics(&joints, pose)?;
            let mut posed = vec![Vector3::zeros(); rest.len()];
            skin_points(
                &rest,
                self.binding.skin_weights(),
                &transforms,
                &mut posed,
                Parallelism::Sequential,
            )?;
            cloth.push(posed);
        }
        Ok(SimulatedMotion {
            betas: shape.betas.clone(),
            previous_pose: poses[0].clone(),
            poses: poses[1..].to_vec(),
            cloth,
        })
    }
}

fn shape(id: &str, b0: f64, split: Split) -> ShapePlan {
    ShapePlan {
        id: id.into(),
        betas: vec![b0, 0.5],
        split,
    }
}

fn seq(shape: usize, motion: &str, split: Split) -> SequencePlan {
    SequencePlan {
        shape,
        motion: motion.into(),
        split,
    }
}

fn plan() -> DatasetPlan {
    DatasetPlan {
        shapes: vec![
            shape("s0", 0.0, Split::Train),
            shape("s1", 1.0, Split::Train),
            shape("t0", 3.0, Split::HeldOutShapes),
        ],
        sequences: vec![
            seq(0, "a", Split::Train),
            seq(1, "a", Split::Train),
            seq(0, "b", Split::HeldOutMotions),
            seq(2, "a", Split::HeldOutShapes),
        ],
    }
}

fn setup() -> (Synthetic, DatasetConfig) {
    let body = body();
    let garment = tiny_tshirt();
    let config = DatasetConfig {
        pca: Some(PcaSettings {
            components: 4,
            max_frames: 100,
            seed: 1,
        }),
        ..DatasetConfig::default()
    };
    let smoother =
        Smoother::new(garment.positions(), garment.faces(), config.smoothing).expect("valid");
    let binding = bind(&body, &garment, &smoother);
    (
        Synthetic {
            body,
            relaxed: garment.positions().to_vec(),
            binding,
            smoother,
            motion_calls: AtomicUsize::new(0),
            frames: 6,
        },
        config,
    )
}

#[test]
fn builds_loads_resumes_and_checks_hashes() {
    let (sim, config) = setup();
    let garment = tiny_tshirt();
    let dir = tempfile::tempdir().expect("temp dir");
    let inputs = DatasetInputs {
        body: &sim.body,
        relaxed: garment.positions(),
        faces: garment.faces(),
        source: source(),
        config_sha256: "c".repeat(64),
    };
    let plan = plan();
    let report =
        build_dataset(&inputs, &plan, &config, &sim, dir.path(), &|_, _| {}).expect("builds");
    assert_eq!(sim.motion_calls.load(Ordering::SeqCst), 4);
    assert_eq!(report.frames_per_split["train"], 12);
    assert_eq!(report.frames_per_split["held_out_shapes"], 6);
    assert_eq!(report.pca_components, 4);
    assert!(report.joints.iter().any(|j| j == "LeftArm"));

    let data = load_dataset(dir.path()).expect("loads");
    assert_eq!(data.sequences().len(), 4);
    assert_eq!(data.n_vertices(), garment.n_vertices());
    assert_eq!(data.source(), &source());
    // Δ_L is the planted wrinkle field (f32 storage).
    let q = &data.sequences()[0];
    let mut worst = 0.0f64;
    for t in 0..q.n_frames {
        for (v, p) in sim.binding.template().iter().enumerate() {
            let w = wrinkle(&p.cast::<f64>(), t);
            for c in 0..3 {
                let got = q.wrinkle_delta[t * data.n_outputs() + 3 * v + c] as f64;
                worst = worst.max((got - w[c]).abs());
            }
        }
    }
    assert!(worst < 1e-5, "Δ_L off by {worst} m");
    // β padded to the body's 10 and first in the inputs.
    assert_eq!(data.n_betas(), 10);
    assert_eq!(&q.inputs[..3], &[0.0, 0.5, 0.0]);
    // Statistics come from the training split: the held-out shape's β₀ = 3 is not in them.
    assert!((data.stats().fit_in.mean[0] - 0.5).abs() < 1e-6);

    // Resume: nothing is re-extracted and the manifest is the same.
    let manifest = std::fs::read(dir.path().join("manifest.json")).expect("written");
    build_dataset(&inputs, &plan, &config, &sim, dir.path(), &|_, _| {}).expect("resumes");
    assert_eq!(sim.motion_calls.load(Ordering::SeqCst), 4);
    assert_eq!(
        std::fs::read(dir.path().join("manifest.json")).expect("written"),
        manifest
    );

    // A corrupted file is found and named.
    let victim = dir.path().join(sequence_file("s1__a"));
    let mut bytes = std::fs::read(&victim).expect("exists");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(&victim, bytes).expect("writable");
    let err = load_dataset(dir.path())
        .expect_err("hash mismatch")
        .to_string();
    assert!(
        err.contains("s1__a.safetensors") && err.contains("hash"),
        "{err}"
    );

    // Another config starts over.
    let other = DatasetInputs {
        config_sha256: "d".repeat(64),
        ..inputs
    };
    build_dataset(&other, &plan, &config, &sim, dir.path(), &|_, _| {}).expect("rebuilds");
    assert_eq!(sim.motion_calls.load(Ordering::SeqCst), 8);
    load_dataset(dir.path()).expect("consistent again");
}

#[test]
fn plans_that_leak_between_splits_are_rejected() {
    let mut p = plan();
    p.sequences[3].split = Split::Train;
    assert!(p.validate(10).is_err(), "a held-out shape in training");
    let mut p = plan();
    p.sequences[0].split = Split::HeldOutShapes;
    assert!(
        p.validate(10).is_err(),
        "a training shape in the held-out shapes"
    );
    let mut p = plan();
    p.shapes[1].id = "s0".into();
    assert!(p.validate(10).is_err(), "duplicate shape id");
    let mut p = plan();
    p.sequences.push(p.sequences[0].clone());
    assert!(p.validate(10).is_err(), "duplicate sequence");
    let mut p = plan();
    p.shapes[0].betas = vec![0.0; 11];
    assert!(p.validate(10).is_err(), "too many betas");
    assert!(plan().validate(10).is_ok());
    // Validation: motions on the training shapes, and shapes of their own with no sequence.
    let mut p = plan();
    p.sequences.push(seq(1, "c", Split::Validation));
    p.shapes.push(shape("v0", 0.5, Split::Validation));
    assert!(p.validate(10).is_ok());
    p.sequences.push(seq(2, "c", Split::Validation));
    assert!(
        p.validate(10).is_err(),
        "a validation motion on a held-out shape"
    );
    let mut p = plan();
    p.shapes.push(shape("v0", 0.5, Split::Validation));
    p.sequences.push(seq(3, "a", Split::Train));
    assert!(p.validate(10).is_err(), "a validation shape in training");
}
