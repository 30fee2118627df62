//! OBJ sequences: one file per frame, through sartor-core's OBJ writer.

use std::path::{Path, PathBuf};

use sartor_core::io::write_atomic;
use sartor_core::obj_text;

use super::MeshSequence;
use crate::error::Result;

/// Write `dir/<name>_<frame>.obj` (frame numbers zero-padded to 5 digits) for every frame of
/// `mesh`, each atomically; returns the paths in frame order.
pub fn write_obj_sequence(dir: &Path, mesh: &MeshSequence) -> Result<Vec<PathBuf>> {
    let mut paths = Vec::with_capacity(mesh.frames().len());
    let mut positions = Vec::with_capacity(mesh.n_vertices());
    for (t, frame) in mesh.frames().iter().enumerate() {
        positions.clear();
        positions.extend(frame.iter().map(|p| p.cast::<f64>()));
        let path = dir.join(format!("{}_{t:05}.obj", mesh.name()));
        write_atomic(&path, obj_text(&positions, mesh.faces()).as_bytes())?;
        paths.push(path);
    }
    Ok(paths)
}
