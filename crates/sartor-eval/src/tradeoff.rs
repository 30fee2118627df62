//! `tradeoff`: what each speed knob of the runtime costs in accuracy.
//!
//! For every exported model of the experiment (its own, plus any `--model` folders, e.g. trained
//! with other hidden sizes, and the models of further `--config`s with other garment
//! resolutions) the sweep crosses:
//!
//! - the output rank `k` (the runtime's `NetworkOptions::output_rank`: the first `k` PCA
//!   components, or a rank-`k` truncated SVD of a dense output layer) — `--ranks`;
//! - the weight precision: f32, f16, int8;
//! - the collision post-process on and off, and on after the strain limit
//!   ([`sartor_runtime::StrainLimit`], its defaults: no edge beyond 1.5× its rest length);
//! - the fit-only static try-on mode (no wrinkle GRU), per precision.
//!
//! Each point's error is the mean vertex error (mm) of `ours` on the experiment's held-out
//! motions (on the nominal shape unless `--all-shapes`), exactly as `eval` computes it, with the
//! share of cloth vertex-frames inside the body before and after the post-process (eval's
//! measure, the body's winding number: [`sartor_core::BodyDistance`]) and the garment's edge
//! stretch (eval's too: each edge's length over its rest length, after the post-process where
//! the point runs it). Its cost is the wall time
//! of `GarmentAnimator::frame` on one thread over one held-out clip ([`time_points`]: every
//! point timed once per round, after a warm-up; the median over a round's frames, then the
//! median over the rounds), and the bytes of its weights. A point is in the Pareto set when no other
//! point is at least as good in error, collisions and time and better in one (`pareto`, the three
//! axes of the trade-off); `pareto_with_stretch` adds the stretch's 99.9th percentile as a fourth,
//! the axis the strain limit buys. Writes
//! `runs/<name>/tradeoff/tradeoff.json` and `pareto.{png,svg}` (one chart per garment resolution
//! on shared axes, log time axis, one marker shape per precision, one colour per post-process
//! setting, the three-axis Pareto set ringed).

use std::path::Path;
use std::sync::Arc;

use sartor_core::Pose;

