//! The CG solve of [`super::LinearWorkspace::solve_cg`] on several threads, its set-up (the
//! preconditioner, the first residual and the norms) and its loop: the threads of the current
//! rayon pool, each owning a fixed range of rows for the whole solve.
//!
//! A CG iteration is three short passes over the vertices, the first two each ended by a
//! global sum. As rayon fork-joins each pass paid a hand-off between threads (16 µs measured on
//! the 2-core VM) against 20–40 µs of work at 8,710 triangles, and the two-thread solve was no
//! faster than one thread's. Here one `rayon::broadcast` starts the loop on every thread of the
//! pool, each runs it over its own rows, and the sums wait at a spinning barrier (well under a
//! microsecond when both threads have a core). The broadcast waits for every thread of the
//! pool: the simulator calls it from its step, when the pool has no other work. (Threads
//! spawned per solve instead cost 60 µs each and ran beside the pool's idle threads: slower.)
//! The set-up before the loop (the preconditioner, `r = b − A x` for the guess, the norms, `z`
//! and `p`) is two more passes on the same team, not four fork-joins and serial loops.
//!
//! What a thread reads of other threads' rows is the search direction `p` at the columns its
//! rows' blocks reach beyond its own rows (its *imports*, the halo of a compact part of the
//! cloth: a few percent of the rows). Each thread keeps `p` at its rows and its imports; the
//! owners publish `z` at the rows others import (their *exports*) with the second pass's sums,
//! and after that barrier every thread computes `p = z + β p` at its imports as the owner does
//! at its rows (the same expression: the same bits). So the third pass needs no barrier: two
//! per iteration, not three, and no copy of the other threads' whole rows of `p` (which the
//! loop made after a third barrier before). With the rows balanced too (below), the
//! two-thread solve went from 31.3–32.7 to 28.3–28.8 ms per frame at 4,210 triangles and from
//! 91.4–96.4 to 84.2–85.5 at 8,710 (`bench sim --sizes … --frames 20 / 10`, the Intel Xeon VM,
//! builds alternated; the same cloth hashes). The plan (rows, imports, exports) and the
//! buffers are made once per pattern and thread count and kept in the workspace.
//!
//! Bitwise the same as the sequential loop, on any number of threads: every chunk's share of
//! each dot product is computed as the sequential loop computes it, and every thread sums the
//! shares in chunk order, so that all threads hold the same scalars and take the same branches.
//! The threads' rows are balanced by the work of the rows ([`split_rows`]), not cut on
//! [`CHUNK`] boundaries: a chunk may then straddle two threads. The thread with its first row
//! sums its own rows' terms into the chunk's share, in row order; the others publish their
//! rows' terms one by one, and after the barrier every thread adds them to the share in row
//! order: the sequential sum, term for term. (Cut on chunk boundaries, the 4,210-triangle
//! shirt's 2,168 rows went 1,024 / 1,144 to the two threads, and the first waited 145 µs per
//! solve of about 1 ms at the barriers.)

use std::ops::Range;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};

use nalgebra::{Matrix3, Vector3};

use super::upper::{UpperBlocks, upper_row_products};
use super::{BlockPattern, CHUNK, Update, inverse_block, update_chunk, update_direction};
use crate::error::StepFailure;

/// Spins of a thread waiting at the barrier before it starts yielding its core (when the team
/// has more threads than free cores, e.g. tests running side by side). The spin is a plain
/// load, without `std::hint::spin_loop` (PAUSE). On the 2-core VM, two threads solving a
/// 4,500-row test system took 52 µs per iteration in about half of the solves with PAUSE and
/// 2–7× that in the others (a hypervisor may take away a vCPU that spins on PAUSE); without it,
/// 55–175 µs, against 88 µs for one thread.
const SPINS: u32 = 4_000;

/// The system `A x = b` and when to stop.
pub(super) struct Problem<'a> {
    pub pattern: &'a BlockPattern,
    /// `A`'s upper triangle ([`super::upper`]).
    pub upper: &'a UpperBlocks,
    pub b: &'a [Vector3<f64>],
    pub max_iterations: usize,
    pub relative_tolerance: f64,
}

