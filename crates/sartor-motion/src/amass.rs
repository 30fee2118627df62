//! AMASS-style `.npz` motions (SMPL / SMPL-H axis-angle poses), retargeted onto the built-in
//! skeleton.
//!
//! # Keys
//!
//! | key | shape | meaning |
//! | --- | --- | --- |
//! | `poses` | `N × 72` (SMPL, 24 joints) or `N × 156` (SMPL-H, 52 joints) | axis-angle per joint, radians; joint 0 is the global orientation |
//! | `trans` | `N × 3` | root translation, metres |
//! | `mocap_framerate` (or `mocap_frame_rate`) | scalar | frames per second |
//! | `betas` | `K` (optional) | shape; read and checked, not used |
//!
//! Only the 22 body joints are used (SMPL's hand joints 22–23 and SMPL-H's finger joints are
//! ignored; the rig's fingers follow the hand).
//!
//! # Joint mapping (SMPL index → rig joint)
//!
//! | SMPL | name | rig | | SMPL | name | rig |
//! | --- | --- | --- | --- | --- | --- | --- |
//! | 0 | pelvis | `Hips` | | 11 | R_foot | `RightToeBase` |
//! | 1 | L_hip | `LeftUpLeg` | | 12 | neck | `Neck` |
//! | 2 | R_hip | `RightUpLeg` | | 13 | L_collar | `LeftShoulder` |
//! | 3 | spine1 | `LowerBack` | | 14 | R_collar | `RightShoulder` |
//! | 4 | L_knee | `LeftLeg` | | 15 | head | `Head` |
//! | 5 | R_knee | `RightLeg` | | 16 | L_shoulder | `LeftArm` |
//! | 6 | spine2 | `Spine` | | 17 | R_shoulder | `RightArm` |
//! | 7 | L_ankle | `LeftFoot` | | 18 | L_elbow | `LeftForeArm` |
//! | 8 | R_ankle | `RightFoot` | | 19 | R_elbow | `RightForeArm` |
//! | 9 | spine3 | `Spine1` | | 20 | L_wrist | `LeftHand` |
//! | 10 | L_foot | `LeftToeBase` | | 21 | R_wrist | `RightHand` |
//!
//! Rig joints without an SMPL counterpart (`LHipJoint`, `RHipJoint`, `Neck1`, the fingers and
//! thumbs) follow their parent: they keep their rest-change relation to it.
//!
//! # Axes, rest pose, units
//!
//! SMPL's axes are ours (+Y up, +Z forward, +X the body's left). Its rotations are relative to
//! its rest pose, a T-pose whose exact bone directions depend on the model's joints: with
//! [`AmassOptions::rest_joints`] (the SMPL model's `J(β)`) the world-orientation retargeting of
//! [`crate::motion_sources`] turns our rest into exactly that pose ([`crate::SourceRest`]), and
//! every posture bone's world direction equals SMPL's in every frame; without them SMPL's rest
//! is taken to be our T-pose. Most AMASS files are Z-up (their global orientation includes a
//! +90° turn about X): with [`UpAxis::Z`] every world rotation and the translation are first
//! rotated by −90° about +X (the rest joints stay in SMPL's Y-up model axes). Translations are
//! in metres, multiplied by [`AmassOptions::translation_scale`] (1 by default) and taken
//! relative to the first frame.

#[cfg(feature = "npz")]
use std::path::Path;

use nalgebra::{UnitQuaternion, Vector3};

#[cfg(feature = "npz")]
use crate::npz::NpzFile;
use crate::rest_pose::SourceRest;
use crate::retarget::RetargetBody;
use crate::{Error, Motion, Result};

/// SMPL's body joints used here: `(SMPL index, SMPL name, rig joint)`.
pub const SMPL_TO_RIG: [(usize, &str, &str); 22] = [
    (0, "pelvis", "Hips"),
    (1, "L_hip", "LeftUpLeg"),
    (2, "R_hip", "RightUpLeg"),
    (3, "spine1", "LowerBack"),
    (4, "L_knee", "LeftLeg"),
    (5, "R_knee", "RightLeg"),
    (6, "spine2", "Spine"),
    (7, "L_ankle", "LeftFoot"),
    (8, "R_ankle", "RightFoot"),
    (9, "spine3", "Spine1"),
    (10, "L_foot", "LeftToeBase"),
    (11, "R_foot", "RightToeBase"),
    (12, "neck", "Neck"),
    (13, "L_collar", "LeftShoulder"),
    (14, "R_collar", "RightShoulder"),
    (15, "head", "Head"),
    (16, "L_shoulder", "LeftArm"),
    (17, "R_shoulder", "RightArm"),
    (18, "L_elbow", "LeftForeArm"),
    (19, "R_elbow", "RightForeArm"),
    (20, "L_wrist", "LeftHand"),
    (21, "R_wrist", "RightHand"),
];

