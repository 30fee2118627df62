//! The training data in memory: what `sartor-model` learns from.
//!
//! Displacements are `f32`, metres, vertex-major `(v·3 + c)`. Inputs of the wrinkle network
//! are per frame `[β, pose features]` (`n_inputs` values, layout in [`InputLayout`]).
//! Normalisation ([`NormStats`]) is `(x − mean) / std`; the displacement outputs use one std
//! for every component (the RMS over all of them), so a mean squared error in normalised units
//! is a fixed multiple of the mean squared vertex error in metres and a PCA in normalised units
//! is a PCA of the displacements themselves.

use serde::{Deserialize, Serialize};

use sartor_core::{NormStats, PoseFeatureSpec};

use crate::{Error, Result};

/// Which part of the data a shape or sequence belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Training shapes × training motions (and the training shapes' rest simulations).
    Train,
    /// Held-out motions on the training shapes.
    HeldOutMotions,
    /// Held-out shapes (every motion, and their rest simulations).
    HeldOutShapes,
    /// Validation: validation motions on the training shapes, and validation shapes (their rest
    /// simulations). Training picks its epochs and settings on it; it is neither trained on nor
    /// reported as the test.
    Validation,
}

/// The layout of the wrinkle network's input vector: `n_betas` shape values, then the pose
/// features of `pose` ([`PoseFeatureSpec::width`] values).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputLayout {
    /// Shape coefficients β at the start of the vector.
    pub n_betas: usize,
    /// The pose features after β.
    pub pose: PoseFeatureSpec,
}

impl InputLayout {
    /// Values per frame: `n_betas + pose.width()`.
    pub fn width(&self) -> usize {
        self.n_betas + self.pose.width()
    }
}

/// One body shape: its β and its garment-fit displacement `Δ_G = ρ(S_c(β, 0)) − T̄_c`.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeSample {
    /// Identifier (e.g. `s03`).
    pub id: String,
    /// β, `[n_betas]`.
    pub betas: Vec<f32>,
    /// `Δ_G`, `[3V]`, metres.
    pub fit_delta: Vec<f32>,
    /// The split.
    pub split: Split,
}

/// One simulated sequence (one shape × one motion), motion frames only.
#[derive(Clone, Debug, PartialEq)]
pub struct SequenceSample {
    /// Identifier (e.g. `s03__walk`).
    pub id: String,
    /// Index into [`TrainingData::shapes`].
    pub shape: usize,
    /// Motion name.
    pub motion: String,
    /// The split.
    pub split: Split,
    /// Frames `T`.
    pub n_frames: usize,
    /// Wrinkle-network inputs, `[T, n_inputs]`, raw (not normalised).
    pub inputs: Vec<f32>,
    /// `Δ_L`, `[T, 3V]`, metres.
    pub wrinkle_delta: Vec<f32>,
}

/// A PCA basis of the normalised `Δ_L` (training split).
#[derive(Clone, Debug, PartialEq)]
pub struct PcaBasis {
    /// Mean of the normalised `Δ_L`, `[3V]`.
    pub mean: Vec<f32>,
    /// Orthonormal components, `[3V, k]` row-major (column `c` is component `c`).
    pub basis: Vec<f32>,
    /// Share of the variance each component explains, `[k]`, descending.
    pub explained_variance_ratio: Vec<f64>,
}

impl PcaBasis {
    /// Number of components `k`.
    pub fn n_components(&self) -> usize {
        self.explained_variance_ratio.len()
    }
}

/// What the data was made from: the garment and the body, by name and content hash (an
/// exported model carries them so a runtime can refuse a mismatched garment or body).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataSource {
    /// The garment, e.g. `tshirt-4210`.
    pub garment: sartor_core::asset::AssetId,
    /// The body model, e.g. `makehuman-cmu_mb`.
    pub body: sartor_core::asset::AssetId,
}

/// Everything a training run needs, validated.
#[derive(Clone, Debug)]
pub struct TrainingData {
    source: DataSource,
    n_vertices: usize,
    layout: InputLayout,
    shapes: Vec<ShapeSample>,
    sequences: Vec<SequenceSample>,
    stats: NormStats,
    pca: Option<PcaBasis>,
}

