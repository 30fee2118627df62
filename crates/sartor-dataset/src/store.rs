//! The dataset on disk: safetensors files (PyTorch can read them) plus a manifest with content
//! hashes. The manifest is written last, so a folder without one is an unfinished build.
//!
//! ```text
//! <dir>/manifest.json                 Manifest: sizes, layout, splits, every file's SHA-256
//! <dir>/binding.safetensors           relaxed [V,3], template [V,3], faces [F,3] (i32),
//!                                     skin_offsets [V+1], skin_joints [nnz] (i32), skin_weights [nnz]
//! <dir>/shapes.safetensors            betas [S,B], fit_delta [S,3V]
//! <dir>/sequences/<id>.safetensors    inputs [T,I], wrinkle_delta [T,3V]
//! <dir>/stats.safetensors             norm.* (as the runtime's model format), and optionally
//!                                     pca.mean [3V], pca.basis [3V,k], pca.explained_variance_ratio [k]
//! ```
//!
//! All values f32 (metres) unless noted; every file is written atomically.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use sartor_core::io::{
    OwnedTensor, TensorFile, read_file, serialize_tensors, sha256_hex, write_atomic,
};
use sartor_core::{BINDING_JSON, BINDING_TENSORS, BodyModel, GarmentBinding};

use crate::smoothing::Smoothing;
use crate::{
    DataSource, Error, InputLayout, MeanStd, NormStats, PcaBasis, Result, SequenceSample,
    ShapeSample, Split, TrainingData,
};

/// The manifest's file name.
pub const MANIFEST_FILE: &str = "manifest.json";
/// The binding's tensors: sartor-core's [`GarmentBinding`] format, the runtime's, with its
/// `binding.json` ([`BINDING_JSON`]) beside it.
pub const BINDING_FILE: &str = BINDING_TENSORS;
/// The shapes' file name.
pub const SHAPES_FILE: &str = "shapes.safetensors";
/// The statistics' file name.
pub const STATS_FILE: &str = "stats.safetensors";
/// The folder of per-sequence files.
pub const SEQUENCES_DIR: &str = "sequences";
/// The manifest's `format`.
pub const DATASET_FORMAT: &str = "sartor-dataset";
/// The manifest's `version`: 2 since the binding is sartor-core's `GarmentBinding` (version 1
/// stored a binding of its own, with the relaxed garment).
pub const DATASET_VERSION: u32 = 2;

/// One shape in the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeEntry {
    /// Identifier.
    pub id: String,
    /// Split.
    pub split: Split,
}

/// One sequence in the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequenceEntry {
    /// Identifier (also the file stem).
    pub id: String,
    /// Index into the shapes.
    pub shape: usize,
    /// Motion name.
    pub motion: String,
    /// Split.
    pub split: Split,
    /// Motion frames.
    pub n_frames: usize,
}

/// `manifest.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always [`DATASET_FORMAT`].
    pub format: String,
    /// Always [`DATASET_VERSION`].
    pub version: u32,
    /// Garment and body identity.
    pub source: DataSource,
    /// SHA-256 of the experiment config's dataset-relevant part.
    pub config_sha256: String,
    /// Garment vertices.
    pub n_vertices: usize,
    /// Input layout of the wrinkle network.
    pub layout: InputLayout,
    /// The smoothing ρ used for `T̄_c` and `Δ_G`.
    pub smoothing: Smoothing,
    /// Shapes, in the order of `shapes.safetensors`.
    pub shapes: Vec<ShapeEntry>,
    /// Sequences.
    pub sequences: Vec<SequenceEntry>,
    /// Relative path → SHA-256 of every data file.
    pub files: BTreeMap<String, String>,
}

/// Relative path of a sequence's file.
pub fn sequence_file(id: &str) -> String {
    format!("{SEQUENCES_DIR}/{id}.safetensors")
}

fn write_tensors(dir: &Path, name: &str, tensors: BTreeMap<String, OwnedTensor>) -> Result<String> {
    let bytes = serialize_tensors(&tensors, None)?;
    write_atomic(&dir.join(name), &bytes)?;
    Ok(sha256_hex(&bytes))
}

/// Read and validate the dataset's garment binding (`binding.json` + `binding.safetensors`,
/// sartor-core's [`GarmentBinding`] format) and check it against `body`.
pub fn read_binding(dir: &Path, body: &BodyModel) -> Result<GarmentBinding> {
    let binding = GarmentBinding::load(dir)?;
    binding
        .check_body(body)
        .map_err(|e| e.in_file(dir.join(BINDING_JSON)))?;
    Ok(binding)
}

