//! `tradeoff`: what each speed knob of the runtime costs in accuracy.
//!
//! For every exported model of the experiment (its own, plus any `--model` folders, e.g. trained
//! with other hidden sizes, and the models of further `--config`s with other garment
//! resolutions) the sweep crosses:
//!
//! - the output rank `k` (the runtime's `NetworkOptions::output_rank`: the first `k` PCA
//!   components, or a rank-`k` truncated SVD of a dense output layer) — `--ranks`;
//! - the weight precision: f32, f16, int8;
//! - the collision post-process on and off;
//! - the fit-only static try-on mode (no wrinkle GRU), per precision.
//!
//! Each point's error is the mean vertex error (mm) of `ours` on the experiment's held-out
//! motions (on the nominal shape unless `--all-shapes`), exactly as `eval` computes it, with the
//! share of cloth vertex-frames inside the body before and after the post-process (eval's
//! measure, the body's winding number: [`sartor_core::BodyDistance`]). Its cost is the wall time
//! of `GarmentAnimator::frame` on one thread over one held-out clip ([`time_points`]: every
//! point timed once per round, after a warm-up; the median over a round's frames, then the
//! median over the rounds), and the bytes of its weights. A point is in the Pareto set when no other
//! point is at least as good in error, collisions and time and better in one. Writes
//! `runs/<name>/tradeoff/tradeoff.json` and `pareto.{png,svg}` (one chart per garment resolution
//! on shared axes, log time axis, one marker shape per precision, the Pareto set ringed).

use std::path::Path;
use std::sync::Arc;

use sartor_core::Pose;

use sartor_runtime::{
    AnimatorOptions, FitMode, GarmentAnimator, GarmentRig, NetworkOptions, OutputKind, Precision,
    WrinkleMode,
};
use serde::Serialize;

use crate::eval::{Assets, Method, TestSequence, evaluate_with};
use crate::plot::{Chart, Marker, Series, write_charts};
use crate::progress::NoProgress;
use crate::report::Machine;
use crate::timing::{median, time_frames};
use crate::{Progress, Result};

/// What the sweep crosses besides precision, post-process and fit-only.
#[derive(Clone, Debug)]
pub struct TradeoffOptions {
    /// Output ranks swept (those below the model's own output width).
    pub ranks: Vec<usize>,
    /// Frames timed per point and round (the first test sequence, looped).
    pub timed_frames: usize,
    /// Timing rounds ([`time_points`]).
    pub rounds: usize,
}

/// One point of the sweep.
#[derive(Clone, Debug, Serialize)]
pub struct TradeoffPoint {
    /// A short label.
    pub label: String,
    /// The model folder.
    pub model: String,
    /// Garment triangles.
    pub garment_triangles: usize,
    /// GRU hidden size (0 in fit-only mode).
    pub gru_hidden: usize,
    /// Output width used: `k` PCA components / SVD rank, or `3V` for a dense output (0 in
    /// fit-only mode).
    pub output_rank: usize,
    /// `f32`, `f16` or `int8`.
    pub precision: String,
    /// Collision post-process on.
    pub post_process: bool,
    /// Fit-only static try-on (no wrinkle GRU).
    pub fit_only: bool,
    /// Mean vertex error on the test set, mm.
    pub mean_vertex_error_mm: f64,
    /// Share of this point's cloth vertex-frames inside the body, %: `collision_percent_after_pp`
    /// with the post-process, `collision_percent_before_pp` without.
    pub collision_percent: f64,
    /// The same network's share before the post-process, %.
    pub collision_percent_before_pp: f64,
    /// The same network's share after the post-process, %.
    pub collision_percent_after_pp: f64,
    /// ms per frame, one thread: the median over the rounds of each round's median.
    pub ms_per_frame: f64,
    /// Each round's median ms per frame.
    pub ms_per_frame_rounds: Vec<f64>,
    /// The weights this point runs (fit MLP, and GRU and output unless fit-only), MB (10⁶ bytes).
    pub model_mb: f64,
    /// No other point is at least as good in error, collisions and time and better in one.
    pub pareto: bool,
}