/// The CG state, all rows: `x` (the guess on entry), the preconditioner's blocks, the residual
/// `r`, the preconditioned residual `z`, the product `q = A p` and the search direction `p`.
pub(super) struct State<'a> {
    pub x: &'a mut [Vector3<f64>],
    pub inverse_diagonal: &'a mut [Matrix3<f64>],
    pub residual: &'a mut [Vector3<f64>],
    pub preconditioned: &'a mut [Vector3<f64>],
    pub product: &'a mut [Vector3<f64>],
    pub direction: &'a mut [Vector3<f64>],
}

/// How a team of threads shares the rows of a pattern, and the buffers it reuses from solve
/// to solve (kept by the workspace: made once per pattern and thread count).
pub(super) struct Plan {
    threads: usize,
    n: usize,
    /// Per thread, its rows.
    ranges: Vec<Range<usize>>,
    /// The chunks' runs of rows that a thread other than the one with the chunk's first row
    /// holds, in row order.
    continuations: Vec<Continuation>,
    /// Per thread, the rows of the others its products read (`p`'s halo): `(owner, place in the
    /// owner's exports, row)`, by owner and row.
    imports: Vec<Vec<(usize, usize, usize)>>,
    /// Per thread, its rows some other thread reads, in order.
    exports: Vec<Vec<usize>>,
    /// Per thread, `z` at its exports as of its last update pass.
    published: Vec<Mutex<Vec<Vector3<f64>>>>,
    /// `p · q`, `r · z` and `r · r` (and in the set-up `b · b` in `p_q`).
    p_q: Sums,
    r_z: Sums,
    r_r: Sums,
    /// The search direction `p` of every thread but the first (which works in the
    /// workspace's): its own rows and its imports are current.
    copies: Vec<Vec<Vector3<f64>>>,
}

impl Plan {
    /// The plan for `threads` threads (at most the pattern's rows).
    pub fn new(pattern: &BlockPattern, threads: usize) -> Self {
        let n = pattern.n_rows();
        let ranges = split_rows(pattern, threads);
        let owner = |j: usize| ranges.partition_point(|r| r.end <= j);
        let mut wanted: Vec<Vec<usize>> = ranges
            .iter()
            .map(|rows| {
                let mut halo: Vec<usize> = rows
                    .clone()
                    .flat_map(|i| pattern.cols[pattern.row(i)].iter().map(|&j| j as usize))
                    .filter(|j| !rows.contains(j))
                    .collect();
                halo.sort_unstable();
                halo.dedup();
                halo
            })
            .collect();
        let mut exports: Vec<Vec<usize>> = vec![Vec::new(); threads];
        for &j in wanted.iter().flatten() {
            exports[owner(j)].push(j);
        }
        for e in &mut exports {
            e.sort_unstable();
            e.dedup();
        }
        let imports = wanted
            .iter_mut()
            .map(|halo| {
                halo.iter()
                    .map(|&j| {
                        let u = owner(j);
                        let place = exports[u].binary_search(&j).expect("exported");
                        (u, place, j)
                    })
                    .collect()
            })
            .collect();
        let continuations = continuations(&ranges);
        let terms = continuations.last().map_or(0, |c| c.base + c.rows.len());
        let chunks = n.div_ceil(CHUNK);
        let sums = || Sums {
            shares: (0..chunks).map(|_| AtomicU64::new(0)).collect(),
            terms: (0..terms).map(|_| AtomicU64::new(0)).collect(),
        };
        Self {
            threads,
            n,
            published: exports
                .iter()
                .map(|e| Mutex::new(vec![Vector3::zeros(); e.len()]))
                .collect(),
            ranges,
            continuations,
            imports,
            exports,
            p_q: sums(),
            r_z: sums(),
            r_r: sums(),
            copies: vec![vec![Vector3::zeros(); n]; threads - 1],
        }
    }

    /// Whether the plan is for `threads` threads over `n` rows.
    pub fn fits(&self, n: usize, threads: usize) -> bool {
        self.n == n && self.threads == threads
    }
}

