//! Row kernels: `y[i·B + b] = scale_i · (w_i · x_b) + bias_i` for a block of rows.
//!
//! [`rows`] is written once, generic over an [`Engine`] that supplies the fused convert + dot
//! product of one stored row with one input, and the accumulation of a column span of one row
//! into the lane sums of one or two inputs (the weights are loaded and converted once for
//! both). [`Portable`] is the safe-Rust engine (auto-vectorised where LLVM manages);
//! `dispatch` adds AVX2 + F16C engines with explicit intrinsics. Every engine follows the same
//! arithmetic contract, so all of them — and the batched and single paths — give bitwise the
//! same numbers:
//!
//! - **Lane rule.** A dot product over `n` columns keeps [`LANES`] independent f32 sums; column
//!   `j` is added to sum `j mod LANES`, in increasing `j`; a partial last chunk is zero-padded
//!   (the padding adds `0·0`). The sums are then reduced by a fixed halving tree
//!   (`s[l] += s[l + 16]`, then `+ 8`, `+ 4`, `+ 2`, `+ 1`). Products are rounded before they
//!   are added (no FMA: Rust never contracts `a * b + c`, and the intrinsics use separate
//!   multiply and add).
//! - **Exact conversion.** f16 and int8 weights convert exactly to f32 before the multiply.
//! - **Epilogue.** `d = tree(...)`; int8 rows: `d = scale · d`; then `d + bias` when a bias is
//!   given.
//!
//! The single-vector path streams each weight row once with the conversion fused into the dot
//! product, four rows at a time (four concurrent memory streams, each input chunk loaded once:
//! one stream per row left a third of the memory bandwidth unused on an Intel Xeon), eight at
//! a time, an eighth of a block of up to [`SPREAD_ROWS`] rows apart ([`spread_block`]), for
//! rows of [`EIGHT_ROWS_FROM`] columns or more (on
//! the AMD EPYC VM the paper-size 13,272 × 1,500 product took 5.0–6.4 ms in f32 with four
//! streams, 4.5–5.0 with eight; the shipped model's rows of 64 to 256 columns, which live in
//! cache, took twice as long with eight; `Matrix` now stores f32 and f16 matrices of such rows
//! interleaved, `interleaved.rs`, read by the same kernel as one stream per panel, and these
//! row-major streams serve int8 rows of more than 2,048 columns). The batched path tiles the
//! work so that everything
//! but the weights stays in L1:
//! blocks of [`ROW_BLOCK`] rows × [`COL_BLOCK`] columns × up to [`GROUP`] inputs, inputs taken
//! two at a time (one weight load feeds two products), lane sums carried across column
//! blocks. `B` avatars thus share one pass over the weights in memory. While the first pair of
//! inputs runs over a row's part of a tile, the SIMD engines ask the cache for that row's part
//! of the next tile (`Engine::madd2`'s `ahead`): the other pairs read the tile from L1, and
//! nothing else kept the memory busy meanwhile. On the 2-core Intel Xeon VM the 13,272 × 1,500
//! product for eight inputs took 19.97 → 16.08 ms in f32 and 14.78 → 12.54 in f16, the
//! paper-size GRU + dense f32 step for eight 24.90 → 20.65 on one thread (`cargo bench --bench
//! kernels`, old and new binaries, four alternating rounds, faster in 15 of 16 paired
//! rounds); asking into L2 only, or four inputs per weight load (eight accumulators in
//! AVX-512's registers), measured level with this. The same bits.
//!
//! With its weights in cache the batched product is bound by loads, one per product (the
//! weight vector feeds two, each input vector one): on that VM a loop of the kernel's pattern
//! from L1 ran about 1.0–1.1 G 16-lane products a second, against 2.1 for the multiplies and
//! adds alone, and 1.4–1.6 when each input vector fed two to four rows (a throwaway harness).
//! So the AVX-512 engines take a whole tile's four rows at once (`Engine::madd2_tile`: each
//! input vector loaded once for four rows, sixteen accumulators): the paper-size GRU + dense
//! f32 step for eight 25.68 → 21.36 ms on one thread and 14.46 → 12.10 on two, f16 on two
//! 12.53 → 10.59 (`cargo bench --bench kernels`, four alternating rounds, faster in each);
//! the product alone from memory 16.6 → 15.3 in f32, level in f16. AVX2's sixteen registers
//! do not hold a tile's accumulators, so it keeps the row-by-row loop; so does the
//! interleaved layout (each row gathered into one buffer). Tried and dropped: f16 tiles
//! converted once into an f32 buffer for all the pairs instead of once per pair (the f16
//! product for eight 13.04 → 15.70 ms, three alternating rounds).

