//! `sartor body` (`cargo xtask body`): write the posed body as one OBJ per frame, to look at what the model does.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use sartor_core::{
    BodyMeasurer, BodyModel, Parallelism, PhenotypeRequest, PhenotypeSpace, skin_points, write_obj,
};
use sartor_import::load_smpl_npz;
use sartor_motion::{ArmClearance, UpAxis, load_motion};
use sartor_pipeline::DataDir;

use crate::demo::player_clearance;
use crate::motion_options;

/// Arguments of `body`.
#[derive(Args, Debug)]
pub struct BodyArgs {
    /// Shape vector, comma-separated (missing components are 0), e.g. `--beta 1.5,-0.5`.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        conflicts_with = "phenotype"
    )]
    beta: Vec<f64>,
    /// A phenotype such as "female, 1.70 m, heavy" (built-in body only).
    #[arg(long)]
    phenotype: Option<String>,
    /// A procedural clip name, `walk`, `rest`, or a .bvh / .npz (AMASS) / .json motion file.
    #[arg(long, default_value = "walk")]
    motion: String,
    /// AMASS files: the up axis of the file (`y` or `z`).
    #[arg(long, default_value = "y")]
    up_axis: UpAxis,
    /// Write at most this many frames.
    #[arg(long)]
    frames: Option<usize>,
    /// An SMPL-family `.npz` model to use instead of the built-in body (its arms are left as
    /// the motion puts them).
    #[arg(long)]
    smpl: Option<PathBuf>,
    /// Leave the motion's arms and legs as they come. By default the built-in body's arms and
    /// legs are held out of its torso as `demo` and the try-on page hold them
    /// (`player_clearance`: the arms as the shipped model's training data held them, and the
    /// legs), so that the body written is the one they show.
    #[arg(long)]
    no_arm_clearance: bool,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