/// Set up and iterate CG on the first `threads` threads of the current rayon pool until the
/// relative residual is within the tolerance: `(iterations, relative residual)`, exactly as the
/// sequential solve returns them. On return `x` holds the solution; the other buffers are
/// scratch. `plan` must be for the problem's pattern.
pub(super) fn iterate(
    plan: &mut Plan,
    problem: &Problem<'_>,
    state: State<'_>,
) -> Result<(usize, f64), StepFailure> {
    let Plan {
        threads,
        ref ranges,
        ref continuations,
        ref imports,
        ref exports,
        ref published,
        ref p_q,
        ref r_z,
        ref r_r,
        ref mut copies,
        ..
    } = *plan;
    let shared = Shared {
        problem,
        ranges,
        continuations,
        imports,
        exports,
        published,
        p_q,
        r_z,
        r_r,
        barrier: Barrier::new(threads),
    };
    let State {
        x,
        inverse_diagonal,
        residual,
        preconditioned,
        product,
        direction,
    } = state;
    // The guess, for the set-up's product `A x`: every thread's `p` holds it at first (at its
    // rows and imports).
    direction.copy_from_slice(x);
    for (copy, (rows, imports)) in copies.iter_mut().zip(ranges.iter().zip(imports).skip(1)) {
        copy[rows.clone()].copy_from_slice(&x[rows.clone()]);
        for &(_, _, j) in imports {
            copy[j] = x[j];
        }
    }
    // Thread 0 works in `direction`; every other thread in its own copy.
    let mut ps: Vec<&mut [Vector3<f64>]> = vec![direction];
    ps.extend(copies.iter_mut().map(|c| c.as_mut_slice()));
    let slots: Vec<Mutex<Option<Own<'_>>>> = split(x, ranges)
        .into_iter()
        .zip(split(inverse_diagonal, ranges))
        .zip(split(residual, ranges))
        .zip(split(preconditioned, ranges))
        .zip(split(product, ranges))
        .zip(ps)
        .enumerate()
        .map(|(t, (((((x, inverse), r), z), q), p))| {
            Mutex::new(Some(Own {
                thread: t,
                x,
                inverse,
                r,
                z,
                q,
                p,
            }))
        })
        .collect();
    // The calling thread takes the first rows, the next pool thread the next, and so on: the
    // parallel assembly fills its first share on the calling thread and hands the next to the
    // others in the same way, so that each thread solves on the rows it has just written
    // rather than reading them from another core's cache.
    let caller = rayon::current_thread_index();
    let results = rayon::broadcast(|ctx| {
        let slot = caller.map_or(ctx.index(), |c| {
            (ctx.index() + ctx.num_threads() - c) % ctx.num_threads()
        });
        let taken = slots
            .get(slot)
            .and_then(|slot| slot.lock().expect("unpoisoned").take());
        taken.map(|own| shared.work(own))
    });
    let mut results = results.into_iter().flatten();
    results.next().expect("thread 0 ran")
}

/// One thread's rows of the state, and its full copy of the search direction `p`.
struct Own<'a> {
    thread: usize,
    x: &'a mut [Vector3<f64>],
    inverse: &'a mut [Matrix3<f64>],
    r: &'a mut [Vector3<f64>],
    z: &'a mut [Vector3<f64>],
    q: &'a mut [Vector3<f64>],
    p: &'a mut [Vector3<f64>],
}

/// What the team shares (see [`Plan`]).
struct Shared<'a> {
    problem: &'a Problem<'a>,
    ranges: &'a [Range<usize>],
    continuations: &'a [Continuation],
    imports: &'a [Vec<(usize, usize, usize)>],
    exports: &'a [Vec<usize>],
    published: &'a [Mutex<Vec<Vector3<f64>>>],
    p_q: &'a Sums,
    r_z: &'a Sums,
    r_r: &'a Sums,
    barrier: Barrier,
}

/// A chunk's rows after its first thread's: their terms of each dot product are published one
/// by one, at `base` on.
struct Continuation {
    chunk: usize,
    rows: Range<usize>,
    base: usize,
}

/// A dot product's parts (f64 bits): per chunk, the sum of the terms of its first thread's
/// rows (the whole chunk's when one thread holds it), and the terms of the continuations' rows.
struct Sums {
    shares: Vec<AtomicU64>,
    terms: Vec<AtomicU64>,
}

