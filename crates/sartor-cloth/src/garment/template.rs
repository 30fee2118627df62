//! The [`Garment`] type: a garment template (positions on the template body, triangles), its
//! rest metric per triangle, its material frames, its bending hinges with their rest angles,
//! and its file format.
//!
//! # Files (`datasets/garments/<name>/`)
//!
//! - `garment.safetensors` (all little-endian, values f32, indices i32):
//!   `positions [V, 3]` (m), `faces [F, 3]`, `rest_dm [F, 2, 2]`, `rest_area_m2 [F]`,
//!   `frame_u [F, 3]`, `frame_v [F, 3]`, `hinges [H, 4]`, `rest_dihedral_rad [H]`.
//! - `garment.json`: format, version, name, units, axes, sizes, where the rest metric comes
//!   from, the material-frame convention, provenance and the SHA-256 of the tensor file.
//! - `garment.obj`: the template positions for viewing.
//!
//! Every stored float is f32; [`Garment`]'s constructors round their inputs to f32 precision
//! before deriving anything, so a saved garment loads back *identical* and saving twice gives
//! the same bytes.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix2, Vector2, Vector3};
use sartor_core::asset::{AssetFiles, AssetId};
use sartor_core::io::{OwnedTensor, serialize_tensors, sha256_hex, write_atomic};
use sartor_core::{TriMesh, obj_text};
use serde::{Deserialize, Serialize};

use crate::energy::dihedral_angle;
use crate::{Error, Result};

/// File name of a saved garment's tensors inside its folder.
pub const GARMENT_TENSORS: &str = "garment.safetensors";
/// File name of a saved garment's JSON header inside its folder.
pub const GARMENT_HEADER: &str = "garment.json";
/// File name of the OBJ written next to a saved garment for viewing.
pub const GARMENT_OBJ: &str = "garment.obj";
/// File name of the quality report written next to a saved garment.
pub const GARMENT_REPORT: &str = "garment-report.json";

/// The garment's file pair.
const FILES: AssetFiles = AssetFiles {
    header: GARMENT_HEADER,
    tensors: GARMENT_TENSORS,
    format: "sartor-garment",
    version: 1,
};
const AXES: &str = "+Y up, +Z forward, +X body's left";

/// The material-frame convention, stored in every header.
pub const MATERIAL_FRAME_CONVENTION: &str = "per triangle: frame_u, frame_v unit and orthonormal in \
the template triangle's plane, frame_u x frame_v = outward normal. Procedural garments: on the torso \
v is the up direction (+Y) projected on the triangle (where the surface is nearly horizontal, the \
direction over the shoulder towards the body's mid-plane), u = v x n runs around the body; on a sleeve \
v runs along the upper-arm bone from elbow to shoulder and u around the arm. Pattern garments: u, v \
are the pattern's x and y axes (x mirrored on mirrored pieces) carried to 3D. rest_dm holds, per \
triangle, the rest edges x1-x0 (column 0) and x2-x0 (column 1) in (u, v) coordinates; det > 0.";

/// Where a garment's rest metric comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RestSource {
    /// The template surface itself is the rest state (the procedural garments).
    Surface,
    /// A flat 2D sewing pattern (an OBJ's `vt` coordinates); rest dihedral angles are zero.
    Pattern,
}

/// What kind of input a garment was made from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceKind {
    /// A procedural recipe (JSON config).
    Recipe,
    /// A user OBJ.
    Obj,
}

/// Where a garment comes from.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GarmentProvenance {
    /// Recipe or OBJ.
    pub kind: SourceKind,
    /// The input file's path as given.
    pub path: String,
    /// SHA-256 of the input file's bytes (lower-case hex).
    pub sha256: String,
    /// The body model the garment was made on, if any (its name and content hash, the same
    /// identity simulations and exported models record).
    pub body: Option<AssetId>,
}

