//! The sparse symmetric block system of the implicit step and its two solvers: faer's sparse
//! Cholesky (symbolic analysis once, numeric factorisation per step, no allocation after the
//! first step) and block-Jacobi preconditioned conjugate gradients.

use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Side};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use sartor_core::Parallelism;
use serde::{Deserialize, Serialize};

use crate::error::StepFailure;

mod team;
mod upper;

use upper::upper_row_products;
pub(crate) use upper::{UpperBlocks, UpperMut};

/// Which linear solver the implicit step uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub enum LinearSolver {
    /// Sparse Cholesky (faer, AMD ordering computed once).
    #[default]
    Cholesky,
    /// Block-Jacobi preconditioned conjugate gradients, warm-started from the current velocity
    /// continued by the last step's acceleration (from zero when that guess is worse than
    /// none).
    ConjugateGradient {
        /// Iteration cap.
        max_iterations: usize,
        /// Stop when `|b − A x| ≤ tol · |b|`.
        relative_tolerance: f64,
        /// A solve that stops short (the cap, or a breakdown) is redone by sparse Cholesky
        /// within the same step (`StepStats::cholesky_fallbacks`); without it, the step fails.
        /// (Left out of the serialised config when on, so that configs and their hashes from
        /// before this option stay valid.)
        #[serde(default = "yes", skip_serializing_if = "is_yes")]
        fallback_to_cholesky: bool,
    },
}

fn yes() -> bool {
    true
}

#[allow(clippy::trivially_copy_pass_by_ref)] // serde's skip_serializing_if passes a reference
fn is_yes(b: &bool) -> bool {
    *b
}

/// What one linear solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinearSolveStats {
    /// CG iterations (0 for Cholesky).
    pub iterations: usize,
    /// Final relative residual `|b − A x| / |b|` (for Cholesky, computed after the solve).
    pub relative_residual: f64,
    /// Time spent in numeric factorisation (Cholesky) or 0, seconds.
    pub factor_secs: f64,
    /// Time spent solving (triangular solves or CG iterations), seconds.
    pub solve_secs: f64,
}

/// Symmetric block-sparse pattern: per vertex row, the sorted columns (vertices) it couples to,
/// the diagonal included (both triangles listed).
///
/// It also lays out the system's *upper triangle* (blocks `(i, j)` with `j ≥ i`, row by row: row
/// `i`'s blocks from its diagonal on, in column order), the only part of the system stored
/// ([`upper`]): the assembly makes the system symmetric bit for bit (every element's blocks
/// below its diagonal are the transposes of those above), and a block below the diagonal is
/// read as the transpose of its mirror.
#[derive(Clone, Debug)]
pub(crate) struct BlockPattern {
    row_offsets: Vec<usize>,
    cols: Vec<u32>,
    diag: Vec<u32>,
    /// Per row, the place of its diagonal block in the upper triangle; `n_upper()` last.
    upper_offsets: Vec<usize>,
    /// Per slot `(i, j)`, the place of block `(min, max)` in the upper triangle.
    mirror: Vec<u32>,
}

