//! The CG solve of [`super::LinearWorkspace::solve_cg`] on several threads, its set-up (the
//! preconditioner, the first residual and the norms) and its loop: the threads of the current
//! rayon pool, each owning a fixed range of rows for the whole solve.
//!
//! A CG iteration is three short passes over the vertices, each ended by a global sum. As rayon
//! fork-joins each pass paid a hand-off between threads (16 µs measured on the 2-core VM)
//! against 20–40 µs of work at 8,710 triangles, and the two-thread solve was no faster than one
//! thread's. Here one `rayon::broadcast` starts the loop on every thread of the pool, each runs
//! it over its own rows, and the passes are separated by a spinning barrier (well under a
//! microsecond when both threads have a core). The broadcast waits for every thread of the
//! pool: the simulator calls it from its step, when the pool has no other work. (Threads
//! spawned per solve instead cost 60 µs each and ran beside the pool's idle threads: slower.)
//! The one thing a thread reads of another's rows, the search direction `p` of the matrix
//! product, it copies after each iteration from the owner's published rows into its own full
//! copy. The set-up before the loop (the preconditioner, `r = b − A x` for the guess, the
//! norms, `z` and `p`) is two more passes on the same team, not four fork-joins and serial
//! loops: two-thread solve 44.0–44.7 → 43.7–44.5 ms per frame at 8,710 triangles in runs
//! without the VM's slow spells, no change seen at 4,210.
//!
//! Bitwise the same as the sequential loop, on any number of threads: the rows are split on
//! [`CHUNK`] boundaries, every chunk's share of each dot product is computed as the sequential
//! loop computes it, and every thread sums the shares in chunk order, so that all threads hold
//! the same scalars and take the same branches.

use std::ops::Range;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};

use nalgebra::{Matrix3, Vector3};

use super::upper::{UpperBlocks, upper_row_products};
use super::{
    BlockPattern, CHUNK, Update, chunk_dot, inverse_block, update_chunk, update_direction,
};
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

