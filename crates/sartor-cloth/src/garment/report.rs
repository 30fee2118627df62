//! The figures of a garment template, written as `garment-report.json`.

use rayon::prelude::*;
use sartor_core::MeshProximity;
use serde::{Deserialize, Serialize};

use super::intersect::self_intersections;
use super::quality::{LengthStatsMm, MeshQuality, percentile_sorted};
use super::template::{Garment, RestSource};

/// How the garment sits on the body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyFit {
    /// Deepest garment vertex inside the body, mm (0 when none is inside).
    pub max_penetration_mm: f64,
    /// Garment vertices inside the body.
    pub vertices_inside: usize,
    /// Signed distance of the garment vertices to the body surface ("ease"), mm: min, 5th
    /// percentile, median, mean, 95th percentile, max.
    pub ease_min_mm: f64,
    /// 5th percentile, mm.
    pub ease_p5_mm: f64,
    /// Median, mm.
    pub ease_p50_mm: f64,
    /// Mean, mm.
    pub ease_mean_mm: f64,
    /// 95th percentile, mm.
    pub ease_p95_mm: f64,
    /// Largest, mm.
    pub ease_max_mm: f64,
}

/// The quality report of a garment template.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GarmentReport {
    /// The garment's name.
    pub name: String,
    /// Where its rest metric comes from.
    pub rest_source: RestSource,
    /// Mesh quality (triangles, vertices, angles, edge lengths in mm, area, boundary loops,
    /// components, manifoldness).
    pub mesh: MeshQuality,
    /// Total rest area (from the rest metric), m².
    pub rest_area_m2: f64,
    /// Rest edge lengths from the rest metric, mm.
    pub rest_edge_length: LengthStatsMm,
    /// Pairs of triangles that intersect each other (sharing no vertex).
    pub self_intersecting_pairs: usize,
    /// Largest deviation of the material frames from orthonormality (|u|−1, |v|−1, u·v).
    pub frame_orthonormality_error: f64,
    /// Fit on the body, when a body was given.
    pub body: Option<BodyFit>,
}

impl GarmentReport {
    /// Measure `garment`, and its fit on `body` (a closest-point structure over the body
    /// surface the garment was made for) when given.
    pub fn measure(garment: &Garment, body: Option<&MeshProximity>) -> Self {
        let mesh = garment.mesh();
        let rest_edges: Vec<f64> = garment
            .rest_dm()
            .iter()
            .flat_map(|dm| {
                let (a, b) = (dm.column(0).into_owned(), dm.column(1).into_owned());
                [a.norm(), b.norm(), (b - a).norm()]
            })
            .collect();
        let frame_error = garment
            .frame_u()
            .iter()
            .zip(garment.frame_v())
            .map(|(u, v)| {
                (u.norm() - 1.0)
                    .abs()
                    .max((v.norm() - 1.0).abs())
                    .max(u.dot(v).abs())
            })
            .fold(0.0, f64::max);
        let fit = body.map(|body| {
            let mut d: Vec<f64> = mesh
                .positions()
                .par_iter()
                .map(|p| body.closest(p).signed_distance_m * 1e3)
                .collect();
            d.sort_by(f64::total_cmp);
            let q = |p: f64| percentile_sorted(&d, p);
            BodyFit {
                max_penetration_mm: (-d[0]).max(0.0),
                vertices_inside: d.iter().filter(|x| **x < 0.0).count(),
                ease_min_mm: d[0],
                ease_p5_mm: q(5.0),
                ease_p50_mm: q(50.0),
                ease_mean_mm: d.iter().sum::<f64>() / d.len() as f64,
                ease_p95_mm: q(95.0),
                ease_max_mm: d[d.len() - 1],
            }
        });
        Self {
            name: garment.name().to_string(),
            rest_source: garment.rest_source(),
            mesh: MeshQuality::of(mesh),
            rest_area_m2: garment.rest_area_m2().iter().sum(),
            rest_edge_length: LengthStatsMm::from_lengths_m(&rest_edges),
            self_intersecting_pairs: self_intersections(mesh).len(),
            frame_orthonormality_error: frame_error,
            body: fit,
        }
    }
}
