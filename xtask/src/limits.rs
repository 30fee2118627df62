//! `cargo xtask limits`: what limits the wrinkle GRU's accuracy on an experiment, by
//! measurement, on the validation split (the test split is not touched):
//!
//! - **data**: the GRU and the ridge baseline retrained on ¼, ½ and all of the training motions
//!   (every shape of a chosen motion comes along; normalisation and PCA recomputed on the
//!   subset), best validation error of each — the learning curve;
//! - **size**: the GRU retrained on all the data with fewer hidden units;
//! - **output basis**: the validation error of the ground truth itself projected onto the
//!   first k PCA components (what a perfect GRU with a k-component output would reach), and of
//!   the training mean (a model that ignores its input);
//! - **ground truth**: each validation clip simulated twice on the nominal body, once from an
//!   earlier start; the cloth of the frames both runs share differs only because the history
//!   before them differs. Past the first second that difference is what the motion alone does
//!   not decide, a floor under any model's error.
//!
//! Every trained variant keeps its folder and report under `runs/<name>/limits/`; a rerun skips
//! the variants that finished (and resumes an interrupted one). Writes `limits.json` and
//! `limits.png`.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, bail};
use rayon::prelude::*;
use sartor_cli::{Env, ExperimentArgs, TrainBar, stop_flag};
use sartor_cloth::simulate_sequence;
use sartor_dataset::{
    MANIFEST_FILE, PcaBasis, PcaSettings, SequenceSample, Split, TrainingData, compute_pca,
    compute_stats, load_dataset,
};
use sartor_eval::{Chart, Machine, Marker, Series, write_charts, write_json};
use sartor_model::{
    ModelKind, ModelReport, TrainOptions, TrainingConfig, train_model, vertex_error_mm,
};
use sartor_motion::{Motion, MotionWindow};
use sartor_pipeline::{Experiment, SimInputs, device};
use serde::{Deserialize, Serialize};

/// Arguments of `limits`.
#[derive(clap::Args, Debug)]
pub struct LimitsArgs {
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// Shares of the training motions for the learning curve (1 is always run).
    #[arg(long, value_delimiter = ',', default_values_t = [0.25, 0.5])]
    pub fractions: Vec<f64>,
    /// GRU hidden sizes tried on all the data, beside the config's.
    #[arg(long, value_delimiter = ',', default_values_t = [128, 256])]
    pub hidden: Vec<usize>,
    /// PCA output sizes whose floor is measured.
    #[arg(long, value_delimiter = ',', default_values_t = [16, 32, 64, 128])]
    pub pca: Vec<usize>,
    /// Frames the earlier start of the ground-truth check runs ahead (30 fps).
    #[arg(long, default_value_t = 30)]
    pub lead_frames: usize,
    /// Skip the retraining (the output-basis and ground-truth parts take minutes).
    #[arg(long)]
    pub no_training: bool,
}

/// One retrained variant.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Variant {
    /// Folder name under `limits/`.
    name: String,
    /// `gru` or `ridge`.
    model: String,
    /// Share of the training motions.
    fraction: f64,
    /// Training motions and sequences and frames used.
    motions: usize,
    sequences: usize,
    frames: usize,
    /// GRU hidden units (0 for ridge).
    hidden: usize,
    parameters: usize,
    best_val_error_mm: f64,
    best_epoch: usize,
    wall_time_s: f64,
    /// Hash of the dataset's manifest and the training settings it ran with: a rerun on other
    /// data or settings does not reuse it.
    fingerprint: String,
}

/// The PCA floor at `k` components.
#[derive(Serialize)]
struct BasisFloor {
    components: usize,
    /// Share of the training variance the components keep.
    explained_variance: f64,
    /// Mean vertex error of the validation ground truth through the basis, mm.
    val_error_mm: f64,
}