/// Write `shapes.safetensors`; returns its SHA-256.
pub fn write_shapes(
    dir: &Path,
    shapes: &[ShapeSample],
    n_betas: usize,
    n3: usize,
) -> Result<String> {
    let mut t = BTreeMap::new();
    t.insert(
        "betas".into(),
        OwnedTensor::f32(
            &[shapes.len(), n_betas],
            shapes.iter().flat_map(|s| s.betas.iter().copied()),
        ),
    );
    t.insert(
        "fit_delta".into(),
        OwnedTensor::f32(
            &[shapes.len(), n3],
            shapes.iter().flat_map(|s| s.fit_delta.iter().copied()),
        ),
    );
    write_tensors(dir, SHAPES_FILE, t)
}

/// Write one sequence's file; returns its SHA-256.
pub fn write_sequence(
    dir: &Path,
    sample: &SequenceSample,
    n_inputs: usize,
    n3: usize,
) -> Result<String> {
    let mut t = BTreeMap::new();
    t.insert(
        "inputs".into(),
        OwnedTensor::f32(&[sample.n_frames, n_inputs], sample.inputs.iter().copied()),
    );
    t.insert(
        "wrinkle_delta".into(),
        OwnedTensor::f32(&[sample.n_frames, n3], sample.wrinkle_delta.iter().copied()),
    );
    write_tensors(dir, &sequence_file(&sample.id), t)
}

/// Read one sequence's arrays `(inputs, wrinkle_delta)`.
pub fn read_sequence(
    dir: &Path,
    entry: &SequenceEntry,
    n_inputs: usize,
    n3: usize,
) -> Result<(Vec<f32>, Vec<f32>)> {
    let file = TensorFile::open(&dir.join(sequence_file(&entry.id)))?;
    let (_, inputs) = file.f32("inputs", &[Some(entry.n_frames), Some(n_inputs)])?;
    let (_, delta) = file.f32("wrinkle_delta", &[Some(entry.n_frames), Some(n3)])?;
    Ok((inputs, delta))
}

fn mean_std(t: &mut BTreeMap<String, OwnedTensor>, name: &str, m: &MeanStd) {
    t.insert(
        format!("norm.{name}_mean"),
        OwnedTensor::f32(&[m.mean.len()], m.mean.iter().copied()),
    );
    t.insert(
        format!("norm.{name}_std"),
        OwnedTensor::f32(&[m.std.len()], m.std.iter().copied()),
    );
}

/// Write `stats.safetensors`; returns its SHA-256.
pub fn write_stats(dir: &Path, stats: &NormStats, pca: Option<&PcaBasis>) -> Result<String> {
    let mut t = BTreeMap::new();
    mean_std(&mut t, "fit_in", &stats.fit_in);
    mean_std(&mut t, "wrinkle_in", &stats.wrinkle_in);
    mean_std(&mut t, "fit_out", &stats.fit_out);
    mean_std(&mut t, "wrinkle_out", &stats.wrinkle_out);
    if let Some(p) = pca {
        let (n3, k) = (p.mean.len(), p.n_components());
        t.insert(
            "pca.mean".into(),
            OwnedTensor::f32(&[n3], p.mean.iter().copied()),
        );
        t.insert(
            "pca.basis".into(),
            OwnedTensor::f32(&[n3, k], p.basis.iter().copied()),
        );
        t.insert(
            "pca.explained_variance_ratio".into(),
            OwnedTensor::f32(&[k], p.explained_variance_ratio.iter().map(|&r| r as f32)),
        );
    }
    write_tensors(dir, STATS_FILE, t)
}

fn read_stats(
    dir: &Path,
    n_betas: usize,
    n_inputs: usize,
    n3: usize,
) -> Result<(NormStats, Option<PcaBasis>)> {
    let file = TensorFile::open(&dir.join(STATS_FILE))?;
    let get = |name: &str, len: usize| -> Result<MeanStd> {
        Ok(MeanStd {
            mean: file.f32(&format!("norm.{name}_mean"), &[Some(len)])?.1,
            std: file.f32(&format!("norm.{name}_std"), &[Some(len)])?.1,
        })
    };
    let stats = NormStats {
        fit_in: get("fit_in", n_betas)?,
        wrinkle_in: get("wrinkle_in", n_inputs)?,
        fit_out: get("fit_out", n3)?,
        wrinkle_out: get("wrinkle_out", n3)?,
    };
    let pca = if file.names().iter().any(|n| n == "pca.basis") {
        let (shape, basis) = file.f32("pca.basis", &[Some(n3), None])?;
        let k = shape[1];
        Some(PcaBasis {
            mean: file.f32("pca.mean", &[Some(n3)])?.1,
            basis,
            explained_variance_ratio: file
                .f32("pca.explained_variance_ratio", &[Some(k)])?
                .1
                .into_iter()
                .map(f64::from)
                .collect(),
        })
    } else {
        None
    };
    Ok((stats, pca))
}