/// Write the posed body (see the module docs).
pub fn body(args: &BodyArgs, data: &DataDir) -> anyhow::Result<()> {
    let model_dir = data.body_dir();
    let model = match &args.smpl {
        Some(path) => load_smpl_npz(path, None)?,
        None => BodyModel::load(&model_dir)?,
    };
    let betas = match &args.phenotype {
        Some(text) => {
            if args.smpl.is_some() {
                bail!("--phenotype works with the built-in body only");
            }
            let request: PhenotypeRequest = text.parse()?;
            let space = PhenotypeSpace::load(&model_dir)?;
            let (phenotype, betas) = space
                .betas_for(&model, &request)
                .with_context(|| format!("--phenotype {text:?}"))?;
            let rounded: Vec<String> = betas.iter().map(|b| format!("{b:.2}")).collect();
            println!(
                "phenotype {text:?} → {phenotype:?}, β [{}]",
                rounded.join(", ")
            );
            betas
        }
        None => args.beta.clone(),
    };
    model.check_betas(&betas)?;
    let rest = model.shaped_vertices(&betas)?;
    // Reported, not required: a body the measurer cannot read is still written.
    match BodyMeasurer::new(&model).and_then(|m| m.measure(&model, &rest, &betas)) {
        Ok(measured) => println!("{measured}"),
        Err(e) => println!("not measured: {e}"),
    }
    let motion = if args.motion == "rest" {
        None
    } else {
        let mut options = motion_options(data, args.up_axis)?;
        if args.smpl.is_some() {
            // Mocap is retargeted onto the built-in rig only.
            options.body = None;
        }
        Some(
            load_motion(&args.motion, &options)
                .with_context(|| format!("motion {:?}", args.motion))?,
        )
    };
    let joints = model.shaped_joints(&betas)?;
    let poses = match &motion {
        Some(m) => {
            if m.joint_names() != model.skeleton().names() {
                bail!(
                    "motion {} is for another skeleton than body {}",
                    m.name(),
                    model.name()
                );
            }
            m.frames().to_vec()
        }
        None => vec![sartor_core::Pose::rest(model.skeleton().n_joints())],
    };
    let n = args.frames.map_or(poses.len(), |f| f.min(poses.len()));
    let poses = if motion.is_some() && args.smpl.is_none() && !args.no_arm_clearance {
        let mut full_betas = betas.clone();
        full_betas.resize(model.n_betas(), 0.0);
        let (held, report) = ArmClearance::new(&model)?.apply(
            &model,
            &full_betas,
            &poses[..n],
            &player_clearance(),
        )?;
        println!(
            "arms and legs held out of the torso in {} of {n} frames (turned up to {:.1}°; \
             {:.1} mm deep before; --no-arm-clearance leaves them)",
            report.frames_changed,
            report.max_angle_rad.to_degrees(),
            report.max_depth_before_m * 1e3
        );
        held
    } else {
        poses
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = indicatif::ProgressBar::new(n as u64).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames {eta}")
            .expect("static template"),
    );
    let mut posed = vec![nalgebra::Vector3::zeros(); rest.len()];
    for (i, pose) in poses.iter().take(n).enumerate() {
        let (_, transforms) = model.skeleton().forward_kinematics(&joints, pose)?;
        skin_points(
            &rest,
            model.skin_weights(),
            &transforms,
            &mut posed,
            Parallelism::Rayon,
        )?;
        write_obj(
            &args.out.join(format!("frame_{i:04}.obj")),
            &posed,
            model.faces(),
        )?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let height = model.height_m(&betas)?;
    println!(
        "wrote {n} frames of {} (β = {betas:.3?}, standing height {height:.3} m) to {}",
        args.motion,
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sartor_core::read_obj;

    #[test]
    fn the_body_written_holds_the_arms_as_the_demo_does_unless_asked_not_to() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
        let data = DataDir::new(&root).expect("data folder");
        let dir = tempfile::tempdir().expect("temp");
        // CMU 02_02 on a heavy body: the hands brush the hips.
        let (clip, betas, frames) = ("cmu/02_02@8+6", vec![0.0, 2.0], 6);
        let written = |no_arm_clearance: bool, name: &str| -> Vec<Vec<nalgebra::Vector3<f64>>> {
            let out = dir.path().join(name);
            let args = BodyArgs {
                beta: betas.clone(),
                phenotype: None,
                motion: clip.into(),
                up_axis: UpAxis::Y,
                frames: None,
                smpl: None,
                no_arm_clearance,
                out: out.clone(),
            };
            body(&args, &data).expect("body");
            (0..frames)
                .map(|i| {
                    let mesh = read_obj(&out.join(format!("frame_{i:04}.obj"))).expect("OBJ");
                    mesh.positions().to_vec()
                })
                .collect()
        };
        let (held, raw) = (written(false, "held"), written(true, "raw"));

        // The same bodies posed here from the motion and from ArmClearance's poses of it.
        let model = BodyModel::load(&data.body_dir()).expect("body");
        let motion =
            load_motion(clip, &motion_options(&data, UpAxis::Y).expect("options")).expect("clip");
        let mut full = betas.clone();
        full.resize(model.n_betas(), 0.0);
        let (poses, report) = ArmClearance::new(&model)
            .expect("arms")
            .apply(&model, &full, motion.frames(), &player_clearance())
            .expect("apply");
        assert!(report.frames_changed > 0, "{report:?}");
        let gap = |a: &[nalgebra::Vector3<f64>], b: &[nalgebra::Vector3<f64>]| {
            a.iter()
                .zip(b)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max)
        };
        for t in 0..frames {
            let expect_held = model.posed_vertices(&full, &poses[t]).expect("pose");
            let expect_raw = model
                .posed_vertices(&full, &motion.frames()[t])
                .expect("pose");
            assert!(gap(&held[t], &expect_held) < 1e-5, "frame {t}");
            assert!(gap(&raw[t], &expect_raw) < 1e-5, "frame {t}");
            let turned = poses[t] != motion.frames()[t];
            assert_eq!(gap(&held[t], &raw[t]) > 1e-3, turned, "frame {t}");
        }
    }
}
