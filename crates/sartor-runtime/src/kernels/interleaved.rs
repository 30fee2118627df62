//! Long rows read from memory: panels of [`IL_ROWS`] rows stored chunk by chunk, so that the
//! eight-row kernel reads each panel as one sequential stream.
//!
//! The single-vector path of `rows.rs` reads rows of `EIGHT_ROWS_FROM` columns or more eight
//! at a time, eight streams an eighth of a block apart. Stored interleaved, the eight rows of
//! a panel follow one another [`LANES`] columns at a time — chunk 0 of rows 0 to 7, then
//! chunk 1 of each, … — each row zero-padded to whole chunks and the last panel to eight rows
//! (1,500 columns: 0.3 % more bytes). The SIMD engines read a panel front to back, ask for the
//! lines [`IL_AHEAD`] bytes ahead, and read every chunk whole: a row's last chunk meets the
//! input's zero-padded tail (loaded once per product) instead of masked loads per row.
//!
//! **The same bits.** Each row is the same chunks in the same order into the same lane sums;
//! its padding adds `0 · 0 = +0` to lanes where the row-major kernels' masked loads add the
//! same `+0`. Every output equals the row-major kernels' (tested for every instruction set,
//! batch size and thread split). The batched path gathers a row's column block into a buffer
//! and runs the row-major tile.
//!
//! **Only on AMD's Zen 5 and later** (and off x86-64): on Intel CPUs the eight prefetched
//! row-major streams read faster, and on the AMD EPYC Zen 3 VM the eight plain ones (one panel,
//! one stream, fetched more slowly there: 1.46× the row-major time in f32 on one thread;
//! `dispatch::interleave_long_rows` has the measurements), so `Matrix` keeps such rows
//! row-major on them.
//!
//! Measured on the 2-core AMD EPYC Zen 5 VM (throwaway harnesses, each call or frame timed in turn
//! with the row-major layout; the VM's speed drifted by a third within minutes):
//!
//! - the paper-size dense output layer, 13,272 × 1,500 f32 (80 MB), one thread: row-major
//!   2.19–2.73 ms, interleaved 2.07–2.27 (0.81–0.94× the time), the memory floor 1.65–1.98;
//!   the first version, with masked loads for each row's partial last chunk, only 0.94–1.01×
//!   when the row kernel ran near its best, and without the prefetch 1.15–1.25× (slower);
//! - the paper-size GRU + dense step (109 MB), f32: one thread 0.73–0.77× the row-major time
//!   (2.80–3.17 ms against 3.71–4.46; 1.10–1.25× the floor against 1.46–1.65), two threads
//!   0.87–0.97× (2.15–2.38 against 2.30–2.68; 1.01–1.27× the floor); f16 0.91–0.96× on one
//!   thread and 0.89–0.92× on two;
//! - matrices that sit in cache (1,536 × 512, 768 × 1,024, 2,048 × 1,500 and 4,500 × 1,500,
//!   the same product repeated, two runs): level within the VM's noise, 0.61–1.10× the
//!   row-major time in f32 and 0.87–1.29× in f16 (the worst of each in one run only), so
//!   every matrix of such rows is stored interleaved, not only those read from memory;
//! - the prefetch distance, in the first version on the dense product (per call against
//!   row-major): 2, 4, 8, 12 and 16 KiB ahead level within 3 % in f32; in f16 (half the bytes
//!   per step) 8 KiB 0.97–1.00× on one thread, 4 KiB 1.18–1.21× and 16 KiB 1.11–1.13×.

use super::rows::{COL_BLOCK, Engine, LANES, SPREAD_ROWS, batched, epilogue};

/// Rows per interleaved panel: the eight-row kernel's group.
pub(crate) const IL_ROWS: usize = 8;

/// Bytes ahead of a panel's current chunk that the SIMD engines prefetch.
#[cfg(target_arch = "x86_64")]
pub(crate) const IL_AHEAD: usize = 8192;

/// Stored columns per row: `cols` rounded up to whole chunks.
#[inline(always)]
pub(crate) fn padded_cols(cols: usize) -> usize {
    cols.next_multiple_of(LANES)
}

/// Where element (`r`, `c`) of a matrix of `cols` columns is stored interleaved.
#[inline(always)]
pub(crate) fn index(r: usize, c: usize, cols: usize) -> usize {
    let panel = r / IL_ROWS * IL_ROWS * padded_cols(cols);
    panel + (c / LANES * IL_ROWS + r % IL_ROWS) * LANES + c % LANES
}

