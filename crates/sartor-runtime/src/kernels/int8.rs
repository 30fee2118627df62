//! int8 rows times inputs quantised to 16 bits: integer dot products.
//!
//! The lane kernels of `rows.rs` convert each int8 weight to f32 before a multiply and an add:
//! four instructions per 16 weights on AVX-512, which made the paper-size 13,272 × 1,500
//! product bound by instructions (1.42 ms, 14 GMAC/s, while streaming its 19.9 MB takes about
//! 0.9 ms; `cargo bench -p sartor-runtime --bench kernels -- matvec`). Here an
//! input vector is quantised once per product to integers `x_q` with one step `t` (symmetric,
//! `t = max_j |x_j| / L`, `x_q = round_ties_even(x / t)` clamped to ±`L`), and every row is one
//! exact integer sum `S_i = Σ_j q_ij · x_q,j`: on x86-64 two instructions per 16 (AVX2) or 32
//! (AVX-512) weights (`vpmovsxbw`, `vpmaddwd`) and an integer add, or with AVX-512 VNNI the
//! widening and one `vpdpwssd` (multiply, pair and add in one instruction, the same wrapping
//! sums): a batch of eight inputs on the paper-size 13,272 × 1,500 product, which meets each
//! row from cache, 8.08 → 6.78 ms on the 2-core Intel Xeon VM (faster in 4 of 4 alternating
//! rounds; one input, read from memory, 1.16 → 1.12). A row's columns past its last whole
//! vector are one more step: masked loads on AVX-512, on AVX2 the row's and the input's last
//! whole vector read again with the input's lanes already summed set to zero.
//!
//! **Arithmetic contract.** `L = min(32,767, ⌊(2³¹ − 1) / (127 · n)⌋)` for rows of `n` columns,
//! so that no partial sum can leave `i32` (`Σ|q x_q| ≤ 127 · n · L`): 16 bits up to 516
//! columns, 14 bits (±11,272) at 1,500. Integer sums are exact, so their order is free: every engine,
//! thread split and batch size gives the same `S_i`, and the output is then
//! `y_i = s_i · (f32(S_i) · t) + b_i` (the row's scale `s_i`, its bias `b_i`), in that order —
//! bitwise the same on every instruction set, on one or many threads, alone or in a batch.
//! An input with a value that is not finite gives NaN for every row (the lane kernels would
//! give NaN or ±∞); an input whose largest magnitude is below `L ·` [`f32::MIN_POSITIVE`]
//! (about 1e-34) is taken as zero.
//!
//! **Error.** Beyond the weights' own rounding (`matrix.rs`), each input value moves by at most
//! `t · (1/2 + 2 L u)` (`u = 2⁻²⁴`): about `4.4e-5 · max|x|` at 1,500 columns (`1.5e-5` up to
//! 516), some ninety times less than an int8 weight moves relative to its row's largest
//! (`1/254`), and the final conversions and products add `γ₄` of the result. `matrix.rs`
//! states the bound its tests assert.
//!
//! Used for int8 rows of 1 to [`MAX_COLS`] columns (the quantised input lives on the stack);
//! wider int8 matrices keep the lane kernels. Until 2026-12-02 int8 matrices of at most 16
//! columns (a PCA basis at a low rank) were stored in the lane kernels' panels instead, which made a 6,504 × 16 PCA decode take 23 µs against 2.8 for
//! 6,504 × 32 in quad panels.

/// The widest rows the integer kernels take (the quantised input is a stack array).
pub(crate) const MAX_COLS: usize = 2048;
/// The narrowest rows the integer kernels take: every int8 row of at most [`MAX_COLS`].
pub(crate) const MIN_COLS: usize = 1;

/// Whether int8 rows of `cols` columns use the integer kernels.
pub(crate) fn applies(cols: usize) -> bool {
    (MIN_COLS..=MAX_COLS).contains(&cols)
}

/// The largest `|x_q|` for rows of `cols` columns (see the module docs).
pub(crate) fn input_limit(cols: usize) -> i32 {
    let per_column = 127 * (cols.max(1) as i64);
    (i64::from(i32::MAX) / per_column).min(i64::from(i16::MAX)) as i32
}

