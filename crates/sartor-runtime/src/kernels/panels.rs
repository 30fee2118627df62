//! Thin matrices (at most [`THIN_COLS`] columns, such as a PCA basis of `3V × k` at a low rank
//! `k`): rows in panels of [`PANEL`], each panel stored column by column, so that one vector
//! holds the same column of [`PANEL`] consecutive rows and a product runs [`PANEL`] rows side by
//! side.
//!
//! The row kernels of `rows.rs` give every row 32 lane sums and a reduction tree: a row of
//! `k < 32` weights is a zero-padded chunk of 32 products (copied into place) and 31
//! additions, whatever `k`. On the T-shirts' PCA bases that made rank 4 six times slower than
//! rank 32 (6,504 × 4 in f32: 100 µs against 17 for 6,504 × 32, `cargo bench -p sartor-runtime
//! --bench kernels -- pca_basis`, one thread of a 2-core Intel Xeon VM). A panel computes only
//! the lanes that hold a weight, [`PANEL`] rows per vector operation: 6,504 × 4 in 3.3 µs, × 8
//! in 10.5 (was 98), × 16 in 18 (was 45). From 32 columns the row kernels are faster (a panel's
//! 32 lane sums no longer fit in registers), so wider matrices stay row-major. Since the block
//! row kernels (2026-12-01) that holds from 9 columns: on the AMD EPYC VM (2026-12-02, same
//! command) 6,504 × 16 in f32 took 14.5 µs in rows against 31.2 in panels, 13,272 × 16 35
//! against 61; × 8 14.4 against 16.1 (level within this VM's noise); × 4 16.6 against 4.6, so
//! panels keep at most 8 columns (they took at most 16 before). f16 panels lost to the f16 row
//! kernels at every width (6,504 × 4 / 8: 11.1 / 23.7 µs against 9.5 / 15.5 in rows, 13,272 ×
//! 4 / 8: 29.8 / 40.9 against 23.1 / 22.3), so only f32 matrices are stored in panels.
//!
//! **Bitwise the same as the lane rule.** Lane `l` of a row sums the products of columns
//! `l, l + 32, …` in increasing order, and the lanes are combined by the same halving tree
//! (`s[l] += s[l + 16]`, then `+ 8`, `+ 4`, `+ 2`, `+ 1`). Lanes without a weight are `+0.0` in
//! the row kernels; here the lanes are rounded up to a power of two `P` and the levels of the
//! tree above `P` are skipped: adding `+0.0` changes nothing but the sign of a zero, and the row
//! kernels' sums are never `−0.0` (they start from `+0.0`; in round-to-nearest a sum is `−0.0`
//! only when both terms are), so one final `d + 0.0` gives the same bits. The epilogue (bias)
//! is the row kernels'. The tests check the bits against the row kernels for f32, every
//! instruction set and batch size, with zeros of both signs and underflowing products. int8
//! matrices are not stored in panels: their rows multiply integers at every width (`int8.rs`).

use super::rows::LANES;

/// Rows per panel (one 256-bit vector of f32).
pub(crate) const PANEL: usize = 8;

/// f32 matrices with at most this many columns (and at least [`PANEL`] rows) are stored in
/// panels.
pub(crate) const THIN_COLS: usize = 8;

/// A stored weight that converts exactly to f32.
pub(crate) trait Elem: Copy + Default + Send + Sync + 'static {
    fn to_f32(self) -> f32;
}

impl Elem for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

/// Row-major `rows × cols` → panels (the last one zero-padded to [`PANEL`] rows): element
/// `(i, j)` at `(i / PANEL)·PANEL·cols + j·PANEL + i % PANEL`.
pub(crate) fn to_panels<T: Copy + Default>(w: &[T], rows: usize, cols: usize) -> Vec<T> {
    let n_panels = rows.div_ceil(PANEL);
    let mut out = vec![T::default(); n_panels * PANEL * cols];
    for (i, row) in w.chunks_exact(cols.max(1)).take(rows).enumerate() {
        let base = (i / PANEL) * PANEL * cols + i % PANEL;
        for (j, &v) in row.iter().enumerate() {
            out[base + j * PANEL] = v;
        }
    }
    out
}

/// The inverse of [`to_panels`]: row-major `rows × cols`.
pub(crate) fn from_panels<T: Copy + Default>(p: &[T], rows: usize, cols: usize) -> Vec<T> {
    let mut out = vec![T::default(); rows * cols];
    for i in 0..rows {
        let base = (i / PANEL) * PANEL * cols + i % PANEL;
        for j in 0..cols {
            out[i * cols + j] = p[base + j * PANEL];
        }
    }
    out
}

#[inline(always)]
fn add(a: [f32; PANEL], b: [f32; PANEL]) -> [f32; PANEL] {
    std::array::from_fn(|r| a[r] + b[r])
}

