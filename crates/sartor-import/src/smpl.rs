//! Loading an SMPL-family model from a `.npz` file into a [`BodyModel`].
//!
//! Expected arrays (the layout of SMPL's `.pkl` converted to `.npz`, C order, float or int):
//!
//! | array | shape | meaning |
//! | --- | --- | --- |
//! | `v_template` | V × 3 | template vertices (metres) |
//! | `f` | F × 3 | triangles |
//! | `shapedirs` | V × 3 × B | shape blend shapes (the first `n_betas` columns are kept) |
//! | `J_regressor` | J × V | dense joint regressor |
//! | `weights` | V × J | skin weights |
//! | `kintree_table` | 2 × J | row 0: parent of each joint (root: −1 or 2³²−1), row 1: joint ids |
//! | `posedirs` | V × 3 × P | **ignored**: sartor's bodies have no pose-corrective blend shapes, and the same linear blend skinning serves every body model |
//!
//! The joint regressor is folded into a joint shape basis at load: `J(β) = R·v_template +
//! (R·shapedirs)·β`, which is exact because the regressor is linear. SMPL's axes (+Y up, facing
//! +Z, +X the body's left) and units (metres) match sartor's.

use std::path::Path;

use nalgebra::Vector3;

use sartor_core::{BodyModel, Provenance, Skeleton, SkinWeights, TriMesh};
use sartor_motion::npz::NpzFile;

use crate::{Error, Result};

/// SMPL's 24 joint names.
pub const SMPL_JOINTS: [&str; 24] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hand",
    "right_hand",
];

/// Load an SMPL-layout `.npz` model, keeping `n_betas` shape components (all when `None`).
pub fn load_smpl_npz(path: &Path, n_betas: Option<usize>) -> Result<BodyModel> {
    smpl_from_npz(NpzFile::open(path)?, n_betas)
}

/// Like [`load_smpl_npz`], from an archive already opened (e.g. from bytes).
pub fn smpl_from_npz(mut npz: NpzFile, n_betas: Option<usize>) -> Result<BodyModel> {
    let path = &npz.path().to_path_buf();
    let fault = |m: String| Error::format(path, m);
    let (vs, v_template) = npz.array_f64_shaped("v_template", &[None, Some(3)])?;
    let n_v = vs[0];
    let (fs, faces) = npz.array_f64_shaped("f", &[None, Some(3)])?;
    let faces = faces
        .chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let idx = |x: f64| {
                if x >= 0.0 && x.fract() == 0.0 && (x as usize) < n_v {
                    Ok(x as u32)
                } else {
                    Err(fault(format!(
                        "array \"f\": triangle {i} has index {x}, outside 0..{n_v}"
                    )))
                }
            };
            Ok([idx(c[0])?, idx(c[1])?, idx(c[2])?])
        })
        .collect::<Result<Vec<_>>>()?;
    debug_assert_eq!(faces.len(), fs[0]);
    let (ss, shapedirs) = npz.array_f64_shaped("shapedirs", &[Some(n_v), Some(3), None])?;
    let n_all = ss[2];
    let nb = n_betas.unwrap_or(n_all);
    if nb > n_all {
        return Err(fault(format!(
            "asked for {nb} shape components, the file has {n_all}"
        )));
    }
    let (js, regressor) = npz.array_f64_shaped("J_regressor", &[None, Some(n_v)])?;
    let n_j = js[0];
    let (_, weights) = npz.array_f64_shaped("weights", &[Some(n_v), Some(n_j)])?;
    let (_, kintree) = npz.array_f64_shaped("kintree_table", &[Some(2), Some(n_j)])?;
    if npz.contains("posedirs") {
        // Validated only for shape, then ignored (see the module docs).
        npz.array_f64_shaped("posedirs", &[Some(n_v), Some(3), None])?;
    }

    // Skeleton: kintree row 1 gives joint ids; row 0 their parents. Joints must be listed so that
    // parents come first and ids are 0..J in order (true of every SMPL-family file).
    let mut parents = Vec::with_capacity(n_j);
    for j in 0..n_j {
        if kintree[n_j + j] != j as f64 {
            return Err(fault(format!(
                "kintree_table: column {j} has joint id {}, expected {j}",
                kintree[n_j + j]
            )));
        }
        let p = kintree[j];
        parents.push(if j == 0 {
            None
        } else if p >= 0.0 && (p as usize) < j && p.fract() == 0.0 {
            Some(p as usize)
        } else {
            return Err(fault(format!(
                "kintree_table: joint {j} has parent {p}, which does not precede it"
            )));
        });
    }
    let names = if n_j == SMPL_JOINTS.len() {
        SMPL_JOINTS.iter().map(|s| s.to_string()).collect()
    } else {
        (0..n_j).map(|j| format!("joint_{j}")).collect()
    };
    let skeleton = Skeleton::new(names, parents).map_err(|e| e.in_file(path))?;

    let points = |flat: &[f64]| {
        flat.chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect::<Vec<_>>()
    };
    let template = TriMesh::new(points(&v_template), faces).map_err(|e| e.in_file(path))?;
    let shape_basis: Vec<f64> = shapedirs
        .chunks_exact(n_all)
        .flat_map(|row| row[..nb].iter().copied())
        .collect::<Vec<_>>();
    // Fold the regressor: J_template = R v_template, J_dirs = R shapedirs.
    let mut joint_template = vec![Vector3::zeros(); n_j];
    let mut joint_shape_basis = vec![0.0; n_j * 3 * nb];
    for j in 0..n_j {
        for v in 0..n_v {
            let r = regressor[j * n_v + v];
            if r == 0.0 {
                continue;
            }
            for c in 0..3 {
                joint_template[j][c] += r * v_template[v * 3 + c];
                for b in 0..nb {
                    joint_shape_basis[(j * 3 + c) * nb + b] +=
                        r * shape_basis[(v * 3 + c) * nb + b];
                }
            }
        }
    }
    let dense: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    let skin = SkinWeights::from_dense_top_k(&dense, n_j, n_j).map_err(|e| e.in_file(path))?;
    let name = path
        .file_stem()
        .map_or_else(|| "smpl".to_string(), |s| s.to_string_lossy().into_owned());
    BodyModel::new(
        name,
        template,
        nb,
        shape_basis,
        joint_template,
        joint_shape_basis,
        skeleton,
        skin,
        Provenance {
            source: path.display().to_string(),
            licence: "user-supplied SMPL-family model: see its own licence".into(),
            notes: "loaded from .npz; joint regressor folded into a joint shape basis; posedirs ignored".into(),
        },
    )
    .map_err(|e| e.in_file(path))
}