/// Quantise `x` into `out` (the same length): the step `t`, `Some(0.0)` for an input taken as
/// zero, `None` when a value is not finite.
#[inline(always)]
pub(crate) fn quantize_input(x: &[f32], out: &mut [i16]) -> Option<f32> {
    // The largest magnitude as bits: for non-negative floats the order of the bits is the order
    // of the values, and NaN and ±∞ lie above `f32::MAX`. An integer maximum vectorises; the
    // float one (`f32::max`, with its NaN rule) ran one value at a time: a tenth of the shipped
    // model's int8 products. Inlined so that the kernels' wrappers compile it (and its
    // rounding) with their instruction set.
    let largest = x
        .iter()
        .map(|v| v.to_bits() & 0x7fff_ffff)
        .max()
        .unwrap_or(0);
    if largest > f32::MAX.to_bits() {
        return None;
    }
    let max_abs = f32::from_bits(largest);
    let limit = input_limit(x.len()) as f32;
    let step = max_abs / limit;
    if step < f32::MIN_POSITIVE {
        out.fill(0);
        return Some(0.0);
    }
    for (q, &v) in out.iter_mut().zip(x) {
        // In range by the clamp; `as` is exact for integers within ±32,767.
        *q = (v / step).round_ties_even().clamp(-limit, limit) as i16;
    }
    Some(step)
}

/// Integer dot products of int8 rows with one quantised input. Sums are exact (the limit keeps
/// them within `i32`), so an engine may add in any order.
pub(crate) trait IntEngine {
    /// `Σ_j w_j · x_j` (both slices the same length).
    fn dot(w: &[i8], x: &[i16]) -> i32;
    /// [`IntEngine::dot`] of eight rows with one input (eight concurrent streams).
    fn dot8(w: [&[i8]; 8], x: &[i16]) -> [i32; 8] {
        w.map(|row| Self::dot(row, x))
    }
    /// [`IntEngine::dot8`] for rows read from memory, each a stream that runs on into the
    /// next row of its own: the SIMD engines prefetch ahead of each stream.
    fn dot8_far(w: [&[i8]; 8], x: &[i16]) -> [i32; 8] {
        Self::dot8(w, x)
    }
    /// [`IntEngine::dot8_far`] of the groups `g` of a matrix `w` (rows of `x.len()` values)
    /// read as eight streams `g.octs` rows apart: row `o + r·octs`'s sum goes to
    /// `sums[r·count + o − first]`.
    fn dot8_far_block(w: &[i8], x: &[i16], g: FarGroups, sums: &mut [i32]) {
        for (o, rows) in g.rows(w, x.len()) {
            for (r, sum) in Self::dot8_far(rows, x).into_iter().enumerate() {
                sums[g.at(o, r)] = sum;
            }
        }
    }
}

/// Groups `first .. first + count` of eight rows, group `o`'s rows `o + r·octs` (`r < 8`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct FarGroups {
    pub(crate) octs: usize,
    pub(crate) first: usize,
    pub(crate) count: usize,
}

impl FarGroups {
    /// Each group and its eight rows of `cols` values in `w`.
    #[inline(always)]
    pub(crate) fn rows(self, w: &[i8], cols: usize) -> impl Iterator<Item = (usize, [&[i8]; 8])> {
        (self.first..self.first + self.count).map(move |o| {
            let rows = std::array::from_fn(|r| {
                let i = o + r * self.octs;
                &w[i * cols..(i + 1) * cols]
            });
            (o, rows)
        })
    }

    /// Where row `r` of group `o`'s sum goes in a block's sums.
    #[inline(always)]
    pub(crate) fn at(self, o: usize, r: usize) -> usize {
        r * self.count + o - self.first
    }
}

/// The safe-Rust engine (LLVM vectorises it; on WebAssembly with `simd128` too).
pub(crate) struct PortableInt;

impl IntEngine for PortableInt {
    #[inline(always)]
    fn dot(w: &[i8], x: &[i16]) -> i32 {
        w.iter()
            .zip(x)
            .map(|(&a, &b)| i32::from(a) * i32::from(b))
            .sum()
    }
}