impl TrainingData {
    /// Check every size, index and value and build. `pca`, if given, must have `3V` rows.
    pub fn new(
        source: DataSource,
        n_vertices: usize,
        layout: InputLayout,
        shapes: Vec<ShapeSample>,
        sequences: Vec<SequenceSample>,
        stats: NormStats,
        pca: Option<PcaBasis>,
    ) -> Result<Self> {
        let n3 = 3 * n_vertices;
        let n_in = layout.width();
        if n_vertices == 0 {
            return Err(Error::invalid("training data", "no garment vertices"));
        }
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        for s in &shapes {
            if s.betas.len() != layout.n_betas || s.fit_delta.len() != n3 {
                return Err(Error::invalid(
                    "training data",
                    format!(
                        "shape {}: {} betas (expected {}) and {} displacement values (expected {n3})",
                        s.id,
                        s.betas.len(),
                        layout.n_betas,
                        s.fit_delta.len()
                    ),
                ));
            }
            if !finite(&s.betas) || !finite(&s.fit_delta) {
                return Err(Error::invalid(
                    "training data",
                    format!("shape {} has a non-finite value", s.id),
                ));
            }
        }
        for q in &sequences {
            if q.shape >= shapes.len() {
                return Err(Error::invalid(
                    "training data",
                    format!(
                        "sequence {} refers to shape {} of {}",
                        q.id,
                        q.shape,
                        shapes.len()
                    ),
                ));
            }
            if q.n_frames == 0
                || q.inputs.len() != q.n_frames * n_in
                || q.wrinkle_delta.len() != q.n_frames * n3
            {
                return Err(Error::invalid(
                    "training data",
                    format!(
                        "sequence {}: {} frames, {} input values (expected {}), {} displacement values (expected {})",
                        q.id,
                        q.n_frames,
                        q.inputs.len(),
                        q.n_frames * n_in,
                        q.wrinkle_delta.len(),
                        q.n_frames * n3
                    ),
                ));
            }
            if !finite(&q.inputs) || !finite(&q.wrinkle_delta) {
                return Err(Error::invalid(
                    "training data",
                    format!("sequence {} has a non-finite value", q.id),
                ));
            }
        }
        stats
            .fit_in
            .validate(layout.n_betas, "fit input statistics")?;
        stats
            .wrinkle_in
            .validate(n_in, "wrinkle input statistics")?;
        stats.fit_out.validate(n3, "fit output statistics")?;
        stats
            .wrinkle_out
            .validate(n3, "wrinkle output statistics")?;
        if let Some(p) = &pca {
            let k = p.n_components();
            if k == 0 || p.mean.len() != n3 || p.basis.len() != n3 * k {
                return Err(Error::invalid(
                    "PCA basis",
                    format!(
                        "{k} components, {} mean values and {} basis values for {n3} outputs",
                        p.mean.len(),
                        p.basis.len()
                    ),
                ));
            }
            if !finite(&p.mean) || !finite(&p.basis) {
                return Err(Error::invalid("PCA basis", "non-finite value"));
            }
        }
        Ok(Self {
            source,
            n_vertices,
            layout,
            shapes,
            sequences,
            stats,
            pca,
        })
    }

    /// The garment and body the data was made from.
    pub fn source(&self) -> &DataSource {
        &self.source
    }

    /// Garment vertices `V`.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// Outputs `3V`.
    pub fn n_outputs(&self) -> usize {
        3 * self.n_vertices
    }

    /// Shape coefficients.
    pub fn n_betas(&self) -> usize {
        self.layout.n_betas
    }

    /// Wrinkle inputs per frame.
    pub fn n_inputs(&self) -> usize {
        self.layout.width()
    }

    /// The input layout.
    pub fn layout(&self) -> &InputLayout {
        &self.layout
    }

    /// Every shape.
    pub fn shapes(&self) -> &[ShapeSample] {
        &self.shapes
    }

    /// Every sequence.
    pub fn sequences(&self) -> &[SequenceSample] {
        &self.sequences
    }

    /// Normalisation statistics.
    pub fn stats(&self) -> &NormStats {
        &self.stats
    }

    /// The PCA basis of `Δ_L`, if computed.
    pub fn pca(&self) -> Option<&PcaBasis> {
        self.pca.as_ref()
    }

    /// Indices of the shapes in `split`, ascending.
    pub fn shape_indices(&self, split: Split) -> Vec<usize> {
        (0..self.shapes.len())
            .filter(|&i| self.shapes[i].split == split)
            .collect()
    }

    /// Indices of the sequences in `split`, ascending.
    pub fn sequence_indices(&self, split: Split) -> Vec<usize> {
        (0..self.sequences.len())
            .filter(|&i| self.sequences[i].split == split)
            .collect()
    }
}
