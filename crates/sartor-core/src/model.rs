//! The parametric body model `M_b(β, θ) = W(T_b(β, θ), β, θ, W_b)`.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, OnceLock};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::asset::AssetFiles;
use crate::io::{OwnedTensor, serialize_tensors, sha256_hex};
use crate::proximity::MeshProximity;
use crate::skeleton::{Pose, Skeleton};
use crate::skinning::{BoneTransform, Parallelism, SkinWeights, skin_points, skin_points_at};
use crate::{Error, Result, TriMesh};

/// File name of the tensors of a saved model inside its folder.
pub const MODEL_TENSORS: &str = "model.safetensors";
/// File name of the JSON header of a saved model inside its folder.
pub const MODEL_HEADER: &str = "model.json";

/// Where a model comes from and under which licence.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance {
    /// What the model was built from.
    pub source: String,
    /// Licence of the data.
    pub licence: String,
    /// How it was converted.
    pub notes: String,
}

/// An SMPL-like body model: template mesh, linear shape basis, joint shape basis (the joint
/// regressor applied to the template and to the shape basis), skeleton and sparse skin weights.
/// Units: metres. Axes: +Y up, +Z forward, +X the body's left.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyModel {
    name: String,
    template: TriMesh,
    n_betas: usize,
    /// `(V·3) × n_betas`, row-major: entry `((v·3 + c)·n_betas + b)`.
    shape_basis: Vec<f64>,
    joint_template: Vec<Vector3<f64>>,
    /// `(J·3) × n_betas`, row-major.
    joint_shape_basis: Vec<f64>,
    skeleton: Skeleton,
    skin_weights: SkinWeights,
    provenance: Provenance,
    /// The template's closest-point structure, built on first use
    /// ([`BodyModel::template_proximity`]).
    template_proximity: ProximityCache,
}

/// A body's [`MeshProximity`] over its template, built once and shared by its clones: a cache,
/// so two models compare equal whether or not theirs is built yet.
#[derive(Clone, Debug, Default)]
struct ProximityCache(OnceLock<Arc<MeshProximity>>);

impl PartialEq for ProximityCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// The JSON header saved next to the tensors.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: String,
    version: u32,
    name: String,
    units: String,
    axes: String,
    n_vertices: usize,
    n_faces: usize,
    n_betas: usize,
    joint_names: Vec<String>,
    parents: Vec<Option<usize>>,
    provenance: Provenance,
    tensors_sha256: String,
}

crate::asset_header!(Header, units);

/// The body model's file pair.
const FILES: AssetFiles = AssetFiles {
    header: MODEL_HEADER,
    tensors: MODEL_TENSORS,
    format: "sartor-body",
    version: 1,
};
const AXES: &str = "+Y up, +Z forward, +X body's left";

impl BodyModel {
    /// Build a model, checking that all sizes agree and all values are finite.
    pub fn new(
        name: String,
        template: TriMesh,
        n_betas: usize,
        shape_basis: Vec<f64>,
        joint_template: Vec<Vector3<f64>>,
        joint_shape_basis: Vec<f64>,
        skeleton: Skeleton,
        skin_weights: SkinWeights,
        provenance: Provenance,
    ) -> Result<Self> {
        let bad = |m: String| Error::invalid("body model", m);
        let (v, j) = (template.n_vertices(), skeleton.n_joints());
        if shape_basis.len() != v * 3 * n_betas {
            return Err(bad(format!(
                "shape basis has {} values, expected {v}×3×{n_betas}",
                shape_basis.len()
            )));
        }
        if joint_template.len() != j {
            return Err(bad(format!(
                "{} joint positions for {j} joints",
                joint_template.len()
            )));
        }
        if joint_shape_basis.len() != j * 3 * n_betas {
            return Err(bad(format!(
                "joint shape basis has {} values, expected {j}×3×{n_betas}",
                joint_shape_basis.len()
            )));
        }
        if skin_weights.n_points() != v || skin_weights.n_joints() != j {
            return Err(bad(format!(
                "skin weights cover {} points and {} joints, model has {v} vertices and {j} joints",
                skin_weights.n_points(),
                skin_weights.n_joints()
            )));
        }
        let finite = |xs: &[f64]| xs.iter().all(|x| x.is_finite());
        if !finite(&shape_basis)
            || !finite(&joint_shape_basis)
            || !joint_template.iter().all(|p| finite(p.as_slice()))
        {
            return Err(bad("non-finite value in the shape or joint basis".into()));
        }
        Ok(Self {
            name,
            template,
            n_betas,
            shape_basis,
            joint_template,
            joint_shape_basis,
            skeleton,
            skin_weights,
            provenance,
            template_proximity: ProximityCache::default(),
        })
    }