/// `y = s · (f32(S) · t) + b` (NaN for an input that was not finite; without scales `s` = 1,
/// an exact product).
#[inline(always)]
fn output(sum: i32, step: Option<f32>, scale: f32, bias: Option<f32>) -> f32 {
    let d = match step {
        Some(t) => scale * (sum as f32 * t),
        None => f32::NAN,
    };
    match bias {
        Some(b) => d + b,
        None => d,
    }
}

/// [`output`] for `N` rows side by side of one finite input (step `t`; row `r`'s scale
/// `scale(r)`, its bias `bias[r]`): the same arithmetic in the same order, so the same bits, in
/// a form the compiler vectorises.
#[inline(always)]
fn outputs<const N: usize>(
    sums: &[i32; N],
    t: f32,
    scale: impl Fn(usize) -> f32,
    bias: Option<&[f32; N]>,
    ys: &mut [f32; N],
) {
    let d: [f32; N] = std::array::from_fn(|r| scale(r) * (sums[r] as f32 * t));
    match bias {
        Some(b) => *ys = std::array::from_fn(|r| d[r] + b[r]),
        None => *ys = d,
    }
}

/// Rows from this many columns on are read eight streams apart (see `group`).
const STRIDED_FROM: usize = 512;
/// Quantised inputs a batch holds at once: 24 KB on the stack (eight inputs of 1,500).
const GROUP_BUFFER: usize = 6 * MAX_COLS;
/// At most this many inputs share one pass over the weights.
const MAX_GROUP: usize = 16;

/// int8 rows (`w`: `rows × cols` row-major, one scale per row) times `batch` inputs (`xs`:
/// `batch × cols`) into `ys_t` (`rows × batch`), by the integer contract of the module docs.
/// Each input is quantised once; eight rows at a time meet every input of a group (as many
/// as [`GROUP_BUFFER`] holds, at most [`MAX_GROUP`]), so that a batch streams the weights
/// from memory once per group rather than once per input. `cols` must satisfy [`applies`];
/// lengths are checked by the caller.
#[inline(always)]
pub(crate) fn rows_int<E: IntEngine>(
    w: &[i8],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    // The per-row scale resolved once (a lookup per output row cost 8 % on short rows).
    match scales {
        Some(s) => rows_scaled::<E>(w, cols, xs, batch, |i| s[i], bias, ys_t),
        None => rows_scaled::<E>(w, cols, xs, batch, |_| 1.0, bias, ys_t),
    }
}

/// [`rows_int`] with row `i`'s scale `scale(i)`.
#[inline(always)]
fn rows_scaled<E: IntEngine>(
    w: &[i8],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: impl Fn(usize) -> f32 + Copy,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    debug_assert!(applies(cols));
    if batch == 1 {
        let mut buffer = [0i16; MAX_COLS];
        let step = quantize_input(xs, &mut buffer[..cols]);
        group::<E>(w, cols, &buffer[..cols], &[step], scales, bias, ys_t, 1, 0);
        return;
    }
    let per_group = (GROUP_BUFFER / cols).clamp(1, MAX_GROUP);
    let mut buffer = [0i16; GROUP_BUFFER];
    for g0 in (0..batch).step_by(per_group) {
        let ng = per_group.min(batch - g0);
        let mut steps = [None; MAX_GROUP];
        for (k, step) in steps[..ng].iter_mut().enumerate() {
            let x = &xs[(g0 + k) * cols..(g0 + k + 1) * cols];
            *step = quantize_input(x, &mut buffer[k * cols..(k + 1) * cols]);
        }
        let xq = &buffer[..ng * cols];
        group::<E>(w, cols, xq, &steps[..ng], scales, bias, ys_t, batch, g0);
    }
}

