//! `MeshProximity`'s tree queries on the built-in MakeHuman body against the same arithmetic
//! over every triangle (`closest_among` all faces, no tree): the same answer bit for bit — near
//! the surface, far from it, inside, with a bound, from a hint, after the body moves (a refit),
//! and with the body a kilometre from the origin (where the tree's f32 boxes round most); the
//! faces within a radius and the faces whose box is, against a filter of every face.

use nalgebra::{UnitQuaternion, Vector3};
use sartor_core::{BodyModel, MeshProximity, NearFaces, Pose, vertex_normals};

/// Points around `positions`: each 13th vertex offset along its normal from 5 cm in to 5 cm
/// out, and points up to a metre beyond the body's box.
fn points(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    let normals = vertex_normals(positions, faces);
    let mut rng = 0x2545f4914f6cdd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let (lo, hi) = positions.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    let mut out = Vec::new();
    for (p, n) in positions.iter().zip(&normals).step_by(13) {
        out.push(p + n * (0.1 * next() - 0.05));
    }
    for _ in 0..300 {
        let t = Vector3::new(next(), next(), next());
        out.push(lo - Vector3::repeat(1.0) + (hi - lo + Vector3::repeat(2.0)).component_mul(&t));
    }
    out
}

/// Every query of the tree against every triangle, for `positions` (set by a refit).
fn agree(tree: &MeshProximity, positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> usize {
    let all: Vec<u32> = (0..faces.len() as u32).collect();
    let mut checked = 0;
    for (i, q) in points(positions, faces).iter().enumerate() {
        let exact = tree.closest_among(q, &all).expect("faces");
        assert_eq!(tree.closest(q), exact, "point {i} at {q}");
        // A bound just above and just below the distance.
        let d = exact.signed_distance_m.abs();
        assert_eq!(tree.closest_within(q, d * 1.001), Some(exact), "point {i}");
        assert_eq!(tree.closest_within(q, d * 0.999), None, "point {i}");
        // From a hint: a face far away, a neighbour of the answer, the answer itself.
        for h in [
            (i * 7919) as u32 % faces.len() as u32,
            exact.face ^ 1,
            exact.face,
        ] {
            let mut hint = h;
            assert_eq!(
                tree.closest_within_hinted(q, f64::INFINITY, &mut hint),
                Some(exact),
                "point {i} from face {h}"
            );
            assert_eq!(hint, exact.face);
        }
        // Every face within 3 cm, and every face whose box is, against the same tests on all.
        let r = 0.03;
        let mut within: Vec<(u32, f64)> = all
            .iter()
            .filter_map(|&f| {
                let d = tree.distance_to_face(q, f);
                (d <= r).then_some((f, d))
            })
            .collect();
        within.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        let from_tree = tree.faces_within(q, r);
        assert_eq!(from_tree.len(), within.len(), "point {i}");
        for (a, b) in from_tree.iter().zip(&within) {
            assert_eq!(a.0, b.0, "point {i}");
            assert!((a.1 - b.1).abs() <= 1e-12 * (1.0 + b.1), "point {i}");
        }
        let mut near = Vec::new();
        tree.for_each_face_near(q, r, |f| near.push(f));
        near.sort_unstable();
        let boxes: Vec<u32> = all
            .iter()
            .copied()
            .filter(|&f| {
                let t = faces[f as usize].map(|v| positions[v as usize]);
                (0..3)
                    .map(|k| {
                        let lo = t[0][k].min(t[1][k]).min(t[2][k]);
                        let hi = t[0][k].max(t[1][k]).max(t[2][k]);
                        (lo - q[k]).max(q[k] - hi).max(0.0).powi(2)
                    })
                    .sum::<f64>()
                    <= r * r
            })
            .collect();
        assert_eq!(near, boxes, "point {i}");
        checked += 1;
    }
    checked
}

#[test]
fn the_tree_query_answers_as_every_triangle_on_the_body_posed_moved_and_far_away() {
    let b = BodyModel::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman"),
    )
    .expect("the built-in body");
    let betas = vec![0.0; b.n_betas()];
    let rest = b
        .posed_vertices(&betas, &Pose::rest(b.skeleton().n_joints()))
        .expect("rest pose");
    let mut tree = MeshProximity::new(&rest, b.faces()).expect("body");
    let mut checked = agree(&tree, &rest, b.faces());
    // The arm swung into the torso (parts pressed together), and the knee bent.
    let mut pose = Pose::rest(b.skeleton().n_joints());
    pose.local_rotations[b.skeleton().index_of("LeftArm").expect("joint")] =
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -1.2);
    pose.local_rotations[b.skeleton().index_of("RightLeg").expect("joint")] =
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 1.4);
    let posed = b.posed_vertices(&betas, &pose).expect("posed");
    tree.update_positions_refit(&posed).expect("same size");
    checked += agree(&tree, &posed, b.faces());
    // A kilometre away: coordinates where f32 keeps only about 0.1 mm.
    let far: Vec<Vector3<f64>> = posed
        .iter()
        .map(|p| p + Vector3::new(1000.0, -250.0, 730.0))
        .collect();
    tree.update_positions(&far).expect("same size");
    checked += agree(&tree, &far, b.faces());
    println!("{checked} points, each asked five ways");
    assert!(checked > 3000, "{checked}");
}

