//! The signed distance of cloth vertices to the posed body by the one collision measure of the
//! workspace ([`sartor_core::BodyDistance`]: exact distance to the whole body, inside by its
//! generalized winding number), and its distribution over many vertex-frames: percentiles to
//! 0.01 mm, the share below 0 mm and below −1 mm (the simulator's promise: none below −1 mm).
//!
//! `eval` reports it for the held-out ground truth (`ground_truth_signed_distance` in
//! `eval.json`) and counts the methods' collisions before and after the post-process with it.

use std::collections::BTreeMap;
use std::sync::Arc;

use nalgebra::Vector3;
use sartor_core::{BodyDistance, BodyModel, Pose};
use serde::Serialize;

use crate::Result;
use crate::error::Context;

/// Bin width of the distance histogram, mm.
const BIN_MM: f64 = 0.01;
/// The histogram covers ±this, mm; beyond, values are counted in the end bins.
const RANGE_MM: f64 = 200.0;

/// A histogram of signed distances (0.01 mm bins over ±200 mm) with exact counts below 0 and
/// −1 mm: percentiles to 0.01 mm without keeping every value. Where the values below −1 mm lie,
/// when the caller says ([`DistanceHistogram::add_deep_place`]): per body part, and how many
/// between two parts.
#[derive(Clone, Debug)]
pub struct DistanceHistogram {
    counts: Vec<u64>,
    total: u64,
    below_zero: u64,
    below_minus_1_mm: u64,
    min_mm: f64,
    deep_by_part: BTreeMap<String, u64>,
    deep_between_parts: u64,
}

impl Default for DistanceHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; (2.0 * RANGE_MM / BIN_MM) as usize + 1],
            total: 0,
            below_zero: 0,
            below_minus_1_mm: 0,
            min_mm: f64::INFINITY,
            deep_by_part: BTreeMap::new(),
            deep_between_parts: 0,
        }
    }
}

impl DistanceHistogram {
    /// Add one signed distance, m.
    pub fn add_m(&mut self, d_m: f64) {
        let d_mm = d_m * 1e3;
        let bin = ((d_mm.clamp(-RANGE_MM, RANGE_MM) + RANGE_MM) / BIN_MM).floor() as usize;
        let last = self.counts.len() - 1;
        self.counts[bin.min(last)] += 1;
        self.total += 1;
        self.below_zero += u64::from(d_mm < 0.0);
        self.below_minus_1_mm += u64::from(d_mm < -1.0);
        self.min_mm = self.min_mm.min(d_mm);
    }

    /// Where a value more than 1 mm inside lies: the body part (joint) of the closest body
    /// triangle, and whether that triangle's own pseudo-normal calls it outside (the point is
    /// inside another part that overlaps this one: caught between two parts).
    pub fn add_deep_place(&mut self, part: &str, between_parts: bool) {
        // The part's name is allocated once per histogram, not once per point.
        match self.deep_by_part.get_mut(part) {
            Some(n) => *n += 1,
            None => {
                self.deep_by_part.insert(part.to_string(), 1);
            }
        }
        self.deep_between_parts += u64::from(between_parts);
    }

    /// Add another histogram's counts.
    pub fn merge(&mut self, o: &Self) {
        self.counts
            .iter_mut()
            .zip(&o.counts)
            .for_each(|(a, b)| *a += b);
        self.total += o.total;
        self.below_zero += o.below_zero;
        self.below_minus_1_mm += o.below_minus_1_mm;
        self.min_mm = self.min_mm.min(o.min_mm);
        for (part, n) in &o.deep_by_part {
            *self.deep_by_part.entry(part.clone()).or_default() += n;
        }
        self.deep_between_parts += o.deep_between_parts;
    }

    /// Distances counted.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// Distances below 0 (inside the body).
    pub fn below_zero(&self) -> u64 {
        self.below_zero
    }

    /// The value below which a share `q` (0..1) of the distances lie (the bin's lower edge), mm.
    pub fn percentile_mm(&self, q: f64) -> f64 {
        quantile_bin(&self.counts, self.total, q)
            .map_or(RANGE_MM, |bin| bin as f64 * BIN_MM - RANGE_MM)
    }

    /// The distribution as reported.
    pub fn summary(&self) -> DistanceSummary {
        let pct = |n: u64| 100.0 * n as f64 / self.total.max(1) as f64;
        DistanceSummary {
            vertex_frames: self.total,
            below_0_mm_percent: pct(self.below_zero),
            below_minus_1_mm_percent: pct(self.below_minus_1_mm),
            at_or_above_minus_1_mm_percent: 100.0 - pct(self.below_minus_1_mm),
            min_mm: self.min_mm.is_finite().then_some(self.min_mm),
            percentiles_mm: [0.0001, 0.001, 0.01, 0.05, 0.5, 0.95]
                .iter()
                .map(|&q| (format!("p{}", q * 100.0), self.percentile_mm(q)))
                .collect(),
            below_minus_1_mm_by_body_part: {
                let mut parts: Vec<(String, u64)> = self
                    .deep_by_part
                    .iter()
                    .map(|(p, n)| (p.clone(), *n))
                    .collect();
                parts.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
                parts
            },
            below_minus_1_mm_between_parts: self.deep_between_parts,
        }
    }
}

