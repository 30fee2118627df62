//! Wavefront OBJ: a strict reader (positions, texture coordinates, polygon faces) and a writer.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Vector2, Vector3};

use crate::io::{read_file, write_atomic};
use crate::{Error, Result, TriMesh};

/// What an OBJ file holds, triangulated.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjData {
    /// `v` lines.
    pub positions: Vec<Vector3<f64>>,
    /// `vt` lines.
    pub texcoords: Vec<Vector2<f64>>,
    /// Triangles (polygons fan-triangulated) into `positions`.
    pub faces: Vec<[u32; 3]>,
    /// For each triangle, its texture-coordinate indices, when every face has them.
    pub face_texcoords: Option<Vec<[u32; 3]>>,
    /// The faces as written (vertex indices of each polygon), before triangulation.
    pub polygons: Vec<Vec<u32>>,
    /// For each polygon, its group: an index into [`Self::groups`].
    pub polygon_groups: Vec<usize>,
    /// Group names (`g` statements) in order of first use; `""` for faces before any `g`.
    pub groups: Vec<String>,
}

impl ObjData {
    /// Parse OBJ text; `path` is used in error messages only.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let mut data = ObjData::default();
        let mut face_tc: Vec<[u32; 3]> = Vec::new();
        let mut faces_without_tc = 0usize;
        let mut group: Option<usize> = None;
        let mut group_name = String::new();
        for (line_no, raw) in text.lines().enumerate() {
            let line_no = line_no + 1;
            let line = raw.split('#').next().unwrap_or("").trim();
            let mut fields = line.split_whitespace();
            let Some(tag) = fields.next() else { continue };
            let err = |m: String| Error::parse(path, line_no, m);
            let number = |s: Option<&str>, what: &str| -> Result<f64> {
                let s = s.ok_or_else(|| err(format!("{what}: missing coordinate")))?;
                let x: f64 = s
                    .parse()
                    .map_err(|_| err(format!("{what}: {s:?} is not a number")))?;
                if !x.is_finite() {
                    return Err(err(format!("{what}: {s:?} is not finite")));
                }
                Ok(x)
            };
            match tag {
                "v" => {
                    let p = Vector3::new(
                        number(fields.next(), "v")?,
                        number(fields.next(), "v")?,
                        number(fields.next(), "v")?,
                    );
                    // An optional 4th (w) or vertex colour fields are allowed but ignored.
                    data.positions.push(p);
                }
                "vt" => {
                    data.texcoords.push(Vector2::new(
                        number(fields.next(), "vt")?,
                        number(fields.next(), "vt")?,
                    ));
                }
                "f" => {
                    let mut corners: Vec<(u32, Option<u32>)> = Vec::new();
                    for corner in fields {
                        let mut parts = corner.split('/');
                        let resolve = |s: &str, n: usize, what: &str| -> Result<u32> {
                            let i: i64 = s.parse().map_err(|_| {
                                err(format!("face: {what} index {s:?} is not an integer"))
                            })?;
                            let idx = if i > 0 { i - 1 } else { n as i64 + i };
                            if i == 0 || idx < 0 || idx >= n as i64 {
                                return Err(err(format!(
                                    "face: {what} index {i} out of range (1..={n} defined so far)"
                                )));
                            }
                            Ok(idx as u32)
                        };
                        let v =
                            resolve(parts.next().unwrap_or(""), data.positions.len(), "vertex")?;
                        let t = match parts.next() {
                            Some(s) if !s.is_empty() => {
                                Some(resolve(s, data.texcoords.len(), "texture")?)
                            }
                            _ => None,
                        };
                        corners.push((v, t));
                    }
                    if corners.len() < 3 {
                        return Err(err(format!(
                            "face has {} corners, needs at least 3",
                            corners.len()
                        )));
                    }
                    let g = match group {
                        Some(g) => g,
                        None => {
                            let g = data
                                .groups
                                .iter()
                                .position(|n| *n == group_name)
                                .unwrap_or_else(|| {
                                    data.groups.push(group_name.clone());
                                    data.groups.len() - 1
                                });
                            group = Some(g);
                            g
                        }
                    };
                    data.polygons.push(corners.iter().map(|c| c.0).collect());
                    data.polygon_groups.push(g);
                    let all_tc = corners.iter().all(|c| c.1.is_some());
                    for k in 1..corners.len() - 1 {
                        let (a, b, c) = (corners[0], corners[k], corners[k + 1]);
                        data.faces.push([a.0, b.0, c.0]);
                        if all_tc {
                            face_tc.push([a.1.unwrap_or(0), b.1.unwrap_or(0), c.1.unwrap_or(0)]);
                        } else {
                            faces_without_tc += 1;
                        }
                    }
                }
                "g" => {
                    group_name = fields.collect::<Vec<_>>().join(" ");
                    group = None;
                }
                "vn" | "vp" | "o" | "s" | "usemtl" | "mtllib" | "l" | "p" => {}
                other => return Err(err(format!("unknown statement {other:?}"))),
            }
        }
        if faces_without_tc == 0 && !face_tc.is_empty() {
            data.face_texcoords = Some(face_tc);
        }
        Ok(data)
    }

    /// Read and parse an OBJ file.
    pub fn read(path: &Path) -> Result<Self> {
        let bytes = read_file(path)?;
        let text = std::str::from_utf8(&bytes)
            .map_err(|e| Error::format(path, format!("not UTF-8 text: {e}")))?;
        Self::parse(text, path)
    }

    /// The polygons of group `name`, as written (errors name `path` when there is no such
    /// group).
    pub fn group_polygons(&self, name: &str, path: &Path) -> Result<Vec<Vec<u32>>> {
        let g = self
            .groups
            .iter()
            .position(|n| n == name)
            .ok_or_else(|| Error::format(path, format!("no group {name:?}")))?;
        Ok(self
            .polygons
            .iter()
            .zip(&self.polygon_groups)
            .filter(|(_, pg)| **pg == g)
            .map(|(p, _)| p.clone())
            .collect())
    }

    /// The triangle mesh of the positions and faces (validated; errors name `path`).
    pub fn to_mesh(&self, path: &Path) -> Result<TriMesh> {
        if self.faces.is_empty() {
            return Err(Error::format(path, "no faces"));
        }
        TriMesh::new(self.positions.clone(), self.faces.clone()).map_err(|e| e.in_file(path))
    }
}

