//! Joint hierarchy, poses and forward kinematics.
//!
//! Convention (as in SMPL): every joint's rest frame is aligned with the world axes, and a pose
//! gives each joint a rotation relative to its parent's frame. The whole body is first rotated by
//! `root_orientation` about the root joint and moved by `root_translation_m`.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::skinning::BoneTransform;
use crate::{Error, Result};

/// Names and parents of the joints. Parents come before children; joint 0 is the only root.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    names: Vec<String>,
    parents: Vec<Option<usize>>,
}

impl Skeleton {
    /// Build a skeleton, checking that names are unique, joint 0 is the one root and every
    /// parent index precedes its child.
    pub fn new(names: Vec<String>, parents: Vec<Option<usize>>) -> Result<Self> {
        if names.len() != parents.len() {
            return Err(Error::invalid(
                "skeleton",
                format!("{} names but {} parents", names.len(), parents.len()),
            ));
        }
        if names.is_empty() {
            return Err(Error::invalid("skeleton", "no joints"));
        }
        for (j, p) in parents.iter().enumerate() {
            match (j, p) {
                (0, None) => {}
                (0, Some(_)) => return Err(Error::invalid("skeleton", "joint 0 must be the root")),
                (_, None) => {
                    return Err(Error::invalid(
                        "skeleton",
                        format!("joint {j} ({}) has no parent", names[j]),
                    ));
                }
                (_, Some(p)) if *p >= j => {
                    return Err(Error::invalid(
                        "skeleton",
                        format!(
                            "joint {j} ({}) has parent {p}, which does not precede it",
                            names[j]
                        ),
                    ));
                }
                _ => {}
            }
        }
        let mut sorted: Vec<&String> = names.iter().collect();
        sorted.sort();
        if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
            return Err(Error::invalid(
                "skeleton",
                format!("joint name {:?} appears twice", w[0]),
            ));
        }
        Ok(Self { names, parents })
    }

    /// Number of joints.
    pub fn n_joints(&self) -> usize {
        self.names.len()
    }

    /// Joint names.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Parent of each joint (`None` for the root).
    pub fn parents(&self) -> &[Option<usize>] {
        &self.parents
    }

    /// Index of a joint by name.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Forward kinematics: for rest joint positions `rest_joints_m` (J(β)) and a pose, write the
    /// posed joint positions and the skinning transform of every joint (posed point = transform ·
    /// rest point). Allocation-free.
    pub fn forward_kinematics_into(
        &self,
        rest_joints_m: &[Vector3<f64>],
        pose: &Pose,
        posed_joints_m: &mut [Vector3<f64>],
        posed_from_rest: &mut [BoneTransform<f64>],
    ) -> Result<()> {
        let n = self.n_joints();
        if rest_joints_m.len() != n || posed_joints_m.len() != n || posed_from_rest.len() != n {
            return Err(Error::invalid(
                "forward kinematics",
                format!(
                    "{n} joints but {} rest joints, {} posed joints, {} transforms",
                    rest_joints_m.len(),
                    posed_joints_m.len(),
                    posed_from_rest.len()
                ),
            ));
        }
        pose.validate(n)?;
        for j in 0..n {
            let local = pose.local_rotations[j].to_rotation_matrix().into_inner();
            let (rot, pos) = match self.parents[j] {
                None => {
                    let r = pose.root_orientation.to_rotation_matrix().into_inner() * local;
                    (r, rest_joints_m[j] + pose.root_translation_m)
                }
                Some(p) => {
                    let parent_rot = posed_from_rest[p].linear;
                    (
                        parent_rot * local,
                        posed_joints_m[p] + parent_rot * (rest_joints_m[j] - rest_joints_m[p]),
                    )
                }
            };
            posed_joints_m[j] = pos;
            posed_from_rest[j] = BoneTransform {
                linear: rot,
                translation: pos - rot * rest_joints_m[j],
            };
        }
        Ok(())
    }

    /// Allocating convenience wrapper of [`Self::forward_kinematics_into`]; returns the posed
    /// joints and the skinning transforms.
    pub fn forward_kinematics(
        &self,
        rest_joints_m: &[Vector3<f64>],
        pose: &Pose,
    ) -> Result<PosedSkeleton> {
        let n = self.n_joints();
        let mut joints = vec![Vector3::zeros(); n];
        let mut transforms = vec![BoneTransform::identity(); n];
        self.forward_kinematics_into(rest_joints_m, pose, &mut joints, &mut transforms)?;
        Ok((joints, transforms))
    }
}

/// Posed joint positions and the skinning transform of every joint.
pub type PosedSkeleton = (Vec<Vector3<f64>>, Vec<BoneTransform<f64>>);

/// One body pose: root motion plus a local rotation per joint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Translation of the root joint from its rest position, in metres (world frame).
    pub root_translation_m: Vector3<f64>,
    /// Rotation of the whole body about the root joint (world frame).
    pub root_orientation: UnitQuaternion<f64>,
    /// Rotation of each joint relative to its parent (for joint 0, relative to
    /// `root_orientation`). One per joint.
    pub local_rotations: Vec<UnitQuaternion<f64>>,
}

impl Pose {
    /// The rest pose of a skeleton with `n_joints` joints.
    pub fn rest(n_joints: usize) -> Self {
        Self {
            root_translation_m: Vector3::zeros(),
            root_orientation: UnitQuaternion::identity(),
            local_rotations: vec![UnitQuaternion::identity(); n_joints],
        }
    }