/// A garment template ready for the simulator: the template mesh `T̄_c` (positions on the
/// template body, β = 0, rest pose), and per triangle the material frame and the rest metric.
///
/// Invariants (checked by every constructor): the mesh is one connected, oriented 2-manifold
/// with at least one boundary loop, every vertex belongs to a triangle, no triangle is
/// degenerate in 3D or in its rest metric (`det rest_dm > 0`), every value is finite and
/// exactly representable in f32.
#[derive(Clone, Debug, PartialEq)]
pub struct Garment {
    name: String,
    mesh: TriMesh,
    rest_source: RestSource,
    rest_dm: Vec<Matrix2<f64>>,
    rest_area_m2: Vec<f64>,
    frame_u: Vec<Vector3<f64>>,
    frame_v: Vec<Vector3<f64>>,
    hinges: Vec<[u32; 4]>,
    rest_dihedral_rad: Vec<f64>,
    provenance: GarmentProvenance,
}

/// Round to the nearest f32 (storage precision).
fn r32(x: f64) -> f64 {
    x as f32 as f64
}

fn r32v(p: &Vector3<f64>) -> Vector3<f64> {
    p.map(r32)
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
    n_hinges: usize,
    rest_source: RestSource,
    material_frame: String,
    provenance: GarmentProvenance,
    tensors_sha256: String,
}

sartor_core::asset_header!(Header, units);

impl Garment {
    /// A garment whose rest state is its template surface, with the material u direction of
    /// each triangle given by `u_axes` (projected onto the triangle; `v = n × u`).
    pub fn from_surface(
        name: &str,
        mesh: &TriMesh,
        u_axes: &[Vector3<f64>],
        provenance: GarmentProvenance,
    ) -> Result<Self> {
        let mesh = round_mesh(mesh)?;
        if u_axes.len() != mesh.n_faces() {
            return Err(Error::invalid(
                "garment",
                format!("{} u axes for {} triangles", u_axes.len(), mesh.n_faces()),
            ));
        }
        let p = mesh.positions();
        let mut rest_dm = Vec::with_capacity(mesh.n_faces());
        for (f, (t, axis)) in mesh.faces().iter().zip(u_axes).enumerate() {
            let x = t.map(|i| p[i as usize]);
            let (e1, e2) = (x[1] - x[0], x[2] - x[0]);
            let n = e1.cross(&e2).normalize();
            let u = (axis - n * n.dot(axis))
                .try_normalize(1e-6 * axis.norm())
                .filter(|u| u.iter().all(|c| c.is_finite()))
                .ok_or_else(|| {
                    Error::invalid(
                        "garment",
                        format!("the u axis of triangle {f} is zero, non-finite or normal to it"),
                    )
                })?;
            let v = n.cross(&u);
            rest_dm.push(Matrix2::new(u.dot(&e1), u.dot(&e2), v.dot(&e1), v.dot(&e2)));
        }
        let hinges = hinges_of(&mesh);
        let rest_dihedral = hinges
            .iter()
            .map(|h| dihedral_angle(&h.map(|i| p[i as usize])))
            .collect();
        Self::assemble(
            name,
            mesh,
            RestSource::Surface,
            rest_dm,
            hinges,
            rest_dihedral,
            provenance,
        )
    }

