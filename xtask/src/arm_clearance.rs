//! `cargo xtask arm-clearance`: how deep the forearms and hands of the posed body (and its upper
//! arms beyond the armpit, when the config's `simulation.arm_clearance` holds them out too) pass
//! into the rest of it, per (shape, motion) sequence of an experiment, beside whether that sequence's
//! simulation failed. Retargeted motion capture made for a slimmer actor can swing the arms
//! through a wider body's hips; cloth caught there has no position outside the body, and the
//! simulator's frame check fails the sequence. This measures the body alone, without cloth.
//!
//! For every motion frame of every planned sequence (the config's `max_frames` applied, no
//! blend or rest frames), the body is posed and every forearm or hand vertex (dominant skinning
//! joint `*ForeArm`, `*Hand`, `*Finger*`, `*Thumb*`) is tested against the torso, where a
//! T-shirt is (triangles of the spine, hips and shoulder roots, none touching an arm vertex),
//! by [`BodyDistance`]: the winding number of that open surface says whether it is inside, the
//! distance how deep.

use std::collections::BTreeSet;
use std::path::PathBuf;

use anyhow::Context;
use rayon::prelude::*;
use sartor_cli::{Env, ExperimentArgs, motion_options};
use sartor_core::BodyModel;
use sartor_dataset::{failed_stems, sequence_stem};
use sartor_eval::write_json;
use sartor_motion::{ArmClearance, UpAxis, load_motion};
use serde::Serialize;

/// Arguments of `arm-clearance`.
#[derive(clap::Args, Debug)]
pub struct ArmClearanceArgs {
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// Depth that counts a frame as intersecting, mm.
    #[arg(long, default_value_t = 5.0)]
    pub depth_mm: f64,
    /// Only the sequences that were simulated (done or failed).
    #[arg(long)]
    pub simulated_only: bool,
    /// Measure the motion after [`ArmClearance::apply`] (with the config's
    /// `simulation.arm_clearance` options, the defaults when it has none), as the simulator
    /// gets it, and report what it changed.
    #[arg(long)]
    pub corrected: bool,
    /// Output JSON.
    #[arg(long, default_value = "arm-clearance.json")]
    pub out: PathBuf,
}

/// One sequence of the report.
#[derive(Serialize)]
struct SequenceClearance {
    stem: String,
    /// Deepest held vertex (forearm, hand, upper arm when the config holds it) inside the
    /// torso, mm (0: none inside).
    max_depth_mm: f64,
    /// Motion frames with a vertex deeper than `--depth-mm`.
    frames_intersecting: usize,
    frames: usize,
    /// With `--corrected`: frames changed, largest shoulder rotation (degrees), time taken (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    frames_changed: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    max_angle_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    correct_secs: Option<f64>,
    /// The sequence's simulation: `failed` (`sim/failed/`), `done` or `not simulated`.
    simulation: &'static str,
}