/// `tradeoff.json`.
#[derive(Clone, Debug, Serialize)]
pub struct TradeoffReport {
    /// The experiments whose models were swept.
    pub configs: Vec<String>,
    /// What the error is measured on.
    pub test_set: String,
    /// Test sequences, over all models.
    pub sequences: usize,
    /// Test frames, over all models.
    pub frames: usize,
    /// Every point of the sweep.
    pub points: Vec<TradeoffPoint>,
    /// Frames timed per point and round.
    pub timed_frames: usize,
    /// Timing rounds ([`time_points`]).
    pub rounds: usize,
    /// Wall time, seconds.
    pub wall_time_s: f64,
    /// Where it ran.
    pub machine: Machine,
}

fn precision_name(p: Precision) -> &'static str {
    match p {
        Precision::F32 => "f32",
        Precision::F16 => "f16",
        Precision::Int8 => "int8",
    }
}

/// The clip a point is timed on: the first test sequence's shape and poses.
#[derive(Debug)]
struct TimedClip {
    betas: Vec<f64>,
    previous_pose: Pose,
    poses: Vec<Pose>,
}

/// A point of the sweep before its timing ([`sweep_model`]) and what runs it.
pub struct SweptPoint {
    /// The point, its `ms_per_frame` not yet measured (NaN).
    pub point: TradeoffPoint,
    rig: Arc<GarmentRig>,
    clip: Arc<TimedClip>,
}

/// Median ms of `GarmentAnimator::frame` over `frames` frames of `clip`'s poses (looped), after
/// a warm-up of up to 10 frames.
fn time_clip(rig: &Arc<GarmentRig>, clip: &TimedClip, frames: usize) -> Result<f64> {
    let n_betas = rig.network().n_betas();
    let betas: Vec<f32> = clip.betas.iter().take(n_betas).map(|&b| b as f32).collect();
    let mut a = GarmentAnimator::new(rig.clone())?;
    a.set_shape(&betas)?;
    a.reset_from(&clip.previous_pose)?;
    let warmup = clip.poses.len().min(10);
    Ok(median(
        &time_frames(&mut a, &clip.poses, warmup, frames.max(1))?.wall_ms,
    ))
}

/// Time every swept point in `options.rounds` rounds: in each round every point in turn, seconds
/// apart at most, so that a machine whose speed drifts over seconds (the VMs of the README's
/// tables do) moves every point of a round alike rather than some points and not others. A
/// point's `ms_per_frame` is the median over the rounds of its round's median.
pub fn time_points(
    swept: Vec<SweptPoint>,
    options: &TradeoffOptions,
    progress: &dyn Progress,
) -> Result<Vec<TradeoffPoint>> {
    let rounds = options.rounds.max(1);
    progress.start("timing", (rounds * swept.len()) as u64, "points");
    let mut times = vec![Vec::with_capacity(rounds); swept.len()];
    for round in 0..rounds {
        progress.message(&format!("round {} of {rounds}", round + 1));
        for (s, t) in swept.iter().zip(&mut times) {
            t.push(time_clip(&s.rig, &s.clip, options.timed_frames)?);
            progress.inc(1);
        }
    }
    progress.finish();
    Ok(swept
        .into_iter()
        .zip(times)
        .map(|(s, t)| TradeoffPoint {
            ms_per_frame: median(&t),
            ms_per_frame_rounds: t,
            ..s.point
        })
        .collect())
}

/// Mark the points no other point dominates over (time, error, collisions): at least as good
/// in all three and strictly better in one.
pub fn mark_pareto(points: &mut [TradeoffPoint]) {
    let key: Vec<[f64; 3]> = points
        .iter()
        .map(|p| [p.ms_per_frame, p.mean_vertex_error_mm, p.collision_percent])
        .collect();
    for (i, p) in points.iter_mut().enumerate() {
        let a = key[i];
        p.pareto = !key
            .iter()
            .enumerate()
            .any(|(j, b)| j != i && (0..3).all(|k| b[k] <= a[k]) && (0..3).any(|k| b[k] < a[k]));
    }
}