/// The bin of a histogram's `counts` (over `total` values) holding the `⌈q total⌉`-th smallest
/// value (the first, for `q` = 0); `None` when the counts hold fewer.
pub(crate) fn quantile_bin(counts: &[u64], total: u64, q: f64) -> Option<usize> {
    let target = (q * total as f64).ceil().max(1.0) as u64;
    let mut seen = 0;
    counts.iter().position(|&c| {
        seen += c;
        seen >= target
    })
}

/// The distribution of the signed distance, as written to reports.
#[derive(Clone, Debug, Default, Serialize)]
pub struct DistanceSummary {
    /// Cloth vertices × frames.
    pub vertex_frames: u64,
    /// Share inside the body, %.
    pub below_0_mm_percent: f64,
    /// Share more than 1 mm inside, %.
    pub below_minus_1_mm_percent: f64,
    /// Share at or above −1 mm (the goal: ≥ 99.9 %), %.
    pub at_or_above_minus_1_mm_percent: f64,
    /// The deepest, mm.
    pub min_mm: Option<f64>,
    /// Percentiles (0.01 %, 0.1 %, 1 %, 5 %, 50 %, 95 %), mm, to 0.01 mm (bin lower edges).
    pub percentiles_mm: Vec<(String, f64)>,
    /// The vertex-frames more than 1 mm inside per body part (the joint that dominates the
    /// closest body triangle's skinning), most first.
    pub below_minus_1_mm_by_body_part: Vec<(String, u64)>,
    /// Of the vertex-frames more than 1 mm inside, those whose closest body triangle's
    /// pseudo-normal calls them outside: inside another part that overlaps it (an arm sunk into
    /// the torso, a thigh into the belly), caught between two parts.
    pub below_minus_1_mm_between_parts: u64,
}

/// The whole body posed frame after frame, with a [`BodyDistance`] refitted to it. Keeps a
/// closest-face hint per cloth vertex between frames (same answers, less work).
pub struct PosedBody {
    body: Arc<BodyModel>,
    distance: Option<BodyDistance>,
    hints: Vec<u32>,
    /// Per body triangle, the joint with the largest skin weight summed over its vertices.
    face_parts: Vec<usize>,
}

impl PosedBody {
    /// For `body`; pose it with [`PosedBody::pose`] before the first query.
    pub fn new(body: Arc<BodyModel>) -> Self {
        let face_parts = body.skin_weights().face_dominant_joints(body.faces());
        Self {
            body,
            distance: None,
            hints: Vec::new(),
            face_parts,
        }
    }

    /// Pose the whole body at `betas` (padded with zeros or cut to the model's count) and `pose`.
    pub fn pose(&mut self, betas: &[f64], pose: &Pose) -> Result<()> {
        let mut b = betas.to_vec();
        b.resize(self.body.n_betas(), 0.0);
        let posed = self.body.posed_vertices(&b, pose)?;
        match &mut self.distance {
            Some(d) => d.update_positions(&posed)?,
            None => self.distance = Some(BodyDistance::new(&posed, self.body.faces())?),
        }
        Ok(())
    }

    /// Add the signed distance of every point to the body as last posed to `histogram`; returns
    /// how many are inside.
    pub fn measure(
        &mut self,
        points: impl ExactSizeIterator<Item = Vector3<f64>>,
        histogram: &mut DistanceHistogram,
    ) -> Result<usize> {
        let distance = self
            .distance
            .as_ref()
            .context("pose the body before asking for distances")?;
        self.hints.resize(points.len(), u32::MAX);
        let mut inside = 0;
        let names = self.body.skeleton().names();
        for (p, hint) in points.zip(&mut self.hints) {
            let q = distance.query_hinted(&p, hint);
            let d = q.signed_distance_m;
            inside += usize::from(d < 0.0);
            histogram.add_m(d);
            if d < -1e-3 {
                let part = &names[self.face_parts[q.closest.face as usize]];
                histogram.add_deep_place(part, q.closest.signed_distance_m >= 0.0);
            }
        }
        Ok(inside)
    }
}