use std::marker::PhantomData;

use super::interleaved::{IL_ROWS, gather, padded_cols};

/// Independent accumulators per dot product (4 × 256-bit registers on AVX2).
pub(crate) const LANES: usize = 32;
/// Columns from which the single-vector path reads eight rows at a time.
pub(crate) const EIGHT_ROWS_FROM: usize = 512;
/// The single-vector path's eight streams run through blocks of this many rows (a multiple
/// of 8), each stream an eighth of the block.
pub(crate) const SPREAD_ROWS: usize = 1024;
/// Rows per tile of the batched path.
pub(crate) const ROW_BLOCK: usize = 4;
/// Columns per tile of the batched path (a multiple of [`LANES`]).
pub(crate) const COL_BLOCK: usize = 512;
/// Inputs per tile of the batched path.
const GROUP: usize = 8;

/// How stored weights become f32, [`LANES`] at a time. Every codec converts exactly, so all
/// codecs of one storage type give the same numbers.
pub(crate) trait Codec {
    /// The stored element; its `Default` is zero.
    type Stored: Copy + Default + Send + Sync + 'static;
    /// The exact f32 values of one chunk.
    fn chunk(src: &[Self::Stored; LANES]) -> [f32; LANES];
}

/// f32 weights.
pub(crate) struct F32Codec;

impl Codec for F32Codec {
    type Stored = f32;

    #[inline(always)]
    fn chunk(src: &[f32; LANES]) -> [f32; LANES] {
        *src
    }
}

/// int8 weights (the per-row scale is applied once per dot product).
pub(crate) struct I8Codec;

impl Codec for I8Codec {
    type Stored = i8;

    #[inline(always)]
    fn chunk(src: &[i8; LANES]) -> [f32; LANES] {
        let mut out = [0.0f32; LANES];
        for (o, &q) in out.iter_mut().zip(src) {
            *o = f32::from(q);
        }
        out
    }
}

/// IEEE binary16 stored as its bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(transparent)]
pub(crate) struct F16Bits(pub(crate) u16);

/// f16 weights, converted in portable code (see [`f16_bits_to_f32`]); `dispatch` has an F16C
/// codec for the same storage.
pub(crate) struct F16Codec;

impl Codec for F16Codec {
    type Stored = F16Bits;

    #[inline(always)]
    fn chunk(src: &[F16Bits; LANES]) -> [f32; LANES] {
        let mut out = [0.0f32; LANES];
        for (o, &h) in out.iter_mut().zip(src) {
            *o = f16_bits_to_f32(h.0);
        }
        out
    }
}

/// Exact binary16 → binary32 conversion for **finite** halves (the loader rejects infinities
/// and NaNs), branch-free so that it vectorises: normal numbers re-bias the exponent by
/// 127 − 15 = 112; subnormals `m·2⁻²⁴` are formed as `(2⁻¹⁴ + m·2⁻²⁴) − 2⁻¹⁴`, which is exact
/// (Sterbenz) and touches no subnormal f32.
#[inline(always)]
pub(crate) fn f16_bits_to_f32(h: u16) -> f32 {
    let h = u32::from(h);
    let sign = (h & 0x8000) << 16;
    let em = (h & 0x7fff) << 13;
    let normal = f32::from_bits(em + (112 << 23));
    let subnormal = f32::from_bits(em + (113 << 23)) - f32::from_bits(113 << 23);
    let magnitude = if h & 0x7c00 == 0 { subnormal } else { normal };
    f32::from_bits(magnitude.to_bits() | sign)
}

#[inline(always)]
pub(crate) fn reduce(mut s: [f32; LANES]) -> f32 {
    let mut width = LANES / 2;
    while width > 0 {
        for l in 0..width {
            s[l] += s[l + width];
        }
        width /= 2;
    }
    s[0]
}

#[inline(always)]
pub(crate) fn epilogue(d: f32, scale: Option<f32>, bias: Option<f32>) -> f32 {
    let d = match scale {
        Some(s) => s * d,
        None => d,
    };
    match bias {
        Some(b) => d + b,
        None => d,
    }
}

