//! [`kernel_probe`]: the runtime's matrix kernels on fixed inputs, so that the browser test can
//! check that the WebAssembly build (with `simd128`) computes bit for bit what the native build
//! computes (AVX2 or portable: those are tested equal in sartor-runtime). Unlike a whole frame,
//! no `exp` or `tanh` is involved, whose maths libraries differ between the two.

use sartor_runtime::{Matrix, Parallelism, Precision};

use crate::error::Result;

/// Deterministic values in `[-1, 1)` (a 64-bit LCG; no randomness crate in the page).
fn values(seed: u64, n: usize) -> Vec<f32> {
    let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
    (0..n)
        .map(|_| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// `W x + b` for f32, f16 and int8 weights of a few sizes (odd column counts exercise the
/// padded tails), batches of 1 and 3: every output, concatenated.
pub fn kernel_probe() -> Result<Vec<f32>> {
    let mut out = Vec::new();
    for (k, &(rows, cols)) in [(67, 300), (5, 31), (129, 1037)].iter().enumerate() {
        let w = values(k as u64 + 1, rows * cols);
        let bias = values(k as u64 + 100, rows);
        for precision in [Precision::F32, Precision::F16, Precision::Int8] {
            let m = Matrix::from_f32(rows, cols, w.clone(), precision)?;
            for batch in [1, 3] {
                let xs = values(k as u64 + 200 + batch as u64, batch * cols);
                let mut ys = vec![0.0; rows * batch];
                m.matmul_t(&xs, batch, Some(&bias), &mut ys, Parallelism::Sequential)?;
                out.extend(ys);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_probe_is_finite_and_deterministic() {
        let a = kernel_probe().expect("probe");
        assert_eq!(a.len(), 12 * (67 + 5 + 129));
        assert!(a.iter().all(|v| v.is_finite()));
        assert_eq!(a, kernel_probe().expect("probe"));
        assert!(values(1, 1000).iter().all(|v| (-1.0..1.0).contains(v)));
    }
}
