//! Plain reference arithmetic shared by tests of several crates (included with `#[path]`, so it
//! names no crate): what the kernels and the runtime are checked against.

/// `W x + b` in f64 (`W` row-major `[b.len(), x.len()]`).
pub fn affine(w: &[f32], b: &[f32], x: &[f64]) -> Vec<f64> {
    let n = x.len();
    b.iter()
        .enumerate()
        .map(|(i, &bi)| (0..n).map(|j| w[i * n + j] as f64 * x[j]).sum::<f64>() + bi as f64)
        .collect()
}

/// The largest absolute difference between two equally long slices.
pub fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}