/// `s[l] += w[l]·x[l]` for every lane.
#[inline(always)]
fn madd(s: &mut [f32; LANES], w: &[f32; LANES], x: &[f32; LANES]) {
    for l in 0..LANES {
        s[l] += w[l] * x[l];
    }
}

/// A partial chunk, zero-padded to [`LANES`] (padding lanes then add `0·0`).
#[inline(always)]
pub(crate) fn padded<T: Copy + Default>(tail: &[T]) -> [T; LANES] {
    let mut a = [T::default(); LANES];
    a[..tail.len()].copy_from_slice(tail);
    a
}

/// Fused convert + dot product of one stored row with one f32 vector (lane rule).
#[inline(always)]
fn dot<C: Codec>(w: &[C::Stored], x: &[f32]) -> f32 {
    let mut s = [0.0f32; LANES];
    let (wc, wt) = w.as_chunks::<LANES>();
    let (xc, xt) = x.as_chunks::<LANES>();
    for (a, b) in wc.iter().zip(xc) {
        madd(&mut s, &C::chunk(a), b);
    }
    if !wt.is_empty() {
        madd(&mut s, &C::chunk(&padded(wt)), &padded(xt));
    }
    reduce(s)
}

/// `s[j mod LANES] += w[j]·x[j]` over a span starting at a multiple of [`LANES`]; a partial
/// last chunk is zero-padded.
#[inline(always)]
fn madd1<C: Codec>(w: &[C::Stored], x: &[f32], s: &mut [f32; LANES]) {
    let (wc, wt) = w.as_chunks::<LANES>();
    let (xc, xt) = x.as_chunks::<LANES>();
    for (a, b) in wc.iter().zip(xc) {
        madd(s, &C::chunk(a), b);
    }
    if !wt.is_empty() {
        madd(s, &C::chunk(&padded(wt)), &padded(xt));
    }
}

/// [`madd1`] for two inputs sharing each converted weight chunk.
#[inline(always)]
fn madd2<C: Codec>(
    w: &[C::Stored],
    x0: &[f32],
    x1: &[f32],
    s0: &mut [f32; LANES],
    s1: &mut [f32; LANES],
) {
    let (wc, wt) = w.as_chunks::<LANES>();
    let (x0c, x0t) = x0.as_chunks::<LANES>();
    let (x1c, x1t) = x1.as_chunks::<LANES>();
    for ((a, b0), b1) in wc.iter().zip(x0c).zip(x1c) {
        let a = C::chunk(a);
        madd(s0, &a, b0);
        madd(s1, &a, b1);
    }
    if !wt.is_empty() {
        let a = C::chunk(&padded(wt));
        madd(s0, &a, &padded(x0t));
        madd(s1, &a, &padded(x1t));
    }
}

