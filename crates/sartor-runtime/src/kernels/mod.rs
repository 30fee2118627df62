//! Inference kernels: weight storage in three precisions, matrix–vector products for one or a
//! few inputs, the fused GRU step, the MLP and the output layer.
//!
//! Everything is allocation-free once the `*Scratch` buffers exist, and deterministic: results
//! do not depend on [`Parallelism`], on the batch size, or on the instruction set the CPU
//! offers (see `rows.rs` for the arithmetic contract and `dispatch.rs` for the only unsafe
//! code).

mod dispatch;
mod gru;
mod int8;
mod interleaved;
mod matrix;
mod mlp;
mod panels;
mod rows;

pub(crate) use dispatch::LaneMask;
#[cfg(target_arch = "x86_64")]
pub(crate) use dispatch::widest_level;
pub(crate) use dispatch::widest_where_present;
pub use gru::{GruCell, GruScratch};
pub use matrix::{INT8_ZERO_ROW, Linear, Matrix, Parallelism, Precision};
pub use mlp::{Mlp, MlpScratch, OutputLayer, OutputScratch};

/// The instruction set the kernels dispatch to on this CPU (`avx512`, `avx2` or `portable`), for
/// reports. Detected once; the environment variable `SARTOR_RUNTIME_ISA` (`portable`, `avx2` or
/// `avx512`) picks a supported one instead.
pub fn instruction_set() -> &'static str {
    dispatch::Isa::best().name()
}
