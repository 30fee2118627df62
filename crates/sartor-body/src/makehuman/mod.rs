//! The built-in body: MakeHuman's CC0 body converted into an SMPL-like [`BodyModel`].
//!
//! The raw assets (`shared/makehuman`, see its README) are converted once by
//! [`import_makehuman`] (`cargo xtask import-body`) into the committed folder
//! `datasets/body/makehuman/`:
//!
//! | file | content |
//! | --- | --- |
//! | `model.safetensors`, `model.json` | the [`BodyModel`]: mean adult template, 10 unit-variance shape components, `cmu_mb` joints and their shape basis, skin weights |
//! | `phenotype.safetensors`, `phenotype.json` | the [`PhenotypeSpace`](crate::PhenotypeSpace): MakeHuman's macro sliders → β |
//! | `bone_frames.json` | [`BoneFrames`]: Blender rest frames of the bones, for Blender-keyed motion |
//! | `tpose.json` | a [`Pose`] from the A-pose rest to MakeHuman's T-pose |
//! | `import-report.json` | [`ImportReport`]: what the import measured, and the files' hashes |
//!
//! Nothing here reads the raw assets at run time.
//!
//! ```no_run
//! let model = sartor_body::load_builtin()?;
//! let height = model.height_m(&[])?; // the mean adult
//! # let _ = height;
//! # Ok::<(), sartor_body::Error>(())
//! ```

use std::path::{Path, PathBuf};

use crate::io::read_file;
use crate::{BodyModel, Error, Pose, Result};

mod assets;
pub(crate) mod blender;
mod import;
mod pca;

pub use blender::{BONE_FRAMES_FILE, BoneFrames, blender_euler_xyz};
pub use import::{
    HeldOutReport, ImportOptions, ImportReport, JointReport, MeshReport, PcaReport, SAMPLE_RANGES,
    ShapeSpaceReport, SkinWeightReport, TPoseReport, TopKReport, import_makehuman,
};

/// File name of the T-pose inside the built-in model's folder.
pub const TPOSE_FILE: &str = "tpose.json";
/// File name of the import report inside the built-in model's folder.
pub const IMPORT_REPORT_FILE: &str = "import-report.json";

/// The folder of the built-in model, `<workspace>/datasets/body/makehuman`, resolved from
/// this crate's source location.
pub fn builtin_model_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman")
}

/// Load the built-in MakeHuman body model from [`builtin_model_dir`].
pub fn load_builtin() -> Result<BodyModel> {
    BodyModel::load(&builtin_model_dir())
}

/// Load `tpose.json` from a model folder (e.g. [`builtin_model_dir`]): the pose that turns
/// the A-pose rest into a T-pose (arms horizontal).
pub fn load_tpose(dir: &Path) -> Result<Pose> {
    let path = dir.join(TPOSE_FILE);
    let pose: Pose = serde_json::from_slice(&read_file(&path)?)
        .map_err(|e| Error::parse(&path, e.line(), e.to_string()))?;
    pose.validate(crate::CMU_MB_JOINTS.len())
        .map_err(|e| e.in_file(&path))?;
    Ok(pose)
}
