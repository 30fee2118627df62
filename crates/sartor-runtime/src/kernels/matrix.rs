//! Weight matrices in f32, f16 or int8 storage and their matrix–vector products.
//!
//! # Error bounds
//!
//! Let `u = 2⁻²⁴` (f32 unit roundoff), `n` the number of columns, `m = ⌈n / 32⌉ + 5` (the
//! longest chain of additions under the lane rule: `⌈n/32⌉` per lane, 5 tree levels) and
//! `γ_k = k·u / (1 − k·u)`. For one output `y_i = Σ_j w_ij x_j + b_i` computed with stored
//! weights `ŵ_ij`, the kernels guarantee (Higham, *Accuracy and Stability of Numerical
//! Algorithms*, §3.1, applied per lane):
//!
//! - **f32**: `|ŷ_i − y_i| ≤ γ_{m+2} · (Σ_j |w_ij x_j| + |b_i|)`. For `n ≤ 1,500` that is
//!   `≤ 3.2e-6` relative to `Σ|w x| + |b|`, well inside the required `1e-5`.
//! - **f16** (round to nearest, weights checked to be at most 65,504 in magnitude):
//!   `|w − ŵ| ≤ 2⁻¹¹|w|` for `|w| ≥ 2⁻¹⁴` and `≤ 2⁻²⁵` below, so
//!   `|ŷ_i − y_i| ≤ Σ_j (2⁻¹¹ |w_ij| + 2⁻²⁵) |x_j| + γ_{m+2} · (Σ_j |ŵ_ij x_j| + |b_i|)`.
//! - **int8** (symmetric per row, `s_i = max_j |w_ij| / 127`, `q = round(w / s)`):
//!   `|w − s·q| ≤ s·(1/2 + 127u)`, so
//!   `|ŷ_i − y_i| ≤ s_i (1/2 + 127u) Σ_j |x_j| + γ_{m+3} · (s_i Σ_j |q_ij x_j| + |b_i|)`.
//!   (A row whose largest weight is below [`INT8_ZERO_ROW`] = 1e-30 is stored as zeros.)
//!   Rows of 17 to 2,048 columns multiply integers (`int8.rs`): the input is quantised with
//!   one step `t = max_j |x_j| / L` (`L` = 32,767 up to 516 columns, `⌊(2³¹ − 1) / 127n⌋`
//!   beyond), which adds `t (1/2 + 2Lu) · s_i Σ_j |q_ij|`, and the rounding term becomes
//!   `γ_4 · (s_i t Σ_j |q_ij x_q,j| + |b_i|)`: one exact integer sum, then three products and
//!   the bias.
//!
//! The unit tests assert these bounds element by element on random matrices of odd sizes. The
//! typical (root-mean-square) relative error is much smaller than the worst case: for a
//! 512 × 1,500 matrix of roughly Gaussian weights and inputs uniform in [−1, 1] (like GRU
//! states), measured `‖ŷ − y‖ / ‖y‖` is 1.3e-7 for f32, 2.0e-4 for f16 and 6.5e-3 for int8
//! (`measured_relative_errors` in the tests prints them).

use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use super::dispatch::{
    Isa, LineAligned, interleave_long_rows, interleaved_f16, interleaved_f32, panels_f32, quads_i8,
    rows_f16, rows_f32, rows_i8,
};
use super::int8::{self, QUAD_PANEL};
use super::interleaved::{IL_ROWS, from_interleaved, padded_cols, to_interleaved};
use super::panels::{PANEL, THIN_COLS, from_panels, to_panels};
use super::rows::{EIGHT_ROWS_FROM, F16Bits};
use crate::error::{Error, Result, check_len};

/// Storage precision of weight matrices, chosen when a network is loaded. Biases, scales,
/// normalisation statistics and all activations stay f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// 4 bytes per weight; reference accuracy.
    #[default]
    F32,
    /// IEEE binary16, 2 bytes per weight, converted exactly to f32 on the fly.
    F16,
    /// Symmetric int8 with one f32 scale per row (`scale = max|row| / 127`), 1 byte per weight.
    Int8,
}

impl Precision {
    /// A short name for reports: `f32`, `f16`, `int8`.
    pub fn name(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
            Self::Int8 => "int8",
        }
    }
}

/// How a kernel may use threads: sartor-core's one choice. Every output row is computed by one
/// thread with the same arithmetic, so [`Parallelism::Rayon`] is bitwise equal to
/// [`Parallelism::Sequential`]; products smaller than `MIN_PARALLEL_MACS` (2¹⁶ multiply–adds)
/// run on the calling thread.
pub use sartor_core::Parallelism;

/// Below this many multiply–adds a product is not worth splitting across threads.
pub const MIN_PARALLEL_MACS: usize = 1 << 16;

/// How many of the integer kernels' multiply–adds count as one of the lane kernels' when a
/// product is sized for threads (`int8.rs`).
const INT8_SPEEDUP: usize = 8;