impl BlockPattern {
    /// The pattern of `n` vertices coupled by the given pairs (either order; duplicates fine).
    pub fn new(n: usize, pairs: &[[u32; 2]]) -> Self {
        let mut rows: Vec<Vec<u32>> = (0..n as u32).map(|i| vec![i]).collect();
        for &[a, b] in pairs {
            rows[a as usize].push(b);
            rows[b as usize].push(a);
        }
        let mut row_offsets = Vec::with_capacity(n + 1);
        let mut cols = Vec::new();
        let mut diag = Vec::with_capacity(n);
        row_offsets.push(0);
        for (i, mut r) in rows.into_iter().enumerate() {
            r.sort_unstable();
            r.dedup();
            let start = cols.len();
            let d = r.binary_search(&(i as u32)).unwrap_or(0);
            diag.push((start + d) as u32);
            cols.extend_from_slice(&r);
            row_offsets.push(cols.len());
        }
        let mut upper_offsets = Vec::with_capacity(n + 1);
        upper_offsets.push(0);
        for i in 0..n {
            let above = row_offsets[i + 1] - diag[i] as usize;
            upper_offsets.push(upper_offsets[i] + above);
        }
        let mut mirror = vec![0u32; cols.len()];
        for i in 0..n {
            for s in diag[i] as usize..row_offsets[i + 1] {
                let j = cols[s] as usize;
                let place = (upper_offsets[i] + s - diag[i] as usize) as u32;
                mirror[s] = place;
                // The mirror (j, i) below the diagonal: its place in row j's columns.
                let r = row_offsets[j]..row_offsets[j + 1];
                let k = cols[r.clone()]
                    .binary_search(&(i as u32))
                    .expect("pairs go both ways");
                mirror[r.start + k] = place;
            }
        }
        Self {
            row_offsets,
            cols,
            diag,
            upper_offsets,
            mirror,
        }
    }

    /// The place in the upper triangle of slot `s`'s block `(i, j)`, or of its mirror
    /// `(j, i)` when `j < i`.
    pub fn upper_place(&self, s: usize) -> usize {
        self.mirror[s] as usize
    }

    /// Blocks in the upper triangle (the diagonal included).
    pub fn n_upper(&self) -> usize {
        self.upper_offsets[self.n_rows()]
    }

    /// Row `i`'s first place (its diagonal block) in the upper triangle, for `i` in
    /// `0..=n_rows()` (`n_upper()` for `n_rows()`).
    pub fn upper_start(&self, i: usize) -> usize {
        self.upper_offsets[i]
    }

    pub fn n_rows(&self) -> usize {
        self.diag.len()
    }

    #[cfg(test)]
    pub fn n_blocks(&self) -> usize {
        self.cols.len()
    }

    pub fn row(&self, i: usize) -> std::ops::Range<usize> {
        self.row_offsets[i]..self.row_offsets[i + 1]
    }

    pub fn cols(&self) -> &[u32] {
        &self.cols
    }

    pub fn diag_slot(&self, i: usize) -> usize {
        self.diag[i] as usize
    }

    /// The slot of block `(i, j)`; `None` if not in the pattern.
    pub fn slot(&self, i: usize, j: usize) -> Option<usize> {
        let r = self.row(i);
        self.cols[r.clone()]
            .binary_search(&(j as u32))
            .ok()
            .map(|k| r.start + k)
    }
}

/// Number of vertices per parallel chunk (deterministic: results never depend on the thread
/// count, only on this constant). Threads take whole chunks: at 512 the two threads of the
/// 8,710-triangle shirt's solve got 2,048 and 2,399 rows (46 / 54 %); at 128, 2,176 and 2,271.
const CHUNK: usize = 128;

/// `y = A x` for the system whose upper triangle is `upper` ([`upper`]'s products, in
/// chunks of [`CHUNK`] rows).
pub(crate) fn block_product(
    pattern: &BlockPattern,
    upper: &UpperBlocks,
    x: &[Vector3<f64>],
    y: &mut [Vector3<f64>],
    par: Parallelism,
) {
    match par {
        Parallelism::Sequential => y
            .chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, out)| upper_row_products(pattern, upper, x, c * CHUNK, out)),
        Parallelism::Rayon => y
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, out)| upper_row_products(pattern, upper, x, c * CHUNK, out)),
    }
}

/// `Σ a_i · b_i`, summed per fixed chunk and then in chunk order (deterministic; the team
/// sums its threads' chunks the same way).
fn dot(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.chunks(CHUNK)
        .zip(b.chunks(CHUNK))
        .map(|(ca, cb)| chunk_dot(ca, cb))
        .sum()
}

