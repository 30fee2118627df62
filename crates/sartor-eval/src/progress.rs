//! Progress of a long job, drawn by whoever runs it (the command line draws bars; tests and
//! libraries pass [`NoProgress`]).

/// Receives the progress of a long job. Called from worker threads, hence `Sync`.
pub trait Progress: Sync {
    /// A new phase: `total` units of `unit` (frames, sequences, ...) to do.
    fn start(&self, phase: &str, total: u64, unit: &str);
    /// `n` more units done.
    fn inc(&self, n: u64);
    /// A short status next to the bar (e.g. the method being evaluated).
    fn message(&self, text: &str);
    /// A line printed above the bar (e.g. a failed sequence).
    fn println(&self, line: &str);
    /// The phase is over.
    fn finish(&self);
}

/// Progress that goes nowhere.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _phase: &str, _total: u64, _unit: &str) {}
    fn inc(&self, _n: u64) {}
    fn message(&self, _text: &str) {}
    fn println(&self, _line: &str) {}
    fn finish(&self) {}
}
