//! `sartor body` (`cargo xtask body`): write the posed body as one OBJ per frame, to look at what the model does.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use sartor_core::{
    BodyModel, Parallelism, PhenotypeRequest, PhenotypeSpace, skin_points, write_obj,
};
use sartor_import::load_smpl_npz;
use sartor_motion::{UpAxis, load_motion};
use sartor_pipeline::DataDir;

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
    /// An SMPL-family `.npz` model to use instead of the built-in body.
    #[arg(long)]
    smpl: Option<PathBuf>,
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
            let (phenotype, betas) = space.betas_for(&model, &request)?;
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
    let rest = model.shaped_vertices(&betas)?;
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
