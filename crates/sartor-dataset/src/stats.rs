//! Normalisation statistics and the PCA basis of `Δ_L`, both from the training split only.

use nalgebra::DMatrix;
use sartor_core::rsvd::{LinearOperator, randomized_svd};

use crate::{Error, MeanStd, NormStats, PcaBasis, Result, SequenceSample, ShapeSample};

/// A standard deviation below this is treated as a constant feature and replaced by 1 (the
/// feature is then only centred).
pub const MIN_STD: f64 = 1e-6;

/// Running per-component sums (f64).
struct Moments {
    n: f64,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
}

impl Moments {
    fn new(width: usize) -> Self {
        Self {
            n: 0.0,
            sum: vec![0.0; width],
            sum_sq: vec![0.0; width],
        }
    }

    fn add_rows(&mut self, values: &[f32]) {
        let w = self.sum.len();
        for row in values.chunks_exact(w) {
            self.n += 1.0;
            for ((s, q), &v) in self.sum.iter_mut().zip(&mut self.sum_sq).zip(row) {
                let v = v as f64;
                *s += v;
                *q += v * v;
            }
        }
    }

    fn mean(&self) -> Vec<f64> {
        self.sum.iter().map(|s| s / self.n.max(1.0)).collect()
    }

    fn variance(&self) -> Vec<f64> {
        let mean = self.mean();
        self.sum_sq
            .iter()
            .zip(&mean)
            .map(|(q, m)| (q / self.n.max(1.0) - m * m).max(0.0))
            .collect()
    }

    /// Mean and per-component std (constant components get std 1).
    fn per_component(&self) -> MeanStd {
        let std = self
            .variance()
            .iter()
            .map(|v| {
                let s = v.sqrt();
                if s < MIN_STD { 1.0 } else { s as f32 }
            })
            .collect();
        MeanStd {
            mean: self.mean().iter().map(|&m| m as f32).collect(),
            std,
        }
    }

    /// Mean per component, one std for all: the RMS of the centred values.
    fn isotropic(&self) -> MeanStd {
        let var = self.variance();
        let rms = (var.iter().sum::<f64>() / var.len().max(1) as f64).sqrt();
        let s = if rms < MIN_STD { 1.0 } else { rms as f32 };
        MeanStd {
            mean: self.mean().iter().map(|&m| m as f32).collect(),
            std: vec![s; var.len()],
        }
    }
}

/// Statistics over the given shapes (fit MLP) and sequences (wrinkle network). Inputs get a
/// std per component; displacements one std for all components (see [`crate::NormStats`]).
pub fn compute_stats(
    shapes: &[&ShapeSample],
    sequences: &[&SequenceSample],
    n_betas: usize,
    n_inputs: usize,
    n_outputs: usize,
) -> Result<NormStats> {
    if shapes.is_empty() || sequences.is_empty() {
        return Err(Error::invalid(
            "statistics",
            format!(
                "need training shapes and sequences, got {} and {}",
                shapes.len(),
                sequences.len()
            ),
        ));
    }
    let (mut fit_in, mut fit_out) = (Moments::new(n_betas), Moments::new(n_outputs));
    for s in shapes {
        fit_in.add_rows(&s.betas);
        fit_out.add_rows(&s.fit_delta);
    }
    let (mut w_in, mut w_out) = (Moments::new(n_inputs), Moments::new(n_outputs));
    for q in sequences {
        w_in.add_rows(&q.inputs);
        w_out.add_rows(&q.wrinkle_delta);
    }
    Ok(NormStats {
        fit_in: fit_in.per_component(),
        wrinkle_in: w_in.per_component(),
        fit_out: fit_out.isotropic(),
        wrinkle_out: w_out.isotropic(),
    })
}

/// Settings of the PCA of `Δ_L`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PcaSettings {
    /// Components kept `k`.
    pub components: usize,
    /// At most this many training frames (an evenly spaced subset) enter the decomposition.
    pub max_frames: usize,
    /// Seed of the random projection.
    pub seed: u64,
}

