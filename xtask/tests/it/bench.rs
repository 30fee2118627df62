//! `bench runtime`'s `trained` section on the shipped models (4,210 and 8,710 triangles) and a
//! real CMU clip, a few frames: the certified post-process makes the exact query's garment, and
//! a motion that is not there fails the command naming it, before any timing.

use std::process::Command;

fn bench_runtime(out: &std::path::Path, motion: &str) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args([
            "bench",
            "runtime",
            "--triangles",
            "4210",
            "--warmup",
            "1",
            "--frames",
            "3",
            "--trained-motion",
            motion,
            "--out",
        ])
        .arg(out)
        .output()
        .expect("xtask runs")
}

#[test]
fn bench_runtime_times_the_shipped_post_process_on_real_motion() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("bench-runtime.json");
    let out = bench_runtime(&path, "cmu/05_10@72+4");
    assert!(
        out.status.success(),
        "bench runtime failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).expect("the report")).expect("json");
    let trained = report["trained"].as_array().expect("a trained section");
    // Every shipped model (by default), each on the clip and the motion asked for.
    let runs: Vec<(f64, &str)> = trained
        .iter()
        .map(|t| {
            let triangles = t["triangles"].as_f64().expect("triangles");
            (triangles, t["motion"].as_str().expect("motion"))
        })
        .collect();
    let motion = "cmu/05_10@72+4";
    let expected = [4210.0, 8710.0].map(|n| [(n, "walk_normal"), (n, motion)]);
    assert_eq!(runs, expected.concat());
    let mut pushed = 0.0;
    for t in trained {
        let num = |k: &str| t[k].as_f64().unwrap_or_else(|| panic!("{k}: {t}"));
        assert_eq!(num("frames"), 3.0);
        for k in ["ms_per_frame", "ms_per_frame_pp"] {
            assert!(num(k) > 0.0 && num(k).is_finite(), "{k}: {t}");
        }
        // Every vertex certified or answered exactly, every frame.
        assert_eq!(
            num("certified_per_frame") + num("exact_per_frame"),
            num("vertices")
        );
        // The certified query leaves what the exact one leaves, vertex for vertex.
        assert_eq!(num("differing_from_bvh"), 0.0, "{t}");
        assert_eq!(num("inside_after"), num("inside_after_bvh"));
        assert_eq!(num("within_margin_after"), num("within_margin_after_bvh"));
        assert!(num("inside_after") <= num("inside_before"));
        pushed += num("pushed_per_frame");
    }
    assert!(pushed > 0.0, "the post-process pushed nothing: {trained:?}");
}

#[test]
fn bench_runtime_names_a_motion_it_cannot_load() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("bench-runtime.json");
    let out = bench_runtime(&path, "cmu/99_99");
    assert!(!out.status.success(), "a missing motion passed");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("99_99"),
        "the error does not name it: {stderr}"
    );
    assert!(!path.exists(), "a report was written");
}
