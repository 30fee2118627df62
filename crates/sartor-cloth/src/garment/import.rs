//! Import of a user garment: an OBJ already positioned on the template body, optionally with
//! its flat sewing pattern as texture coordinates (`vt`, one 2D point per pattern corner; a
//! seam vertex has one `vt` per pattern piece, which OBJ allows because faces index positions
//! and texture coordinates separately).

use std::path::Path;

use nalgebra::Vector2;
use sartor_core::io::{read_file, sha256_hex};
use sartor_core::{BodyModel, ObjData};

use super::frame::material_u_axes;
use super::template::{Garment, GarmentProvenance, SourceKind, check_garment_topology};
use crate::{Error, Result};

/// How to read a garment OBJ.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjImportOptions {
    /// The garment's name.
    pub name: String,
    /// Use the `vt` coordinates as the rest shape (a 2D sewing pattern), scaled by this many
    /// metres per texture unit; `None` makes the 3D positions the rest shape.
    pub pattern_scale_m: Option<f64>,
}

/// Read a garment OBJ. Checks that it is one connected, oriented manifold with at least one
/// opening, that every vertex belongs to a triangle, that no triangle has zero area in 3D
/// or (when the pattern is used) in 2D, and that the pattern's area is within a factor 4 of
/// the 3D area (a wrong scale is the usual mistake). Every error names the file.
///
/// With a pattern, the rest metric comes from the 2D coordinates; without, from the 3D
/// positions, with material frames from [`material_u_axes`] (which uses `body`, if given, to
/// find the sleeves).
pub fn import_obj_garment(
    path: &Path,
    options: &ObjImportOptions,
    body: Option<&BodyModel>,
) -> Result<Garment> {
    let bytes = read_file(path)?;
    let text = std::str::from_utf8(&bytes)
        .map_err(|e| Error::format(path, format!("not UTF-8 text: {e}")))?;
    let data = ObjData::parse(text, path)?;
    let mesh = data.to_mesh(path)?;
    let in_file = |e: Error| match e {
        Error::Invalid { what, message } => {
            Error::format(path, format!("invalid {what}: {message}"))
        }
        Error::Mesh(e) => Error::Mesh(e.in_file(path)),
        other => other,
    };
    check_garment_topology(&mesh).map_err(in_file)?;
    let provenance = GarmentProvenance {
        kind: SourceKind::Obj,
        path: path.display().to_string(),
        sha256: sha256_hex(&bytes),
        body: body.map(BodyModel::asset_id).transpose()?,
    };
    match options.pattern_scale_m {
        None => {
            let axes = material_u_axes(&mesh, body)?;
            Garment::from_surface(&options.name, &mesh, &axes, provenance).map_err(in_file)
        }
        Some(scale) => {
            if !(scale.is_finite() && scale > 0.0) {
                return Err(Error::invalid(
                    "OBJ import",
                    format!("pattern scale {scale} m per unit is not positive"),
                ));
            }
            let Some(face_uv) = data.face_texcoords.as_ref() else {
                return Err(Error::format(
                    path,
                    "a sewing pattern was requested but not every face has texture coordinates (f v/vt)",
                ));
            };
            let uv_m: Vec<Vector2<f64>> = data.texcoords.iter().map(|t| t * scale).collect();
            let (lo, hi) = uv_m.iter().fold(
                (
                    Vector2::repeat(f64::INFINITY),
                    Vector2::repeat(f64::NEG_INFINITY),
                ),
                |(lo, hi), t| (lo.inf(t), hi.sup(t)),
            );
            let min_double_area = 2e-12 * (hi - lo).norm_squared();
            let mut area_2d = 0.0;
            for (f, t) in face_uv.iter().enumerate() {
                let x = t.map(|i| uv_m[i as usize]);
                let (e1, e2) = (x[1] - x[0], x[2] - x[0]);
                let double_area = (e1.x * e2.y - e1.y * e2.x).abs();
                if double_area <= min_double_area {
                    return Err(Error::format(
                        path,
                        format!(
                            "triangle {f} has zero area in the pattern (vt {} {} {})",
                            t[0] + 1,
                            t[1] + 1,
                            t[2] + 1
                        ),
                    ));
                }
                area_2d += 0.5 * double_area;
            }
            let area_3d: f64 = mesh.face_areas().iter().sum();
            let ratio = area_2d / area_3d;
            if !(0.25..=4.0).contains(&ratio) {
                return Err(Error::format(
                    path,
                    format!(
                        "the pattern's area ({area_2d:.4} m² at {scale} m per vt unit) is {ratio:.3} \
                         times the garment's 3D area ({area_3d:.4} m²); is the pattern scale right?"
                    ),
                ));
            }
            Garment::from_pattern(&options.name, &mesh, &uv_m, face_uv, provenance).map_err(in_file)
        }
    }
}
