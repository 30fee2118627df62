//! One wrinkle frame at the paper's size: a GRU with 1,500 hidden units (input 160: 10 betas +
//! 25 joints in 6D) and a 1,500 → 13,272 dense output (the 4,424-vertex T-shirt), per weight
//! precision, on one thread and on rayon's pool; batch 1 and batch 8 (8 avatars sharing one
//! pass over the weights — divide by 8 for the time per avatar).
//!
//! `pca_basis` times the thin PCA decode at the ranks `sartor tradeoff` sweeps; `shipped` one
//! wrinkle step (GRU and output layer, batch 1, one thread and rayon's pool) of the shipped model in
//! `datasets/models/default`, per precision, when it is there.
//!
//! `cargo bench -p sartor-runtime --bench kernels -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sartor_runtime::{
    GarmentNetwork, GruCell, Linear, Matrix, OutputLayer, Parallelism, Precision, instruction_set,
};

const INPUT: usize = 160;
const HIDDEN: usize = 1500;
const OUTPUTS: usize = 3 * 4424;

struct Weights {
    w_ih: Vec<f32>,
    w_hh: Vec<f32>,
    b_ih: Vec<f32>,
    b_hh: Vec<f32>,
    w_out: Vec<f32>,
    b_out: Vec<f32>,
}

fn random(rng: &mut ChaCha8Rng, n: usize, amp: f32) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-amp..amp)).collect()
}

/// Random weights of a GRU of `hidden` units on `input` values with a dense output of
/// `outputs` values.
fn weights(input: usize, hidden: usize, outputs: usize) -> Weights {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let a = 1.0 / (hidden as f32).sqrt();
    Weights {
        w_ih: random(&mut rng, 3 * hidden * input, a),
        w_hh: random(&mut rng, 3 * hidden * hidden, a),
        b_ih: random(&mut rng, 3 * hidden, a),
        b_hh: random(&mut rng, 3 * hidden, a),
        w_out: random(&mut rng, outputs * hidden, a),
        b_out: random(&mut rng, outputs, a),
    }
}

fn build(w: &Weights, p: Precision) -> (GruCell, OutputLayer) {
    let (hidden, outputs) = (w.b_ih.len() / 3, w.b_out.len());
    let input = w.w_ih.len() / (3 * hidden);
    let gru = GruCell::new(
        Matrix::from_f32(3 * hidden, input, w.w_ih.clone(), p).expect("finite"),
        Matrix::from_f32(3 * hidden, hidden, w.w_hh.clone(), p).expect("finite"),
        w.b_ih.clone(),
        w.b_hh.clone(),
    )
    .expect("shapes");
    let out = OutputLayer::Dense(
        Linear::new(
            Matrix::from_f32(outputs, hidden, w.w_out.clone(), p).expect("finite"),
            w.b_out.clone(),
        )
        .expect("shapes"),
    );
    (gru, out)
}

/// Where a crowd's shared pass over the weights starts to pay (`GarmentNetwork`'s
/// `set_shared_pass_from`): a GRU on the shipped model's 98 wrinkle inputs with a dense output
/// of its 6,504 values, at 256, 512 and 1,024 units, per precision, one thread: eight inputs
/// through one shared pass (`/shared8`) and one at a time (`/alone8`).
fn shared_line(c: &mut Criterion) {
    const CROWD: usize = 8;
    let (input, outputs) = (98, 6504);
    for hidden in [256, 512, 1024] {
        let w = weights(input, hidden, outputs);
        let mut group = c.benchmark_group(format!("shared_line/gru{hidden}_out{outputs}"));
        for precision in [Precision::F32, Precision::F16, Precision::Int8] {
            let (gru, out) = build(&w, precision);
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            let xs = random(&mut rng, CROWD * input, 1.0);
            let mut hs = random(&mut rng, CROWD * hidden, 0.5);
            let (mut gs, mut os) = (gru.scratch(CROWD), out.scratch(CROWD));
            let mut ys = vec![0.0f32; CROWD * outputs];
            let bytes = gru.weight_bytes() + out.weight_bytes();
            let name = |way: &str| {
                format!(
                    "{}/{way}{CROWD}/{:.1}MB",
                    precision.name(),
                    bytes as f64 / 1e6
                )
            };
            let seq = Parallelism::Sequential;
            group.bench_function(name("shared"), |b| {
                b.iter(|| {
                    gru.step_batch(black_box(&xs), CROWD, &mut hs, &mut gs, seq)
                        .expect("sizes");
                    out.forward_batch_t(&hs, CROWD, &mut ys, &mut os, seq)
                        .expect("sizes");
                    black_box(&ys);
                })
            });
            group.bench_function(name("alone"), |b| {
                b.iter(|| {
                    for a in 0..CROWD {
                        let h = &mut hs[a * hidden..(a + 1) * hidden];
                        gru.step_batch(
                            black_box(&xs[a * input..(a + 1) * input]),
                            1,
                            h,
                            &mut gs,
                            seq,
                        )
                        .expect("sizes");
                        out.forward_batch_t(
                            h,
                            1,
                            &mut ys[a * outputs..(a + 1) * outputs],
                            &mut os,
                            seq,
                        )
                        .expect("sizes");
                    }
                    black_box(&ys);
                })
            });
        }
        group.finish();
    }
}

