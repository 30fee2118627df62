//! The garment binding: what the runtime needs of the garment and of its attachment to the
//! body, beside the network weights. Saved in the exported model folder as
//! `binding.safetensors` + `binding.json`, next to `model.safetensors` + `model.json`.
//!
//! # Tensors (`V` garment vertices, `F` garment triangles, `R` region faces)
//!
//! | name | dtype, shape | |
//! | --- | --- | --- |
//! | `template` | f32 `[V, 3]` | the garment template `T̄_c`, metres, on the template body |
//! | `faces` | i32 `[F, 3]` | garment triangles (indices into `template`) |
//! | `skin.offsets` | i32 `[V + 1]` | cloth skin weights `W_c`, CSR row offsets |
//! | `skin.joints` | i32 `[N]` | `W_c` joint indices (body skeleton order) |
//! | `skin.weights` | f32 `[N]` | `W_c` weights, each row sums to 1 |
//! | `region.faces` | i32 `[R]` | body faces the garment can touch, strictly ascending |
//!
//! No other tensor may be present.
//!
//! # JSON (`deny_unknown_fields`)
//!
//! ```json
//! {
//!   "format": "sartor-garment-binding",
//!   "version": 1,
//!   "garment": { "id": "tshirt-8710", "sha256": "<64 hex>" },
//!   "body": { "id": "makehuman", "sha256": "<64 hex>" },
//!   "n_vertices": 4424, "n_faces": 8710,
//!   "body_joints": 31, "body_faces": 26000, "region_faces": 9000,
//!   "tensors_sha256": "<sha256 of binding.safetensors>"
//! }
//! ```
//!
//! `garment` and `body` must equal the model's (`model.json`); `n_vertices` must equal the
//! model's `sizes.n_vertices`; `body_joints` and `body_faces` must equal the body model's.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use nalgebra::Vector3;
use sartor_core::asset::AssetFiles;
use sartor_core::io::{OwnedTensor, read_file, serialize_tensors, sha256_hex};
use sartor_core::{BodyModel, SkinWeights, faces_near, transfer_skin_weights};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::format::{AssetId, ModelHeader};

/// The `format` string of `binding.json`.
pub const BINDING_FORMAT: &str = "sartor-garment-binding";
/// The `version` of `binding.json` this crate reads and writes.
pub const BINDING_VERSION: u32 = 1;
/// File name of the binding's JSON sidecar inside a model folder.
pub const BINDING_JSON: &str = "binding.json";
/// File name of the binding's tensors inside a model folder.
pub const BINDING_TENSORS: &str = "binding.safetensors";

/// The binding's file pair.
const FILES: AssetFiles = AssetFiles {
    header: BINDING_JSON,
    tensors: BINDING_TENSORS,
    format: BINDING_FORMAT,
    version: BINDING_VERSION,
};

/// The contents of `binding.json`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BindingHeader {
    /// Always [`BINDING_FORMAT`].
    pub format: String,
    /// Always [`BINDING_VERSION`].
    pub version: u32,
    /// The garment.
    pub garment: AssetId,
    /// The body model.
    pub body: AssetId,
    /// Garment vertices `V`.
    pub n_vertices: usize,
    /// Garment triangles `F`.
    pub n_faces: usize,
    /// Joints of the body skeleton (`W_c` refers to them).
    pub body_joints: usize,
    /// Triangles of the body mesh (region indices are below this).
    pub body_faces: usize,
    /// Body faces in the region `R`.
    pub region_faces: usize,
    /// SHA-256 of `binding.safetensors`.
    pub tensors_sha256: String,
}

sartor_core::asset_header!(BindingHeader);

/// A garment bound to a body: template `T̄_c`, triangles, cloth skin weights `W_c` and the body
/// region the garment can touch. Validated on construction: finite template, face indices in
/// range and not repeated within a face, one weight row per vertex, region faces strictly
/// ascending and below the body's face count, well-formed asset ids.
#[derive(Clone, Debug, PartialEq)]
pub struct GarmentBinding {
    garment: AssetId,
    body: AssetId,
    template: Vec<Vector3<f32>>,
    faces: Vec<[u32; 3]>,
    skin_weights: SkinWeights,
    region_faces: Vec<u32>,
    body_faces: usize,
}