/// The top `k` principal components of the normalised `Δ_L` over `sequences`, by sartor-core's
/// randomized SVD ([`sartor_core::rsvd`]) of the centred frames. The explained-variance ratios are relative to the total variance of
/// the subset, so they show how much of `Δ_L` the basis keeps.
pub fn compute_pca(
    sequences: &[&SequenceSample],
    stats: &NormStats,
    settings: &PcaSettings,
) -> Result<PcaBasis> {
    let d = stats.wrinkle_out.mean.len();
    let total_frames: usize = sequences.iter().map(|q| q.n_frames).sum();
    if total_frames == 0 || settings.components == 0 || settings.max_frames == 0 {
        return Err(Error::invalid(
            "PCA",
            format!(
                "{} frames, {} components, max_frames {}",
                total_frames, settings.components, settings.max_frames
            ),
        ));
    }
    // An evenly spaced subset of frames, normalised.
    let n = total_frames.min(settings.max_frames);
    let mut rows: Vec<f32> = Vec::with_capacity(n * d);
    let mut index = 0usize;
    let mut next_pick = 0usize;
    for q in sequences {
        for t in 0..q.n_frames {
            if index * n / total_frames >= next_pick && next_pick < n {
                let start = rows.len();
                rows.extend_from_slice(&q.wrinkle_delta[t * d..(t + 1) * d]);
                stats.wrinkle_out.normalize(&mut rows[start..]);
                next_pick += 1;
            }
            index += 1;
        }
    }
    let n = rows.len() / d;
    let k = settings.components.min(n).min(d);
    let mut x = DMatrix::<f32>::from_row_slice(n, d, &rows);
    drop(rows);
    // Centre.
    let mean: Vec<f32> = (0..d)
        .map(|c| (x.column(c).iter().map(|&v| v as f64).sum::<f64>() / n as f64) as f32)
        .collect();
    for (c, m) in mean.iter().enumerate() {
        x.column_mut(c).add_scalar_mut(-m);
    }
    let total_variance: f64 = x.iter().map(|&v| (v as f64) * (v as f64)).sum();
    if total_variance <= 0.0 {
        return Err(Error::invalid(
            "PCA",
            "the wrinkle displacements have no variance",
        ));
    }
    let svd = randomized_svd(&Centred(x), k, settings.seed)?;
    let ratios = svd
        .singular_values
        .iter()
        .map(|s| s * s / total_variance)
        .collect();
    // The components are the right singular vectors: column `c` of the basis is row `c` of Vᵀ.
    let basis = (0..d * k).map(|i| svd.v_t[(i % k, i / k)] as f32).collect();
    Ok(PcaBasis {
        mean,
        basis,
        explained_variance_ratio: ratios,
    })
}

/// The centred frames `X` (`n × d`, f32) as the SVD's operator.
struct Centred(DMatrix<f32>);