fn bench(c: &mut Criterion) {
    let w = weights(INPUT, HIDDEN, OUTPUTS);
    eprintln!(
        "kernels: {} , rayon threads: {}",
        instruction_set(),
        rayon::current_num_threads()
    );
    let mut group = c.benchmark_group(format!("matvec{OUTPUTS}x{HIDDEN}"));
    for precision in [Precision::F32, Precision::F16, Precision::Int8] {
        let m = Matrix::from_f32(OUTPUTS, HIDDEN, w.w_out.clone(), precision).expect("finite");
        for batch in [1usize, 8] {
            let x = vec![0.5f32; batch * HIDDEN];
            let mut y = vec![0.0f32; batch * OUTPUTS];
            let name = format!("{}/batch{batch}/1thread", precision.name());
            group.bench_function(name, |b| {
                b.iter(|| {
                    m.matmul_t(
                        black_box(&x),
                        batch,
                        Some(&w.b_out),
                        &mut y,
                        Parallelism::Sequential,
                    )
                    .expect("sizes")
                })
            });
        }
    }
    group.finish();
    let mut group = c.benchmark_group(format!("gru{HIDDEN}_out{OUTPUTS}"));
    for precision in [Precision::F32, Precision::F16, Precision::Int8] {
        let (gru, out) = build(&w, precision);
        for batch in [1usize, 8] {
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            let xs = random(&mut rng, batch * INPUT, 1.0);
            let mut hs = random(&mut rng, batch * HIDDEN, 0.5);
            let mut gs = gru.scratch(batch);
            let mut os = out.scratch(batch);
            let mut ys = vec![0.0f32; batch * OUTPUTS];
            for (par, par_name) in [
                (Parallelism::Sequential, "1thread"),
                (Parallelism::Rayon, "rayon"),
            ] {
                if batch > 1 && par == Parallelism::Sequential && precision != Precision::F32 {
                    continue;
                }
                let name = format!("{}/batch{batch}/{par_name}", precision.name());
                group.bench_function(name, |b| {
                    b.iter(|| {
                        gru.step_batch(black_box(&xs), batch, &mut hs, &mut gs, par)
                            .expect("sizes");
                        out.forward_batch_t(&hs, batch, &mut ys, &mut os, par)
                            .expect("sizes");
                        black_box(&ys);
                    })
                });
            }
        }
    }
    group.finish();
}

/// The PCA decode `mean + basis · c` of the two T-shirts (3V = 6,504 and 13,272 rows) at the
/// ranks `sartor tradeoff` sweeps, one thread: a thin matrix, stored in panels.
fn pca_basis(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut group = c.benchmark_group("pca_basis");
    for rows in [3 * 2168, OUTPUTS] {
        let mean = random(&mut rng, rows, 0.1);
        for rank in [4usize, 8, 16, 32, 64] {
            let basis = random(&mut rng, rows * rank, 0.05);
            let coefficients = random(&mut rng, rank, 1.0);
            let mut y = vec![0.0f32; rows];
            for precision in [Precision::F32, Precision::F16, Precision::Int8] {
                let m = Matrix::from_f32(rows, rank, basis.clone(), precision).expect("finite");
                let name = format!("{rows}x{rank}/{}", precision.name());
                group.bench_function(name, |b| {
                    b.iter(|| {
                        m.matvec(
                            black_box(&coefficients),
                            Some(&mean),
                            &mut y,
                            Parallelism::Sequential,
                        )
                        .expect("sizes")
                    })
                });
            }
        }
    }
    group.finish();
}