/// Write `manifest.json` (last: it marks the dataset complete).
pub fn write_manifest(dir: &Path, manifest: &Manifest) -> Result<()> {
    let json = serde_json::to_vec_pretty(manifest)
        .map_err(|e| Error::format(dir.join(MANIFEST_FILE), format!("cannot serialise: {e}")))?;
    write_atomic(&dir.join(MANIFEST_FILE), &json)?;
    Ok(())
}

/// Read and check `manifest.json`.
pub fn read_manifest(dir: &Path) -> Result<Manifest> {
    let path = dir.join(MANIFEST_FILE);
    let bytes = read_file(&path)?;
    let m: Manifest = serde_json::from_slice(&bytes)
        .map_err(|e| Error::format(&path, format!("bad manifest: {e}")))?;
    if m.format != DATASET_FORMAT || m.version != DATASET_VERSION {
        return Err(Error::format(
            &path,
            format!(
                "format {:?} version {}, expected {DATASET_FORMAT:?} version {DATASET_VERSION}",
                m.format, m.version
            ),
        ));
    }
    for q in &m.sequences {
        if q.shape >= m.shapes.len() {
            return Err(Error::format(
                &path,
                format!(
                    "sequence {} refers to shape {} of {}",
                    q.id,
                    q.shape,
                    m.shapes.len()
                ),
            ));
        }
        if !m.files.contains_key(&sequence_file(&q.id)) {
            return Err(Error::format(
                &path,
                format!("sequence {} has no file entry", q.id),
            ));
        }
    }
    for f in [BINDING_FILE, BINDING_JSON, SHAPES_FILE, STATS_FILE] {
        if !m.files.contains_key(f) {
            return Err(Error::format(&path, format!("no entry for {f}")));
        }
    }
    Ok(m)
}

/// Check a file's SHA-256 against the manifest.
fn verify(dir: &Path, manifest: &Manifest, name: &str) -> Result<()> {
    let path: PathBuf = dir.join(name);
    let bytes = read_file(&path)?;
    let expected = manifest.files.get(name).map(String::as_str).unwrap_or("");
    let got = sha256_hex(&bytes);
    if got != expected {
        return Err(Error::format(
            &path,
            format!("content hash {got} does not match the manifest's {expected}"),
        ));
    }
    Ok(())
}

/// Load a finished dataset into memory, checking every file's hash against the manifest.
pub fn load_dataset(dir: &Path) -> Result<TrainingData> {
    let m = read_manifest(dir)?;
    for name in m.files.keys() {
        verify(dir, &m, name)?;
    }
    let (nb, ni, n3) = (m.layout.n_betas, m.layout.width(), 3 * m.n_vertices);
    let shapes_path = dir.join(SHAPES_FILE);
    let file = TensorFile::open(&shapes_path)?;
    let s = m.shapes.len();
    let (_, betas) = file.f32("betas", &[Some(s), Some(nb)])?;
    let (_, fit) = file.f32("fit_delta", &[Some(s), Some(n3)])?;
    let shapes = m
        .shapes
        .iter()
        .enumerate()
        .map(|(i, e)| ShapeSample {
            id: e.id.clone(),
            betas: betas[i * nb..(i + 1) * nb].to_vec(),
            fit_delta: fit[i * n3..(i + 1) * n3].to_vec(),
            split: e.split,
        })
        .collect();
    let sequences = m
        .sequences
        .iter()
        .map(|e| {
            let (inputs, wrinkle_delta) = read_sequence(dir, e, ni, n3)?;
            Ok(SequenceSample {
                id: e.id.clone(),
                shape: e.shape,
                motion: e.motion.clone(),
                split: e.split,
                n_frames: e.n_frames,
                inputs,
                wrinkle_delta,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let (stats, pca) = read_stats(dir, nb, ni, n3)?;
    TrainingData::new(
        m.source,
        m.n_vertices,
        m.layout,
        shapes,
        sequences,
        stats,
        pca,
    )
}