/// One validation clip simulated from two starts.
#[derive(Serialize)]
struct HistoryPair {
    /// The validation window, and the window with the earlier start.
    window: String,
    earlier: String,
    /// Frames both share.
    shared_frames: usize,
    /// Mean cloth vertex distance between the two runs over the shared frames, mm.
    mean_mm: f64,
    /// The same, over the shared frames from one second (30 frames) in.
    after_1s_mm: f64,
    /// Of that, the shift of the whole garment: the distance between the two runs' vertex
    /// centroids, mean over the shared frames, mm.
    shift_mm: f64,
    /// What is left once that shift is taken out, mean over the shared frames, mm.
    residual_mm: f64,
    /// Per shared frame, mm.
    per_frame_mm: Vec<f64>,
}

#[derive(Serialize)]
struct Report {
    config: String,
    /// The error the validation split measures: mean garment vertex error of `Δ_L` in the
    /// unposed space, mm (the `best_val_error_mm` of `train.json`).
    measure: &'static str,
    training_motions: usize,
    training_frames: usize,
    validation_frames: usize,
    /// The training mean of `Δ_L` as the prediction.
    mean_prediction_val_error_mm: f64,
    basis: Vec<BasisFloor>,
    variants: Vec<Variant>,
    /// The config's GRU hidden units (the learning curve's).
    gru_hidden: usize,
    /// Cloth of the same frames from two starts, per validation clip.
    history: Vec<HistoryPair>,
    machine: Machine,
}

/// Run `limits`.
pub fn limits(args: &LimitsArgs, env: &Env) -> anyhow::Result<()> {
    let e = args.experiment.load(env)?;
    let config = e.training()?.clone();
    let data_dir = e.dataset_dir();
    let data = load_dataset(&data_dir)
        .with_context(|| format!("loading the dataset {} (run `dataset`)", data_dir.display()))?;
    let manifest_path = data_dir.join(MANIFEST_FILE);
    let manifest: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&manifest_path)
            .with_context(|| format!("reading {}", manifest_path.display()))?,
    )
    .with_context(|| format!("parsing {}", manifest_path.display()))?;
    let out = e.run_dir().join("limits");
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let motions = training_motions(&data);
    if motions.is_empty() {
        bail!(
            "{}: the dataset has no training sequences",
            data_dir.display()
        );
    }
    let frames_of = |split: Split| -> usize {
        data.sequences()
            .iter()
            .filter(|q| q.split == split)
            .map(|q| q.n_frames)
            .sum()
    };
    println!(
        "{} training motions, {} training frames, {} validation frames",
        motions.len(),
        frames_of(Split::Train),
        frames_of(Split::Validation)
    );

    let mean_error = basis_error(&data, None)?;
    println!("training mean as the prediction: {mean_error:.2} mm");
    let pca = data
        .pca()
        .context("the dataset has no PCA basis (dataset.pca)")?;
    let mut basis = Vec::new();
    for &k in &args.pca {
        if k > pca.n_components() {
            println!("PCA {k}: the dataset's basis has {}", pca.n_components());
            continue;
        }
        let err = basis_error(&data, Some((pca, k)))?;
        let explained: f64 = pca.explained_variance_ratio[..k].iter().sum();
        println!(
            "PCA {k}: keeps {:.1} % of the variance, validation floor {err:.2} mm",
            explained * 100.0
        );
        basis.push(BasisFloor {
            components: k,
            explained_variance: explained,
            val_error_mm: err,
        });
    }

    let history = history_pairs(&e, env, args.lead_frames)?;

    let mut variants = Vec::new();
    if !args.no_training {
        let stop = stop_flag();
        let mut fractions: Vec<f64> = args.fractions.clone();
        fractions.push(1.0);
        fractions.sort_by(f64::total_cmp);
        fractions.dedup();
        for &f in &fractions {
            if !(f > 0.0 && f <= 1.0) {
                bail!("--fractions: {f} is not in (0, 1]");
            }
            let subset = subset(&data, &motions, f, &e)?;
            for kind in [ModelKind::Linear, ModelKind::Wrinkle] {
                let v = variant(
                    &out,
                    &subset,
                    &config,
                    kind,
                    f,
                    config.gru_hidden,
                    &stop,
                    &manifest,
                )?;
                variants.push(v);
            }
        }
        for &h in &args.hidden {
            if h == config.gru_hidden {
                continue;
            }
            let mut c = config.clone();
            c.gru_hidden = h;
            let v = variant(
                &out,
                &data,
                &c,
                ModelKind::Wrinkle,
                1.0,
                h,
                &stop,
                &manifest,
            )?;
            variants.push(v);
        }
    }

    let report = Report {
        config: args.experiment.name(&env.data),
        measure: "mean vertex error of the wrinkle displacement, unposed, validation split (mm)",
        training_motions: motions.len(),
        training_frames: frames_of(Split::Train),
        validation_frames: frames_of(Split::Validation),
        mean_prediction_val_error_mm: mean_error,
        basis,
        variants,
        gru_hidden: config.gru_hidden,
        history,
        machine: Machine::current(),
    };
    write_json(&out.join("limits.json"), &report)?;
    write_charts(&out.join("limits"), &charts(&report), 2, (520, 340))?;
    println!("wrote {}", out.join("limits.json").display());
    Ok(())
}