/// One wrinkle step of the shipped model (normalisation, GRU, PCA output, checks), batch 1,
/// on one thread and (`/rayon`) on rayon's pool, over a loop of 64 made-up inputs so that the
/// state keeps moving; and the step of a crowd of eight on one thread: as a crowd takes it
/// (`/batch8`), through one pass over the weights shared by all (`/shared8`: the batched
/// kernels, with weights that stay in cache), and the reference, each avatar stepped alone
/// (`/alone8`).
fn shipped(c: &mut Criterion) {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/models/default");
    if !dir.join("model.json").exists() {
        eprintln!("shipped: no model at {}, skipped", dir.display());
        return;
    }
    let mut group = c.benchmark_group("shipped");
    for precision in [Precision::F32, Precision::F16, Precision::Int8] {
        let net = GarmentNetwork::load(&dir, precision).expect("the shipped model loads");
        let mut ws = net.workspace(1);
        let mut state = net.initial_state();
        let mut out = vec![0.0f32; net.output_size()];
        let n_in = net.input_size();
        let xs: Vec<Vec<f32>> = (0..64)
            .map(|f| {
                (0..n_in)
                    .map(|i| ((i * 7 + f * 13) % 11) as f32 * 0.05 - 0.25)
                    .collect()
            })
            .collect();
        let mut f = 0;
        for (par, suffix) in [
            (Parallelism::Sequential, ""),
            (Parallelism::Rayon, "/rayon"),
        ] {
            group.bench_function(format!("{}{suffix}", precision.name()), |b| {
                b.iter(|| {
                    f = (f + 1) % xs.len();
                    net.wrinkle_step(black_box(&xs[f]), &mut state, &mut out, &mut ws, par)
                        .expect("finite");
                    black_box(&out);
                })
            });
        }
        const CROWD: usize = 8;
        let mut shared = net.clone();
        shared.set_shared_pass_from(0);
        let mut ws = net.workspace(CROWD);
        let mut states: Vec<f32> = (0..CROWD).flat_map(|_| net.initial_state()).collect();
        let mut outs = vec![0.0f32; CROWD * net.output_size()];
        // Each avatar at its own place in the loop of inputs.
        let batches: Vec<Vec<f32>> = (0..xs.len())
            .map(|f| {
                (0..CROWD)
                    .flat_map(|a| xs[(f + 5 * a) % xs.len()].clone())
                    .collect()
            })
            .collect();
        // As a crowd steps them (each alone, for so small a model), and through one shared
        // pass over the weights (the batched kernels).
        for (name, net) in [("batch", &net), ("shared", &shared)] {
            group.bench_function(format!("{}/{name}{CROWD}", precision.name()), |b| {
                b.iter(|| {
                    f = (f + 1) % batches.len();
                    net.wrinkle_step_batch(
                        black_box(&batches[f]),
                        CROWD,
                        &mut states,
                        &mut outs,
                        &mut ws,
                        Parallelism::Sequential,
                    )
                    .expect("finite");
                    black_box(&outs);
                })
            });
        }
        // The reference: the same eight stepped one at a time.
        let (n_in, n_state, n_out) = (net.input_size(), net.state_size(), net.output_size());
        group.bench_function(format!("{}/alone{CROWD}", precision.name()), |b| {
            b.iter(|| {
                f = (f + 1) % batches.len();
                for a in 0..CROWD {
                    net.wrinkle_step(
                        black_box(&batches[f][a * n_in..(a + 1) * n_in]),
                        &mut states[a * n_state..(a + 1) * n_state],
                        &mut outs[a * n_out..(a + 1) * n_out],
                        &mut ws,
                        Parallelism::Sequential,
                    )
                    .expect("finite");
                }
                black_box(&outs);
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench, pca_basis, shipped, shared_line);
criterion_main!(benches);