    /// The model's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Template mesh `T̄_b` (β = 0, rest pose).
    pub fn template(&self) -> &TriMesh {
        &self.template
    }

    /// The closest-point structure over the template's faces, built on the first call and kept
    /// (its clones share it): every garment put on this body anchors its vertices to the
    /// template through it, so a second garment (a change of garment on the try-on page) does
    /// not build it again.
    pub fn template_proximity(&self) -> Result<&MeshProximity> {
        let cache = &self.template_proximity.0;
        if let Some(built) = cache.get() {
            return Ok(built);
        }
        let built = MeshProximity::new(self.template.positions(), self.template.faces())?;
        Ok(cache.get_or_init(|| Arc::new(built)))
    }

    /// Triangles of the body mesh.
    pub fn faces(&self) -> &[[u32; 3]] {
        self.template.faces()
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.template.n_vertices()
    }

    /// Number of shape components.
    pub fn n_betas(&self) -> usize {
        self.n_betas
    }

    /// Joint names and parents.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// Skin weights of the body vertices.
    pub fn skin_weights(&self) -> &SkinWeights {
        &self.skin_weights
    }

    /// Provenance and licence.
    pub fn provenance(&self) -> &Provenance {
        &self.provenance
    }

    /// Shape basis `(V·3) × n_betas`, row-major.
    pub fn shape_basis(&self) -> &[f64] {
        &self.shape_basis
    }

    /// Joint positions at β = 0.
    pub fn joint_template(&self) -> &[Vector3<f64>] {
        &self.joint_template
    }

    /// Joint shape basis `(J·3) × n_betas`, row-major.
    pub fn joint_shape_basis(&self) -> &[f64] {
        &self.joint_shape_basis
    }

    /// Check a shape vector: at most `n_betas` entries (missing ones are zero), all finite.
    pub fn check_betas(&self, betas: &[f64]) -> Result<()> {
        if betas.len() > self.n_betas {
            return Err(Error::invalid(
                "shape",
                format!("{} betas for a model with {}", betas.len(), self.n_betas),
            ));
        }
        if let Some(i) = betas.iter().position(|b| !b.is_finite()) {
            return Err(Error::invalid("shape", format!("beta {i} is {}", betas[i])));
        }
        Ok(())
    }

    fn apply_basis(
        base: &[Vector3<f64>],
        basis: &[f64],
        n_betas: usize,
        betas: &[f64],
        out: &mut [Vector3<f64>],
    ) {
        for (i, (o, b)) in out.iter_mut().zip(base).enumerate() {
            let mut p = *b;
            for c in 0..3 {
                let row = &basis[(i * 3 + c) * n_betas..(i * 3 + c) * n_betas + betas.len()];
                p[c] += row.iter().zip(betas).map(|(d, b)| d * b).sum::<f64>();
            }
            *o = p;
        }
    }

    /// `T_b(β)` into `out` (one entry per vertex).
    pub fn shaped_vertices_into(&self, betas: &[f64], out: &mut [Vector3<f64>]) -> Result<()> {
        self.check_betas(betas)?;
        if out.len() != self.n_vertices() {
            return Err(Error::invalid(
                "shape",
                format!(
                    "output has {} entries, model {}",
                    out.len(),
                    self.n_vertices()
                ),
            ));
        }
        Self::apply_basis(
            self.template.positions(),
            &self.shape_basis,
            self.n_betas,
            betas,
            out,
        );
        Ok(())
    }