/// Row-major `rows × cols` → interleaved (zeros in the padding), a chunk at a time.
pub(crate) fn to_interleaved<T: Copy + Default>(w: &[T], rows: usize, cols: usize) -> Vec<T> {
    let mut out = vec![T::default(); rows.next_multiple_of(IL_ROWS) * padded_cols(cols)];
    if cols > 0 {
        for (r, row) in w[..rows * cols].chunks_exact(cols).enumerate() {
            for (c, chunk) in row.chunks(LANES).enumerate() {
                let at = index(r, c * LANES, cols);
                out[at..at + chunk.len()].copy_from_slice(chunk);
            }
        }
    }
    out
}

/// Interleaved → row-major, a chunk at a time.
pub(crate) fn from_interleaved<T: Copy + Default>(w: &[T], rows: usize, cols: usize) -> Vec<T> {
    let mut out = vec![T::default(); rows * cols];
    if cols > 0 {
        for (r, row) in out.chunks_exact_mut(cols).enumerate() {
            for (c, chunk) in row.chunks_mut(LANES).enumerate() {
                let at = index(r, c * LANES, cols);
                chunk.copy_from_slice(&w[at..at + chunk.len()]);
            }
        }
    }
    out
}

/// Columns `c0..c1` of row `r` of panels `w` (`c0` a multiple of [`LANES`], at most
/// [`COL_BLOCK`] columns), copied into `buf`.
#[inline(always)]
pub(crate) fn gather<'a, T: Copy>(
    w: &[T],
    cols: usize,
    r: usize,
    (c0, c1): (usize, usize),
    buf: &'a mut [T; COL_BLOCK],
) -> &'a [T] {
    for c in (c0..c1).step_by(LANES) {
        let len = LANES.min(c1 - c);
        let at = index(r, c, cols);
        buf[c - c0..c - c0 + len].copy_from_slice(&w[at..at + len]);
    }
    &buf[..c1 - c0]
}

/// `rows.rs`'s kernel for an interleaved block: `w` holds the panels of `ys_t.len() / batch`
/// rows of `cols` columns (the block starts at a panel), `scales` and `bias` one value per
/// row. Lengths are checked by the caller.
#[inline(always)]
pub(crate) fn interleaved<E: Engine>(
    w: &[E::Stored],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    let n_rows = ys_t.len() / batch;
    if batch > 1 {
        batched::<E, true>(w, cols, xs, batch, scales, bias, ys_t);
        return;
    }
    let stride = IL_ROWS * padded_cols(cols);
    let mut sums = [0.0f32; SPREAD_ROWS];
    for b0 in (0..n_rows).step_by(SPREAD_ROWS) {
        let nb = SPREAD_ROWS.min(n_rows - b0);
        let n8 = nb.div_ceil(IL_ROWS);
        let panels = &w[b0 / IL_ROWS * stride..(b0 / IL_ROWS + n8) * stride];
        E::dot8_interleaved(panels, cols, xs, n8, &mut sums);
        for (j, (y, &d)) in ys_t[b0..b0 + nb].iter_mut().zip(&sums).enumerate() {
            let i = b0 + j;
            *y = epilogue(d, scales.map(|s| s[i]), bias.map(|b| b[i]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interleaving_is_a_permutation_padded_with_zeros() {
        for (rows, cols) in [(8, 512), (17, 520), (9, 1500), (24, 64), (3, 700), (16, 33)] {
            let w: Vec<u32> = (1..=(rows * cols) as u32).collect();
            let il = to_interleaved(&w, rows, cols);
            assert_eq!(
                il.len(),
                rows.next_multiple_of(8) * cols.next_multiple_of(LANES)
            );
            let mut seen: Vec<u32> = il.iter().copied().filter(|&v| v != 0).collect();
            seen.sort_unstable();
            assert_eq!(
                seen, w,
                "{rows} × {cols}: every value once, zeros elsewhere"
            );
            assert_eq!(from_interleaved(&il, rows, cols), w);
            for r in 0..rows {
                for c in 0..cols {
                    assert_eq!(il[index(r, c, cols)], w[r * cols + c], "({r}, {c})");
                }
            }
            // Chunk 1 of row 3 follows chunk 1 of row 2; a panel's rows are 32 apart.
            if rows >= 8 && cols >= 2 * LANES {
                assert_eq!(index(3, LANES, cols), index(2, LANES, cols) + LANES);
                assert_eq!(index(1, 0, cols), LANES);
            }
            let mut buf = [0u32; COL_BLOCK];
            for r in 0..rows {
                for c0 in (0..cols).step_by(COL_BLOCK) {
                    let c1 = (c0 + COL_BLOCK).min(cols);
                    let got = gather(&il, cols, r, (c0, c1), &mut buf);
                    assert_eq!(got, &w[r * cols + c0..r * cols + c1]);
                }
            }
        }
    }
}
