//! `sartor demo` (`cargo xtask demo`): the shipped T-shirt model on a few bodies through a few clips, with
//! frames per second and glTF / MCAP / PNG (/ OBJ) files. Needs only a clone and a toolchain.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use sartor_core::{BodyMeasurements, BodyMeasurer, BodyModel, PhenotypeRequest, PhenotypeSpace};
use sartor_eval::{Machine, write_json};
use sartor_motion::{
    Bvh, BvhJointMatch, ClearanceOptions, MotionWindow, UpAxis, load_motion, map_bvh_joints,
};
use sartor_pipeline::{ClothCheck, DataDir, Format, animate, model_betas, write_animation};
use sartor_runtime::{
    AnimatorOptions, CollisionOptions, GarmentBinding, GarmentNetwork, GarmentRig, NetworkOptions,
    Precision, StrainLimit,
};
use serde::Serialize;

use crate::motion_options;

/// The bodies shown when neither `--phenotype` nor `--beta` is given.
pub const DEFAULT_PHENOTYPES: [&str; 3] = [
    "female, 1.60 m, light",
    "male, 1.75 m, average",
    "male, 1.90 m, heavy",
];

/// The clips shown when `--motion` is not given.
pub const DEFAULT_MOTIONS: [&str; 3] = ["walk", "dance_disco", "jumping_jacks"];

/// Arguments of `demo`.
#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// The exported model folder (default: the shipped `datasets/models/default`).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// A body, as a phenotype such as "female, 1.70 m, heavy" (repeatable).
    #[arg(long)]
    pub phenotype: Vec<String>,
    /// A body, as a comma-separated shape vector (repeatable; missing components are 0).
    #[arg(long = "beta", allow_hyphen_values = true)]
    pub betas: Vec<String>,
    /// A motion: a procedural clip name, `walk`, or a .bvh / .npz (AMASS) / .json file
    /// (repeatable).
    #[arg(long)]
    pub motion: Vec<String>,
    /// AMASS files: the file's up axis (`y` or `z`).
    #[arg(long, default_value = "y")]
    pub up_axis: UpAxis,
    /// Frames per clip (at most the clip's length).
    #[arg(long, default_value_t = 120)]
    pub frames: usize,
    /// Output formats.
    #[arg(long, value_delimiter = ',', default_value = "gltf,mcap,png")]
    pub formats: Vec<Format>,
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    /// Push only the garment's vertices out of the body, not its triangles too. By default
    /// (as on the try-on page) the triangles are pushed as well: where the body is curved more
    /// tightly than the garment is fine (raised arms' shoulders), skin otherwise shows between
    /// cloth vertices that are all outside. Faster; `demo.json` records which.
    #[arg(long, conflicts_with = "push_triangles")]
    pub vertices_only: bool,
    /// Push the garment's triangles out of the body too: the default (kept for scripts that
    /// pass it).
    #[arg(long)]
    pub push_triangles: bool,
    /// The longest a garment edge may be, over its rest length: edges the network and the
    /// skinning stretch further (a sleeve's underside with the arms up) are pulled back before
    /// the post-process (`sartor_runtime::StrainLimit`). 1.5 by default: the simulated cloth's
    /// 99.9th percentile over the training sequences is 1.41–1.56.
    #[arg(long, default_value_t = StrainLimit::default().max_stretch)]
    pub max_stretch: f32,
    /// No strain limit: the garment as the network and the skinning predict it (the paper's
    /// method); `demo.json` records which.
    #[arg(long, conflicts_with = "max_stretch")]
    pub no_strain_limit: bool,
    /// Storage of the network's weights: f32, or f16 / int8 (smaller and faster, within
    /// 0.1 mm / 1 mm of f32 per vertex on the runtime's test scene).
    #[arg(long, value_enum, default_value = "f32")]
    pub precision: DemoPrecision,
    /// Leave the motion's arms as they come. By default each body's arms are first held out of
    /// its torso as the shipped model's training data held them ([`shipped_arm_clearance`]):
    /// motion capture retargeted onto a body wider than its performer sinks the forearms into
    /// the hips and the upper arms into the torso's sides, with the shirt caught between.
    #[arg(long)]
    pub no_arm_clearance: bool,
    /// Leave the motion's legs as they come. By default they are held out of the torso too
    /// (`sartor_motion::LEG_CLEARANCE_M`, which the training data did not do): a performer's
    /// raised thigh (climbing, dancing, crouching) sinks into the body's belly with the shirt
    /// between. Without the arms' clearance the legs are not held either.
    #[arg(long)]
    pub no_leg_clearance: bool,
}

