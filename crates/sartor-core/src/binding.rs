//! Binding other surfaces to the body: skin-weight transfer (the cloth skin weights `W_c` of
//! Santesteban et al.), the selection of the body region a garment can touch, points glued to
//! the body's surface ([`SurfaceAnchors`]), and the garment binding itself
//! ([`GarmentBinding`]). One implementation each, on [`MeshProximity`], used by the simulator,
//! the dataset and the runtime alike.
//!
//! # The garment binding
//!
//! What the runtime needs of the garment and of its attachment to the body, beside the network
//! weights. The dataset stage writes it (`binding.json` + `binding.safetensors` in the dataset
//! folder), the export step copies it into the model folder with the region at its margin, next
//! to `model.safetensors` + `model.json`: one type, one file format.
//!

//! ## Tensors (`V` garment vertices, `F` garment triangles, `R` region faces)
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
//! ## JSON (`deny_unknown_fields`)
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
//! `garment` and `body` must equal the model's (`model.json`) and `n_vertices` the model's
//! `sizes.n_vertices` (the runtime checks, `ModelHeader::check_binding`); `body_joints` and
//! `body_faces` must equal the body model's ([`GarmentBinding::check_body`]).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::asset::{AssetFiles, AssetId};
use crate::io::{OwnedTensor, serialize_tensors, sha256_hex};
use crate::{BodyModel, Error, MeshProximity, Result, SkinWeights};

/// Skin weights for arbitrary `points` from a skinned surface: each point takes the closest
/// point on the surface (`positions`, `faces`, one weight row per surface vertex) and blends the
/// weights of that triangle's three vertices with the barycentric coordinates. Weights below
/// `min_weight` are dropped and the rest renormalised (use 0 to keep every influence).
///
/// This is how `W_c` is defined in the paper: "each template cloth vertex is projected on the
/// closest triangle of the template body; its weights are the barycentric blend of that
/// triangle's body weights".
pub fn transfer_skin_weights(
    positions: &[Vector3<f64>],
    faces: &[[u32; 3]],
    weights: &SkinWeights,
    points: &[Vector3<f64>],
    min_weight: f32,
) -> Result<SkinWeights> {
    let proximity = MeshProximity::new(positions, faces)?;
    transfer_skin_weights_on(&proximity, weights, points, min_weight)
}

/// [`transfer_skin_weights`] from a surface whose closest-point structure is built already
/// (e.g. [`BodyModel::template_proximity`]): the same weights.
pub fn transfer_skin_weights_on(
    proximity: &MeshProximity,
    weights: &SkinWeights,
    points: &[Vector3<f64>],
    min_weight: f32,
) -> Result<SkinWeights> {
    let (positions, faces) = (proximity.positions(), proximity.faces());
    if weights.n_points() != positions.len() {
        return Err(Error::invalid(
            "skin-weight transfer",
            format!(
                "{} weight rows for a surface of {} vertices",
                weights.n_points(),
                positions.len()
            ),
        ));
    }
    if !(min_weight.is_finite() && (0.0..0.5).contains(&min_weight)) {
        return Err(Error::invalid(
            "skin-weight transfer",
            format!("min_weight must be in [0, 0.5), got {min_weight}"),
        ));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(Error::invalid(
            "skin-weight transfer",
            format!("point {i} is not finite"),
        ));
    }
    let mut offsets = Vec::with_capacity(points.len() + 1);
    offsets.push(0u32);
    let (mut joints, mut values) = (Vec::new(), Vec::new());
    let mut row: BTreeMap<usize, f64> = BTreeMap::new();
    for p in points {
        let c = proximity.closest(p);
        row.clear();
        let face = faces[c.face as usize];
        for (k, &v) in face.iter().enumerate() {
            for (j, w) in weights.point(v as usize) {
                *row.entry(j).or_default() += c.barycentric[k] * w as f64;
            }
        }
        let kept: f64 = row.values().filter(|&&w| w >= min_weight as f64).sum();
        // The largest weight is at least 1/n_joints ≥ min_weight's bound, so `kept` > 0 unless
        // every weight is tiny; then keep them all.
        let threshold = if kept > 0.0 { min_weight as f64 } else { 0.0 };
        let total: f64 = row.values().filter(|&&w| w >= threshold).sum();
        for (&j, &w) in &row {
            if w >= threshold && w > 0.0 {
                joints.push(j as u32);
                values.push((w / total) as f32);
            }
        }
        offsets.push(joints.len() as u32);
    }
    SkinWeights::new(offsets, joints, values, weights.n_joints())
}