/// Set up and iterate CG on the first `threads` threads of the current rayon pool until the
/// relative residual is within the tolerance: `(iterations, relative residual)`, exactly as the
/// sequential solve returns them. On return `x` holds the solution; the other buffers are
/// scratch.
pub(super) fn iterate(
    threads: usize,
    problem: &Problem<'_>,
    state: State<'_>,
) -> Result<(usize, f64), StepFailure> {
    let n = state.x.len();
    let ranges = split_rows(n, threads);
    let chunks = n.div_ceil(CHUNK);
    let shares = || (0..chunks).map(|_| AtomicU64::new(0)).collect::<Vec<_>>();
    let shared = Shared {
        problem,
        published: ranges
            .iter()
            .map(|r| Mutex::new(state.direction[r.clone()].to_vec()))
            .collect(),
        ranges: ranges.clone(),
        p_q: shares(),
        r_z: shares(),
        r_r: shares(),
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
    // The guess, for the set-up's product `A x`: every thread's `p` holds it at first.
    direction.copy_from_slice(x);
    // Thread 0 works in `direction`; every other thread in its own copy.
    let mut copies: Vec<Vec<Vector3<f64>>> = (1..threads).map(|_| direction.to_vec()).collect();
    let mut ps: Vec<&mut [Vector3<f64>]> = vec![direction];
    ps.extend(copies.iter_mut().map(|c| c.as_mut_slice()));
    let slots: Vec<Mutex<Option<Own<'_>>>> = split(x, &ranges)
        .into_iter()
        .zip(split(inverse_diagonal, &ranges))
        .zip(split(residual, &ranges))
        .zip(split(preconditioned, &ranges))
        .zip(split(product, &ranges))
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

/// What the team shares.
struct Shared<'a> {
    problem: &'a Problem<'a>,
    /// Per thread, its rows.
    ranges: Vec<Range<usize>>,
    /// Per thread, its rows of `p` as of the last iteration.
    published: Vec<Mutex<Vec<Vector3<f64>>>>,
    /// Per chunk, its share of `p · q`, `r · z` and `r · r` (f64 bits).
    p_q: Vec<AtomicU64>,
    r_z: Vec<AtomicU64>,
    r_r: Vec<AtomicU64>,
    barrier: Barrier,
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
        let n = p.len();
        // Each chunk as (its index, its rows relative to this thread's first row).
        let chunks: Vec<(usize, Range<usize>)> = (rows.start / CHUNK..rows.end.div_ceil(CHUNK))
            .map(|c| {
                (
                    c,
                    c * CHUNK - rows.start..((c + 1) * CHUNK).min(n) - rows.start,
                )
            })
            .collect();
        let sum = |shares: &[AtomicU64]| -> f64 {
            shares
                .iter()
                .map(|s| f64::from_bits(s.load(Ordering::Relaxed)))
                .sum()
        };
        let mut round = 0;
        // (0) The set-up, as the sequential solve makes it: the preconditioner, `r = b − A x`
        // (x the guess, which `p` holds), with each chunk's shares of b · b (in `p_q`) and
        // r · r; the guess dropped if worse than none; `z = P⁻¹ r`, `p = z` and `r · z`.
        for (k, inverse) in inverse.iter_mut().enumerate() {
            *inverse = inverse_block(&upper.block(pattern.upper_start(rows.start + k)));
        }
        for (c, local) in &chunks {
            let first = rows.start + local.start;
            let out = &mut q[local.clone()];
            upper_row_products(pattern, upper, p, first, out);
            for (k, q) in local.clone().zip(out.iter()) {
                r[k] = b[rows.start + k] - q;
            }
            let bc = &b[first..first + out.len()];
            let b_b = chunk_dot(bc, bc);
            let rc = &r[local.clone()];
            let r_r = chunk_dot(rc, rc);
            self.p_q[*c].store(b_b.to_bits(), Ordering::Relaxed);
            self.r_r[*c].store(r_r.to_bits(), Ordering::Relaxed);
        }
        self.barrier.wait(&mut round);
        let b_norm = sum(&self.p_q).sqrt();
        let mut r_norm = sum(&self.r_r).sqrt();
        if r_norm > b_norm {
            x.iter_mut().for_each(|v| *v = Vector3::zeros());
            r.copy_from_slice(&b[rows.clone()]);
            r_norm = b_norm;
        }
        for (c, local) in &chunks {
            for k in local.clone() {
                z[k] = inverse[k] * r[k];
            }
            let r_z = chunk_dot(&r[local.clone()], &z[local.clone()]);
            self.r_z[*c].store(r_z.to_bits(), Ordering::Relaxed);
        }
        p[rows.clone()].copy_from_slice(z);
        self.published[thread]
            .lock()
            .expect("no thread of the team panicked")
            .copy_from_slice(&p[rows.clone()]);
        self.barrier.wait(&mut round);
        let mut rz = sum(&self.r_z);
        self.copy_published(thread, p);
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
            for (c, local) in &chunks {
                let first = rows.start + local.start;
                let out = &mut q[local.clone()];
                upper_row_products(pattern, upper, p, first, out);
                let share = chunk_dot(&p[first..first + out.len()], out);
                self.p_q[*c].store(share.to_bits(), Ordering::Relaxed);
            }
            self.barrier.wait(&mut round);
            let p_ap = sum(&self.p_q);
            if p_ap.is_nan() || p_ap <= 0.0 {
                return Err(StepFailure::SolverNotConverged {
                    iterations,
                    relative_residual: relative,
                });
            }
            let alpha = rz / p_ap;
            // (2) x += α p, r −= α q, z = P⁻¹ r, with each chunk's shares of r · z and r · r.
            for (c, local) in &chunks {
                let global = rows.start + local.start..rows.start + local.end;
                let (r_z, r_r) = update_chunk(
                    Update {
                        x: &mut x[local.clone()],
                        r: &mut r[local.clone()],
                        z: &mut z[local.clone()],
                    },
                    &p[global],
                    &q[local.clone()],
                    &inverse[local.clone()],
                    alpha,
                );
                self.r_z[*c].store(r_z.to_bits(), Ordering::Relaxed);
                self.r_r[*c].store(r_r.to_bits(), Ordering::Relaxed);
            }
            self.barrier.wait(&mut round);
            let (rz_new, rr) = (sum(&self.r_z), sum(&self.r_r));
            let beta = rz_new / rz;
            rz = rz_new;
            // (3) p = z + β p over this thread's rows, published for the others.
            update_direction(&mut p[rows.clone()], z, beta);
            self.published[thread]
                .lock()
                .expect("no thread of the team panicked")
                .copy_from_slice(&p[rows.clone()]);
            self.barrier.wait(&mut round);
            self.copy_published(thread, p);
            relative = rr.sqrt() / b_norm;
            iterations += 1;
        }
        Ok((iterations, relative))
    }

    /// Copy into `p` the rows the other threads published.
    fn copy_published(&self, thread: usize, p: &mut [Vector3<f64>]) {
        for (u, range) in self.ranges.iter().enumerate() {
            if u != thread {
                p[range.clone()].copy_from_slice(
                    &self.published[u]
                        .lock()
                        .expect("no thread of the team panicked"),
                );
            }
        }
    }
}

/// `n` rows in `threads` ranges of whole chunks (the last may end short), as even as chunks
/// allow; `threads` must not exceed the number of chunks.
fn split_rows(n: usize, threads: usize) -> Vec<Range<usize>> {
    let chunks = n.div_ceil(CHUNK);
    assert!(
        threads >= 1 && threads <= chunks,
        "{threads} threads for {chunks} chunks"
    );
    let mut bounds = vec![0usize];
    for t in 1..threads {
        let previous = bounds[t - 1] / CHUNK;
        let nearest = (n * t / threads + CHUNK / 2) / CHUNK;
        let c = nearest.clamp(previous + 1, chunks - (threads - t));
        bounds.push(c * CHUNK);
    }
    bounds.push(n);
    bounds.windows(2).map(|w| w[0]..w[1]).collect()
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

    #[test]
    fn rows_split_on_chunk_boundaries_as_evenly_as_chunks_allow() {
        assert_eq!(split_rows(4_500, 2), vec![0..2_304, 2_304..4_500]);
        assert_eq!(split_rows(700, 2), vec![0..384, 384..700]);
        assert_eq!(split_rows(2_200, 3), vec![0..768, 768..1_408, 1_408..2_200]);
        for n in [1usize, 511, 512, 513, 2_200, 4_500, 9_001, 13_100] {
            let chunks = n.div_ceil(CHUNK);
            for threads in 1..=chunks.min(7) {
                let ranges = split_rows(n, threads);
                assert_eq!(ranges.len(), threads);
                assert_eq!(ranges[0].start, 0);
                assert_eq!(ranges[threads - 1].end, n);
                for w in ranges.windows(2) {
                    assert_eq!(w[0].end, w[1].start);
                    assert_eq!(w[0].end % CHUNK, 0);
                    assert!(!w[0].is_empty());
                }
                assert!(!ranges[threads - 1].is_empty());
            }
        }
    }
}
