//! The collision post-process of the shipped model (the 4,210-triangle T-shirt on the built-in
//! body, nominal shape) on the procedural walk, one thread: milliseconds per frame of the
//! post-process alone (posing the body region and pushing the cloth out), per query, and the
//! whole frame with the default query. `certified-2threads` is the default query with its first
//! pass split over a pool of two threads; `certified-buried` is the certified query as a body
//! shape beyond the model's training shapes gets it (the faces buried inside another body part
//! sought every frame). The frames run the network in f32 on one thread, and in int8 on one
//! thread and on the pool of two (`-int8-2threads`: the network's products and the
//! post-process's first pass split). Each iteration is the next frame of the clip, so the
//! temporal caches see real motion. `crowd/…` is a `GarmentCrowd` of two or three avatars
//! (different shapes and phases of the walk), the whole crowd's frame on one thread and on
//! the pool of two. `certified-heavy-cmu` is the default query at the try-on page's "male,
//! 1.90 m, heavy" body (beyond the training shapes) dancing CMU 05_06; `-faces` pushes the
//! triangles out too, as the page does. `strain-limit/…` is the strain limit's own time
//! ([`sartor_runtime::StrainLimit`], before the post-process) on the walk and on that dance.
//! `certified-first-frame-faces` is a new avatar's first frame (no face to start any search
//! from), the triangles pushed out too.
//!
//! `cargo bench -p sartor-runtime --bench postprocess -- --warm-up-time 1 --measurement-time 3`
//!
//! `SARTOR_BENCH_MODEL=datasets/models/default-8710` runs the same benchmarks on another trained
//! export (here the shipped 8,710-triangle T-shirt, which `cargo xtask pipeline --config
//! configs/default-8710.json` trains), named by its folder (`post-process/default-8710/…`).

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use sartor_core::{BodyModel, Pose};
use sartor_runtime::{
    AnimatorOptions, CollisionOptions, CollisionQuery, GarmentAnimator, GarmentBinding,
    GarmentCrowd, GarmentNetwork, GarmentRig, Interpenetration, NetworkOptions, Parallelism,
    Precision, StageTimes, StrainLimit,
};

fn data(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../datasets")
        .join(path)
}

fn clock_ms() -> f64 {
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64() * 1e3
}

fn rig(
    query: CollisionQuery,
    interpenetration: Interpenetration,
    faces: bool,
    parallelism: Parallelism,
    precision: Precision,
) -> Arc<GarmentRig> {
    let options = AnimatorOptions {
        parallelism,
        collision: Some(CollisionOptions {
            query,
            interpenetration,
            faces,
            ..CollisionOptions::default()
        }),
        ..AnimatorOptions::default()
    };
    rig_with(options, precision)
}

/// The model the benchmarks run: the shipped one, or the export `SARTOR_BENCH_MODEL` names
/// (a trained model of another garment, e.g. `datasets/models/default-8710`; relative to the
/// workspace).
fn model_dir() -> PathBuf {
    match std::env::var_os("SARTOR_BENCH_MODEL") {
        Some(dir) => PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(dir),
        None => data("models/default"),
    }
}

/// The benchmarked model's name in the benchmarks' ids: `shipped-4210`, or the named export's
/// folder (its parent's name for an `export` folder, e.g. `default-8710`).
fn model_label() -> String {
    let Some(dir) = std::env::var_os("SARTOR_BENCH_MODEL") else {
        return "shipped-4210".into();
    };
    let dir = PathBuf::from(dir);
    let name = |p: &std::path::Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    match name(&dir).as_deref() {
        Some("export") => dir.parent().and_then(name),
        other => other.map(str::to_owned),
    }
    .unwrap_or_else(|| "model".into())
}

/// The benchmarked model's rig with `options`, its weights in `precision`.
fn rig_with(options: AnimatorOptions, precision: Precision) -> Arc<GarmentRig> {
    let dir = model_dir();
    let body = Arc::new(BodyModel::load(&data("body/makehuman")).expect("built-in body"));
    let network_options = NetworkOptions {
        precision,
        ..NetworkOptions::default()
    };
    let network = Arc::new(GarmentNetwork::load_with(&dir, network_options).expect("model"));
    let binding = Arc::new(GarmentBinding::load(&dir).expect("binding"));
    Arc::new(GarmentRig::new(network, binding, body, options).expect("rig"))
}

fn animator(
    query: CollisionQuery,
    interpenetration: Interpenetration,
    faces: bool,
    parallelism: Parallelism,
    precision: Precision,
) -> GarmentAnimator {
    let rig = rig(query, interpenetration, faces, parallelism, precision);
    let mut avatar = GarmentAnimator::new(rig).expect("avatar");
    avatar.set_stage_clock(Some(clock_ms));
    avatar
}

