//! The tiny pipeline on configs/tiny.json (a procedural clip, a window of an imported CMU clip by
//! name and a CMU BVH file by path): `simulate` + `dataset` (resume after a kill gives
//! byte-identical files, the dataset loads, no frame of a held-out clip or shape is in the
//! training split), then `train`, `export` and `eval` on it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use sartor_dataset::{Split, load_dataset, read_manifest};

fn xtask() -> Command {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
}

fn tiny() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/tiny.json")
}

fn run(args: &[&str], runs: &Path) {
    let out = xtask()
        .args(args)
        .arg("--config")
        .arg(tiny())
        .arg("--runs-dir")
        .arg(runs)
        .output()
        .expect("xtask runs");
    assert!(
        out.status.success(),
        "xtask {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every file under `dir` (relative path → bytes), reports with timings excluded.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).expect("readable") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            let rel = path
                .strip_prefix(dir)
                .expect("inside")
                .display()
                .to_string();
            let timing_report = ["simulate.json", "dataset.json", "dataset-run.json"]
                .iter()
                .any(|r| rel.ends_with(r));
            if !timing_report {
                out.insert(rel, std::fs::read(&path).expect("readable"));
            }
        }
    }
    out
}

#[test]
fn tiny_pipeline_resumes_byte_identically_and_keeps_splits_apart() {
    let straight = tempfile::tempdir().expect("temp dir");
    run(&["simulate"], straight.path());
    // The report gives the step against the garment's resolution: 10 substeps (the config
    // sets no rule) and 1 / (30 fps × 10 × the median edge, measured here over every face's
    // edges).
    let report = read_json(&straight.path().join("tiny/sim/simulate.json"));
    assert_eq!(report["substeps_per_frame"], 10);
    let garment = sartor_cloth::Garment::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../datasets/garments/tshirt-tiny"),
    )
    .expect("the tiny garment");
    let p = garment.positions();
    let mut edges: Vec<f64> = garment
        .faces()
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
        .map(|(a, b)| (p[a as usize] - p[b as usize]).norm())
        .collect();
    edges.sort_by(f64::total_cmp);
    let expected = 1.0 / (300.0 * edges[edges.len() / 2]);
    let step = report["step_per_edge_s_per_m"].as_f64().expect("a number");
    assert!(
        (step - expected).abs() < 0.05 * expected,
        "{step} s/m against {expected}"
    );

    // Kill a second run as soon as its first sequences are finished, then resume it.
    let resumed = tempfile::tempdir().expect("temp dir");
    let sim = resumed.path().join("tiny/sim");
    let mut child = xtask()
        .args(["simulate", "--jobs", "1", "--config"])
        .arg(tiny())
        .arg("--runs-dir")
        .arg(resumed.path())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("xtask starts");
    let start = Instant::now();
    let finished = |dir: &Path| {
        std::fs::read_dir(dir).map_or(0, |es| {
            es.filter(|e| {
                e.as_ref()
                    .is_ok_and(|e| e.path().extension().is_some_and(|x| x == "mcap"))
            })
            .count()
        })
    };
    while finished(&sim) < 3 && start.elapsed() < Duration::from_secs(600) {
        if child.try_wait().expect("waitable").is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let killed_midway = child.try_wait().expect("waitable").is_none();
    child.kill().expect("killable");
    child.wait().expect("reaped");
    assert!(killed_midway, "the run finished before it could be killed");
    let total = files(&straight.path().join("tiny/sim"))
        .keys()
        .filter(|k| k.ends_with(".mcap"))
        .count();
    assert!(
        finished(&sim) < total,
        "the kill came too late to test a resume"
    );
    run(&["simulate"], resumed.path());

    let a = files(&straight.path().join("tiny/sim"));
    let b = files(&sim);
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the same files"
    );
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "{name} differs after the resume");
    }

    // The dataset from both is identical too, and loads.
    run(&["dataset"], straight.path());
    run(&["dataset"], resumed.path());
    let da = files(&straight.path().join("tiny/dataset"));
    let db = files(&resumed.path().join("tiny/dataset"));
    assert_eq!(da, db, "datasets differ");
    let dir = straight.path().join("tiny/dataset");
    let data = load_dataset(&dir).expect("the dataset loads");
    let manifest = read_manifest(&dir).expect("manifest");

    // No leakage: training sequences use training shapes and training motions only.
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tiny()).expect("config")).expect("json");
    let held_motions: Vec<&str> = config["motions"]["held_out"]
        .as_array()
        .expect("list")
        .iter()
        .filter_map(|m| m.as_str())
        .collect();
    let held_shapes: Vec<&str> = config["shapes"]["held_out"]
        .as_array()
        .expect("list")
        .iter()
        .filter_map(|s| s["id"].as_str())
        .collect();
    let mut n_train = 0;
    for q in data.sequences() {
        let shape = &manifest.shapes[q.shape];
        if q.split == Split::Train {
            n_train += 1;
            assert!(!held_motions.contains(&q.motion.as_str()), "{}", q.id);
            assert!(!held_shapes.contains(&shape.id.as_str()), "{}", q.id);
        }
        if held_shapes.contains(&shape.id.as_str()) {
            assert_eq!(q.split, Split::HeldOutShapes, "{}", q.id);
        } else if held_motions.contains(&q.motion.as_str()) {
            assert_eq!(q.split, Split::HeldOutMotions, "{}", q.id);
        }
    }
    assert!(n_train > 0);
    // Statistics come from the training split: recomputing them from it gives the same means.
    let train: Vec<_> = data
        .sequences()
        .iter()
        .filter(|q| q.split == Split::Train)
        .collect();
    let n_in = data.n_inputs();
    let frames: usize = train.iter().map(|q| q.n_frames).sum();
    for c in [0, n_in - 1] {
        let mean: f64 = train
            .iter()
            .flat_map(|q| q.inputs.chunks_exact(n_in).map(move |r| r[c] as f64))
            .sum::<f64>()
            / frames as f64;
        assert!((mean - data.stats().wrinkle_in.mean[c] as f64).abs() < 1e-4);
    }

    train_export_eval(straight.path(), &config);
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(
        &std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    )
    .expect("json")
}

