//! AMASS retargeting against SMPL's own forward kinematics, computed here independently: a
//! synthetic SMPL-H file (the layout `sartor_motion::AmassData` reads) with random poses over a
//! made-up SMPL rest pose whose thighs splay outwards like CMU's, so that taking SMPL's rest for
//! our T-pose would show.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use sartor_motion::{
    AmassData, AmassOptions, POSTURE_BONES, SMPL_BODY_PARENTS, SMPL_TO_RIG, UpAxis,
    retarget_amass_native_rate, world_rotations,
};

use crate::motion_sources::rng;
use crate::motion_sources::{posed_joints, synthetic_body, write_npz};

/// A made-up SMPL rest (metres, Y up, +X the body's left): thighs 15° outwards, shins back
/// towards the vertical, arms horizontal with the elbows 10° forward, a leaning spine.
fn smpl_rest() -> Vec<Vector3<f64>> {
    let mut p = vec![Vector3::zeros(); 22];
    let s15 = 15f64.to_radians().sin();
    let c15 = 15f64.to_radians().cos();
    p[0] = Vector3::new(0.0, 0.93, 0.0);
    p[3] = Vector3::new(0.0, 1.03, -0.02);
    p[6] = Vector3::new(0.0, 1.16, 0.0);
    p[9] = Vector3::new(0.0, 1.22, 0.02);
    p[12] = Vector3::new(0.0, 1.44, -0.01);
    p[15] = Vector3::new(0.0, 1.52, 0.04);
    for (side, sx) in [(0usize, 1.0), (1, -1.0)] {
        let hip = Vector3::new(0.07 * sx, 0.84, 0.0);
        let knee = hip + 0.40 * Vector3::new(s15 * sx, -c15, 0.0);
        let ankle = knee + Vector3::new(-0.02 * sx, -0.40, -0.02);
        let toe = ankle + Vector3::new(0.01 * sx, -0.05, 0.12);
        p[1 + side] = hip;
        p[4 + side] = knee;
        p[7 + side] = ankle;
        p[10 + side] = toe;
        let collar = Vector3::new(0.08 * sx, 1.36, 0.0);
        let shoulder = collar + Vector3::new(0.10 * sx, 0.01, -0.01);
        let elbow = shoulder + Vector3::new(0.26 * sx, 0.0, 0.0);
        let wrist = elbow
            + 0.25 * Vector3::new(10f64.to_radians().cos() * sx, 0.0, 10f64.to_radians().sin());
        p[13 + side] = collar;
        p[16 + side] = shoulder;
        p[18 + side] = elbow;
        p[20 + side] = wrist;
    }
    p
}

/// Rodrigues: the rotation matrix of an axis-angle vector.
fn rodrigues(v: &Vector3<f64>) -> Matrix3<f64> {
    let a = v.norm();
    if a < 1e-15 {
        return Matrix3::identity();
    }
    let k = v / a;
    let kx = Matrix3::new(0.0, -k.z, k.y, k.z, 0.0, -k.x, -k.y, k.x, 0.0);
    Matrix3::identity() + a.sin() * kx + (1.0 - a.cos()) * kx * kx
}

