//! How far a garment's edges are stretched: each edge's length over its length in the template
//! (the rest garment), and the distribution of that ratio over many edge-frames: quantiles to
//! 0.001 without keeping every value, the exact maximum, and the shares stretched beyond 1.5×
//! and 2×.
//!
//! `eval` reports it for every method after and before the post-process (`edge_stretch`,
//! `edge_stretch_before_pp`) and for the simulated ground truth of the same frames
//! (`ground_truth_edge_stretch` in `eval.json`), so that a model's stretched sleeves can be told
//! from cloth that stretches there in physics too; `demo` reports its p99 and maximum.
//! Knit cloth stretches by tens of percent; several times its length is a garment torn open.

use nalgebra::{RealField, Scalar, Vector3};
use sartor_core::MeshTopology;
use serde::Serialize;

use crate::Result;
use crate::error::ensure;
use crate::gt_distance::quantile_bin;

/// Bin width of the stretch histogram (a ratio, no unit).
const BIN: f64 = 0.001;
/// The histogram covers ratios in `[0, RANGE)`; larger ones are counted in the last bin (the
/// maximum is kept exactly).
const RANGE: f64 = 20.0;

/// A garment's edges and their lengths in its template.
#[derive(Clone, Debug)]
pub struct GarmentEdges {
    edges: Vec<[u32; 2]>,
    rest: Vec<f64>,
    n_vertices: usize,
}

impl GarmentEdges {
    /// The edges of `faces` over `template` (the rest garment); an error for a face index out
    /// of the template or an edge of zero length.
    pub fn new(template: &[Vector3<f32>], faces: &[[u32; 3]]) -> Result<Self> {
        let n = template.len();
        ensure!(
            faces.iter().flatten().all(|&v| (v as usize) < n),
            "the garment's faces index past its template ({n} vertices)"
        );
        let edges = MeshTopology::new(n, faces).edges;
        let rest: Vec<f64> = edges
            .iter()
            .map(|&[a, b]| f64::from((template[a as usize] - template[b as usize]).norm()))
            .collect();
        ensure!(
            rest.iter().all(|&l| l > 0.0),
            "the garment template has an edge of zero length"
        );
        Ok(Self {
            edges,
            rest,
            n_vertices: n,
        })
    }

    /// How many edges.
    pub fn len(&self) -> usize {
        self.edges.len()
    }

    /// Whether there are no edges.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Each edge's length in `garment` (the template's vertices, posed) over its rest length, in
    /// edge order.
    pub fn ratios<'a, T>(&'a self, garment: &'a [Vector3<T>]) -> impl Iterator<Item = f64> + 'a
    where
        T: Scalar + RealField + Copy + Into<f64>,
    {
        self.edges
            .iter()
            .zip(&self.rest)
            .map(move |(&[a, b], l)| (garment[a as usize] - garment[b as usize]).norm().into() / l)
    }

    /// Add one frame of `garment` to `histogram`; an error unless it has the template's vertex
    /// count.
    pub fn add_frame<T>(
        &self,
        garment: &[Vector3<T>],
        histogram: &mut StretchHistogram,
    ) -> Result<()>
    where
        T: Scalar + RealField + Copy + Into<f64>,
    {
        ensure!(
            garment.len() == self.n_vertices,
            "a garment frame has {} vertices, its template {}",
            garment.len(),
            self.n_vertices
        );
        self.ratios(garment).for_each(|r| histogram.add(r));
        Ok(())
    }
}

/// A histogram of edge stretch ratios (0.001 bins over `[0, 20)`), with the exact maximum and
/// exact counts beyond 1.5× and 2×.
#[derive(Clone, Debug)]
pub struct StretchHistogram {
    counts: Vec<u64>,
    total: u64,
    over_1_5: u64,
    over_2: u64,
    max: f64,
}

impl Default for StretchHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; (RANGE / BIN) as usize],
            total: 0,
            over_1_5: 0,
            over_2: 0,
            max: 0.0,
        }
    }
}

impl StretchHistogram {
    /// Add one ratio (NaN is counted as beyond every bin and makes the maximum NaN: a broken
    /// garment is not hidden).
    pub fn add(&mut self, ratio: f64) {
        let last = self.counts.len() - 1;
        let bin = if ratio.is_nan() {
            last
        } else {
            ((ratio.max(0.0) / BIN).floor() as usize).min(last)
        };
        self.counts[bin] += 1;
        self.total += 1;
        // NaN counts as beyond both.
        self.over_1_5 += u64::from(ratio.is_nan() || ratio > 1.5);
        self.over_2 += u64::from(ratio.is_nan() || ratio > 2.0);
        self.max = nan_max(self.max, ratio);
    }

    /// Add another histogram's counts.
    pub fn merge(&mut self, o: &Self) {
        let mine = [&mut self.total, &mut self.over_1_5, &mut self.over_2];
        let theirs = [o.total, o.over_1_5, o.over_2];
        for (a, b) in self
            .counts
            .iter_mut()
            .chain(mine)
            .zip(o.counts.iter().chain(&theirs))
        {
            *a += b;
        }
        self.max = nan_max(self.max, o.max);
    }

    /// Ratios counted.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// The largest ratio (NaN if one was; 0 when empty).
    pub fn max(&self) -> f64 {
        self.max
    }

