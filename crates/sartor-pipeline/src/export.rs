//! The `export` stage ([`export_run`], `sartor export --run runs/<exp> [--out DIR]`): the
//! trained models of a run as one
//! runtime model folder (default `runs/<exp>/export`): `model.safetensors` + `model.json`
//! (`sartor_model::export_model`: fit MLP, wrinkle GRU, linear baseline, normalisation, input
//! layout, garment and body identity) and `binding.safetensors` + `binding.json` (the dataset's
//! `T̄_c` and `W_c`, the body region the garment can touch). Nothing burn-specific is written.
//!
//! It also animates the exported model on the template body through one clip and writes the
//! result as an animated glTF, an MCAP (Foxglove) and OBJ sequences under `<out>/preview/`.
//!
//! The folder is assembled under a temporary name and renamed into place, so a failed export
//! leaves the previous one untouched.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use sartor_core::BodyModel;
use sartor_model::burn::tensor::Device;
use sartor_model::{AnyModel, ModelKind, export_model, load_trained};
use sartor_motion::{MotionSourceOptions, RetargetBody, load_motion};
use sartor_runtime::{AnimatorOptions, GarmentNetwork, GarmentRig};

use crate::error::{Context, ensure};
use crate::experiment::Experiment;
use crate::preview::{Format, animate, write_animation};
use crate::{DataDir, Error, Result};

pub use sartor_core::DEFAULT_REGION_MARGIN_MM;

/// How [`export_run`] exports.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// Output folder (default `<run>/export`).
    pub out: Option<PathBuf>,
    /// Body region margin, mm (see [`DEFAULT_REGION_MARGIN_MM`]).
    pub region_margin_mm: f64,
    /// Clip of the preview animation (`none` for no preview).
    pub preview_motion: String,
    /// Frames of the preview.
    pub preview_frames: usize,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            out: None,
            region_margin_mm: DEFAULT_REGION_MARGIN_MM,
            preview_motion: "walk_normal".into(),
            preview_frames: 60,
        }
    }
}

/// The experiment a run was made with (`sim/config.json`, as `simulate` saved it; its paths are
/// already absolute, `data` resolves any that are not).
pub fn run_experiment(run: &Path, data: &DataDir) -> Result<Experiment> {
    let path = run.join("sim/config.json");
    let runs_root = run
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    let e = Experiment::load(&path, data, &runs_root)
        .with_context(|| format!("{}: the run's experiment config", run.display()))?;
    ensure!(
        e.run_dir().file_name() == run.file_name(),
        "{}: the run folder is not named after its experiment {:?}",
        run.display(),
        e.name
    );
    Ok(e)
}

/// What [`export_run`] wrote.
#[derive(Clone, Debug)]
pub struct ExportSummary {
    /// The experiment.
    pub experiment: String,
    /// The export folder.
    pub out: PathBuf,
    /// The model's sizes.
    pub sizes: sartor_runtime::ModelSizes,
}

/// Export the run in folder `run` (see the module docs).
pub fn export_run(run: &Path, folders: &DataDir, args: &ExportOptions) -> Result<ExportSummary> {
    let e = run_experiment(run, folders)?;
    let out = args.out.clone().unwrap_or_else(|| run.join("export"));
    let data_dir = e.dataset_dir();
    let data = sartor_dataset::load_dataset(&data_dir)
        .with_context(|| format!("loading the dataset from {}", data_dir.display()))?;
    let body = BodyModel::load(&e.body)
        .with_context(|| format!("loading the body model from {}", e.body.display()))?;
    let cloth = sartor_dataset::read_binding(&data_dir, &body)?;
    let device = Device::flex();
    let train = e.train_dir();
    let load = |kind: ModelKind| {
        let dir = train.join(kind.name());
        load_trained(kind, &dir, &device).with_context(|| {
            format!(
                "loading the trained {} model from {} (run the train stage)",
                kind.name(),
                dir.display()
            )
        })
    };
    let (AnyModel::Fit(fit), AnyModel::Wrinkle(wrinkle)) =
        (load(ModelKind::Fit)?, load(ModelKind::Wrinkle)?)
    else {
        return Err(Error::Invalid(
            "load_trained returned another kind of model".into(),
        ));
    };
    // The baseline is optional in the format; export it when it was trained.
    let linear = match train.join("linear").join(sartor_model::BEST_FILE).exists() {
        true => match load(ModelKind::Linear)? {
            AnyModel::Linear(l) => Some(l),
            _ => {
                return Err(Error::Invalid(
                    "load_trained returned another kind of model".into(),
                ));
            }
        },
        false => None,
    };
    let model = export_model(&data, &fit, &wrinkle, linear.as_ref())?;

    // The dataset's binding, with the body region at the export's margin.
    let binding = cloth.with_region(&body, args.region_margin_mm * 1e-3)?;
    model.header().check_binding(&binding)?;
    binding.check_body(&body)?;

    let name = out
        .file_name()
        .map_or_else(|| "export".into(), |n| n.to_string_lossy().into_owned());
    let tmp = out.with_file_name(format!(".{name}.tmp"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    model.save(&tmp)?;
    binding.save(&tmp)?;

    if args.preview_motion != "none" {
        let network = Arc::new(GarmentNetwork::load(&tmp, Default::default())?);
        let body = Arc::new(body);
        let rig = Arc::new(GarmentRig::new(
            network,
            Arc::new(binding),
            body.clone(),
            AnimatorOptions::default(),
        )?);
        let options = MotionSourceOptions {
            motions_dir: folders.motions_dir(),
            body: Some(RetargetBody::load(&e.body)?),
            lenient: false,
            keep_tpose_frame: false,
            up_axis: sartor_motion::UpAxis::Y,
        };
        let motion = load_motion(&args.preview_motion, &options)
            .with_context(|| format!("preview motion {:?}", args.preview_motion))?;
        let betas = vec![0.0; rig.network().n_betas()];
        // The arms held as the training data held them.
        let clearance = e.simulation.arm_clearance.as_ref();
        let anim = animate(
            &rig,
            &body,
            &betas,
            &motion,
            Some(args.preview_frames),
            clearance,
        )?;
        write_animation(
            &tmp.join("preview"),
            &args.preview_motion,
            &anim,
            body.faces(),
            rig.binding().faces(),
            motion.fps(),
            &[Format::Gltf, Format::Mcap, Format::Obj],
        )?;
    }

    let old = out.with_file_name(format!(".{name}.old"));
    if out.exists() {
        if old.exists() {
            std::fs::remove_dir_all(&old).with_context(|| format!("removing {}", old.display()))?;
        }
        std::fs::rename(&out, &old).with_context(|| format!("moving {} aside", out.display()))?;
    }
    std::fs::rename(&tmp, &out).with_context(|| format!("renaming into {}", out.display()))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).with_context(|| format!("removing {}", old.display()))?;
    }
    Ok(ExportSummary {
        experiment: e.name.clone(),
        out,
        sizes: model.header().sizes,
    })
}