#[derive(Serialize)]
struct Report {
    config: String,
    depth_mm: f64,
    sequences: Vec<SequenceClearance>,
    /// Per simulation outcome (`failed`, `done`, `not simulated`): sequences that intersect
    /// in some frame, of all.
    intersecting: Vec<(&'static str, usize, usize)>,
}

/// Run `arm-clearance`.
pub fn arm_clearance(args: &ArmClearanceArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let body = BodyModel::load(&e.body)?;
    let probe = ArmClearance::new(&body)?;
    let clearance = e.simulation.arm_clearance.clone().unwrap_or_default();
    let options = motion_options(&env.data, UpAxis::Y)?;
    let plan = e.plan();
    let failed: BTreeSet<String> = failed_stems(&e.sim_dir()).unwrap_or_default();
    let depth_m = args.depth_mm * 1e-3;
    let simulated = |q: &&sartor_dataset::SequencePlan| {
        let stem = sequence_stem(&plan.shapes[q.shape].id, &q.motion);
        failed.contains(&stem) || e.sim_dir().join(format!("{stem}.mcap")).exists()
    };
    let sequences: Vec<SequenceClearance> = plan
        .sequences
        .par_iter()
        .filter(|q| !args.simulated_only || simulated(q))
        .map(|q| -> anyhow::Result<SequenceClearance> {
            let shape = &plan.shapes[q.shape];
            let stem = sequence_stem(&shape.id, &q.motion);
            let motion = load_motion(&q.motion, &options)
                .with_context(|| format!("motion {:?}", q.motion))?;
            let n = e
                .motions
                .max_frames
                .map_or(motion.frames().len(), |m| m.min(motion.frames().len()));
            let poses = &motion.frames()[..n];
            let (depths, correction) = if args.corrected {
                let started = std::time::Instant::now();
                let (poses, r) = probe.apply(&body, &shape.betas, poses, &clearance)?;
                let secs = started.elapsed().as_secs_f64();
                let depths = probe.depths(&body, &shape.betas, &poses, &clearance)?;
                (depths, Some((r, secs)))
            } else {
                (probe.depths(&body, &shape.betas, poses, &clearance)?, None)
            };
            let max_depth = depths.iter().copied().fold(0.0f64, f64::max);
            let intersecting = depths.iter().filter(|&&d| d > depth_m).count();
            let simulation = if failed.contains(&stem) {
                "failed"
            } else if e.sim_dir().join(format!("{stem}.mcap")).exists() {
                "done"
            } else {
                "not simulated"
            };
            Ok(SequenceClearance {
                simulation,
                stem,
                max_depth_mm: max_depth * 1e3,
                frames_intersecting: intersecting,
                frames: n,
                frames_changed: correction.as_ref().map(|c| c.0.frames_changed),
                max_angle_deg: correction.as_ref().map(|c| c.0.max_angle_rad.to_degrees()),
                correct_secs: correction.as_ref().map(|c| c.1),
            })
        })
        .collect::<anyhow::Result<_>>()?;
    let intersecting: Vec<(&'static str, usize, usize)> = ["failed", "done", "not simulated"]
        .into_iter()
        .map(|outcome| {
            let of = sequences.iter().filter(|s| s.simulation == outcome);
            let hit = of.clone().filter(|s| s.frames_intersecting > 0).count();
            (outcome, hit, of.count())
        })
        .collect();
    println!(
        "sequences whose held arm vertices go deeper than {} mm into the torso:",
        args.depth_mm
    );
    for (outcome, hit, of) in &intersecting {
        println!("  simulation {outcome}: {hit} of {of}");
    }
    let report = Report {
        config: args.experiment.name(&env.data),
        depth_mm: args.depth_mm,
        intersecting,
        sequences,
    };
    write_json(&args.out, &report)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sartor_motion::ClearanceOptions;

    #[test]
    fn a_walk_on_a_wide_body_sinks_the_hands_into_the_hips_and_the_rest_pose_does_not() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let data = sartor_core_data(&root);
        let body = BodyModel::load(&data.body_dir()).expect("body");
        let probe = ArmClearance::new(&body).expect("probe");
        let betas = [0.0, 2.0];
        let rest = sartor_core::Pose::rest(body.skeleton().n_joints());
        let options = ClearanceOptions::default();
        let at_rest = probe
            .depths(&body, &betas, &[rest], &options)
            .expect("depths");
        assert!(at_rest[0] < 1e-3, "rest pose: {:.1} mm", at_rest[0] * 1e3);
        // CMU 02_02 (a walk, a failing sequence of the CMU experiment on this shape): the
        // swinging forearm goes centimetres into the hips.
        let motion = motion_options(&data, UpAxis::Y).expect("options");
        let walk = load_motion("cmu/02_02@8+60", &motion).expect("clip");
        let depths = probe
            .depths(&body, &betas, walk.frames(), &options)
            .expect("depths");
        let deepest = depths.iter().copied().fold(0.0, f64::max);
        assert!(deepest > 0.02, "deepest {:.1} mm", deepest * 1e3);
    }

    fn sartor_core_data(root: &std::path::Path) -> sartor_pipeline::DataDir {
        sartor_pipeline::DataDir::new(root).expect("the workspace is a data folder")
    }
}
