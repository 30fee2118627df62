//! Normalisation of the networks' inputs and outputs: `(x − mean) / std` per component, with
//! statistics of the training split. The dataset computes them, training uses them and the
//! exported model carries them to the runtime: one type for all three.

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Per-component mean and standard deviation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeanStd {
    /// Mean.
    pub mean: Vec<f32>,
    /// Standard deviation (positive).
    pub std: Vec<f32>,
}

impl MeanStd {
    /// Check sizes, finiteness and positive std.
    pub fn validate(&self, len: usize, what: &'static str) -> Result<()> {
        if self.mean.len() != len || self.std.len() != len {
            return Err(Error::invalid(
                what,
                format!(
                    "{} means and {} stds for {len} values",
                    self.mean.len(),
                    self.std.len()
                ),
            ));
        }
        if !self.mean.iter().all(|m| m.is_finite()) {
            return Err(Error::invalid(what, "non-finite mean"));
        }
        if !self.std.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(Error::invalid(what, "std must be finite and positive"));
        }
        Ok(())
    }

    /// Normalise `values` in place; `values.len()` must be a multiple of the size.
    pub fn normalize(&self, values: &mut [f32]) {
        let n = self.mean.len();
        for row in values.chunks_mut(n) {
            for ((v, m), s) in row.iter_mut().zip(&self.mean).zip(&self.std) {
                *v = (*v - m) / s;
            }
        }
    }

    /// Undo [`MeanStd::normalize`].
    pub fn denormalize(&self, values: &mut [f32]) {
        let n = self.mean.len();
        for row in values.chunks_mut(n) {
            for ((v, m), s) in row.iter_mut().zip(&self.mean).zip(&self.std) {
                *v = *v * s + m;
            }
        }
    }
}

/// Normalisation statistics of the network inputs and outputs, computed on the training split
/// only: what the dataset gives training and the exported model gives the runtime.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NormStats {
    /// Fit MLP input (β), `[n_betas]`.
    pub fit_in: MeanStd,
    /// Wrinkle input, `[n_inputs]`.
    pub wrinkle_in: MeanStd,
    /// Fit displacement `Δ_G`, `[3V]` (one std for all components).
    pub fit_out: MeanStd,
    /// Wrinkle displacement `Δ_L`, `[3V]` (one std for all components).
    pub wrinkle_out: MeanStd,
}
