//! The simulation folder of a run (`runs/<name>/sim/`): one MCAP sequence file per
//! `<shape>__<motion>` ([`sequence_stem`]; each shape's rest simulation under [`REST_MOTION`]),
//! and a failure note per sequence that could not be simulated (`failed/<stem>.json`).
//! [`SimFolder`] reads and checks the sequences as a [`SimulationSource`]: the dataset builder
//! and the evaluation read ground truth through it.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use sartor_cloth::{ClothSequence, Phase};

use crate::{
    DatasetPlan, Error, Result, SequencePlan, ShapePlan, SimulatedMotion, SimulationSource,
};

/// The rest-pose simulation of a shape (for Δ_G) is stored under this motion name.
pub const REST_MOTION: &str = "rest";

/// Failure notes go here, inside the sim folder.
pub const FAILED_DIR: &str = "failed";

/// The file stem of a simulated sequence: `<shape>__<motion's file stem>`
/// ([`sartor_motion::motion_file_stem`]: `cmu/05_02@120+90` → `cmu-05_02@120+90`, a path →
/// its file's stem), so that every motion spec names one file in the sim folder.
pub fn sequence_stem(shape_id: &str, motion: &str) -> String {
    format!("{shape_id}__{}", sartor_motion::motion_file_stem(motion))
}

/// Reads the sequence files of a simulation folder.
pub struct SimFolder {
    dir: PathBuf,
    garment_sha256: String,
    n_betas: usize,
}

impl SimFolder {
    /// The sequences in `dir`, which must have been simulated with the garment of hash
    /// `garment_sha256` on a body with `n_betas` shape components.
    pub fn new(dir: &Path, garment_sha256: String, n_betas: usize) -> Self {
        Self {
            dir: dir.to_path_buf(),
            garment_sha256,
            n_betas,
        }
    }

    /// Read and check one sequence file.
    pub fn read(&self, shape: &ShapePlan, motion: &str) -> Result<ClothSequence> {
        let path = self
            .dir
            .join(format!("{}.mcap", sequence_stem(&shape.id, motion)));
        let bad = |m: String| Error::format(&path, m);
        let seq = ClothSequence::read(&path).map_err(|e| bad(e.to_string()))?;
        let h = &seq.header;
        if h.garment.asset.sha256 != self.garment_sha256 {
            return Err(bad(format!(
                "simulated with garment {} ({}), the experiment's garment has hash {}",
                h.garment.asset.id, h.garment.asset.sha256, self.garment_sha256
            )));
        }
        let mut betas = shape.betas.clone();
        betas.resize(self.n_betas, 0.0);
        if h.betas.len() != betas.len()
            || h.betas
                .iter()
                .zip(&betas)
                .any(|(a, b)| (a - b).abs() > 1e-9)
        {
            return Err(bad(format!(
                "simulated with β {:?}, the experiment says {:?} for shape {}",
                h.betas, shape.betas, shape.id
            )));
        }
        let expected_motion = (motion != REST_MOTION).then_some(motion);
        if h.motion.as_ref().map(|m| m.name.as_str()) != expected_motion {
            return Err(bad(format!(
                "holds motion {:?}, expected {motion:?}",
                h.motion.as_ref().map(|m| &m.name)
            )));
        }
        Ok(seq)
    }
}

fn to_f64(p: &[[f32; 3]]) -> Vec<Vector3<f64>> {
    p.iter()
        .map(|q| Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64))
        .collect()
}

impl SimulationSource for SimFolder {
    fn rest(&self, shape: &ShapePlan) -> Result<Vec<Vector3<f64>>> {
        let seq = self.read(shape, REST_MOTION)?;
        let last = seq
            .last_frame()
            .ok_or_else(|| Error::invalid("rest sequence", format!("{}: no frames", shape.id)))?;
        Ok(to_f64(&last.positions))
    }

    fn motion(&self, shape: &ShapePlan, motion: &str) -> Result<SimulatedMotion> {
        let seq = self.read(shape, motion)?;
        let first = seq
            .frames
            .iter()
            .position(|f| f.phase == Phase::Motion)
            .ok_or_else(|| {
                let stem = sequence_stem(&shape.id, motion);
                Error::invalid("sequence", format!("{stem}: no motion frames"))
            })?;
        let previous_pose = seq.frames[first.saturating_sub(1)].pose.clone();
        let frames: Vec<_> = seq.frames[first..]
            .iter()
            .filter(|f| f.phase == Phase::Motion)
            .collect();
        Ok(SimulatedMotion {
            betas: seq.header.betas.clone(),
            previous_pose,
            poses: frames.iter().map(|f| f.pose.clone()).collect(),
            cloth: frames.iter().map(|f| to_f64(&f.positions)).collect(),
        })
    }
}

/// The stems of sequences whose simulation failed (from `sim/failed/*.json`).
pub fn failed_stems(sim_dir: &Path) -> Result<BTreeSet<String>> {
    let dir = sim_dir.join(FAILED_DIR);
    let mut out = BTreeSet::new();
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for entry in entries {
            let path = entry.map_err(|e| Error::io(&dir, e))?.path();
            if path.extension().is_some_and(|e| e == "json")
                && let Some(stem) = path.file_stem()
            {
                out.insert(stem.to_string_lossy().into_owned());
            }
        }
    }
    Ok(out)
}

/// A plan without what failed to simulate: a shape whose rest simulation failed goes with all
/// its sequences. Returns the plan and the stems left out.
pub fn simulated_plan(full: &DatasetPlan, failed: &BTreeSet<String>) -> (DatasetPlan, Vec<String>) {
    let mut left_out = Vec::new();
    let mut shapes = Vec::new();
    // New index of each old shape (None: dropped).
    let mut index = Vec::with_capacity(full.shapes.len());
    for s in &full.shapes {
        let rest = sequence_stem(&s.id, REST_MOTION);
        if failed.contains(&rest) {
            left_out.push(rest);
            index.push(None);
        } else {
            index.push(Some(shapes.len()));
            shapes.push(s.clone());
        }
    }
    let mut sequences = Vec::new();
    for q in full.sequences.iter().cloned() {
        let stem = sequence_stem(&full.shapes[q.shape].id, &q.motion);
        match index[q.shape] {
            Some(i) if !failed.contains(&stem) => sequences.push(SequencePlan { shape: i, ..q }),
            _ => left_out.push(stem),
        }
    }
    (DatasetPlan { shapes, sequences }, left_out)
}
