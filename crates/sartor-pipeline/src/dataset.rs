//! The `dataset` stage ([`dataset`], `sartor dataset --config C`): build the training data of an experiment from its
//! simulated sequences (`runs/<name>/sim`) into `runs/<name>/dataset` (see
//! `sartor_dataset::build_dataset`): binding, Δ_G, Δ_L, inputs, splits, statistics, PCA,
//! manifest and `dataset.json`. Resumable; sequences that failed to simulate are left out and
//! listed in the report.

use std::time::Instant;

use sartor_cloth::Garment;
use sartor_core::BodyModel;
use sartor_dataset::{
    DataSource, DatasetInputs, DatasetReport, SimFolder, build_dataset, failed_stems,
    simulated_plan,
};
use sartor_eval::{Machine, Progress, write_json};
use serde::Serialize;

use crate::Result;
use crate::error::Context;
use crate::experiment::Experiment;

#[derive(Serialize)]
struct DatasetRun<'a> {
    config: String,
    config_sha256: &'a str,
    left_out_failed_simulations: Vec<String>,
    wall_time_s: f64,
    machine: Machine,
}

/// Build the dataset of `e` from its simulations (see the module docs). `config` names the
/// config file in the report. Returns the dataset's report and the sequences left out.
pub fn dataset(
    e: &Experiment,
    config: &str,
    progress: &dyn Progress,
) -> Result<(DatasetReport, Vec<String>)> {
    let start = Instant::now();
    let body = BodyModel::load(&e.body)
        .with_context(|| format!("loading the body model from {}", e.body.display()))?;
    let garment = Garment::load(&e.garment)
        .with_context(|| format!("loading the garment from {}", e.garment.display()))?;
    let garment_sha256 = garment.content_sha256()?;
    let failed = failed_stems(&e.sim_dir())?;
    let (plan, left_out) = simulated_plan(&e.plan(), &failed);
    for stem in &left_out {
        progress.println(&format!(
            "dataset: leaving out {stem} (its simulation failed)"
        ));
    }
    let source = DataSource {
        garment: garment.asset_id()?,
        body: body.asset_id()?,
    };
    let config_sha256 = Experiment::section_sha256(&serde_json::json!({
        "dataset": &e.dataset,
        "plan": &plan,
        "simulation": &e.simulation,
        "max_frames": e.motions.max_frames,
        "source": &source,
    }))?;
    let inputs = DatasetInputs {
        body: &body,
        relaxed: garment.positions(),
        faces: garment.faces(),
        source,
        config_sha256: config_sha256.clone(),
    };
    let files = SimFolder::new(&e.sim_dir(), garment_sha256, body.n_betas());
    let out = e.dataset_dir();
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    write_json(&out.join("config.json"), e)?;
    progress.start("dataset", plan.sequences.len() as u64, "sequences");
    let last = std::sync::atomic::AtomicUsize::new(0);
    let report = build_dataset(&inputs, &plan, &e.dataset, &files, &out, &|done, _| {
        let before = last.swap(done, std::sync::atomic::Ordering::Relaxed);
        progress.inc(done.saturating_sub(before) as u64);
    })
    .with_context(|| format!("building the dataset in {}", out.display()))?;
    progress.finish();
    write_json(
        &out.join("dataset-run.json"),
        &DatasetRun {
            config: config.to_string(),
            config_sha256: &config_sha256,
            left_out_failed_simulations: left_out.clone(),
            wall_time_s: start.elapsed().as_secs_f64(),
            machine: Machine::current(),
        },
    )?;
    Ok((report, left_out))
}