/// Parents of SMPL's first 22 joints (the kinematic tree shared by SMPL, SMPL-H and SMPL-X).
pub const SMPL_BODY_PARENTS: [Option<usize>; 22] = [
    None,
    Some(0),
    Some(0),
    Some(0),
    Some(1),
    Some(2),
    Some(3),
    Some(4),
    Some(5),
    Some(6),
    Some(7),
    Some(8),
    Some(9),
    Some(9),
    Some(9),
    Some(12),
    Some(13),
    Some(14),
    Some(16),
    Some(17),
    Some(18),
    Some(19),
];

/// Options of [`retarget_amass`].
#[derive(Clone, Debug, PartialEq)]
pub struct AmassOptions {
    /// The file's up axis.
    pub up_axis: UpAxis,
    /// Factor applied to `trans` (1: the file's metres).
    pub translation_scale: f64,
    /// Rest positions of SMPL's joints (at least the 22 body joints, SMPL's own Y-up axes, any
    /// length unit): `J(β)` of the file's SMPL / SMPL-H model, e.g. from
    /// [`crate::smpl_from_npz`] and [`crate::BodyModel::shaped_joints`] with the file's `betas`.
    /// They give the rest bone directions the rotations are relative to. `None`: SMPL's rest is
    /// taken to be our T-pose (its thighs and arms then differ by the difference between the
    /// two skeletons' T-poses, a few degrees).
    pub rest_joints: Option<Vec<Vector3<f64>>>,
}

impl Default for AmassOptions {
    fn default() -> Self {
        Self {
            up_axis: UpAxis::Y,
            translation_scale: 1.0,
            rest_joints: None,
        }
    }
}

/// The rest change `C_j` for AMASS data: from `rest_joints` when given, else our T-pose.
fn amass_rest_change(
    body: &RetargetBody,
    rig: &[Option<usize>],
    options: &AmassOptions,
) -> Result<Vec<UnitQuaternion<f64>>> {
    let Some(rest) = &options.rest_joints else {
        return Ok(body.tpose_world_rotations().to_vec());
    };
    if rest.len() < SMPL_TO_RIG.len() {
        return Err(Error::invalid(
            "AMASS retarget",
            format!(
                "{} rest joints, SMPL has {} body joints",
                rest.len(),
                SMPL_TO_RIG.len()
            ),
        ));
    }
    let n = body.skeleton().n_joints();
    let mut positions = vec![None; n];
    let mut smpl_of_rig = vec![None; n];
    for (s, r) in rig.iter().enumerate() {
        if let Some(r) = r {
            positions[*r] = Some(rest[s]);
            smpl_of_rig[*r] = Some(s);
        }
    }
    let source = SourceRest::from_positions(body.skeleton().names(), &positions, |j, c| {
        match (smpl_of_rig[j], smpl_of_rig[c]) {
            (Some(sj), Some(sc)) => SMPL_BODY_PARENTS[sc] == Some(sj),
            _ => false,
        }
    })?;
    body.rest_change(&source)
}

/// The contents of an AMASS-style file.
#[derive(Clone, Debug, PartialEq)]
pub struct AmassData {
    /// Frames per second.
    pub fps: f64,
    /// Joints per frame in `poses` (24 for SMPL, 52 for SMPL-H).
    pub n_pose_joints: usize,
    /// Axis-angle vectors, `N × n_pose_joints`, row-major.
    pub poses: Vec<Vector3<f64>>,
    /// Root translations, one per frame, metres.
    pub trans: Vec<Vector3<f64>>,
    /// Shape coefficients, when present.
    pub betas: Option<Vec<f64>>,
}

impl AmassData {
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.trans.len()
    }

    /// Read and check an AMASS-style `.npz`.
    #[cfg(feature = "npz")]
    pub fn read(path: &Path) -> Result<Self> {
        let mut npz = NpzFile::open(path)?;
        let (shape, poses) = npz.array_f64("poses")?;
        let fault = |m: String| Error::format(path, m);
        let [n, width] = shape[..] else {
            return Err(fault(format!(
                "array \"poses\" has shape {shape:?}, expected [N, 72] or [N, 156]"
            )));
        };
        if width != 72 && width != 156 {
            return Err(fault(format!(
                "array \"poses\" has shape {shape:?}, expected [N, 72] (SMPL) or [N, 156] (SMPL-H)"
            )));
        }
        if n == 0 {
            return Err(fault("array \"poses\" has no frames".into()));
        }
        let (_, trans) = npz.array_f64_shaped("trans", &[Some(n), Some(3)])?;
        let rate_key = ["mocap_framerate", "mocap_frame_rate"]
            .into_iter()
            .find(|k| npz.contains(k))
            .ok_or_else(|| {
                fault("missing array \"mocap_framerate\" (or \"mocap_frame_rate\")".into())
            })?;
        let (rate_shape, rate) = npz.array_f64(rate_key)?;
        if rate.len() != 1 {
            return Err(fault(format!(
                "array {rate_key:?} has shape {rate_shape:?}, expected a scalar"
            )));
        }
        let fps = rate[0];
        if fps <= 0.0 {
            return Err(fault(format!(
                "array {rate_key:?}: frame rate {fps} is not positive"
            )));
        }
        let betas = if npz.contains("betas") {
            let (bs, b) = npz.array_f64("betas")?;
            if bs.len() > 1 && bs[..bs.len() - 1].iter().any(|&d| d != 1) {
                return Err(fault(format!(
                    "array \"betas\" has shape {bs:?}, expected a vector"
                )));
            }
            Some(b)
        } else {
            None
        };
        let to_vecs = |xs: &[f64]| {
            xs.chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2]))
                .collect::<Vec<_>>()
        };
        Ok(Self {
            fps,
            n_pose_joints: width / 3,
            poses: to_vecs(&poses),
            trans: to_vecs(&trans),
            betas,
        })
    }

    /// SMPL world rotations of the 22 body joints in frame `i` (file axes).
    pub fn body_world_rotations(&self, i: usize) -> [UnitQuaternion<f64>; 22] {
        let row = &self.poses[i * self.n_pose_joints..(i + 1) * self.n_pose_joints];
        let mut q = [UnitQuaternion::identity(); 22];
        for j in 0..22 {
            let local = UnitQuaternion::from_scaled_axis(row[j]);
            q[j] = match SMPL_BODY_PARENTS[j] {
                None => local,
                Some(p) => q[p] * local,
            };
        }
        q
    }
}

