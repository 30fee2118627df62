//! The system's upper triangle, as the CG loop reads it, and its row products.
//!
//! The system is symmetric bit for bit (every element's blocks below its diagonal are the
//! transposes of those above, and the assembly sums each block's contributions in element
//! order from both sides), so CG reads each off-diagonal block once per product where the
//! full rows read it twice: about half the bytes per iteration (2.3 against 4.3 MB at 8,710
//! triangles). Row `i` reads its blocks on and above the diagonal `A_ij` (`j ≥ i`) in its own
//! run of the triangle, and those below as the transposes of their mirrors `A_ji`, which
//! the rows just before it have read (still in the core's cache, in the simulator's Morton
//! order).
//!
//! Each block is stored as its first eight values (column-major) in one 64-byte line, its
//! ninth apart: one aligned load per block, none split over two lines. A product sums, per
//! row and per stored value `k` of a block, `value_k · x_c` over the row's blocks (`c = k / 3`
//! for a block above the diagonal, `k mod 3` for a transposed one below), the even and the
//! odd blocks of each kind apart, and adds the lanes at the row's end in a fixed order
//! ([`finish`]): eight or four lanes per instruction, and no broadcast of `x_j`'s components.
//! The portable, AVX2 and AVX-512 kernels do exactly the same arithmetic, so every bit of a
//! product is the same on any CPU (tested).

use std::ops::Range;

use nalgebra::{Matrix3, Vector3};

use super::BlockPattern;

/// A block's first eight values (column-major), in one cache line.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(64))]
pub(crate) struct Head(pub [f64; 8]);

/// The upper triangle's blocks (`(i, j)`, `j ≥ i`, row by row; see
/// [`BlockPattern::upper_start`]): each as its [`Head`] and its ninth value.
#[derive(Clone, Debug, Default)]
pub(crate) struct UpperBlocks {
    pub head: Vec<Head>,
    pub tail: Vec<f64>,
}

impl UpperBlocks {
    /// `n` zero blocks.
    pub fn zeros(n: usize) -> Self {
        Self {
            head: vec![Head::default(); n],
            tail: vec![0.0; n],
        }
    }

    /// The upper triangle of the full blocks `values` over `pattern`.
    #[cfg(test)]
    pub fn of(pattern: &BlockPattern, values: &[Matrix3<f64>]) -> Self {
        let mut out = Self::zeros(pattern.n_upper());
        let mut view = out.view_mut();
        for i in 0..pattern.n_rows() {
            let at = pattern.upper_start(i);
            for (k, m) in values[pattern.diag_slot(i)..pattern.row(i).end]
                .iter()
                .enumerate()
            {
                view.set(at + k, m);
            }
        }
        out
    }

    /// Value `k` (column-major) of the block at `place`.
    #[inline(always)]
    pub fn value(&self, place: usize, k: usize) -> f64 {
        if k < 8 {
            self.head[place].0[k]
        } else {
            self.tail[place]
        }
    }

    /// The block at `place`.
    pub fn block(&self, place: usize) -> Matrix3<f64> {
        Matrix3::from_fn(|r, c| self.value(place, 3 * c + r))
    }

    /// All blocks, to be written.
    pub fn view_mut(&mut self) -> UpperMut<'_> {
        UpperMut {
            head: &mut self.head,
            tail: &mut self.tail,
        }
    }
}

/// A run of the upper triangle's blocks, to be written.
#[derive(Debug)]
pub(crate) struct UpperMut<'a> {
    head: &'a mut [Head],
    tail: &'a mut [f64],
}

impl<'a> UpperMut<'a> {
    /// The first `n` blocks, and the rest.
    pub fn split_at(self, n: usize) -> (Self, Self) {
        let (h0, h1) = self.head.split_at_mut(n);
        let (t0, t1) = self.tail.split_at_mut(n);
        (Self { head: h0, tail: t0 }, Self { head: h1, tail: t1 })
    }

    /// No blocks.
    pub fn empty() -> Self {
        Self {
            head: &mut [],
            tail: &mut [],
        }
    }

