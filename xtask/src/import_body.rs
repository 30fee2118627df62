//! `cargo xtask import-body`: convert the raw MakeHuman assets into the built-in body model
//! (`datasets/body/makehuman/`, see [`sartor_import::import_makehuman`]).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;

/// Arguments of `import-body`.
#[derive(clap::Args, Debug)]
pub struct ImportBodyArgs {
    /// The raw MakeHuman assets folder (`3dobjs/`, `targets/`, `rigs/`, ...).
    #[arg(long, default_value = "../shared/makehuman")]
    pub from: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "datasets/body/makehuman")]
    pub out: PathBuf,
    /// Phenotypes sampled for the PCA (default: the committed model's, 2000).
    #[arg(long)]
    pub samples: Option<usize>,
    /// Held-out phenotypes for the reconstruction error (default 200).
    #[arg(long)]
    pub held_out: Option<usize>,
    /// Seed of the phenotype sample (default 2019).
    #[arg(long)]
    pub seed: Option<u64>,
}

/// Run the import and print its key figures.
pub fn import_body(args: &ImportBodyArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let mut options = sartor_import::ImportOptions::new(args.from.clone(), args.out.clone());
    if let Some(n) = args.samples {
        options.n_samples = n;
    }
    if let Some(n) = args.held_out {
        options.n_held_out = n;
    }
    if let Some(s) = args.seed {
        options.seed = s;
    }
    let report = sartor_import::import_makehuman(&options)
        .with_context(|| format!("importing the MakeHuman body from {}", args.from.display()))?;
    let pca = &report.pca;
    println!(
        "wrote {}: {} vertices, {} faces, {} joints, {} betas",
        args.out.display(),
        report.mesh.n_vertices,
        report.mesh.n_faces,
        sartor_motion::CMU_MB_JOINTS.len(),
        pca.explained_variance_ratio.len()
    );
    println!(
        "explained variance: {:?} (cumulative {:.4})",
        pca.explained_variance_ratio,
        pca.cumulative_explained_variance_ratio
            .last()
            .copied()
            .unwrap_or(0.0)
    );
    let h = &report.held_out;
    println!(
        "held-out reconstruction ({} phenotypes): mean {:.3} mm, max {:.3} mm per vertex; \
         joints mean {:.3} mm, max {:.3} mm",
        h.n,
        h.mean_vertex_error_mm,
        h.max_vertex_error_mm,
        h.mean_joint_error_mm,
        h.max_joint_error_mm
    );
    println!(
        "mean adult height {:.3} m; skin weights: top {}; T-pose upper arms {:.1}° / {:.1}° \
         above horizontal",
        report.mean_adult_height_m,
        report.skin_weights.k,
        report.tpose.left_upper_arm_tpose_deg,
        report.tpose.right_upper_arm_tpose_deg
    );
    println!(
        "report: {} ({:.1} s)",
        args.out.join(sartor_import::IMPORT_REPORT_FILE).display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
