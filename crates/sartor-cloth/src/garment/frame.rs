//! Material frames of garments worn on the body.
//!
//! Convention (documented in every saved garment's header): per triangle, `u` and `v` are
//! unit, orthonormal, in the triangle's plane, with `u × v` the outward normal `n`.
//!
//! - Torso: `v` is the world up direction (+Y) projected onto the triangle: the grain line of
//!   a T-shirt's front and back panels. Where the surface is nearly horizontal (the projection
//!   is shorter than 0.3, on top of the shoulders), `v` is the direction over the shoulder
//!   towards the body's mid-plane (−Z in front of it, +Z behind it), which is where the up
//!   direction of a flat front or back panel points once sewn over the shoulder. `u = v × n`
//!   runs around the body (towards the body's left on the front).
//! - Sleeves (triangles whose closest body point is skinned mostly — weight above ½ — to an
//!   arm bone or its descendants): `v` runs along the upper-arm bone from the elbow to the
//!   shoulder (the grain line of a sleeve pattern), `u = v × n` around the arm.
//!
//! Without a body, every triangle follows the torso rule with the mid-plane at the mesh's
//! bounding-box centre.

use nalgebra::Vector3;
use sartor_core::{BodyModel, MeshProximity, TriMesh};

use crate::{Error, Result};

/// Shortest projected up vector (relative to unit length) used before switching to the
/// over-the-shoulder direction.
const MIN_PROJECTION: f64 = 0.3;

/// The joints of one arm: the upper-arm bone's two ends and, per body vertex, the skin weight
/// of the arm bone and its descendants.
#[derive(Clone, Debug)]
pub(crate) struct Arm {
    /// Shoulder joint position (the upper-arm bone's head), m.
    pub shoulder: Vector3<f64>,
    /// Elbow joint position (the upper-arm bone's tail), m.
    pub elbow: Vector3<f64>,
    /// Per body vertex, the summed weight of the arm chain.
    pub weight: Vec<f64>,
}

/// Both arms of a body whose skeleton names its joints like the CMU rig (`LeftArm`,
/// `LeftForeArm`, `RightArm`, `RightForeArm`).
pub(crate) fn body_arms(body: &BodyModel) -> Result<[Arm; 2]> {
    let skeleton = body.skeleton();
    let joints = body.joint_template();
    let index = |name: &str| {
        skeleton.index_of(name).ok_or_else(|| {
            Error::invalid(
                "body model",
                format!("no joint named {name:?} (needed to find the arms)"),
            )
        })
    };
    let arm = |upper: &str, lower: &str| -> Result<Arm> {
        let (a, b) = (index(upper)?, index(lower)?);
        let parents = skeleton.parents();
        // A joint is in the chain if `a` is among its ancestors or itself.
        let in_chain: Vec<bool> = (0..skeleton.n_joints())
            .map(|mut j| {
                loop {
                    if j == a {
                        break true;
                    }
                    match parents[j] {
                        Some(p) => j = p,
                        None => break false,
                    }
                }
            })
            .collect();
        let sw = body.skin_weights();
        let weight = (0..body.n_vertices())
            .map(|v| {
                sw.point(v)
                    .filter(|(j, _)| in_chain[*j])
                    .map(|(_, w)| w as f64)
                    .sum()
            })
            .collect();
        Ok(Arm {
            shoulder: joints[a],
            elbow: joints[b],
            weight,
        })
    };
    Ok([
        arm("LeftArm", "LeftForeArm")?,
        arm("RightArm", "RightForeArm")?,
    ])
}

/// The in-plane unit direction of `g` on a plane of unit normal `n`, if the projection is
/// at least `MIN_PROJECTION` long (`g` unit).
fn project(g: &Vector3<f64>, n: &Vector3<f64>) -> Option<Vector3<f64>> {
    let p = g - n * n.dot(g);
    (p.norm() >= MIN_PROJECTION).then(|| p.normalize())
}