use sartor_runtime::{
    AnimatorOptions, FitMode, GarmentAnimator, GarmentRig, NetworkOptions, OutputKind, Precision,
    StrainLimit, WrinkleMode,
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
    /// The strain limit before the post-process ([`sartor_runtime::StrainLimit::default`]).
    pub strain_limit: bool,
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
    /// The 99.9th percentile of this point's edge-frames' stretch (length over rest length).
    pub edge_stretch_p999: f64,
    /// The longest edge over its rest length, of all this point's edge-frames.
    pub edge_stretch_max: f64,
    /// ms per frame, one thread: the median over the rounds of each round's median.
    pub ms_per_frame: f64,
    /// Each round's median ms per frame.
    pub ms_per_frame_rounds: Vec<f64>,
    /// The weights this point runs (fit MLP, and GRU and output unless fit-only), MB (10⁶ bytes).
    pub model_mb: f64,
    /// No other point is at least as good in error, collisions and time and better in one.
    pub pareto: bool,
    /// No other point is at least as good in error, collisions, time and stretch (99.9th
    /// percentile) and better in one.
    pub pareto_with_stretch: bool,
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
/// in all three and strictly better in one (`pareto`); and over those and the stretch's 99.9th
/// percentile (`pareto_with_stretch`).
pub fn mark_pareto(points: &mut [TradeoffPoint]) {
    let key: Vec<[f64; 4]> = points
        .iter()
        .map(|p| {
            [
                p.ms_per_frame,
                p.mean_vertex_error_mm,
                p.collision_percent,
                p.edge_stretch_p999,
            ]
        })
        .collect();
    let undominated = |i: usize, axes: usize| {
        let a = &key[i][..axes];
        !key.iter().enumerate().any(|(j, b)| {
            let b = &b[..axes];
            j != i && (0..axes).all(|k| b[k] <= a[k]) && (0..axes).any(|k| b[k] < a[k])
        })
    };
    for (i, p) in points.iter_mut().enumerate() {
        p.pareto = undominated(i, 3);
        p.pareto_with_stretch = undominated(i, 4);
    }
}

/// Sweep one exported model (its assets and its test sequences): every output rank of
/// `options` below the model's own, f32 / f16 / int8, post-process on and off and on after the
/// strain limit, and fit-only; each point's error, collisions and stretch, and what
/// [`time_points`] times it with (on the first test sequence).
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
                let options = |pp: bool, limit: bool| {
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
                        strain_limit: limit.then(StrainLimit::default),
                        ..o
                    }
                };
                let bytes = network.fit_weight_bytes()
                    + if fit_only {
                        0
                    } else {
                        network.wrinkle_weight_bytes()
                    };
                // One evaluation gives the error with and without the post-process; the strain
                // limit is swept with the post-process after it, as a scene runs it.
                let report = evaluate_with(assets, &network, options(true, false), seqs, &quiet)?;
                let limited = evaluate_with(assets, &network, options(true, true), seqs, &quiet)?;
                for (pp, limit, report) in [
                    (true, false, &report),
                    (false, false, &report),
                    (true, true, &limited),
                ] {
                    let rig = assets.rig(&network, options(pp, limit))?;
                    let stretch = if pp {
                        &report.edge_stretch
                    } else {
                        &report.edge_stretch_before_pp
                    };
                    let point = TradeoffPoint {
                        label: format!(
                            "{label}{}{}",
                            if limit { " sl" } else { "" },
                            if pp { " pp" } else { "" }
                        ),
                        model: model.clone(),
                        garment_triangles: triangles,
                        gru_hidden: if fit_only { 0 } else { sizes.gru_hidden },
                        output_rank: if fit_only { 0 } else { width },
                        precision: pname.into(),
                        post_process: pp,
                        strain_limit: limit,
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
                        edge_stretch_p999: stretch.edge_stretch_p999,
                        edge_stretch_max: stretch.edge_stretch_max,
                        ms_per_frame: f64::NAN,
                        ms_per_frame_rounds: Vec::new(),
                        model_mb: bytes as f64 * 1e-6,
                        pareto: false,
                        pareto_with_stretch: false,
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
/// axes, of error against ms per frame on a log axis, one marker shape per precision (and one
/// for fit-only), one colour per post-process setting (off, on, on after the strain limit), the
/// three-axis Pareto set (over every size) ringed.
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
    // Marker: the precision (or fit-only); colour: what runs after the network. Each has its
    // own legend entries, so that the legend stays short enough to leave the points clear.
    const MODES: [(&str, usize); 3] = [
        ("network only", 1),
        ("+ post-process", 0),
        ("+ strain limit + post-process", 2),
    ];
    let kinds = [
        ("f32", Marker::Circle),
        ("f16", Marker::Triangle),
        ("int8", Marker::Cross),
        ("fit MLP only (any precision)", Marker::Square),
    ];
    let mut charts = Vec::new();
    for &size in &sizes {
        let mut series: Vec<Series> = Vec::new();
        for p in points.iter().filter(|p| p.garment_triangles == size) {
            let kind = if p.fit_only {
                3
            } else {
                match p.precision.as_str() {
                    "f32" => 0,
                    "f16" => 1,
                    _ => 2,
                }
            };
            let mode = match (p.post_process, p.strain_limit) {
                (false, _) => 0,
                (true, false) => 1,
                (true, true) => 2,
            };
            let (name, color) = (format!("{kind} {mode}"), MODES[mode].1);
            let point = (x(p), y(p));
            match series.iter_mut().find(|s| s.name == name) {
                Some(s) => s.points.push(point),
                None => series.push(Series {
                    name,
                    points: vec![point],
                    marker: Some(kinds[kind].1),
                    color: Some(color),
                }),
            }
        }
        // The data series draw without legend entries; the legend's come last, without
        // points: the markers in black, the modes as coloured bars.
        for s in &mut series {
            s.name.clear();
        }
        series.extend(kinds.iter().map(|&(name, marker)| Series {
            name: name.into(),
            points: Vec::new(),
            marker: Some(marker),
            color: Some(7),
        }));
        series.extend(MODES.iter().map(|&(name, color)| Series {
            name: name.into(),
            points: Vec::new(),
            marker: None,
            color: Some(color),
        }));
        series.push(Series {
            name: "Pareto set of all sizes (error, collisions, time)".into(),
            points: points
                .iter()
                .filter(|p| p.pareto && p.garment_triangles == size)
                .map(|p| (x(p), y(p)))
                .collect(),
            marker: Some(Marker::Ring),
            color: None,
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
            strain_limit: false,
            fit_only: false,
            mean_vertex_error_mm: err,
            collision_percent: 0.0,
            collision_percent_before_pp: 0.0,
            collision_percent_after_pp: 0.0,
            edge_stretch_p999: 1.0,
            edge_stretch_max: 1.0,
            ms_per_frame: ms,
            ms_per_frame_rounds: vec![ms],
            model_mb: 0.0,
            pareto: false,
            pareto_with_stretch: false,
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
        // Stretch is the fourth axis of the second set only: the third point, dominated on
        // the three axes, stretches least.
        q[2].edge_stretch_p999 = 0.5;
        mark_pareto(&mut q);
        let flags: Vec<[bool; 2]> = q
            .iter()
            .map(|p| [p.pareto, p.pareto_with_stretch])
            .collect();
        assert_eq!(flags, [[true, true], [true, true], [false, true]]);
    }
}
