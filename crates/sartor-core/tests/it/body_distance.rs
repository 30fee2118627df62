//! `BodyDistance` on the built-in MakeHuman body: points whose side is known (joints inside,
//! far points outside, points just off the surface), the arm pressed into the torso (checked
//! against the exact winding number, an independent sum over every triangle), and the cut
//! edges of a body region.

use std::sync::OnceLock;

use nalgebra::{UnitQuaternion, Vector3};
use sartor_core::{BodyDistance, BodyModel, MeshProximity, MeshTopology, Pose, vertex_normals};

fn body() -> &'static BodyModel {
    static BODY: OnceLock<BodyModel> = OnceLock::new();
    BODY.get_or_init(|| {
        BodyModel::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman"),
        )
        .expect("the built-in body")
    })
}

fn rest() -> Vec<Vector3<f64>> {
    let b = body();
    b.posed_vertices(
        &vec![0.0; b.n_betas()],
        &Pose::rest(b.skeleton().n_joints()),
    )
    .expect("rest pose")
}

#[test]
fn joints_are_inside_far_points_outside_and_offsets_keep_their_side() {
    let b = body();
    let positions = rest();
    let topology = MeshTopology::new(positions.len(), b.faces());
    println!(
        "the built-in body: {} triangles, {} boundary loops",
        b.faces().len(),
        topology.boundary_loops().len()
    );
    let distance = BodyDistance::new(&positions, b.faces()).expect("body");
    let joints = b.shaped_joints(&vec![0.0; b.n_betas()]).expect("joints");
    for name in [
        "Hips",
        "LowerBack",
        "Spine",
        "Spine1",
        "Neck",
        "LeftArm",
        "RightArm",
        "LeftForeArm",
        "LeftUpLeg",
        "RightLeg",
    ] {
        let j = joints[b.skeleton().index_of(name).expect("joint")];
        let a = distance.query(&j);
        assert!(a.inside(), "{name} at {j}: {a:?}");
        assert!(a.signed_distance_m < -0.01, "{name}: {a:?}");
    }
    let (lo, hi) = positions.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    let centre = (lo + hi) / 2.0;
    for k in 0..50 {
        let a = k as f64 * 0.77;
        let dir = Vector3::new(a.cos() * (0.3 * a).cos(), (0.3 * a).sin(), a.sin());
        let q = centre + dir.normalize() * ((hi - lo).norm() * 0.6);
        let r = distance.query(&q);
        assert!(!r.inside() && r.winding_number.abs() < 0.02, "{q}: {r:?}");
    }
    // Every vertex offset 2 mm out along its normal and 2 mm in, where that offset point's
    // closest body point is the vertex itself at 2 mm (a locally simple surface): the sign is
    // the offset's, except where the body overlaps itself (the exact winding number, an
    // independent sum over all triangles, is then 1 on both sides of the sheet).
    let normals = vertex_normals(&positions, b.faces());
    let proximity = MeshProximity::new(&positions, b.faces()).expect("body");
    let (mut checked, mut overlapping) = (0, 0);
    for (i, (p, n)) in positions.iter().zip(&normals).enumerate() {
        for side in [1.0, -1.0] {
            let q = p + n * (0.002 * side);
            if ((proximity.closest(&q).point - p).norm()) > 1e-7 {
                continue;
            }
            let a = distance.query(&q);
            assert!((a.signed_distance_m.abs() - 0.002).abs() < 1e-9, "{a:?}");
            checked += 1;
            if a.inside() == (side < 0.0) && i % 7 != 0 {
                continue;
            }
            // Disagreements, and every 7th vertex, against the exact winding number.
            let exact = distance.winding_number_exact(&q);
            assert!(
                (a.winding_number - exact).abs() < 1e-6,
                "{q}: {a:?}, exact {exact}"
            );
            overlapping += usize::from(a.inside() != (side < 0.0));
        }
    }
    println!("{checked} points 2 mm off the surface; {overlapping} inside another body part");
    assert!(checked > positions.len() / 4, "{checked} points checked");
    assert!(overlapping * 1000 < checked, "{overlapping} of {checked}");
}