    /// The value at or below which a share `q` (0..1) of the ratios lie: the upper edge of the
    /// bin holding the `⌈q n⌉`-th smallest (at most 0.001 above it), never above the maximum.
    pub fn quantile(&self, q: f64) -> f64 {
        quantile_bin(&self.counts, self.total, q)
            .map_or(self.max, |bin| ((bin + 1) as f64 * BIN).min(self.max))
    }

    /// The distribution as reported.
    pub fn summary(&self) -> StretchSummary {
        let pct = |n: u64| 100.0 * n as f64 / self.total.max(1) as f64;
        StretchSummary {
            edge_frames: self.total,
            edge_stretch_p50: self.quantile(0.5),
            edge_stretch_p99: self.quantile(0.99),
            edge_stretch_p999: self.quantile(0.999),
            edge_stretch_max: self.max,
            over_1_5x_percent: pct(self.over_1_5),
            over_2x_percent: pct(self.over_2),
        }
    }
}

/// The larger of `a` and `b`, NaN if either is (`f64::max` drops a NaN).
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// The distribution of edge stretch, as written to reports: each edge's length over its length
/// in the template, over edges × frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct StretchSummary {
    /// Edges × frames.
    pub edge_frames: u64,
    /// The median ratio (to 0.001, the bin's upper edge; a quantile of 20 or more reads 20).
    pub edge_stretch_p50: f64,
    /// The 99th percentile.
    pub edge_stretch_p99: f64,
    /// The 99.9th percentile.
    pub edge_stretch_p999: f64,
    /// The largest ratio, exact.
    pub edge_stretch_max: f64,
    /// Share of edge-frames longer than 1.5× their rest length, %.
    pub over_1_5x_percent: f64,
    /// Share longer than 2×, %.
    pub over_2x_percent: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quantiles against the exact order statistic of the values (sorted), on spread and
    /// clustered values: never below it, at most one bin above, and the maximum exact.
    #[test]
    fn quantiles_match_the_sorted_values_to_a_bin() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let values: Vec<f64> = (0..20_000)
            .map(|k| match k % 4 {
                0 => 0.8 + 0.4 * next(),
                1 => 1.0 + 0.002 * next(),
                2 => 1.0 + 6.0 * next() * next() * next(),
                _ => 25.0 * next(),
            })
            .collect();
        let mut h = StretchHistogram::default();
        values.iter().for_each(|&v| h.add(v));
        let mut sorted = values.clone();
        sorted.sort_by(f64::total_cmp);
        for q in [0.01, 0.5, 0.9, 0.99, 0.999] {
            let exact = sorted[(q * sorted.len() as f64).ceil() as usize - 1];
            let got = h.quantile(q);
            assert!(
                got >= exact && got <= exact + BIN + 1e-12 || exact >= RANGE,
                "q {q}: {got} against {exact}"
            );
        }
        let s = h.summary();
        assert_eq!(s.edge_stretch_max, sorted[sorted.len() - 1]);
        let over = |t: f64| 100.0 * values.iter().filter(|&&v| v > t).count() as f64 / 2e4;
        assert_eq!(s.over_1_5x_percent, over(1.5));
        assert_eq!(s.over_2x_percent, over(2.0));
        // Merged halves read as the whole.
        let (mut a, mut b) = (StretchHistogram::default(), StretchHistogram::default());
        values[..7_000].iter().for_each(|&v| a.add(v));
        values[7_000..].iter().for_each(|&v| b.add(v));
        a.merge(&b);
        assert_eq!(a.summary(), s);
    }

    /// A unit square of two triangles stretched 2× along x: its x edges read 2, its y edges 1,
    /// its diagonal √5/√2; a NaN vertex makes the maximum NaN and counts as over 2×.
    #[test]
    fn ratios_of_a_stretched_square() {
        let square = [
            Vector3::new(0.0f32, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(1.0, 1.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        let faces = [[0, 1, 2], [0, 2, 3]];
        let edges = GarmentEdges::new(&square, &faces).expect("edges");
        assert_eq!(edges.len(), 5);
        let stretched: Vec<Vector3<f64>> = square
            .iter()
            .map(|p| Vector3::new(2.0 * f64::from(p.x), f64::from(p.y), 0.0))
            .collect();
        let mut ratios: Vec<f64> = edges.ratios(&stretched).collect();
        ratios.sort_by(f64::total_cmp);
        let diagonal = 5.0f64.sqrt() / 2.0f64.sqrt();
        let want = [1.0, 1.0, diagonal, 2.0, 2.0];
        for (r, w) in ratios.iter().zip(want) {
            assert!((r - w).abs() < 1e-7, "{ratios:?}");
        }
        let mut h = StretchHistogram::default();
        edges.add_frame(&stretched, &mut h).expect("a frame");
        assert_eq!(h.summary().over_2x_percent, 0.0);
        assert!((h.summary().edge_stretch_max - 2.0).abs() < 1e-7);
        let mut broken = stretched.clone();
        broken[2].x = f64::NAN;
        edges.add_frame(&broken, &mut h).expect("a frame");
        assert!(h.summary().edge_stretch_max.is_nan());
        assert_eq!(h.summary().over_2x_percent, 100.0 * 3.0 / 10.0);
        // Too few vertices, or a degenerate template: errors.
        assert!(edges.add_frame(&stretched[..3], &mut h).is_err());
        let flat = [square[0], square[0], square[2]];
        assert!(GarmentEdges::new(&flat, &[[0, 1, 2]]).is_err());
        assert!(GarmentEdges::new(&square, &[[0, 1, 4]]).is_err());
    }
}