/// Column `j` of a panel times `x`.
#[inline(always)]
fn column<T: Elem>(panel: &[T], j: usize, x: f32) -> [f32; PANEL] {
    let c: &[T; PANEL] = panel[j * PANEL..(j + 1) * PANEL]
        .try_into()
        .expect("a panel column is PANEL long");
    std::array::from_fn(|r| c[r].to_f32() * x)
}

/// `W x` for the [`PANEL`] rows of one panel (`cols` columns), lane rule and tree, with the
/// lanes that hold a weight (`min(cols, 32)`) rounded up to `P`, a power of two: the extra
/// lanes are +0.0, as in the row kernels, and the levels of the tree above `P` would only add
/// +0.0. With `P` fixed the loops unroll and the lane sums stay in registers.
#[inline(always)]
fn panel_dot<T: Elem, const P: usize>(panel: &[T], cols: usize, x: &[f32]) -> [f32; PANEL] {
    // The tree's first level as the lanes are made (`s[l] = lane l + lane l + P/2`): half as
    // many sums live at once, so that they stay in registers.
    let half = (P / 2).max(1);
    let mut s = [[0.0f32; PANEL]; P];
    for (l, sl) in s[..half].iter_mut().enumerate() {
        if l < cols {
            *sl = lane(panel, cols, x, l);
        }
        if P > 1 && l + half < cols {
            *sl = add(*sl, lane(panel, cols, x, l + half));
        }
    }
    let mut width = half / 2;
    while width > 0 {
        for l in 0..width {
            s[l] = add(s[l], s[l + width]);
        }
        width /= 2;
    }
    // `+ 0.0` turns a −0.0 into the row kernels' +0.0.
    s[0].map(|d| d + 0.0)
}

/// Lane `l`'s sum: columns `l, l + 32, …` in increasing order.
#[inline(always)]
fn lane<T: Elem>(panel: &[T], cols: usize, x: &[f32], l: usize) -> [f32; PANEL] {
    let mut acc = column(panel, l, x[l]);
    let mut j = l + LANES;
    while j < cols {
        acc = add(acc, column(panel, j, x[j]));
        j += LANES;
    }
    acc
}

/// [`panels`] with `P` lanes (see [`panel_dot`]).
#[inline(always)]
fn panels_p<T: Elem, const P: usize>(
    w: &[T],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    let n_rows = ys_t.len() / batch;
    // The epilogue of a panel's rows `i0..i0 + nr`, one input (`d` its products).
    let epilogue = |d: [f32; PANEL], i0: usize, nr: usize| -> [f32; PANEL] {
        let mut v = d;
        if let Some(s) = scales {
            for (v, s) in v.iter_mut().zip(&s[i0..i0 + nr]) {
                *v *= s;
            }
        }
        if let Some(b) = bias {
            for (v, b) in v.iter_mut().zip(&b[i0..i0 + nr]) {
                *v += b;
            }
        }
        v
    };
    for (p, panel) in w.chunks_exact(PANEL * cols).enumerate() {
        let i0 = p * PANEL;
        let nr = PANEL.min(n_rows.saturating_sub(i0));
        if batch == 1 && nr == PANEL {
            // The common case: eight contiguous outputs.
            let d = epilogue(panel_dot::<T, P>(panel, cols, xs), i0, PANEL);
            ys_t[i0..i0 + PANEL].copy_from_slice(&d);
            continue;
        }
        for b in 0..batch {
            let x = &xs[b * cols..(b + 1) * cols];
            let d = epilogue(panel_dot::<T, P>(panel, cols, x), i0, nr);
            for (r, &v) in d[..nr].iter().enumerate() {
                ys_t[(i0 + r) * batch + b] = v;
            }
        }
    }
}

/// `ys_t[i·B + b] = scale_i · (w_i · x_b) + bias_i` for the rows of whole panels `w`
/// (`ys_t.len() / batch` rows, the last panel possibly partial), the row kernels' contract.
#[inline(always)]
pub(crate) fn panels<T: Elem>(
    w: &[T],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    debug_assert!(cols >= 1, "thin matrices have at least one column");
    let f = match cols.min(LANES).next_power_of_two() {
        1 => panels_p::<T, 1>,
        2 => panels_p::<T, 2>,
        4 => panels_p::<T, 4>,
        8 => panels_p::<T, 8>,
        16 => panels_p::<T, 16>,
        _ => panels_p::<T, 32>,
    };
    f(w, cols, xs, batch, scales, bias, ys_t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_round_trip() {
        let (rows, cols) = (19, 5);
        let w: Vec<u32> = (0..(rows * cols) as u32).collect();
        let p = to_panels(&w, rows, cols);
        assert_eq!(p.len(), 3 * PANEL * cols);
        assert_eq!(p[PANEL], 1, "row 0, column 1");
        assert_eq!(from_panels(&p, rows, cols), w);
    }
}