/// Every row times the quantised inputs `xq` (`steps.len()` of them, `cols` each), written to
/// `ys_t[i·batch + first + k]`; eight rows at a time, an eighth of the rows apart from
/// [`STRIDED_FROM`] columns on (long rows come from memory), neighbours below.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn group<E: IntEngine>(
    w: &[i8],
    cols: usize,
    xq: &[i16],
    steps: &[Option<f32>],
    scales: impl Fn(usize) -> f32,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
    batch: usize,
    first: usize,
) {
    let n_rows = ys_t.len() / batch;
    let input = |k: usize| &xq[k * cols..(k + 1) * cols];
    let out = |i: usize, k: usize, sum: i32| output(sum, steps[k], scales(i), bias.map(|v| v[i]));
    let octs = n_rows / 8;
    if let ([Some(t)], 1) = (steps, batch)
        && cols < STRIDED_FROM
    {
        // One finite input, short rows (in cache): the eight outputs side by side, in vectors
        // where the compiler can, the arithmetic of `output` (so the same bits). With the eight
        // sums' tree of horizontal adds (`dispatch.rs`) the 6,504 × 64 product took 27.1 →
        // 20.4 µs, 6,504 × 32 23.6 → 16.5 (`cargo bench --bench kernels -- pca_basis`); this
        // loop's shape matters: with `step_by`, or the outputs computed before `ys` is taken,
        // 23–24 µs.
        let t = *t;
        for o in 0..octs {
            let i0 = 8 * o;
            let rows: [&[i8]; 8] =
                std::array::from_fn(|r| &w[(i0 + r) * cols..(i0 + r + 1) * cols]);
            let sums = E::dot8(rows, input(0));
            let ys: &mut [f32; 8] = (&mut ys_t[i0..i0 + 8]).try_into().expect("eight rows");
            outputs(
                &sums,
                t,
                |r| scales(i0 + r),
                bias.map(|b| (&b[i0..i0 + 8]).try_into().expect("a bias per row")),
                ys,
            );
        }
    } else {
        // Long rows come from memory: the eight rows an eighth of the block apart, each stream
        // running on through its own part of the weights, as in `rows.rs` but over the whole
        // block (its blocks of `SPREAD_ROWS` rows measured no faster here: 0.73–0.74 → 0.76 ms
        // on the AMD EPYC VM, where these weights sit in L3) (the paper-size GRU
        // + dense int8 step took 1.16–1.28 → 1.03–1.07 ms on one thread, 0.82–0.84 →
        // 0.66–0.73 on two; a batch of eight on two threads 3.65–3.69 → 3.37–3.43; alternating
        // builds, `cargo bench --bench kernels -- gru1500_out13272`). Several inputs, or one
        // not finite, take this loop too.
        let spread = cols >= STRIDED_FROM;
        if let ([_], 1, true) = (steps, batch, spread) {
            // One input: the groups' sums a block of groups at a time, the loop over the groups
            // inside the engine (as `rows.rs`' eight-row blocks; the paper-size 13,272 × 1,500
            // int8 product 284–306 → 256–265 µs on the AMD EPYC VM, the GRU + dense step
            // 455–461 → 420–438, alternating builds), then the outputs. Integer sums: the
            // same bits.
            const BLOCK: usize = 128;
            let mut sums = [0i32; 8 * BLOCK];
            for o0 in (0..octs).step_by(BLOCK) {
                let n = BLOCK.min(octs - o0);
                let g = FarGroups {
                    octs,
                    first: o0,
                    count: n,
                };
                E::dot8_far_block(w, input(0), g, &mut sums[..8 * n]);
                for (r, part) in sums[..8 * n].chunks_exact(n).enumerate() {
                    for (j, &sum) in part.iter().enumerate() {
                        let i = o0 + j + r * octs;
                        ys_t[i * batch + first] = out(i, 0, sum);
                    }
                }
            }
        } else {
            for o in 0..octs {
                let at = |r: usize| if spread { o + r * octs } else { 8 * o + r };
                let rows: [&[i8]; 8] =
                    std::array::from_fn(|r| &w[at(r) * cols..(at(r) + 1) * cols]);
                for k in 0..steps.len() {
                    let sums = if spread {
                        E::dot8_far(rows, input(k))
                    } else {
                        E::dot8(rows, input(k))
                    };
                    for (r, &sum) in sums.iter().enumerate() {
                        ys_t[at(r) * batch + first + k] = out(at(r), k, sum);
                    }
                }
            }
        }
    }
    for i in 8 * octs..n_rows {
        let row = &w[i * cols..(i + 1) * cols];
        for k in 0..steps.len() {
            ys_t[i * batch + first + k] = out(i, k, E::dot(row, input(k)));
        }
    }
}