/// How the shipped model's training motions held the arms out of the torso: the
/// `simulation.arm_clearance` of `configs/default.json` (forearms and hands 25 mm out, upper
/// arms beyond the armpit 5 mm).
pub fn shipped_arm_clearance() -> ClearanceOptions {
    ClearanceOptions {
        upper_arm_clearance_m: Some(0.005),
        ..ClearanceOptions::default()
    }
}

/// The limbs as the players (`demo`, the try-on page) hold them: the arms as the shipped
/// model's training motions did ([`shipped_arm_clearance`]), and the legs at
/// `sartor_motion::LEG_CLEARANCE_M`.
pub fn player_clearance() -> ClearanceOptions {
    shipped_arm_clearance().with_player_legs()
}

/// The limbs as `demo` holds them ([`player_clearance`]), unless `--no-arm-clearance` /
/// `--no-leg-clearance`.
fn demo_clearance(args: &DemoArgs) -> Option<ClearanceOptions> {
    (!args.no_arm_clearance).then(|| {
        let mut limbs = player_clearance();
        if args.no_leg_clearance {
            limbs.leg_clearance_m = None;
        }
        limbs
    })
}

/// `--precision` of `demo`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum DemoPrecision {
    F32,
    F16,
    Int8,
}

impl From<DemoPrecision> for Precision {
    fn from(p: DemoPrecision) -> Self {
        match p {
            DemoPrecision::F32 => Precision::F32,
            DemoPrecision::F16 => Precision::F16,
            DemoPrecision::Int8 => Precision::Int8,
        }
    }
}

#[derive(Serialize)]
struct DemoEntry {
    body: String,
    betas: Vec<f64>,
    motion: String,
    frames: usize,
    ms_per_frame: f64,
    frames_per_second: f64,
    /// Frames whose arms (or legs) were turned out of the torso (none without the clearance).
    arm_clearance_frames_changed: usize,
    /// The largest such turn, degrees.
    arm_clearance_max_angle_deg: f64,
    /// The deepest held arm (or leg) vertex inside the torso as the motion came, mm.
    arm_depth_before_mm: Option<f64>,
    /// The body's size-chart measurements (`sartor_core::BodyMeasurer`): height, girths, mass.
    body_measurements: Option<BodyMeasurements>,
    /// How the garment sits on the body over the clip: inside it, and stretched.
    #[serde(flatten)]
    check: ClothCheck,
    files: Vec<String>,
}

#[derive(Serialize)]
struct DemoReport {
    model: String,
    precision: &'static str,
    garment_vertices: usize,
    /// Whether the post-process pushed the garment's triangles out of the body as well as its
    /// vertices (`CollisionOptions::faces`; `--vertices-only` turns it off).
    push_triangles: bool,
    /// The strain limit's longest edge over its rest length (`--max-stretch`); none with
    /// `--no-strain-limit`.
    strain_limit: Option<f32>,
    /// How far out of the torso the limbs were held, m: the arms' forearms and hands and upper
    /// arms, and the legs (`null`: not held).
    arm_clearance_m: Option<f64>,
    upper_arm_clearance_m: Option<f64>,
    leg_clearance_m: Option<f64>,
    machine: Machine,
    note: &'static str,
    /// For each BVH motion whose joints were matched by the skeleton's structure (another
    /// tool's naming than CMU's), which file joint drove which rig joint.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    motion_joints: Vec<MotionJoints>,
    runs: Vec<DemoEntry>,
}

/// Which file joint drove which rig joint, for one BVH motion.
#[derive(Serialize)]
struct MotionJoints {
    motion: String,
    /// `[file joint, rig joint]` in file order.
    joints: Vec<[String; 2]>,
    /// The file's joints that drove nothing (fingers, eyes, end joints).
    unused: Vec<String>,
}

/// The joint match of each BVH file among `specs` that was matched by its structure (printed
/// too: a user's file from another tool should say what drove what).
fn bvh_joint_maps(specs: &[&str]) -> anyhow::Result<Vec<MotionJoints>> {
    let mut out = Vec::new();
    for spec in specs {
        let file = MotionWindow::parse(spec)?.map_or_else(|| spec.to_string(), |w| w.motion);
        if !file.to_ascii_lowercase().ends_with(".bvh") {
            continue;
        }
        let bvh = Bvh::load(Path::new(&file))?;
        let Ok(map) = map_bvh_joints(&bvh) else {
            continue;
        };
        if map.matched_by != BvhJointMatch::Structure {
            continue;
        }
        let (joints, unused) = map.pairs(&bvh);
        let pairs: Vec<String> = joints.iter().map(|[f, r]| format!("{f}→{r}")).collect();
        println!(
            "{spec}: joints matched by the skeleton's structure: {}; unused: {}",
            pairs.join(", "),
            if unused.is_empty() {
                "none".to_string()
            } else {
                unused.join(", ")
            }
        );
        out.push(MotionJoints {
            motion: spec.to_string(),
            joints,
            unused,
        });
    }
    Ok(out)
}

