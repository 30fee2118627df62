//! Output writers for animated meshes (garment and body): OBJ sequences, animated glTF 2.0
//! (`.glb`), and a small software rasterizer for preview images (PNG with the default `png`
//! feature). None of them needs a GPU or a C library.

mod gltf;
mod obj;
mod raster;

use nalgebra::Vector3;

use crate::error::{Error, Result};

pub use gltf::write_gltf;
pub use obj::write_obj_sequence;
#[cfg(feature = "png")]
pub use raster::render_png;
pub use raster::{BODY_COLOR, Camera, GARMENT_COLOR, Image, Panel, Projection, RenderMesh, render};

/// An animated triangle mesh: fixed triangles, one vertex array per frame (metres), a colour.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshSequence {
    name: String,
    faces: Vec<[u32; 3]>,
    frames: Vec<Vec<Vector3<f32>>>,
    color: [f32; 3],
}

impl MeshSequence {
    /// Check that the name is a plain file stem (letters, digits, `-`, `_`), there is at least
    /// one frame and one triangle, every frame has the same number of finite vertices, every
    /// index is in range, and the colour is in [0, 1].
    pub fn new(
        name: String,
        faces: Vec<[u32; 3]>,
        frames: Vec<Vec<Vector3<f32>>>,
        color: [f32; 3],
    ) -> Result<Self> {
        let bad = |m: String| Error::invalid("mesh sequence", m);
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(bad(format!(
                "name {name:?} must be letters, digits, '-' or '_'"
            )));
        }
        let n = frames.first().map(Vec::len).unwrap_or(0);
        if frames.is_empty() || n == 0 || faces.is_empty() {
            return Err(bad(format!(
                "{name}: {} frames of {n} vertices and {} faces; all must be positive",
                frames.len(),
                faces.len()
            )));
        }
        for (t, f) in frames.iter().enumerate() {
            if f.len() != n {
                return Err(bad(format!(
                    "{name}: frame {t} has {} vertices, frame 0 has {n}",
                    f.len()
                )));
            }
            if let Some(v) = f.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
                return Err(bad(format!("{name}: frame {t}, vertex {v} is not finite")));
            }
        }
        if let Some(f) = faces
            .iter()
            .position(|t| t.iter().any(|&i| i as usize >= n))
        {
            return Err(bad(format!("{name}: face {f} indexes past {n} vertices")));
        }
        if !color.iter().all(|c| (0.0..=1.0).contains(c)) {
            return Err(bad(format!("{name}: colour {color:?} is not in [0, 1]")));
        }
        Ok(Self {
            name,
            faces,
            frames,
            color,
        })
    }

    /// The name (file stem, glTF node and mesh name).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Vertex positions per frame.
    pub fn frames(&self) -> &[Vec<Vector3<f32>>] {
        &self.frames
    }

    /// Linear RGB colour in [0, 1].
    pub fn color(&self) -> [f32; 3] {
        self.color
    }

    /// Vertices per frame.
    pub fn n_vertices(&self) -> usize {
        self.frames[0].len()
    }
}
