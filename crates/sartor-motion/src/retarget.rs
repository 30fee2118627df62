//! The one retargeting rule every motion source shares.
//!
//! Sources: the procedural library ([`crate::procedural`]), the imported MakeHuman walk cycle
//! (`datasets/motions/walk.json`, made by sartor-import), CMU-style BVH files
//! ([`crate::bvh`]) and AMASS-style `.npz` files ([`crate::amass`]). [`crate::load_motion`]
//! picks one from a command-line string.
//!
//! # Conventions every source follows
//!
//! - Skeleton: the built-in 31-joint `cmu_mb` rig ([`crate::cmu_mb_skeleton`]), 30 fps
//!   ([`crate::FPS`]) after resampling.
//! - The root's world rotation is split in two: `root_orientation` holds the **heading** (the
//!   rotation about +Y) and `local_rotations[0]` the rest of the pelvis orientation (tilt and
//!   roll, a rotation about a horizontal axis). Their product is the pelvis' world rotation.
//! - `root_translation_m` is the pelvis' displacement from its rest position; imported motions
//!   start at the origin horizontally (the first frame's horizontal position is subtracted).
//!
//! # World-orientation retargeting
//!
//! Mocap rotations (BVH, SMPL/AMASS) are relative to the **source's rest pose** (all rotations
//! zero), ours to our **A-pose**. Both use world-aligned rest frames (a joint's rotation is
//! expressed in world axes, relative to its parent), so the difference is one rotation per
//! bone: `C_j`, the world rotation that takes our rest bone `j` to where the source's rest pose
//! has it ([`RetargetBody::rest_change`], built from the source's own rest bone directions, see
//! [`crate::POSTURE_BONES`]). With `Q_j` the source's world rotation of bone `j` (identity at its
//! rest), our world rotation is `G_j = Q_j · C_j` and our local rotation
//! `θ_j = G_parent⁻¹ · G_j`. A rig joint the source does not drive takes its parent's `Q` (it
//! keeps its rest-change relation to its parent). A source that gives no rest directions (an
//! AMASS file without its SMPL rest joints) is taken to rest in our T-pose: `C_j` = the
//! T-pose's world rotations.
//!
//! The source's rest is **not** assumed to be a T-pose: the CMU BVH conversion's rest has the
//! thighs about 20° outwards (its T-pose is frame 0, made by rotations), and taking it for a
//! T-pose turned our thighs 20° inwards in every frame — knees together, feet apart.

use std::path::Path;

use nalgebra::{UnitQuaternion, Vector3};
use sartor_core::io::read_file;
use sartor_core::{BodyModel, Pose, Skeleton, canonical, split_heading};

use crate::{Error, Result};

/// File name of the T-pose inside a body model's folder (written by the MakeHuman importer).
pub const TPOSE_FILE: &str = "tpose.json";

/// Load `tpose.json` from a body model folder: the pose that turns the A-pose rest into a
/// T-pose (arms horizontal).
pub fn load_tpose(dir: &Path) -> Result<Pose> {
    let path = dir.join(TPOSE_FILE);
    let pose: Pose = serde_json::from_slice(&read_file(&path)?)
        .map_err(|e| Error::parse(&path, e.line(), e.to_string()))?;
    pose.validate(crate::CMU_MB_JOINTS.len())
        .map_err(|e| e.in_file(&path))?;
    Ok(pose)
}

/// The body a mocap motion is retargeted onto: its skeleton, rest joints and T-pose.
#[derive(Clone, Debug, PartialEq)]
pub struct RetargetBody {
    skeleton: Skeleton,
    rest_joints_m: Vec<Vector3<f64>>,
    tpose: Pose,
    /// `C_j`: world rotation of every joint in the T-pose.
    tpose_world: Vec<UnitQuaternion<f64>>,
}

