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
//! let model = sartor_core::BodyModel::load("datasets/body/makehuman".as_ref())?;
//! let height = model.height_m(&[])?; // the mean adult
//! # let _ = height;
//! # Ok::<(), sartor_core::Error>(())
//! ```

mod assets;
pub(crate) mod blender;
mod import;
mod pca;

pub(crate) use blender::vec_roll_to_mat3;
pub use blender::{BONE_FRAMES_FILE, BoneFrames, blender_euler_xyz};
pub use import::{
    HeldOutReport, ImportOptions, ImportReport, JointReport, MeshReport, PcaReport, SAMPLE_RANGES,
    ShapeSpaceReport, SkinWeightReport, TPoseReport, TopKReport, import_makehuman,
};

/// File name of the import report inside the built-in model's folder.
pub const IMPORT_REPORT_FILE: &str = "import-report.json";

/// Every file an import writes into its folder; the report, last, records the others' hashes.
pub const IMPORT_FILES: [&str; 7] = [
    sartor_core::MODEL_TENSORS,
    sartor_core::MODEL_HEADER,
    sartor_core::PHENOTYPE_TENSORS,
    sartor_core::PHENOTYPE_HEADER,
    BONE_FRAMES_FILE,
    sartor_motion::TPOSE_FILE,
    IMPORT_REPORT_FILE,
];