/// The block-diagonal preconditioner's block for the diagonal block `d`: its inverse, or where
/// it has none the inverse of its diagonal (1 for a zero).
fn inverse_block(d: &Matrix3<f64>) -> Matrix3<f64> {
    d.try_inverse().unwrap_or_else(|| {
        Matrix3::from_diagonal(&d.diagonal().map(|v| if v != 0.0 { 1.0 / v } else { 1.0 }))
    })
}

/// Reusable state of the two solvers for one pattern.
pub(crate) struct LinearWorkspace {
    // Cholesky: lower-triangular scalar CSC and where each entry comes from.
    csc_col_ptr: Vec<usize>,
    csc_row_idx: Vec<usize>,
    csc_source: Vec<(u32, u8)>,
    csc_values: Vec<f64>,
    symbolic: Option<SymbolicCholesky<usize>>,
    factor_values: Vec<f64>,
    factor_stack: Option<MemBuffer>,
    solve_stack: Option<MemBuffer>,
    flat: Vec<f64>,
    // CG.
    residual: Vec<Vector3<f64>>,
    preconditioned: Vec<Vector3<f64>>,
    direction: Vec<Vector3<f64>>,
    product: Vec<Vector3<f64>>,
    inverse_diagonal: Vec<Matrix3<f64>>,
    pair_partial: Vec<(f64, f64)>,
    /// The CG team's plan, for the last thread count used.
    team: Option<team::Plan>,
}

impl LinearWorkspace {
    pub fn new(pattern: &BlockPattern) -> Self {
        let n = pattern.n_rows();
        let mut csc_col_ptr = Vec::with_capacity(3 * n + 1);
        let mut csc_row_idx = Vec::new();
        let mut csc_source = Vec::new();
        csc_col_ptr.push(0);
        for j in 0..n {
            for c in 0..3 {
                // Column 3j + c holds rows 3i + r ≥ 3j + c from blocks (i, j), i ≥ j; by symmetry
                // row j's columns are column j's rows.
                for s in pattern.row(j) {
                    let i = pattern.cols[s] as usize;
                    if i < j {
                        continue;
                    }
                    // Block (i, j) is stored as (j, i), its transpose, unless i = j: its entry
                    // (r, c) is value 3 r + c there (column-major), 3 c + r of a diagonal block.
                    let place = pattern.upper_place(s) as u32;
                    for r in 0..3 {
                        if 3 * i + r >= 3 * j + c {
                            let value = if i == j { 3 * c + r } else { 3 * r + c };
                            csc_row_idx.push(3 * i + r);
                            csc_source.push((place, value as u8));
                        }
                    }
                }
                csc_col_ptr.push(csc_row_idx.len());
            }
        }
        Self {
            csc_values: vec![0.0; csc_row_idx.len()],
            csc_col_ptr,
            csc_row_idx,
            csc_source,
            symbolic: None,
            factor_values: Vec::new(),
            factor_stack: None,
            solve_stack: None,
            flat: vec![0.0; 3 * n],
            residual: vec![Vector3::zeros(); n],
            preconditioned: vec![Vector3::zeros(); n],
            direction: vec![Vector3::zeros(); n],
            product: vec![Vector3::zeros(); n],
            inverse_diagonal: vec![Matrix3::identity(); n],
            pair_partial: vec![(0.0, 0.0); n.div_ceil(CHUNK)],
            team: None,
        }
    }

    fn faer_par(par: Parallelism) -> faer::Par {
        match par {
            Parallelism::Sequential => faer::Par::Seq,
            Parallelism::Rayon => faer::Par::rayon(0),
        }
    }