impl GarmentBinding {
    /// Build from parts (the export step passes the dataset's `T̄_c` and `W_c`): `region_faces`
    /// index the body's `body_faces` triangles.
    pub fn new(
        garment: AssetId,
        body: AssetId,
        template: Vec<Vector3<f32>>,
        faces: Vec<[u32; 3]>,
        skin_weights: SkinWeights,
        region_faces: Vec<u32>,
        body_faces: usize,
    ) -> Result<Self> {
        let bad = |m: String| Error::invalid("garment binding", m);
        garment.check("garment").map_err(bad)?;
        body.check("body").map_err(bad)?;
        let v = template.len();
        if v == 0 || faces.is_empty() {
            return Err(bad(format!(
                "{v} template vertices and {} faces: both must be positive",
                faces.len()
            )));
        }
        if let Some(i) = template
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(bad(format!("template vertex {i} is not finite")));
        }
        for (f, t) in faces.iter().enumerate() {
            if t.iter().any(|&i| i as usize >= v) {
                return Err(bad(format!("face {f} {t:?} indexes past {v} vertices")));
            }
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                return Err(bad(format!("face {f} {t:?} repeats a vertex")));
            }
        }
        if skin_weights.n_points() != v {
            return Err(bad(format!(
                "{} skin-weight rows for {v} template vertices",
                skin_weights.n_points()
            )));
        }
        if region_faces.is_empty() {
            return Err(bad("the body region is empty".into()));
        }
        if let Some(k) = region_faces.windows(2).position(|w| w[1] <= w[0]) {
            return Err(bad(format!(
                "region faces are not strictly ascending at position {}",
                k + 1
            )));
        }
        if let Some(&last) = region_faces.last()
            && last as usize >= body_faces
        {
            return Err(bad(format!(
                "region face {last} is past the body's {body_faces} faces"
            )));
        }
        Ok(Self {
            garment,
            body,
            template,
            faces,
            skin_weights,
            region_faces,
            body_faces,
        })
    }

    /// Bind a garment mesh to `body` in its template (β = 0, rest pose): `W_c` by
    /// [`transfer_skin_weights`] from the body template (influences below `min_weight` dropped),
    /// the region by [`faces_near`] (body faces with a vertex within `region_margin_m` of the
    /// garment surface). For benchmarks and for users who bring their own garment; a trained
    /// model's export uses [`GarmentBinding::new`] with the dataset's `T̄_c` and `W_c`.
    pub fn from_body(
        garment: AssetId,
        positions: &[Vector3<f64>],
        faces: &[[u32; 3]],
        body_id: AssetId,
        body: &BodyModel,
        region_margin_m: f64,
        min_weight: f32,
    ) -> Result<Self> {
        let rest = body.template().positions();
        let skin_weights = transfer_skin_weights(
            rest,
            body.faces(),
            body.skin_weights(),
            positions,
            min_weight,
        )?;
        let region = faces_near(rest, body.faces(), positions, faces, region_margin_m)?;
        Self::new(
            garment,
            body_id,
            positions.iter().map(|p| p.cast::<f32>()).collect(),
            faces.to_vec(),
            skin_weights,
            region,
            body.faces().len(),
        )
    }

    /// The garment id.
    pub fn garment(&self) -> &AssetId {
        &self.garment
    }

    /// The body id.
    pub fn body(&self) -> &AssetId {
        &self.body
    }

    /// `T̄_c`, `[V]`, metres.
    pub fn template(&self) -> &[Vector3<f32>] {
        &self.template
    }

    /// Garment triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Number of garment vertices `V`.
    pub fn n_vertices(&self) -> usize {
        self.template.len()
    }

    /// `W_c`.
    pub fn skin_weights(&self) -> &SkinWeights {
        &self.skin_weights
    }

    /// Body faces the garment can touch, ascending.
    pub fn region_faces(&self) -> &[u32] {
        &self.region_faces
    }

    /// Number of faces of the body this binding was made for.
    pub fn body_faces(&self) -> usize {
        self.body_faces
    }

    /// Check that `header` describes a model of this garment on this body: same garment and
    /// body ids and hashes, same vertex count.
    pub fn check_model(&self, header: &ModelHeader) -> Result<()> {
        let bad = |m: String| Err(Error::invalid("garment binding", m));
        if header.sizes.n_vertices != self.n_vertices() {
            return bad(format!(
                "the model has {} garment vertices, the binding {}",
                header.sizes.n_vertices,
                self.n_vertices()
            ));
        }
        if header.garment != self.garment {
            return bad(format!(
                "the model is for garment {:?} ({}), the binding for {:?} ({})",
                header.garment.id, header.garment.sha256, self.garment.id, self.garment.sha256
            ));
        }
        if header.body != self.body {
            return bad(format!(
                "the model is for body {:?} ({}), the binding for {:?} ({})",
                header.body.id, header.body.sha256, self.body.id, self.body.sha256
            ));
        }
        Ok(())
    }

    /// Check that `body` has the skeleton and mesh this binding refers to (joint and face
    /// counts).
    pub fn check_body(&self, body: &BodyModel) -> Result<()> {
        let joints = body.skeleton().n_joints();
        if self.skin_weights.n_joints() != joints {
            return Err(Error::invalid(
                "garment binding",
                format!(
                    "W_c refers to {} joints, the body {:?} has {joints}",
                    self.skin_weights.n_joints(),
                    body.name()
                ),
            ));
        }
        if self.body_faces != body.faces().len() {
            return Err(Error::invalid(
                "garment binding",
                format!(
                    "made for a body of {} faces, the body {:?} has {}",
                    self.body_faces,
                    body.name(),
                    body.faces().len()
                ),
            ));
        }
        Ok(())
    }

    /// The JSON header (with an empty hash) and the safetensors bytes (deterministic).
    fn to_parts(&self) -> Result<(BindingHeader, Vec<u8>)> {
        let i32s = |xs: &[u32]| xs.iter().map(|&x| x as i32).collect::<Vec<_>>();
        let mut t = BTreeMap::new();
        t.insert(
            "template".to_string(),
            OwnedTensor::f32(
                &[self.template.len(), 3],
                self.template.iter().flat_map(|p| [p.x, p.y, p.z]),
            ),
        );
        t.insert(
            "faces".to_string(),
            OwnedTensor::i32(
                &[self.faces.len(), 3],
                self.faces.iter().flatten().map(|&i| i as i32),
            ),
        );
        self.skin_weights.insert_tensors(&mut t, "skin.");
        t.insert(
            "region.faces".to_string(),
            OwnedTensor::i32(&[self.region_faces.len()], i32s(&self.region_faces)),
        );
        let bytes = serialize_tensors(&t, None)?;
        let header = BindingHeader {
            format: BINDING_FORMAT.into(),
            version: BINDING_VERSION,
            garment: self.garment.clone(),
            body: self.body.clone(),
            n_vertices: self.template.len(),
            n_faces: self.faces.len(),
            body_joints: self.skin_weights.n_joints(),
            body_faces: self.body_faces,
            region_faces: self.region_faces.len(),
            tensors_sha256: sha256_hex(&bytes),
        };
        Ok((header, bytes))
    }

    /// Write `dir/binding.safetensors` and `dir/binding.json` atomically; returns the header
    /// as written.
    pub fn save(&self, dir: &Path) -> Result<BindingHeader> {
        let (header, bytes) = self.to_parts()?;
        FILES.write(dir, &header, &bytes)?;
        Ok(header)
    }

    /// Read and validate `dir/binding.json` and `dir/binding.safetensors`: JSON fields, the
    /// tensors' hash, the exact set of tensors, dtypes and shapes against the header, and every
    /// invariant of [`GarmentBinding::new`]. Errors name the file and the fault.
    pub fn load(dir: &Path) -> Result<Self> {
        let header = read_file(&dir.join(BINDING_JSON))?;
        let tensors = read_file(&dir.join(BINDING_TENSORS))?;
        Self::from_bytes(dir, &header, tensors)
    }

    /// [`Self::load`] from the two files' bytes, read from folder `dir` (named in errors
    /// only): how a web page, which has no file system, loads the binding it fetched.
    pub fn from_bytes(dir: &Path, header_bytes: &[u8], tensor_bytes: Vec<u8>) -> Result<Self> {
        let (header, file): (BindingHeader, _) = FILES.parse(dir, header_bytes, tensor_bytes)?;
        let (json_path, path) = (dir.join(BINDING_JSON), dir.join(BINDING_TENSORS));
        let bad_json = |m: String| Error::format(&json_path, m);
        header.garment.check("garment").map_err(bad_json)?;
        header.body.check("body").map_err(bad_json)?;
        let expected: BTreeSet<&str> = [
            "template",
            "faces",
            "skin.offsets",
            "skin.joints",
            "skin.weights",
            "region.faces",
        ]
        .into();
        for name in file.names() {
            if !expected.contains(name.as_str()) {
                return Err(Error::format(&path, format!("unexpected tensor {name:?}")));
            }
        }
        let (v, f, r) = (header.n_vertices, header.n_faces, header.region_faces);
        let (_, template) = file.f32("template", &[Some(v), Some(3)])?;
        let (_, faces) = file.u32("faces", &[Some(f), Some(3)])?;
        let faces = faces.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let skin_weights = SkinWeights::from_tensors(&file, "skin.", v, header.body_joints)?;
        let (_, region) = file.u32("region.faces", &[Some(r)])?;
        let template = template
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect();
        Self::new(
            header.garment,
            header.body,
            template,
            faces,
            skin_weights,
            region,
            header.body_faces,
        )
        .map_err(|e| e.in_file(&path))
    }
}
