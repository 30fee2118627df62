//! The fused GRU cell (PyTorch's equations and gate order).

use crate::error::{Error, Result, check_finite, check_len};

use super::matrix::{Matrix, Parallelism};
use super::mlp::transpose;

/// A GRU cell with PyTorch's parameter layout: gates stacked `(r, z, n)` in `[3H, I]` input
/// weights and `[3H, H]` hidden weights, and
///
/// ```text
/// r  = σ(W_ir x + b_ir + W_hr h + b_hr)
/// z  = σ(W_iz x + b_iz + W_hz h + b_hz)
/// n  = tanh(W_in x + b_in + r ⊙ (W_hn h + b_hn))
/// h' = (1 − z) ⊙ n + z ⊙ h
/// ```
///
/// One step makes one pass over each of the two matrices (all three gates at once) and then
/// applies the gate math in one loop. `|h'| ≤ 1` whenever `|h| ≤ 1`, also in f32: `σ ∈ [0, 1]`,
/// `tanh ∈ [−1, 1]`, and with round-to-nearest `fl(fl(1 − z)·n + z·h)` cannot exceed 1
/// (`fl(1 − z) + z ≤ 1 + 2⁻²⁵`, which rounds to 1).
#[derive(Clone, Debug, PartialEq)]
pub struct GruCell {
    input: usize,
    hidden: usize,
    weight_ih: Matrix,
    weight_hh: Matrix,
    bias_ih: Vec<f32>,
    bias_hh: Vec<f32>,
}

/// Work buffers for [`GruCell`] steps, sized for up to `capacity` sequences at once: the input
/// and hidden gate pre-activations, `[3H, B]` each.
#[derive(Clone, Debug)]
pub struct GruScratch {
    capacity: usize,
    gates_x: Vec<f32>,
    gates_h: Vec<f32>,
    /// A batch's states unit-major (`[H, B]`, as the gates come), empty for capacity 1.
    states_t: Vec<f32>,
}

impl GruScratch {
    /// The largest batch these buffers hold.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

/// `e^x` for the gates, in plain f32 arithmetic without branches so that the gate loop
/// vectorises (the C library's `expf` and `tanhf`, called once per gate and unit, took about a
/// fifth of the shipped model's int8 step): `x` clamped to `[−87, 88]` (where `e^x` is a normal
/// f32), `x = n ln 2 + r` with `n` rounded to nearest (Cody–Waite: `n · LN2_HI` is exact),
/// `e^r` by Cephes' `expf` polynomial on `|r| ≤ ln 2 / 2`, then `2^n` through the exponent
/// bits. Within 1 ulp of `e^x` there (tested); every operation is IEEE and Rust contracts none
/// into an FMA, so the bits are the same in every lane width, on every instruction set.
#[inline(always)]
fn exp_gate(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // 1.5 · 2²³: adding and subtracting it rounds to the nearest integer (ties to even) for
    // |v| < 2²², in any lane width.
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let shifted = x * LOG2E + ROUND;
    let n = shifted - ROUND;
    // The integer `n` from the same bits (no float-to-integer conversion, which does not
    // vectorise): `shifted`'s exponent is that of ROUND, and its mantissa is ROUND's plus `n`.
    let n_int = (shifted.to_bits() as i32).wrapping_sub(ROUND.to_bits() as i32);
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.987_569_2e-4_f32;
    let p = p * r + 1.398_2e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 0.166_666_65;
    let p = p * r + 0.5;
    let er = (p * r) * r + r + 1.0;
    // n ∈ [−126, 127]: a normal power of two.
    er * f32::from_bits(((n_int + 127) as u32) << 23)
}

/// The logistic function, in (0, 1], within 1.5e-7 of it (absolute; tested).
#[inline(always)]
fn sigmoid(a: f32) -> f32 {
    1.0 / (1.0 + exp_gate(-a))
}

/// `tanh`, in [−1, 1], as `1 − 2 / (e^{2y} + 1)`: within 2.5e-7 of it (absolute; tested).
#[inline(always)]
fn tanh_gate(y: f32) -> f32 {
    1.0 - 2.0 / (exp_gate(2.0 * y) + 1.0)
}

/// The new state of one unit from its gate pre-activations (input and hidden parts of `r`,
/// `z`, `n`) and its state `h` (PyTorch's GRU equations).
#[inline(always)]
fn unit(x: [f32; 3], g: [f32; 3], h: f32) -> f32 {
    let r = sigmoid(x[0] + g[0]);
    let z = sigmoid(x[1] + g[1]);
    let n = tanh_gate(x[2] + r * g[2]);
    (1.0 - z) * n + z * h
}

super::widest_where_present! {
    /// [`unit()`] of every unit of one sequence: `gx` and `gh` hold the `r`, `z` and `n` rows
    /// one after the other, `hs` the state (updated). Built for the widest vectors present (the
    /// baseline x86-64 target lacks the vector rounding and integer steps the loop needs); the
    /// same bits either way.
    fn units(gx: &[f32], gh: &[f32], hs: &mut [f32]) {
        let hid = hs.len();
        // The three gates' rows as slices, so that the loop vectorises.
        let (xr, xz, xn) = (&gx[..hid], &gx[hid..2 * hid], &gx[2 * hid..3 * hid]);
        let (hr, hz, hn) = (&gh[..hid], &gh[hid..2 * hid], &gh[2 * hid..3 * hid]);
        for (j, hj) in hs.iter_mut().enumerate() {
            *hj = unit([xr[j], xz[j], xn[j]], [hr[j], hz[j], hn[j]], *hj);
        }
    }
}

impl GruCell {
    /// Check the shapes (`weight_ih`: `[3H, I]`, `weight_hh`: `[3H, H]`, biases `[3H]`) and
    /// that the biases are finite.
    pub fn new(
        weight_ih: Matrix,
        weight_hh: Matrix,
        bias_ih: Vec<f32>,
        bias_hh: Vec<f32>,
    ) -> Result<Self> {
        let rows = weight_hh.rows();
        if !rows.is_multiple_of(3) || rows == 0 {
            return Err(Error::invalid(
                "GRU",
                format!("weight_hh has {rows} rows, expected a positive multiple of 3"),
            ));
        }
        let hidden = rows / 3;
        check_len("GRU weight_hh columns", weight_hh.cols(), hidden)?;
        check_len("GRU weight_ih rows", weight_ih.rows(), 3 * hidden)?;
        check_len("GRU bias_ih", bias_ih.len(), 3 * hidden)?;
        check_len("GRU bias_hh", bias_hh.len(), 3 * hidden)?;
        check_finite("GRU bias_ih", &bias_ih)?;
        check_finite("GRU bias_hh", &bias_hh)?;
        Ok(Self {
            input: weight_ih.cols(),
            hidden,
            weight_ih,
            weight_hh,
            bias_ih,
            bias_hh,
        })
    }

