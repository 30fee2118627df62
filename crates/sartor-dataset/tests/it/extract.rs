//! Ground-truth extraction: the round trip through skinning, and the joint selection.

use nalgebra::{UnitQuaternion, Vector3};
use sartor_core::{Parallelism, Pose, skin_points};
use sartor_dataset::{Smoother, Smoothing, WrinkleExtractor, fit_delta, select_joints};
use sartor_motion::procedural;

use crate::common::{bind, body, tiny_tshirt};

/// A smooth known field, up to `amplitude_m` per component.
fn field(p: &Vector3<f64>, amplitude_m: f64, phase: f64) -> Vector3<f64> {
    Vector3::new(
        (7.0 * p.y + phase).sin(),
        (5.0 * p.x - phase).cos(),
        (9.0 * p.z + 2.0 * p.y).sin(),
    ) * amplitude_m
}

#[test]
fn displacements_survive_skinning_and_inverse_skinning() {
    let body = body();
    let garment = tiny_tshirt();
    let smoother =
        Smoother::new(garment.positions(), garment.faces(), Smoothing::default()).expect("valid");
    let binding = bind(&body, &garment, &smoother);
    let betas = [1.5, -0.8, 0.4, 1.0, 0.0, -0.3, 0.0, 0.2, 0.0, 0.0];
    // A known Δ_G (as stored: f32) and a known Δ_L.
    let template: Vec<Vector3<f64>> = binding.template().iter().map(|p| p.cast()).collect();
    let delta_g: Vec<f32> = template
        .iter()
        .flat_map(|p| {
            let f = field(p, 0.03, 0.3);
            [f.x as f32, f.y as f32, f.z as f32]
        })
        .collect();
    let delta_l: Vec<Vector3<f64>> = template.iter().map(|p| field(p, 0.02, 1.1)).collect();
    // Poses: frames of a procedural clip, one with a 170° elbow bend, root moved and turned.
    let clip = procedural::clip(&procedural::clip_names()[0]).expect("clip exists");
    let mut poses: Vec<Pose> = clip.frames().iter().step_by(17).take(4).cloned().collect();
    let mut bent = poses[0].clone();
    let elbow = body
        .skeleton()
        .index_of("LeftForeArm")
        .expect("joint exists");
    bent.local_rotations[elbow] =
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 170f64.to_radians());
    bent.root_translation_m += Vector3::new(0.3, 0.1, -2.0);
    bent.root_orientation = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 2.5);
    poses.push(bent);

    let joints = body.shaped_joints(&betas).expect("valid betas");
    let mut extractor = WrinkleExtractor::new(&body, &binding, &betas, &delta_g).expect("valid");
    let rest: Vec<Vector3<f64>> = (0..binding.n_vertices())
        .map(|v| {
            let g = Vector3::new(
                delta_g[3 * v] as f64,
                delta_g[3 * v + 1] as f64,
                delta_g[3 * v + 2] as f64,
            );
            template[v] + g + delta_l[v]
        })
        .collect();
    let mut worst = 0.0f64;
    for pose in &poses {
        let (_, transforms) = body
            .skeleton()
            .forward_kinematics(&joints, pose)
            .expect("valid pose");
        let mut posed = vec![Vector3::zeros(); rest.len()];
        skin_points(
            &rest,
            binding.skin_weights(),
            &transforms,
            &mut posed,
            Parallelism::Sequential,
        )
        .expect("sizes match");
        let mut out = Vec::new();
        extractor
            .push_frame(pose, &posed, &mut out)
            .expect("invertible");
        for (v, d) in delta_l.iter().enumerate() {
            let got = Vector3::new(
                out[3 * v] as f64,
                out[3 * v + 1] as f64,
                out[3 * v + 2] as f64,
            );
            worst = worst.max((got - d).norm());
        }
    }
    assert!(worst < 1e-5, "largest recovery error {worst} m");
}

#[test]
fn fit_delta_of_the_template_itself_is_small_and_sizes_are_checked() {
    let body = body();
    let garment = tiny_tshirt();
    let smoother =
        Smoother::new(garment.positions(), garment.faces(), Smoothing::default()).expect("valid");
    let binding = bind(&body, &garment, &smoother);
    // ρ(relaxed) − T̄_c is T̄_c's f32 rounding only: the shape simulated at β = 0 is the
    // template, and the stored T̄_c plus Δ_G gives ρ(relaxed) back.
    let relaxed = garment.positions();
    let exact = smoother.apply(relaxed).expect("valid");
    let zero = fit_delta(&binding, &smoother, relaxed).expect("valid");
    for (v, (e, t)) in exact.iter().zip(binding.template()).enumerate() {
        for c in 0..3 {
            let d = f64::from(zero[3 * v + c]);
            assert!(d.abs() <= 1e-7, "vertex {v}: Δ_G {d} at β = 0");
            assert!((f64::from(t[c]) + d - e[c]).abs() <= 1e-12, "vertex {v}");
        }
    }
    // A translated garment gives the translation (ρ commutes with translations).
    let moved: Vec<Vector3<f64>> = relaxed
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.01, 0.002))
        .collect();
    let d = fit_delta(&binding, &smoother, &moved).expect("valid");
    for v in 0..binding.n_vertices() {
        assert!((d[3 * v + 1] - 0.01).abs() < 1e-6 && (d[3 * v + 2] - 0.002).abs() < 1e-6);
    }
    assert!(fit_delta(&binding, &smoother, &moved[1..]).is_err());
    assert!(WrinkleExtractor::new(&body, &binding, &[0.0; 10], &d[3..]).is_err());
    // ρ smooths: the template is not the relaxed garment (wrinkles removed), but close to it.
    let max_change = relaxed
        .iter()
        .zip(binding.template())
        .map(|(a, b)| (a - b.cast::<f64>()).norm())
        .fold(0.0, f64::max);
    assert!(
        max_change > 0.0 && max_change < 0.02,
        "ρ moved a vertex by {max_change} m"
    );
}

#[test]
fn the_network_sees_the_upper_body_joints_only() {
    let body = body();
    let garment = tiny_tshirt();
    let smoother =
        Smoother::new(garment.positions(), garment.faces(), Smoothing::default()).expect("valid");
    let binding = bind(&body, &garment, &smoother);
    let joints = select_joints(&body, binding.skin_weights(), 0.1);
    let has = |n: &str| joints.iter().any(|j| j == n);
    assert!(
        has("Hips") && has("Spine") && has("LeftArm") && has("RightArm"),
        "{joints:?}"
    );
    assert!(
        !has("LeftFoot") && !has("RightLeg") && !has("Head"),
        "{joints:?}"
    );
}