/// The primitives [`rows`] is built from; see the module docs for the arithmetic every
/// implementation must follow.
pub(crate) trait Engine {
    /// The stored weight element.
    type Stored: Copy + Default + Send + Sync + 'static;
    /// `w · x` under the lane rule (all slices the same length).
    fn dot(w: &[Self::Stored], x: &[f32]) -> f32;
    /// [`Engine::dot`] of a block of `8·n8` rows of `cols` columns (`w`, row-major), bitwise
    /// the same as one call per row: the SIMD engines read them eight at a time as eight
    /// concurrent streams an eighth of the block apart, each chunk of `x` loaded once.
    /// `sums[q + k·n8]` is row `q + k·n8`'s dot product with `x`, for `q < n8` and `k < 8`.
    fn dot8_block(w: &[Self::Stored], cols: usize, x: &[f32], n8: usize, sums: &mut [f32]) {
        for (i, s) in sums[..8 * n8].iter_mut().enumerate() {
            *s = Self::dot(&w[i * cols..(i + 1) * cols], x);
        }
    }
    /// [`Engine::dot`] of `4·nq` neighbouring rows of `cols` columns (`w`, row-major), bitwise
    /// the same as one call per row: the SIMD engines read them four at a time as four
    /// concurrent streams (one stream per row leaves memory bandwidth unused on some machines).
    /// `sums[i]` is row `i`'s dot product with `x`.
    fn dot4_block(w: &[Self::Stored], cols: usize, x: &[f32], nq: usize, sums: &mut [f32]) {
        for (i, s) in sums[..4 * nq].iter_mut().enumerate() {
            *s = Self::dot(&w[i * cols..(i + 1) * cols], x);
        }
    }
    /// [`Engine::dot`] of the `8·n8` rows of `n8` interleaved panels of `cols` columns
    /// (`interleaved.rs`: eight rows, chunk by chunk, each row zero-padded to whole chunks),
    /// bitwise the same as one call per row: the SIMD engines read each panel as one stream,
    /// prefetched. `sums[i]` is row `i`'s dot product with `x`.
    fn dot8_interleaved(w: &[Self::Stored], cols: usize, x: &[f32], n8: usize, sums: &mut [f32]) {
        let stride = IL_ROWS * padded_cols(cols);
        for (q, s8) in sums[..IL_ROWS * n8].chunks_exact_mut(IL_ROWS).enumerate() {
            let panel = &w[q * stride..(q + 1) * stride];
            for (k, d) in s8.iter_mut().enumerate() {
                let mut s = [0.0f32; LANES];
                for c in (0..cols).step_by(LANES) {
                    // The padding is not read: a partial chunk of the row's length.
                    let at = c * IL_ROWS + k * LANES;
                    let n = LANES.min(cols - c);
                    Self::madd1(&panel[at..at + n], &x[c..c + n], &mut s);
                }
                *d = reduce(s);
            }
        }
    }
    /// `s[j mod LANES] += w[j]·x[j]` over a span that starts at a multiple of [`LANES`]
    /// (a partial last chunk zero-padded).
    fn madd1(w: &[Self::Stored], x: &[f32], s: &mut [f32; LANES]);
    /// [`Engine::madd1`] for two inputs. The SIMD engines also ask the cache for `ahead` (the
    /// weights the caller reads next; may be empty), a chunk's worth of it beside each chunk of
    /// `w`; that changes no result.
    fn madd2(
        w: &[Self::Stored],
        ahead: &[Self::Stored],
        x0: &[f32],
        x1: &[f32],
        s0: &mut [f32; LANES],
        s1: &mut [f32; LANES],
    );
    /// [`Engine::madd2`] for the [`ROW_BLOCK`] rows of a tile (`w[r]`, `ahead[r]`, sums
    /// `s[r]`), bitwise the same as one call per row. The AVX-512 engines load each input
    /// vector once for all the rows: with one weight load per two products, the loads (one
    /// per product) bound the arithmetic.
    #[inline(always)]
    fn madd2_tile(
        w: [&[Self::Stored]; ROW_BLOCK],
        ahead: [&[Self::Stored]; ROW_BLOCK],
        x0: &[f32],
        x1: &[f32],
        s: [&mut [[f32; LANES]; 2]; ROW_BLOCK],
    ) {
        madd2_rows::<Self>(w, ahead, x0, x1, s)
    }
}

/// [`Engine::madd2_tile`] as one [`Engine::madd2`] per row (the engines that do not take a
/// tile at once).
#[inline(always)]
pub(crate) fn madd2_rows<E: Engine + ?Sized>(
    w: [&[E::Stored]; ROW_BLOCK],
    ahead: [&[E::Stored]; ROW_BLOCK],
    x0: &[f32],
    x1: &[f32],
    s: [&mut [[f32; LANES]; 2]; ROW_BLOCK],
) {
    for ((w, ahead), [s0, s1]) in w.into_iter().zip(ahead).zip(s) {
        E::madd2(w, ahead, x0, x1, s0, s1);
    }
}

/// The safe-Rust engine for codec `C`.
pub(crate) struct Portable<C>(PhantomData<C>);

impl<C: Codec> Engine for Portable<C> {
    type Stored = C::Stored;

    #[inline(always)]
    fn dot(w: &[C::Stored], x: &[f32]) -> f32 {
        dot::<C>(w, x)
    }

    #[inline(always)]
    fn madd1(w: &[C::Stored], x: &[f32], s: &mut [f32; LANES]) {
        madd1::<C>(w, x, s)
    }

    #[inline(always)]
    fn madd2(
        w: &[C::Stored],
        _ahead: &[C::Stored],
        x0: &[f32],
        x1: &[f32],
        s0: &mut [f32; LANES],
        s1: &mut [f32; LANES],
    ) {
        madd2::<C>(w, x0, x1, s0, s1)
    }
}

