//! `cargo xtask dataset --config C`: build the training data of an experiment from its
//! simulated sequences (`runs/<name>/sim`) into `runs/<name>/dataset` (see
//! `sartor_dataset::build_dataset`): binding, Δ_G, Δ_L, inputs, splits, statistics, PCA,
//! manifest and `dataset.json`. Resumable; sequences that failed to simulate are left out and
//! listed in the report.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Vector3;
use sartor_cloth::{ClothSequence, Garment, Phase};
use sartor_core::BodyModel;
use sartor_dataset::{
    DataSource, DatasetInputs, DatasetPlan, SequencePlan, ShapePlan, SimulatedMotion,
    SimulationSource, build_dataset,
};
use serde::Serialize;

use crate::experiment::{Experiment, ExperimentArgs, REST_MOTION, sequence_stem};
use crate::machine::{Machine, write_json};
use crate::simulate::FAILED_DIR;

/// Arguments of `dataset`.
#[derive(clap::Args, Debug)]
pub struct DatasetArgs {
    /// The experiment.
    #[command(flatten)]
    pub experiment: ExperimentArgs,
}

/// Reads an experiment's sequence files.
pub struct SequenceFiles {
    dir: PathBuf,
    garment_sha256: String,
    n_betas: usize,
}

impl SequenceFiles {
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
    pub fn read(&self, shape: &ShapePlan, motion: &str) -> sartor_dataset::Result<ClothSequence> {
        let path = self
            .dir
            .join(format!("{}.mcap", sequence_stem(&shape.id, motion)));
        let bad = |m: String| sartor_dataset::Error::Format {
            path: path.clone(),
            message: m,
        };
        let seq = ClothSequence::read(&path).map_err(|e| bad(e.to_string()))?;
        let h = &seq.header;
        if h.garment.sha256 != self.garment_sha256 {
            return Err(bad(format!(
                "simulated with garment {} ({}), the experiment's garment has hash {}",
                h.garment.name, h.garment.sha256, self.garment_sha256
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

impl SimulationSource for SequenceFiles {
    fn rest(&self, shape: &ShapePlan) -> sartor_dataset::Result<Vec<Vector3<f64>>> {
        let seq = self.read(shape, REST_MOTION)?;
        let last = seq
            .last_frame()
            .ok_or_else(|| sartor_dataset::Error::Invalid {
                what: "rest sequence",
                message: format!("{}: no frames", shape.id),
            })?;
        Ok(to_f64(&last.positions))
    }

    fn motion(&self, shape: &ShapePlan, motion: &str) -> sartor_dataset::Result<SimulatedMotion> {
        let seq = self.read(shape, motion)?;
        let first = seq
            .frames
            .iter()
            .position(|f| f.phase == Phase::Motion)
            .ok_or_else(|| sartor_dataset::Error::Invalid {
                what: "sequence",
                message: format!("{}: no motion frames", sequence_stem(&shape.id, motion)),
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
pub fn failed_stems(sim_dir: &Path) -> anyhow::Result<BTreeSet<String>> {
    let dir = sim_dir.join(FAILED_DIR);
    let mut out = BTreeSet::new();
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for entry in entries {
            let path = entry?.path();
            if path.extension().is_some_and(|e| e == "json")
                && let Some(stem) = path.file_stem()
            {
                out.insert(stem.to_string_lossy().into_owned());
            }
        }
    }
    Ok(out)
}

/// The experiment's plan without what failed to simulate: a shape whose rest simulation failed
/// goes with all its sequences. Returns the plan and the stems left out.
pub fn simulated_plan(e: &Experiment, failed: &BTreeSet<String>) -> (DatasetPlan, Vec<String>) {
    let full = e.plan();
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
    for q in full.sequences {
        let stem = sequence_stem(&full.shapes[q.shape].id, &q.motion);
        match index[q.shape] {
            Some(i) if !failed.contains(&stem) => sequences.push(SequencePlan { shape: i, ..q }),
            _ => left_out.push(stem),
        }
    }
    (DatasetPlan { shapes, sequences }, left_out)
}

#[derive(Serialize)]
struct DatasetRun<'a> {
    config: String,
    config_sha256: &'a str,
    left_out_failed_simulations: Vec<String>,
    wall_time_s: f64,
    machine: Machine,
}

/// Run `dataset`.
pub fn dataset(args: &DatasetArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let e = args.experiment.load()?;
    let body = BodyModel::load(&e.body)
        .with_context(|| format!("loading the body model from {}", e.body.display()))?;
    let garment = Garment::load(&e.garment)
        .with_context(|| format!("loading the garment from {}", e.garment.display()))?;
    let garment_sha256 = garment.content_sha256()?;
    let failed = failed_stems(&e.sim_dir())?;
    let (plan, left_out) = simulated_plan(&e, &failed);
    for stem in &left_out {
        eprintln!("dataset: leaving out {stem} (its simulation failed)");
    }
    let source = DataSource {
        garment_id: garment.name().to_string(),
        garment_sha256: garment_sha256.clone(),
        body_id: body.name().to_string(),
        body_sha256: body.content_sha256()?,
    };
    let config_sha256 = Experiment::section_sha256(&serde_json::json!({
        "dataset": &e.dataset,
        "plan": &plan,
        "simulation": &e.simulation,
        "max_frames": e.motions.max_frames,
        "source": &source,
    }))?;
    let inputs = DatasetInputs {
        body: &body,
        relaxed: garment.positions(),
        faces: garment.faces(),
        source,
        config_sha256: config_sha256.clone(),
    };
    let files = SequenceFiles::new(&e.sim_dir(), garment_sha256, body.n_betas());
    let out = e.dataset_dir();
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    write_json(&out.join("config.json"), &e)?;
    let bar = ProgressBar::new(plan.sequences.len() as u64);
    bar.set_style(ProgressStyle::with_template(
        "{spinner} dataset [{elapsed_precise}] {wide_bar} {pos}/{len} sequences (ETA {eta})",
    )?);
    let report = build_dataset(&inputs, &plan, &e.dataset, &files, &out, &|done, _| {
        bar.set_position(done as u64)
    })
    .with_context(|| format!("building the dataset in {}", out.display()))?;
    bar.finish();
    write_json(
        &out.join("dataset-run.json"),
        &DatasetRun {
            config: crate::workspace_relative(&args.experiment.config),
            config_sha256: &config_sha256,
            left_out_failed_simulations: left_out,
            wall_time_s: start.elapsed().as_secs_f64(),
            machine: Machine::current(),
        },
    )?;
    println!(
        "dataset: {} vertices, {} inputs ({} joints), frames {:?}, Δ_G mean {:.1} mm, Δ_L mean {:.1} mm (train) → {}",
        report.n_vertices,
        report.n_inputs,
        report.joints.len(),
        report.frames_per_split,
        report.fit_delta.mean_mm,
        report.wrinkle_delta.get("train").map_or(0.0, |m| m.mean_mm),
        out.display()
    );
    Ok(())
}