    /// `T_b(β)`.
    pub fn shaped_vertices(&self, betas: &[f64]) -> Result<Vec<Vector3<f64>>> {
        let mut out = vec![Vector3::zeros(); self.n_vertices()];
        self.shaped_vertices_into(betas, &mut out)?;
        Ok(out)
    }

    /// Rest joint positions `J(β)`.
    pub fn shaped_joints(&self, betas: &[f64]) -> Result<Vec<Vector3<f64>>> {
        self.check_betas(betas)?;
        let mut out = vec![Vector3::zeros(); self.joint_template.len()];
        Self::apply_basis(
            &self.joint_template,
            &self.joint_shape_basis,
            self.n_betas,
            betas,
            &mut out,
        );
        Ok(out)
    }

    /// Skinning transforms of every joint for shape β and a pose.
    pub fn skinning_transforms(
        &self,
        betas: &[f64],
        pose: &Pose,
    ) -> Result<Vec<BoneTransform<f64>>> {
        let joints = self.shaped_joints(betas)?;
        Ok(self.skeleton.forward_kinematics(&joints, pose)?.1)
    }

    /// The posed body `M_b(β, θ)` (no pose-dependent correctives).
    pub fn posed_vertices(&self, betas: &[f64], pose: &Pose) -> Result<Vec<Vector3<f64>>> {
        let rest = self.shaped_vertices(betas)?;
        let transforms = self.skinning_transforms(betas, pose)?;
        let mut out = vec![Vector3::zeros(); rest.len()];
        skin_points(
            &rest,
            &self.skin_weights,
            &transforms,
            &mut out,
            Parallelism::Sequential,
        )?;
        Ok(out)
    }

