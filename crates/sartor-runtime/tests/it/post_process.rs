//! The certified query (the default) against the exact BVH query on the shipped model: the
//! same garment, vertex for vertex, on a real motion and the procedural walk, at the nominal
//! shape and at a trained extreme (the tree search answers there; beyond the training shapes the grid
//! path with buried faces runs, which pushes more by design: see `extremes.rs`).

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Vector3;
use sartor_core::{BodyModel, Pose};
use sartor_motion::{MotionSourceOptions, RetargetBody, load_motion};
use sartor_runtime::{
    AnimatorOptions, CollisionOptions, CollisionQuery, GarmentAnimator, GarmentBinding,
    GarmentNetwork, GarmentRig, Interpenetration, NetworkOptions, Parallelism, PostProcessReport,
    StrainLimit,
};

fn data(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../datasets")
        .join(path)
}

/// The shipped model: the built-in body, its network and binding.
fn shipped() -> (Arc<BodyModel>, Arc<GarmentNetwork>, Arc<GarmentBinding>) {
    let dir = data("models/default");
    let body = Arc::new(BodyModel::load(&data("body/makehuman")).expect("built-in body"));
    let network =
        Arc::new(GarmentNetwork::load_with(&dir, NetworkOptions::default()).expect("model"));
    let binding = Arc::new(GarmentBinding::load(&dir).expect("binding"));
    (body, network, binding)
}

/// Stored motions, retargeted onto the built-in body.
fn motion_options() -> MotionSourceOptions {
    MotionSourceOptions {
        motions_dir: data("motions"),
        body: Some(RetargetBody::load(&data("body/makehuman")).expect("built-in body")),
        ..MotionSourceOptions::default()
    }
}