/// One block of rows: `w` is `rows × cols` row-major, `xs` is `batch × cols`, `ys_t` is
/// `rows × batch` (row-major by output row), `scales` and `bias` have one value per row.
/// Lengths are checked by the caller.
#[inline(always)]
pub(crate) fn rows<E: Engine>(
    w: &[E::Stored],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    if cols == 0 {
        for (i, y) in ys_t.chunks_exact_mut(batch).enumerate() {
            let d = epilogue(0.0, scales.map(|s| s[i]), bias.map(|b| b[i]));
            y.fill(d);
        }
        return;
    }
    if batch == 1 {
        // Eight streams for long rows (memory-bound: more rows in flight), four for short ones
        // (cache-resident: eight rows' accumulators cost more than they hide). The eight rows
        // are an eighth of the block apart, so that each stream runs on through its own
        // contiguous part of the weights: eight neighbouring rows (one 48 KB run read at eight
        // places) made the paper-size GRU + dense step 9–14 % slower in f32 and 17–25 % in
        // f16, where the weights come from memory (`cargo bench --bench kernels --
        // gru1500_out13272`, 2-core Intel Xeon VM, alternating builds). The streams run
        // through blocks of `SPREAD_ROWS` rows rather than the whole matrix, so that the
        // outputs and biases each stream wrote and read stayed close too (before the buffer
        // below took them out of the streams' way): on the AMD EPYC VM
        // the same step took 3.82–3.93 → 3.21–3.28 ms in f32 with the bounds checks out of
        // the eight-row kernel (`dispatch.rs`), of which the blocks gave about 7 % (f16 1.99 → 1.81–1.83).
        // Every row's sum is the same either way.
        //
        // A block's sums wait in a buffer on the stack, and its outputs are written (and its
        // biases read) in one pass after it: written as they came, the outputs and biases
        // were eight more streams each beside the weights' eight (the 13,272 × 1,500 product
        // took 2.01–2.03 ms with a bias against 1.88–1.96 without one). With the buffer, four
        // alternating rounds on the AMD EPYC VM: that product 1.96–2.05 → 1.82–1.92 ms, the
        // paper-size GRU + dense f32 step 2.87–2.98 → 2.69–2.78 on one thread.
        let whole = if cols >= EIGHT_ROWS_FROM {
            ys_t.len() / 8 * 8
        } else {
            0
        };
        if whole > 0 {
            // Only long rows take the buffer (short ones, the shipped model's, skip zeroing it).
            let mut sums = [0.0f32; SPREAD_ROWS];
            let block = spread_block(cols * size_of::<E::Stored>());
            for b0 in (0..whole).step_by(block) {
                let nb = block.min(whole - b0);
                E::dot8_block(&w[b0 * cols..(b0 + nb) * cols], cols, xs, nb / 8, &mut sums);
                for (j, (y, &d)) in ys_t[b0..b0 + nb].iter_mut().zip(&sums).enumerate() {
                    let i = b0 + j;
                    *y = epilogue(d, scales.map(|s| s[i]), bias.map(|b| b[i]));
                }
            }
        }
        let base = whole;
        let after = &mut ys_t[base..];
        let nq = after.len() / 4;
        let (quads, rest) = after.split_at_mut(4 * nq);
        E::dot4_block(&w[base * cols..(base + 4 * nq) * cols], cols, xs, nq, quads);
        for (j, y) in quads.iter_mut().enumerate() {
            let i = base + j;
            *y = epilogue(*y, scales.map(|s| s[i]), bias.map(|b| b[i]));
        }
        let done = base + 4 * nq;
        for (k, y) in rest.iter_mut().enumerate() {
            let i = done + k;
            let row = &w[i * cols..(i + 1) * cols];
            *y = epilogue(E::dot(row, xs), scales.map(|s| s[i]), bias.map(|b| b[i]));
        }
        return;
    }
    batched::<E, false>(w, cols, xs, batch, scales, bias, ys_t);
}