    /// A garment whose rest metric comes from a flat 2D pattern: `uv_m[face_uv[f][k]]` is the
    /// rest position (m) of corner `k` of triangle `f`. A triangle that is mirrored in the
    /// pattern (clockwise) gets its u axis mirrored, which leaves its metric unchanged. Rest
    /// dihedral angles are zero (the pattern is flat).
    pub fn from_pattern(
        name: &str,
        mesh: &TriMesh,
        uv_m: &[Vector2<f64>],
        face_uv: &[[u32; 3]],
        provenance: GarmentProvenance,
    ) -> Result<Self> {
        let mesh = round_mesh(mesh)?;
        if face_uv.len() != mesh.n_faces() {
            return Err(Error::invalid(
                "garment pattern",
                format!(
                    "{} texture triangles for {} triangles",
                    face_uv.len(),
                    mesh.n_faces()
                ),
            ));
        }
        let mut rest_dm = Vec::with_capacity(face_uv.len());
        for (f, t) in face_uv.iter().enumerate() {
            if let Some(&i) = t.iter().find(|&&i| i as usize >= uv_m.len()) {
                return Err(Error::invalid(
                    "garment pattern",
                    format!("triangle {f} uses texture coordinate {i} of {}", uv_m.len()),
                ));
            }
            let x = t.map(|i| uv_m[i as usize].map(r32));
            let (e1, e2) = (x[1] - x[0], x[2] - x[0]);
            let mut dm = Matrix2::new(e1.x, e2.x, e1.y, e2.y);
            if dm.determinant() < 0.0 {
                dm.row_mut(0).neg_mut();
            }
            rest_dm.push(dm);
        }
        let hinges = hinges_of(&mesh);
        let zeros = vec![0.0; hinges.len()];
        Self::assemble(
            name,
            mesh,
            RestSource::Pattern,
            rest_dm,
            hinges,
            zeros,
            provenance,
        )
    }

    /// The same garment (rest metric, rest angles, provenance) with new template positions:
    /// the hook for relaxing a garment on the body before it is saved. Material frames follow
    /// the new positions.
    pub fn with_template_positions(&self, positions: Vec<Vector3<f64>>) -> Result<Self> {
        let mesh = round_mesh(&self.mesh.with_positions(positions)?)?;
        Self::assemble(
            &self.name,
            mesh,
            self.rest_source,
            self.rest_dm.clone(),
            self.hinges.clone(),
            self.rest_dihedral_rad.clone(),
            self.provenance.clone(),
        )
    }

    /// The same garment with another provenance record.
    pub fn with_provenance(mut self, provenance: GarmentProvenance) -> Self {
        self.provenance = provenance;
        self
    }

    /// Validate and derive areas and frames. `mesh` is already rounded to f32.
    fn assemble(
        name: &str,
        mesh: TriMesh,
        rest_source: RestSource,
        rest_dm: Vec<Matrix2<f64>>,
        hinges: Vec<[u32; 4]>,
        rest_dihedral_rad: Vec<f64>,
        provenance: GarmentProvenance,
    ) -> Result<Self> {
        let bad = |m: String| Error::invalid("garment", m);
        if name.is_empty() || name.contains(['/', '\\']) {
            return Err(bad(format!(
                "name {name:?} must be non-empty and have no slashes"
            )));
        }
        check_garment_topology(&mesh)?;
        let n_f = mesh.n_faces();
        if rest_dm.len() != n_f || rest_dihedral_rad.len() != hinges.len() {
            return Err(bad(format!(
                "{} rest matrices for {n_f} triangles, {} rest angles for {} hinges",
                rest_dm.len(),
                rest_dihedral_rad.len(),
                hinges.len()
            )));
        }
        let rest_dm: Vec<Matrix2<f64>> = rest_dm.iter().map(|m| m.map(r32)).collect();
        let rest_dihedral_rad: Vec<f64> = rest_dihedral_rad.iter().map(|&a| r32(a)).collect();
        if let Some(i) = rest_dihedral_rad.iter().position(|a| !a.is_finite()) {
            return Err(bad(format!("rest angle of hinge {i} is not finite")));
        }
        let p = mesh.positions();
        let mut rest_area_m2 = Vec::with_capacity(n_f);
        let mut frame_u = Vec::with_capacity(n_f);
        let mut frame_v = Vec::with_capacity(n_f);
        for (f, (t, dm)) in mesh.faces().iter().zip(&rest_dm).enumerate() {
            let det = dm.determinant();
            let scale = dm.column(0).norm_squared().max(dm.column(1).norm_squared());
            if !(det.is_finite() && det > 1e-10 * scale && scale > 0.0) {
                return Err(bad(format!(
                    "triangle {f} has a degenerate rest shape (rest edge matrix {:?})",
                    dm.as_slice()
                )));
            }
            let inv = dm
                .try_inverse()
                .ok_or_else(|| bad(format!("triangle {f}: rest edge matrix is singular")))?;
            let x = t.map(|i| p[i as usize]);
            let (e1, e2) = (x[1] - x[0], x[2] - x[0]);
            let n = e1.cross(&e2).normalize();
            // Deformation gradient F = Ds Dm⁻¹ (3 × 2); u is its first column's direction.
            let fu = e1 * inv[(0, 0)] + e2 * inv[(1, 0)];
            let u = fu
                .try_normalize(0.0)
                .ok_or_else(|| bad(format!("triangle {f}: material u axis collapses in 3D")))?;
            let v = n.cross(&u);
            rest_area_m2.push(r32(0.5 * det));
            frame_u.push(r32v(&u));
            frame_v.push(r32v(&v));
        }
        Ok(Self {
            name: name.to_string(),
            mesh,
            rest_source,
            rest_dm,
            rest_area_m2,
            frame_u,
            frame_v,
            hinges,
            rest_dihedral_rad,
            provenance,
        })
    }