    /// Input size `I`.
    pub fn input_size(&self) -> usize {
        self.input
    }

    /// Hidden size `H`.
    pub fn hidden_size(&self) -> usize {
        self.hidden
    }

    /// The `[3H, I]` input weights.
    pub fn weight_ih(&self) -> &Matrix {
        &self.weight_ih
    }

    /// The `[3H, H]` hidden weights.
    pub fn weight_hh(&self) -> &Matrix {
        &self.weight_hh
    }

    /// Whether one of its products of `batch` inputs under `par` runs on more than one thread.
    pub(crate) fn splits(&self, batch: usize, par: Parallelism) -> bool {
        self.weight_ih.splits(batch, par) || self.weight_hh.splits(batch, par)
    }

    /// Bytes held by the two weight matrices.
    pub fn weight_bytes(&self) -> usize {
        self.weight_ih.weight_bytes() + self.weight_hh.weight_bytes()
    }

    /// Work buffers for batches of up to `capacity` sequences (at least 1).
    pub fn scratch(&self, capacity: usize) -> GruScratch {
        let capacity = capacity.max(1);
        GruScratch {
            capacity,
            gates_x: vec![0.0; 3 * self.hidden * capacity],
            gates_h: vec![0.0; 3 * self.hidden * capacity],
            states_t: if capacity > 1 {
                vec![0.0; self.hidden * capacity]
            } else {
                Vec::new()
            },
        }
    }

    /// One step for one sequence: `x` (`I`) and the carried state `h` (`H`, updated in place).
    /// Allocates nothing. Values are not checked for finiteness here (see
    /// [`crate::GarmentNetwork::wrinkle_step`], which does).
    pub fn step(
        &self,
        x: &[f32],
        h: &mut [f32],
        scratch: &mut GruScratch,
        par: Parallelism,
    ) -> Result<()> {
        self.step_batch(x, 1, h, scratch, par)
    }