/// The batched path of [`rows`] (and, with `IL`, of `interleaved.rs`'s panels, each row's
/// column block gathered into a buffer first): tiles of [`ROW_BLOCK`] rows × [`COL_BLOCK`]
/// columns × up to [`GROUP`] inputs.
#[inline(always)]
pub(crate) fn batched<E: Engine, const IL: bool>(
    w: &[E::Stored],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    let mut buf = [E::Stored::default(); COL_BLOCK];
    let n_rows = ys_t.len() / batch;
    for r0 in (0..n_rows).step_by(ROW_BLOCK) {
        let nr = ROW_BLOCK.min(n_rows - r0);
        for g0 in (0..batch).step_by(GROUP) {
            let ng = GROUP.min(batch - g0);
            let mut sums = [[[0.0f32; LANES]; GROUP]; ROW_BLOCK];
            for c0 in (0..cols).step_by(COL_BLOCK) {
                let c1 = (c0 + COL_BLOCK).min(cols);
                let x = |k: usize| &xs[(g0 + k) * cols + c0..(g0 + k) * cols + c1];
                // Each row's part of the next tile, which the first pair asks the cache for.
                let ahead = |r: usize| {
                    if IL {
                        &[][..]
                    } else if c1 < cols {
                        let at = (r0 + r) * cols;
                        &w[at + c1..at + (c1 + COL_BLOCK).min(cols)]
                    } else if r0 + ROW_BLOCK + r < n_rows {
                        let at = (r0 + ROW_BLOCK + r) * cols;
                        &w[at..at + COL_BLOCK.min(cols)]
                    } else {
                        &[][..]
                    }
                };
                if !IL && nr == ROW_BLOCK {
                    // A whole tile: its rows at once, pair by pair.
                    let rows: [&[E::Stored]; ROW_BLOCK] =
                        std::array::from_fn(|r| &w[(r0 + r) * cols + c0..(r0 + r) * cols + c1]);
                    for p in 0..ng / 2 {
                        let ahead = std::array::from_fn(|r| if p == 0 { ahead(r) } else { &[] });
                        let s = sums.each_mut().map(|s| {
                            s[2 * p..]
                                .first_chunk_mut::<2>()
                                .expect("a pair within the group")
                        });
                        E::madd2_tile(rows, ahead, x(2 * p), x(2 * p + 1), s);
                    }
                    if ng % 2 == 1 {
                        for (row, s) in rows.into_iter().zip(&mut sums) {
                            E::madd1(row, x(ng - 1), &mut s[ng - 1]);
                        }
                    }
                    continue;
                }
                for (r, s) in sums[..nr].iter_mut().enumerate() {
                    let row = if IL {
                        gather(w, cols, r0 + r, (c0, c1), &mut buf)
                    } else {
                        &w[(r0 + r) * cols + c0..(r0 + r) * cols + c1]
                    };
                    let (pairs, odd) = s[..ng].as_chunks_mut::<2>();
                    for (p, [s0, s1]) in pairs.iter_mut().enumerate() {
                        let ahead = if p == 0 { ahead(r) } else { &[][..] };
                        E::madd2(row, ahead, x(2 * p), x(2 * p + 1), s0, s1);
                    }
                    if let [s0] = odd {
                        E::madd1(row, x(ng - 1), s0);
                    }
                }
            }
            for (r, s) in sums[..nr].iter().enumerate() {
                let i = r0 + r;
                let (scale, b) = (scales.map(|s| s[i]), bias.map(|b| b[i]));
                for (k, s) in s[..ng].iter().enumerate() {
                    ys_t[i * batch + g0 + k] = epilogue(reduce(*s), scale, b);
                }
            }
        }
    }
}