/// Rows per task under `par` (a multiple of `align`), or `None` to run on the calling thread.
fn rows_per_task(
    par: Parallelism,
    rows: usize,
    cols: usize,
    batch: usize,
    align: usize,
) -> Option<usize> {
    match par {
        Parallelism::Sequential => None,
        Parallelism::Rayon => {
            let threads = rayon::current_num_threads();
            if threads < 2 || rows < 2 || rows * cols.max(1) * batch < MIN_PARALLEL_MACS {
                return None;
            }
            let tasks = 4 * threads;
            Some(rows.div_ceil(tasks).max(8).next_multiple_of(align))
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
enum Storage {
    F32(Vec<f32>),
    F16(Vec<F16Bits>),
    /// int8 weights start on a cache line (the quad panels' loads).
    Int8 {
        q: LineAligned,
        scales: Vec<f32>,
    },
}

/// How `Storage` orders the weights.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Layout {
    /// Row by row (`rows.rs`).
    RowMajor,
    /// Panels of `PANEL` rows, each column by column (`panels.rs`): thin matrices.
    Panels,
    /// int8 only: panels of `QUAD_PANEL` rows, four columns by four (`int8.rs`): rows the
    /// integer kernels take that are read from cache.
    Quads,
    /// f32 and f16 only: panels of `IL_ROWS` rows, 32 columns of each in turn
    /// (`interleaved.rs`): rows the single-vector path reads eight at a time.
    Interleaved,
}

impl Layout {
    /// Quad panels for int8 matrices `int8::quads_apply` takes (int8 is never stored in
    /// panels: its row-major rows multiply integers at every width); panels for f32
    /// matrices of at most `THIN_COLS` columns and at least `PANEL` rows; interleaved rows for
    /// f32 and f16 matrices of `EIGHT_ROWS_FROM` columns or more and at least `IL_ROWS` rows
    /// where `interleave_long_rows` says (AMD's Zen 5 and later); rows otherwise.
    fn for_shape(rows: usize, cols: usize, precision: Precision) -> Self {
        if precision == Precision::Int8 && int8::quads_apply(rows, cols) {
            Self::Quads
        } else if precision == Precision::F32 && (1..=THIN_COLS).contains(&cols) && rows >= PANEL {
            Self::Panels
        } else if precision != Precision::Int8
            && cols >= EIGHT_ROWS_FROM
            && rows >= IL_ROWS
            && interleave_long_rows()
        {
            Self::Interleaved
        } else {
            Self::RowMajor
        }
    }
}

/// A `rows × cols` weight matrix in the storage of its [`Precision`]: row-major, or for a thin
/// f32 matrix (at most 8 columns, such as a PCA basis at a low rank) in panels of 8 rows
/// stored column by column (`panels.rs`), for int8 rows of up to 511 columns in quad panels
/// (`int8.rs`), for f32 and f16 rows of 512 columns or more in panels of 8 rows stored 32
/// columns of each at a time (`interleaved.rs`; on AMD's Zen 5 and later: elsewhere row-major
/// rows read faster); each the same results bit for bit, faster.
/// Built only from finite f32 values; immutable after construction.
#[derive(Clone, Debug, PartialEq)]
pub struct Matrix {
    rows: usize,
    cols: usize,
    layout: Layout,
    storage: Storage,
}

impl Matrix {
    /// Store the row-major `rows × cols` values `data` in `precision`. Errors when the length
    /// is not `rows · cols`, a value is not finite, or (f16) a value is too large for binary16.
    pub fn from_f32(
        rows: usize,
        cols: usize,
        data: Vec<f32>,
        precision: Precision,
    ) -> Result<Self> {
        let layout = Layout::for_shape(rows, cols, precision);
        Self::with_layout(rows, cols, data, precision, layout)
    }

    fn with_layout(
        rows: usize,
        cols: usize,
        data: Vec<f32>,
        precision: Precision,
        layout: Layout,
    ) -> Result<Self> {
        let n = rows
            .checked_mul(cols)
            .ok_or_else(|| Error::invalid("matrix", format!("{rows} × {cols} overflows")))?;
        check_len("matrix data", data.len(), n)?;
        crate::error::check_finite("matrix data", &data)?;
        let storage = match precision {
            Precision::F32 => Storage::F32(data),
            Precision::F16 => {
                let mut h = vec![half::f16::ZERO; n];
                h.convert_from_f32_slice(&data);
                if let Some(i) = h.iter().position(|v| !v.is_finite()) {
                    return Err(Error::invalid(
                        "matrix",
                        format!(
                            "value {} at row {}, column {} does not fit in f16 (|x| > 65504)",
                            data[i],
                            i / cols,
                            i % cols
                        ),
                    ));
                }
                Storage::F16(h.into_iter().map(|v| F16Bits(v.to_bits())).collect())
            }
            Precision::Int8 => {
                let mut q = vec![0i8; n];
                let mut scales = vec![0.0f32; rows];
                if cols > 0 {
                    for ((row, qrow), scale) in data
                        .chunks_exact(cols)
                        .zip(q.chunks_exact_mut(cols))
                        .zip(&mut scales)
                    {
                        *scale = quantize_row(row, qrow);
                    }
                }
                Storage::Int8 {
                    q: q.into(),
                    scales,
                }
            }
        };
        let storage = match (layout, storage) {
            (Layout::RowMajor, s) => s,
            (Layout::Panels, Storage::F32(w)) => Storage::F32(to_panels(&w, rows, cols)),
            (Layout::Panels, _) => {
                return Err(Error::invalid("matrix", "panels hold f32 weights only"));
            }
            (Layout::Quads, Storage::Int8 { q, scales }) => Storage::Int8 {
                q: int8::to_quad_panels(&q, rows, cols).into(),
                scales,
            },
            (Layout::Quads, _) => {
                return Err(Error::invalid(
                    "matrix",
                    "quad panels hold int8 weights only",
                ));
            }
            (Layout::Interleaved, Storage::F32(w)) => Storage::F32(to_interleaved(&w, rows, cols)),
            (Layout::Interleaved, Storage::F16(w)) => Storage::F16(to_interleaved(&w, rows, cols)),
            (Layout::Interleaved, Storage::Int8 { .. }) => {
                return Err(Error::invalid(
                    "matrix",
                    "interleaved rows hold f32 and f16 weights only",
                ));
            }
        };
        Ok(Self {
            rows,
            cols,
            layout,
            storage,
        })
    }

    /// Number of rows (outputs).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Number of columns (inputs).
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// The storage precision.
    pub fn precision(&self) -> Precision {
        match self.storage {
            Storage::F32(_) => Precision::F32,
            Storage::F16(_) => Precision::F16,
            Storage::Int8 { .. } => Precision::Int8,
        }
    }

    /// Bytes held by the weights (and int8 scales; a thin matrix's last panel is padded to 8
    /// rows, interleaved rows to whole chunks of 32 and whole panels of 8).
    pub fn weight_bytes(&self) -> usize {
        match &self.storage {
            Storage::F32(w) => 4 * w.len(),
            Storage::F16(w) => 2 * w.len(),
            Storage::Int8 { q, scales } => q.len() + 4 * scales.len(),
        }
    }

    /// The stored weights as f32 (dequantised: `scale · q` for int8), row-major.
    pub fn to_f32(&self) -> Vec<f32> {
        match &self.storage {
            Storage::F32(w) => self.row_major(w),
            Storage::F16(w) => self
                .row_major(w)
                .iter()
                .map(|h| half::f16::from_bits(h.0).to_f32())
                .collect(),
            Storage::Int8 { q, scales } => {
                let q = match self.layout {
                    Layout::Quads => int8::from_quad_panels(q, self.rows, self.cols),
                    _ => self.row_major(&q[..]),
                };
                if self.cols == 0 {
                    return Vec::new();
                }
                q.chunks_exact(self.cols)
                    .zip(scales)
                    .flat_map(|(row, &s)| row.iter().map(move |&v| s * f32::from(v)))
                    .collect()
            }
        }
    }

    /// The stored elements in row-major order.
    fn row_major<T: Copy + Default>(&self, w: &[T]) -> Vec<T> {
        match self.layout {
            Layout::RowMajor => w.to_vec(),
            Layout::Panels => from_panels(w, self.rows, self.cols),
            Layout::Interleaved => from_interleaved(w, self.rows, self.cols),
            Layout::Quads => unreachable!("quad panels hold int8 weights only"),
        }
    }

    /// The per-row int8 scales, if this matrix is int8.
    pub fn int8_scales(&self) -> Option<&[f32]> {
        match &self.storage {
            Storage::Int8 { scales, .. } => Some(scales),
            _ => None,
        }
    }

    /// `y = W x + bias` for one input vector (`x`: `cols`, `bias` and `y`: `rows`).
    /// Allocates nothing.
    pub fn matvec(
        &self,
        x: &[f32],
        bias: Option<&[f32]>,
        y: &mut [f32],
        par: Parallelism,
    ) -> Result<()> {
        self.matmul_t(x, 1, bias, y, par)
    }

    /// `ys_t[i·B + b] = (W x_b)_i + bias_i` for `B = batch` input vectors that share one pass
    /// over the weights.
    ///
    /// # Shapes
    /// - `xs`: `[batch, cols]` row-major (input vector `b` at `xs[b·cols..]`),
    /// - `bias`: `[rows]`,
    /// - `ys_t`: `[rows, batch]` row-major — output row `i` of every input at
    ///   `ys_t[i·batch..(i+1)·batch]`. With `batch = 1` this is simply `y`.
    ///
    /// Each column of `ys_t` is bitwise equal to [`Matrix::matvec`] of that input, for every
    /// precision and [`Parallelism`]. Allocates nothing.
    pub fn matmul_t(
        &self,
        xs: &[f32],
        batch: usize,
        bias: Option<&[f32]>,
        ys_t: &mut [f32],
        par: Parallelism,
    ) -> Result<()> {
        if batch == 0 {
            return Err(Error::invalid("batch", "must be at least 1"));
        }
        check_len("matrix input", xs.len(), batch * self.cols)?;
        check_len("matrix output", ys_t.len(), batch * self.rows)?;
        if let Some(b) = bias {
            check_len("matrix bias", b.len(), self.rows)?;
        }
        if self.rows == 0 {
            return Ok(());
        }
        let isa = Isa::best();
        self.run_rows(isa, xs, batch, bias, ys_t, par);
        Ok(())
    }

    /// Whether a product of `batch` inputs under `par` is split across threads (rows per task,
    /// or `None` on the calling thread).
    fn task_rows(&self, batch: usize, par: Parallelism) -> Option<usize> {
        let align = match self.layout {
            Layout::Panels => PANEL,
            Layout::Quads => QUAD_PANEL,
            Layout::Interleaved => IL_ROWS,
            Layout::RowMajor => 1,
        };
        // The integer kernels' products are worth splitting only from eight times the size:
        // the shipped model's int8 step (GRU 256, PCA 64: products of 10–20 µs) took 0.048 ms
        // on one thread and 0.065–0.069 on two with the lane kernels' threshold (the hand-off
        // cost more than the half product it saved), 0.050 with this one (`cargo xtask bench
        // runtime --anchors`, 2-core Intel Xeon VM).
        let integer = self.layout == Layout::Quads
            || matches!(self.storage, Storage::Int8 { .. })
                && self.layout != Layout::Panels
                && int8::applies(self.cols);
        let work = if integer {
            self.cols.div_ceil(INT8_SPEEDUP)
        } else {
            self.cols
        };
        rows_per_task(par, self.rows, work, batch, align)
    }

    /// Whether a product of `batch` inputs under `par` runs on more than one thread.
    pub(crate) fn splits(&self, batch: usize, par: Parallelism) -> bool {
        self.task_rows(batch, par).is_some()
    }

    /// Split the output rows into blocks (each computed by one thread) and run the kernel.
    pub(crate) fn run_rows(
        &self,
        isa: Isa,
        xs: &[f32],
        batch: usize,
        bias: Option<&[f32]>,
        ys_t: &mut [f32],
        par: Parallelism,
    ) {
        let cols = self.cols;
        let panels = self.layout == Layout::Panels;
        let quads = self.layout == Layout::Quads;
        let il = self.layout == Layout::Interleaved;
        let task = |r0: usize, ys: &mut [f32]| {
            let r1 = r0 + ys.len() / batch;
            let b = bias.map(|b| &b[r0..r1]);
            // Panels: whole panels from `r0` (a multiple of PANEL) to past `r1`; interleaved,
            // of rows padded to whole chunks.
            let span = if panels {
                r0 * cols..r1.next_multiple_of(PANEL) * cols
            } else if il {
                let stored = padded_cols(cols);
                r0 * stored..r1.next_multiple_of(IL_ROWS) * stored
            } else {
                r0 * cols..r1 * cols
            };
            if let (Storage::Int8 { q, scales }, true) = (&self.storage, quads) {
                // Whole quad panels from `r0` (a multiple of QUAD_PANEL) to past `r1`.
                let per_row = int8::quad_row_bytes(cols);
                let span = r0 * per_row..r1.next_multiple_of(QUAD_PANEL) * per_row;
                let s = Some(&scales[r0..r1]);
                quads_i8(isa, &q[span], cols, xs, batch, s, b, ys);
                return;
            }
            match (&self.storage, panels) {
                (Storage::F32(w), false) if il => {
                    interleaved_f32(isa, &w[span], cols, xs, batch, None, b, ys)
                }
                (Storage::F16(w), false) if il => {
                    interleaved_f16(isa, &w[span], cols, xs, batch, None, b, ys)
                }
                (Storage::F32(w), false) => rows_f32(isa, &w[span], cols, xs, batch, None, b, ys),
                (Storage::F32(w), true) => panels_f32(isa, &w[span], cols, xs, batch, None, b, ys),
                (Storage::F16(w), false) => rows_f16(isa, &w[span], cols, xs, batch, None, b, ys),
                (Storage::Int8 { q, scales }, false) => {
                    let s = Some(&scales[r0..r1]);
                    rows_i8(isa, &q[span], cols, xs, batch, s, b, ys)
                }
                (_, true) => unreachable!("panels hold f32 weights only"),
            }
        };
        match self.task_rows(batch, par) {
            None => task(0, ys_t),
            Some(block) => ys_t
                .par_chunks_mut(block * batch)
                .enumerate()
                .for_each(|(k, ys)| task(k * block, ys)),
        }
    }
}

/// int8 rows whose largest weight magnitude is below this are stored as zeros.
pub const INT8_ZERO_ROW: f32 = 1.0e-30;

/// Symmetric int8 quantisation of one row: `scale = max|row| / 127`, `q = round(w / scale)`
/// clamped to ±127. A row whose largest magnitude is below [`INT8_ZERO_ROW`] is stored as
/// zeros with scale 0 (its scale would be subnormal). Returns the scale.
fn quantize_row(row: &[f32], q: &mut [i8]) -> f32 {
    let max_abs = row.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    if max_abs < INT8_ZERO_ROW {
        q.fill(0);
        return 0.0;
    }
    let scale = max_abs / 127.0;
    for (qv, &w) in q.iter_mut().zip(row) {
        // In range by the clamp; `as` is exact for integers in [-127, 127].
        *qv = (w / scale).round().clamp(-127.0, 127.0) as i8;
    }
    scale
}

/// A dense layer `y = W x + b` (weights in any [`Precision`], bias f32).
#[derive(Clone, Debug, PartialEq)]
pub struct Linear {
    weight: Matrix,
    bias: Vec<f32>,
}

impl Linear {
    /// Check that `bias` has one finite value per row of `weight`.
    pub fn new(weight: Matrix, bias: Vec<f32>) -> Result<Self> {
        check_len("linear bias", bias.len(), weight.rows())?;
        crate::error::check_finite("linear bias", &bias)?;
        Ok(Self { weight, bias })
    }

    /// The weight matrix.
    pub fn weight(&self) -> &Matrix {
        &self.weight
    }

    /// The bias.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }

    /// Input size.
    pub fn n_in(&self) -> usize {
        self.weight.cols()
    }

    /// Output size.
    pub fn n_out(&self) -> usize {
        self.weight.rows()
    }

    /// Whether its product of `batch` inputs under `par` runs on more than one thread.
    pub(crate) fn splits(&self, batch: usize, par: Parallelism) -> bool {
        self.weight.splits(batch, par)
    }

    /// `y = W x + b` (see [`Matrix::matvec`]).
    pub fn forward(&self, x: &[f32], y: &mut [f32], par: Parallelism) -> Result<()> {
        self.weight.matvec(x, Some(&self.bias), y, par)
    }

    /// `ys_t[i·B + b] = (W x_b + b)_i` (see [`Matrix::matmul_t`] for the layouts).
    pub fn forward_batch_t(
        &self,
        xs: &[f32],
        batch: usize,
        ys_t: &mut [f32],
        par: Parallelism,
    ) -> Result<()> {
        self.weight.matmul_t(xs, batch, Some(&self.bias), ys_t, par)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::rows::LANES;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const U: f64 = 1.0 / (1u64 << 24) as f64;

    fn gamma(k: usize) -> f64 {
        let k = k as f64;
        k * U / (1.0 - k * U)
    }

    fn chain(cols: usize) -> usize {
        cols.div_ceil(LANES) + 5
    }

    fn random(rng: &mut ChaCha8Rng, n: usize, amp: f32) -> Vec<f32> {
        (0..n).map(|_| rng.random_range(-amp..amp)).collect()
    }

    const SIZES: &[(usize, usize)] = &[
        (1, 1),
        (3, 7),
        (17, 31),
        (33, 33),
        (65, 129),
        (40, 255),
        (31, 1000),
        (9, 1501),
        (5, 4099),
    ];

    /// Per-element check of the documented bound; returns (max |err| / (Σ|wx| + |b|),
    /// ‖ŷ − y‖ / ‖y‖).
    fn check_precision(precision: Precision, seed: u64) -> (f64, f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mut worst_rel, mut err2, mut ref2) = (0.0f64, 0.0f64, 0.0f64);
        for &(rows, cols) in SIZES {
            let mut w = random(&mut rng, rows * cols, 1.0);
            // A few tiny weights exercise f16 subnormals and int8 rounding to zero.
            for v in w.iter_mut().step_by(7) {
                *v *= 1.0e-6;
            }
            let x = random(&mut rng, cols, 3.0);
            let bias = random(&mut rng, rows, 0.5);
            let m = Matrix::from_f32(rows, cols, w.clone(), precision).expect("finite");
            let stored = m.to_f32();
            let mut y = vec![0.0f32; rows];
            m.matvec(&x, Some(&bias), &mut y, Parallelism::Sequential)
                .expect("sizes");
            for i in 0..rows {
                let row = &w[i * cols..(i + 1) * cols];
                let srow = &stored[i * cols..(i + 1) * cols];
                let exact: f64 = row
                    .iter()
                    .zip(&x)
                    .map(|(&a, &b)| a as f64 * b as f64)
                    .sum::<f64>()
                    + bias[i] as f64;
                let abs_wx: f64 = row
                    .iter()
                    .zip(&x)
                    .map(|(&a, &b)| (a as f64 * b as f64).abs())
                    .sum();
                let abs_swx: f64 = srow
                    .iter()
                    .zip(&x)
                    .map(|(&a, &b)| (a as f64 * b as f64).abs())
                    .sum();
                let abs_x: f64 = x.iter().map(|&v| (v as f64).abs()).sum();
                let abs_b = (bias[i] as f64).abs();
                let k = chain(cols);
                let bound = match precision {
                    Precision::F32 => gamma(k + 2) * (abs_wx + abs_b),
                    Precision::F16 => {
                        let store: f64 = row
                            .iter()
                            .zip(&x)
                            .map(|(&a, &b)| {
                                ((a as f64).abs() / 2048.0 + 2f64.powi(-25)) * (b as f64).abs()
                            })
                            .sum();
                        store + gamma(k + 2) * (abs_swx + abs_b)
                    }
                    Precision::Int8 if super::super::int8::applies(cols) => {
                        let s = m.int8_scales().expect("int8")[i] as f64;
                        let limit = super::super::int8::input_limit(cols);
                        let max_x = x.iter().fold(0.0f32, |a, v| a.max(v.abs()));
                        let t = f64::from(max_x / limit as f32);
                        let (l, t) = (f64::from(limit), t);
                        // Σ_j |ŵ_ij x̂_j| ≤ Σ_j |ŵ_ij| (|x_j| + t (1/2 + 2Lu)).
                        let move_x = t * (0.5 + 2.0 * l * U);
                        let abs_sw: f64 = srow.iter().map(|&a| f64::from(a).abs()).sum();
                        s * (0.5 + 127.0 * U) * abs_x
                            + move_x * abs_sw
                            + gamma(4) * (abs_swx + move_x * abs_sw + abs_b)
                    }
                    Precision::Int8 => {
                        let s = m.int8_scales().expect("int8")[i] as f64;
                        s * (0.5 + 127.0 * U) * abs_x + gamma(k + 3) * (abs_swx + abs_b)
                    }
                };
                let err = (y[i] as f64 - exact).abs();
                assert!(
                    err <= bound,
                    "{precision:?} {rows}x{cols} row {i}: error {err:e} > bound {bound:e}"
                );
                worst_rel = worst_rel.max(err / (abs_wx + abs_b));
                if cols >= 255 {
                    err2 += err * err;
                    ref2 += exact * exact;
                }
            }
        }
        (worst_rel, (err2 / ref2).sqrt())
    }

    #[test]
    fn f32_matvec_within_bound_and_1e_5() {
        let (worst, _) = check_precision(Precision::F32, 1);
        assert!(worst <= 1e-5, "worst relative error {worst:e}");
    }

    #[test]
    fn f16_matvec_within_documented_bound() {
        check_precision(Precision::F16, 2);
    }

    #[test]
    fn int8_matvec_within_documented_bound() {
        check_precision(Precision::Int8, 3);
    }

    /// Typical errors for the documentation (run with `--nocapture` to see them).
    #[test]
    fn measured_relative_errors() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (rows, cols) = (512, 1500);
        // Gaussian-like weights (sum of uniforms) and inputs in [-1, 1] like GRU states.
        let w: Vec<f32> = (0..rows * cols)
            .map(|_| (0..4).map(|_| rng.random_range(-1.0f32..1.0)).sum::<f32>() * 0.05)
            .collect();
        let x = random(&mut rng, cols, 1.0);
        let exact: Vec<f64> = w
            .chunks_exact(cols)
            .map(|r| r.iter().zip(&x).map(|(&a, &b)| a as f64 * b as f64).sum())
            .collect();
        let norm: f64 = exact.iter().map(|v| v * v).sum::<f64>().sqrt();
        for precision in [Precision::F32, Precision::F16, Precision::Int8] {
            let m = Matrix::from_f32(rows, cols, w.clone(), precision).expect("finite");
            let mut y = vec![0.0f32; rows];
            m.matvec(&x, None, &mut y, Parallelism::Sequential)
                .expect("sizes");
            let err: f64 = y
                .iter()
                .zip(&exact)
                .map(|(&a, &b)| (a as f64 - b).powi(2))
                .sum::<f64>()
                .sqrt();
            let rel = err / norm;
            eprintln!(
                "{}: ‖ŷ − y‖/‖y‖ = {rel:.3e} ({rows}×{cols})",
                precision.name()
            );
            let limit = match precision {
                Precision::F32 => 1e-6,
                Precision::F16 => 1e-3,
                Precision::Int8 => 2e-2,
            };
            assert!(rel < limit, "{precision:?}: {rel:e}");
        }
    }

    #[test]
    fn int8_quantisation_error_per_weight() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (rows, cols) = (13, 77);
        let mut w = random(&mut rng, rows * cols, 2.0);
        w[cols..2 * cols].fill(0.0); // an all-zero row
        let m = Matrix::from_f32(rows, cols, w.clone(), Precision::Int8).expect("finite");
        let stored = m.to_f32();
        let scales = m.int8_scales().expect("int8");
        assert_eq!(scales[1], 0.0);
        for i in 0..rows {
            for j in 0..cols {
                let e = (w[i * cols + j] - stored[i * cols + j]).abs() as f64;
                assert!(e <= scales[i] as f64 * (0.5 + 127.0 * U) + 1e-30);
            }
        }
        assert_eq!(m.weight_bytes(), rows * cols + 4 * rows);
    }

    #[test]
    fn f16_rejects_values_out_of_range() {
        let err = Matrix::from_f32(1, 2, vec![1.0, 70_000.0], Precision::F16).unwrap_err();
        assert!(err.to_string().contains("f16"), "{err}");
        assert!(Matrix::from_f32(1, 2, vec![1.0, f32::NAN], Precision::F32).is_err());
        assert!(Matrix::from_f32(2, 2, vec![1.0; 3], Precision::F32).is_err());
    }

    #[test]
    fn batched_and_parallel_equal_single_sequential_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("pool");
        for &(rows, cols) in &[
            (1, 5),
            (37, 45),
            (301, 257),
            (130, 1031),
            (700, 1031),
            (50, 1500),
            // Long rows in more than one block of the single-vector path's eight streams, the
            // last one partial.
            (2 * super::super::rows::SPREAD_ROWS + 43, 520),
        ] {
            for precision in [Precision::F32, Precision::F16, Precision::Int8] {
                let m = Matrix::from_f32(rows, cols, random(&mut rng, rows * cols, 1.0), precision)
                    .expect("finite");
                let bias = random(&mut rng, rows, 1.0);
                for batch in [1, 2, 8, 11] {
                    let xs = random(&mut rng, batch * cols, 1.0);
                    let mut seq = vec![0.0; rows * batch];
                    m.matmul_t(&xs, batch, Some(&bias), &mut seq, Parallelism::Sequential)
                        .expect("sizes");
                    let mut par = vec![0.0; rows * batch];
                    pool.install(|| {
                        m.matmul_t(&xs, batch, Some(&bias), &mut par, Parallelism::Rayon)
                            .expect("sizes")
                    });
                    for b in 0..batch {
                        let mut single = vec![0.0; rows];
                        m.matvec(
                            &xs[b * cols..(b + 1) * cols],
                            Some(&bias),
                            &mut single,
                            Parallelism::Sequential,
                        )
                        .expect("sizes");
                        for i in 0..rows {
                            assert_eq!(single[i].to_bits(), seq[i * batch + b].to_bits());
                            assert_eq!(single[i].to_bits(), par[i * batch + b].to_bits());
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn size_mismatches_are_errors() {
        let m = Matrix::from_f32(2, 3, vec![0.5; 6], Precision::F32).expect("finite");
        let mut y = [0.0; 2];
        assert!(
            m.matvec(&[1.0; 2], None, &mut y, Parallelism::Sequential)
                .is_err()
        );
        assert!(
            m.matvec(&[1.0; 3], Some(&[0.0]), &mut y, Parallelism::Sequential)
                .is_err()
        );
        assert!(
            m.matvec(&[1.0; 3], None, &mut [0.0; 3], Parallelism::Sequential)
                .is_err()
        );
        assert!(
            m.matmul_t(&[1.0; 3], 0, None, &mut [], Parallelism::Sequential)
                .is_err()
        );
        m.matvec(
            &[1.0; 3],
            Some(&[0.0, 1.0]),
            &mut y,
            Parallelism::Sequential,
        )
        .expect("sizes");
        assert_eq!(y, [1.5, 2.5]);
    }

    /// `a` and `b` give the same bits for `xs` (`batch` inputs) under every instruction set,
    /// on the calling thread without a bias and on rayon's pool with `bias`; `a`'s outputs of
    /// each run are returned (`what` names the case in a failure).
    fn same_bits_everywhere(
        a: &Matrix,
        b: &Matrix,
        xs: &[f32],
        batch: usize,
        bias: &[f32],
        what: &str,
    ) -> Vec<Vec<u32>> {
        use crate::kernels::dispatch::Isa;
        let mut outputs = Vec::new();
        for &isa in &Isa::available() {
            for (bias, par) in [
                (None, Parallelism::Sequential),
                (Some(bias), Parallelism::Rayon),
            ] {
                let run = |m: &Matrix| {
                    let mut y = vec![f32::NAN; m.rows() * batch];
                    m.run_rows(isa, xs, batch, bias, &mut y, par);
                    y.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
                };
                let got = run(a);
                let bias = bias.is_some();
                assert_eq!(
                    got,
                    run(b),
                    "{what} batch {batch} {} bias {bias}",
                    isa.name()
                );
                outputs.push(got);
            }
        }
        outputs
    }

    #[test]
    fn int8_quad_panels_equal_the_row_kernels_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(29);
        // Widths of every remainder modulo 4 (a partial last quad), a partial last panel, the
        // shipped model's products (GRU input 88 and state 256, PCA 64) and the widest rows
        // stored so.
        let sizes = [
            (16, 1),
            (17, 3),
            (16, 4),
            (33, 8),
            (40, 16),
            (6_504, 16),
            (16, 18),
            (19, 19),
            (16, 17),
            (17, 31),
            (40, 64),
            (33, 88),
            (100, 256),
            (21, 511),
            (6_504, 64),
        ];
        for (rows, cols) in sizes {
            assert!(int8::quads_apply(rows, cols), "{rows} × {cols}");
            let mut w = random(&mut rng, rows * cols, 1.0);
            // A zero row (stored with scale 0).
            w[cols..2 * cols].fill(0.0);
            // The extremes of the integer contract: a row of the largest weights (all ±127
            // after quantisation) meets an input whose largest values quantise to ±L.
            for (c, v) in w[2 * cols..3 * cols].iter_mut().enumerate() {
                *v = if c % 3 == 0 { -1.0 } else { 1.0 };
            }
            let quads = Matrix::with_layout(rows, cols, w.clone(), Precision::Int8, Layout::Quads)
                .expect("finite");
            let plain =
                Matrix::with_layout(rows, cols, w.clone(), Precision::Int8, Layout::RowMajor)
                    .expect("finite");
            assert_eq!(
                Matrix::from_f32(rows, cols, w, Precision::Int8).expect("finite"),
                quads
            );
            assert_eq!(quads.to_f32(), plain.to_f32());
            assert!(quads.weight_bytes() >= plain.weight_bytes());
            for batch in [1, 3, 17] {
                let mut xs = random(&mut rng, batch * cols, 2.0);
                // Input 0 at the extremes: ±2 against the row of ±127 (every product ±127 · L,
                // the row's sum as far from zero as the signs allow).
                for (c, x) in xs[..cols].iter_mut().enumerate() {
                    *x = if c % 3 == 0 { -2.0 } else { 2.0 };
                }
                if batch > 1 {
                    // An input that is not finite (every row NaN), and one of zeros.
                    xs[cols + 5 % cols] = f32::NAN;
                    xs[2 * cols..3 * cols].fill(0.0);
                }
                let bias = random(&mut rng, rows, 0.5);
                let what = format!("{rows} × {cols}");
                for got in same_bits_everywhere(&quads, &plain, &xs, batch, &bias, &what) {
                    if batch > 1 {
                        assert!(
                            got.iter()
                                .skip(1)
                                .step_by(batch)
                                .all(|&v| f32::from_bits(v).is_nan())
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn interleaved_rows_equal_the_row_kernels_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        // Whole chunks only, a partial last chunk of every kind, rows left over after the
        // panels (for the four-row groups and `dot`), more than one block of panels, the
        // paper's hidden size and rows wider than a batched tile.
        let sizes = [
            (8, 512),
            (17, 520),
            (12, 531),
            (31, 1500),
            (2 * crate::kernels::rows::SPREAD_ROWS + 21, 544),
            (9, 1057),
        ];
        for (rows, cols) in sizes {
            let mut w = random(&mut rng, rows * cols, 1.0);
            // Zeros of both signs and products that underflow, as for the panels.
            for (k, v) in w.iter_mut().enumerate() {
                match k % 13 {
                    0 => *v = -0.0,
                    1 => *v *= 1.0e-30,
                    _ => {}
                }
            }
            for precision in [Precision::F32, Precision::F16] {
                let il = Matrix::with_layout(rows, cols, w.clone(), precision, Layout::Interleaved)
                    .expect("finite");
                let plain = Matrix::with_layout(rows, cols, w.clone(), precision, Layout::RowMajor)
                    .expect("finite");
                assert_eq!(il.to_f32(), plain.to_f32());
                // Padded to whole panels of rows of whole chunks.
                let elem = plain.weight_bytes() / (rows * cols);
                assert_eq!(
                    il.weight_bytes(),
                    elem * rows.next_multiple_of(8) * cols.next_multiple_of(32)
                );
                for batch in [1, 2, 9] {
                    let mut xs = random(&mut rng, batch * cols, 2.0);
                    xs[1] = -0.0;
                    if batch > 1 {
                        // An input that is not finite.
                        xs[cols + 7] = f32::NAN;
                    }
                    let bias = random(&mut rng, rows, 0.5);
                    let what = format!("{rows} × {cols} {}", precision.name());
                    same_bits_everywhere(&il, &plain, &xs, batch, &bias, &what);
                }
            }
        }
        assert!(
            Matrix::with_layout(
                8,
                512,
                vec![0.5; 8 * 512],
                Precision::Int8,
                Layout::Interleaved
            )
            .is_err()
        );
        // Rows of 512 columns or more from 8 rows on are stored interleaved in f32 and f16
        // where `interleave_long_rows` says; narrower rows, fewer rows and int8 are not.
        let long = if interleave_long_rows() {
            Layout::Interleaved
        } else {
            Layout::RowMajor
        };
        for (rows, cols, precision, want) in [
            (13_272, 1_500, Precision::F32, long),
            (4_500, 1_500, Precision::F16, long),
            (8, 512, Precision::F32, long),
            (7, 4_099, Precision::F32, Layout::RowMajor),
            (13_272, 1_500, Precision::Int8, Layout::RowMajor),
            (40_000, 511, Precision::F32, Layout::RowMajor),
        ] {
            assert_eq!(
                Layout::for_shape(rows, cols, precision),
                want,
                "{rows} × {cols}"
            );
        }
    }

    #[test]
    fn thin_matrices_in_panels_equal_the_row_kernels_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let sizes = [
            (8, 1),
            (9, 3),
            (17, 4),
            (40, 8),
            (23, 16),
            (31, 31),
            (64, 32),
            (19, 33),
            (33, 47),
            (16, 64),
            (12_630, 64),
        ];
        for (rows, cols) in sizes {
            let mut w = random(&mut rng, rows * cols, 1.0);
            // Zeros of both signs, and products that underflow to −0.0: the lane rule's sums
            // are +0.0 there, which the panels must reproduce.
            for (k, v) in w.iter_mut().enumerate() {
                match k % 11 {
                    0 => *v = -0.0,
                    1 => *v = 0.0,
                    2 => *v *= 1.0e-30,
                    _ => {}
                }
            }
            // One row of nothing but −0.0 (int8: the zero row).
            w[cols..2 * cols].fill(-0.0);
            // int8: no panels; rows multiply integers at every width, in quad panels from 16
            // rows on (`int8_quad_panels_equal_the_row_kernels_bitwise`).
            let chosen = Matrix::from_f32(rows, cols, w.clone(), Precision::Int8).expect("finite");
            let want = if int8::quads_apply(rows, cols) {
                Layout::Quads
            } else {
                Layout::RowMajor
            };
            assert_eq!(chosen.layout, want, "{rows} × {cols} int8");
            // f16: no panels either (slower than its rows at every width, `panels.rs`).
            for precision in [Precision::Int8, Precision::F16] {
                assert!(
                    Matrix::with_layout(rows, cols, w.clone(), precision, Layout::Panels).is_err()
                );
            }
            if cols < EIGHT_ROWS_FROM {
                let f16 = Matrix::from_f32(rows, cols, w.clone(), Precision::F16).expect("finite");
                assert_eq!(f16.layout, Layout::RowMajor, "{rows} × {cols} f16");
            }
            {
                let precision = Precision::F32;
                // Panels for every width (the kernel takes any), not only those `from_f32`
                // stores so.
                let thin = Matrix::with_layout(rows, cols, w.clone(), precision, Layout::Panels)
                    .expect("finite");
                let plain = Matrix::with_layout(rows, cols, w.clone(), precision, Layout::RowMajor)
                    .expect("finite");
                let chosen = Matrix::from_f32(rows, cols, w.clone(), precision).expect("finite");
                if cols <= THIN_COLS {
                    assert_eq!(&chosen, &thin, "{rows} × {cols}: the layout by width");
                } else if cols < EIGHT_ROWS_FROM {
                    assert_eq!(&chosen, &plain, "{rows} × {cols}: the layout by width");
                }
                assert_eq!(thin.to_f32(), plain.to_f32());
                for batch in [1, 2, 5] {
                    let mut xs = random(&mut rng, batch * cols, 2.0);
                    xs[0] = -0.0;
                    for x in xs.iter_mut().skip(3).step_by(7) {
                        *x *= 1.0e-20;
                    }
                    let bias = random(&mut rng, rows, 0.5);
                    let what = format!("{rows} × {cols} {}", precision.name());
                    same_bits_everywhere(&thin, &plain, &xs, batch, &bias, &what);
                }
            }
        }
    }
}