impl RetargetBody {
    /// Check sizes and the T-pose, and precompute the T-pose's world rotations.
    pub fn new(skeleton: Skeleton, rest_joints_m: Vec<Vector3<f64>>, tpose: Pose) -> Result<Self> {
        let n = skeleton.n_joints();
        if rest_joints_m.len() != n {
            return Err(Error::invalid(
                "retarget body",
                format!("{} rest joints for {n} joints", rest_joints_m.len()),
            ));
        }
        if !rest_joints_m
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite()))
        {
            return Err(Error::invalid("retarget body", "non-finite rest joint"));
        }
        tpose.validate(n)?;
        let tpose_world = world_rotations(&skeleton, &tpose);
        Ok(Self {
            skeleton,
            rest_joints_m,
            tpose,
            tpose_world,
        })
    }

    /// Load a saved body model (β = 0 rest joints) and the T-pose beside it
    /// ([`load_tpose`]), e.g. the built-in `datasets/body/makehuman`.
    pub fn load(model_dir: &Path) -> Result<Self> {
        let model = BodyModel::load(model_dir)?;
        let betas = vec![0.0; model.n_betas()];
        let joints = model.shaped_joints(&betas)?;
        let tpose = load_tpose(model_dir)?;
        Self::new(model.skeleton().clone(), joints, tpose).map_err(|e| e.in_file(model_dir))
    }

    /// The skeleton.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// Rest joint positions (A-pose), metres.
    pub fn rest_joints_m(&self) -> &[Vector3<f64>] {
        &self.rest_joints_m
    }

    /// The T-pose.
    pub fn tpose(&self) -> &Pose {
        &self.tpose
    }

    /// The world rotation of each joint in the T-pose: the rest change `C_j` for a source taken
    /// to rest in our T-pose (AMASS without rest joints).
    pub fn tpose_world_rotations(&self) -> &[UnitQuaternion<f64>] {
        &self.tpose_world
    }

    /// Joint positions in the T-pose.
    pub fn tpose_joints_m(&self) -> Vec<Vector3<f64>> {
        self.skeleton
            .forward_kinematics(&self.rest_joints_m, &self.tpose)
            .expect("RetargetBody::new checked the joint count and the T-pose")
            .0
    }

    /// Vertical distance from the root joint down to the mean of the `LeftFoot`/`RightFoot`
    /// joints in the T-pose (or to the lowest joint when those are missing): the unit-free
    /// yardstick that scales mocap root translations.
    pub fn hip_height_m(&self) -> f64 {
        let joints = self.tpose_joints_m();
        hip_height(self.skeleton.names(), &joints)
    }

    /// Turn per-joint source world rotations into our pose: `Q_j` for the joints the source drives
    /// (`None` = follow the parent), `G_j = Q_j · C_j` with `rest_change` = `C_j` (from
    /// [`Self::rest_change`] or [`Self::tpose_world_rotations`]), then local rotations (see the
    /// module docs).
    pub(crate) fn pose_from_source(
        &self,
        rest_change: &[UnitQuaternion<f64>],
        source_world: &[Option<UnitQuaternion<f64>>],
        root_translation_m: Vector3<f64>,
    ) -> Pose {
        let n = self.skeleton.n_joints();
        let mut q = vec![UnitQuaternion::identity(); n];
        let mut g = vec![UnitQuaternion::identity(); n];
        for j in 0..n {
            q[j] = match (source_world[j], self.skeleton.parents()[j]) {
                (Some(s), _) => s,
                (None, Some(p)) => q[p],
                (None, None) => UnitQuaternion::identity(),
            };
            g[j] = q[j] * rest_change[j];
        }
        pose_from_world(&self.skeleton, &g, root_translation_m)
    }
}

