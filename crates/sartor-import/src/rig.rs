//! The one reader of MakeHuman rig files (`rig.*.json`), for the body importer (which places
//! joints from each bone end's vertex anchor) and the walk-cycle importer (which poses the
//! default rig from the bones' default positions and rolls).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde::Deserialize;

use crate::{Error, Result};
use sartor_core::io::read_file;

/// How a bone end is placed on a body mesh: the mean of a vertex group (`CUBE`, by name) or of
/// listed vertices (`MEAN`).
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub(crate) struct RigAnchor {
    /// `CUBE` or `MEAN`.
    pub strategy: String,
    /// The vertex group of a `CUBE` anchor.
    #[serde(default)]
    pub cube_name: Option<String>,
    /// The vertices of a `MEAN` anchor.
    #[serde(default)]
    pub vertex_indices: Option<Vec<u32>>,
}

/// A bone of a MakeHuman rig file, in Blender armature space (metres, Z up, −Y forward).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct RigBone {
    /// Bone name.
    pub name: String,
    /// Parent bone name (`None` for roots).
    pub parent: Option<String>,
    /// Rest head at MPFB's default body.
    pub head: Vector3<f64>,
    /// Rest tail at MPFB's default body.
    pub tail: Vector3<f64>,
    /// Blender edit-bone roll, radians.
    pub roll: f64,
    /// Where the head sits on a body mesh.
    pub head_anchor: RigAnchor,
    /// Where the tail sits on a body mesh.
    pub tail_anchor: RigAnchor,
}

impl RigBone {
    /// Rest axes (columns X, Y, Z) in armature space, as Blender's
    /// `vec_roll_to_mat3_normalized`.
    pub fn rest_axes(&self) -> Matrix3<f64> {
        crate::makehuman::vec_roll_to_mat3(&(self.tail - self.head).normalize(), self.roll)
    }
}

/// A bone end as stored (fields the importers do not use are ignored).
#[derive(Deserialize)]
struct RawEnd {
    #[serde(flatten)]
    anchor: RigAnchor,
    default_position: [f64; 3],
}

/// A bone as stored.
#[derive(Deserialize)]
struct RawBone {
    head: RawEnd,
    tail: RawEnd,
    #[serde(default)]
    parent: String,
    roll: f64,
}

/// Read a rig file: bone name → bone, checked (finite, non-zero-length bones, known parents).
/// Errors name the file, and the line or the bone.
pub(crate) fn read_rig(path: &Path) -> Result<BTreeMap<String, RigBone>> {
    let raw: BTreeMap<String, RawBone> = serde_json::from_slice(&read_file(path)?)
        .map_err(|e| Error::parse(path, e.line(), e.to_string()))?;
    let mut bones = BTreeMap::new();
    for (name, b) in raw {
        let fault = |m: &str| Error::format(path, format!("bone {name:?}: {m}"));
        let (head, tail) = (
            Vector3::from(b.head.default_position),
            Vector3::from(b.tail.default_position),
        );
        if !head.iter().chain(tail.iter()).all(|x| x.is_finite()) || !b.roll.is_finite() {
            return Err(fault("non-finite position or roll"));
        }
        if (tail - head).norm() < 1e-9 {
            return Err(fault("zero-length bone"));
        }
        let parent = (!b.parent.is_empty()).then_some(b.parent);
        let bone = RigBone {
            name: name.clone(),
            parent,
            head,
            tail,
            roll: b.roll,
            head_anchor: b.head.anchor,
            tail_anchor: b.tail.anchor,
        };
        bones.insert(name, bone);
    }
    for b in bones.values() {
        if let Some(p) = &b.parent
            && !bones.contains_key(p)
        {
            return Err(Error::format(
                path,
                format!("bone {:?}: unknown parent {p:?}", b.name),
            ));
        }
    }
    Ok(bones)
}