/// Rows per quad panel (one 512-bit vector of 32-bit sums).
pub(crate) const QUAD_PANEL: usize = 16;
/// Whole quad panels of one input of a batch computed into a buffer at a time ([`quads_int`]).
const BATCH_PANELS: usize = 32;
/// Columns per quad: four 16-bit inputs fill one 64-bit word, which broadcast against a row's
/// four weights widened to 16 bits gives the row two half sums (`vpmaddwd`).
pub(crate) const QUAD: usize = 4;
/// Bytes of one quad of a panel: [`QUAD`] weights of each of its [`QUAD_PANEL`] rows.
pub(crate) const QUAD_BYTES: usize = QUAD * QUAD_PANEL;

/// Whether int8 rows of this shape are stored in quad panels ([`quads_int`]): rows the integer
/// kernels take ([`applies`]) shorter than [`STRIDED_FROM`] (read from cache, not memory), at
/// least [`QUAD_PANEL`] of them.
pub(crate) fn quads_apply(rows: usize, cols: usize) -> bool {
    applies(cols) && cols < STRIDED_FROM && rows >= QUAD_PANEL
}

/// Bytes a row of `cols` columns takes in quad panels: its quads and its share of the panel's
/// row sums (one more quad's worth).
pub(crate) fn quad_row_bytes(cols: usize) -> usize {
    (cols.div_ceil(QUAD) + 1) * QUAD
}

/// Row-major int8 `rows × cols` → quad panels: [`QUAD_PANEL`] rows per panel, and within a
/// panel the column quads `(4j … 4j + 3)` one after another, each holding the quad of every row
/// of the panel (64 bytes: row 0's four weights, row 1's, …). Element `(i, c)` goes to
/// `((i / 16 · (Q + 1) + c / 4) · 16 + i % 16) · 4 + c % 4` with `Q = ⌈cols / 4⌉` quads; the
/// last panel's missing rows and the last quad's missing columns are zero. After its `Q` quads
/// each panel holds one more [`QUAD_BYTES`]: its 16 rows' weight sums `Σ_c q_rc` as
/// little-endian `i32` (the VNNI engine's offset; see `dispatch.rs`).
pub(crate) fn to_quad_panels(q: &[i8], rows: usize, cols: usize) -> Vec<i8> {
    let quads = cols.div_ceil(QUAD);
    let mut out = vec![0i8; rows.div_ceil(QUAD_PANEL) * (quads + 1) * QUAD_BYTES];
    for (i, row) in q.chunks_exact(cols.max(1)).take(rows).enumerate() {
        for (c, &v) in row.iter().enumerate() {
            out[quad_index(i, c, quads)] = v;
        }
        let sum: i32 = row.iter().map(|&v| i32::from(v)).sum();
        let at = ((i / QUAD_PANEL * (quads + 1) + quads) * QUAD_PANEL + i % QUAD_PANEL) * QUAD;
        for (o, b) in out[at..at + QUAD].iter_mut().zip(sum.to_le_bytes()) {
            *o = b as i8;
        }
    }
    out
}

/// The inverse of [`to_quad_panels`]: row-major `rows × cols`.
pub(crate) fn from_quad_panels(p: &[i8], rows: usize, cols: usize) -> Vec<i8> {
    let quads = cols.div_ceil(QUAD);
    let mut out = vec![0i8; rows * cols];
    for i in 0..rows {
        for c in 0..cols {
            out[i * cols + c] = p[quad_index(i, c, quads)];
        }
    }
    out
}

fn quad_index(i: usize, c: usize, quads: usize) -> usize {
    (((i / QUAD_PANEL) * (quads + 1) + c / QUAD) * QUAD_PANEL + i % QUAD_PANEL) * QUAD + c % QUAD
}