    /// Solve `A x = b` by sparse Cholesky; `x` is overwritten.
    pub fn solve_cholesky(
        &mut self,
        pattern: &BlockPattern,
        upper: &UpperBlocks,
        b: &[Vector3<f64>],
        x: &mut [Vector3<f64>],
        par: Parallelism,
    ) -> Result<LinearSolveStats, StepFailure> {
        let start = Instant::now();
        let n3 = 3 * pattern.n_rows();
        for (dst, &(place, k)) in self.csc_values.iter_mut().zip(&self.csc_source) {
            *dst = upper.value(place as usize, k as usize);
        }
        if self.csc_values.iter().any(|v| !v.is_finite()) {
            return Err(StepFailure::NonFinite {
                what: "linear system",
            });
        }
        let symbolic_ref = SymbolicSparseColMatRef::new_checked(
            n3,
            n3,
            &self.csc_col_ptr,
            None,
            &self.csc_row_idx,
        );
        let fpar = Self::faer_par(par);
        if self.symbolic.is_none() {
            let symbolic = factorize_symbolic_cholesky(
                symbolic_ref,
                Side::Lower,
                SymmetricOrdering::Amd,
                CholeskySymbolicParams::default(),
            )
            .map_err(|e| StepFailure::Factorization {
                message: format!("{e:?}"),
            })?;
            self.factor_values = vec![0.0; symbolic.len_val()];
            self.factor_stack = Some(MemBuffer::new(
                symbolic.factorize_numeric_llt_scratch::<f64>(fpar, Default::default()),
            ));
            self.solve_stack = Some(MemBuffer::new(
                symbolic.solve_in_place_scratch::<f64>(1, fpar),
            ));
            self.symbolic = Some(symbolic);
        }
        let (Some(symbolic), Some(factor_stack), Some(solve_stack)) = (
            self.symbolic.as_ref(),
            self.factor_stack.as_mut(),
            self.solve_stack.as_mut(),
        ) else {
            return Err(StepFailure::Factorization {
                message: "no symbolic factorisation".into(),
            });
        };
        let matrix = SparseColMatRef::new(symbolic_ref, &self.csc_values);
        let llt = symbolic
            .factorize_numeric_llt(
                &mut self.factor_values,
                matrix,
                Side::Lower,
                Default::default(),
                fpar,
                MemStack::new(factor_stack),
                Default::default(),
            )
            .map_err(|e| StepFailure::Factorization {
                message: format!("{e:?}"),
            })?;
        let factored = Instant::now();
        for (i, v) in b.iter().enumerate() {
            self.flat[3 * i..3 * i + 3].copy_from_slice(v.as_slice());
        }
        let llt: LltRef<'_, usize, f64> = llt;
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut self.flat, n3, 1),
            fpar,
            MemStack::new(solve_stack),
        );
        for (i, v) in x.iter_mut().enumerate() {
            *v = Vector3::new(self.flat[3 * i], self.flat[3 * i + 1], self.flat[3 * i + 2]);
        }
        let solved = Instant::now();
        // Residual check (one matvec): catches a silently bad factorisation.
        block_product(pattern, upper, x, &mut self.product, par);
        let mut r2 = 0.0;
        let mut b2 = 0.0;
        for (ax, bi) in self.product.iter().zip(b) {
            r2 += (bi - ax).norm_squared();
            b2 += bi.norm_squared();
        }
        let relative_residual = if b2 > 0.0 {
            (r2 / b2).sqrt()
        } else {
            r2.sqrt()
        };
        Ok(LinearSolveStats {
            iterations: 0,
            relative_residual,
            factor_secs: (factored - start).as_secs_f64(),
            solve_secs: (solved - factored).as_secs_f64(),
        })
    }

    /// Solve `A x = b` by block-Jacobi preconditioned CG starting from the given `x`; `upper`
    /// is `A`'s upper triangle as `pattern` lays it out ([`upper`]).
    pub fn solve_cg(
        &mut self,
        pattern: &BlockPattern,
        upper: &UpperBlocks,
        b: &[Vector3<f64>],
        x: &mut [Vector3<f64>],
        max_iterations: usize,
        relative_tolerance: f64,
        par: Parallelism,
    ) -> Result<LinearSolveStats, StepFailure> {
        let start = Instant::now();
        let n = pattern.n_rows();
        let stats = |iterations, relative_residual| LinearSolveStats {
            iterations,
            relative_residual,
            factor_secs: 0.0,
            solve_secs: start.elapsed().as_secs_f64(),
        };
        // Preconditioned by the block diagonal. Each iteration is three passes over the
        // vertices in chunks of `CHUNK`: (1) q = A p with the chunk's share of p·q; (2) the x
        // and r updates, z = P⁻¹ r, with the chunk's shares of r·z and r·r; (3) p = z + β p.
        // Every dot product is summed per chunk and then over the chunks in order: the same
        // numbers on any thread count, and the same as separate dot products. With rayon the
        // set-up and the loop run on a team of threads, one range of rows each ([`team`]).
        let threads = match par {
            Parallelism::Sequential => 1,
            Parallelism::Rayon => rayon::current_num_threads().min(n.div_ceil(CHUNK)),
        };
        if threads > 1 {
            let (iterations, relative) = self.solve_cg_team(
                threads,
                &team::Problem {
                    pattern,
                    upper,
                    b,
                    max_iterations,
                    relative_tolerance,
                },
                x,
            )?;
            return Ok(stats(iterations, relative));
        }
        // One thread from here on (on rayon too when the rows fit in one chunk).
        for (i, inverse) in self.inverse_diagonal.iter_mut().enumerate() {
            *inverse = inverse_block(&upper.block(pattern.upper_start(i)));
        }
        block_product(
            pattern,
            upper,
            x,
            &mut self.product,
            Parallelism::Sequential,
        );
        for i in 0..n {
            self.residual[i] = b[i] - self.product[i];
        }
        let b_norm = dot(b, b).sqrt();
        // A guess worse than none (its residual above |b|, e.g. the previous velocity when the
        // body has just changed direction) is dropped: CG then starts from zero, whose residual
        // is `b` itself.
        let mut r_norm = dot(&self.residual, &self.residual).sqrt();
        if r_norm > b_norm {
            x.iter_mut().for_each(|v| *v = Vector3::zeros());
            self.residual.copy_from_slice(b);
            r_norm = b_norm;
        }
        for i in 0..n {
            self.preconditioned[i] = self.inverse_diagonal[i] * self.residual[i];
        }
        self.direction.copy_from_slice(&self.preconditioned);
        if b_norm == 0.0 {
            x.iter_mut().for_each(|v| *v = Vector3::zeros());
            return Ok(stats(0, 0.0));
        }
        let mut rz = dot(&self.residual, &self.preconditioned);
        let mut relative = r_norm / b_norm;
        let mut iterations = 0;
        while relative > relative_tolerance {
            if iterations == max_iterations || !relative.is_finite() {
                return Err(StepFailure::SolverNotConverged {
                    iterations,
                    relative_residual: relative,
                });
            }
            let p_ap = self.product_and_dot(pattern, upper);
            if p_ap.is_nan() || p_ap <= 0.0 {
                return Err(StepFailure::SolverNotConverged {
                    iterations,
                    relative_residual: relative,
                });
            }
            let alpha = rz / p_ap;
            let (rz_new, rr) = self.update_and_precondition(x, alpha);
            let beta = rz_new / rz;
            rz = rz_new;
            self.update_direction(beta);
            relative = rr.sqrt() / b_norm;
            iterations += 1;
        }
        Ok(stats(iterations, relative))
    }
}