/// A thread's rows within one chunk: `local` relative to the thread's first row, and where its
/// terms go when it continues a chunk another thread started.
struct Piece {
    chunk: usize,
    local: Range<usize>,
    terms: Option<usize>,
}

impl Sums {
    /// The piece's part: its rows' terms `term(k)` (`k` local to the piece, in order), summed
    /// into the chunk's share or published one by one.
    #[inline]
    fn put(&self, piece: &Piece, len: usize, mut term: impl FnMut(usize) -> f64) {
        match piece.terms {
            None => {
                let share: f64 = (0..len).map(&mut term).sum();
                self.shares[piece.chunk].store(share.to_bits(), Ordering::Relaxed);
            }
            Some(base) => {
                for k in 0..len {
                    self.terms[base + k].store(term(k).to_bits(), Ordering::Relaxed);
                }
            }
        }
    }

    /// The dot product, after a barrier: each chunk's share with its continuations' terms
    /// added in row order, then the chunks in order (as the sequential loop sums).
    fn total(&self, continuations: &[Continuation]) -> f64 {
        let load = |a: &AtomicU64| f64::from_bits(a.load(Ordering::Relaxed));
        let mut next = continuations.iter().peekable();
        self.shares
            .iter()
            .enumerate()
            .map(|(c, share)| {
                let mut v = load(share);
                while let Some(k) = next.next_if(|k| k.chunk == c) {
                    for t in &self.terms[k.base..k.base + k.rows.len()] {
                        v += load(t);
                    }
                }
                v
            })
            .sum()
    }
}