/// Vertical distance from the hips (`Hips`, else joint 0) down to the feet (`LeftFoot`/`RightFoot`,
/// else the lowest joint).
pub(crate) fn hip_height(names: &[String], joints: &[Vector3<f64>]) -> f64 {
    let find = |n: &str| names.iter().position(|x| x == n);
    let hips = find("Hips").unwrap_or(0);
    let feet_y = match (find("LeftFoot"), find("RightFoot")) {
        (Some(l), Some(r)) => 0.5 * (joints[l].y + joints[r].y),
        _ => joints.iter().map(|p| p.y).fold(f64::INFINITY, f64::min),
    };
    joints[hips].y - feet_y
}

/// World rotation of every joint (`G_j`, the product of the local rotations down the chain, the
/// root's including `root_orientation`).
pub fn world_rotations(skeleton: &Skeleton, pose: &Pose) -> Vec<UnitQuaternion<f64>> {
    let mut g: Vec<UnitQuaternion<f64>> = Vec::with_capacity(skeleton.n_joints());
    for (j, parent) in skeleton.parents().iter().enumerate() {
        let local = pose.local_rotations[j];
        let w = match parent {
            None => pose.root_orientation * local,
            Some(p) => g[*p] * local,
        };
        g.push(w);
    }
    g
}

/// Local rotations from world rotations (`θ_j = G_parent⁻¹ · G_j`), with the root's world rotation
/// split into heading (`root_orientation`) and tilt (`local_rotations[0]`).
pub fn pose_from_world(
    skeleton: &Skeleton,
    world: &[UnitQuaternion<f64>],
    root_translation_m: Vector3<f64>,
) -> Pose {
    let mut local = Vec::with_capacity(world.len());
    let mut heading = UnitQuaternion::identity();
    for (j, parent) in skeleton.parents().iter().enumerate() {
        match parent {
            None => {
                let (h, tilt) = split_heading(&world[j]);
                heading = h;
                local.push(tilt);
            }
            Some(p) => local.push(canonical(world[*p].inverse() * world[j])),
        }
    }
    Pose {
        root_translation_m,
        root_orientation: heading,
        local_rotations: local,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmu_mb_skeleton;

    #[test]
    fn heading_split_recomposes_and_is_horizontal() {
        for (axis, angle) in [
            (Vector3::new(0.3, 1.0, -0.2), 2.0),
            (Vector3::new(1.0, 0.0, 0.0), 0.4),
            (Vector3::new(0.0, 1.0, 0.0), -2.5),
            (Vector3::new(0.2, -0.1, 1.0), 3.0),
        ] {
            let q = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
            let (h, t) = split_heading(&q);
            assert!((h * t).angle_to(&q) < 1e-12);
            // The heading is about Y, the tilt about a horizontal axis.
            assert!(h.as_ref().i.abs() < 1e-15 && h.as_ref().k.abs() < 1e-15);
            assert!(t.as_ref().j.abs() < 1e-12);
        }
    }

    #[test]
    fn world_and_local_round_trip() {
        let s = cmu_mb_skeleton();
        let mut pose = Pose::rest(s.n_joints());
        pose.root_orientation = UnitQuaternion::from_euler_angles(0.0, 0.7, 0.0);
        for (j, q) in pose.local_rotations.iter_mut().enumerate() {
            *q = UnitQuaternion::from_euler_angles(0.1 * j as f64, -0.05 * j as f64, 0.02);
        }
        // Keep the root tilt horizontal so the split reproduces it.
        pose.local_rotations[0] = UnitQuaternion::from_euler_angles(0.2, 0.0, 0.1);
        let (h, t) = split_heading(&(pose.root_orientation * pose.local_rotations[0]));
        pose.root_orientation = h;
        pose.local_rotations[0] = t;
        let g = world_rotations(&s, &pose);
        let back = pose_from_world(&s, &g, pose.root_translation_m);
        for (a, b) in back.local_rotations.iter().zip(&pose.local_rotations) {
            assert!(a.angle_to(b) < 1e-12);
        }
        assert!(back.root_orientation.angle_to(&pose.root_orientation) < 1e-12);
    }
}
