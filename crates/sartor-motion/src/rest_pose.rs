//! The rest-pose change between a motion source and our body.
//!
//! A mocap joint's rotation `Q_j` (world frame, relative to the source's rest) means "bone `j`
//! is turned by `Q_j` from where it lies in the **source's** rest pose". Our rest is an A-pose;
//! the source's rest is whatever its skeleton's offsets describe: a T-pose for SMPL, and for
//! the CMU BVH conversion a pose with the arms horizontal and the thighs pointing down *and
//! outwards* (about 20°). Retargeting therefore needs, per rig joint, the world rotation `C_j`
//! that takes our rest bone to where the source's rest has it; then `G_j = Q_j · C_j` puts
//! our bone where the source's bone is in every frame.
//!
//! # How `C_j` is built ([`RetargetBody::rest_change`])
//!
//! Joints in skeleton order, `C_parent` first (`C_root` = identity: both rests stand upright
//! facing +Z, so the pelvis orientation is taken as is):
//!
//! - a **posture bone** ([`POSTURE_BONES`]: joint `j` and its direction child `c`) whose
//!   direction the source gives (`v_j`, the source's rest direction of the same bone) is
//!   turned by the smallest rotation that takes it from where its parent's change left it onto
//!   the source's: `C_j = swing(C_parent · u_j → v_j) · C_parent`, `u_j` our rest direction
//!   `J_c − J_j`. Its world direction then equals the source's in every frame.
//! - every other joint keeps its rest relation to its parent: `C_j = C_parent`. These are the
//!   **proportion bones**, where the two skeletons put their joint centres differently inside
//!   the body and turning ours to match would deform our body rather than pose it:
//!   - the hip sockets (`LHipJoint`/`RHipJoint` → `*UpLeg`) and the collars (`LeftShoulder`/
//!     `RightShoulder` → `*Arm`): fixed offsets in CMU's skeleton (their channels are zero in
//!     every frame of all 60 clips), 41–51° (hip sockets) and 17–34° (collars) from ours,
//!     depending on the subject; matching them would move our hip sockets by about 7 cm and
//!     shrug our shoulders by about 6 cm;
//!   - the skull base (`Neck1` → `Head`): 15–40° from ours depending on the subject (41° at
//!     rest and 36° between the two T-poses for subject 07), so not a posture either; matching
//!     it would tilt the head back by as much.
//!
//!   (Ranges: `worst_angle_to_file_bone_deg` of `cargo xtask check-retarget` over the 60 CMU
//!   clips.)
//!
//!   Also joints whose source bone has zero length (CMU's `Hips`, `Spine1` and `LeftHand`
//!   children start where their parent does) and leaves (`Head`, toes, finger tips, thumbs).
//!
//! A proportion bone still turns with its source joint (`G_j = Q_j · C_j`): its direction keeps
//! a constant angle to the source's (the proportion difference), checked by
//! [`crate::check_bvh_retarget`].

use nalgebra::{Unit, UnitQuaternion, Vector3};

use crate::retarget::{RetargetBody, hip_height, pose_from_world};
use crate::{Error, Result};

/// The rig's posture bones: `(joint, direction child)`. A source's rest direction of these bones
/// is a posture (arms horizontal or down, splayed thighs, bent elbows, a lean), which the
/// rest-pose change turns ours into; every other bone is a proportion and keeps our rest
/// relation to its parent (see the module docs).
pub const POSTURE_BONES: [(&str, &str); 18] = [
    ("LeftUpLeg", "LeftLeg"),
    ("LeftLeg", "LeftFoot"),
    ("LeftFoot", "LeftToeBase"),
    ("RightUpLeg", "RightLeg"),
    ("RightLeg", "RightFoot"),
    ("RightFoot", "RightToeBase"),
    ("LowerBack", "Spine"),
    ("Spine", "Spine1"),
    ("Spine1", "Neck"),
    ("Neck", "Neck1"),
    ("LeftArm", "LeftForeArm"),
    ("LeftForeArm", "LeftHand"),
    ("LeftHand", "LeftFingerBase"),
    ("LeftFingerBase", "LeftHandFinger1"),
    ("RightArm", "RightForeArm"),
    ("RightForeArm", "RightHand"),
    ("RightHand", "RightFingerBase"),
    ("RightFingerBase", "RightHandFinger1"),
];

/// A motion source's rest pose, as rest bone directions per rig joint: for rig joint `j`, the
/// source's rest direction (world axes, any length) of the bone from `j` to `j`'s direction child
/// in [`POSTURE_BONES`], when the source has that bone with a non-zero length.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceRest {
    directions: Vec<Option<Vector3<f64>>>,
}