/// `train` (all three models, with the epochs the config asks for), a refused second run and an
/// immediate `--resume`, `export --run` (a runtime model folder with a preview), `eval`.
fn train_export_eval(runs: &Path, config: &serde_json::Value) {
    run(&["train"], runs);
    let train = runs.join("tiny/train");
    let report = read_json(&train.join("train.json"));
    for m in ["fit", "wrinkle", "linear"] {
        let r = &report["models"][m];
        let epochs = config["training"][m]["epochs"].as_u64().expect("epochs");
        let err = r["best_val_error_mm"].as_f64().expect("a validation error");
        assert!(err.is_finite() && err > 0.0, "{m}: {err}");
        if m == "linear" {
            // Closed form: one solve, whatever the configured epochs.
            assert_eq!(r["epochs"].as_u64(), Some(epochs.min(1)), "{m}");
            continue;
        }
        assert_eq!(r["epochs"].as_u64(), Some(epochs), "{m}");
        let curve = r["curve"].as_array().expect("curve");
        let first = curve[0]["train_loss"].as_f64().expect("loss");
        let last = curve[curve.len() - 1]["train_loss"].as_f64().expect("loss");
        assert!(
            last < first,
            "{m}: the loss did not fall ({first} → {last})"
        );
    }
    for ext in ["png", "svg"] {
        assert!(train.join(format!("loss.{ext}")).is_file());
    }
    // A second run without --resume refuses to overwrite; with it, there is nothing left to do.
    let again = xtask()
        .args(["train", "--models", "fit", "--config"])
        .arg(tiny())
        .arg("--runs-dir")
        .arg(runs)
        .output()
        .expect("xtask runs");
    assert!(!again.status.success(), "train overwrote an existing run");
    run(&["train", "--resume"], runs);

    let out = xtask()
        .args(["export", "--run"])
        .arg(runs.join("tiny"))
        .output()
        .expect("xtask runs");
    assert!(
        out.status.success(),
        "export failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let export = runs.join("tiny/export");
    let model = sartor_runtime::GarmentModel::load(&export).expect("the export loads");
    assert!(model.header().sizes.linear_baseline);
    sartor_runtime::GarmentBinding::load(&export).expect("the binding loads");
    assert!(export.join("preview/walk_normal.glb").is_file());
    assert!(export.join("preview/walk_normal.mcap").is_file());

    run(&["eval"], runs);
    let eval = read_json(&runs.join("tiny/eval/eval.json"));
    for (set, methods) in [
        (
            "held_out_motions",
            &["ours", "ours_strain_limit", "lbs", "lr"][..],
        ),
        (
            "held_out_shapes",
            &["ours", "ours_strain_limit", "retarget", "lbs"][..],
        ),
    ] {
        for m in methods {
            let e = eval[set][m]["mean_vertex_error_mm"].as_f64();
            assert!(
                e.is_some_and(|e| e.is_finite() && e > 0.0),
                "{set}/{m}: {e:?}"
            );
            assert!(
                eval[set][m]["collision_percent_after_pp"].is_number(),
                "{set}/{m}"
            );
            // Edge stretch: ordered quantiles, and the set's maximum that of its sequences.
            let stretch = &eval[set][m]["edge_stretch"];
            let q = |k: &str| stretch[k].as_f64().unwrap_or(f64::NAN);
            assert!(
                q("edge_stretch_p50") > 0.0
                    && q("edge_stretch_p50") <= q("edge_stretch_p99")
                    && q("edge_stretch_p99") <= q("edge_stretch_max")
                    && q("edge_stretch_max").is_finite(),
                "{set}/{m}: {stretch}"
            );
            let seq_max = eval[set][m]["sequences"]
                .as_array()
                .expect("sequences")
                .iter()
                .map(|s| s["edge_stretch_max"].as_f64().expect("a number"))
                .fold(0.0, f64::max);
            assert_eq!(seq_max, q("edge_stretch_max"), "{set}/{m}");
        }
        let truth = &eval["ground_truth_edge_stretch"][set];
        let p99 = truth["edge_stretch_p99"].as_f64();
        assert!(
            p99.is_some_and(|p| p.is_finite() && p > 0.0),
            "{set}: {truth}"
        );
        assert_eq!(
            truth["sequences"].as_array().map(Vec::len),
            eval[set]["ours"]["sequences"].as_array().map(Vec::len),
            "{set}"
        );
        // The strain limit leaves no edge longer than the network and skinning made it.
        let longest = |m: &str| {
            eval[set][m]["edge_stretch_before_pp"]["edge_stretch_max"]
                .as_f64()
                .expect("a number")
        };
        assert!(
            longest("ours_strain_limit") <= longest("ours"),
            "{set}: {} against {}",
            longest("ours_strain_limit"),
            longest("ours")
        );
    }
    // The simulated cloth's stretch on the sequences learnt from, too (and selected on, where
    // a config has validation motions: the tiny one has none).
    let truth = &eval["ground_truth_edge_stretch"]["train"];
    let frames = truth["edge_frames"].as_u64();
    assert!(frames.is_some_and(|n| n > 0), "train: {truth}");
    assert!(eval["ground_truth_edge_stretch"]["validation"].is_null());

    // The trade-off sweep: each variant with and without the post-process, and with the
    // strain limit before it; every point's error, collisions, stretch and time.
    run(
        &[
            "tradeoff",
            "--ranks",
            "4",
            "--timed-frames",
            "2",
            "--rounds",
            "1",
        ],
        runs,
    );
    let dir = runs.join("tiny/tradeoff");
    let report = read_json(&dir.join("tradeoff.json"));
    let points = report["points"].as_array().expect("points");
    let flag = |p: &serde_json::Value, k: &str| p[k].as_bool().expect("a flag");
    let number = |p: &serde_json::Value, k: &str| p[k].as_f64().unwrap_or(f64::NAN);
    for p in points {
        for k in [
            "mean_vertex_error_mm",
            "edge_stretch_p999",
            "edge_stretch_max",
            "ms_per_frame",
        ] {
            assert!(number(p, k).is_finite() && number(p, k) > 0.0, "{k}: {p}");
        }
        assert!(
            number(p, "edge_stretch_p999") <= number(p, "edge_stretch_max"),
            "{p}"
        );
        let inside = if flag(p, "post_process") {
            "collision_percent_after_pp"
        } else {
            "collision_percent_before_pp"
        };
        assert_eq!(number(p, "collision_percent"), number(p, inside), "{p}");
        // A strain-limited point runs the post-process after the limit.
        assert!(!flag(p, "strain_limit") || flag(p, "post_process"), "{p}");
    }
    // Three points a variant: the post-process off, on, and on after the strain limit.
    let limited = points.iter().filter(|p| flag(p, "strain_limit")).count();
    let raw = points.iter().filter(|p| !flag(p, "post_process")).count();
    assert!(limited > 0 && limited == raw && 3 * limited == points.len());
    for set in ["pareto", "pareto_with_stretch"] {
        assert!(points.iter().any(|p| flag(p, set)), "no point in {set}");
    }
    assert!(dir.join("pareto.png").is_file());
}
