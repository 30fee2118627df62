//! The trade-off sweep of one or more experiments ([`run_tradeoff`], `sartor tradeoff`): every
//! exported model of the experiments (each its own export, plus extra model folders of the
//! first) swept by `sartor_eval::sweep_model` on its experiment's held-out motions →
//! `runs/<name>/tradeoff/tradeoff.json` and `pareto.{png,svg}`.

use std::path::PathBuf;
use std::time::Instant;

use sartor_dataset::SimFolder;
use sartor_eval::{
    Assets, Machine, Progress, TestSets, TradeoffOptions, TradeoffReport, load_truth, mark_pareto,
    plot_tradeoff, sweep_model, test_sets, time_points, write_json,
};

use crate::Result;
use crate::error::{Context, ensure};
use crate::experiment::Experiment;

/// What [`run_tradeoff`] sweeps.
#[derive(Clone, Debug)]
pub struct TradeoffRun {
    /// The experiments (the first names the output folder; the others add garment
    /// resolutions), each with its own export and held-out motions.
    pub experiments: Vec<Experiment>,
    /// Further exported models of the first experiment's garment (e.g. other hidden sizes).
    pub extra_models: Vec<PathBuf>,
    /// Evaluate on every training shape (default: the nominal shape only, as the paper did).
    pub all_shapes: bool,
    /// Ranks and timing.
    pub options: TradeoffOptions,
}

/// Run the sweep; returns the report and where it was written.
pub fn run_tradeoff(
    run: &TradeoffRun,
    progress: &dyn Progress,
) -> Result<(TradeoffReport, PathBuf)> {
    let start = Instant::now();
    let first = run.experiments.first().context("no experiment to sweep")?;
    let mut swept = Vec::new();
    let (mut n_sequences, mut n_frames) = (0, 0);
    for (i, e) in run.experiments.iter().enumerate() {
        let mut models = vec![e.export_dir()];
        if i == 0 {
            models.extend(run.extra_models.iter().cloned());
        }
        let plan = e.plan();
        let TestSets { motions, .. } = test_sets(&plan, &e.sim_dir(), !run.all_shapes)?;
        ensure!(
            !motions.is_empty(),
            "{}: no held-out motion was simulated",
            e.name
        );
        for model_dir in &models {
            let assets = Assets::load(&e.body, model_dir)?;
            let files = SimFolder::new(
                &e.sim_dir(),
                assets.binding.garment().sha256.clone(),
                assets.body.n_betas(),
            );
            let seqs = load_truth(&plan, &files, &motions)?;
            n_sequences += seqs.len();
            n_frames += seqs.iter().map(|s| s.truth.poses.len()).sum::<usize>();
            swept.extend(sweep_model(&assets, &seqs, &run.options, progress)?);
        }
    }
    // Timed after every model is swept: the rounds interleave every point of every model.
    let mut points = time_points(swept, &run.options, progress)?;
    mark_pareto(&mut points);

    let dir = first.run_dir().join("tradeoff");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    plot_tradeoff(&dir, &points)?;
    let report = TradeoffReport {
        configs: run.experiments.iter().map(|e| e.name.clone()).collect(),
        test_set: if run.all_shapes {
            "held-out motions, all training shapes".into()
        } else {
            "held-out motions, nominal shape".into()
        },
        sequences: n_sequences,
        frames: n_frames,
        points,
        timed_frames: run.options.timed_frames,
        rounds: run.options.rounds,
        wall_time_s: start.elapsed().as_secs_f64(),
        machine: Machine::current(),
    };
    let path = dir.join("tradeoff.json");
    write_json(&path, &report)?;
    Ok((report, path))
}