impl Shared<'_> {
    /// The CG loop over `own`'s rows, in step with the other threads.
    fn work(&self, own: Own<'_>) -> Result<(usize, f64), StepFailure> {
        let _poison = PoisonOnPanic(&self.barrier.poisoned);
        let Problem {
            pattern,
            upper,
            b,
            max_iterations,
            relative_tolerance,
        } = *self.problem;
        let Own {
            thread,
            x,
            inverse,
            r,
            z,
            q,
            p,
        } = own;
        let rows = self.ranges[thread].clone();
        let pieces = self.pieces(&rows);
        let sum = |sums: &Sums| sums.total(self.continuations);
        let mut round = 0;
        // (0) The set-up, as the sequential solve makes it: the preconditioner, `r = b − A x`
        // (x the guess, which `p` holds), with each chunk's shares of b · b (in `p_q`) and
        // r · r; the guess dropped if worse than none; `z = P⁻¹ r`, `p = z` and `r · z`.
        for (k, inverse) in inverse.iter_mut().enumerate() {
            *inverse = inverse_block(&upper.block(pattern.upper_start(rows.start + k)));
        }
        for piece in &pieces {
            let local = piece.local.clone();
            let first = rows.start + local.start;
            let out = &mut q[local.clone()];
            upper_row_products(pattern, upper, p, first, out);
            for (k, q) in local.clone().zip(out.iter()) {
                r[k] = b[rows.start + k] - q;
            }
            let bc = &b[first..first + local.len()];
            self.p_q.put(piece, local.len(), |k| bc[k].dot(&bc[k]));
            let rc = &r[local.clone()];
            self.r_r.put(piece, local.len(), |k| rc[k].dot(&rc[k]));
        }
        self.barrier.wait(&mut round);
        let b_norm = sum(self.p_q).sqrt();
        let mut r_norm = sum(self.r_r).sqrt();
        if r_norm > b_norm {
            x.iter_mut().for_each(|v| *v = Vector3::zeros());
            r.copy_from_slice(&b[rows.clone()]);
            r_norm = b_norm;
        }
        for piece in &pieces {
            let local = piece.local.clone();
            for k in local.clone() {
                z[k] = inverse[k] * r[k];
            }
            let (rc, zc) = (&r[local.clone()], &z[local.clone()]);
            self.r_z.put(piece, local.len(), |k| rc[k].dot(&zc[k]));
        }
        p[rows.clone()].copy_from_slice(z);
        self.publish(thread, z);
        self.barrier.wait(&mut round);
        let mut rz = sum(self.r_z);
        self.import(thread, p, None);
        if b_norm == 0.0 {
            x.iter_mut().for_each(|v| *v = Vector3::zeros());
            return Ok((0, 0.0));
        }
        let mut relative = r_norm / b_norm;
        let mut iterations = 0;
        while relative > relative_tolerance {
            if iterations == max_iterations || !relative.is_finite() {
                return Err(StepFailure::SolverNotConverged {
                    iterations,
                    relative_residual: relative,
                });
            }
            // (1) q = A p over this thread's rows, with each chunk's share of p · q.
            for piece in &pieces {
                let local = piece.local.clone();
                let first = rows.start + local.start;
                let out = &mut q[local.clone()];
                upper_row_products(pattern, upper, p, first, out);
                let pc = &p[first..first + local.len()];
                self.p_q.put(piece, local.len(), |k| pc[k].dot(&out[k]));
            }
            self.barrier.wait(&mut round);
            let p_ap = sum(self.p_q);
            if p_ap.is_nan() || p_ap <= 0.0 {
                return Err(StepFailure::SolverNotConverged {
                    iterations,
                    relative_residual: relative,
                });
            }
            let alpha = rz / p_ap;
            // (2) x += α p, r −= α q, z = P⁻¹ r, with each chunk's shares of r · z and r · r;
            // `z` at the exports published.
            for piece in &pieces {
                let mut update = |local: Range<usize>| {
                    let global = rows.start + local.start..rows.start + local.end;
                    update_chunk(
                        Update {
                            x: &mut x[local.clone()],
                            r: &mut r[local.clone()],
                            z: &mut z[local.clone()],
                        },
                        &p[global],
                        &q[local.clone()],
                        &inverse[local],
                        alpha,
                    )
                };
                let local = piece.local.clone();
                match piece.terms {
                    None => {
                        let (r_z, r_r) = update(local);
                        self.r_z.shares[piece.chunk].store(r_z.to_bits(), Ordering::Relaxed);
                        self.r_r.shares[piece.chunk].store(r_r.to_bits(), Ordering::Relaxed);
                    }
                    // Row by row: each row's sums start from −0, so they are its terms exactly.
                    Some(base) => {
                        for (k, row) in local.enumerate() {
                            let (r_z, r_r) = update(row..row + 1);
                            self.r_z.terms[base + k].store(r_z.to_bits(), Ordering::Relaxed);
                            self.r_r.terms[base + k].store(r_r.to_bits(), Ordering::Relaxed);
                        }
                    }
                }
            }
            self.publish(thread, z);
            self.barrier.wait(&mut round);
            let (rz_new, rr) = (sum(self.r_z), sum(self.r_r));
            let beta = rz_new / rz;
            rz = rz_new;
            // (3) p = z + β p over this thread's rows and its imports (from the owners'
            // published `z`, as the owners compute them: no barrier before the next product).
            update_direction(&mut p[rows.clone()], z, beta);
            self.import(thread, p, Some(beta));
            relative = rr.sqrt() / b_norm;
            iterations += 1;
        }
        Ok((iterations, relative))
    }

    /// `rows` (a thread's) cut at the chunks' bounds.
    fn pieces(&self, rows: &Range<usize>) -> Vec<Piece> {
        (rows.start / CHUNK..rows.end.div_ceil(CHUNK))
            .map(|chunk| {
                let global = (chunk * CHUNK).max(rows.start)..((chunk + 1) * CHUNK).min(rows.end);
                let terms = self
                    .continuations
                    .iter()
                    .find(|k| k.rows.start == global.start)
                    .map(|k| k.base);
                Piece {
                    chunk,
                    local: global.start - rows.start..global.end - rows.start,
                    terms,
                }
            })
            .collect()
    }

    /// Publish `z` (the thread's rows) at the thread's exports.
    fn publish(&self, thread: usize, z: &[Vector3<f64>]) {
        let first = self.ranges[thread].start;
        let mut out = self.published[thread]
            .lock()
            .expect("no thread of the team panicked");
        for (o, &j) in out.iter_mut().zip(&self.exports[thread]) {
            *o = z[j - first];
        }
    }

    /// `p` at the thread's imports from the owners' published `z`: `z` in the set-up (`beta`
    /// `None`), `z + β p` after an update (the expression of [`update_direction`]).
    fn import(&self, thread: usize, p: &mut [Vector3<f64>], beta: Option<f64>) {
        let imports = &self.imports[thread];
        let mut at = 0;
        while at < imports.len() {
            let owner = imports[at].0;
            let published = self.published[owner]
                .lock()
                .expect("no thread of the team panicked");
            while let Some(&(u, place, j)) = imports.get(at)
                && u == owner
            {
                let zj = published[place];
                p[j] = match beta {
                    None => zj,
                    Some(beta) => zj + p[j] * beta,
                };
                at += 1;
            }
        }
    }
}