/// The distinct motions of the training sequences, sorted.
fn training_motions(data: &TrainingData) -> Vec<String> {
    let mut m: Vec<String> = data
        .sequences()
        .iter()
        .filter(|q| q.split == Split::Train)
        .map(|q| q.motion.clone())
        .collect();
    m.sort();
    m.dedup();
    m
}

/// Evenly spaced picks of `round(f·n)` (at least one) of `n` items, by index.
fn even_picks(n: usize, f: f64) -> Vec<usize> {
    let k = ((f * n as f64).round() as usize).clamp(1, n);
    (0..k).map(|i| i * n / k).collect()
}

/// `data` with only the training sequences of an evenly spaced share `f` of `motions`;
/// normalisation and PCA are recomputed on those, as the dataset stage would.
fn subset(
    data: &TrainingData,
    motions: &[String],
    f: f64,
    e: &Experiment,
) -> anyhow::Result<TrainingData> {
    if f >= 1.0 {
        return Ok(data.clone());
    }
    let keep: Vec<&String> = even_picks(motions.len(), f)
        .into_iter()
        .map(|i| &motions[i])
        .collect();
    let sequences: Vec<SequenceSample> = data
        .sequences()
        .iter()
        .filter(|q| q.split != Split::Train || keep.contains(&&q.motion))
        .cloned()
        .collect();
    let train_shapes: Vec<_> = data
        .shapes()
        .iter()
        .filter(|s| s.split == Split::Train)
        .collect();
    let train_seqs: Vec<&SequenceSample> = sequences
        .iter()
        .filter(|q| q.split == Split::Train)
        .collect();
    let stats = compute_stats(
        &train_shapes,
        &train_seqs,
        data.n_betas(),
        data.n_inputs(),
        data.n_outputs(),
    )?;
    let settings = e.dataset.pca.unwrap_or(PcaSettings {
        components: data.pca().map_or(0, PcaBasis::n_components),
        max_frames: 6000,
        seed: 2019,
    });
    let pca = compute_pca(&train_seqs, &stats, &settings)?;
    Ok(TrainingData::new(
        data.source().clone(),
        data.n_vertices(),
        data.layout().clone(),
        data.shapes().to_vec(),
        sequences,
        stats,
        Some(pca),
    )?)
}