    /// Check sizes, finiteness and unit norm of every rotation.
    pub fn validate(&self, n_joints: usize) -> Result<()> {
        if self.local_rotations.len() != n_joints {
            return Err(Error::invalid(
                "pose",
                format!(
                    "{} joint rotations for a skeleton of {n_joints} joints",
                    self.local_rotations.len()
                ),
            ));
        }
        if !self.root_translation_m.iter().all(|c| c.is_finite()) {
            return Err(Error::invalid("pose", "root translation is not finite"));
        }
        // `joint`: `None` for the root orientation. The label is formatted only on error: a
        // valid pose is checked without allocating (the runtime validates every frame).
        let check = |q: &UnitQuaternion<f64>, joint: Option<usize>| -> Result<()> {
            let c = q.as_ref().coords;
            let fault = if !c.iter().all(|x| x.is_finite()) {
                "is not finite"
            } else if (c.norm() - 1.0).abs() > 1e-6 {
                "is not a unit quaternion"
            } else {
                return Ok(());
            };
            let what = joint.map_or_else(|| "root".to_string(), |j| format!("joint {j}"));
            Err(Error::invalid("pose", format!("{what} rotation {fault}")))
        };
        check(&self.root_orientation, None)?;
        for (j, q) in self.local_rotations.iter().enumerate() {
            check(q, Some(j))?;
        }
        Ok(())
    }
}

/// The frame rate the simulator, the dataset and the networks use.
pub const FPS: f64 = 30.0;

/// Interpolate two poses: slerp for rotations (shortest arc), lerp for translation.
pub fn interpolate_pose(a: &Pose, b: &Pose, s: f64) -> Pose {
    let slerp = |p: &UnitQuaternion<f64>, q: &UnitQuaternion<f64>| {
        // `try_slerp` fails only for antipodal quaternions, i.e. the same rotation: keep p.
        p.try_slerp(q, s, 1e-12).unwrap_or(*p)
    };
    Pose {
        root_translation_m: a.root_translation_m.lerp(&b.root_translation_m, s),
        root_orientation: slerp(&a.root_orientation, &b.root_orientation),
        local_rotations: a
            .local_rotations
            .iter()
            .zip(&b.local_rotations)
            .map(|(p, q)| slerp(p, q))
            .collect(),
    }
}

/// Split a rotation `q = heading · tilt` into a rotation about +Y (`heading`) and a rotation about
/// a horizontal axis (`tilt`). When `q` turns +Y upside down exactly, the heading is undefined and
/// identity is returned for it.
pub fn split_heading(q: &UnitQuaternion<f64>) -> (UnitQuaternion<f64>, UnitQuaternion<f64>) {
    let c = q.as_ref();
    let norm = (c.w * c.w + c.j * c.j).sqrt();
    if norm < 1e-12 {
        return (UnitQuaternion::identity(), canonical(*q));
    }
    let heading = canonical(UnitQuaternion::new_unchecked(Quaternion::new(
        c.w / norm,
        0.0,
        c.j / norm,
        0.0,
    )));
    let tilt = canonical(heading.inverse() * q);
    (heading, tilt)
}

/// The quaternion with a non-negative scalar part (the same rotation), renormalised, so that
/// outputs are reproducible and interpolate along the short arc.
pub fn canonical(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    let c = q.into_inner();
    let c = if c.w < 0.0 { -c } else { c };
    UnitQuaternion::new_normalize(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain() -> Skeleton {
        Skeleton::new(
            vec!["a".into(), "b".into(), "c".into()],
            vec![None, Some(0), Some(1)],
        )
        .expect("valid")
    }

    #[test]
    fn rejects_bad_skeletons() {
        assert!(Skeleton::new(vec!["a".into(), "b".into()], vec![None, Some(1)]).is_err());
        assert!(Skeleton::new(vec!["a".into(), "a".into()], vec![None, Some(0)]).is_err());
        assert!(Skeleton::new(vec!["a".into(), "b".into()], vec![None, None]).is_err());
    }

    #[test]
    fn elbow_bend_moves_child() {
        let s = chain();
        let rest = vec![Vector3::zeros(), Vector3::x(), 2.0 * Vector3::x()];
        let mut pose = Pose::rest(3);
        pose.local_rotations[1] =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let (joints, t) = s.forward_kinematics(&rest, &pose).expect("fk");
        assert!((joints[2] - Vector3::new(1.0, 1.0, 0.0)).norm() < 1e-12);
        assert!((t[1].apply(&rest[1]) - joints[1]).norm() < 1e-12);
        assert!((t[2].apply(&rest[2]) - joints[2]).norm() < 1e-12);
    }

    #[test]
    fn non_finite_pose_is_an_error() {
        let s = chain();
        let rest = vec![Vector3::zeros(), Vector3::x(), 2.0 * Vector3::x()];
        let mut pose = Pose::rest(3);
        pose.root_translation_m.y = f64::INFINITY;
        assert!(s.forward_kinematics(&rest, &pose).is_err());
        let mut pose = Pose::rest(3);
        pose.local_rotations[2] =
            UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(f64::NAN, 0.0, 0.0, 0.0));
        assert!(s.forward_kinematics(&rest, &pose).is_err());
        assert!(s.forward_kinematics(&rest, &Pose::rest(2)).is_err());
    }
}