    /// Store `m` as its `k`-th block.
    #[inline(always)]
    pub fn set(&mut self, k: usize, m: &Matrix3<f64>) {
        let v = m.as_slice();
        self.head[k].0.copy_from_slice(&v[..8]);
        self.tail[k] = v[8];
    }

    /// Add `m` to its `k`-th block.
    #[inline(always)]
    pub fn add(&mut self, k: usize, m: &Matrix3<f64>) {
        let (v, head) = (m.as_slice(), &mut self.head[k].0);
        for (h, v) in head.iter_mut().zip(v) {
            *h += v;
        }
        self.tail[k] += v[8];
    }

    /// Blocks `range` set to zero.
    pub fn zero(&mut self, range: Range<usize>) {
        self.head[range.clone()].fill(Head::default());
        self.tail[range].fill(0.0);
    }

    /// Blocks `range` times `s`.
    #[inline(always)]
    pub fn scale(&mut self, range: Range<usize>, s: f64) {
        for h in &mut self.head[range.clone()] {
            h.0.iter_mut().for_each(|v| *v *= s);
        }
        self.tail[range].iter_mut().for_each(|v| *v *= s);
    }

    /// Add `d` to the diagonal of its `k`-th block.
    #[inline(always)]
    pub fn add_to_diagonal(&mut self, k: usize, d: f64) {
        self.head[k].0[0] += d;
        self.head[k].0[4] += d;
        self.tail[k] += d;
    }

    /// Where its `k`-th block starts, for a prefetch (never dereferenced here).
    #[inline(always)]
    pub fn address(&self, k: usize) -> *const Head {
        self.head.as_ptr().wrapping_add(k)
    }
}

/// `out[k] = (A x)_{first + k}` from `A`'s upper triangle `upper` (see the module docs).
pub(super) fn upper_row_products(
    pattern: &BlockPattern,
    upper: &UpperBlocks,
    x: &[Vector3<f64>],
    first: usize,
    out: &mut [Vector3<f64>],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if simd::has_avx512() {
            simd::rows_avx512(pattern, upper, x, first, out);
            return;
        }
        if simd::has_avx2() {
            simd::rows_avx2(pattern, upper, x, first, out);
            return;
        }
    }
    rows_portable(pattern, upper, x, first, out);
}

/// Row `i`'s blocks below the diagonal (its slots, each read through its mirror) and the
/// places of those on and above it.
#[inline(always)]
fn row_parts(pattern: &BlockPattern, i: usize) -> (Range<usize>, Range<usize>, usize) {
    let (row, diag) = (pattern.row(i), pattern.diag_slot(i));
    (row.start..diag, diag..row.end, pattern.upper_start(i))
}

/// Row `r` of the product from the lane sums: `l` of the blocks below the diagonal (lane
/// `k = 3 r + c` holds `Σ A_ji[c, r] x_j[c]`) and `u` of those on and above it (lane
/// `k = 3 c + r` holds `Σ A_ij[r, c] x_j[c]`), each the even blocks' plus the odd ones'.
#[inline(always)]
fn finish(l: &[f64; 9], u: &[f64; 9]) -> Vector3<f64> {
    Vector3::from_fn(|r, _| {
        ((l[3 * r] + l[3 * r + 1]) + l[3 * r + 2]) + ((u[r] + u[r + 3]) + u[r + 6])
    })
}

fn rows_portable(
    pattern: &BlockPattern,
    upper: &UpperBlocks,
    x: &[Vector3<f64>],
    first: usize,
    out: &mut [Vector3<f64>],
) {
    for (n, yi) in out.iter_mut().enumerate() {
        let (lower, mine, start) = row_parts(pattern, first + n);
        let mut l = [[0.0; 9]; 2];
        for (b, s) in lower.enumerate() {
            let (at, v) = (pattern.mirror[s] as usize, &x[pattern.cols[s] as usize]);
            for k in 0..9 {
                l[b % 2][k] += upper.value(at, k) * v[k % 3];
            }
        }
        let mut u = [[0.0; 9]; 2];
        for (b, s) in mine.enumerate() {
            let (at, v) = (start + b, &x[pattern.cols[s] as usize]);
            for k in 0..9 {
                u[b % 2][k] += upper.value(at, k) * v[k / 3];
            }
        }
        *yi = finish(
            &std::array::from_fn(|k| l[0][k] + l[1][k]),
            &std::array::from_fn(|k| u[0][k] + u[1][k]),
        );
    }
}

