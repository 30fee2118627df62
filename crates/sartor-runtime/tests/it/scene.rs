//! A small scene for the animator tests: the built-in body, the committed tiny T-shirt (266
//! vertices), its binding, and random models whose input layout is the real one (β, 20 joints
//! in 6D, 4 root values).

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use sartor_core::{BodyModel, Pose, PoseFeatureSpec, RootFeature, TriMesh};
pub use sartor_motion::cmu_mb_body_joints as feature_joints;
use sartor_runtime::{
    AnimatorOptions, AssetId, FeatureBlock, GarmentBinding, GarmentModel, GarmentNetwork,
    GarmentRig, ModelHeader, ModelSizes, NetworkOptions, OutputKind, RotationEncoding,
};

use crate::common::random_model_with;

pub fn body() -> Arc<BodyModel> {
    static BODY: OnceLock<Arc<BodyModel>> = OnceLock::new();
    BODY.get_or_init(|| Arc::new(crate::common::load_builtin().expect("built-in body")))
        .clone()
}

pub fn garment_mesh() -> TriMesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../datasets/garments/tshirt-tiny/garment.obj");
    sartor_core::read_obj(&path).expect("tiny T-shirt")
}

pub fn garment_id() -> AssetId {
    AssetId {
        id: "tshirt-tiny".into(),
        sha256: "c".repeat(64),
    }
}

pub fn body_id() -> AssetId {
    AssetId {
        id: "makehuman".into(),
        sha256: "d".repeat(64),
    }
}

pub fn binding() -> Arc<GarmentBinding> {
    static BINDING: OnceLock<Arc<GarmentBinding>> = OnceLock::new();
    BINDING
        .get_or_init(|| {
            let mesh = garment_mesh();
            Arc::new(
                GarmentBinding::from_body(
                    garment_id(),
                    mesh.positions(),
                    mesh.faces(),
                    body_id(),
                    &body(),
                    0.03,
                    0.0,
                )
                .expect("binding"),
            )
        })
        .clone()
}

/// The header of a model of the tiny T-shirt with the real input layout.
pub fn header(output: OutputKind, gru_hidden: usize) -> ModelHeader {
    let n_betas = 10;
    let rot = feature_joints().len() * 6;
    ModelHeader::new(
        garment_id(),
        body_id(),
        ModelSizes {
            n_vertices: binding().n_vertices(),
            n_betas,
            n_pose_features: rot + RootFeature::ALL.len(),
            fit_hidden: 8,
            gru_hidden,
            output,
            linear_baseline: false,
        },
        FeatureBlock::layout(
            n_betas,
            &PoseFeatureSpec {
                joints: feature_joints(),
                encoding: RotationEncoding::Rot6d,
                root: RootFeature::ALL.to_vec(),
            },
        ),
    )
}

/// A random model of the tiny T-shirt: displacements of about 1 cm.
pub fn model(seed: u64, output: OutputKind, gru_hidden: usize) -> GarmentModel {
    random_model_with(seed, header(output, gru_hidden), 0.01)
}

pub fn rig(
    model: &GarmentModel,
    network: NetworkOptions,
    options: AnimatorOptions,
) -> Arc<GarmentRig> {
    let net = GarmentNetwork::with_options(model.clone(), network).expect("network");
    Arc::new(GarmentRig::new(Arc::new(net), binding(), body(), options).expect("rig"))
}

/// `n` frames of a procedural clip, every `step`-th frame (a fast test motion).
pub fn clip(name: &str, n: usize, step: usize) -> Vec<Pose> {
    let motion = sartor_motion::procedural::clip(name).expect("clip");
    motion
        .frames()
        .iter()
        .step_by(step)
        .take(n)
        .cloned()
        .collect()
}