    /// Standing height of `T_b(β)` in metres (vertical extent of the rest mesh).
    pub fn height_m(&self, betas: &[f64]) -> Result<f64> {
        let v = self.shaped_vertices(betas)?;
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.y), hi.max(p.y))
            });
        Ok(hi - lo)
    }

    /// SHA-256 (lower-case hex) of the model's tensor file as [`Self::save`] would write it
    /// now: identifies the body in the outputs made with it (deterministic for a given model
    /// file). It is the `tensors_sha256` of the `model.json` written with it; a model *loaded*
    /// from a file may hash differently from that file, because loading renormalises the skin
    /// weights (not bit-idempotent in f32).
    pub fn content_sha256(&self) -> Result<String> {
        Ok(sha256_hex(&self.tensor_bytes()?))
    }

    /// The body's identity: its name and [`Self::content_sha256`].
    pub fn asset_id(&self) -> Result<crate::asset::AssetId> {
        Ok(crate::asset::AssetId {
            id: self.name.clone(),
            sha256: self.content_sha256()?,
        })
    }

    /// The bytes of `model.safetensors` (deterministic).
    fn tensor_bytes(&self) -> Result<Vec<u8>> {
        let (v, j, nb) = (self.n_vertices(), self.skeleton.n_joints(), self.n_betas);
        let f32s = |xs: &[f64]| xs.iter().map(|&x| x as f32).collect::<Vec<_>>();
        let mut tensors = BTreeMap::new();
        tensors.insert(
            "v_template".to_string(),
            OwnedTensor::points(self.template.positions()),
        );
        tensors.insert("faces".to_string(), OwnedTensor::indices(self.faces()));
        tensors.insert(
            "shapedirs".to_string(),
            OwnedTensor::f32(&[v, 3, nb], f32s(&self.shape_basis)),
        );
        tensors.insert(
            "j_template".to_string(),
            OwnedTensor::points(&self.joint_template),
        );
        tensors.insert(
            "j_shapedirs".to_string(),
            OwnedTensor::f32(&[j, 3, nb], f32s(&self.joint_shape_basis)),
        );
        self.skin_weights.insert_tensors(&mut tensors, "skin_");
        serialize_tensors(&tensors, None)
    }

    /// Save into `dir` as `model.safetensors` + `model.json`, atomically and deterministically
    /// (values stored as f32; the same model gives the same bytes).
    pub fn save(&self, dir: &Path) -> Result<()> {
        let (v, nb) = (self.n_vertices(), self.n_betas);
        let bytes = self.tensor_bytes()?;
        let header = Header {
            format: FILES.format.into(),
            version: FILES.version,
            name: self.name.clone(),
            units: "m".into(),
            axes: AXES.into(),
            n_vertices: v,
            n_faces: self.template.n_faces(),
            n_betas: nb,
            joint_names: self.skeleton.names().to_vec(),
            parents: self.skeleton.parents().to_vec(),
            provenance: self.provenance.clone(),
            tensors_sha256: sha256_hex(&bytes),
        };
        FILES.write(dir, &header, &bytes)
    }

    /// Load a model saved by [`Self::save`] from `dir`, checking the header, the tensors' hash,
    /// every shape and every invariant.
    pub fn load(dir: &Path) -> Result<Self> {
        let (header_bytes, tensor_bytes) = FILES.read_bytes(dir)?;
        Self::from_bytes(dir, &header_bytes, tensor_bytes)
    }

    /// Parse a model from the bytes of its two files, read from folder `dir` (used in error
    /// messages only).
    pub fn from_bytes(dir: &Path, header_bytes: &[u8], bytes: Vec<u8>) -> Result<Self> {
        let (header, file): (Header, _) = FILES.parse(dir, header_bytes, bytes)?;
        let (header_path, tensor_path) = (dir.join(MODEL_HEADER), dir.join(MODEL_TENSORS));
        let in_file = |e: Error| e.in_file(&tensor_path);
        let (v, f, nb) = (header.n_vertices, header.n_faces, header.n_betas);
        let j = header.joint_names.len();
        let skeleton = Skeleton::new(header.joint_names, header.parents)
            .map_err(|e| e.in_file(&header_path))?;
        let vt = file.points("v_template", Some(v))?;
        let faces = file.indices("faces", Some(f))?;
        let template = TriMesh::new(vt, faces).map_err(in_file)?;
        let (_, shapedirs) = file.f32("shapedirs", &[Some(v), Some(3), Some(nb)])?;
        let jt = file.points("j_template", Some(j))?;
        let (_, jdirs) = file.f32("j_shapedirs", &[Some(j), Some(3), Some(nb)])?;
        let weights = SkinWeights::from_tensors(&file, "skin_", v, j)?;
        Self::new(
            header.name,
            template,
            nb,
            shapedirs.into_iter().map(f64::from).collect(),
            jt,
            jdirs.into_iter().map(f64::from).collect(),
            skeleton,
            weights,
            header.provenance,
        )
        .map_err(in_file)
    }
}

/// Poses the body into caller buffers, re-shaping only when β changes.
pub struct BodyPoser<'a> {
    body: &'a BodyModel,
    buffers: PoseBuffers,
}

impl<'a> BodyPoser<'a> {
    /// A poser of `body`; nothing is shaped until the first pose.
    pub fn new(body: &'a BodyModel) -> Self {
        Self {
            body,
            buffers: PoseBuffers::default(),
        }
    }

    /// `M_b(β, θ)` into `out`; afterwards [`BodyPoser::transforms`] are this pose's.
    pub fn pose_into(
        &mut self,
        betas: &[f64],
        pose: &Pose,
        out: &mut [Vector3<f64>],
    ) -> Result<()> {
        self.buffers.pose_into(self.body, betas, pose, out)
    }

