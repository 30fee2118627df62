//! Triangle-mesh quality figures: angles, edge-length spread, topology.

use sartor_core::TriMesh;
use serde::{Deserialize, Serialize};

/// Distribution of a length, mm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LengthStatsMm {
    /// Shortest, mm.
    pub min_mm: f64,
    /// 5th percentile, mm.
    pub p5_mm: f64,
    /// Median, mm.
    pub p50_mm: f64,
    /// 95th percentile, mm.
    pub p95_mm: f64,
    /// Longest, mm.
    pub max_mm: f64,
    /// Mean, mm.
    pub mean_mm: f64,
    /// Longest / shortest.
    pub max_over_min: f64,
    /// 95th / 5th percentile.
    pub p95_over_p5: f64,
}

impl LengthStatsMm {
    /// Statistics of lengths given in metres (empty input: all zero).
    pub fn from_lengths_m(lengths_m: &[f64]) -> Self {
        if lengths_m.is_empty() {
            return Self {
                min_mm: 0.0,
                p5_mm: 0.0,
                p50_mm: 0.0,
                p95_mm: 0.0,
                max_mm: 0.0,
                mean_mm: 0.0,
                max_over_min: 0.0,
                p95_over_p5: 0.0,
            };
        }
        let mut mm: Vec<f64> = lengths_m.iter().map(|l| l * 1e3).collect();
        mm.sort_by(f64::total_cmp);
        let q = |p: f64| percentile_sorted(&mm, p);
        let (min, max) = (mm[0], mm[mm.len() - 1]);
        Self {
            min_mm: min,
            p5_mm: q(5.0),
            p50_mm: q(50.0),
            p95_mm: q(95.0),
            max_mm: max,
            mean_mm: mm.iter().sum::<f64>() / mm.len() as f64,
            max_over_min: max / min,
            p95_over_p5: q(95.0) / q(5.0),
        }
    }
}

/// The `p`-th percentile (0–100) of sorted values, linearly interpolated.
pub(crate) fn percentile_sorted(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let x = (p / 100.0).clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let i = x.floor() as usize;
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] + (sorted[j] - sorted[i]) * (x - i as f64)
}

/// Quality of a triangle mesh.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshQuality {
    /// Number of triangles.
    pub triangles: usize,
    /// Number of vertices.
    pub vertices: usize,
    /// Smallest triangle angle, deg.
    pub min_angle_deg: f64,
    /// Largest triangle angle, deg.
    pub max_angle_deg: f64,
    /// 1st percentile of the per-triangle smallest angle, deg.
    pub p1_min_angle_deg: f64,
    /// Share of triangles whose smallest angle is below 30°.
    pub fraction_below_30_deg: f64,
    /// Edge lengths.
    pub edge_length: LengthStatsMm,
    /// Total area, m².
    pub area_m2: f64,
    /// Number of boundary loops.
    pub boundary_loops: usize,
    /// Number of connected components (by shared edges).
    pub components: usize,
    /// Whether the mesh is an oriented 2-manifold (with boundary).
    pub manifold: bool,
    /// Number of vertices whose valence is 6 (interior) or 4 (boundary), over all vertices.
    pub fraction_regular_valence: f64,
}

impl MeshQuality {
    /// Measure `mesh`.
    pub fn of(mesh: &TriMesh) -> Self {
        let p = mesh.positions();
        let topology = mesh.topology();
        let mut min_angles = Vec::with_capacity(mesh.n_faces());
        let mut max_angle = 0.0f64;
        for t in mesh.faces() {
            let x = t.map(|i| p[i as usize]);
            let mut tri_min = f64::INFINITY;
            for k in 0..3 {
                let a = (x[(k + 1) % 3] - x[k]).angle(&(x[(k + 2) % 3] - x[k]));
                tri_min = tri_min.min(a);
                max_angle = max_angle.max(a);
            }
            min_angles.push(tri_min.to_degrees());
        }
        min_angles.sort_by(f64::total_cmp);
        let lengths: Vec<f64> = topology
            .edges
            .iter()
            .map(|[a, b]| (p[*a as usize] - p[*b as usize]).norm())
            .collect();
        let boundary = topology.boundary_vertices();
        let regular = (0..mesh.n_vertices())
            .filter(|&v| {
                let valence = topology.neighbours(v).len();
                valence == if boundary[v] { 4 } else { 6 }
            })
            .count();
        let manifold = topology.check_manifold().is_ok();
        Self {
            triangles: mesh.n_faces(),
            vertices: mesh.n_vertices(),
            min_angle_deg: min_angles.first().copied().unwrap_or(0.0),
            max_angle_deg: max_angle.to_degrees(),
            p1_min_angle_deg: percentile_sorted(&min_angles, 1.0),
            fraction_below_30_deg: min_angles.iter().filter(|a| **a < 30.0).count() as f64
                / min_angles.len().max(1) as f64,
            edge_length: LengthStatsMm::from_lengths_m(&lengths),
            area_m2: mesh.face_areas().iter().sum(),
            boundary_loops: if manifold {
                topology.boundary_loops().len()
            } else {
                0
            },
            components: topology.face_components().1,
            manifold,
            fraction_regular_valence: regular as f64 / mesh.n_vertices().max(1) as f64,
        }
    }
}