/// A row's weight in [`split_rows`], in blocks: the passes' per-row work (the update, the
/// preconditioner, the product's lane sums) beside the product's per-block work.
const ROW_WEIGHT: usize = 4;

/// The pattern's rows in `threads` consecutive non-empty ranges of about equal work (a row
/// weighs its blocks and [`ROW_WEIGHT`]); `threads` must not exceed the rows.
fn split_rows(pattern: &BlockPattern, threads: usize) -> Vec<Range<usize>> {
    let n = pattern.n_rows();
    assert!(
        threads >= 1 && threads <= n,
        "{threads} threads for {n} rows"
    );
    let weight = |i: usize| pattern.row(i).len() + ROW_WEIGHT;
    let total: usize = (0..n).map(weight).sum();
    let mut bounds = vec![0usize];
    let mut acc = 0;
    for i in 0..n {
        // Range `t` ends at the first row where the running weight reaches `t / threads` of the
        // total, each range keeping at least one row.
        let t = bounds.len();
        if t < threads && (acc * threads >= total * t || n - i == threads - t) && i > bounds[t - 1]
        {
            bounds.push(i);
        }
        acc += weight(i);
    }
    bounds.push(n);
    bounds.windows(2).map(|w| w[0]..w[1]).collect()
}

/// The runs of rows of `ranges` (consecutive, covering the rows) that continue a chunk begun by
/// an earlier range, in row order, with their terms' places.
fn continuations(ranges: &[Range<usize>]) -> Vec<Continuation> {
    let mut out: Vec<Continuation> = Vec::new();
    for r in ranges.iter().skip(1) {
        let chunk = r.start / CHUNK;
        if r.start % CHUNK != 0 {
            let base = out.last().map_or(0, |c| c.base + c.rows.len());
            out.push(Continuation {
                chunk,
                rows: r.start..r.end.min((chunk + 1) * CHUNK),
                base,
            });
        }
    }
    out
}

/// `s` cut into the consecutive `ranges` (which cover it).
fn split<'a, T>(mut s: &'a mut [T], ranges: &[Range<usize>]) -> Vec<&'a mut [T]> {
    let mut parts = Vec::with_capacity(ranges.len());
    for r in ranges {
        let (head, tail) = s.split_at_mut(r.len());
        parts.push(head);
        s = tail;
    }
    parts
}

/// A reusable spinning barrier for a fixed number of threads.
struct Barrier {
    threads: usize,
    arrived: AtomicUsize,
    /// A thread of the team panicked: the others stop waiting for it.
    poisoned: AtomicBool,
}

impl Barrier {
    fn new(threads: usize) -> Self {
        Self {
            threads,
            arrived: AtomicUsize::new(0),
            poisoned: AtomicBool::new(false),
        }
    }

    /// Wait until every thread has arrived for the `round`-th time (counted by the caller).
    /// What each thread wrote before arriving is visible to every thread after.
    fn wait(&self, round: &mut usize) {
        *round += 1;
        let target = *round * self.threads;
        self.arrived.fetch_add(1, Ordering::AcqRel);
        let mut spins = 0;
        while self.arrived.load(Ordering::Acquire) < target {
            assert!(
                !self.poisoned.load(Ordering::Relaxed),
                "another thread of the CG team panicked"
            );
            if spins < SPINS {
                // No `spin_loop` (PAUSE) here: see [`SPINS`].
                spins += 1;
            } else {
                std::thread::yield_now();
            }
        }
    }
}

/// Poisons the barrier when its thread unwinds, so that the others do not wait for it forever.
struct PoisonOnPanic<'a>(&'a AtomicBool);