    /// The garment's name (its folder name under `datasets/garments/`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The template mesh `T̄_c` (positions in m, triangles counter-clockwise seen from outside).
    pub fn mesh(&self) -> &TriMesh {
        &self.mesh
    }

    /// Template positions, m.
    pub fn positions(&self) -> &[Vector3<f64>] {
        self.mesh.positions()
    }

    /// Triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        self.mesh.faces()
    }

    /// Where the rest metric comes from.
    pub fn rest_source(&self) -> RestSource {
        self.rest_source
    }

    /// Per triangle, the rest edge matrix `Dm`: columns `x1 − x0` and `x2 − x0` at rest, in
    /// the material frame's (u, v) coordinates, m. The deformation gradient of a deformed
    /// triangle is `F = Ds Dm⁻¹` with `Ds` its 3D edge columns.
    pub fn rest_dm(&self) -> &[Matrix2<f64>] {
        &self.rest_dm
    }

    /// Per triangle, the rest area `det(Dm) / 2`, m².
    pub fn rest_area_m2(&self) -> &[f64] {
        &self.rest_area_m2
    }

    /// Per triangle, the material u axis (unit, in the template triangle's plane).
    pub fn frame_u(&self) -> &[Vector3<f64>] {
        &self.frame_u
    }

    /// Per triangle, the material v axis (`n × u`).
    pub fn frame_v(&self) -> &[Vector3<f64>] {
        &self.frame_v
    }

    /// Bending hinges `[x0, x1, x2, x3]`, one per interior edge in the order of
    /// [`sartor_core::MeshTopology::edges`]: `x0 → x1` is the edge as directed in the first
    /// face of the edge (which has `x2` opposite), `x3` is opposite in the other face (the
    /// convention of [`crate::energy::dihedral_angle`]).
    pub fn hinges(&self) -> &[[u32; 4]] {
        &self.hinges
    }

    /// Rest dihedral angle of each hinge, rad (ARCSim's signed angle; zero for a pattern).
    pub fn rest_dihedral_rad(&self) -> &[f64] {
        &self.rest_dihedral_rad
    }

    /// Where the garment comes from.
    pub fn provenance(&self) -> &GarmentProvenance {
        &self.provenance
    }

    /// SHA-256 (lower-case hex) of the garment's tensor file as [`Garment::save`] writes it
    /// (the `tensors_sha256` of its `garment.json`): identifies the garment in the outputs
    /// made with it.
    pub fn content_sha256(&self) -> Result<String> {
        Ok(sha256_hex(&self.tensors()?))
    }

    /// The garment's identity: its name and [`Self::content_sha256`].
    pub fn asset_id(&self) -> Result<AssetId> {
        Ok(AssetId {
            id: self.name.clone(),
            sha256: self.content_sha256()?,
        })
    }

    fn tensors(&self) -> Result<Vec<u8>> {
        let (n_f, n_h) = (self.mesh.n_faces(), self.hinges.len());
        let mut t = BTreeMap::new();
        t.insert(
            "positions".to_string(),
            OwnedTensor::points(self.mesh.positions()),
        );
        t.insert("faces".to_string(), OwnedTensor::indices(self.mesh.faces()));
        t.insert(
            "rest_dm".to_string(),
            OwnedTensor::f32(
                &[n_f, 2, 2],
                self.rest_dm
                    .iter()
                    .flat_map(|m| [m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)]].map(|x| x as f32)),
            ),
        );
        t.insert(
            "rest_area_m2".to_string(),
            OwnedTensor::f32(&[n_f], self.rest_area_m2.iter().map(|&a| a as f32)),
        );
        t.insert("frame_u".to_string(), OwnedTensor::points(&self.frame_u));
        t.insert("frame_v".to_string(), OwnedTensor::points(&self.frame_v));
        t.insert("hinges".to_string(), OwnedTensor::indices(&self.hinges));
        t.insert(
            "rest_dihedral_rad".to_string(),
            OwnedTensor::f32(&[n_h], self.rest_dihedral_rad.iter().map(|&a| a as f32)),
        );
        Ok(serialize_tensors(&t, None)?)
    }

    /// The bytes of the three files (`garment.safetensors`, `garment.json`, `garment.obj`),
    /// deterministic.
    pub fn to_bytes(&self) -> Result<(Vec<u8>, Vec<u8>, Vec<u8>)> {
        let tensors = self.tensors()?;
        let header = Header {
            format: FILES.format.into(),
            version: FILES.version,
            name: self.name.clone(),
            units: "m".into(),
            axes: AXES.into(),
            n_vertices: self.mesh.n_vertices(),
            n_faces: self.mesh.n_faces(),
            n_hinges: self.hinges.len(),
            rest_source: self.rest_source,
            material_frame: MATERIAL_FRAME_CONVENTION.into(),
            provenance: self.provenance.clone(),
            tensors_sha256: sha256_hex(&tensors),
        };
        let json = FILES.header_json(Path::new(""), &header)?;
        let obj = format!(
            "# sartor garment {:?}: template positions (m)\n{}",
            self.name,
            obj_text(self.mesh.positions(), self.mesh.faces())
        );
        Ok((tensors, json, obj.into_bytes()))
    }

    /// Save into `dir` as `garment.safetensors`, `garment.json` and `garment.obj`, each
    /// written atomically; the same garment always gives the same bytes.
    pub fn save(&self, dir: &Path) -> Result<()> {
        let (tensors, header, obj) = self.to_bytes()?;
        write_atomic(&dir.join(GARMENT_TENSORS), &tensors)?;
        write_atomic(&dir.join(GARMENT_OBJ), &obj)?;
        // The header (with the tensors' hash) last: a reader that finds it finds the rest.
        write_atomic(&dir.join(GARMENT_HEADER), &header)?;
        Ok(())
    }

    /// Load a garment saved by [`Garment::save`], checking the header, the content hash, every
    /// shape and every invariant, and that the stored frames and areas are the ones the
    /// positions and rest metric imply.
    pub fn load(dir: &Path) -> Result<Self> {
        let (header, tensors) = FILES.read_bytes(dir)?;
        Self::from_bytes(dir, &header, tensors)
    }

    /// Parse a garment from the bytes of its header and tensor files, read from folder `dir`
    /// (used in error messages only).
    pub fn from_bytes(dir: &Path, header_bytes: &[u8], tensor_bytes: Vec<u8>) -> Result<Self> {
        let (header, file): (Header, _) = FILES.parse(dir, header_bytes, tensor_bytes)?;
        let tensor_path = dir.join(GARMENT_TENSORS);
        let (n_v, n_f, n_h) = (header.n_vertices, header.n_faces, header.n_hinges);
        let in_file = |e: Error| match e {
            Error::Invalid { what, message } => {
                Error::format(&tensor_path, format!("invalid {what}: {message}"))
            }
            Error::Mesh(e) => Error::Mesh(e.in_file(&tensor_path)),
            other => other,
        };
        let positions = file.points("positions", Some(n_v))?;
        let faces = file.indices("faces", Some(n_f))?;
        let mesh =
            TriMesh::new(positions, faces).map_err(|e| Error::Mesh(e.in_file(&tensor_path)))?;
        let (_, dm) = file.f32("rest_dm", &[Some(n_f), Some(2), Some(2)])?;
        let rest_dm = dm
            .chunks_exact(4)
            .map(|c| Matrix2::new(c[0] as f64, c[1] as f64, c[2] as f64, c[3] as f64))
            .collect();
        let hinges: Vec<[u32; 4]> = file.indices("hinges", Some(n_h))?;
        if hinges != hinges_of(&mesh) {
            return Err(Error::format(
                &tensor_path,
                "tensor \"hinges\" does not match the interior edges of the faces",
            ));
        }
        let (_, angles) = file.f32("rest_dihedral_rad", &[Some(n_h)])?;
        let garment = Self::assemble(
            &header.name,
            mesh,
            header.rest_source,
            rest_dm,
            hinges,
            angles.into_iter().map(f64::from).collect(),
            header.provenance,
        )
        .map_err(in_file)?;
        let (_, area) = file.f32("rest_area_m2", &[Some(n_f)])?;
        let fu = file.points("frame_u", Some(n_f))?;
        let fv = file.points("frame_v", Some(n_f))?;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * (1.0 + a.abs().max(b.abs()));
        let stored_area: Vec<f64> = area.into_iter().map(f64::from).collect();
        let checks = [
            (
                "rest_area_m2",
                stored_area
                    .iter()
                    .zip(&garment.rest_area_m2)
                    .all(|(a, b)| close(*a, *b)),
            ),
            (
                "frame_u",
                fu.iter()
                    .zip(&garment.frame_u)
                    .all(|(a, b)| (a - b).norm() <= 1e-5),
            ),
            (
                "frame_v",
                fv.iter()
                    .zip(&garment.frame_v)
                    .all(|(a, b)| (a - b).norm() <= 1e-5),
            ),
        ];
        if let Some((name, _)) = checks.iter().find(|(_, ok)| !ok) {
            return Err(Error::format(
                &tensor_path,
                format!("tensor {name:?} does not match the positions and rest_dm"),
            ));
        }
        Ok(garment)
    }
}

