//! Animated glTF 2.0 as one binary `.glb` file, written without dependencies.
//!
//! Each [`MeshSequence`] becomes one node with one mesh: frame 0 is the base `POSITION`, every
//! later frame `t` a morph target holding `frame_t − frame_0`, and one animation drives the
//! morph weights (weight `t` is 1 at time `t / fps`, 0 at the other frames; linear in between,
//! which blends neighbouring frames). Blender imports the targets as shape keys with their
//! animation; three.js plays them with its `AnimationMixer`. Sizes grow as `frames × vertices`
//! (positions) plus `frames²` (weights): fine for previews of a few hundred frames. Materials are
//! double-sided, unlit-looking (metallic 0, roughness 1) with the sequence's colour; normals are
//! left to the viewer (the glTF rule: flat normals when none are given).

use std::path::Path;

use nalgebra::Vector3;
use sartor_core::io::write_atomic;
use serde_json::{Value, json};

use super::MeshSequence;
use crate::error::{Error, Result};

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// The binary buffer and the JSON arrays that describe it.
#[derive(Default)]
struct Builder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Builder {
    /// Append a buffer view of `bytes` (4-byte aligned) and return its index.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({ "buffer": 0, "byteOffset": offset, "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.views.push(v);
        self.views.len() - 1
    }

    fn accessor(&mut self, accessor: Value) -> usize {
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// A VEC3 float accessor with its bounds (required for positions and their targets).
    fn vec3(&mut self, points: &[Vector3<f32>]) -> usize {
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        let mut bytes = Vec::with_capacity(12 * points.len());
        for p in points {
            for c in 0..3 {
                min[c] = min[c].min(p[c]);
                max[c] = max[c].max(p[c]);
                bytes.extend_from_slice(&p[c].to_le_bytes());
            }
        }
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        self.accessor(json!({
            "bufferView": view, "componentType": FLOAT, "count": points.len(), "type": "VEC3",
            "min": min, "max": max
        }))
    }

    /// A float accessor of `kind` (`SCALAR`), optionally with bounds.
    fn floats(&mut self, values: &[f32], bounds: bool) -> usize {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let mut a = json!({
            "bufferView": view, "componentType": FLOAT, "count": values.len(), "type": "SCALAR"
        });
        if bounds {
            let min = values.iter().copied().fold(f32::INFINITY, f32::min);
            let max = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            a["min"] = json!([min]);
            a["max"] = json!([max]);
        }
        self.accessor(a)
    }

    fn indices(&mut self, faces: &[[u32; 3]]) -> usize {
        let bytes: Vec<u8> = faces
            .iter()
            .flatten()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        self.accessor(json!({
            "bufferView": view, "componentType": UNSIGNED_INT, "count": 3 * faces.len(),
            "type": "SCALAR"
        }))
    }
}

/// Pad to a multiple of 4 bytes with `fill`.
fn pad(bytes: &mut Vec<u8>, fill: u8) {
    while !bytes.len().is_multiple_of(4) {
        bytes.push(fill);
    }
}

/// The `.glb` bytes of `meshes` animated at `fps` (see the module docs).
pub(crate) fn glb_bytes(meshes: &[MeshSequence], fps: f64) -> Result<Vec<u8>> {
    let bad = |m: String| Error::invalid("glTF", m);
    if meshes.is_empty() {
        return Err(bad("no mesh to write".into()));
    }
    if !(fps.is_finite() && fps > 0.0) {
        return Err(bad(format!("fps must be finite and positive, got {fps}")));
    }
    let n_frames = meshes.iter().map(|m| m.frames().len()).max().unwrap_or(1);
    if let Some(m) = meshes
        .iter()
        .find(|m| m.frames().len() != n_frames && m.frames().len() != 1)
    {
        return Err(bad(format!(
            "{} has {} frames, others {n_frames}: every sequence needs the same count (or 1)",
            m.name(),
            m.frames().len()
        )));
    }
    let mut b = Builder::default();
    let (mut nodes, mut gltf_meshes, mut materials, mut channels, mut samplers) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let times = (n_frames > 1).then(|| {
        let t: Vec<f32> = (0..n_frames).map(|k| (k as f64 / fps) as f32).collect();
        b.floats(&t, true)
    });
    for (i, m) in meshes.iter().enumerate() {
        let base = &m.frames()[0];
        let position = b.vec3(base);
        let indices = b.indices(m.faces());
        let n_targets = m.frames().len() - 1;
        let targets: Vec<Value> = m.frames()[1..]
            .iter()
            .map(|f| {
                let delta: Vec<Vector3<f32>> = f.iter().zip(base).map(|(p, q)| p - q).collect();
                json!({ "POSITION": b.vec3(&delta) })
            })
            .collect();
        let [r, g, bl] = m.color();
        materials.push(json!({
            "name": m.name(),
            "pbrMetallicRoughness": {
                "baseColorFactor": [r, g, bl, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0
            },
            "doubleSided": true
        }));
        let mut primitive = json!({
            "attributes": { "POSITION": position }, "indices": indices, "material": i, "mode": 4
        });
        let mut mesh = json!({ "name": m.name(), "primitives": [] });
        if n_targets > 0 {
            primitive["targets"] = Value::Array(targets);
            mesh["weights"] = json!(vec![0.0f32; n_targets]);
            // Keyframe k: weight k − 1 is 1 (frame 0 is the base: all zero).
            let mut w = vec![0.0f32; n_frames * n_targets];
            for k in 1..n_frames {
                w[k * n_targets + (k - 1)] = 1.0;
            }
            let output = b.floats(&w, false);
            samplers.push(json!({
                "input": times.ok_or_else(|| bad("no time axis".into()))?,
                "output": output,
                "interpolation": "LINEAR"
            }));
            channels.push(json!({
                "sampler": samplers.len() - 1, "target": { "node": i, "path": "weights" }
            }));
        }
        mesh["primitives"] = json!([primitive]);
        gltf_meshes.push(mesh);
        nodes.push(json!({ "name": m.name(), "mesh": i }));
    }
    pad(&mut b.bin, 0);
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": "sartor-runtime" },
        "scene": 0,
        "scenes": [{ "nodes": (0..meshes.len()).collect::<Vec<_>>() }],
        "nodes": nodes,
        "meshes": gltf_meshes,
        "materials": materials,
        "buffers": [{ "byteLength": b.bin.len() }],
        "bufferViews": b.views,
        "accessors": b.accessors,
    });
    if !channels.is_empty() {
        doc["animations"] =
            json!([{ "name": "animation", "samplers": samplers, "channels": channels }]);
    }
    let mut json_bytes =
        serde_json::to_vec(&doc).map_err(|e| bad(format!("JSON encoding: {e}")))?;
    pad(&mut json_bytes, b' ');
    let total = 12 + 8 + json_bytes.len() + 8 + b.bin.len();
    let total = u32::try_from(total).map_err(|_| bad(format!("{total} bytes exceed 4 GiB")))?;
    let mut out = Vec::with_capacity(total as usize);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total.to_le_bytes());
    // Chunk lengths fit: each is below `total`.
    out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json_bytes);
    out.extend_from_slice(&(b.bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b.bin);
    Ok(out)
}

/// Write `meshes` (e.g. the body and the garment) animated at `fps` frames per second as one
/// binary glTF file at `path`, atomically. Every sequence has the same number of frames, or one
/// (a static mesh).
pub fn write_gltf(path: &Path, meshes: &[MeshSequence], fps: f64) -> Result<()> {
    let bytes = glb_bytes(meshes, fps)?;
    write_atomic(path, &bytes)?;
    Ok(())
}