impl LinearWorkspace {
    /// [`Self::solve_cg`] on a team of `threads` threads ([`team`]), with the plan kept from the
    /// last solve when it is for as many threads.
    #[inline(never)]
    fn solve_cg_team(
        &mut self,
        threads: usize,
        problem: &team::Problem<'_>,
        x: &mut [Vector3<f64>],
    ) -> Result<(usize, f64), StepFailure> {
        let n = problem.pattern.n_rows();
        let plan = match &mut self.team {
            Some(plan) if plan.fits(n, threads) => plan,
            slot => slot.insert(team::Plan::new(problem.pattern, threads)),
        };
        let state = team::State {
            x,
            inverse_diagonal: &mut self.inverse_diagonal,
            residual: &mut self.residual,
            preconditioned: &mut self.preconditioned,
            product: &mut self.product,
            direction: &mut self.direction,
        };
        team::iterate(plan, problem, state)
    }

    /// `product = A direction` (from `A`'s upper triangle); returns `direction · product` (per chunk, then in order).
    fn product_and_dot(&mut self, pattern: &BlockPattern, upper: &UpperBlocks) -> f64 {
        let direction = &self.direction;
        self.product
            .chunks_mut(CHUNK)
            .enumerate()
            .map(|(c, out)| {
                let start = c * CHUNK;
                upper_row_products(pattern, upper, direction, start, out);
                chunk_dot(&direction[start..start + out.len()], out)
            })
            .sum()
    }

