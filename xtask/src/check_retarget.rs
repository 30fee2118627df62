//! `cargo xtask check-retarget`: retarget every BVH file of a folder onto the built-in body and
//! check every frame against the file's own forward kinematics
//! ([`sartor_motion::check_bvh_retarget`]); print one line per clip and write a JSON report with
//! the worst angle per bone and clip. Fails when a clip fails.

use std::path::PathBuf;

use anyhow::Context;
use sartor_cli::Env;
use sartor_eval::{Machine, write_json};
use sartor_motion::{
    Bvh, BvhJointMatch, ClipCheck, RetargetBody, RetargetCheckOptions, check_bvh_retarget,
};
use serde::Serialize;

/// Arguments of `check-retarget`.
#[derive(clap::Args, Debug)]
pub struct CheckRetargetArgs {
    /// A folder of `.bvh` files (all are checked, in name order) or one file.
    #[arg(long, default_value = "../shared/cmu")]
    pub from: PathBuf,
    /// The JSON report.
    #[arg(long, default_value = "check-retarget.json")]
    pub out: PathBuf,
    /// Largest angle between our bone and the file's, degrees.
    #[arg(long, default_value_t = sartor_motion::MAX_BONE_ANGLE_DEG)]
    pub max_angle_deg: f64,
}

/// The worst value of one bone over all clips.
#[derive(Serialize)]
struct BoneSummary {
    bone: String,
    kind: &'static str,
    worst_angle_deg: f64,
    worst_clip: String,
    worst_frame: usize,
    worst_angle_to_file_bone_deg: f64,
}

#[derive(Serialize)]
struct Report {
    from: String,
    body: String,
    machine: Machine,
    max_angle_deg: f64,
    clips_checked: usize,
    clips_failed: usize,
    frames_checked: usize,
    worst_bone_angle_deg: f64,
    worst_pelvis_deg: f64,
    worst_root_m: f64,
    worst_separation_difference: f64,
    crossed_frames: usize,
    file_close_or_crossed_frames: usize,
    tpose_frames_detected: usize,
    smallest_tpose_jump_deg: f64,
    largest_limb_step_deg: f64,
    bones: Vec<BoneSummary>,
    clips: Vec<ClipCheck>,
}

