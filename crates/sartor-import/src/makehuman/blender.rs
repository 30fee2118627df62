//! Blender bone rest frames and pose-bone rotations, expressed in the model's axes.
//!
//! Blender's armature space is Z up, −Y forward; the model's is Y up, +Z forward (both +X the
//! body's left), so a Blender vector `(x, y, z)` is the model vector `(x, z, −y)`. A bone's rest
//! frame `B` (columns: the bone's X, Y, Z axes; Y from head to tail, X and Z set by the roll,
//! computed as Blender's `vec_roll_to_mat3`) turns a pose-bone local rotation `R` into our local
//! rotation `θ = B R Bᵀ` (every joint's rest frame world-aligned, SMPL convention).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use sartor_core::Pose;
use sartor_core::io::{read_file, write_atomic};

use crate::{Error, Result};

/// File name of the bone rest frames inside the built-in model's folder.
pub const BONE_FRAMES_FILE: &str = "bone_frames.json";

const FORMAT: &str = "sartor-bone-frames";

/// `model_from_blender`: the model vector of a Blender vector, `(x, y, z) ↦ (x, z, −y)`.
pub(crate) fn model_from_blender() -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0)
}

/// Blender's `vec_roll_to_mat3_normalized` (in f64): the rest frame of a bone whose unit
/// direction is `nor` and whose roll is `roll_rad`, in the axes `nor` is given in.
pub(crate) fn vec_roll_to_mat3(nor: &Vector3<f64>, roll_rad: f64) -> Matrix3<f64> {
    const SAFE_THRESHOLD: f64 = 6.1e-3;
    const CRITICAL_THRESHOLD: f64 = 2.5e-4;
    let (x, y, z) = (nor.x, nor.y, nor.z);
    let mut theta = 1.0 + y;
    let theta_alt = x * x + z * z;
    // Blender's matrices are column-major; columns are written here as columns.
    let b = if theta > SAFE_THRESHOLD || theta_alt > CRITICAL_THRESHOLD * CRITICAL_THRESHOLD {
        if theta <= SAFE_THRESHOLD {
            theta = theta_alt * 0.5 + theta_alt * theta_alt * 0.125;
        }
        Matrix3::from_columns(&[
            Vector3::new(1.0 - x * x / theta, -x, -x * z / theta),
            Vector3::new(x, y, z),
            Vector3::new(-x * z / theta, -z, 1.0 - z * z / theta),
        ])
    } else {
        Matrix3::from_diagonal(&Vector3::new(-1.0, -1.0, 1.0))
    };
    let roll = Rotation3::from_axis_angle(&Unit::new_unchecked(*nor), roll_rad).into_inner();
    roll * b
}

/// Blender's Euler `XYZ` rotation (`eul_to_mat3`): `Rz(z) · Ry(y) · Rx(x)`, X applied first.
pub fn blender_euler_xyz(euler_rad: [f64; 3]) -> Rotation3<f64> {
    let [x, y, z] = euler_rad;
    Rotation3::from_axis_angle(&Vector3::z_axis(), z)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), y)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), x)
}

/// Make a near-rotation exactly orthonormal, keeping its Y column's direction (Gram–Schmidt on
/// Y, then X; Z = X × Y).
fn orthonormalize(m: &Matrix3<f64>) -> Result<Rotation3<f64>> {
    let bad = || Error::invalid("bone frame", format!("{m} is not a rotation"));
    let y = m
        .column(1)
        .into_owned()
        .try_normalize(1e-9)
        .ok_or_else(bad)?;
    let x0 = m.column(0).into_owned();
    let x = (x0 - y * y.dot(&x0)).try_normalize(1e-9).ok_or_else(bad)?;
    let z = x.cross(&y);
    if z.dot(&m.column(2)) < 0.5 || (m.transpose() * m - Matrix3::identity()).norm() > 1e-4 {
        return Err(bad());
    }
    Ok(Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        x, y, z,
    ])))
}