/// The mesh with positions rounded to f32.
fn round_mesh(mesh: &TriMesh) -> Result<TriMesh> {
    Ok(TriMesh::new(
        mesh.positions().iter().map(r32v).collect(),
        mesh.faces().to_vec(),
    )?)
}

/// One connected oriented manifold with boundary, every vertex used.
pub(crate) fn check_garment_topology(mesh: &TriMesh) -> Result<()> {
    let topology = mesh.topology();
    topology.check_manifold()?;
    let (_, components) = topology.face_components();
    if components != 1 {
        return Err(Error::invalid(
            "garment",
            format!("the mesh has {components} disconnected parts; a garment must be one piece"),
        ));
    }
    if let Some(v) = mesh.first_unused_vertex() {
        return Err(Error::invalid(
            "garment",
            format!("vertex {v} belongs to no triangle"),
        ));
    }
    if topology.boundary_edges().is_empty() {
        return Err(Error::invalid(
            "garment",
            "the mesh is closed; a garment needs at least one opening (boundary loop)",
        ));
    }
    Ok(())
}

/// Bending hinges in the order of the mesh's sorted unique edges (see [`Garment::hinges`]).
fn hinges_of(mesh: &TriMesh) -> Vec<[u32; 4]> {
    mesh.topology()
        .hinges()
        .into_iter()
        .map(|h| h.vertices)
        .collect()
}