/// Train (or reuse) one variant in `out/<name>`.
#[allow(clippy::too_many_arguments)]
fn variant(
    out: &Path,
    data: &TrainingData,
    config: &TrainingConfig,
    kind: ModelKind,
    fraction: f64,
    hidden: usize,
    stop: &AtomicBool,
    dataset_manifest: &serde_json::Value,
) -> anyhow::Result<Variant> {
    let (model, hidden) = match kind {
        ModelKind::Linear => ("ridge", 0),
        _ => ("gru", hidden),
    };
    let name = format!(
        "{model}-h{hidden}-f{:03}",
        (fraction * 100.0).round() as usize
    );
    let dir = out.join(&name);
    let done = dir.join("variant.json");
    let fingerprint = Experiment::section_sha256(&(dataset_manifest, config))?;
    if let Ok(bytes) = std::fs::read(&done)
        && let Ok(v) = serde_json::from_slice::<Variant>(&bytes)
    {
        if v.fingerprint != fingerprint {
            bail!(
                "{}: made from another dataset or other training settings; remove {} to \
                 measure again",
                done.display(),
                out.display()
            );
        }
        println!("{name}: done before, {:.2} mm", v.best_val_error_mm);
        return Ok(v);
    }
    println!("{name}: training");
    let options = TrainOptions {
        dir: dir.clone(),
        device: device("flex")?,
        resume: dir.exists(),
        stop,
        contact: None,
    };
    let mut bar = TrainBar::new();
    let r: ModelReport = train_model(kind, data, config, &options, &mut bar)
        .with_context(|| format!("training {name}"))?;
    bar.finish();
    if r.interrupted {
        bail!("{name} was interrupted; rerun to resume it");
    }
    let train: Vec<&SequenceSample> = data
        .sequences()
        .iter()
        .filter(|q| q.split == Split::Train)
        .collect();
    let mut motions: Vec<&String> = train.iter().map(|q| &q.motion).collect();
    motions.sort();
    motions.dedup();
    let v = Variant {
        name: name.clone(),
        model: model.into(),
        fraction,
        motions: motions.len(),
        sequences: train.len(),
        frames: train.iter().map(|q| q.n_frames).sum(),
        hidden,
        parameters: r.parameters,
        best_val_error_mm: r
            .best_val_error_mm
            .context("the run has no validation error (no validation split?)")?,
        best_epoch: r.best_epoch.unwrap_or(0),
        wall_time_s: r.wall_time_s,
        fingerprint,
    };
    println!(
        "{name}: {:.2} mm (epoch {}), {:.0} s",
        v.best_val_error_mm, v.best_epoch, v.wall_time_s
    );
    write_json(&done, &v)?;
    Ok(v)
}

/// Mean vertex error (mm) over the validation frames of the ground truth `Δ_L` reconstructed
/// from its projection on the first `k` components of `pca`; `None`: of the training mean.
fn basis_error(data: &TrainingData, pca: Option<(&PcaBasis, usize)>) -> anyhow::Result<f64> {
    let norm = &data.stats().wrinkle_out;
    let n3 = data.n_outputs();
    let (mut sum, mut count) = (0.0f64, 0usize);
    let mut target = Vec::new();
    let mut recon = Vec::new();
    let mut coef = Vec::new();
    for q in data
        .sequences()
        .iter()
        .filter(|q| q.split == Split::Validation)
    {
        target.clear();
        target.extend_from_slice(&q.wrinkle_delta);
        recon.clear();
        recon.resize(target.len(), 0f32);
        for (row, out) in target.chunks_exact_mut(n3).zip(recon.chunks_exact_mut(n3)) {
            norm.normalize(row);
            // Through the basis: mean + B_k B_kᵀ (row − mean); `None`: zero (the mean of the
            // normalised training displacements).
            if let Some((p, k)) = pca {
                let kk = p.n_components();
                coef.clear();
                coef.resize(k, 0f64);
                for (i, (x, m)) in row.iter().zip(&p.mean).enumerate() {
                    let c = f64::from(x - m);
                    for (a, &w) in coef.iter_mut().zip(&p.basis[i * kk..i * kk + k]) {
                        *a += c * f64::from(w);
                    }
                }
                for (i, (r, m)) in out.iter_mut().zip(&p.mean).enumerate() {
                    let b = &p.basis[i * kk..i * kk + k];
                    let s: f64 = coef.iter().zip(b).map(|(a, &w)| a * f64::from(w)).sum();
                    *r = m + s as f32;
                }
            }
        }
        // The measure training reports (`best_val_error_mm`).
        let (s, c) = vertex_error_mm(&recon, &target, &norm.std, None);
        sum += s;
        count += c;
    }
    if count == 0 {
        bail!("the dataset has no validation frames");
    }
    Ok(sum / count as f64)
}

