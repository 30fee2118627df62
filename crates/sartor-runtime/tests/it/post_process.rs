//! The certified query (the default) against the exact BVH query on the shipped model: the
//! same garment, vertex for vertex, on a real motion and the procedural walk, at the nominal
//! shape and at a trained extreme (the tree search answers there; beyond the training shapes the grid
//! path with buried faces runs, which pushes more by design: see `extremes.rs`).

use std::path::PathBuf;
use std::sync::Arc;

use sartor_core::{BodyModel, Pose};
use sartor_motion::{MotionSourceOptions, RetargetBody, load_motion};
use sartor_runtime::{
    AnimatorOptions, CollisionOptions, CollisionQuery, GarmentAnimator, GarmentBinding,
    GarmentNetwork, GarmentRig, NetworkOptions,
};

fn data(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../datasets")
        .join(path)
}

#[test]
fn the_certified_query_makes_the_exact_queries_pushes_on_the_shipped_model() {
    let dir = data("models/default");
    let body = Arc::new(BodyModel::load(&data("body/makehuman")).expect("built-in body"));
    let network =
        Arc::new(GarmentNetwork::load_with(&dir, NetworkOptions::default()).expect("model"));
    let binding = Arc::new(GarmentBinding::load(&dir).expect("binding"));
    let avatar = |query| {
        let options = AnimatorOptions {
            collision: Some(CollisionOptions {
                query,
                ..CollisionOptions::default()
            }),
            ..AnimatorOptions::default()
        };
        let rig = GarmentRig::new(network.clone(), binding.clone(), body.clone(), options);
        GarmentAnimator::new(Arc::new(rig.expect("rig"))).expect("avatar")
    };
    let walk = sartor_motion::procedural::clip("walk_normal").expect("clip");
    // A real capture: CMU 02_04 (a jump), retargeted onto the built-in body.
    let options = MotionSourceOptions {
        motions_dir: data("motions"),
        body: Some(RetargetBody::load(&data("body/makehuman")).expect("built-in body")),
        ..MotionSourceOptions::default()
    };
    let cmu = load_motion("cmu/02_04@60+24", &options).expect("stored CMU clip");
    let clips: Vec<(&str, Vec<Pose>)> = vec![
        ("walk", walk.frames()[..24].to_vec()),
        ("cmu/02_04", cmu.frames().to_vec()),
    ];
    let training = network
        .header()
        .training_betas
        .clone()
        .expect("training shapes");
    // The nominal shape and the trained shape farthest from it.
    let far = training
        .0
        .iter()
        .max_by(|a, b| {
            let n = |v: &Vec<f32>| v.iter().map(|x| x * x).sum::<f32>();
            n(a).total_cmp(&n(b))
        })
        .expect("a shape")
        .clone();
    let mut pushed_total = 0;
    for betas in [vec![0.0f32; far.len()], far] {
        for (name, poses) in &clips {
            let mut exact = avatar(CollisionQuery::EXACT_BVH);
            let mut certified = avatar(CollisionQuery::Certified);
            exact.set_shape(&betas).expect("shape");
            certified.set_shape(&betas).expect("shape");
            for (k, pose) in poses.iter().enumerate() {
                let a = exact.frame(pose).expect("frame").to_vec();
                let b = certified.frame(pose).expect("frame");
                let differing = a.iter().zip(b).filter(|(p, q)| p != q).count();
                assert_eq!(differing, 0, "{name}, β {betas:?}, frame {k}");
                assert_eq!(exact.last_frame_pushed(), certified.last_frame_pushed());
                pushed_total += certified.last_frame_pushed();
                let stats = certified.certify_stats().expect("certified");
                assert_eq!(stats.certified + stats.exact, a.len());
            }
        }
    }
    assert!(pushed_total > 0, "the clips collide");
}