/// The torso rule's `v` for a triangle of unit normal `n` and centroid `c`.
fn torso_v(n: &Vector3<f64>, c: &Vector3<f64>, mid_z: f64) -> Vector3<f64> {
    project(&Vector3::y(), n).unwrap_or_else(|| {
        let towards_mid = if c.z >= mid_z {
            -Vector3::z()
        } else {
            Vector3::z()
        };
        // The normal is within ~17° of ±Y here, so ±Z projects to at least 0.95.
        (towards_mid - n * n.dot(&towards_mid)).normalize()
    })
}

/// Per triangle, the material u axis of a garment worn on `body` (or, without a body, with
/// the torso rule everywhere), following the convention in the module docs.
pub fn material_u_axes(mesh: &TriMesh, body: Option<&BodyModel>) -> Result<Vec<Vector3<f64>>> {
    let p = mesh.positions();
    let guide = match body {
        Some(body) => {
            let arms = body_arms(body)?;
            let proximity = MeshProximity::new(body.template().positions(), body.faces())?;
            let spine = body
                .skeleton()
                .index_of("Spine1")
                .map(|j| body.joint_template()[j].z);
            Some((arms, proximity, body.faces().to_vec(), spine))
        }
        None => None,
    };
    let mid_z = match &guide {
        Some((_, _, _, Some(z))) => *z,
        _ => mesh.bounds().map_or(0.0, |(lo, hi)| 0.5 * (lo.z + hi.z)),
    };
    let mut axes = Vec::with_capacity(mesh.n_faces());
    for t in mesh.faces() {
        let x = t.map(|i| p[i as usize]);
        let n = (x[1] - x[0]).cross(&(x[2] - x[0])).normalize();
        let c = (x[0] + x[1] + x[2]) / 3.0;
        let mut v = None;
        if let Some((arms, proximity, faces, _)) = &guide {
            let hit = proximity.closest(&c);
            let corners = faces[hit.face as usize];
            for arm in arms {
                let w: f64 = (0..3)
                    .map(|k| hit.barycentric[k] * arm.weight[corners[k] as usize])
                    .sum();
                if w > 0.5 {
                    let along = (arm.shoulder - arm.elbow).normalize();
                    v = project(&along, &n);
                }
            }
        }
        let v = v.unwrap_or_else(|| torso_v(&n, &c, mid_z));
        axes.push(v.cross(&n));
    }
    Ok(axes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn torso_rule_on_a_vertical_cylinder() {
        // A tube around +Y: u must be horizontal and circulate consistently, v = +Y.
        let n = 16;
        let mut positions = Vec::new();
        for j in 0..2 {
            for i in 0..n {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                positions.push(Vector3::new(a.sin(), j as f64, a.cos()));
            }
        }
        let mut faces = Vec::new();
        for i in 0..n as u32 {
            let k = (i + 1) % n as u32;
            faces.push([i, k, k + n as u32]);
            faces.push([i, k + n as u32, i + n as u32]);
        }
        let mesh = TriMesh::new(positions, faces).unwrap();
        let normals = mesh.face_normals();
        // Normals point outwards.
        assert!(normals[0].dot(&Vector3::new(0.2, 0.0, 1.0)) > 0.0);
        let axes = material_u_axes(&mesh, None).unwrap();
        for (u, n) in axes.iter().zip(&normals) {
            assert!(u.y.abs() < 1e-12);
            assert!((u.norm() - 1.0).abs() < 1e-12);
            let v = n.cross(u);
            assert!((v - Vector3::y()).norm() < 1e-12, "{v:?}");
        }
        // On the front (n = +Z) u points to the body's left (+X).
        assert!(axes[0].x > 0.9);
    }

    #[test]
    fn horizontal_triangles_point_over_the_shoulder() {
        let n = Vector3::y();
        assert_eq!(
            torso_v(&n, &Vector3::new(0.0, 1.5, 0.1), 0.0),
            -Vector3::z()
        );
        assert_eq!(
            torso_v(&n, &Vector3::new(0.0, 1.5, -0.1), 0.0),
            Vector3::z()
        );
    }
}