/// Simulate every validation window on the nominal body from its own start and from
/// `lead` frames earlier, and compare the cloth of the shared frames.
fn history_pairs(e: &Experiment, env: &Env, lead: usize) -> anyhow::Result<Vec<HistoryPair>> {
    let inputs = SimInputs::load(e, &env.data)?;
    let nominal = e
        .shapes
        .train
        .first()
        .context("the experiment has no training shape")?;
    let mut betas = nominal.betas.clone();
    betas.resize(inputs.body.n_betas(), 0.0);
    // (later, earlier): a window that starts after the clip's first frame gets a start up to
    // `lead` frames earlier; one starting at the first frame is compared with the same clip
    // started `lead` frames later.
    let mut pairs = Vec::new();
    for spec in &e.motions.validation {
        let whole = inputs.motion(e, spec)?;
        let (base, start, frames) = match MotionWindow::parse(spec)? {
            Some(w) => (w.motion, w.start, w.frames),
            None => (spec.clone(), 0, whole.n_frames()),
        };
        let end = start + frames;
        // An earlier start where the window leaves room, else a later one.
        let (a, b) = if start > 0 {
            (start.saturating_sub(lead), start)
        } else {
            (start, start + lead)
        };
        if end < b + 40 {
            println!("{spec}: fewer than 40 frames shared by two starts, skipped");
            continue;
        }
        pairs.push((
            MotionWindow {
                motion: base.clone(),
                start: b,
                frames: end - b,
            },
            MotionWindow {
                motion: base,
                start: a,
                frames: end - a,
            },
        ));
    }
    println!(
        "ground truth: {} validation clips simulated from two starts ({lead} frames apart)",
        pairs.len()
    );
    let run = |w: &MotionWindow| -> anyhow::Result<Vec<Vec<[f32; 3]>>> {
        let name = w.to_string();
        let motion: Motion = inputs.motion(e, &name)?;
        let seq = simulate_sequence(
            &inputs.body,
            &inputs.garment,
            &inputs.material,
            &betas,
            Some(&motion),
            &inputs.drive,
            &mut |_, _| {},
        )
        .with_context(|| format!("simulating {name}"))?;
        Ok(seq
            .frames
            .into_iter()
            .filter(|f| f.motion_frame.is_some())
            .map(|f| f.positions)
            .collect())
    };
    pairs
        .par_iter()
        .map(|(later, earlier)| -> anyhow::Result<HistoryPair> {
            let (l, r) = rayon::join(|| run(later), || run(earlier));
            let (l, r) = (l?, r?);
            let offset = later.start - earlier.start;
            let shared = l.len().min(r.len().saturating_sub(offset));
            // Per shared frame: (mean distance, centroid distance, mean distance less the shift).
            let per_frame: Vec<[f64; 3]> = (0..shared)
                .map(|j| frame_difference(&l[j], &r[j + offset]))
                .collect();
            let mean = |s: &[[f64; 3]], k: usize| {
                s.iter().map(|d| d[k]).sum::<f64>() / s.len().max(1) as f64
            };
            let pair = HistoryPair {
                window: later.to_string(),
                earlier: earlier.to_string(),
                shared_frames: shared,
                mean_mm: mean(&per_frame, 0),
                after_1s_mm: mean(per_frame.get(30..).unwrap_or(&[]), 0),
                shift_mm: mean(&per_frame, 1),
                residual_mm: mean(&per_frame, 2),
                per_frame_mm: per_frame.iter().map(|d| d[0]).collect(),
            };
            println!(
                "{} vs {}: {:.2} mm over {} shared frames ({:.2} mm after the first second); \
                 shift of the whole garment {:.2} mm, {:.2} mm without it",
                pair.window,
                pair.earlier,
                pair.mean_mm,
                pair.shared_frames,
                pair.after_1s_mm,
                pair.shift_mm,
                pair.residual_mm
            );
            Ok(pair)
        })
        .collect()
}

/// Between two cloth frames, mm: the mean vertex distance, the distance between the centroids,
/// and the mean vertex distance once the centroids are made to agree.
fn frame_difference(p: &[[f32; 3]], q: &[[f32; 3]]) -> [f64; 3] {
    let n = p.len().max(1) as f64;
    let mut shift = [0f64; 3];
    for (x, y) in p.iter().zip(q) {
        for c in 0..3 {
            shift[c] += f64::from(x[c] - y[c]) / n;
        }
    }
    let (mut all, mut rest) = (0f64, 0f64);
    for (x, y) in p.iter().zip(q) {
        let d: [f64; 3] = std::array::from_fn(|c| f64::from(x[c] - y[c]));
        all += d.iter().map(|v| v * v).sum::<f64>().sqrt();
        rest += (0..3)
            .map(|c| (d[c] - shift[c]).powi(2))
            .sum::<f64>()
            .sqrt();
    }
    let norm = shift.iter().map(|v| v * v).sum::<f64>().sqrt();
    [all / n * 1e3, norm * 1e3, rest / n * 1e3]
}