#[test]
fn the_certified_query_makes_the_exact_queries_pushes_on_the_shipped_model() {
    let (body, network, binding) = shipped();
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
    let cmu = load_motion("cmu/02_04@60+24", &motion_options()).expect("stored CMU clip");
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

#[test]
fn the_certified_query_split_over_threads_makes_the_same_garment() {
    let (body, network, binding) = shipped();
    // The triangles pushed too and the buried faces sought every frame: every path of the
    // first pass (certificates, exact answers, the way out of a part) runs split.
    let avatar = |parallelism| {
        let options = AnimatorOptions {
            parallelism,
            collision: Some(CollisionOptions {
                query: CollisionQuery::Certified,
                interpenetration: Interpenetration::Always,
                faces: true,
                ..CollisionOptions::default()
            }),
            ..AnimatorOptions::default()
        };
        let rig = GarmentRig::new(network.clone(), binding.clone(), body.clone(), options);
        GarmentAnimator::new(Arc::new(rig.expect("rig"))).expect("avatar")
    };
    let cmu = load_motion("cmu/02_04@60+16", &motion_options()).expect("stored CMU clip");
    // Three threads: parts of unequal cost, taken in any order.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .expect("pool");
    // A heavy shape beyond the training shapes, so that body parts press into each other.
    let mut heavy = vec![0.0f32; network.header().sizes.n_betas];
    heavy[0] = 3.0;
    heavy[1] = -3.0;
    let mut one = avatar(Parallelism::Sequential);
    let mut split = avatar(Parallelism::Rayon);
    let mut pushed = 0;
    for betas in [vec![0.0f32; heavy.len()], heavy] {
        one.set_shape(&betas).expect("shape");
        split.set_shape(&betas).expect("shape");
        for (k, pose) in cmu.frames().iter().enumerate() {
            let a = one.frame(pose).expect("frame").to_vec();
            let b = pool.install(|| split.frame(pose).expect("frame").to_vec());
            assert_eq!(a, b, "β {betas:?}, frame {k}");
            assert_eq!(one.last_frame_pushed(), split.last_frame_pushed());
            assert_eq!(one.certify_stats(), split.certify_stats(), "frame {k}");
            pushed += split.last_frame_pushed();
        }
    }
    assert!(pushed > 0, "the clip collides");
}

/// The shipped model as the try-on page runs it: the triangles pushed too, buried faces sought
/// beyond the training shapes; and its β count.
fn page_rig() -> (Arc<GarmentRig>, usize) {
    let (body, network, binding) = shipped();
    let options = AnimatorOptions {
        collision: Some(CollisionOptions {
            faces: true,
            ..CollisionOptions::default()
        }),
        ..AnimatorOptions::default()
    };
    let n_betas = network.header().sizes.n_betas;
    let rig = GarmentRig::new(network, binding, body, options).expect("rig");
    (Arc::new(rig), n_betas)
}

#[test]
fn frames_advanced_without_their_garment_leave_the_next_frame_bit_for_bit() {
    let (rig, n_betas) = page_rig();
    let cmu = load_motion("cmu/02_04@60+20", &motion_options()).expect("stored CMU clip");
    let poses = cmu.frames();
    // The nominal shape, and a heavy one beyond the training shapes (the grid path with the
    // buried faces, whose search state the advanced frames leave where the last frame put it).
    let mut heavy = vec![0.0f32; n_betas];
    heavy[0] = 3.0;
    heavy[1] = -3.0;
    let mut pushed = 0;
    for betas in [vec![0.0f32; heavy.len()], heavy] {
        let mut every = GarmentAnimator::new(rig.clone()).expect("avatar");
        every.set_shape(&betas).expect("shape");
        let full: Vec<Vec<_>> = poses
            .iter()
            .map(|p| every.frame(p).expect("frame").to_vec())
            .collect();
        for shown in [1, 7, poses.len() - 1] {
            let mut skip = GarmentAnimator::new(rig.clone()).expect("avatar");
            skip.set_shape(&betas).expect("shape");
            // A frame made before the jump, a new sequence, then the network alone up to the
            // frame shown.
            let before = skip.frame(&poses[shown]).expect("frame").to_vec();
            skip.reset();
            for pose in &poses[..shown] {
                skip.advance(pose).expect("advance");
                assert_eq!(skip.vertices(), &before[..], "advance makes no garment");
            }
            let garment = skip.frame(&poses[shown]).expect("frame");
            assert!(
                garment == &full[shown][..],
                "β {betas:?}, frame {shown}: not the garment of every frame made"
            );
            pushed += skip.last_frame_pushed();
        }
        // A pose of another skeleton: an error, and the avatar as it was.
        let state = every.state().to_vec();
        let mut wrong = poses[0].clone();
        wrong.local_rotations.pop();
        assert!(every.advance(&wrong).is_err());
        assert_eq!(every.state(), &state[..]);
    }
    assert!(pushed > 0, "the clip collides");
}

#[test]
fn a_post_process_run_by_another_animator_gives_the_frames_garment_bit_for_bit() {
    // The try-on page's options: the strain limit, then the collisions with the triangles.
    let (body, network, binding) = shipped();
    let options = AnimatorOptions {
        strain_limit: Some(StrainLimit::default()),
        collision: Some(CollisionOptions {
            faces: true,
            ..CollisionOptions::default()
        }),
        ..AnimatorOptions::default()
    };
    let n_betas = network.header().sizes.n_betas;
    let rig = Arc::new(GarmentRig::new(network, binding, body, options).expect("rig"));
    let cmu = load_motion("cmu/05_06@30+16", &motion_options()).expect("stored CMU clip");
    let poses = cmu.frames();
    // The nominal shape, and a heavy one beyond the training shapes (the buried faces sought).
    let mut heavy = vec![0.0f32; n_betas];
    heavy[0] = 3.0;
    heavy[1] = -3.0;
    let (mut pushed, mut strained) = (0, 0);
    for betas in [vec![0.0f32; n_betas], heavy] {
        let mut whole = GarmentAnimator::new(rig.clone()).expect("avatar");
        let mut page = GarmentAnimator::new(rig.clone()).expect("avatar");
        // The worker sees the frames in another order than they are made (a jump back, one
        // skipped): the post-process's state across frames only warm-starts its search.
        let mut worker = GarmentAnimator::new(rig.clone()).expect("avatar");
        for a in [&mut whole, &mut page, &mut worker] {
            a.set_shape(&betas).expect("shape");
        }
        let order: Vec<usize> = (0..8).chain([3, 4]).chain(10..poses.len()).collect();
        for &t in &order {
            if t == 3 || t == 10 {
                whole.reset();
                page.reset();
            }
            let expected = whole.frame(&poses[t]).expect("frame").to_vec();
            let mut garment = page.frame_deferred(&poses[t]).expect("frame").to_vec();
            let nothing_yet = (page.last_frame_pushed(), page.last_frame_strained());
            assert_eq!(nothing_yet, (0, 0), "nothing limited or pushed yet");
            let state = worker.state().to_vec();
            let report = worker.post_process(&poses[t], &mut garment);
            let report = report.expect("post-process");
            assert_eq!(worker.state(), &state[..], "the network does not step");
            assert!(
                garment == expected,
                "β {betas:?}, frame {t}: not the frame's"
            );
            assert_eq!(report.pushed, whole.last_frame_pushed());
            assert_eq!(report.strained, whole.last_frame_strained());
            pushed += report.pushed;
            strained += report.strained;
            page.take_post_processed(&garment, &report).expect("taken");
            assert_eq!(page.vertices(), whole.vertices());
            let counts = (page.last_frame_pushed(), page.last_frame_strained());
            assert_eq!(counts, (report.pushed, report.strained));
        }
    }
    assert!(pushed > 0, "the clip collides");
    assert!(strained > 0, "and stretches edges beyond the limit");

    // Refused, changing nothing: a pose of another skeleton, vertices of another count or not
    // finite, and a rig with neither a strain limit nor a post-process.
    let mut worker = GarmentAnimator::new(rig.clone()).expect("avatar");
    worker.set_shape(&vec![0.0f32; n_betas]).expect("shape");
    let mut garment = worker.frame_deferred(&poses[0]).expect("frame").to_vec();
    let kept = garment.clone();
    let mut wrong = poses[0].clone();
    wrong.local_rotations.pop();
    assert!(worker.post_process(&wrong, &mut garment).is_err());
    assert!(worker.post_process(&poses[0], &mut garment[1..]).is_err());
    garment[5].y = f32::NAN;
    let e = worker.post_process(&poses[0], &mut garment).unwrap_err();
    assert!(e.to_string().contains("garment vertices"), "{e}");
    let none = PostProcessReport::default();
    assert!(worker.take_post_processed(&garment, &none).is_err());
    assert!(worker.take_post_processed(&kept[1..], &none).is_err());
    assert_eq!(worker.vertices(), &kept[..], "nothing taken");
    let (body, network, binding) = shipped();
    let options = AnimatorOptions {
        strain_limit: None,
        collision: None,
        ..AnimatorOptions::default()
    };
    let bare = GarmentRig::new(network, binding, body, options).expect("rig");
    let mut bare = GarmentAnimator::new(Arc::new(bare)).expect("avatar");
    let mut garment = kept.clone();
    let e = bare.post_process(&poses[0], &mut garment).unwrap_err();
    assert!(e.to_string().contains("neither a strain limit nor"), "{e}");
    assert_eq!(garment, kept);
}

#[test]
fn a_new_shape_starts_from_the_last_shapes_faces_and_gives_a_fresh_avatars_garment() {
    let (rig, n) = page_rig();
    let cmu = load_motion("cmu/02_04@60+12", &motion_options()).expect("stored CMU clip");
    let poses = cmu.frames();
    let shape = |b0: f32, b1: f32| {
        let mut b = vec![0.0f32; n];
        (b[0], b[1]) = (b0, b1);
        b
    };
    // Within the training shapes and beyond them (buried faces sought), in both orders.
    let (nominal, heavy, light) = (shape(0.0, 0.0), shape(3.0, -3.0), shape(-2.0, 2.5));
    let mut pushed = 0;
    for (before, after) in [(&nominal, &heavy), (&heavy, &nominal), (&heavy, &light)] {
        let mut fresh = GarmentAnimator::new(rig.clone()).expect("avatar");
        fresh.set_shape(after).expect("shape");
        let expected: Vec<Vec<_>> = poses
            .iter()
            .map(|p| fresh.frame(p).expect("frame").to_vec())
            .collect();
        let mut changed = GarmentAnimator::new(rig.clone()).expect("avatar");
        changed.set_shape(before).expect("shape");
        for pose in poses.iter().rev() {
            changed.frame(pose).expect("frame");
        }
        changed.set_shape(after).expect("shape");
        changed.reset();
        for (t, pose) in poses.iter().enumerate() {
            let garment = changed.frame(pose).expect("frame");
            assert!(
                garment == &expected[t][..],
                "β {before:?} -> {after:?}, frame {t}: not a fresh avatar's garment"
            );
            pushed += changed.last_frame_pushed();
        }
    }
    assert!(pushed > 0, "the clip collides");
}

#[test]
fn the_triangle_pass_moves_only_triangles_whose_centroid_is_within_half_the_margin() {
    // `CollisionOptions::faces` runs the vertex passes first, so the garment without it is the
    // one whose centroids the triangle pass reads; every vertex it moves, and every vertex the
    // later passes move after it, belongs to a triangle whose centroid there lies inside the
    // body or within half the margin. Cloth held at the margin sags between its vertices, so
    // many centroids lie between half the margin and the margin: those triangles stay.
    // And the certified query's pass (which leaves a centroid farther than the pass's depth from
    // every face without its answer) moves the triangles the exact query's does.
    let (body, network, binding) = shipped();
    let avatar = |faces, query| {
        let options = AnimatorOptions {
            collision: Some(CollisionOptions {
                faces,
                query,
                ..CollisionOptions::default()
            }),
            ..AnimatorOptions::default()
        };
        let rig = GarmentRig::new(network.clone(), binding.clone(), body.clone(), options);
        GarmentAnimator::new(Arc::new(rig.expect("rig"))).expect("avatar")
    };
    let (mut vertices_only, mut with_faces, mut exact) = (
        avatar(false, CollisionQuery::Certified),
        avatar(true, CollisionQuery::Certified),
        avatar(true, CollisionQuery::EXACT_BVH),
    );
    let region = sartor_runtime::BodyRegion::new(&body, binding.region_faces()).expect("region");
    let cmu = load_motion("cmu/02_04@60+8", &motion_options()).expect("stored CMU clip");
    let half = 0.5 * sartor_runtime::DEFAULT_MARGIN_M;
    let (mut moved, mut between) = (0, 0);
    for (k, pose) in cmu.frames().iter().enumerate() {
        let before = vertices_only.frame(pose).expect("frame").to_vec();
        let after = with_faces.frame(pose).expect("frame").to_vec();
        assert!(
            exact.frame(pose).expect("frame") == &after[..],
            "frame {k}: the exact query's triangle pass differs"
        );
        // The region as the post-process posed it (the nominal shape: no buried faces, so the
        // exact query is the post-process's own).
        let posed = vertices_only
            .posed_region()
            .expect("post-process on")
            .to_vec();
        let proximity = sartor_core::MeshProximity::new(&posed, region.faces()).expect("region");
        let mut near = vec![false; before.len()];
        for t in with_faces.faces() {
            let c = t.iter().map(|&v| before[v as usize]).sum::<Vector3<f32>>() / 3.0;
            let d = proximity.closest(&c.cast::<f64>()).signed_distance_m;
            between += usize::from(d >= half && d < sartor_runtime::DEFAULT_MARGIN_M);
            if d < half {
                for &v in t {
                    near[v as usize] = true;
                }
            }
        }
        for (v, (p, q)) in before.iter().zip(&after).enumerate() {
            if p != q {
                moved += 1;
                assert!(
                    near[v],
                    "frame {k}: vertex {v} moved, no triangle of it within half the margin"
                );
            }
        }
    }
    assert!(moved > 0, "the triangle pass moves vertices");
    assert!(
        between > 0,
        "centroids lie between half the margin and the margin"
    );
    eprintln!(
        "triangle pass: {moved} vertex-frames moved, {between} centroids left between half \
         the margin and the margin"
    );
}