    /// `x += α p`, `r −= α q`, `z = P⁻¹ r`; returns `(r · z, r · r)` (per chunk, in order).
    fn update_and_precondition(&mut self, x: &mut [Vector3<f64>], alpha: f64) -> (f64, f64) {
        let (direction, product, inverse_diagonal) =
            (&self.direction, &self.product, &self.inverse_diagonal);
        x.chunks_mut(CHUNK)
            .zip(self.residual.chunks_mut(CHUNK))
            .zip(self.preconditioned.chunks_mut(CHUNK))
            .zip(self.pair_partial.iter_mut())
            .enumerate()
            .for_each(|(c, (((x, r), z), p))| {
                let rows = c * CHUNK..c * CHUNK + x.len();
                *p = update_chunk(
                    Update { x, r, z },
                    &direction[rows.clone()],
                    &product[rows.clone()],
                    &inverse_diagonal[rows],
                    alpha,
                );
            });
        (
            self.pair_partial.iter().map(|p| p.0).sum(),
            self.pair_partial.iter().map(|p| p.1).sum(),
        )
    }

    /// `p = z + β p`.
    fn update_direction(&mut self, beta: f64) {
        update_direction(&mut self.direction, &self.preconditioned, beta);
    }
}

/// `Σ a_k · b_k` in order: a chunk's share of a dot product.
fn chunk_dot(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a.dot(b)).sum()
}

/// A chunk's rows of what CG's second pass writes.
struct Update<'a> {
    x: &'a mut [Vector3<f64>],
    r: &'a mut [Vector3<f64>],
    z: &'a mut [Vector3<f64>],
}

/// CG's second pass over a chunk, in one sweep: `x += α p`, `r −= α q`, `z = P⁻¹ r`
/// (`inverse`: the preconditioner's blocks), returning the chunk's `(r · z, r · r)` summed in
/// row order (the same numbers as three sweeps and two [`chunk_dot`]s).
fn update_chunk(
    out: Update<'_>,
    p: &[Vector3<f64>],
    q: &[Vector3<f64>],
    inverse: &[Matrix3<f64>],
    alpha: f64,
) -> (f64, f64) {
    let Update { x, r, z } = out;
    let (mut r_z, mut r_r) = (-0.0, -0.0);
    for ((((x, r), z), p), (q, inverse)) in x
        .iter_mut()
        .zip(r.iter_mut())
        .zip(z.iter_mut())
        .zip(p)
        .zip(q.iter().zip(inverse))
    {
        *x += p * alpha;
        *r -= q * alpha;
        *z = inverse * *r;
        r_z += r.dot(z);
        r_r += r.dot(r);
    }
    (r_z, r_r)
}

