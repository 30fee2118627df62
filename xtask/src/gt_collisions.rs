//! `cargo xtask gt-collisions`: how far ground-truth cloth vertices lie from the posed body by
//! the one collision measure ([`sartor_core::BodyDistance`], through
//! [`sartor_eval::PosedBody`]): percentiles, the share below 0 mm and below −1 mm (the
//! simulator's promise: none below −1 mm), per sequence and in total, printed and written as
//! JSON; where the vertex-frames below −1 mm lie (the closest body part, and how many are
//! caught between two overlapping parts).
//!
//! Sources: simulated sequence files (`--sim DIR`, e.g. `runs/<name>/sim`, motion frames only
//! unless `--all-frames`), or a shipped model's stored slice of held-out ground truth
//! (`--model DIR`, default `datasets/models/default`).

use std::path::PathBuf;
use std::sync::Arc;

use sartor_cli::{Env, in_data};
use sartor_core::BodyModel;
use sartor_eval::{
    DistanceHistogram, DistanceSummary, SLICE_FILE, ground_truth_signed_distance, read_slice,
    sequence_files_signed_distance, write_json,
};

/// Arguments of `gt-collisions`.
#[derive(clap::Args, Debug)]
pub struct GtCollisionsArgs {
    /// A folder of simulated sequences (`*.mcap`), e.g. `runs/<name>/sim`.
    #[arg(long)]
    pub sim: Option<PathBuf>,
    /// A shipped model whose stored ground-truth slice is measured (when `--sim` is not given).
    #[arg(long, default_value = "datasets/models/default")]
    pub model: PathBuf,
    /// At most this many sequences of `--sim`, in file-name order (0: all).
    #[arg(long, default_value_t = 0)]
    pub max_sequences: usize,
    /// Count blend and rest frames of `--sim` too.
    #[arg(long)]
    pub all_frames: bool,
    /// Output JSON.
    #[arg(long, default_value = "gt-collisions.json")]
    pub out: PathBuf,
}

/// Run `gt-collisions`.
pub fn gt_collisions(args: &GtCollisionsArgs, env: &Env) -> anyhow::Result<()> {
    let body = Arc::new(BodyModel::load(&env.data.body_dir())?);
    let (source, parts): (String, Vec<(String, DistanceHistogram)>) = match &args.sim {
        Some(dir) => {
            let dir = in_data(&env.data, dir);
            let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
                .map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
                .collect();
            files.sort();
            if args.max_sequences > 0 {
                files.truncate(args.max_sequences);
            }
            anyhow::ensure!(!files.is_empty(), "{}: no *.mcap sequences", dir.display());
            let parts = sequence_files_signed_distance(&body, &files, args.all_frames)?;
            (dir.display().to_string(), parts)
        }
        None => {
            let path = in_data(&env.data, &args.model).join(SLICE_FILE);
            let seq = read_slice(&path)?;
            let name = format!("{}__{}", seq.shape, seq.motion);
            let h = ground_truth_signed_distance(&body, &[&seq])?;
            (path.display().to_string(), vec![(name, h)])
        }
    };
    let mut total = DistanceHistogram::default();
    parts.iter().for_each(|(_, h)| total.merge(h));
    let sequences: Vec<(String, DistanceSummary)> = parts
        .iter()
        .map(|(n, h)| (n.clone(), h.summary()))
        .collect();
    let summary = total.summary();
    for (name, s) in sequences
        .iter()
        .chain(std::iter::once(&("total".to_string(), summary.clone())))
    {
        println!(
            "{name}: {} vertex-frames, below 0 mm {:.3} %, below -1 mm {:.4} %, min {:.2} mm, \
             percentiles (mm) {:?}",
            s.vertex_frames,
            s.below_0_mm_percent,
            s.below_minus_1_mm_percent,
            s.min_mm.unwrap_or(f64::NAN),
            s.percentiles_mm
        );
    }
    println!(
        "below -1 mm by the closest body part: {:?}; of them between two overlapping parts: {}",
        summary.below_minus_1_mm_by_body_part, summary.below_minus_1_mm_between_parts
    );
    let report = serde_json::json!({
        "source": source,
        "total": summary,
        "sequences": sequences,
    });
    write_json(&args.out, &report)?;
    println!("wrote {}", args.out.display());
    Ok(())
}