/// Rows per block of the eight-row path: a multiple of 8 between `SPREAD_ROWS − 192` and
/// [`SPREAD_ROWS`] for which the eight streams, `block / 8` rows of `row_bytes` apart, start as
/// far apart as possible modulo 4 KiB (the span of one way of the L1 data cache's sets on the
/// CPUs measured; the largest block among equals).
///
/// With blocks of 1,024 rows, f32 rows of 1,500 columns (6,000 bytes) put the eight streams at
/// two offsets modulo 4 KiB, four streams on each, and rows of 1,504 or 1,536 columns at one:
/// the 13,272-row product then read 38 GB/s against 41 (AMD EPYC VM, before the block kernels).
/// Blocks of 1,000 rows put the streams 432 bytes apart: the 13,272 × 1,500 product took
/// 1.75–1.77 → 1.63–1.68 ms on one thread (a throwaway harness, two builds alternated twice;
/// `cargo bench --bench kernels`, alternating builds: the product 1.71 → 1.61–1.63 ms in f32
/// and 678–682 → 641–648 µs in f16, the paper-size GRU + dense f32 step 2.57–2.63 → 2.36–2.40
/// ms; two threads level within this VM's noise). Each row's sum does not depend on the block:
/// the same bits.
pub(crate) fn spread_block(row_bytes: usize) -> usize {
    const WAY: usize = 4096;
    // The offsets are an arithmetic progression, so the closest two are `j` strides apart
    // for some `j` in 1..8.
    let spread = |n8: usize| {
        (1..8)
            .map(|j| {
                let d = (j * n8 * row_bytes) % WAY;
                d.min(WAY - d)
            })
            .min()
            .unwrap_or(0)
    };
    let top = SPREAD_ROWS / 8;
    (top - 24..=top)
        .rev()
        .max_by_key(|&n8| (spread(n8), n8))
        .map_or(SPREAD_ROWS, |n8| 8 * n8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_spread_the_streams_over_the_cache_sets() {
        let spread = |block: usize, row_bytes: usize| {
            (1..8)
                .map(|j| (j * block / 8 * row_bytes) % 4096)
                .map(|d| d.min(4096 - d))
                .min()
                .expect("seven strides")
        };
        // f32 rows of 1,500 and 1,504 columns, f16 of 1,500, f32 of 520: with blocks of
        // SPREAD_ROWS rows two or more streams start at one offset.
        for row_bytes in [6000, 6016, 3000, 2080] {
            let block = spread_block(row_bytes);
            assert!(
                block.is_multiple_of(8) && (SPREAD_ROWS - 192..=SPREAD_ROWS).contains(&block),
                "{row_bytes} bytes: {block} rows"
            );
            assert_eq!(spread(SPREAD_ROWS, row_bytes), 0, "{row_bytes} bytes");
            assert!(
                spread(block, row_bytes) >= 256,
                "{row_bytes} bytes: {block} rows, streams {} bytes apart",
                spread(block, row_bytes)
            );
        }
        // Rows of a whole number of 2 KiB: every block puts streams together; the largest.
        assert_eq!(spread_block(6144), SPREAD_ROWS);
    }

    #[test]
    fn f16_conversion_is_exact_for_every_finite_half() {
        for bits in 0..=u16::MAX {
            let h = half::f16::from_bits(bits);
            if !h.is_finite() {
                continue;
            }
            let ours = f16_bits_to_f32(bits);
            assert_eq!(ours.to_bits(), h.to_f32().to_bits(), "bits {bits:#06x}");
        }
    }

    #[test]
    fn reduce_follows_the_halving_tree() {
        let s: [f32; LANES] = std::array::from_fn(|l| (l + 1) as f32);
        assert_eq!(reduce(s), (LANES * (LANES + 1) / 2) as f32);
        // A case where the order matters: 1e8 + 1 - 1e8 in different lanes.
        let mut s = [0.0f32; LANES];
        s[0] = 1.0e8;
        s[16] = -1.0e8;
        s[1] = 1.0;
        // Tree: s[0] += s[16] first (exactly 0), then s[0] += s[8], ..., s[0] += s[1] = 1.
        assert_eq!(reduce(s), 1.0);
    }

    #[test]
    fn batched_rows_equal_single_rows_bitwise() {
        let cols = 2 * COL_BLOCK + 7 * LANES + 5;
        let n_rows = ROW_BLOCK + 3;
        let batch = GROUP + 3;
        let w: Vec<f32> = (0..n_rows * cols)
            .map(|i| ((i * 7919 % 1013) as f32 / 1013.0 - 0.5) * 1.7)
            .collect();
        let xs: Vec<f32> = (0..batch * cols)
            .map(|i| ((i * 104_729 % 997) as f32 / 997.0 - 0.5) * 3.1)
            .collect();
        let bias: Vec<f32> = (0..n_rows).map(|i| i as f32 * 0.75 - 1.0).collect();
        let mut batched = vec![0.0; n_rows * batch];
        rows::<Portable<F32Codec>>(&w, cols, &xs, batch, None, Some(&bias), &mut batched);
        for b in 0..batch {
            let mut single = vec![0.0; n_rows];
            rows::<Portable<F32Codec>>(
                &w,
                cols,
                &xs[b * cols..(b + 1) * cols],
                1,
                None,
                Some(&bias),
                &mut single,
            );
            for i in 0..n_rows {
                assert_eq!(single[i].to_bits(), batched[i * batch + b].to_bits());
            }
        }
    }
}