/// Sweep one exported model (its assets and its test sequences): every output rank of
/// `options` below the model's own, f32 / f16 / int8, post-process on and off, and fit-only;
/// each point's error and collisions, and what [`time_points`] times it with (on the first
/// test sequence).
pub fn sweep_model(
    assets: &Assets,
    seqs: &[TestSequence],
    args: &TradeoffOptions,
    progress: &dyn Progress,
) -> Result<Vec<SweptPoint>> {
    crate::error::ensure!(!seqs.is_empty(), "no test sequences to sweep on");
    let clip = Arc::new(TimedClip {
        betas: seqs[0].truth.betas.clone(),
        previous_pose: seqs[0].truth.previous_pose.clone(),
        poses: seqs[0].truth.poses.clone(),
    });
    let full = assets.network(NetworkOptions::default())?;
    let sizes = full.header().sizes;
    let own_width = match sizes.output {
        OutputKind::Dense => 3 * sizes.n_vertices,
        OutputKind::Pca(k) => k,
    };
    let mut ranks: Vec<Option<usize>> = vec![None];
    ranks.extend(
        args.ranks
            .iter()
            .filter(|&&r| r > 0 && r < own_width)
            .map(|&r| Some(r)),
    );
    let triangles = assets.binding.faces().len();
    let model = assets.model_dir.display().to_string();
    let total = (ranks.len() + 1) * 3;
    progress.start("tradeoff", total as u64, "variants");
    let quiet = NoProgress;
    let mut points = Vec::new();
    for precision in [Precision::F32, Precision::F16, Precision::Int8] {
        for fit_only in [false, true] {
            let rank_list: &[Option<usize>] = if fit_only { &[None] } else { &ranks };
            for &rank in rank_list {
                let pname = precision_name(precision);
                let width = rank.unwrap_or(own_width);
                let label = if fit_only {
                    format!("{triangles}t fit-only {pname}")
                } else {
                    format!("{triangles}t h{} k{width} {pname}", sizes.gru_hidden)
                };
                progress.message(&label);
                let network = assets.network(NetworkOptions {
                    precision,
                    output_rank: rank,
                })?;
                let base = AnimatorOptions::default();
                let options = |pp: bool| {
                    let o = if fit_only {
                        AnimatorOptions {
                            fit: FitMode::Network,
                            wrinkles: WrinkleMode::None,
                            ..base
                        }
                    } else {
                        Method::Ours.options(base)
                    };
                    AnimatorOptions {
                        collision: if pp { o.collision } else { None },
                        ..o
                    }
                };
                let bytes = network.fit_weight_bytes()
                    + if fit_only {
                        0
                    } else {
                        network.wrinkle_weight_bytes()
                    };
                // One evaluation gives the error with and without the post-process.
                let report = evaluate_with(assets, &network, options(true), seqs, &quiet)?;
                for pp in [true, false] {
                    let rig = assets.rig(&network, options(pp))?;
                    let point = TradeoffPoint {
                        label: format!("{label}{}", if pp { " pp" } else { "" }),
                        model: model.clone(),
                        garment_triangles: triangles,
                        gru_hidden: if fit_only { 0 } else { sizes.gru_hidden },
                        output_rank: if fit_only { 0 } else { width },
                        precision: pname.into(),
                        post_process: pp,
                        fit_only,
                        mean_vertex_error_mm: if pp {
                            report.mean_vertex_error_mm
                        } else {
                            report.mean_vertex_error_mm_before_pp
                        },
                        collision_percent: if pp {
                            report.collision_percent_after_pp
                        } else {
                            report.collision_percent_before_pp
                        },
                        collision_percent_before_pp: report.collision_percent_before_pp,
                        collision_percent_after_pp: report.collision_percent_after_pp,
                        ms_per_frame: f64::NAN,
                        ms_per_frame_rounds: Vec::new(),
                        model_mb: bytes as f64 * 1e-6,
                        pareto: false,
                    };
                    points.push(SweptPoint {
                        point,
                        rig,
                        clip: clip.clone(),
                    });
                }
                progress.inc(1);
            }
        }
    }
    progress.finish();
    Ok(points)
}

