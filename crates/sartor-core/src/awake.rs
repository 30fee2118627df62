//! Keeping rayon's workers awake through a step ([`with_workers_awake`]).
//!
//! A step runs short parallel loops separated by serial code: the simulator's time step a dozen
//! (the frozen coefficients, the contact queries, the assembly, CG's broadcast, …), the
//! runtime's network step two or three split products. Between them rayon's idle workers go to
//! sleep, and waking one costs more than a loop's hand-off: on the 2-core Intel Xeon VM a
//! `rayon::join` of two 200 µs halves, called from inside the pool, took 7 µs more than 200 µs
//! right after the previous join, 50 µs more after 30 µs of serial work, 75 after 100 µs and 94
//! after 1 ms (from outside the pool: 31, 55, 89 and 171). The two-thread simulator step lost a
//! third of its speed-up this way: each parallel part of the 4,210-triangle walk ran at
//! 0.63–0.68× of its one-thread time, although two one-thread simulations side by side each ran
//! at full speed. The shipped model's f32 network step on two threads took 27–29 µs in most
//! frames and 68–80 µs (its one-thread time: the helper asleep, the join done alone) in a
//! third of them, pool by pool.
//!
//! [`with_workers_awake`] runs the step on a worker of the current pool while every other
//! worker runs a poller that executes whatever work the pool has (`rayon::yield_now`) and
//! otherwise yields its core to the OS scheduler, so that a parallel loop finds its helpers
//! awake. The pollers are not needed for correctness: results are the same bits with or without
//! them (every parallel loop of the simulator and the runtime is deterministic by construction).
//!
//! Deadlock-freedom: a poller that lands on the thread running the step returns at once, and a
//! poller idle for `IDLE_LIMIT` (5 ms) returns too, so a poller can never wait on work that waits on
//! it for longer than that (e.g. several steps running at once on one pool, each poller nested
//! inside another step's wait).

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// A poller that found no work for this long returns (the worker may then sleep again).
const IDLE_LIMIT: Duration = Duration::from_millis(5);

thread_local! {
    /// Whether this thread is running the `f` of a [`with_workers_awake`].
    static AWAKE: Cell<bool> = const { Cell::new(false) };
}

/// Whether this thread is running the `f` of a [`with_workers_awake`] (its pollers are up).
pub fn is_awake() -> bool {
    AWAKE.get()
}

/// Run `f` on a worker of the current rayon pool while the pool's other workers poll for work
/// (see the module docs). With one thread in the pool this is `f` on a worker; inside another
/// `with_workers_awake` it is `f`, here (its pollers are already running). The pollers are
/// handed out by nested `rayon::join`s, whose jobs live on the stack: no heap allocation per
/// call (the runtime's network step promises none).
pub fn with_workers_awake<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if AWAKE.get() {
        return f();
    }
    let Some(owner) = rayon::current_thread_index() else {
        // Onto a worker first: the pollers must know which thread runs `f`.
        return rayon::scope(|_| with_workers_awake(f));
    };
    let others = rayon::current_num_threads().saturating_sub(1);
    let done = AtomicBool::new(false);
    with_pollers(others, owner, &done, f)
}

/// `f` here, with `others` pollers offered to the pool: one per level of nested joins, each
/// level's first half run here (so `f` runs on `owner`), its second half a poller for any
/// other worker to take. A poller left untaken is run here after `f` and returns at once.
fn with_pollers<R: Send>(
    others: usize,
    owner: usize,
    done: &AtomicBool,
    f: impl FnOnce() -> R + Send,
) -> R {
    if others > 0 {
        return rayon::join(
            || with_pollers(others - 1, owner, done, f),
            || poll(owner, done),
        )
        .0;
    }
    // Reset on the way out even if `f` unwinds (rayon re-raises the panic), and release the
    // pollers then too.
    struct Reset<'a>(&'a AtomicBool);
    impl Drop for Reset<'_> {
        fn drop(&mut self) {
            AWAKE.set(false);
            self.0.store(true, Ordering::Release);
        }
    }
    AWAKE.set(true);
    let _reset = Reset(done);
    f()
}

/// Execute the pool's work until `done` (or [`IDLE_LIMIT`] without any); at once on `owner`.
fn poll(owner: usize, done: &AtomicBool) {
    if rayon::current_thread_index() == Some(owner) {
        return;
    }
    let mut idle_since = Instant::now();
    while !done.load(Ordering::Acquire) {
        match rayon::yield_now() {
            Some(rayon::Yield::Executed) => idle_since = Instant::now(),
            _ => {
                if idle_since.elapsed() > IDLE_LIMIT {
                    return;
                }
                std::thread::yield_now();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn runs_on_any_pool_and_nests_without_deadlock() {
        for threads in [1, 2, 4] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            // Several steps at once on one pool, each with parallel loops inside.
            let sums: Vec<u64> = pool.install(|| {
                (0..8u64)
                    .into_par_iter()
                    .map(|k| {
                        with_workers_awake(|| {
                            (0..10_000u64).into_par_iter().map(|i| i * k).sum::<u64>()
                        })
                    })
                    .collect()
            });
            let want: Vec<u64> = (0..8u64).map(|k| k * 10_000 * 9_999 / 2).collect();
            assert_eq!(sums, want, "{threads} threads");
            // From outside the pool.
            assert_eq!(with_workers_awake(|| 7), 7);
        }
    }
}