/// Retarget AMASS data onto `body` at the file's frame rate (see the module docs).
pub fn retarget_amass_native_rate(
    data: &AmassData,
    name: &str,
    body: &RetargetBody,
    options: &AmassOptions,
) -> Result<Motion> {
    let skeleton = body.skeleton();
    let up = match options.up_axis {
        UpAxis::Y => UnitQuaternion::identity(),
        UpAxis::Z => {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -std::f64::consts::FRAC_PI_2)
        }
    };
    let rig: Vec<Option<usize>> = SMPL_TO_RIG
        .iter()
        .map(|(_, _, r)| skeleton.index_of(r))
        .collect();
    if rig[0] != Some(0) {
        return Err(Error::invalid(
            "AMASS retarget",
            "the body's root must be the rig's Hips",
        ));
    }
    let rest_change = amass_rest_change(body, &rig, options)?;
    let first = data.trans[0];
    let mut source = vec![None; skeleton.n_joints()];
    let mut frames = Vec::with_capacity(data.n_frames());
    for i in 0..data.n_frames() {
        let q = data.body_world_rotations(i);
        for (s, r) in rig.iter().enumerate() {
            if let Some(r) = r {
                source[*r] = Some(up * q[s]);
            }
        }
        let d = up * (data.trans[i] - first) * options.translation_scale;
        frames.push(body.pose_from_source(&rest_change, &source, d));
    }
    Motion::new(
        name.to_string(),
        data.fps,
        skeleton.names().to_vec(),
        frames,
    )
}

/// Retarget AMASS data onto `body` and resample to [`sartor_core::FPS`].
pub fn retarget_amass(
    data: &AmassData,
    name: &str,
    body: &RetargetBody,
    options: &AmassOptions,
) -> Result<Motion> {
    retarget_amass_native_rate(data, name, body, options)?.resample(sartor_core::FPS)
}

/// Read an AMASS-style `.npz`, retarget it onto `body` and resample to [`sartor_core::FPS`].
#[cfg(feature = "npz")]
pub fn load_amass(path: &Path, body: &RetargetBody, options: &AmassOptions) -> Result<Motion> {
    let data = AmassData::read(path)?;
    let name = path
        .file_stem()
        .map_or_else(|| "amass".to_string(), |s| s.to_string_lossy().into_owned());
    retarget_amass(&data, &name, body, options).map_err(|e| e.in_file(path))
}

/// The up axis of an AMASS-style file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UpAxis {
    /// +Y up (SMPL's own convention, and ours).
    #[default]
    Y,
    /// +Z up (most AMASS files): the data is rotated by −90° about +X, which takes +Z to +Y.
    Z,
}

impl std::str::FromStr for UpAxis {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "y" | "Y" => Ok(Self::Y),
            "z" | "Z" => Ok(Self::Z),
            other => Err(Error::invalid(
                "up axis",
                format!("{other:?} is not y or z"),
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping_names_exist_in_the_rig() {
        let s = crate::cmu_mb_skeleton();
        for (i, (k, name, rig)) in SMPL_TO_RIG.iter().enumerate() {
            assert_eq!(i, *k);
            assert!(s.index_of(rig).is_some(), "{name} -> {rig}");
        }
        // SMPL parents map onto rig ancestors.
        for (j, p) in SMPL_BODY_PARENTS.iter().enumerate().skip(1) {
            let p = p.expect("non-root");
            let (rj, rp) = (
                s.index_of(SMPL_TO_RIG[j].2).expect("joint"),
                s.index_of(SMPL_TO_RIG[p].2).expect("parent"),
            );
            let mut a = s.parents()[rj];
            while let Some(x) = a {
                if x == rp {
                    break;
                }
                a = s.parents()[x];
            }
            assert_eq!(
                a,
                Some(rp),
                "{} is not below {}",
                SMPL_TO_RIG[j].2,
                SMPL_TO_RIG[p].2
            );
        }
    }
}