/// Run the demo.
/// The strain limit `args` ask for.
fn strain_limit(args: &DemoArgs) -> Option<StrainLimit> {
    (!args.no_strain_limit).then(|| StrainLimit {
        max_stretch: args.max_stretch,
        ..StrainLimit::default()
    })
}

pub fn demo(args: &DemoArgs, data: &DataDir) -> anyhow::Result<()> {
    let model_dir = args
        .model
        .clone()
        .unwrap_or_else(|| data.default_model_dir());
    let body_dir = data.body_dir();
    let body = Arc::new(
        BodyModel::load(&body_dir)
            .with_context(|| format!("loading the body from {}", body_dir.display()))?,
    );
    let options = NetworkOptions {
        precision: args.precision.into(),
        ..NetworkOptions::default()
    };
    let network = GarmentNetwork::load_with(&model_dir, options).with_context(|| {
        format!(
            "loading the garment model from {} (the shipped one is datasets/models/default; \
             make one with `sartor pipeline --config configs/default.json`)",
            model_dir.display()
        )
    })?;
    let binding = GarmentBinding::load(&model_dir)
        .with_context(|| format!("loading the garment binding from {}", model_dir.display()))?;
    let rig = Arc::new(GarmentRig::new(
        Arc::new(network),
        Arc::new(binding),
        body.clone(),
        AnimatorOptions {
            strain_limit: strain_limit(args),
            collision: Some(CollisionOptions {
                faces: !args.vertices_only,
                ..CollisionOptions::default()
            }),
            ..AnimatorOptions::default()
        },
    )?);

    // Bodies.
    let mut bodies: Vec<(String, Vec<f64>)> = Vec::new();
    for text in &args.betas {
        let betas = text
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<Result<Vec<_>, _>>()
            .with_context(|| format!("--beta {text:?}: not a comma-separated list of numbers"))?;
        body.check_betas(&betas)?;
        bodies.push((format!("beta {text}"), betas));
    }
    let phenotypes: Vec<&str> = if args.phenotype.is_empty() && args.betas.is_empty() {
        DEFAULT_PHENOTYPES.to_vec()
    } else {
        args.phenotype.iter().map(String::as_str).collect()
    };
    if !phenotypes.is_empty() {
        let space = PhenotypeSpace::load(&body_dir)?;
        for text in phenotypes {
            let request: PhenotypeRequest = text.parse()?;
            let (_, betas) = space
                .betas_for(&body, &request)
                .with_context(|| format!("--phenotype {text:?}"))?;
            bodies.push((text.to_owned(), betas));
        }
    }

    // Motions.
    let options = motion_options(data, args.up_axis)?;
    let specs: Vec<&str> = if args.motion.is_empty() {
        DEFAULT_MOTIONS.to_vec()
    } else {
        args.motion.iter().map(String::as_str).collect()
    };
    let motions = specs
        .iter()
        .map(|s| load_motion(s, &options).with_context(|| format!("motion {s:?}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let motion_joints = bvh_joint_maps(&specs)?;

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let total = (bodies.len() * motions.len()) as u64;
    let bar = indicatif::ProgressBar::new(total).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} clips {msg}")
            .expect("static template"),
    );
    let clearance = demo_clearance(args);
    let measurer = BodyMeasurer::new(&body)
        .inspect_err(|e| bar.println(format!("the bodies are not measured: {e}")))
        .ok();
    let mut runs = Vec::new();
    for (b, (label, betas)) in bodies.iter().enumerate() {
        let (betas, dropped) = model_betas(&rig, betas);
        if dropped > 0 {
            bar.println(format!(
                "{label}: the model takes {} shape components; {dropped} more are set to 0 \
                 (body and garment both)",
                betas.len()
            ));
        }
        // Reported, not required: a body the measurer cannot read is still animated.
        let body_measurements = match &measurer {
            Some(m) => {
                let mut full = betas.clone();
                full.resize(body.n_betas(), 0.0);
                match m.measure(&body, &body.shaped_vertices(&full)?, &full) {
                    Ok(measured) => {
                        bar.println(format!("{label}: {measured}"));
                        Some(measured)
                    }
                    Err(e) => {
                        bar.println(format!("{label}: not measured: {e}"));
                        None
                    }
                }
            }
            None => None,
        };
        for (spec, motion) in specs.iter().zip(&motions) {
            bar.set_message(format!("{label} / {spec}"));
            let anim = animate(
                &rig,
                &body,
                &betas,
                motion,
                Some(args.frames),
                clearance.as_ref(),
            )?;
            let clip: String = spec
                .rsplit('/')
                .next()
                .unwrap_or(spec)
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect();
            let stem = format!("body{b}_{clip}");
            let files = write_animation(
                &args.out,
                &stem,
                &anim,
                body.faces(),
                rig.binding().faces(),
                motion.fps(),
                &args.formats,
            )?;
            let ms = anim.ms_per_frame();
            let check = anim.check(
                body.faces(),
                rig.binding().faces(),
                rig.binding().template(),
            )?;
            let held = anim.arm_clearance.as_ref();
            let arms = held.map_or_else(String::new, |r| {
                format!(
                    "  arms held out of the torso in {} frames (up to {:.0}°)",
                    r.frames_changed,
                    r.max_angle_rad.to_degrees()
                )
            });
            let worst = check.worst_frame.map_or_else(String::new, |t| {
                format!(
                    " (most at frame {t}: {})",
                    check.worst_frame_triangles_inside
                )
            });
            bar.println(format!(
                "{label:<24} {spec:<16} {:>4} frames  {ms:>7.3} ms/frame  {:>8.0} frames/s{arms}\n\
                 {:<41} inside the body: {:.3} % of cloth vertices, {:.3} % of triangles{worst}; \
                 edges up to {:.1}× their rest length (p99 {:.2}×)",
                anim.garment.len(),
                1e3 / ms,
                "",
                check.cloth_vertices_inside_percent,
                check.cloth_triangles_inside_percent,
                check.edge_stretch_max,
                check.edge_stretch_p99,
            ));
            runs.push(DemoEntry {
                body: label.clone(),
                betas: betas.clone(),
                motion: (*spec).to_owned(),
                frames: anim.garment.len(),
                ms_per_frame: ms,
                frames_per_second: 1e3 / ms,
                arm_clearance_frames_changed: held.map_or(0, |r| r.frames_changed),
                arm_clearance_max_angle_deg: held.map_or(0.0, |r| r.max_angle_rad.to_degrees()),
                arm_depth_before_mm: held.map(|r| r.max_depth_before_m * 1e3),
                body_measurements,
                check,
                files: files.iter().map(|p| p.display().to_string()).collect(),
            });
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let report = DemoReport {
        model: model_dir.display().to_string(),
        precision: Precision::from(args.precision).name(),
        garment_vertices: rig.n_vertices(),
        push_triangles: !args.vertices_only,
        strain_limit: strain_limit(args).map(|l| l.max_stretch),
        arm_clearance_m: clearance.as_ref().map(|c| c.clearance_m),
        upper_arm_clearance_m: clearance.as_ref().and_then(|c| c.upper_arm_clearance_m),
        leg_clearance_m: clearance.as_ref().and_then(|c| c.leg_clearance_m),
        machine: Machine::current(),
        motion_joints,
        note: "ms_per_frame: GarmentAnimator::frame (network, skinning, collision post-process), \
               one thread; posing the full body for the files and holding the arms and legs out \
               of the torso (before the clip, per body) are not counted; \
               cloth_*_inside_percent: garment vertex-frames and triangle-frames (by centroid) \
               inside the whole posed body, by its winding number (eval's measure); \
               edge_stretch_*: garment edge length over its length in the rest template",
        runs,
    };
    let path = args.out.join("demo.json");
    write_json(&path, &report)?;
    println!(
        "wrote {} clips ({}) and {} to {}",
        report.runs.len(),
        args.formats
            .iter()
            .map(|f| f.name())
            .collect::<Vec<_>>()
            .join(", "),
        path.display(),
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_demo_holds_the_arms_as_the_shipped_models_experiment_did() {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/default.json");
        let config: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).expect("config")).expect("JSON");
        let theirs: ClearanceOptions =
            serde_json::from_value(config["simulation"]["arm_clearance"].clone())
                .expect("the shipped experiment holds the arms out");
        assert_eq!(shipped_arm_clearance(), theirs);
    }
}