/// The betas of "male, 1.90 m, heavy" (the phenotype space of the built-in body), and CMU 05_06
/// retargeted to the built-in body.
fn heavy_on_cmu() -> (Vec<f32>, Vec<Pose>) {
    use sartor_core::{PhenotypeRequest, PhenotypeSpace};
    use sartor_motion::{MotionSourceOptions, RetargetBody, load_motion};
    let dir = data("body/makehuman");
    let body = BodyModel::load(&dir).expect("built-in body");
    let space = PhenotypeSpace::load(&dir).expect("phenotype space");
    let request: PhenotypeRequest = "male, 1.90 m, heavy".parse().expect("valid request");
    let (_, betas) = space
        .betas_for(&body, &request)
        .expect("reachable phenotype");
    let options = MotionSourceOptions {
        motions_dir: data("motions"),
        body: Some(RetargetBody::load(&dir).expect("built-in body")),
        ..MotionSourceOptions::default()
    };
    let clip = load_motion("cmu/05_06", &options).expect("stored CMU clip");
    let betas = betas.iter().map(|&b| b as f32).collect();
    (betas, clip.frames().to_vec())
}

/// The post-process's own time (the avatar's stage clock) over the next `iters` frames of
/// `poses`, from frame `*k` on, cycling.
fn post_process_time(
    avatar: &mut GarmentAnimator,
    poses: &[Pose],
    k: &mut usize,
    iters: u64,
) -> Duration {
    stage_time(avatar, poses, k, iters, |t| t.post_process_ms)
}

/// The time of the stage `stage` picks (the avatar's stage clock) over the next `iters` frames
/// of `poses`, from frame `*k` on, cycling.
fn stage_time(
    avatar: &mut GarmentAnimator,
    poses: &[Pose],
    k: &mut usize,
    iters: u64,
    stage: impl Fn(&StageTimes) -> f64,
) -> Duration {
    let mut total = 0.0;
    for _ in 0..iters {
        avatar.frame(&poses[*k % poses.len()]).expect("frame");
        *k += 1;
        total += stage(&avatar.stage_times().expect("clock"));
    }
    Duration::from_secs_f64(total * 1e-3)
}