/// The sums of one quad panel: `q` its quads ([`QUAD_BYTES`] each) and then its row sums
/// ([`to_quad_panels`]), `words[j]` quad `j`'s inputs `4j … 4j + 3` in the engine's form
/// ([`QuadEngine::word`]); returns `S_r = Σ_c q_rc · x_q,c` for its 16 rows. Sums are exact,
/// so an engine may add in any order.
pub(crate) trait QuadEngine {
    /// The word a quad of quantised inputs is broadcast from: by default the four as 16-bit
    /// integers, column `4j` in the low bits.
    #[inline(always)]
    fn word(x: &[i16; QUAD]) -> u64 {
        x.iter()
            .enumerate()
            .fold(0, |w, (c, &v)| w | u64::from(v as u16) << (16 * c))
    }
    fn panel(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL];
}

/// The safe-Rust engine of the quad panels.
pub(crate) struct PortableQuads;

impl QuadEngine for PortableQuads {
    #[inline(always)]
    fn panel(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
        let mut acc = [0i32; QUAD_PANEL];
        for (quad, &w) in q.chunks_exact(QUAD_BYTES).zip(words) {
            let x: [i32; QUAD] = std::array::from_fn(|c| i32::from((w >> (16 * c)) as u16 as i16));
            for (r, a) in acc.iter_mut().enumerate() {
                for (c, &xc) in x.iter().enumerate() {
                    *a += i32::from(quad[QUAD * r + c]) * xc;
                }
            }
        }
        acc
    }
}

/// int8 rows in quad panels (`q`: the panels from the first row's, which is a multiple of
/// [`QUAD_PANEL`]; `cols` per row; one scale per row) times `batch` inputs, by the integer
/// contract of the module docs: each input quantised once, then 16 rows at a time summed in
/// vector lanes — no sum across lanes at the end of a row, as the row kernels need, and the
/// output of 16 rows side by side. The same sums and the same `output` as [`rows_int`], so the
/// same bits. Lengths are checked by the caller.
///
/// Four columns to a quad rather than two to a pair: one broadcast of the input per four
/// columns, and per 64 bytes of weights two loads and two widenings into one pair of sums
/// for each eight rows. The shipped model's 6,504 × 64 PCA decode took 4.6–4.9 → 3.8 µs, its
/// whole int8 step 10.2–10.9 → 8.5–9.3 µs (three alternating rounds of `cargo bench -p
/// sartor-runtime --bench kernels -- 'shipped/int8|pca_basis/6504x64/int8'`, AMD EPYC VM).
#[inline(always)]
pub(crate) fn quads_int<E: QuadEngine>(
    q: &[i8],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    debug_assert!(cols < STRIDED_FROM);
    let quads = cols.div_ceil(QUAD);
    let n_rows = ys_t.len() / batch;
    let mut buffer = [0i16; STRIDED_FROM];
    let mut words = [0u64; STRIDED_FROM / QUAD];
    for k in 0..batch {
        let step = quantize_input(&xs[k * cols..(k + 1) * cols], &mut buffer[..cols]);
        buffer[cols..quads * QUAD].fill(0);
        for (w, x) in words
            .iter_mut()
            .zip(buffer[..quads * QUAD].as_chunks::<QUAD>().0)
        {
            *w = E::word(x);
        }
        let words = &words[..quads];
        // A whole panel of one finite input: its 16 outputs side by side, the panels, their
        // outputs, scales and biases zipped (no bounds check or look at the options per panel).
        let panel_bytes = (quads + 1) * QUAD_BYTES;
        let whole = match step {
            Some(t) if batch == 1 => {
                let whole = n_rows / QUAD_PANEL;
                let panels = q.chunks_exact(panel_bytes).take(whole);
                let ys = ys_t[..whole * QUAD_PANEL].as_chunks_mut::<QUAD_PANEL>().0;
                let s = scales.map(|s| s[..whole * QUAD_PANEL].as_chunks::<QUAD_PANEL>().0);
                let b = bias.map(|b| b[..whole * QUAD_PANEL].as_chunks::<QUAD_PANEL>().0);
                whole_panels::<E>(panels, words, t, ys, s, b);
                whole
            }
            Some(t) => {
                // In a batch, input `k`'s outputs lie `batch` apart: runs of whole panels into
                // a buffer, then each output to its place (the way one input takes, the same
                // bits). Each output on its own, through the options, made a batch of eight on
                // the shipped model 2.5–3 times as slow as eight inputs alone, this about
                // twice (`cargo bench --bench kernels -- 'shipped/int8/(batch|alone)8'` before
                // the network stepped so small a model's avatars alone; three alternating
                // rounds, 618 → 374 µs for the batch on the 2-core Intel Xeon VM). Writing a
                // group of inputs' runs row by row instead measured no faster.
                let whole = n_rows / QUAD_PANEL;
                let mut buf = [[0.0f32; QUAD_PANEL]; BATCH_PANELS];
                for p0 in (0..whole).step_by(BATCH_PANELS) {
                    let n = BATCH_PANELS.min(whole - p0);
                    let rows = p0 * QUAD_PANEL..(p0 + n) * QUAD_PANEL;
                    let panels = q[p0 * panel_bytes..].chunks_exact(panel_bytes).take(n);
                    let s = scales.map(|s| s[rows.clone()].as_chunks::<QUAD_PANEL>().0);
                    let b = bias.map(|b| b[rows.clone()].as_chunks::<QUAD_PANEL>().0);
                    whole_panels::<E>(panels, words, t, &mut buf[..n], s, b);
                    for (i, &y) in rows.zip(buf[..n].as_flattened()) {
                        ys_t[i * batch + k] = y;
                    }
                }
                whole
            }
            None => 0,
        };
        for (p, panel) in q
            .chunks_exact(panel_bytes)
            .take(n_rows.div_ceil(QUAD_PANEL))
            .enumerate()
            .skip(whole)
        {
            let sums = E::panel(panel, words);
            let i0 = p * QUAD_PANEL;
            let n = QUAD_PANEL.min(n_rows - i0);
            for (r, &sum) in sums.iter().enumerate().take(n) {
                let i = i0 + r;
                let scale = scales.map_or(1.0, |s| s[i]);
                ys_t[i * batch + k] = output(sum, step, scale, bias.map(|b| b[i]));
            }
        }
    }
}