/// The faces of a surface (`positions`, `faces`) with at least one vertex within `margin_m` of
/// another surface (`other_positions`, `other_faces`), ascending. Used to restrict body contact
/// to the region a garment can reach.
pub fn faces_near(
    positions: &[Vector3<f64>],
    faces: &[[u32; 3]],
    other_positions: &[Vector3<f64>],
    other_faces: &[[u32; 3]],
    margin_m: f64,
) -> Result<Vec<u32>> {
    if !(margin_m.is_finite() && margin_m >= 0.0) {
        return Err(Error::invalid(
            "region selection",
            format!("margin must be finite and ≥ 0, got {margin_m}"),
        ));
    }
    let other = MeshProximity::new(other_positions, other_faces)?;
    let near: Vec<bool> = positions
        .iter()
        .map(|p| other.closest_within(p, margin_m).is_some())
        .collect();
    Ok(faces
        .iter()
        .enumerate()
        .filter(|(_, t)| t.iter().any(|&v| near[v as usize]))
        .map(|(f, _)| f as u32)
        .collect())
}

/// Points glued to a surface: each point's closest triangle of the surface in its rest state
/// and the barycentric weights of the closest point on it. The point then follows the surface's
/// change — `Σ_k b_k (to − from)[f_k]` — as if glued to it: how the simulator carries a garment
/// through a body's shape change, and how the runtime fits a garment to a shape without a
/// network (or beyond the trained shapes).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceAnchors {
    anchors: Vec<([u32; 3], [f64; 3])>,
}

impl SurfaceAnchors {
    /// Anchor `points` to their closest points on the surface (`positions`, `faces`).
    pub fn new(
        positions: &[Vector3<f64>],
        faces: &[[u32; 3]],
        points: impl IntoIterator<Item = Vector3<f64>>,
    ) -> Result<Self> {
        let proximity = MeshProximity::new(positions, faces)?;
        Ok(Self::on(&proximity, points))
    }

    /// Anchor `points` to their closest points on a surface whose closest-point structure is
    /// built already (e.g. [`BodyModel::template_proximity`]).
    pub fn on(proximity: &MeshProximity, points: impl IntoIterator<Item = Vector3<f64>>) -> Self {
        let faces = proximity.faces();
        let anchors = points
            .into_iter()
            .map(|p| {
                let c = proximity.closest(&p);
                (faces[c.face as usize], c.barycentric)
            })
            .collect();
        Self { anchors }
    }

    /// Anchored points.
    pub fn len(&self) -> usize {
        self.anchors.len()
    }

    /// Whether no point is anchored.
    pub fn is_empty(&self) -> bool {
        self.anchors.is_empty()
    }

    /// Point `i`'s displacement as the surface moves from `from` to `to` (every surface
    /// vertex, in the order of the positions given at construction).
    ///
    /// # Panics
    /// If `i` is out of range or `from`/`to` are shorter than the surface.
    #[inline]
    pub fn displacement(
        &self,
        i: usize,
        to: &[Vector3<f64>],
        from: &[Vector3<f64>],
    ) -> Vector3<f64> {
        let (tri, b) = &self.anchors[i];
        let mut delta = Vector3::zeros();
        for (&v, &w) in tri.iter().zip(b) {
            delta += (to[v as usize] - from[v as usize]) * w;
        }
        delta
    }
}

/// Default margin of the body region, mm: body triangles farther than this from the garment
/// template never take part in the collision post-process.
pub const DEFAULT_REGION_MARGIN_MM: f64 = 60.0;

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

