//! The `simulate` stage ([`simulate`], `sartor simulate --config C [--shard I/N] [--jobs J]`):
//! every (shape, motion) pair of an experiment, plus each shape's rest-pose simulation (for
//! Δ_G), into `runs/<name>/sim/<shape>__<motion>.mcap`.
//!
//! - Parallel over sequences (each sequence runs on one thread, so its result does not depend
//!   on the thread count), with a progress bar (sequences, frames, ETA).
//! - Resumable: a finished file is skipped; files are written under a temporary name and
//!   renamed when complete, so a partial file never counts.
//! - Sharded: `--shard I/N` takes every N-th job starting at I (in a fixed order), so N
//!   machines split the work deterministically and their outputs merge by copying files into
//!   one folder. Without `--shard`, `JOB_COMPLETION_INDEX` (Kubernetes Indexed Job) or
//!   `SLURM_ARRAY_TASK_ID` (SLURM array) give I, and `--shard-count`, `SARTOR_SHARDS` or
//!   `SLURM_ARRAY_TASK_COUNT` give N.
//! - A sequence that fails (NaN, blow-up, penetration, non-convergence, even after the
//!   simulator's retries) is never written as ground truth: a `failed/<stem>.json` note records
//!   why, and the dataset step leaves it out.
//! - `--only PREFIX` keeps the jobs whose file stem starts with one of the prefixes (e.g.
//!   `s00__`: the nominal shape's sequences, enough for `tradeoff`).
//! - Writes `simulate.json` (or `simulate-shard-I-of-N.json`): jobs done, skipped and failed,
//!   frames, wall time, ms per frame.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use sartor_cloth::{
    Cloth, DriveConfig, FrictionModel, Garment, IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME, Material,
    simulate_sequence,
};
use sartor_core::BodyModel;
use sartor_dataset::{FAILED_DIR, REST_MOTION, sequence_stem};
use sartor_eval::{Machine, Progress, write_json};
use sartor_motion::{Motion, MotionSourceOptions, RetargetBody, load_motion};
use serde::Serialize;

use crate::error::{Context, bail};
use crate::experiment::{Experiment, resolve_motion_spec};
use crate::{DataDir, Error, Result};

/// How [`simulate`] runs.
#[derive(Clone, Debug)]
pub struct SimulateOptions {
    /// This machine's shard `(I, N)`: every N-th job starting at I (see [`resolve_shard`]).
    pub shard: (usize, usize),
    /// Sequences simulated at once (default: all cores).
    pub jobs: Option<usize>,
    /// Simulate again the jobs that failed before (by default they are skipped: a simulation
    /// is deterministic, so the same inputs fail the same way; retry after changing settings).
    pub retry_failed: bool,
    /// Only the jobs whose file stem (`<shape>__<motion>`) starts with one of these (all jobs
    /// when empty), e.g. `s00__` for the nominal shape's sequences.
    pub only: Vec<String>,
}

impl Default for SimulateOptions {
    fn default() -> Self {
        Self {
            shard: (0, 1),
            jobs: None,
            retry_failed: false,
            only: Vec::new(),
        }
    }
}

/// One simulation job.
#[derive(Clone, Debug)]
pub struct Job {
    /// Index into the plan's shapes.
    pub shape: usize,
    /// Motion name, or [`REST_MOTION`].
    pub motion: String,
    /// Output file stem.
    pub stem: String,
}

/// Every job of an experiment in a fixed order: each shape's rest simulation, then the plan's
/// sequences.
pub fn jobs(e: &Experiment) -> Vec<Job> {
    let plan = e.plan();
    let mut jobs: Vec<Job> = plan
        .shapes
        .iter()
        .enumerate()
        .map(|(i, s)| Job {
            shape: i,
            motion: REST_MOTION.into(),
            stem: sequence_stem(&s.id, REST_MOTION),
        })
        .collect();
    jobs.extend(plan.sequences.iter().map(|q| Job {
        shape: q.shape,
        motion: q.motion.clone(),
        stem: sequence_stem(&plan.shapes[q.shape].id, &q.motion),
    }));
    jobs
}