/// `pareto.{png,svg}` in `dir`: one chart per garment resolution, side by side on the same
/// axes, of error against ms per frame on a log axis, one series per precision (its marker
/// shape) and post-process setting, the Pareto set (over every size) ringed.
pub fn plot_tradeoff(dir: &Path, points: &[TradeoffPoint]) -> Result<()> {
    // One chart per garment resolution, side by side on the same axes.
    let mut sizes: Vec<usize> = points.iter().map(|p| p.garment_triangles).collect();
    sizes.sort_unstable();
    sizes.dedup();
    let x = |p: &TradeoffPoint| p.ms_per_frame;
    let y = |p: &TradeoffPoint| p.mean_vertex_error_mm;
    let y_hi = points
        .iter()
        .map(y)
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    // The time axis as `plot` pads a log axis; errors from zero.
    let ranges = crate::plot::log_range(points.iter().map(x)).map(|xs| (xs, 0.0..y_hi * 1.05));
    let mut charts = Vec::new();
    for &size in &sizes {
        let mut series: Vec<Series> = Vec::new();
        for p in points.iter().filter(|p| p.garment_triangles == size) {
            let (kind, marker) = if p.fit_only {
                ("fit-only", Marker::Square)
            } else {
                match p.precision.as_str() {
                    "f32" => ("f32", Marker::Circle),
                    "f16" => ("f16", Marker::Triangle),
                    _ => ("int8", Marker::Cross),
                }
            };
            let name = format!("{kind}{}", if p.post_process { " + pp" } else { "" });
            let point = (x(p), y(p));
            match series.iter_mut().find(|s| s.name == name) {
                Some(s) => s.points.push(point),
                None => series.push(Series {
                    name,
                    points: vec![point],
                    marker: Some(marker),
                }),
            }
        }
        series.push(Series {
            name: "Pareto set of all sizes (error, collisions, time)".into(),
            points: points
                .iter()
                .filter(|p| p.pareto && p.garment_triangles == size)
                .map(|p| (x(p), y(p)))
                .collect(),
            marker: Some(Marker::Ring),
        });
        charts.push(Chart {
            title: format!("{size}-triangle garment: error against cost per frame (one thread)"),
            x_label: "ms per frame (log)".into(),
            y_label: "mean vertex error (mm)".into(),
            series,
            log_x: true,
            // Errors sit well above zero: the bottom of the chart is empty.
            legend_at_bottom: true,
            ranges: ranges.clone(),
        });
    }
    write_charts(&dir.join("pareto"), &charts, charts.len(), (900, 600))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(ms: f64, err: f64) -> TradeoffPoint {
        TradeoffPoint {
            label: String::new(),
            model: String::new(),
            garment_triangles: 0,
            gru_hidden: 0,
            output_rank: 0,
            precision: "f32".into(),
            post_process: false,
            fit_only: false,
            mean_vertex_error_mm: err,
            collision_percent: 0.0,
            collision_percent_before_pp: 0.0,
            collision_percent_after_pp: 0.0,
            ms_per_frame: ms,
            ms_per_frame_rounds: vec![ms],
            model_mb: 0.0,
            pareto: false,
        }
    }

    #[test]
    fn pareto_front_keeps_exactly_the_undominated_points() {
        let mut p = vec![
            point(1.0, 10.0), // front: fastest
            point(2.0, 5.0),  // front
            point(3.0, 6.0),  // dominated by (2, 5)
            point(4.0, 1.0),  // front: most accurate
            point(2.0, 5.0),  // equal to a front point: neither dominates
            point(1.0, 11.0), // dominated by (1, 10)
        ];
        mark_pareto(&mut p);
        let flags: Vec<bool> = p.iter().map(|p| p.pareto).collect();
        assert_eq!(flags, [true, true, false, true, true, false]);
        // Collisions are the third axis: a slower, less accurate point that leaves fewer
        // vertices inside the body is in the set; one that is worse on all three is not.
        let mut q = vec![point(1.0, 10.0), point(2.0, 11.0), point(3.0, 12.0)];
        q[0].collision_percent = 5.0;
        q[1].collision_percent = 0.1;
        q[2].collision_percent = 0.1;
        mark_pareto(&mut q);
        let flags: Vec<bool> = q.iter().map(|p| p.pareto).collect();
        assert_eq!(flags, [true, true, false]);
    }
}
