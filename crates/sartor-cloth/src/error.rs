//! The crate's one error type.

use std::path::PathBuf;

/// Why a simulation step was rejected. The simulator's state is left exactly as it was before
/// the step, so the caller can retry (typically with a smaller time step).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepFailure {
    /// A position, velocity or solver value became NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Where it was found ("velocity update", "linear system", ...).
        what: &'static str,
    },
    /// The kinetic energy after the step exceeds the configured bound (a blow-up).
    #[error("kinetic energy {kinetic_energy_j:.3e} J exceeds the bound {bound_j:.3e} J")]
    EnergyBlowUp {
        /// Kinetic energy after the step, J.
        kinetic_energy_j: f64,
        /// The bound, J (`½ · total mass · max_speed²`).
        bound_j: f64,
    },
    /// The conjugate-gradient solver reached its iteration cap.
    #[error(
        "conjugate gradient did not converge: {iterations} iterations, relative residual {relative_residual:.3e}"
    )]
    SolverNotConverged {
        /// Iterations performed.
        iterations: usize,
        /// Final `|b − A x| / |b|`.
        relative_residual: f64,
    },
    /// The sparse Cholesky factorisation failed (matrix not numerically positive definite).
    #[error("sparse Cholesky factorisation failed: {message}")]
    Factorization {
        /// faer's message.
        message: String,
    },
}

/// Why a simulated sequence (or a frame of it) was rejected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SequenceFailure {
    /// A substep failed (NaN, energy blow-up, solver failure).
    #[error("{0}")]
    Step(StepFailure),
    /// After a frame, a cloth vertex was deeper inside the body than the tolerance.
    #[error(
        "cloth vertex {vertex} is {depth_mm:.2} mm inside the body (tolerance {tolerance_mm:.2} mm)"
    )]
    Penetration {
        /// The vertex.
        vertex: usize,
        /// How deep, mm.
        depth_mm: f64,
        /// The tolerance, mm.
        tolerance_mm: f64,
    },
    /// A cloth vertex came within the contact thickness of a body triangle that was left out
    /// of the contact region (the region was too small).
    #[error(
        "cloth vertex {vertex} came within {distance_mm:.2} mm of a body triangle outside the contact region"
    )]
    OutsideRegion {
        /// The vertex.
        vertex: usize,
        /// Its distance to the excluded triangle, mm.
        distance_mm: f64,
    },
    /// After a frame, the garment's centroid had moved away from the body's contact region by
    /// more than [`crate::LEFT_BODY_M`] since the first frame: the body jumped and left the
    /// cloth behind (a jump in the motion, such as a blank frame in a BVH file).
    #[error(
        "the cloth was left behind: its centroid is {offset_mm:.0} mm farther from the body's \
         contact region than at the start (limit {limit_mm:.0} mm)"
    )]
    LeftBody {
        /// How much farther, mm.
        offset_mm: f64,
        /// The limit, mm.
        limit_mm: f64,
    },
}

/// Everything that can go wrong in `sartor-cloth`. Each variant names the file (when there is
/// one) and the fault.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A mesh fault reported by `sartor-core` (non-finite vertex, zero-area triangle,
    /// non-manifold edge or vertex, ...).
    #[error(transparent)]
    Mesh(#[from] sartor_core::Error),
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A file is malformed (bad JSON, wrong table size, non-finite value, ...).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An in-memory value breaks an invariant (a cloth mesh, a material, a config, ...).
    #[error("invalid {what}: {message}")]
    Invalid {
        /// What kind of value.
        what: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A simulation step was rejected; the state is unchanged.
    #[error("simulation step failed: {0}")]
    Step(#[from] StepFailure),
    /// A sequence could not be simulated, even with the retries the config allows; nothing was
    /// written.
    #[error("{sequence}: failed at frame {frame} after {attempts} attempts: {reason}")]
    SequenceFailed {
        /// Which sequence (garment, shape, motion).
        sequence: String,
        /// The frame (0-based, in the sequence's frames) that failed last.
        frame: usize,
        /// Attempts made at that frame.
        attempts: usize,
        /// Why.
        reason: SequenceFailure,
    },
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        Self::Invalid {
            what,
            message: message.into(),
        }
    }

    pub(crate) fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// The step failure, if this error is one (the caller may retry with a smaller step).
    pub fn step_failure(&self) -> Option<&StepFailure> {
        match self {
            Self::Step(failure) => Some(failure),
            _ => None,
        }
    }
}