/// Round to f32 (what the file stores), so in-memory frames equal loaded ones bit for bit;
/// entries below 1e-9 (rounding noise of `sin`/`cos`, which differs between platforms) are 0.
fn to_stored(m: &Matrix3<f64>) -> [[f32; 3]; 3] {
    [0, 1, 2].map(|r| [0, 1, 2].map(|c| snap(m[(r, c)])))
}

fn snap(x: f64) -> f32 {
    if x.abs() < 1e-9 { 0.0 } else { x as f32 }
}

fn from_stored(rows: &[[f32; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| f64::from(rows[r][c]))
}

/// One bone in `bone_frames.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StoredBone {
    name: String,
    /// Rows of the 3×3 matrix whose columns are the bone's X, Y, Z axes in model axes.
    world_from_bone: [[f32; 3]; 3],
    head_m: [f32; 3],
    tail_m: [f32; 3],
    roll_rad: f32,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StoredFrames {
    format: String,
    version: u32,
    axes: String,
    layout: String,
    bones: Vec<StoredBone>,
}

/// The rest frames of the built-in body's bones (the `cmu_mb` rig at the mean adult shape),
/// for converting Blender-keyed rotations into [`Pose`]s. Saved as `bone_frames.json`: one
/// entry per joint in skeleton order with `name`, `world_from_bone` (3×3, row-major rows;
/// its columns are the bone's X, Y, Z axes in model axes, Y from head to tail), `head_m`,
/// `tail_m` (metres, model axes, β = 0) and `roll_rad` (Blender edit-bone roll).
#[derive(Clone, Debug, PartialEq)]
pub struct BoneFrames {
    /// What the file holds (saved as is, so save/load round-trips bit for bit).
    stored: Vec<StoredBone>,
    names: Vec<String>,
    world_from_bone: Vec<Rotation3<f64>>,
    heads_m: Vec<Vector3<f64>>,
    tails_m: Vec<Vector3<f64>>,
}

impl BoneFrames {
    /// Frames from bone heads and tails (model axes, metres) and Blender rolls, computed as
    /// Blender does in its own axes and converted. Values are rounded to what the file stores.
    pub(crate) fn from_heads_tails(
        names: Vec<String>,
        heads_m: &[Vector3<f64>],
        tails_m: &[Vector3<f64>],
        rolls_rad: &[f64],
    ) -> Result<Self> {
        let m_from_b = model_from_blender();
        let mut stored = Vec::new();
        for (j, name) in names.iter().enumerate() {
            let dir = m_from_b.transpose() * (tails_m[j] - heads_m[j]);
            let nor = dir.try_normalize(1e-9).ok_or_else(|| {
                Error::invalid("bone frame", format!("bone {name} has zero length"))
            })?;
            let blender = vec_roll_to_mat3(&nor, rolls_rad[j]);
            let f3 = |v: &Vector3<f64>| [snap(v.x), snap(v.y), snap(v.z)];
            stored.push(StoredBone {
                name: name.clone(),
                world_from_bone: to_stored(&(m_from_b * blender)),
                head_m: f3(&heads_m[j]),
                tail_m: f3(&tails_m[j]),
                roll_rad: rolls_rad[j] as f32,
            });
        }
        Self::from_stored(stored)
    }

    fn from_stored(bones: Vec<StoredBone>) -> Result<Self> {
        let v3 = |a: &[f32; 3]| Vector3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        let mut out = Self {
            stored: bones.clone(),
            names: Vec::new(),
            world_from_bone: Vec::new(),
            heads_m: Vec::new(),
            tails_m: Vec::new(),
        };
        for b in bones {
            let all = b
                .world_from_bone
                .iter()
                .flatten()
                .chain(&b.head_m)
                .chain(&b.tail_m)
                .chain(std::iter::once(&b.roll_rad));
            if let Some(x) = all.into_iter().find(|x| !x.is_finite()) {
                return Err(Error::invalid(
                    "bone frame",
                    format!("bone {}: value {x} is not finite", b.name),
                ));
            }
            let r = orthonormalize(&from_stored(&b.world_from_bone))
                .map_err(|e| Error::invalid("bone frame", format!("bone {}: {e}", b.name)))?;
            out.names.push(b.name);
            out.world_from_bone.push(r);
            out.heads_m.push(v3(&b.head_m));
            out.tails_m.push(v3(&b.tail_m));
        }
        Ok(out)
    }

    /// Joint names, in skeleton order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Rest frame of each bone: columns are the bone's X, Y, Z axes in model axes.
    pub fn world_from_bone(&self) -> &[Rotation3<f64>] {
        &self.world_from_bone
    }

    /// Bone heads (= joint positions) at β = 0, metres.
    pub fn heads_m(&self) -> &[Vector3<f64>] {
        &self.heads_m
    }

    /// Bone tails at β = 0, metres.
    pub fn tails_m(&self) -> &[Vector3<f64>] {
        &self.tails_m
    }

    /// Our local rotation (relative to the parent, world-aligned rest frames) of joint `joint`
    /// for a Blender pose-bone local rotation `blender_local` (`matrix_basis`):
    /// `B · blender_local · Bᵀ`.
    pub fn local_rotation_from_blender(
        &self,
        joint: usize,
        blender_local: &Rotation3<f64>,
    ) -> Result<UnitQuaternion<f64>> {
        let b = self.world_from_bone.get(joint).ok_or_else(|| {
            Error::invalid(
                "bone frame",
                format!("joint {joint} of {}", self.names.len()),
            )
        })?;
        Ok(UnitQuaternion::from_rotation_matrix(
            &(b * blender_local * b.inverse()),
        ))
    }

    /// A [`Pose`] from Blender Euler `XYZ` pose-bone rotations (radians) by bone name; bones
    /// not listed keep the identity. Quaternions are rounded to f32 precision (then
    /// renormalised) so the result does not depend on the platform's `sin`/`cos` last bits.
    pub fn pose_from_blender_euler_xyz(
        &self,
        rotations: &BTreeMap<String, [f64; 3]>,
    ) -> Result<Pose> {
        let mut pose = Pose::rest(self.names.len());
        for (name, euler) in rotations {
            let j = self.names.iter().position(|n| n == name).ok_or_else(|| {
                Error::invalid("pose", format!("bone {name:?} is not in the skeleton"))
            })?;
            let q = self.local_rotation_from_blender(j, &blender_euler_xyz(*euler))?;
            let c = q.as_ref().coords.map(|x| x as f32 as f64);
            pose.local_rotations[j] = UnitQuaternion::new_normalize(nalgebra::Quaternion::from(c));
        }
        Ok(pose)
    }

    /// Save as JSON in `dir` (atomically, deterministically).
    pub(crate) fn save(&self, dir: &Path) -> Result<()> {
        let bones = self.stored.clone();
        let file = StoredFrames {
            format: FORMAT.into(),
            version: 1,
            axes: "+Y up, +Z forward, +X body's left; Blender (x, y, z) = model (x, -z, y)".into(),
            layout: "world_from_bone: 3x3 rotation as rows; its columns are the bone's X, Y, Z \
                     axes in model axes (Y from head to tail, X/Z from the Blender roll); a \
                     Blender pose-bone local rotation R is the local rotation \
                     world_from_bone * R * world_from_bone^T in sartor's Pose"
                .into(),
            bones,
        };
        let mut json = serde_json::to_string_pretty(&file)
            .map_err(|e| Error::invalid("bone frames", e.to_string()))?;
        json.push('\n');
        write_atomic(&dir.join(BONE_FRAMES_FILE), json.as_bytes())
    }

    /// Load `bone_frames.json` from `dir` (e.g. the built-in `datasets/body/makehuman`).
    pub fn load(dir: &Path) -> Result<Self> {
        let path = dir.join(BONE_FRAMES_FILE);
        let file: StoredFrames = serde_json::from_slice(&read_file(&path)?)
            .map_err(|e| Error::parse(&path, e.line(), e.to_string()))?;
        if file.format != FORMAT || file.version != 1 {
            return Err(Error::format(
                &path,
                format!(
                    "format {:?} version {} is not {FORMAT} version 1",
                    file.format, file.version
                ),
            ));
        }
        Self::from_stored(file.bones).map_err(|e| e.in_file(&path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roll_matrix_matches_blender_conventions() {
        // A bone along +Y with no roll has the identity frame.
        let m = vec_roll_to_mat3(&Vector3::y(), 0.0);
        assert!((m - Matrix3::identity()).norm() < 1e-15);
        // Along +Z (Blender up): Y → Z, and Z → −Y.
        let m = vec_roll_to_mat3(&Vector3::z(), 0.0);
        assert!((m.column(1) - Vector3::z()).norm() < 1e-15);
        assert!((m.column(2) + Vector3::y()).norm() < 1e-15);
        // Any direction and roll gives a rotation with Y along the bone.
        let nor = Vector3::new(0.3, -0.5, 0.8).normalize();
        let m = vec_roll_to_mat3(&nor, 1.3);
        assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
        assert!((m.determinant() - 1.0).abs() < 1e-12);
        assert!((m.column(1) - nor).norm() < 1e-12);
        // Roll turns X about the bone.
        let m0 = vec_roll_to_mat3(&nor, 0.0);
        let angle = m0.column(0).angle(&m.column(0));
        assert!((angle - 1.3).abs() < 1e-9);
        // Near −Y: still a rotation.
        let nor = Vector3::new(1e-3, -1.0, 0.0).normalize();
        let m = vec_roll_to_mat3(&nor, 0.0);
        assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-6);
    }

    #[test]
    fn euler_xyz_applies_x_first() {
        let r = blender_euler_xyz([
            std::f64::consts::FRAC_PI_2,
            0.0,
            std::f64::consts::FRAC_PI_2,
        ]);
        // X first: y → z; then Z: z stays z.
        assert!((r * Vector3::y() - Vector3::z()).norm() < 1e-12);
        // x: unchanged by X, then Z turns it to y.
        assert!((r * Vector3::x() - Vector3::y()).norm() < 1e-12);
    }

    #[test]
    fn blender_rotation_becomes_world_rotation_about_the_bone() {
        // A bone pointing to the body's left (+X in both axes), no roll: Blender's bone Y is
        // world +X. A pose rotation about the bone's Y twists about world +X.
        let frames = BoneFrames::from_heads_tails(
            vec!["arm".into()],
            &[Vector3::zeros()],
            &[Vector3::x()],
            &[0.0],
        )
        .expect("valid");
        let twist = Rotation3::from_axis_angle(&Vector3::y_axis(), 0.7);
        let q = frames
            .local_rotation_from_blender(0, &twist)
            .expect("joint exists");
        let axis = q.axis().expect("non-zero").into_inner();
        assert!((axis - Vector3::x()).norm() < 1e-6, "{axis}");
        assert!((q.angle() - 0.7).abs() < 1e-6);
        assert!(frames.local_rotation_from_blender(1, &twist).is_err());
    }

    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().expect("tempdir");
        let frames = BoneFrames::from_heads_tails(
            vec!["a".into(), "b".into()],
            &[Vector3::zeros(), Vector3::new(0.0, 1.0, 0.0)],
            &[Vector3::new(0.0, 1.0, 0.0), Vector3::new(0.3, 1.2, 0.1)],
            &[0.0, 0.4],
        )
        .expect("valid");
        frames.save(dir.path()).expect("save");
        let back = BoneFrames::load(dir.path()).expect("load");
        assert_eq!(back, frames);
        let path = dir.path().join(BONE_FRAMES_FILE);
        let text = std::fs::read_to_string(&path).expect("read");
        std::fs::write(&path, text.replacen("\"version\": 1", "\"version\": 7", 1)).expect("write");
        let err = BoneFrames::load(dir.path())
            .expect_err("bad version")
            .to_string();
        assert!(
            err.contains("bone_frames.json") && err.contains("version 7"),
            "{err}"
        );
    }
}