/// Run the check.
pub fn check_retarget(args: &CheckRetargetArgs, env: &Env) -> anyhow::Result<()> {
    let files: Vec<PathBuf> = if args.from.is_dir() {
        let mut f: Vec<PathBuf> = std::fs::read_dir(&args.from)
            .with_context(|| format!("reading {}", args.from.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("bvh")))
            .collect();
        f.sort();
        f
    } else {
        vec![args.from.clone()]
    };
    anyhow::ensure!(
        !files.is_empty(),
        "no .bvh files in {}",
        args.from.display()
    );
    let body_dir = env.data.body_dir();
    let body = RetargetBody::load(&body_dir)?;
    let options = RetargetCheckOptions {
        max_bone_angle_deg: args.max_angle_deg,
        ..RetargetCheckOptions::default()
    };
    let mut clips = Vec::with_capacity(files.len());
    for path in &files {
        let bvh = Bvh::load(path)?;
        let c = check_bvh_retarget(&bvh, &body, &options)
            .with_context(|| format!("checking {}", path.display()))?;
        println!(
            "{:<8} {:>6} frames  bones ≤ {:>5.2}°  pelvis {:>5.2}°  root {:.1e} m  \
             separation Δ {:>4.2}  tpose {}  {}",
            c.clip,
            c.frames,
            c.worst_bone_angle_deg(),
            c.pelvis_worst_deg,
            c.root_worst_m,
            c.crossing.max_separation_difference,
            match &c.tpose_frame {
                Some(t) if t.is_added_tpose => "dropped",
                Some(_) => "no",
                None => "n/a",
            },
            if c.passed() {
                "ok".to_string()
            } else {
                format!("FAIL: {}", c.failures.join("; "))
            }
        );
        if c.matched_by == BvhJointMatch::Structure {
            let pairs: Vec<String> = c.joints.iter().map(|[f, r]| format!("{f}→{r}")).collect();
            println!("    matched by structure: {}", pairs.join(", "));
        }
        clips.push(c);
    }
    let mut bones: Vec<BoneSummary> = Vec::new();
    for c in &clips {
        for b in &c.bones {
            match bones.iter_mut().find(|s| s.bone == b.bone) {
                Some(s) => {
                    if b.worst_angle_deg > s.worst_angle_deg {
                        s.worst_angle_deg = b.worst_angle_deg;
                        s.worst_clip = c.clip.clone();
                        s.worst_frame = b.worst_frame;
                    }
                    s.worst_angle_to_file_bone_deg = s
                        .worst_angle_to_file_bone_deg
                        .max(b.worst_angle_to_file_bone_deg);
                }
                None => bones.push(BoneSummary {
                    bone: b.bone.clone(),
                    kind: b.kind,
                    worst_angle_deg: b.worst_angle_deg,
                    worst_clip: c.clip.clone(),
                    worst_frame: b.worst_frame,
                    worst_angle_to_file_bone_deg: b.worst_angle_to_file_bone_deg,
                }),
            }
        }
    }
    let max = |f: &dyn Fn(&ClipCheck) -> f64| clips.iter().map(f).fold(0.0, f64::max);
    let detected: Vec<f64> = clips
        .iter()
        .filter_map(|c| c.tpose_frame.as_ref())
        .filter(|t| t.is_added_tpose)
        .map(|t| t.jump_to_next_deg)
        .collect();
    let report = Report {
        from: env.data.relative(&args.from),
        body: env.data.relative(&body_dir),
        machine: Machine::current(),
        max_angle_deg: args.max_angle_deg,
        clips_checked: clips.len(),
        clips_failed: clips.iter().filter(|c| !c.passed()).count(),
        frames_checked: clips.iter().map(|c| c.frames).sum(),
        worst_bone_angle_deg: max(&|c| c.worst_bone_angle_deg()),
        worst_pelvis_deg: max(&|c| c.pelvis_worst_deg),
        worst_root_m: max(&|c| c.root_worst_m),
        worst_separation_difference: max(&|c| c.crossing.max_separation_difference),
        crossed_frames: clips.iter().map(|c| c.crossing.crossed_frames).sum(),
        file_close_or_crossed_frames: clips
            .iter()
            .map(|c| c.crossing.file_close_or_crossed_frames)
            .sum(),
        tpose_frames_detected: detected.len(),
        smallest_tpose_jump_deg: detected.iter().copied().fold(f64::INFINITY, f64::min),
        largest_limb_step_deg: max(&|c| c.max_limb_step_deg.unwrap_or(0.0)),
        bones,
        clips,
    };
    write_json(&args.out, &report)?;
    println!(
        "{} clips, {} frames: {} failed; worst bone {:.2e}°, pelvis {:.2e}°, root {:.1e} m, \
         separation Δ {:.3} leg lengths, {} crossed frames; T-pose frame detected in {} \
         (smallest jump {:.1}°, largest limb step elsewhere {:.1}°); wrote {}",
        report.clips_checked,
        report.frames_checked,
        report.clips_failed,
        report.worst_bone_angle_deg,
        report.worst_pelvis_deg,
        report.worst_root_m,
        report.worst_separation_difference,
        report.crossed_frames,
        report.tpose_frames_detected,
        report.smallest_tpose_jump_deg,
        report.largest_limb_step_deg,
        args.out.display()
    );
    anyhow::ensure!(
        report.clips_failed == 0,
        "{} of {} clips failed the retarget check",
        report.clips_failed,
        report.clips_checked
    );
    Ok(())
}
