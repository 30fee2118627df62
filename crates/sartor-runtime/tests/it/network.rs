//! `GarmentNetwork` against the f64 reference; batching, threads, non-finite inputs.

use sartor_runtime::{Error, GarmentNetwork, OutputKind, Parallelism, Precision};

use crate::common::{
    bits, random, random_model, reference_fit, reference_linear, reference_wrinkle_step, rel_err,
    rng, sizes,
};

/// Tolerances relative to the largest reference value: f32 from the kernels' bound, f16 and
/// int8 loose (they only check the plumbing; the kernel bounds are tested per element).
fn tolerance(p: Precision) -> f64 {
    match p {
        Precision::F32 => 1e-5,
        Precision::F16 => 5e-3,
        Precision::Int8 => 5e-2,
    }
}

#[test]
fn fit_and_wrinkle_match_the_f64_reference() {
    for output in [OutputKind::Dense, OutputKind::Pca(6)] {
        let model = random_model(20, sizes(output, true));
        for precision in [Precision::F32, Precision::F16, Precision::Int8] {
            let net = GarmentNetwork::new(model.clone(), precision).expect("valid");
            let mut ws = net.workspace(1);
            let mut r = rng(21);
            let o3 = net.output_size();
            let mut out = vec![0.0; o3];
            for _ in 0..3 {
                let betas = random(&mut r, net.n_betas(), 2.0);
                net.fit(&betas, &mut out, &mut ws, Parallelism::Sequential)
                    .expect("finite");
                let e = rel_err(&out, &reference_fit(&model, &betas));
                assert!(e < tolerance(precision), "fit {precision:?}: {e:e}");
            }
            let mut state = net.initial_state();
            let mut h_ref = vec![0.0f64; net.state_size()];
            let mut worst = 0.0f64;
            for t in 0..20 {
                let x = random(&mut r, net.input_size(), 2.0);
                net.wrinkle_step(&x, &mut state, &mut out, &mut ws, Parallelism::Sequential)
                    .expect("finite");
                let want = reference_wrinkle_step(&model, &x, &mut h_ref);
                let e = rel_err(&out, &want);
                worst = worst.max(e);
                assert!(
                    e < tolerance(precision),
                    "{output:?} {precision:?} step {t}: {e:e}"
                );
                assert!(state.iter().all(|h| h.abs() <= 1.0));
            }
            eprintln!("{output:?} {precision:?}: worst wrinkle relative error {worst:.2e}");
            let x = random(&mut r, net.input_size(), 2.0);
            net.linear_baseline(&x, &mut out, &mut ws, Parallelism::Sequential)
                .expect("finite");
            let e = rel_err(&out, &reference_linear(&model, &x));
            assert!(e < tolerance(precision), "lr {precision:?}: {e:e}");
        }
    }
}

#[test]
fn batched_and_parallel_equal_single_sequential_bitwise() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .expect("pool");
    for output in [OutputKind::Dense, OutputKind::Pca(6)] {
        let model = random_model(22, sizes(output, false));
        // So small a model steps a batch's avatars alone by default; from zero bytes the
        // batch shares one pass over the weights (the batched kernels).
        let modes = [Precision::F32, Precision::F16, Precision::Int8]
            .into_iter()
            .flat_map(|p| [(p, false), (p, true)]);
        for (precision, shared) in modes {
            let mut net = GarmentNetwork::new(model.clone(), precision).expect("valid");
            if shared {
                net.set_shared_pass_from(0);
            }
            let (n_in, hid, o3, nb) = (
                net.input_size(),
                net.state_size(),
                net.output_size(),
                net.n_betas(),
            );
            let batch = 5;
            let mut ws_batch = net.workspace(batch);
            let mut ws_one = net.workspace(1);
            let mut r = rng(23);

            let betas = random(&mut r, batch * nb, 1.5);
            let mut fit_batch = vec![0.0; batch * o3];
            pool.install(|| {
                net.fit_batch(
                    &betas,
                    batch,
                    &mut fit_batch,
                    &mut ws_batch,
                    Parallelism::Rayon,
                )
            })
            .expect("finite");
            for b in 0..batch {
                let mut one = vec![0.0; o3];
                net.fit(
                    &betas[b * nb..(b + 1) * nb],
                    &mut one,
                    &mut ws_one,
                    Parallelism::Sequential,
                )
                .expect("finite");
                assert_eq!(bits(&one), bits(&fit_batch[b * o3..(b + 1) * o3]));
            }

            let mut states = vec![0.0; batch * hid];
            let mut singles = states.clone();
            let mut out_batch = vec![0.0; batch * o3];
            let mut out_one = vec![0.0; o3];
            for _ in 0..4 {
                let xs = random(&mut r, batch * n_in, 1.5);
                pool.install(|| {
                    net.wrinkle_step_batch(
                        &xs,
                        batch,
                        &mut states,
                        &mut out_batch,
                        &mut ws_batch,
                        Parallelism::Rayon,
                    )
                })
                .expect("finite");
                for b in 0..batch {
                    net.wrinkle_step(
                        &xs[b * n_in..(b + 1) * n_in],
                        &mut singles[b * hid..(b + 1) * hid],
                        &mut out_one,
                        &mut ws_one,
                        Parallelism::Sequential,
                    )
                    .expect("finite");
                    assert_eq!(bits(&out_one), bits(&out_batch[b * o3..(b + 1) * o3]));
                }
                assert_eq!(
                    bits(&singles),
                    bits(&states),
                    "{output:?} {precision:?} shared {shared}"
                );
            }
        }
    }
}