#[test]
fn the_faces_listed_near_a_point_answer_as_the_tree_until_it_has_moved_half_the_margin() {
    // Points within 1 cm of the built-in body, each listed with a 4 mm margin; then the body
    // moves (a translation, and every vertex departing from it by up to `travel`) and the point
    // moves by `step` relative to the translation. While `step + travel` is at most half the
    // margin, the listed faces give the tree's answer bit for bit; moved four times as far, they
    // must fail somewhere (else this test could not catch a list cut too short).
    let b = BodyModel::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman"),
    )
    .expect("the built-in body");
    let rest = b
        .posed_vertices(
            &vec![0.0; b.n_betas()],
            &Pose::rest(b.skeleton().n_joints()),
        )
        .expect("rest pose");
    let faces = b.faces();
    let normals = vertex_normals(&rest, faces);
    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let mut unit = move || {
        let v = Vector3::new(next(), next(), next());
        let v = v / v.norm().max(1e-9);
        (v, next() + 0.5)
    };
    let margin = 4e-3;
    let translation = Vector3::new(0.013, -0.004, 0.021);
    let (mut listed, mut failed_far) = (0, 0);
    for scale in [0.49, 2.0] {
        let mut tree = MeshProximity::new(&rest, faces).expect("body");
        let mut lists = Vec::new();
        for (p, n) in rest.iter().zip(&normals).step_by(7) {
            let (u, s) = unit();
            let q = p + n * (0.02 * s - 0.01) + u * 0.002;
            let mut hint = tree.closest(&q).face;
            let mut near = NearFaces::EMPTY;
            let exact = tree.closest_within_hinted(&q, 0.05, &mut hint.clone());
            let got = tree.closest_within_listing(&q, 0.05, &mut hint, margin, &mut near);
            assert_eq!(got, exact, "the listing query answers as the tree");
            if !near.is_empty() {
                lists.push((q, near));
            }
        }
        // Half the allowance for the body's departure from the translation, half for the point.
        let allowance = scale * margin;
        let moved: Vec<Vector3<f64>> = rest
            .iter()
            .map(|p| {
                let (u, s) = unit();
                p + translation + u * (0.5 * allowance * s)
            })
            .collect();
        tree.update_positions_refit(&moved).expect("same size");
        let mut wrong = 0;
        for (q, near) in &lists {
            let (u, s) = unit();
            let q = q + translation + u * (0.5 * allowance * s);
            let mut hint = u32::MAX;
            let exact = tree.closest_within_hinted(&q, 0.05, &mut hint);
            let mut hint = u32::MAX;
            let from_list = tree.closest_within_near(&q, 0.05, &mut hint, near);
            if scale < 0.5 {
                assert_eq!(from_list, exact, "{q}");
            } else if from_list != exact {
                wrong += 1;
            }
        }
        if scale < 0.5 {
            listed = lists.len();
        } else {
            failed_far = wrong;
        }
    }
    println!("{listed} points listed; moved four times as far, {failed_far} wrong");
    assert!(listed > 500, "{listed}");
    assert!(
        failed_far > 0,
        "lists moved beyond their margin never failed"
    );
}