/// The AVX2 and AVX-512 kernels.
///
/// Unsafe operations, each with its `SAFETY` comment: the calls of the `#[target_feature]`
/// functions, sound exactly when the CPU has the features (checked by the only callers), and
/// the loads from a [`Head`] (aligned, within its eight values) and from an `x_j` (three
/// values, the fourth and later lanes masked off: not read).
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod simd {
    use std::arch::x86_64::{
        __m256d, __m512d, _mm256_add_pd, _mm256_load_pd, _mm256_maskload_pd, _mm256_mul_pd,
        _mm256_permute4x64_pd, _mm256_set_epi64x, _mm256_setzero_pd, _mm256_storeu_pd,
        _mm512_add_pd, _mm512_load_pd, _mm512_maskz_loadu_pd, _mm512_mul_pd, _mm512_permutexvar_pd,
        _mm512_set_epi64, _mm512_setzero_pd, _mm512_storeu_pd,
    };

    use nalgebra::Vector3;

    use super::{BlockPattern, UpperBlocks, finish, row_parts};

    /// Where the kernels read: the blocks' heads and tails and `x`, checked once against the
    /// pattern, whose columns (`< n_rows()`) and places (`< n_upper()`) are in bounds by
    /// construction.
    struct Ends {
        head: *const f64,
        tail: *const f64,
        x: *const f64,
    }

    impl Ends {
        fn new(pattern: &BlockPattern, upper: &UpperBlocks, x: &[Vector3<f64>]) -> Self {
            assert!(
                upper.head.len() == pattern.n_upper()
                    && upper.tail.len() == pattern.n_upper()
                    && x.len() == pattern.n_rows(),
                "the system's triangle and x must match the pattern"
            );
            Self {
                head: upper.head.as_ptr().cast(),
                tail: upper.tail.as_ptr(),
                x: x.as_ptr().cast(),
            }
        }

        /// Block `at`'s head and tail, and `x_c`.
        ///
        /// # Safety
        ///
        /// `at < n_upper()` and `c < n_rows()` of the pattern `self` was made for.
        #[inline(always)]
        unsafe fn at(&self, at: u32, c: u32) -> (*const f64, f64, *const f64) {
            let (at, c) = (at as usize, c as usize);
            // SAFETY: in bounds by the caller's promise (`Head` is eight f64, `Vector3` three).
            unsafe { (self.head.add(8 * at), *self.tail.add(at), self.x.add(3 * c)) }
        }
    }

    pub(super) fn has_avx2() -> bool {
        is_x86_feature_detected!("avx2")
    }

    pub(super) fn has_avx512() -> bool {
        is_x86_feature_detected!("avx512f")
    }

    /// The lane sums of a row's blocks in one instruction set: eight lanes (a block's
    /// [`Head`](super::Head)) in vectors and the ninth apart.
    trait Lanes: Copy {
        /// Zero sums.
        ///
        /// # Safety
        ///
        /// The CPU has the instruction set.
        unsafe fn zero() -> Self;

        /// `self + head ⊙ x_j[lane's component]` (lane `k` takes `x_j[k mod 3]` `BELOW` the
        /// diagonal, `x_j[k / 3]` on and above) and `ninth + tail · x_j.z`, for the block at
        /// `at` and `x_j` at `c`.
        ///
        /// # Safety
        ///
        /// The CPU has the instruction set; `at < n_upper()` and `c < n_rows()` of the
        /// pattern `ends` was made for.
        unsafe fn add<const BELOW: bool>(&mut self, ends: &Ends, at: u32, c: u32);

        /// `a + b`, lane by lane, as nine values.
        ///
        /// # Safety
        ///
        /// The CPU has the instruction set.
        unsafe fn sum(a: Self, b: Self) -> [f64; 9];
    }

    /// AVX-512: the eight lanes in one vector.
    #[derive(Clone, Copy)]
    struct Wide(__m512d, f64);

    impl Lanes for Wide {
        #[target_feature(enable = "avx512f")]
        #[inline]
        unsafe fn zero() -> Self {
            Self(_mm512_setzero_pd(), 0.0)
        }

        #[target_feature(enable = "avx512f")]
        #[inline]
        unsafe fn add<const BELOW: bool>(&mut self, ends: &Ends, at: u32, c: u32) {
            let index = if BELOW {
                _mm512_set_epi64(1, 0, 2, 1, 0, 2, 1, 0)
            } else {
                _mm512_set_epi64(2, 2, 1, 1, 1, 0, 0, 0)
            };
            // SAFETY: `at` and `c` are in bounds (the caller's promise); a `Head` is 64-byte
            // aligned and holds eight f64; `x_j` holds three, the lanes from the fourth on
            // are masked off.
            unsafe {
                let (head, tail, v) = ends.at(at, c);
                let h = _mm512_load_pd(head);
                let xv = _mm512_permutexvar_pd(index, _mm512_maskz_loadu_pd(0b111, v));
                self.0 = _mm512_add_pd(self.0, _mm512_mul_pd(h, xv));
                self.1 += tail * *v.add(2);
            }
        }

        #[target_feature(enable = "avx512f")]
        #[inline]
        unsafe fn sum(a: Self, b: Self) -> [f64; 9] {
            let mut out = [0.0; 9];
            // SAFETY: `out` holds the eight values stored.
            unsafe { _mm512_storeu_pd(out.as_mut_ptr(), _mm512_add_pd(a.0, b.0)) };
            out[8] = a.1 + b.1;
            out
        }
    }

    /// AVX2: the eight lanes in two vectors.
    #[derive(Clone, Copy)]
    struct Halves(__m256d, __m256d, f64);

    impl Lanes for Halves {
        #[target_feature(enable = "avx2")]
        #[inline]
        unsafe fn zero() -> Self {
            Self(_mm256_setzero_pd(), _mm256_setzero_pd(), 0.0)
        }

        #[target_feature(enable = "avx2")]
        #[inline]
        unsafe fn add<const BELOW: bool>(&mut self, ends: &Ends, at: u32, c: u32) {
            // `vpermpd` selectors (lane t's source in bits 2t..2t+2): below the diagonal
            // (0 1 2 0), (1 2 0 1); on and above (0 0 0 1), (1 1 2 2).
            const BELOW_LO: i32 = 0b00_10_01_00;
            const BELOW_HI: i32 = 0b01_00_10_01;
            const ABOVE_LO: i32 = 0b01_00_00_00;
            const ABOVE_HI: i32 = 0b10_10_01_01;
            // SAFETY: as in `Wide::add`; the head is two aligned halves, lane 3 of `x_j` is
            // masked off.
            unsafe {
                let (head, tail, v) = ends.at(at, c);
                let (h0, h1) = (_mm256_load_pd(head), _mm256_load_pd(head.add(4)));
                let xv = _mm256_maskload_pd(v, _mm256_set_epi64x(0, -1, -1, -1));
                let (x0, x1) = if BELOW {
                    (
                        _mm256_permute4x64_pd::<BELOW_LO>(xv),
                        _mm256_permute4x64_pd::<BELOW_HI>(xv),
                    )
                } else {
                    (
                        _mm256_permute4x64_pd::<ABOVE_LO>(xv),
                        _mm256_permute4x64_pd::<ABOVE_HI>(xv),
                    )
                };
                self.0 = _mm256_add_pd(self.0, _mm256_mul_pd(h0, x0));
                self.1 = _mm256_add_pd(self.1, _mm256_mul_pd(h1, x1));
                self.2 += tail * *v.add(2);
            }
        }

        #[target_feature(enable = "avx2")]
        #[inline]
        unsafe fn sum(a: Self, b: Self) -> [f64; 9] {
            let mut out = [0.0; 9];
            // SAFETY: `out` holds the eight values stored.
            unsafe {
                _mm256_storeu_pd(out.as_mut_ptr(), _mm256_add_pd(a.0, b.0));
                _mm256_storeu_pd(out.as_mut_ptr().add(4), _mm256_add_pd(a.1, b.1));
            }
            out[8] = a.2 + b.2;
            out
        }
    }

    /// [`super::rows_portable`] in lanes `L`.
    ///
    /// # Safety
    ///
    /// The CPU has `L`'s instruction set (the callers enable it, and this is inlined into
    /// them).
    #[inline(always)]
    unsafe fn rows<L: Lanes>(
        pattern: &BlockPattern,
        upper: &UpperBlocks,
        x: &[Vector3<f64>],
        first: usize,
        out: &mut [Vector3<f64>],
    ) {
        let ends = Ends::new(pattern, upper, x);
        // SAFETY: the CPU has the instruction set (the caller's promise); the blocks' places
        // and columns come from the pattern `ends` was checked against.
        unsafe {
            for (n, yi) in out.iter_mut().enumerate() {
                let (lower, mine, start) = row_parts(pattern, first + n);
                let (mut l0, mut l1) = (L::zero(), L::zero());
                let mut blocks = pattern.mirror[lower.clone()]
                    .iter()
                    .zip(&pattern.cols[lower]);
                while let Some((&at, &c)) = blocks.next() {
                    l0.add::<true>(&ends, at, c);
                    if let Some((&at, &c)) = blocks.next() {
                        l1.add::<true>(&ends, at, c);
                    }
                }
                let (mut u0, mut u1) = (L::zero(), L::zero());
                let mut blocks = pattern.cols[mine].iter().zip(start as u32..);
                while let Some((&c, at)) = blocks.next() {
                    u0.add::<false>(&ends, at, c);
                    if let Some((&c, at)) = blocks.next() {
                        u1.add::<false>(&ends, at, c);
                    }
                }
                *yi = finish(&L::sum(l0, l1), &L::sum(u0, u1));
            }
        }
    }

    /// A kernel entry point: `rows::<$lanes>` in a function that enables `$feature`.
    macro_rules! kernel {
        ($(#[$doc:meta])* $name:ident, $feature:literal, $lanes:ty, $has:ident) => {
            $(#[$doc])*
            pub(super) fn $name(
                pattern: &BlockPattern,
                upper: &UpperBlocks,
                x: &[Vector3<f64>],
                first: usize,
                out: &mut [Vector3<f64>],
            ) {
                #[target_feature(enable = $feature)]
                fn enabled(
                    pattern: &BlockPattern,
                    upper: &UpperBlocks,
                    x: &[Vector3<f64>],
                    first: usize,
                    out: &mut [Vector3<f64>],
                ) {
                    // SAFETY: this function enables the instruction set.
                    unsafe { rows::<$lanes>(pattern, upper, x, first, out) }
                }
                debug_assert!($has());
                // SAFETY: the caller checked that the CPU has the instruction set.
                unsafe { enabled(pattern, upper, x, first, out) }
            }
        };
    }

    kernel!(
        /// Call only when [`has_avx512`].
        rows_avx512, "avx512f", Wide, has_avx512
    );
    kernel!(
        /// Call only when [`has_avx2`].
        rows_avx2, "avx2", Halves, has_avx2
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An irregular symmetric system (a chain with scattered couplings; values of mixed signs
    /// and magnitudes, every block below the diagonal the transpose of its mirror) and an `x`.
    fn system(n: usize) -> (BlockPattern, Vec<Matrix3<f64>>, Vec<Vector3<f64>>) {
        let mut pairs: Vec<[u32; 2]> = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
        pairs.extend((0..n as u32).map(|i| [i, (i * 37 + 11) % n as u32]));
        let pattern = BlockPattern::new(n, &pairs);
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 10f64.powi((seed % 7) as i32 - 3)
        };
        let mut values = vec![Matrix3::zeros(); pattern.n_blocks()];
        for i in 0..n {
            for s in pattern.row(i) {
                let j = pattern.cols()[s] as usize;
                if j >= i {
                    values[s] = Matrix3::from_fn(|_, _| next());
                    let mirror = pattern.slot(j, i).expect("symmetric pattern");
                    values[mirror] = values[s].transpose();
                }
            }
        }
        let x = (0..n)
            .map(|_| Vector3::new(next(), next(), next()))
            .collect();
        (pattern, values, x)
    }

    #[test]
    fn the_triangle_holds_every_block_once_and_its_mirror_finds_it() {
        let (pattern, values, _) = system(300);
        let upper = UpperBlocks::of(&pattern, &values);
        assert_eq!(
            pattern.n_upper(),
            (pattern.n_blocks() + pattern.n_rows()) / 2
        );
        for i in 0..pattern.n_rows() {
            for s in pattern.row(i) {
                let j = pattern.cols()[s] as usize;
                let stored = upper.block(pattern.mirror[s] as usize);
                let expected = if j >= i {
                    values[s]
                } else {
                    values[s].transpose()
                };
                assert_eq!(stored, expected, "block ({i}, {j})");
            }
        }
    }

    #[test]
    fn every_instruction_set_gives_the_same_products_as_documented() {
        let n = 300;
        let (pattern, values, x) = system(n);
        let upper = UpperBlocks::of(&pattern, &values);
        let mut portable = vec![Vector3::zeros(); n];
        rows_portable(&pattern, &upper, &x, 0, &mut portable);
        // The documented arithmetic, block by block, from the full rows.
        for (i, y) in portable.iter().enumerate() {
            let (mut l, mut u) = ([[0.0; 9]; 2], [[0.0; 9]; 2]);
            let (mut below, mut above) = (0, 0);
            for s in pattern.row(i) {
                let (j, m) = (pattern.cols()[s] as usize, values[s]);
                for r in 0..3 {
                    for c in 0..3 {
                        if j < i {
                            l[below % 2][3 * r + c] += m[(r, c)] * x[j][c];
                        } else {
                            u[above % 2][3 * c + r] += m[(r, c)] * x[j][c];
                        }
                    }
                }
                if j < i {
                    below += 1;
                } else {
                    above += 1;
                }
            }
            let sum = |a: &[[f64; 9]; 2]| std::array::from_fn(|k| a[0][k] + a[1][k]);
            assert_eq!(*y, finish(&sum(&l), &sum(&u)), "row {i}");
            // And the product it stands for, to rounding.
            let full: Vector3<f64> = pattern
                .row(i)
                .map(|s| values[s] * x[pattern.cols()[s] as usize])
                .sum();
            assert!((y - full).norm() <= 1e-12 * (1.0 + full.norm()), "row {i}");
        }
        type Kernel = fn(&BlockPattern, &UpperBlocks, &[Vector3<f64>], usize, &mut [Vector3<f64>]);
        let mut kernels: Vec<(&str, Kernel)> = vec![("dispatched", upper_row_products)];
        #[cfg(target_arch = "x86_64")]
        {
            if simd::has_avx2() {
                kernels.push(("AVX2", simd::rows_avx2));
            }
            if simd::has_avx512() {
                kernels.push(("AVX-512", simd::rows_avx512));
            }
        }
        for (name, kernel) in kernels {
            let mut y = vec![Vector3::zeros(); n];
            kernel(&pattern, &upper, &x, 0, &mut y);
            assert_eq!(y, portable, "{name}");
            // A chunk that starts inside the matrix.
            kernel(&pattern, &upper, &x, 100, &mut y[..57]);
            assert_eq!(y[..57], portable[100..157], "{name}");
        }
    }
}