/// SMPL forward kinematics of one frame (world positions and rotations of the 22 body joints).
fn smpl_fk(
    rest: &[Vector3<f64>],
    pose: &[Vector3<f64>],
    trans: &Vector3<f64>,
) -> (Vec<Vector3<f64>>, Vec<Matrix3<f64>>) {
    let mut p = Vec::with_capacity(22);
    let mut r: Vec<Matrix3<f64>> = Vec::with_capacity(22);
    for j in 0..22 {
        let local = rodrigues(&pose[j]);
        match SMPL_BODY_PARENTS[j] {
            None => {
                p.push(rest[j] + trans);
                r.push(local);
            }
            Some(q) => {
                p.push(p[q] + r[q] * (rest[j] - rest[q]));
                r.push(r[q] * local);
            }
        }
    }
    (p, r)
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.normalize()
        .dot(&b.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// The worst angle between our posture bones and SMPL's (and our pelvis' and SMPL's) over the
/// frames, for a file written with `up` (`to_file` turns SMPL's axes into the file's).
fn worst_angles(options: &AmassOptions, to_file: Matrix3<f64>, path: &Path) -> (f64, f64) {
    let body = synthetic_body();
    let s = body.skeleton();
    let rest = smpl_rest();
    let n_frames = 6;
    let mut r = rng(16);
    let mut poses = Vec::new();
    let mut trans = Vec::new();
    let mut frames = Vec::new();
    for f in 0..n_frames {
        let pose: Vec<Vector3<f64>> = (0..52)
            .map(|j| {
                let amp = if j == 0 { 1.5 } else { 0.7 };
                Vector3::new(
                    r.random_range(-amp..amp),
                    r.random_range(-amp..amp),
                    r.random_range(-amp..amp),
                )
            })
            .collect();
        let t = Vector3::new(0.1 * f as f64, 0.9, -0.05 * f as f64);
        frames.push((pose.clone(), t));
        // Stored in the file's axes: the root rotation and the translation turned by to_file.
        let mut stored = pose.clone();
        let root = nalgebra::Rotation3::from_matrix_unchecked(to_file * rodrigues(&pose[0]));
        stored[0] = root.scaled_axis();
        poses.extend(stored.iter().flat_map(|v| [v.x, v.y, v.z]));
        let tf = to_file * t;
        trans.extend([tf.x, tf.y, tf.z]);
    }
    write_npz(
        path,
        &[
            ("poses", vec![n_frames as u64, 156], poses),
            ("trans", vec![n_frames as u64, 3], trans),
            ("mocap_framerate", vec![], vec![120.0]),
        ],
    );
    let data = AmassData::read(path).expect("read");
    let m = retarget_amass_native_rate(&data, "synthetic", &body, options).expect("retarget");
    let smpl_of = |rig: &str| SMPL_TO_RIG.iter().position(|(_, _, r)| *r == rig);
    let (mut bones, mut pelvis): (f64, f64) = (0.0, 0.0);
    let mut compared = 0;
    for (pose, (smpl_pose, t)) in m.frames().iter().zip(&frames) {
        let (p, rot) = smpl_fk(&rest, smpl_pose, t);
        let ours = posed_joints(&body, pose);
        for (j, c) in POSTURE_BONES {
            let (Some(sj), Some(sc)) = (smpl_of(j), smpl_of(c)) else {
                continue;
            };
            if SMPL_BODY_PARENTS[sc] != Some(sj) {
                continue;
            }
            let (rj, rc) = (s.index_of(j).expect(j), s.index_of(c).expect(c));
            bones = bones.max(angle_deg(&(ours[rc] - ours[rj]), &(p[sc] - p[sj])));
            compared += 1;
        }
        let g = world_rotations(s, pose)[0]
            .to_rotation_matrix()
            .into_inner();
        let rel = nalgebra::Rotation3::from_matrix_unchecked(g.transpose() * rot[0]);
        pelvis = pelvis.max(rel.angle().to_degrees());
    }
    assert_eq!(
        compared,
        13 * n_frames,
        "13 posture bones have an SMPL counterpart"
    );
    (bones, pelvis)
}

#[test]
fn amass_bones_point_where_smpls_own_fk_puts_them() {
    let dir = tempfile::tempdir().expect("tmp");
    let with_rest = AmassOptions {
        rest_joints: Some(smpl_rest()),
        ..AmassOptions::default()
    };
    let (bones, pelvis) = worst_angles(&with_rest, Matrix3::identity(), &dir.path().join("y.npz"));
    assert!(
        bones < 1e-4 && pelvis < 1e-4,
        "bones {bones}°, pelvis {pelvis}°"
    );
    // Z-up files (AMASS style): the same motion, the same angles.
    let to_z = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 90f64.to_radians());
    let z_up = AmassOptions {
        up_axis: UpAxis::Z,
        ..with_rest.clone()
    };
    let (bones, pelvis) = worst_angles(&z_up, *to_z.matrix(), &dir.path().join("z.npz"));
    assert!(
        bones < 1e-4 && pelvis < 1e-4,
        "Z-up: bones {bones}°, pelvis {pelvis}°"
    );
    // Without the rest joints SMPL's rest is taken for our T-pose, which does not splay the
    // thighs: the legs are off by about the splay, and this check sees it.
    let (bones, _) = worst_angles(
        &AmassOptions::default(),
        Matrix3::identity(),
        &dir.path().join("t.npz"),
    );
    println!("SMPL rest taken for our T-pose: posture bones up to {bones:.1}° off");
    assert!(bones > 10.0, "bones {bones}°");
}