    /// One step for `batch` sequences that share one pass over the weights.
    ///
    /// # Shapes
    /// - `xs`: `[batch, I]`, `hs`: `[batch, H]` (sequence `b` at `hs[b·H..]`), updated in place.
    ///
    /// Each sequence's new state is bitwise equal to [`GruCell::step`] on it alone.
    pub fn step_batch(
        &self,
        xs: &[f32],
        batch: usize,
        hs: &mut [f32],
        scratch: &mut GruScratch,
        par: Parallelism,
    ) -> Result<()> {
        if batch == 0 || batch > scratch.capacity {
            return Err(Error::invalid(
                "batch",
                format!("{batch} sequences, scratch holds 1 to {}", scratch.capacity),
            ));
        }
        check_len(
            "GRU scratch",
            scratch.gates_h.len(),
            3 * self.hidden * scratch.capacity,
        )?;
        check_len("GRU input", xs.len(), batch * self.input)?;
        check_len("GRU state", hs.len(), batch * self.hidden)?;
        let n = 3 * self.hidden * batch;
        let gx = &mut scratch.gates_x[..n];
        let gh = &mut scratch.gates_h[..n];
        self.weight_ih
            .matmul_t(xs, batch, Some(&self.bias_ih), gx, par)?;
        self.weight_hh
            .matmul_t(hs, batch, Some(&self.bias_hh), gh, par)?;
        let hid = self.hidden;
        if batch == 1 {
            units(gx, gh, hs);
            return Ok(());
        }
        // The gates come unit-major (`[3H, B]`): gate `g` of every unit and sequence is the
        // run `g·H·B..(g + 1)·H·B`, so with the states unit-major too, `units` takes the whole
        // batch as one sequence of `H·B` units (the same `unit` of each). A unit at a time,
        // gathered from the gates, was a fifth of the shipped model's int8 step for eight
        // through the batched kernels (`perf`, 2-core Intel Xeon VM); this, 3 %.
        let hs_t = &mut scratch.states_t[..hid * batch];
        transpose(hs, hid, hs_t);
        units(gx, gh, hs_t);
        transpose(hs_t, batch, hs);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::Precision;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random(rng: &mut ChaCha8Rng, n: usize, amp: f32) -> Vec<f32> {
        (0..n).map(|_| rng.random_range(-amp..amp)).collect()
    }

    #[test]
    fn the_gates_functions_are_within_their_stated_error() {
        let (mut worst_exp, mut worst_sig, mut worst_tanh) = (0.0f64, 0.0f64, 0.0f64);
        let n = 400_000;
        for i in 0..=n {
            // x over the clamped range and a little beyond, and small values densely.
            let x = -90.0 + 180.0 * i as f64 / n as f64;
            let x = x as f32;
            let e = f64::from(exp_gate(x));
            let want = f64::from(x.clamp(-87.0, 88.0)).exp();
            worst_exp = worst_exp.max((e - want).abs() / want);
            let small = (x / 9.0) as f64;
            for a in [x, small as f32] {
                let a64 = f64::from(a);
                let sig = f64::from(sigmoid(a));
                worst_sig = worst_sig.max((sig - 1.0 / (1.0 + (-a64).exp())).abs());
                let t = f64::from(tanh_gate(a));
                assert!(t.abs() <= 1.0, "tanh({a}) = {t}");
                worst_tanh = worst_tanh.max((t - a64.tanh()).abs());
            }
        }
        let ulp = f64::from(f32::EPSILON);
        // Measured: 8.0e-8, 8.9e-8 and 1.8e-7.
        assert!(worst_exp <= ulp, "exp: {worst_exp:e}");
        assert!(worst_sig <= 1.5e-7, "sigmoid: {worst_sig:e}");
        assert!(worst_tanh <= 2.5e-7, "tanh: {worst_tanh:e}");
        // Saturation: no NaN or infinity at the ends.
        for a in [f32::MIN, -1e6, 1e6, f32::MAX] {
            assert!(sigmoid(a).is_finite() && tanh_gate(a).is_finite(), "{a}");
        }
        assert_eq!(tanh_gate(1e6), 1.0);
        assert_eq!(tanh_gate(-1e6), -1.0);
    }

    /// PyTorch's GRU equations, naively, in f64.
    fn reference_step(
        wih: &[f32],
        whh: &[f32],
        bih: &[f32],
        bhh: &[f32],
        x: &[f32],
        h: &[f32],
    ) -> Vec<f64> {
        let (hid, inp) = (h.len(), x.len());
        let lin = |w: &[f32], b: &[f32], v: &[f32], row: usize| -> f64 {
            let n = v.len();
            (0..n)
                .map(|j| w[row * n + j] as f64 * v[j] as f64)
                .sum::<f64>()
                + b[row] as f64
        };
        let _ = inp;
        let sig = |a: f64| 1.0 / (1.0 + (-a).exp());
        (0..hid)
            .map(|j| {
                let r = sig(lin(wih, bih, x, j) + lin(whh, bhh, h, j));
                let z = sig(lin(wih, bih, x, hid + j) + lin(whh, bhh, h, hid + j));
                let n = (lin(wih, bih, x, 2 * hid + j) + r * lin(whh, bhh, h, 2 * hid + j)).tanh();
                (1.0 - z) * n + z * h[j] as f64
            })
            .collect()
    }

    #[test]
    fn step_matches_pytorch_equations_in_f64() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        for &(inp, hid) in &[(1, 1), (7, 5), (13, 33), (40, 67), (150, 129)] {
            let wih = random(&mut rng, 3 * hid * inp, 0.5);
            let whh = random(&mut rng, 3 * hid * hid, 0.5);
            let bih = random(&mut rng, 3 * hid, 0.5);
            let bhh = random(&mut rng, 3 * hid, 0.5);
            let cell = GruCell::new(
                Matrix::from_f32(3 * hid, inp, wih.clone(), Precision::F32).expect("ok"),
                Matrix::from_f32(3 * hid, hid, whh.clone(), Precision::F32).expect("ok"),
                bih.clone(),
                bhh.clone(),
            )
            .expect("shapes");
            let mut scratch = cell.scratch(1);
            let mut h = random(&mut rng, hid, 1.0);
            for _ in 0..5 {
                let x = random(&mut rng, inp, 2.0);
                let want = reference_step(&wih, &whh, &bih, &bhh, &x, &h);
                cell.step(&x, &mut h, &mut scratch, Parallelism::Sequential)
                    .expect("sizes");
                for (g, w) in h.iter().zip(&want) {
                    assert!((*g as f64 - w).abs() < 1e-5, "{inp}x{hid}: {g} vs {w}");
                    assert!(g.abs() <= 1.0);
                }
                // Continue from the reference state so errors do not compound.
                h = want.iter().map(|&v| v as f32).collect();
            }
        }
    }