crate::asset_header!(BindingHeader);

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
    /// garment surface). The dataset binds its garment this way, with `T̄_c = ρ(relaxed
    /// garment)`; so do benchmarks and users who bring their own garment.
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
        let skin_weights = transfer_skin_weights_on(
            body.template_proximity()?,
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

    /// The same binding with the body region chosen again: body faces with a vertex within
    /// `region_margin_m` of the template, in the body's template (β = 0, rest pose).
    pub fn with_region(self, body: &BodyModel, region_margin_m: f64) -> Result<Self> {
        let template: Vec<Vector3<f64>> = self.template.iter().map(|p| p.cast()).collect();
        let rest = body.template().positions();
        let region = faces_near(rest, body.faces(), &template, &self.faces, region_margin_m)?;
        Self::new(
            self.garment,
            self.body,
            self.template,
            self.faces,
            self.skin_weights,
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
        t.insert("template".to_string(), OwnedTensor::points(&self.template));
        t.insert("faces".to_string(), OwnedTensor::indices(&self.faces));
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
        let (header, tensors) = FILES.read_bytes(dir)?;
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
        let template = file.points("template", Some(v))?;
        let faces = file.indices("faces", Some(f))?;
        let skin_weights = SkinWeights::from_tensors(&file, "skin.", v, header.body_joints)?;
        let (_, region) = file.u32("region.faces", &[Some(r)])?;
        let template = template.iter().map(|p| p.cast::<f32>()).collect();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles in the z = 0 plane: a unit square split on its diagonal.
    fn square() -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        (
            vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(1.0, 0.0, 0.0),
                Vector3::new(1.0, 1.0, 0.0),
                Vector3::new(0.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn transferred_weights_are_the_barycentric_blend() {
        let (positions, faces) = square();
        // Vertex 0, 1 on joint 0; 2 on joint 1; 3 half-half.
        let weights = SkinWeights::new(
            vec![0, 1, 2, 3, 5],
            vec![0, 0, 1, 0, 1],
            vec![1.0, 1.0, 1.0, 0.5, 0.5],
            2,
        )
        .expect("valid");
        // Above the first triangle at barycentric (0.2, 0.5, 0.3): x = 0.8, y = 0.3.
        let points = [Vector3::new(0.8, 0.3, 0.05)];
        let w = transfer_skin_weights(&positions, &faces, &weights, &points, 0.0).expect("ok");
        let dense = w.to_dense();
        assert!((dense[0] - 0.7).abs() < 1e-6, "{dense:?}");
        assert!((dense[1] - 0.3).abs() < 1e-6, "{dense:?}");
        // Dropping influences below 0.4 keeps joint 0 alone.
        let w = transfer_skin_weights(&positions, &faces, &weights, &points, 0.4).expect("ok");
        assert_eq!(w.point(0).collect::<Vec<_>>(), vec![(0, 1.0)]);
    }

    #[test]
    fn transfer_rejects_bad_input() {
        let (positions, faces) = square();
        let weights = SkinWeights::from_dense_top_k(&[1.0; 3], 1, 1).expect("valid");
        let p = [Vector3::zeros()];
        assert!(transfer_skin_weights(&positions, &faces, &weights, &p, 0.0).is_err());
        let weights = SkinWeights::from_dense_top_k(&[1.0; 4], 1, 1).expect("valid");
        let nan = [Vector3::new(f64::NAN, 0.0, 0.0)];
        assert!(transfer_skin_weights(&positions, &faces, &weights, &nan, 0.0).is_err());
        assert!(transfer_skin_weights(&positions, &faces, &weights, &p, 0.7).is_err());
    }

    #[test]
    fn faces_near_selects_by_vertex_distance() {
        let (positions, faces) = square();
        // A small triangle 0.1 above vertex 3 (0, 1, 0).
        let other = vec![
            Vector3::new(-0.05, 1.0, 0.1),
            Vector3::new(0.0, 1.05, 0.1),
            Vector3::new(-0.05, 1.05, 0.1),
        ];
        let near = faces_near(&positions, &faces, &other, &[[0, 1, 2]], 0.15).expect("ok");
        assert_eq!(near, vec![1]);
        let none = faces_near(&positions, &faces, &other, &[[0, 1, 2]], 0.05).expect("ok");
        assert!(none.is_empty());
        assert!(faces_near(&positions, &faces, &other, &[[0, 1, 2]], -1.0).is_err());
    }
}