/// [`crate::ground_truth_signed_distance`] of simulated sequence files (`*.mcap`, e.g. a run's
/// `sim/` folder), their motion frames only (as `eval`, unless `all_frames`): per file its
/// stem and histogram, in the order given; files in parallel on rayon's pool.
pub fn sequence_files_signed_distance(
    body: &Arc<BodyModel>,
    files: &[std::path::PathBuf],
    all_frames: bool,
) -> Result<Vec<(String, DistanceHistogram)>> {
    use rayon::prelude::*;
    files
        .par_iter()
        .map(|path| -> Result<(String, DistanceHistogram)> {
            let seq = sartor_cloth::ClothSequence::read(path)?;
            let mut posed = PosedBody::new(body.clone());
            let mut histogram = DistanceHistogram::default();
            for f in seq
                .frames
                .iter()
                .filter(|f| all_frames || f.phase == sartor_cloth::Phase::Motion)
            {
                posed.pose(&f.betas, &f.pose)?;
                posed.measure(
                    f.positions_vec3().iter().map(|p| p.cast::<f64>()),
                    &mut histogram,
                )?;
            }
            let stem = path
                .file_stem()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
            Ok((stem, histogram))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_counts_and_percentiles() {
        let mut h = DistanceHistogram::default();
        // -2.5 mm, then 0.000, 0.001, ..., 0.998 m (one thousand values from 0 to 998 mm).
        h.add_m(-2.5e-3);
        for i in 0..999 {
            h.add_m(i as f64 * 1e-3);
        }
        let mut other = DistanceHistogram::default();
        other.add_m(-0.5e-3);
        h.merge(&other);
        let s = h.summary();
        assert_eq!(s.vertex_frames, 1001);
        assert!((s.below_0_mm_percent - 200.0 / 1001.0).abs() < 1e-12);
        assert!((s.below_minus_1_mm_percent - 100.0 / 1001.0).abs() < 1e-12);
        assert_eq!(s.min_mm, Some(-2.5));
        assert!(s.below_minus_1_mm_by_body_part.is_empty());
        assert!((h.percentile_mm(0.0) - (-2.5)).abs() <= BIN_MM + 1e-9);
        // The median: the 501st value is 499 mm, beyond the ±200 mm range: the top bin.
        assert!((h.percentile_mm(0.5) - RANGE_MM).abs() < 1e-9);
        // The 3rd value is 0 mm.
        assert!(h.percentile_mm(2.5 / 1001.0).abs() <= BIN_MM + 1e-9);
    }

    #[test]
    fn deep_points_are_placed_by_body_part_and_pockets_between_parts_are_told_apart() {
        use sartor_motion::{MotionSourceOptions, RetargetBody, load_motion};
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let body_dir = root.join("datasets/body/makehuman");
        let body = Arc::new(BodyModel::load(&body_dir).expect("built-in body"));
        let names = body.skeleton().names();
        let dominant = |v: usize| names[body.skin_weights().dominant_joint(v)].as_str();
        // CMU 05_18, frame 50, on β₀ = 2: the hanging upper arms sink into the torso's sides
        // (what `ArmClearance`'s upper-arm option mends). Points 5 mm under the skin of a
        // forearm are inside one part; points 2 mm outside the skin of an upper arm far from
        // the shoulder are, where they are inside at all, inside the torso: between two parts.
        let options = MotionSourceOptions {
            motions_dir: root.join("datasets/motions"),
            body: Some(RetargetBody::load(&body_dir).expect("retarget body")),
            ..MotionSourceOptions::default()
        };
        let clip = load_motion("cmu/05_18@184+90", &options).expect("clip");
        let betas = [2.0];
        let pose = &clip.frames()[50];
        let positions = body.posed_vertices(&[2.0, 0.0], pose).expect("posed");
        let normals = sartor_core::vertex_normals(&positions, body.faces());
        let mut posed = PosedBody::new(body.clone());
        posed.pose(&betas, pose).expect("pose");

        let forearm: Vec<Vector3<f64>> = (0..body.n_vertices())
            .filter(|&v| dominant(v) == "LeftForeArm")
            .map(|v| positions[v] - normals[v] * 5e-3)
            .collect();
        let mut under = DistanceHistogram::default();
        let inside = posed
            .measure(forearm.iter().copied(), &mut under)
            .expect("measure");
        let s = under.summary();
        assert!(
            inside as f64 > 0.9 * forearm.len() as f64,
            "{inside} of {}",
            forearm.len()
        );
        assert_eq!(s.below_minus_1_mm_between_parts, 0, "{s:?}");
        let under_deep: u64 = s.below_minus_1_mm_by_body_part.iter().map(|p| p.1).sum();
        let (top, n) = &s.below_minus_1_mm_by_body_part[0];
        assert_eq!(top, "LeftForeArm", "{s:?}");
        assert!(*n as f64 > 0.8 * forearm.len() as f64, "{s:?}");

        let outside_upper_arms: Vec<Vector3<f64>> = (0..body.n_vertices())
            .filter(|&v| matches!(dominant(v), "LeftArm" | "RightArm"))
            .map(|v| positions[v] + normals[v] * 2e-3)
            .collect();
        let mut pocket = DistanceHistogram::default();
        posed
            .measure(outside_upper_arms.iter().copied(), &mut pocket)
            .expect("measure");
        let s = pocket.summary();
        let deep: u64 = s.below_minus_1_mm_by_body_part.iter().map(|p| p.1).sum();
        assert!(
            deep >= 10,
            "the arms sink into the torso in this frame: {s:?}"
        );
        assert!(
            s.below_minus_1_mm_between_parts as f64 >= 0.9 * deep as f64,
            "{s:?}"
        );
        // The merged counts add up.
        under.merge(&pocket);
        let merged = under.summary();
        let total: u64 = merged
            .below_minus_1_mm_by_body_part
            .iter()
            .map(|p| p.1)
            .sum();
        assert_eq!(total, under_deep + deep);
        assert_eq!(
            merged.below_minus_1_mm_between_parts,
            s.below_minus_1_mm_between_parts
        );
    }
}