#[test]
fn an_arm_pressed_into_the_torso_agrees_with_the_exact_winding_number() {
    let b = body();
    let mut pose = Pose::rest(b.skeleton().n_joints());
    // The left arm (at +X) swung down and across, into the torso.
    pose.local_rotations[b.skeleton().index_of("LeftArm").expect("joint")] =
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -1.2);
    let positions = b
        .posed_vertices(&vec![0.0; b.n_betas()], &pose)
        .expect("posed");
    let distance = BodyDistance::new(&positions, b.faces()).expect("body");
    // Sample points around the upper arm and the side of the torso.
    let shoulder = b.shaped_joints(&vec![0.0; b.n_betas()]).expect("joints")
        [b.skeleton().index_of("LeftArm").expect("joint")];
    let mut points = Vec::new();
    for i in 0..12 {
        for j in 0..12 {
            for k in 0..6 {
                points.push(
                    shoulder
                        + Vector3::new(
                            -0.15 + 0.025 * i as f64,
                            -0.30 + 0.025 * j as f64,
                            -0.06 + 0.025 * k as f64,
                        ),
                );
            }
        }
    }
    let (mut overlap, mut pseudo_wrong) = (0, 0);
    for q in &points {
        let exact = distance.winding_number_exact(q);
        let a = distance.query(q);
        assert!(
            (a.winding_number - exact).abs() < 0.02,
            "{q}: {} vs exact {exact}",
            a.winding_number
        );
        if (exact - 0.5).abs() > 0.1 {
            assert_eq!(a.inside(), exact > 0.5, "{q}: {a:?}, exact w {exact}");
        }
        overlap += usize::from(exact > 1.5);
        pseudo_wrong +=
            usize::from((distance.proximity().closest(q).signed_distance_m < 0.0) != (exact > 0.5));
    }
    println!(
        "{} points: {overlap} inside two parts, {pseudo_wrong} where the pseudo-normal sign is wrong",
        points.len()
    );
    assert!(overlap > 0, "the arm does not enter the torso: no test");
    assert!(
        pseudo_wrong > 0,
        "no point where the closest point's pseudo-normal fails: the case is not exercised"
    );
}

#[test]
fn the_cut_edges_of_a_region_do_not_change_the_side() {
    let b = body();
    let positions = rest();
    // A region like a T-shirt's: the faces with every vertex between hips and neck.
    let joints = b.shaped_joints(&vec![0.0; b.n_betas()]).expect("joints");
    let (y_lo, y_hi) = (
        joints[b.skeleton().index_of("Hips").expect("joint")].y,
        joints[b.skeleton().index_of("Neck").expect("joint")].y,
    );
    let region: Vec<[u32; 3]> = b
        .faces()
        .iter()
        .filter(|t| {
            t.iter()
                .all(|&v| (y_lo..y_hi).contains(&positions[v as usize].y))
        })
        .copied()
        .collect();
    let region_proximity = MeshProximity::new(&positions, &region).expect("region");
    let topology = MeshTopology::new(positions.len(), &region);
    let distance = BodyDistance::new(&positions, b.faces()).expect("body");
    let normals = vertex_normals(&positions, b.faces());
    // Points beyond the region's cut edges (1 or 3 cm past them along the body, 3 mm or 2 cm
    // off the surface on either side), judged by the exact winding number of the whole body.
    let (mut checked, mut region_wrong) = (0, 0);
    for boundary in topology.boundary_loops() {
        for &v in &boundary {
            let (p, n) = (positions[v as usize], normals[v as usize]);
            let beyond = if p.y > 0.5 * (y_lo + y_hi) { 1.0 } else { -1.0 };
            let along = (Vector3::y() * beyond - n * (n.y * beyond)).normalize();
            for (past, side) in [(0.01, 0.003), (0.01, -0.003), (0.03, 0.02), (0.03, -0.02)] {
                let q = p + along * past + n * side;
                let exact = distance.winding_number_exact(&q);
                if (exact - 0.5).abs() < 0.1 {
                    continue;
                }
                assert_eq!(
                    distance.query(&q).inside(),
                    exact > 0.5,
                    "{q}: exact {exact}"
                );
                checked += 1;
                region_wrong += usize::from(
                    (region_proximity.closest(&q).signed_distance_m < 0.0) != (exact > 0.5),
                );
            }
        }
    }
    println!(
        "{checked} points past the region's cut edges; the region's pseudo-normal gets \
         {region_wrong} wrong"
    );
    assert!(checked > 100, "{checked}");
}