fn charts(r: &Report) -> Vec<Chart> {
    let line = |name: &str, points: Vec<(f64, f64)>| Series {
        name: name.into(),
        points,
        marker: Some(Marker::Circle),
        color: None,
    };
    let curve = |model: &str, hidden: Option<usize>| -> Vec<(f64, f64)> {
        let mut p: Vec<(f64, f64)> = r
            .variants
            .iter()
            .filter(|v| v.model == model && hidden.is_none_or(|h| v.hidden == h))
            .map(|v| (v.frames as f64, v.best_val_error_mm))
            .collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        p
    };
    let hidden = r.gru_hidden;
    let mut sizes: Vec<(f64, f64)> = r
        .variants
        .iter()
        .filter(|v| v.model == "gru" && v.fraction >= 1.0)
        .map(|v| (v.hidden as f64, v.best_val_error_mm))
        .collect();
    sizes.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut charts = vec![
        Chart {
            title: "learning curve (validation)".into(),
            x_label: "training frames".into(),
            y_label: "mean vertex error (mm)".into(),
            series: vec![
                line(&format!("GRU {hidden}"), curve("gru", Some(hidden))),
                line("ridge", curve("ridge", None)),
            ],
            log_x: false,
            legend_at_bottom: true,
            ranges: None,
        },
        Chart {
            title: "GRU size, all training data (validation)".into(),
            x_label: "hidden units".into(),
            y_label: "mean vertex error (mm)".into(),
            series: vec![line("GRU", sizes)],
            log_x: false,
            legend_at_bottom: true,
            ranges: None,
        },
        Chart {
            title: "output basis floor (validation)".into(),
            x_label: "PCA components".into(),
            y_label: "mean vertex error (mm)".into(),
            series: vec![line(
                "ground truth through the basis",
                r.basis
                    .iter()
                    .map(|b| (b.components as f64, b.val_error_mm))
                    .collect(),
            )],
            log_x: false,
            legend_at_bottom: true,
            ranges: None,
        },
    ];
    if !r.history.is_empty() {
        charts.push(Chart {
            title: "same frames, two simulation starts".into(),
            x_label: "frames since the later start".into(),
            y_label: "cloth difference (mm)".into(),
            series: r
                .history
                .iter()
                .map(|h| Series {
                    name: h.window.clone(),
                    points: h
                        .per_frame_mm
                        .iter()
                        .enumerate()
                        .map(|(i, &d)| (i as f64, d))
                        .collect(),
                    marker: None,
                    color: None,
                })
                .collect(),
            log_x: false,
            legend_at_bottom: true,
            ranges: None,
        });
    }
    charts
}

#[cfg(test)]
mod tests {
    use super::even_picks;

    #[test]
    fn even_picks_spread_over_the_list_and_keep_at_least_one() {
        assert_eq!(even_picks(8, 0.25), vec![0, 4]);
        assert_eq!(even_picks(8, 0.5), vec![0, 2, 4, 6]);
        assert_eq!(even_picks(8, 1.0), (0..8).collect::<Vec<_>>());
        assert_eq!(even_picks(3, 0.01), vec![0]);
        assert_eq!(even_picks(51, 0.25).len(), 13);
    }

    #[test]
    fn a_shifted_garment_differs_by_its_shift_alone() {
        let p = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let q = p.map(|v| [v[0] + 0.003, v[1], v[2] - 0.004]);
        let [all, shift, rest] = super::frame_difference(&p, &q);
        assert!((all - 5.0).abs() < 1e-3, "{all}");
        assert!((shift - 5.0).abs() < 1e-3, "{shift}");
        assert!(rest < 1e-3, "{rest}");
    }
}