    /// The body it poses.
    pub fn body(&self) -> &'a BodyModel {
        self.body
    }

    /// The shaped rest body `T_b(β)` of the last [`BodyPoser::pose_into`].
    pub fn shaped(&self) -> &[Vector3<f64>] {
        self.buffers.shaped()
    }

    /// The posed joint positions of the last [`BodyPoser::pose_into`].
    pub fn posed_joints(&self) -> &[Vector3<f64>] {
        self.buffers.posed_joints()
    }

    /// The skinning transforms of the last [`BodyPoser::pose_into`].
    pub fn transforms(&self) -> &[BoneTransform<f64>] {
        self.buffers.transforms()
    }
}

/// A [`BodyPoser`] that does not hold its body: each pose is given it. For a poser kept
/// beside its body rather than borrowing it (an `Arc` in the same struct). The shaped body is
/// kept for the β and the body (by address) of the last pose: give one body for as long as it
/// lives.
#[derive(Clone, Debug, Default)]
pub struct PoseBuffers {
    /// The body's address and the β of `shaped` and `joints`.
    shaped_for: Option<(usize, Vec<f64>)>,
    shaped: Vec<Vector3<f64>>,
    joints: Vec<Vector3<f64>>,
    posed_joints: Vec<Vector3<f64>>,
    transforms: Vec<BoneTransform<f64>>,
}

impl PoseBuffers {
    /// `M_b(β, θ)` of `body` into `out`; afterwards [`PoseBuffers::transforms`] are this
    /// pose's.
    pub fn pose_into(
        &mut self,
        body: &BodyModel,
        betas: &[f64],
        pose: &Pose,
        out: &mut [Vector3<f64>],
    ) -> Result<()> {
        self.prepare(body, betas, pose)?;
        skin_points(
            &self.shaped,
            body.skin_weights(),
            &self.transforms,
            out,
            Parallelism::Sequential,
        )?;
        Ok(())
    }

    /// [`PoseBuffers::pose_into`] for the body vertices `vertices` only: `out` (every body
    /// vertex) gets the same bits there and is left as it was elsewhere. For a caller that
    /// reads a few parts of the body per pose.
    pub fn pose_vertices_into(
        &mut self,
        body: &BodyModel,
        betas: &[f64],
        pose: &Pose,
        vertices: &[u32],
        out: &mut [Vector3<f64>],
    ) -> Result<()> {
        self.prepare(body, betas, pose)?;
        skin_points_at(
            &self.shaped,
            body.skin_weights(),
            &self.transforms,
            vertices,
            out,
        )
    }

    /// The shaped body for `betas` (kept while the body and β stay) and the forward kinematics
    /// of `pose`.
    fn prepare(&mut self, body: &BodyModel, betas: &[f64], pose: &Pose) -> Result<()> {
        let address = body as *const BodyModel as usize;
        let shaped = self
            .shaped_for
            .as_ref()
            .is_some_and(|(a, b)| *a == address && b == betas);
        if !shaped {
            // Unset first: a failed shaping must not leave the last body's key.
            self.shaped_for = None;
            let j = body.skeleton().n_joints();
            self.shaped.resize(body.n_vertices(), Vector3::zeros());
            self.posed_joints.resize(j, Vector3::zeros());
            self.transforms.resize(j, BoneTransform::identity());
            body.shaped_vertices_into(betas, &mut self.shaped)?;
            self.joints = body.shaped_joints(betas)?;
            self.shaped_for = Some((address, betas.to_vec()));
        }
        body.skeleton().forward_kinematics_into(
            &self.joints,
            pose,
            &mut self.posed_joints,
            &mut self.transforms,
        )
    }

    /// The shaped rest body `T_b(β)` of the last [`PoseBuffers::pose_into`].
    pub fn shaped(&self) -> &[Vector3<f64>] {
        &self.shaped
    }

    /// The posed joint positions of the last [`PoseBuffers::pose_into`].
    pub fn posed_joints(&self) -> &[Vector3<f64>] {
        &self.posed_joints
    }

    /// The skinning transforms of the last [`PoseBuffers::pose_into`].
    pub fn transforms(&self) -> &[BoneTransform<f64>] {
        &self.transforms
    }
}
