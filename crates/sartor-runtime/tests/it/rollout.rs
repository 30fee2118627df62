//! A long rollout of a random GRU stays finite and bounded.

use sartor_runtime::{GruCell, Matrix, Parallelism, Precision};

use crate::common::{random, rng};

#[test]
fn hundred_thousand_steps_stay_finite_and_bounded() {
    let (inp, hid) = (12, 64);
    let mut r = rng(30);
    // Weights larger than PyTorch's default init, so the state saturates sometimes.
    let a = 3.0 / (hid as f32).sqrt();
    let cell = GruCell::new(
        Matrix::from_f32(
            3 * hid,
            inp,
            random(&mut r, 3 * hid * inp, a),
            Precision::F32,
        )
        .expect("finite"),
        Matrix::from_f32(
            3 * hid,
            hid,
            random(&mut r, 3 * hid * hid, a),
            Precision::F32,
        )
        .expect("finite"),
        random(&mut r, 3 * hid, a),
        random(&mut r, 3 * hid, a),
    )
    .expect("shapes");
    let mut scratch = cell.scratch(1);
    let mut h = vec![0.0f32; hid];
    let mut x = vec![0.0f32; inp];
    let period = 97.0f32;
    let mut max_abs = 0.0f32;
    for t in 0..100_000u32 {
        for (i, v) in x.iter_mut().enumerate() {
            let phase = std::f32::consts::TAU * ((t as f32 / period).fract() + i as f32 / 13.0);
            *v = 2.0 * phase.sin();
        }
        cell.step(&x, &mut h, &mut scratch, Parallelism::Sequential)
            .expect("sizes");
        for &v in &h {
            assert!(v.is_finite() && v.abs() <= 1.0, "step {t}: {v}");
            max_abs = max_abs.max(v.abs());
        }
    }
    // The state is not stuck at zero: the test exercises the gates.
    assert!(max_abs > 0.5, "{max_abs}");
}