/// Read an OBJ file as a validated triangle mesh.
pub fn read_obj(path: &Path) -> Result<TriMesh> {
    ObjData::read(path)?.to_mesh(path)
}

/// OBJ text of a triangle set (positions printed with 6 decimals: micrometres).
pub fn obj_text(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> String {
    let mut s = String::with_capacity(positions.len() * 36 + faces.len() * 24);
    for p in positions {
        let _ = writeln!(s, "v {:.6} {:.6} {:.6}", p.x, p.y, p.z);
    }
    for f in faces {
        let _ = writeln!(s, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    s
}

/// Write a triangle set as OBJ, atomically.
pub fn write_obj(path: &Path, positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Result<()> {
    write_atomic(path, obj_text(positions, faces).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<ObjData> {
        ObjData::parse(s, Path::new("t.obj"))
    }

    #[test]
    fn reads_quads_negative_indices_and_texcoords() {
        let d = parse("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\nf -4/-4 -2/-2 -1/-1\n")
            .expect("valid");
        assert_eq!(d.faces, vec![[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
        assert_eq!(d.face_texcoords.as_ref().map(Vec::len), Some(3));
        let m = d.to_mesh(Path::new("t.obj")).expect("mesh");
        let back = parse(&obj_text(m.positions(), m.faces())).expect("round trip");
        assert_eq!(back.faces, d.faces);
        assert_eq!(back.positions, d.positions);
    }

    #[test]
    fn errors_name_the_line() {
        for (text, needle) in [
            ("v 0 0\n", "t.obj:1"),
            ("v 0 0 0\nv 1 0 x\n", "t.obj:2"),
            ("v 0 0 nan\n", "not finite"),
            ("v 0 0 0\nf 1 2 3\n", "out of range"),
            ("v 0 0 0\nv 1 0 0\nf 1 2\n", "at least 3"),
            ("bogus 1\n", "unknown statement"),
            ("v 0 0 0\nf 0 1 1\n", "out of range"),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
        let e = parse("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
            .expect("parses")
            .to_mesh(Path::new("t.obj"));
        assert!(e.unwrap_err().to_string().contains("t.obj"));
    }
}