/// CG's third pass: `p = z + β p`.
fn update_direction(p: &mut [Vector3<f64>], z: &[Vector3<f64>], beta: f64) {
    for (pi, zi) in p.iter_mut().zip(z) {
        *pi = zi + *pi * beta;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1-D chain Laplacian plus mass as 3 × 3 blocks: SPD.
    fn chain(n: usize) -> (BlockPattern, Vec<Matrix3<f64>>) {
        let pairs: Vec<[u32; 2]> = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
        let pattern = BlockPattern::new(n, &pairs);
        let mut values = vec![Matrix3::zeros(); pattern.n_blocks()];
        for i in 0..n {
            for s in pattern.row(i) {
                let j = pattern.cols()[s] as usize;
                values[s] = if i == j {
                    Matrix3::new(3.0, 0.1, 0.0, 0.1, 2.5, 0.2, 0.0, 0.2, 3.0)
                } else {
                    Matrix3::identity() * -1.0
                };
            }
        }
        (pattern, values)
    }

    #[test]
    fn the_cholesky_fallback_is_on_by_default_and_left_out_of_saved_configs() {
        // Configs (and their hashes) written before the option read and write as before.
        let old = r#"{"ConjugateGradient":{"max_iterations":1000,"relative_tolerance":1e-5}}"#;
        let solver: LinearSolver = serde_json::from_str(old).expect("parses");
        assert_eq!(
            solver,
            LinearSolver::ConjugateGradient {
                max_iterations: 1000,
                relative_tolerance: 1e-5,
                fallback_to_cholesky: true,
            }
        );
        let written = serde_json::to_string(&solver).expect("writes");
        assert!(!written.contains("fallback"), "{written}");
        let off = LinearSolver::ConjugateGradient {
            max_iterations: 1000,
            relative_tolerance: 1e-5,
            fallback_to_cholesky: false,
        };
        let text = serde_json::to_string(&off).expect("writes");
        assert!(text.contains("\"fallback_to_cholesky\":false"), "{text}");
        assert_eq!(
            serde_json::from_str::<LinearSolver>(&text).expect("parses"),
            off
        );
    }

    #[test]
    fn cg_gives_the_same_bits_on_any_number_of_threads() {
        // Six chunks, the last one short; a chain with long-range couplings so that every
        // thread's rows read other threads' rows of p.
        let n = 5 * CHUNK + 77;
        let mut pairs: Vec<[u32; 2]> = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
        pairs.extend((0..n as u32).map(|i| [i, (i * 613 + 29) % n as u32]));
        pairs.retain(|[a, b]| a != b);
        let pattern = BlockPattern::new(n, &pairs);
        let mut values = vec![Matrix3::zeros(); pattern.n_blocks()];
        for i in 0..n {
            let row = pattern.row(i);
            let degree = row.len() as f64;
            for s in row {
                let j = pattern.cols()[s] as usize;
                values[s] = if i == j {
                    Matrix3::new(3.0, 0.1, 0.0, 0.1, 2.5, 0.2, 0.0, 0.2, 3.0) * degree
                } else {
                    Matrix3::identity() * -(1.0 + 0.1 * ((i + j) % 5) as f64)
                };
            }
        }
        let upper = UpperBlocks::of(&pattern, &values);
        let b: Vec<Vector3<f64>> = (0..n)
            .map(|i| Vector3::new((i as f64).sin(), 1.0, (i as f64 * 0.3).cos()))
            .collect();
        // A guess near the solution, one worse than none (dropped by the set-up), and a zero
        // right-hand side (its solution zero whatever the guess).
        let zero = vec![Vector3::zeros(); n];
        for (guess, b, what) in [
            (Vector3::new(0.01, 0.0, -0.02), &b, "a near guess"),
            (
                Vector3::new(40.0, -30.0, 20.0),
                &b,
                "a guess worse than none",
            ),
            (Vector3::new(0.01, 0.0, -0.02), &zero, "b = 0"),
        ] {
            let solve = |par, max_iterations| {
                let mut ws = LinearWorkspace::new(&pattern);
                let mut x = vec![guess; n];
                let stats = ws.solve_cg(&pattern, &upper, b, &mut x, max_iterations, 1e-11, par);
                (
                    stats.map(|s| (s.iterations, s.relative_residual.to_bits())),
                    x,
                )
            };
            let (sequential, x_sequential) = solve(Parallelism::Sequential, 500);
            if b == &zero {
                assert_eq!(sequential, Ok((0, 0)), "{what}");
                assert!(x_sequential == zero, "{what}");
            } else {
                assert!(
                    sequential.as_ref().is_ok_and(|s| s.0 > 5),
                    "{what}: {sequential:?}"
                );
            }
            let (short, _) = solve(Parallelism::Sequential, 3);
            for threads in 1..=7 {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                let (stats, x) = pool.install(|| solve(Parallelism::Rayon, 500));
                assert_eq!(stats, sequential, "{what}, {threads} threads");
                assert!(x == x_sequential, "{what}, {threads} threads: another x");
                if b == &zero {
                    continue;
                }
                // The same failure, at the same iteration, when the cap is hit.
                let (failed, _) = pool.install(|| solve(Parallelism::Rayon, 3));
                assert!(
                    matches!(
                        (&failed, &short),
                        (Err(StepFailure::SolverNotConverged { iterations: 3, relative_residual: a }),
                         Err(StepFailure::SolverNotConverged { iterations: 3, relative_residual: b }))
                        if a.to_bits() == b.to_bits()
                    ),
                    "{what}, {threads} threads: {failed:?} against {short:?}"
                );
            }
        }
    }

    #[test]
    fn cholesky_and_cg_agree() {
        let n = 700; // more than one parallel chunk
        let (pattern, values) = chain(n);
        let upper = UpperBlocks::of(&pattern, &values);
        let b: Vec<Vector3<f64>> = (0..n)
            .map(|i| Vector3::new((i as f64).sin(), 1.0, (i as f64 * 0.3).cos()))
            .collect();
        let mut ws = LinearWorkspace::new(&pattern);
        for par in [Parallelism::Sequential, Parallelism::Rayon] {
            let mut x_chol = vec![Vector3::zeros(); n];
            let stats = ws
                .solve_cholesky(&pattern, &upper, &b, &mut x_chol, par)
                .expect("SPD");
            assert!(stats.relative_residual < 1e-12, "{stats:?}");
            let mut x_cg = vec![Vector3::zeros(); n];
            let stats = ws
                .solve_cg(&pattern, &upper, &b, &mut x_cg, 500, 1e-12, par)
                .expect("converges");
            assert!(stats.iterations > 0);
            let err: f64 = x_chol
                .iter()
                .zip(&x_cg)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            assert!(err < 1e-9, "max difference {err}");
        }
        // A guess far worse than none is dropped: CG takes as many iterations as from zero.
        let mut from_zero = vec![Vector3::zeros(); n];
        let zero = ws
            .solve_cg(
                &pattern,
                &upper,
                &b,
                &mut from_zero,
                500,
                1e-10,
                Parallelism::Sequential,
            )
            .expect("converges");
        let mut from_bad = vec![Vector3::new(1e6, -1e6, 1e6); n];
        let bad = ws
            .solve_cg(
                &pattern,
                &upper,
                &b,
                &mut from_bad,
                500,
                1e-10,
                Parallelism::Sequential,
            )
            .expect("converges from a bad guess");
        assert_eq!(bad.iterations, zero.iterations);
        assert_eq!(from_bad, from_zero);
        let mut x = vec![Vector3::zeros(); n];
        let err = ws
            .solve_cg(
                &pattern,
                &upper,
                &b,
                &mut x,
                2,
                1e-12,
                Parallelism::Sequential,
            )
            .expect_err("must fail");
        assert!(matches!(
            err,
            StepFailure::SolverNotConverged { iterations: 2, .. }
        ));
    }
}