impl LinearOperator for Centred {
    fn rows(&self) -> usize {
        self.0.nrows()
    }
    fn cols(&self) -> usize {
        self.0.ncols()
    }
    fn apply(&self, x: &DMatrix<f64>) -> sartor_core::Result<DMatrix<f64>> {
        Ok((&self.0 * x.map(|v| v as f32)).map(f64::from))
    }
    fn apply_transpose(&self, y: &DMatrix<f64>) -> sartor_core::Result<DMatrix<f64>> {
        Ok(self.0.tr_mul(&y.map(|v| v as f32)).map(f64::from))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Box–Muller: a standard-normal sample without a distribution crate.
    fn standard_normal<R: Rng>(rng: &mut R) -> f32 {
        let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
        let u2: f64 = rng.random::<f64>();
        ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
    }
    use crate::Split;

    fn sequence(values: Vec<f32>, d: usize) -> SequenceSample {
        let n_frames = values.len() / d;
        SequenceSample {
            id: "q".into(),
            shape: 0,
            motion: "m".into(),
            split: Split::Train,
            n_frames,
            inputs: vec![0.0; n_frames],
            wrinkle_delta: values,
        }
    }

    #[test]
    fn pca_recovers_a_planted_subspace() {
        // 400 frames in 30 dimensions: two strong directions plus weak noise.
        let d = 30;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let a: Vec<f32> = (0..d).map(|_| standard_normal(&mut rng)).collect();
        let b: Vec<f32> = (0..d)
            .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let mut values = Vec::new();
        for _ in 0..400 {
            let (s, t) = (3.0 * standard_normal(&mut rng), standard_normal(&mut rng));
            for i in 0..d {
                values.push(s * a[i] + t * b[i] + 0.01 * standard_normal(&mut rng) + 0.5);
            }
        }
        let q = sequence(values, d);
        let stats = compute_stats(
            &[&ShapeSample {
                id: "s".into(),
                betas: vec![0.0],
                fit_delta: vec![0.0; d],
                split: Split::Train,
            }],
            &[&q],
            1,
            1,
            d,
        )
        .expect("valid");
        let pca = compute_pca(
            &[&q],
            &stats,
            &PcaSettings {
                components: 2,
                max_frames: 1000,
                seed: 1,
            },
        )
        .expect("valid");
        let kept: f64 = pca.explained_variance_ratio.iter().sum();
        assert!(kept > 0.999, "two components keep {kept}");
        assert!(pca.explained_variance_ratio[0] > pca.explained_variance_ratio[1]);
        // Orthonormal columns.
        for c in 0..2 {
            for e in 0..2 {
                let dot: f32 = (0..d)
                    .map(|r| pca.basis[r * 2 + c] * pca.basis[r * 2 + e])
                    .sum();
                let expected = if c == e { 1.0 } else { 0.0 };
                assert!((dot - expected).abs() < 1e-4, "({c}, {e}): {dot}");
            }
        }
        // The planted directions lie in the span: residual of b after projection is tiny.
        let norm_b: f32 = b.iter().map(|v| v * v).sum::<f32>().sqrt();
        let coef: Vec<f32> = (0..2)
            .map(|c| (0..d).map(|r| pca.basis[r * 2 + c] * b[r] / norm_b).sum())
            .collect();
        let residual: f32 = (0..d)
            .map(|r| {
                let p: f32 = (0..2).map(|c| coef[c] * pca.basis[r * 2 + c]).sum();
                (b[r] / norm_b - p).powi(2)
            })
            .sum::<f32>()
            .sqrt();
        assert!(residual < 0.01, "residual {residual}");
    }

    #[test]
    fn stats_are_isotropic_for_displacements_and_floor_constant_inputs() {
        let d = 3;
        let q = SequenceSample {
            inputs: vec![5.0, 1.0, 5.0, 3.0],
            ..sequence(vec![0.0, 1.0, 0.0, 0.0, 3.0, 0.0], d)
        };
        let shape = ShapeSample {
            id: "s".into(),
            betas: vec![0.0],
            fit_delta: vec![0.0; d],
            split: Split::Train,
        };
        let stats = compute_stats(&[&shape], &[&q], 1, 2, d).expect("valid");
        // Input 0 is constant (5): std 1; input 1 is 1, 3: std 1 (population).
        assert_eq!(stats.wrinkle_in.mean, vec![5.0, 2.0]);
        assert_eq!(stats.wrinkle_in.std, vec![1.0, 1.0]);
        // Outputs: component 1 varies (1, 3): variance 1, others 0 → RMS std sqrt(1/3).
        let s = stats.wrinkle_out.std[0];
        assert!((s - (1.0f32 / 3.0).sqrt()).abs() < 1e-6);
        assert!(stats.wrinkle_out.std.iter().all(|&x| x == s));
        assert_eq!(stats.fit_in.std, vec![1.0]);
    }
}