fn post_process(c: &mut Criterion) {
    let walk = sartor_motion::procedural::clip("walk_normal").expect("clip");
    let poses: Vec<Pose> = walk.frames().to_vec();
    let mut group = c.benchmark_group(format!("post-process/{}", model_label()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("a pool of two threads");
    let within = Interpenetration::BeyondTrainingShapes;
    let seq = Parallelism::Sequential;
    for (name, query, interpenetration, faces, parallelism) in [
        ("certified", CollisionQuery::Certified, within, false, seq),
        // Its first pass split over two threads.
        (
            "certified-2threads",
            CollisionQuery::Certified,
            within,
            false,
            Parallelism::Rayon,
        ),
        // The triangles' centroids pushed out too (`CollisionOptions::faces`).
        (
            "certified-faces",
            CollisionQuery::Certified,
            within,
            true,
            seq,
        ),
        // What a shape beyond the training shapes gets: buried faces sought every frame.
        (
            "certified-buried",
            CollisionQuery::Certified,
            Interpenetration::Always,
            false,
            seq,
        ),
        ("bvh", CollisionQuery::EXACT_BVH, within, false, seq),
    ] {
        let mut avatar = animator(query, interpenetration, faces, parallelism, Precision::F32);
        let mut k = 0;
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                pool.install(|| post_process_time(&mut avatar, &poses, &mut k, iters))
            })
        });
    }
    // An avatar's first frame, the triangles pushed out too (as `demo` and the page do): no
    // cloth vertex or triangle has a face to start its search from (a new avatar, a sequence
    // of `eval`, a garment chosen on the page). A new avatar each iteration, built untimed.
    let first = rig(CollisionQuery::Certified, within, true, seq, Precision::F32);
    group.bench_function("certified-first-frame-faces", |b| {
        b.iter_custom(|iters| {
            let mut total = 0.0;
            for _ in 0..iters {
                let mut avatar = GarmentAnimator::new(first.clone()).expect("avatar");
                avatar.set_stage_clock(Some(clock_ms));
                avatar.frame(&poses[0]).expect("frame");
                total += avatar.stage_times().expect("clock").post_process_ms;
            }
            Duration::from_secs_f64(total * 1e-3)
        })
    });
    // A shopper's body beyond the training shapes on real motion capture: the try-on page's
    // "male, 1.90 m, heavy" dancing CMU 05_06 (arms raised, a cartwheel), the whole clip.
    // With `-faces`, the triangles pushed out too, as the page does.
    let (betas, dance) = heavy_on_cmu();
    for (name, faces) in [
        ("certified-heavy-cmu", false),
        ("certified-heavy-cmu-faces", true),
    ] {
        let mut avatar = animator(
            CollisionQuery::Certified,
            within,
            faces,
            seq,
            Precision::F32,
        );
        avatar.set_shape(&betas).expect("finite shape");
        let mut k = 0;
        group.bench_function(name, |b| {
            b.iter_custom(|iters| post_process_time(&mut avatar, &dance, &mut k, iters))
        });
    }
    group.finish();
    // The strain limit's own time (`StrainLimit::default()`, before the post-process): on the
    // walk at the nominal shape, where few edges are too long, and at the heavy body dancing
    // CMU 05_06, where the arms go up.
    let nominal = vec![0.0; betas.len()];
    let label = model_label();
    for (name, shape, clip) in [
        (format!("strain-limit/{label}"), &nominal, &poses),
        (format!("strain-limit/{label}-heavy-cmu"), &betas, &dance),
    ] {
        let options = AnimatorOptions {
            strain_limit: Some(StrainLimit::default()),
            ..AnimatorOptions::default()
        };
        let mut avatar = GarmentAnimator::new(rig_with(options, Precision::F32)).expect("avatar");
        avatar.set_stage_clock(Some(clock_ms));
        avatar.set_shape(shape).expect("finite shape");
        let mut k = 0;
        c.bench_function(&name, |b| {
            b.iter_custom(|iters| {
                stage_time(&mut avatar, clip, &mut k, iters, |t| t.strain_limit_ms)
            })
        });
    }
    // The whole frame: f32 on one thread, and int8 on one thread and on a pool of two.
    for (name, precision, parallelism) in [
        ("certified", Precision::F32, seq),
        ("certified-int8", Precision::Int8, seq),
        (
            "certified-int8-2threads",
            Precision::Int8,
            Parallelism::Rayon,
        ),
    ] {
        let name = format!("frame/{label}-{name}");
        let mut avatar = animator(
            CollisionQuery::Certified,
            within,
            false,
            parallelism,
            precision,
        );
        let mut k = 0;
        // The pool entered once per batch of iterations, not per frame: handing each frame to
        // a pool thread and back cost some 35 µs, which the frame itself does not.
        c.bench_function(&name, |b| {
            b.iter_custom(|iters| {
                pool.install(|| {
                    let start = Instant::now();
                    for _ in 0..iters {
                        avatar.frame(&poses[k % poses.len()]).expect("frame");
                        k += 1;
                    }
                    start.elapsed()
                })
            })
        });
    }
    // Crowds of two and three avatars in int8 with the default post-process, on one thread
    // and on the pool of two: shapes β₀ = 0, +1, −1 (within the training shapes), each
    // avatar at its own phase of the walk; milliseconds per frame of the whole crowd.
    for (n, parallelism, threads) in [
        (2, seq, "1thread"),
        (2, Parallelism::Rayon, "2threads"),
        (3, seq, "1thread"),
        (3, Parallelism::Rayon, "2threads"),
    ] {
        let rig = rig(
            CollisionQuery::Certified,
            within,
            false,
            parallelism,
            Precision::Int8,
        );
        let n_betas = rig.network().n_betas();
        let mut crowd = GarmentCrowd::new(rig, n).expect("crowd");
        for i in 0..n {
            let mut betas = vec![0.0; n_betas];
            betas[0] = [0.0, 1.0, -1.0][i];
            crowd.set_shape(i, &betas).expect("shape");
        }
        // Per frame of the clip, every avatar's pose (made before the timing).
        let sets: Vec<Vec<Pose>> = (0..poses.len())
            .map(|k| {
                (0..n)
                    .map(|i| poses[(k + 11 * i) % poses.len()].clone())
                    .collect()
            })
            .collect();
        let mut k = 0;
        let name = format!("crowd/{label}-certified-int8-{n}avatars-{threads}");
        c.bench_function(&name, |b| {
            b.iter_custom(|iters| {
                pool.install(|| {
                    let start = Instant::now();
                    for _ in 0..iters {
                        crowd.frame(&sets[k % sets.len()]).expect("crowd frame");
                        k += 1;
                    }
                    start.elapsed()
                })
            })
        });
    }
}

criterion_group!(benches, post_process);
criterion_main!(benches);