/// `(index, count)` of this machine's shard.
pub fn resolve_shard(
    shard: Option<&str>,
    shard_count: Option<usize>,
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<(usize, usize)> {
    let parse = |what: &str, v: &str| -> Result<usize> {
        v.trim()
            .parse()
            .map_err(|_| Error::Invalid(format!("{what} {v:?} is not a non-negative integer")))
    };
    let (index, count) = if let Some(s) = shard {
        let (i, n) = s
            .split_once('/')
            .with_context(|| format!("--shard {s:?}: expected I/N, e.g. 3/16"))?;
        (parse("shard index", i)?, parse("shard count", n)?)
    } else if let Some(i) = env("JOB_COMPLETION_INDEX").or_else(|| env("SLURM_ARRAY_TASK_ID")) {
        let n = match shard_count {
            Some(n) => n,
            None => match env("SARTOR_SHARDS").or_else(|| env("SLURM_ARRAY_TASK_COUNT")) {
                Some(n) => parse("shard count", &n)?,
                None => bail!(
                    "a shard index came from the environment but not the count: pass --shard-count N or set SARTOR_SHARDS"
                ),
            },
        };
        (parse("shard index", &i)?, n)
    } else {
        (0, 1)
    };
    if count == 0 || index >= count {
        bail!("shard {index}/{count}: need 0 ≤ I < N");
    }
    Ok((index, count))
}

/// Loads everything a simulation job needs.
pub struct SimInputs {
    /// The body.
    pub body: BodyModel,
    /// The garment template (relaxed on the template body).
    pub garment: Garment,
    /// The cloth material.
    pub material: Material,
    /// The driver settings.
    pub drive: DriveConfig,
    /// Motion sources.
    pub motions: MotionSourceOptions,
    /// The data folder (motion files named by a relative path are resolved against it).
    pub data: DataDir,
}

impl SimInputs {
    /// Load the experiment's body, garment, material and settings (imported motions from
    /// `data`).
    pub fn load(e: &Experiment, data: &DataDir) -> Result<Self> {
        let body = BodyModel::load(&e.body)
            .with_context(|| format!("loading the body model from {}", e.body.display()))?;
        let garment = Garment::load(&e.garment)
            .with_context(|| format!("loading the garment from {}", e.garment.display()))?;
        let material = if e.material == "gray_interlock" {
            Material::gray_interlock()
        } else {
            Material::from_json_file(Path::new(&e.material))
                .with_context(|| format!("loading the material {}", e.material))?
        };
        let drive = e.simulation.clone();
        let motions = MotionSourceOptions {
            motions_dir: data.motions_dir(),
            body: RetargetBody::load(&e.body).ok(),
            lenient: false,
            keep_tpose_frame: false,
            up_axis: sartor_motion::UpAxis::Y,
        };
        Ok(Self {
            body,
            garment,
            material,
            drive,
            motions,
            data: data.clone(),
        })
    }

    /// The motion of a job, cut to the experiment's `max_frames`.
    pub fn motion(&self, e: &Experiment, name: &str) -> Result<Motion> {
        let spec = resolve_motion_spec(name, &self.data);
        // Named by the spec as the config writes it (a BVH file's motion is otherwise named
        // after the file), so that the sequence files record what the plan asks for.
        let m = load_motion(&spec, &self.motions)
            .with_context(|| format!("motion {name:?}"))?
            .renamed(name.to_string());
        Ok(match e.motions.max_frames {
            Some(n) if n < m.n_frames() => m.slice(0..n)?,
            _ => m,
        })
    }
}

/// A sequence that could not be simulated, and why.
#[derive(Clone, Debug, Serialize)]
pub struct FailedJob {
    /// Its file stem.
    pub stem: String,
    /// The simulator's error.
    pub reason: String,
}

/// `simulate.json` (or `simulate-shard-I-of-N.json`).
#[derive(Clone, Debug, Serialize)]
pub struct SimulateReport {
    /// The config file.
    pub config: String,
    /// Hash of the whole config.
    pub config_sha256: String,
    /// Hash of the simulation section.
    pub simulation_sha256: String,
    /// This shard.
    pub shard_index: usize,
    /// Shards in all.
    pub shard_count: usize,
    /// Jobs of this shard.
    pub jobs_in_shard: usize,
    /// Jobs simulated now.
    pub jobs_done: usize,
    /// Jobs whose file was already there.
    pub jobs_skipped_existing: usize,
    /// Jobs with a failure note from an earlier run, not retried (see `retry_failed`).
    pub jobs_skipped_failed: usize,
    /// Jobs that failed now.
    pub jobs_failed: usize,
    /// Those failures.
    pub failed: Vec<FailedJob>,
    /// Frames simulated now.
    pub frames_simulated: usize,
    /// Wall time, seconds.
    pub wall_time_s: f64,
    /// Threads used.
    pub threads: usize,
    /// Wall time per simulated frame times the threads used: the cost of a frame on one core.
    pub ms_per_frame_per_thread: f64,
    /// Wall time per simulated frame (throughput of the whole run).
    pub ms_per_frame_wall: f64,
    /// Substeps per frame (without retries) for this garment.
    pub substeps_per_frame: usize,
    /// Their step in seconds per metre of the garment's median rest edge: above
    /// [`DriveConfig::stable_step_per_edge_s_per_m`] the cloth may crumple (set
    /// `simulation.max_step_per_edge_s_per_m`).
    pub step_per_edge_s_per_m: f64,
    /// Where it ran.
    pub machine: Machine,
}

/// What [`simulate`] did.
#[derive(Clone, Debug)]
pub enum SimulateOutcome {
    /// Jobs ran; the report was written to the path.
    Ran(Box<SimulateReport>, PathBuf),
    /// Nothing was left to do: `done` jobs finished, `failed_before` failed in an earlier run;
    /// the report of the run that did the work is kept at the path.
    NothingToDo {
        /// Jobs already simulated.
        done: usize,
        /// Jobs that failed in an earlier run and were not retried.
        failed_before: usize,
        /// The kept report.
        report: PathBuf,
    },
}

/// This shard's jobs of `e`, those `only` keeps (an error when it keeps none).
fn selected_jobs(e: &Experiment, options: &SimulateOptions) -> Result<Vec<Job>> {
    let (index, count) = options.shard;
    let only = &options.only;
    let mine: Vec<Job> = jobs(e)
        .into_iter()
        .enumerate()
        .filter(|(k, _)| k % count == index)
        .map(|(_, j)| j)
        .filter(|j| only.is_empty() || only.iter().any(|p| j.stem.starts_with(p)))
        .collect();
    if mine.is_empty() && !only.is_empty() {
        bail!("no job of {} starts with {}", e.name, only.join(" or "));
    }
    Ok(mine)
}

/// Simulate this shard's jobs of `e` (see the module docs). `config` names the config file in
/// the report.
pub fn simulate(
    e: &Experiment,
    data: &DataDir,
    options: &SimulateOptions,
    config: &str,
    progress: &dyn Progress,
) -> Result<SimulateOutcome> {
    let start = Instant::now();
    let args = options;
    let (index, count) = options.shard;
    if count == 0 || index >= count {
        bail!("shard {index}/{count}: need 0 ≤ I < N");
    }
    let inputs = SimInputs::load(e, data)?;
    let edge = Cloth::from_garment(&inputs.garment, inputs.material.clone())?.median_rest_edge_m();
    let substeps_per_frame = inputs.drive.substeps_for_edge(edge, sartor_core::FPS);
    let step_per_edge_s_per_m = inputs.drive.step_per_edge_s_per_m(edge, sartor_core::FPS);
    let stable = inputs.drive.stable_step_per_edge_s_per_m();
    if step_per_edge_s_per_m > stable * (1.0 + 1e-9) {
        progress.println(&format!(
            "warning: {} substeps per frame are a step of {step_per_edge_s_per_m:.3} s per metre \
             of the garment's median edge ({:.1} mm), above the {stable} at which the T-shirts \
             stay smooth with {:?} friction: the cloth may crumple (set \
             simulation.max_step_per_edge_s_per_m)",
            substeps_per_frame,
            edge * 1e3,
            inputs.drive.sim.friction_model
        ));
    }
    if inputs.drive.sim.friction_model == FrictionModel::Implicit
        && substeps_per_frame < IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME
    {
        progress.println(&format!(
            "warning: {substeps_per_frame} substeps per frame, fewer than the \
             {IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME} at which the implicit friction kept contacts \
             off the projection fallback (set simulation.substeps_per_frame)"
        ));
    }
    let out = e.sim_dir();
    std::fs::create_dir_all(out.join(FAILED_DIR))
        .with_context(|| format!("creating {}", out.display()))?;
    write_json(&out.join("config.json"), e)?;
    let plan = e.plan();
    let mine = selected_jobs(e, options)?;
    let failed_before = |j: &Job| {
        out.join(FAILED_DIR)
            .join(format!("{}.json", j.stem))
            .exists()
    };
    let todo: Vec<&Job> = mine
        .iter()
        .filter(|j| !out.join(format!("{}.mcap", j.stem)).exists())
        .filter(|j| args.retry_failed || !failed_before(j))
        .collect();
    let skipped_failed = mine
        .iter()
        .filter(|j| !out.join(format!("{}.mcap", j.stem)).exists() && failed_before(j))
        .count()
        * usize::from(!args.retry_failed);
    let skipped = mine.len() - todo.len() - skipped_failed;
    let name = if count == 1 {
        "simulate.json".to_string()
    } else {
        format!("simulate-shard-{index}-of-{count}.json")
    };
    if todo.is_empty() && out.join(&name).exists() {
        // Keep the report of the run that did the work.
        return Ok(SimulateOutcome::NothingToDo {
            done: skipped,
            failed_before: skipped_failed,
            report: out.join(&name),
        });
    }
    // Frames per job, for the ETA.
    let frames_of = |j: &Job| -> Result<usize> {
        let n = if j.motion == REST_MOTION {
            0
        } else {
            inputs.motion(e, &j.motion)?.n_frames()
        };
        Ok(inputs.drive.blend_frames + inputs.drive.rest_frames + n)
    };
    let total_frames: usize = todo
        .iter()
        .map(|j| frames_of(j))
        .collect::<Result<Vec<_>>>()?
        .iter()
        .sum();
    progress.start("simulate", total_frames as u64, "frames");
    let sequences_done = AtomicUsize::new(0);
    let failed = Mutex::new(Vec::new());
    let frames_done = AtomicUsize::new(0);
    let threads = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|err| Error::Invalid(format!("starting {threads} threads: {err}")))?;
    progress.message(&format!("0/{} sequences", todo.len()));
    let result: Result<()> = pool.install(|| {
        todo.par_iter().try_for_each(|job| -> Result<()> {
            let shape = &plan.shapes[job.shape];
            let mut betas = shape.betas.clone();
            betas.resize(inputs.body.n_betas(), 0.0);
            let motion = if job.motion == REST_MOTION {
                None
            } else {
                Some(inputs.motion(e, &job.motion)?)
            };
            let mut last = 0usize;
            // The simulator counts frames from 0 again when it restarts a sequence with a larger
            // body region (the cloth left the region): only frames past the furthest reached
            // advance the bar. (A CMU clip in the tiny pipeline test restarts this way.)
            let mut on_frame = |done: usize, _total: usize| {
                if done > last {
                    progress.inc((done - last) as u64);
                    frames_done.fetch_add(done - last, Ordering::Relaxed);
                    last = done;
                }
            };
            let path = out.join(format!("{}.mcap", job.stem));
            match simulate_sequence(
                &inputs.body,
                &inputs.garment,
                &inputs.material,
                &betas,
                motion.as_ref(),
                &inputs.drive,
                &mut on_frame,
            ) {
                Ok(sequence) => {
                    sequence
                        .write(&path)
                        .with_context(|| format!("writing {}", path.display()))?;
                    let _ = std::fs::remove_file(
                        out.join(FAILED_DIR).join(format!("{}.json", job.stem)),
                    );
                }
                Err(err) => {
                    let note = FailedJob {
                        stem: job.stem.clone(),
                        reason: err.to_string(),
                    };
                    write_json(
                        &out.join(FAILED_DIR).join(format!("{}.json", job.stem)),
                        &note,
                    )?;
                    progress.println(&format!("failed: {} — {}", job.stem, note.reason));
                    failed
                        .lock()
                        .map_err(|_| Error::Invalid("a simulation thread panicked".into()))?
                        .push(note);
                }
            }
            let n = sequences_done.fetch_add(1, Ordering::Relaxed) + 1;
            progress.message(&format!("{n}/{} sequences", todo.len()));
            Ok(())
        })
    });
    progress.finish();
    result?;
    let failed = failed
        .into_inner()
        .map_err(|_| Error::Invalid("a simulation thread panicked".into()))?;
    let wall = start.elapsed().as_secs_f64();
    let frames = frames_done.load(Ordering::Relaxed);
    let per_frame_wall = if frames > 0 {
        wall * 1e3 / frames as f64
    } else {
        0.0
    };
    let report = SimulateReport {
        config: config.to_string(),
        config_sha256: Experiment::section_sha256(e)?,
        simulation_sha256: Experiment::section_sha256(&inputs.drive)?,
        shard_index: index,
        shard_count: count,
        jobs_in_shard: mine.len(),
        jobs_done: todo.len() - failed.len(),
        jobs_skipped_existing: skipped,
        jobs_skipped_failed: skipped_failed,
        jobs_failed: failed.len(),
        failed,
        frames_simulated: frames,
        wall_time_s: wall,
        threads,
        ms_per_frame_per_thread: per_frame_wall * threads.min(todo.len().max(1)) as f64,
        ms_per_frame_wall: per_frame_wall,
        substeps_per_frame,
        step_per_edge_s_per_m,
        machine: Machine::current(),
    };
    let path = out.join(&name);
    write_json(&path, &report)?;
    Ok(SimulateOutcome::Ran(Box::new(report), path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_come_from_flags_or_the_environment() {
        let none = |_: &str| None;
        assert_eq!(resolve_shard(None, None, &none).expect("ok"), (0, 1));
        assert_eq!(
            resolve_shard(Some("3/16"), None, &none).expect("ok"),
            (3, 16)
        );
        assert!(resolve_shard(Some("16/16"), None, &none).is_err());
        assert!(resolve_shard(Some("3"), None, &none).is_err());
        let k8s = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "2".to_string());
        assert_eq!(resolve_shard(None, Some(4), &k8s).expect("ok"), (2, 4));
        assert!(resolve_shard(None, None, &k8s).is_err(), "count missing");
        let slurm = |k: &str| match k {
            "SLURM_ARRAY_TASK_ID" => Some("5".to_string()),
            "SLURM_ARRAY_TASK_COUNT" => Some("8".to_string()),
            _ => None,
        };
        assert_eq!(resolve_shard(None, None, &slurm).expect("ok"), (5, 8));
    }

    #[test]
    fn only_keeps_the_jobs_with_a_prefix_and_names_one_that_matches_none() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let data = DataDir::new(&root).expect("data folder");
        let path = root.join("configs/default.json");
        let e = Experiment::load(&path, &data, Path::new("runs")).expect("valid");
        let stems = |options: &SimulateOptions| -> Vec<String> {
            selected_jobs(&e, options)
                .expect("jobs")
                .into_iter()
                .map(|j| j.stem)
                .collect()
        };
        let all = stems(&SimulateOptions::default());
        let only = |prefixes: &[&str], shard| SimulateOptions {
            only: prefixes.iter().map(|p| p.to_string()).collect(),
            shard,
            ..SimulateOptions::default()
        };
        let nominal = stems(&only(&["s00__"], (0, 1)));
        let expected: Vec<String> = all
            .iter()
            .filter(|s| s.starts_with("s00__"))
            .cloned()
            .collect();
        assert!(nominal.len() > 4 && nominal.len() < all.len() / 4);
        assert_eq!(nominal, expected);
        let two = stems(&only(&["s00__", "h00__"], (0, 1)));
        assert!(two.len() > nominal.len());
        assert!(
            two.iter()
                .all(|s| s.starts_with("s00__") || s.starts_with("h00__"))
        );
        // Within a shard: the shard's jobs, then the prefix.
        let shard = stems(&only(&["s00__"], (1, 3)));
        let shard_all = stems(&only(&[], (1, 3)));
        assert!(
            shard
                .iter()
                .all(|s| s.starts_with("s00__") && shard_all.contains(s))
        );
        let err = selected_jobs(&e, &only(&["s99__"], (0, 1))).expect_err("no such shape");
        assert!(err.to_string().contains("s99__"), "{err}");
    }

    #[test]
    fn every_shape_gets_a_rest_job_and_file_names_are_unique() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let data = DataDir::new(&root).expect("data folder");
        for name in ["default", "procedural"] {
            let path = root.join(format!("configs/{name}.json"));
            let e = Experiment::load(&path, &data, Path::new("runs")).expect("valid");
            let all = jobs(&e);
            let n_shapes =
                e.shapes.train.len() + e.shapes.held_out.len() + e.shapes.validation.len();
            assert_eq!(
                all.iter().filter(|j| j.motion == REST_MOTION).count(),
                n_shapes
            );
            assert_eq!(all.len(), n_shapes + e.plan().sequences.len());
            let stems: std::collections::BTreeSet<&String> = all.iter().map(|j| &j.stem).collect();
            assert_eq!(stems.len(), all.len(), "{name}: unique file names");
        }
    }
}