impl SourceRest {
    /// From per-rig-joint rest directions (`None`: the source does not give that bone). Zero
    /// vectors count as `None`; non-finite ones are an error.
    pub fn new(directions: Vec<Option<Vector3<f64>>>) -> Result<Self> {
        let mut out = Vec::with_capacity(directions.len());
        for (j, d) in directions.into_iter().enumerate() {
            match d {
                Some(v) if !v.iter().all(|c| c.is_finite()) => {
                    return Err(Error::invalid(
                        "source rest",
                        format!("joint {j}: direction {v:?} is not finite"),
                    ));
                }
                Some(v) => out.push(v.try_normalize(1e-9)),
                None => out.push(None),
            }
        }
        Ok(Self { directions: out })
    }

    /// From source rest joint positions mapped onto the rig: `positions[j]` is the rest position
    /// of the source joint driving rig joint `j` (`None`: not driven). A posture bone `(j, c)`
    /// gets the direction `positions[c] − positions[j]` when both are given and
    /// `source_parent_of(c)` says the source joint of `c` is a direct child of the source joint
    /// of `j` (so the source bone turns rigidly with joint `j`).
    pub fn from_positions(
        names: &[String],
        positions: &[Option<Vector3<f64>>],
        is_direct_child: impl Fn(usize, usize) -> bool,
    ) -> Result<Self> {
        let find = |n: &str| names.iter().position(|x| x == n);
        let mut directions = vec![None; names.len()];
        for (joint, child) in POSTURE_BONES {
            let (Some(j), Some(c)) = (find(joint), find(child)) else {
                continue;
            };
            if let (Some(a), Some(b)) = (positions.get(j), positions.get(c))
                && let (Some(a), Some(b)) = (a, b)
                && is_direct_child(j, c)
            {
                directions[j] = Some(b - a);
            }
        }
        Self::new(directions)
    }

    /// The source's rest direction of each rig joint's posture bone (unit length).
    pub fn directions(&self) -> &[Option<Vector3<f64>>] {
        &self.directions
    }
}

/// The smallest rotation taking unit vector `from` onto unit vector `to` (for opposite vectors,
/// a half turn about an axis perpendicular to `from`).
pub(crate) fn swing(from: &Vector3<f64>, to: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(from, to).unwrap_or_else(|| {
        let axis = if from.x.abs() < 0.9 {
            from.cross(&Vector3::x())
        } else {
            from.cross(&Vector3::y())
        };
        UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), std::f64::consts::PI)
    })
}

impl RetargetBody {
    /// `C_j` for every rig joint: the world rotation from our rest bone to the source's rest
    /// (see the module docs). `source` must have one entry per rig joint.
    pub fn rest_change(&self, source: &SourceRest) -> Result<Vec<UnitQuaternion<f64>>> {
        let skeleton = self.skeleton();
        let n = skeleton.n_joints();
        if source.directions.len() != n {
            return Err(Error::invalid(
                "source rest",
                format!("{} directions for {n} joints", source.directions.len()),
            ));
        }
        let rest = self.rest_joints_m();
        let names = skeleton.names();
        let direction_child = |j: usize| {
            POSTURE_BONES
                .iter()
                .find(|(a, _)| *a == names[j])
                .and_then(|(_, c)| skeleton.index_of(c))
        };
        let mut c: Vec<UnitQuaternion<f64>> = Vec::with_capacity(n);
        for j in 0..n {
            let parent = skeleton.parents()[j].map_or_else(UnitQuaternion::identity, |p| c[p]);
            let turned = match (direction_child(j), source.directions[j]) {
                (Some(k), Some(v)) => match (rest[k] - rest[j]).try_normalize(1e-9) {
                    Some(u) => swing(&(parent * u), &v) * parent,
                    None => parent,
                },
                _ => parent,
            };
            c.push(turned);
        }
        Ok(c)
    }

    /// Our hip height (metres, as [`Self::hip_height_m`]) with every joint at the world rotation
    /// `world` (e.g. a [`Self::rest_change`]: our body in a source's rest posture).
    pub fn hip_height_in_m(&self, world: &[UnitQuaternion<f64>]) -> Result<f64> {
        let pose = pose_from_world(self.skeleton(), world, Vector3::zeros());
        let (joints, _) = self
            .skeleton()
            .forward_kinematics(self.rest_joints_m(), &pose)?;
        Ok(hip_height(self.skeleton().names(), &joints))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn posture_bones_are_rig_bones() {
        let s = crate::cmu_mb_skeleton();
        for (j, c) in POSTURE_BONES {
            let (j, c) = (s.index_of(j).expect(j), s.index_of(c).expect(c));
            assert_eq!(s.parents()[c], Some(j));
        }
    }

    #[test]
    fn swing_handles_opposite_vectors() {
        let x = Vector3::x();
        let q = swing(&x, &-x);
        assert!((q * x + x).norm() < 1e-12);
        let y = Vector3::y();
        let q = swing(&y, &x);
        assert!((q * y - x).norm() < 1e-12);
        assert!((q.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }
}