#[test]
fn non_finite_inputs_are_errors_not_nan_outputs() {
    let model = random_model(24, sizes(OutputKind::Dense, true));
    let net = GarmentNetwork::new(model, Precision::F32).expect("valid");
    let mut ws = net.workspace(2);
    let seq = Parallelism::Sequential;
    let mut out = vec![0.0; net.output_size()];
    let mut betas = vec![0.1; net.n_betas()];
    betas[2] = f32::NAN;
    let err = net.fit(&betas, &mut out, &mut ws, seq).expect_err("NaN β");
    assert!(matches!(err, Error::NonFinite { index: 2, .. }), "{err}");

    let mut state = net.initial_state();
    let mut x = vec![0.1; net.input_size()];
    x[7] = f32::INFINITY;
    let err = net
        .wrinkle_step(&x, &mut state, &mut out, &mut ws, seq)
        .expect_err("infinite input");
    assert!(matches!(err, Error::NonFinite { index: 7, .. }), "{err}");
    assert!(state.iter().all(|&h| h == 0.0), "state untouched on error");
    assert!(net.linear_baseline(&x, &mut out, &mut ws, seq).is_err());

    x[7] = 0.0;
    state[3] = f32::NAN;
    assert!(
        net.wrinkle_step(&x, &mut state, &mut out, &mut ws, seq)
            .is_err()
    );

    // Sizes and batch capacity.
    state[3] = 0.0;
    assert!(
        net.wrinkle_step(&x[1..], &mut state, &mut out, &mut ws, seq)
            .is_err()
    );
    // A batch with one non-finite input changes no avatar's state, stepped alone or through
    // a shared pass.
    for shared_from in [usize::MAX, 0] {
        let mut net = net.clone();
        net.set_shared_pass_from(shared_from);
        let mut xs = vec![0.1; 2 * net.input_size()];
        xs[net.input_size() + 3] = f32::NAN;
        let mut states = vec![0.25; 2 * net.state_size()];
        let mut outs = vec![0.0; 2 * net.output_size()];
        let err = net
            .wrinkle_step_batch(&xs, 2, &mut states, &mut outs, &mut ws, seq)
            .expect_err("NaN in the second avatar's input");
        assert!(matches!(err, Error::NonFinite { .. }), "{err}");
        assert!(
            states.iter().all(|&h| h == 0.25),
            "states untouched on error"
        );
    }
    let mut big = vec![0.0; 3 * net.output_size()];
    let xs = vec![0.0; 3 * net.input_size()];
    let mut states = vec![0.0; 3 * net.state_size()];
    assert!(
        net.wrinkle_step_batch(&xs, 3, &mut states, &mut big, &mut ws, seq)
            .is_err()
    );

    // A workspace made for another network is refused, not a panic.
    let mut other_sizes = sizes(OutputKind::Dense, false);
    other_sizes.gru_hidden += 1;
    let other = GarmentNetwork::new(random_model(26, other_sizes), Precision::F32).expect("valid");
    let mut other_ws = other.workspace(2);
    let err = net
        .wrinkle_step(&x, &mut state, &mut out, &mut other_ws, seq)
        .expect_err("foreign workspace");
    assert!(err.to_string().contains("workspace"), "{err}");
}

#[test]
fn model_without_baseline_says_so() {
    let model = random_model(25, sizes(OutputKind::Dense, false));
    let net = GarmentNetwork::new(model, Precision::F16).expect("valid");
    assert!(!net.has_linear_baseline());
    let mut ws = net.workspace(1);
    let mut out = vec![0.0; net.output_size()];
    let x = vec![0.0; net.input_size()];
    let err = net
        .linear_baseline(&x, &mut out, &mut ws, Parallelism::Sequential)
        .expect_err("no baseline");
    assert!(err.to_string().contains("linear baseline"), "{err}");
    assert!(net.weight_bytes() > 0);
}

/// From a thread outside rayon's pool (this test's), a step whose products split across
/// threads runs on the pool with its other workers polling (`runs_awake`); its results are
/// still bitwise those of the sequential step, frame after frame, for the fit and the wrinkle
/// step.
#[test]
fn rayon_from_outside_the_pool_equals_sequential_bitwise() {
    let mut big = sizes(OutputKind::Dense, false);
    // 3·160 × 160 and 3·120 × 300: products of more than 2¹⁶ multiply–adds, which split.
    big.gru_hidden = 160;
    big.fit_hidden = 300;
    big.n_vertices = 120;
    let model = random_model(27, big);
    for precision in [Precision::F32, Precision::F16, Precision::Int8] {
        let net = GarmentNetwork::new(model.clone(), precision).expect("valid");
        let (mut ws_seq, mut ws_par) = (net.workspace(1), net.workspace(1));
        let mut r = rng(28);
        let o3 = net.output_size();
        let (mut seq, mut par) = (vec![0.0; o3], vec![0.0; o3]);
        let betas = random(&mut r, net.n_betas(), 1.5);
        net.fit(&betas, &mut seq, &mut ws_seq, Parallelism::Sequential)
            .expect("finite");
        net.fit(&betas, &mut par, &mut ws_par, Parallelism::Rayon)
            .expect("finite");
        assert_eq!(bits(&seq), bits(&par), "fit {precision:?}");
        let (mut h_seq, mut h_par) = (net.initial_state(), net.initial_state());
        for t in 0..4 {
            let x = random(&mut r, net.input_size(), 1.5);
            net.wrinkle_step(
                &x,
                &mut h_seq,
                &mut seq,
                &mut ws_seq,
                Parallelism::Sequential,
            )
            .expect("finite");
            net.wrinkle_step(&x, &mut h_par, &mut par, &mut ws_par, Parallelism::Rayon)
                .expect("finite");
            assert_eq!(bits(&seq), bits(&par), "step {t} {precision:?}");
            assert_eq!(bits(&h_seq), bits(&h_par), "state {t} {precision:?}");
        }
    }
}