impl Drop for PoisonOnPanic<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.store(true, Ordering::Relaxed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chain whose rows get more blocks along it (every row `i` also coupled to `i / 2`).
    fn uneven(n: usize) -> BlockPattern {
        let mut pairs: Vec<[u32; 2]> = (1..n as u32).map(|i| [i - 1, i]).collect();
        pairs.extend((2..n as u32).map(|i| [i / 2, i]));
        BlockPattern::new(n, &pairs)
    }

    #[test]
    fn rows_split_into_consecutive_ranges_of_about_equal_work() {
        for n in [1usize, 2, 7, 511, 512, 513, 2_200, 4_500] {
            let pattern = uneven(n);
            let weight = |i: usize| pattern.row(i).len() + ROW_WEIGHT;
            let total: usize = (0..n).map(weight).sum();
            let heaviest = (0..n).map(weight).max().expect("rows");
            for threads in 1..=n.min(7) {
                let ranges = split_rows(&pattern, threads);
                assert_eq!(ranges.len(), threads);
                assert_eq!(ranges[0].start, 0);
                assert_eq!(ranges[threads - 1].end, n);
                for w in ranges.windows(2) {
                    assert_eq!(w[0].end, w[1].start);
                }
                for r in &ranges {
                    assert!(!r.is_empty(), "{n} rows, {threads} threads: {ranges:?}");
                    // Within a row's weight of an equal share (when the rows are many enough
                    // that each range needs no forced row).
                    let work: usize = r.clone().map(weight).sum();
                    if n >= 4 * threads {
                        assert!(
                            work.abs_diff(total / threads) <= 2 * heaviest,
                            "{n} rows, {threads} threads: {work} of {total} in {r:?}"
                        );
                    }
                }
                // The continuations: every range that starts inside a chunk, up to the chunk's
                // end or its own, their terms packed in row order.
                let cont = continuations(&ranges);
                let mut base = 0;
                for r in ranges.iter().skip(1).filter(|r| r.start % CHUNK != 0) {
                    let k = cont
                        .iter()
                        .find(|k| k.rows.start == r.start)
                        .expect("a continuation");
                    assert_eq!(k.chunk, r.start / CHUNK);
                    assert_eq!(k.rows.end, r.end.min((k.chunk + 1) * CHUNK));
                    assert_eq!(k.base, base);
                    base += k.rows.len();
                }
                assert_eq!(
                    cont.len(),
                    ranges
                        .iter()
                        .skip(1)
                        .filter(|r| r.start % CHUNK != 0)
                        .count()
                );
            }
        }
        // The 4,210-triangle shirt's case: the rows are no longer cut at a chunk's bound.
        // (See also `cg_gives_the_same_bits_on_any_number_of_threads`.)
        let ranges = split_rows(&uneven(2_168), 2);
        assert_ne!(ranges[0].end % CHUNK, 0, "{ranges:?}");
    }

    #[test]
    fn each_thread_imports_exactly_the_rows_of_others_its_products_read() {
        let pattern = uneven(1_000);
        for threads in 1..=5 {
            let plan = Plan::new(&pattern, threads);
            assert!(plan.fits(1_000, threads) && !plan.fits(1_000, threads + 1));
            for (t, rows) in plan.ranges.iter().enumerate() {
                let mut read: Vec<usize> = rows
                    .clone()
                    .flat_map(|i| pattern.row(i).map(|s| pattern.cols()[s] as usize))
                    .filter(|j| !rows.contains(j))
                    .collect();
                read.sort_unstable();
                read.dedup();
                let imported: Vec<usize> = plan.imports[t].iter().map(|&(_, _, j)| j).collect();
                assert_eq!(imported, read, "thread {t} of {threads}");
                for &(u, place, j) in &plan.imports[t] {
                    assert!(u != t && plan.ranges[u].contains(&j));
                    assert_eq!(plan.exports[u][place], j);
                }
            }
            for (u, exports) in plan.exports.iter().enumerate() {
                assert!(exports.windows(2).all(|w| w[0] < w[1]));
                assert!(exports.iter().all(|j| plan.ranges[u].contains(j)));
                assert_eq!(
                    plan.published[u].lock().expect("unpoisoned").len(),
                    exports.len()
                );
            }
        }
    }
}