/// Whole quad panels of one finite input (quantisation step `t`): each panel's 16 sums, then
/// its 16 outputs side by side (`outputs`), the panels zipped with their outputs, scales and
/// biases. One loop per combination of scales and bias, so that no panel looks at the options
/// or checks a bound: the shipped model's 6,504 × 64 PCA decode (407 panels of 16 quads) spent
/// about a quarter of its time between the panels' sums.
#[inline(always)]
fn whole_panels<'a, E: QuadEngine>(
    panels: impl Iterator<Item = &'a [i8]>,
    words: &[u64],
    t: f32,
    ys: &mut [[f32; QUAD_PANEL]],
    scales: Option<&[[f32; QUAD_PANEL]]>,
    bias: Option<&[[f32; QUAD_PANEL]]>,
) {
    let one = |_: usize| 1.0;
    match (scales, bias) {
        (Some(s), Some(b)) => {
            for (((panel, y), s), b) in panels.zip(ys).zip(s).zip(b) {
                outputs(&E::panel(panel, words), t, |r| s[r], Some(b), y);
            }
        }
        (Some(s), None) => {
            for ((panel, y), s) in panels.zip(ys).zip(s) {
                outputs(&E::panel(panel, words), t, |r| s[r], None, y);
            }
        }
        (None, Some(b)) => {
            for ((panel, y), b) in panels.zip(ys).zip(b) {
                outputs(&E::panel(panel, words), t, one, Some(b), y);
            }
        }
        (None, None) => {
            for (panel, y) in panels.zip(ys) {
                outputs(&E::panel(panel, words), t, one, None, y);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limit_keeps_every_sum_within_i32() {
        for cols in [MIN_COLS, 100, 516, 517, 1500, MAX_COLS] {
            let l = i64::from(input_limit(cols));
            assert!(127 * cols as i64 * l <= i64::from(i32::MAX), "{cols}");
            assert!(l <= i64::from(i16::MAX));
        }
        assert_eq!(input_limit(516), 32_767);
        assert_eq!(input_limit(1500), 11_272);
        // The worst case itself: every weight −127 against every input at the limit.
        let cols = 1500;
        let l = input_limit(cols) as i16;
        let (w, x) = (vec![-127i8; cols], vec![-l; cols]);
        assert_eq!(
            i64::from(PortableInt::dot(&w, &x)),
            127 * i64::from(l) * cols as i64
        );
    }

    #[test]
    fn quantisation_is_within_half_a_step_and_keeps_non_finite_inputs_out() {
        let x: Vec<f32> = (0..700)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) * 0.013)
            .collect();
        let mut q = vec![0i16; x.len()];
        let t = quantize_input(&x, &mut q).expect("finite");
        let limit = input_limit(x.len());
        assert!(
            q.iter().any(|&v| i32::from(v).abs() == limit),
            "the largest maps to ±L"
        );
        let u = f64::from(f32::EPSILON) / 2.0;
        let tol = f64::from(t) * (0.5 + 2.0 * f64::from(limit) * u);
        for (&v, &qv) in x.iter().zip(&q) {
            let err = (f64::from(v) - f64::from(t) * f64::from(qv)).abs();
            assert!(err <= tol, "{v}: {err:e} > {tol:e}");
        }
        let mut bad = x.clone();
        bad[3] = f32::NAN;
        assert_eq!(quantize_input(&bad, &mut q), None);
        bad[3] = f32::NEG_INFINITY;
        assert_eq!(quantize_input(&bad, &mut q), None);
        let tiny = vec![1e-40f32; 50];
        assert_eq!(quantize_input(&tiny, &mut q[..50]), Some(0.0));
        assert!(q[..50].iter().all(|&v| v == 0));
    }

    #[test]
    fn one_input_gives_the_bits_of_the_formula_row_by_row() {
        // The one-input paths write eight rows at a time (side by side for short rows, an
        // eighth of the block apart for long ones); here every row against `output` of its
        // own integer sum, with and without bias and scales, and a tail of rows.
        for (rows, cols) in [(8 * 5 + 3, 70), (8 * 3 + 5, STRIDED_FROM + 88)] {
            let w: Vec<i8> = (0..rows * cols)
                .map(|i| ((i * 7919 % 255) as i32 - 127) as i8)
                .collect();
            let x: Vec<f32> = (0..cols)
                .map(|j| ((j * 31 % 67) as f32 - 33.0) * 0.071)
                .collect();
            let scales: Vec<f32> = (0..rows).map(|i| 0.003 + i as f32 * 1e-4).collect();
            let bias: Vec<f32> = (0..rows).map(|i| (i as f32 - 20.0) * 0.013).collect();
            let mut xq = vec![0i16; cols];
            let step = quantize_input(&x, &mut xq);
            for (s, b) in [
                (Some(&scales[..]), Some(&bias[..])),
                (Some(&scales[..]), None),
                (None, Some(&bias[..])),
                (None, None),
            ] {
                let mut y = vec![f32::NAN; rows];
                rows_int::<PortableInt>(&w, cols, &x, 1, s, b, &mut y);
                for i in 0..rows {
                    let sum = PortableInt::dot(&w[i * cols..(i + 1) * cols], &xq);
                    let want = output(sum, step, s.map_or(1.0, |s| s[i]), b.map(|b| b[i]));
                    assert_eq!(y[i].to_bits(), want.to_bits(), "{rows} × {cols}: row {i}");
                }
            }
        }
    }

    #[test]
    fn a_non_finite_input_gives_nan_rows_and_leaves_the_others_alone() {
        let (rows, cols) = (11, 40);
        let w: Vec<i8> = (0..rows * cols).map(|i| (i % 255) as i8).collect();
        let scales = vec![0.01f32; rows];
        let mut xs: Vec<f32> = (0..2 * cols).map(|i| i as f32 * 0.1 - 3.0).collect();
        xs[cols + 5] = f32::INFINITY;
        let mut ys = vec![0.0f32; rows * 2];
        rows_int::<PortableInt>(&w, cols, &xs, 2, Some(&scales), None, &mut ys);
        for i in 0..rows {
            assert!(ys[2 * i].is_finite());
            assert!(ys[2 * i + 1].is_nan());
        }
    }
}