    #[test]
    fn batched_steps_equal_single_steps_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        let (inp, hid, batch) = (19, 70, 5);
        for precision in [Precision::F32, Precision::F16, Precision::Int8] {
            let cell = GruCell::new(
                Matrix::from_f32(
                    3 * hid,
                    inp,
                    random(&mut rng, 3 * hid * inp, 0.5),
                    precision,
                )
                .expect("ok"),
                Matrix::from_f32(
                    3 * hid,
                    hid,
                    random(&mut rng, 3 * hid * hid, 0.5),
                    precision,
                )
                .expect("ok"),
                random(&mut rng, 3 * hid, 0.5),
                random(&mut rng, 3 * hid, 0.5),
            )
            .expect("shapes");
            let mut scratch = cell.scratch(batch);
            let mut hs = random(&mut rng, batch * hid, 1.0);
            let mut singles = hs.clone();
            for _ in 0..3 {
                let xs = random(&mut rng, batch * inp, 1.0);
                cell.step_batch(&xs, batch, &mut hs, &mut scratch, Parallelism::Rayon)
                    .expect("sizes");
                for b in 0..batch {
                    cell.step(
                        &xs[b * inp..(b + 1) * inp],
                        &mut singles[b * hid..(b + 1) * hid],
                        &mut scratch,
                        Parallelism::Sequential,
                    )
                    .expect("sizes");
                }
                let a: Vec<u32> = hs.iter().map(|v| v.to_bits()).collect();
                let b: Vec<u32> = singles.iter().map(|v| v.to_bits()).collect();
                assert_eq!(a, b, "{precision:?}");
            }
        }
    }

    #[test]
    fn shape_and_batch_errors() {
        let m = |r, c| Matrix::from_f32(r, c, vec![0.1; r * c], Precision::F32).expect("ok");
        assert!(GruCell::new(m(6, 3), m(6, 2), vec![0.0; 6], vec![0.0; 6]).is_ok());
        assert!(GruCell::new(m(6, 3), m(6, 3), vec![0.0; 6], vec![0.0; 6]).is_err());
        assert!(GruCell::new(m(3, 3), m(6, 2), vec![0.0; 6], vec![0.0; 6]).is_err());
        assert!(GruCell::new(m(6, 3), m(6, 2), vec![0.0; 5], vec![0.0; 6]).is_err());
        let cell = GruCell::new(m(6, 3), m(6, 2), vec![0.0; 6], vec![0.0; 6]).expect("ok");
        let mut s = cell.scratch(2);
        let mut h = vec![0.0; 6];
        let seq = Parallelism::Sequential;
        assert!(cell.step_batch(&[0.0; 9], 3, &mut h, &mut s, seq).is_err());
        assert!(cell.step(&[0.0; 2], &mut h[..2], &mut s, seq).is_err());
        cell.step(&[0.0; 3], &mut h[..2], &mut s, seq)
            .expect("sizes");
    }
}
