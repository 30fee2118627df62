//! The smoothing operator ρ of Santesteban et al.: it removes wrinkles from a garment mesh so
//! that the template `T̄_c = ρ(relaxed garment)` and the fit `Δ_G = ρ(S_c(β, 0)) − T̄_c` carry
//! only the overall shape, leaving every fold to the wrinkle regressor.
//!
//! ρ is Taubin's λ|μ smoothing (Taubin 1995): each iteration moves every vertex by `λ` times its
//! umbrella Laplacian (towards the mean of its neighbours), then by `μ < −λ` times the new
//! Laplacian (back out). The pair is a low-pass filter that removes wrinkle-scale detail without
//! the shrinkage of plain Laplacian smoothing (which would pull a T-shirt inside the body).
//! Boundary vertices (hem, neck, sleeve openings) are smoothed along their boundary loop only,
//! so openings keep their place and do not curl inwards.
//!
//! The strength is set in metres, not iterations, so ρ means the same on a coarse and a fine
//! garment: one λ|μ iteration multiplies a surface wave of frequency `k` (eigenvalue of the
//! umbrella operator) by `f(k) = (1 − λk)(1 − μk)`; for a wave of wavelength `L` on a mesh of
//! mean edge length `h`, `k ≈ 1 − cos(2πh/L)` (the 1-D estimate). The number of iterations is
//! the smallest that halves waves of [`Smoothing::cutoff_wavelength_m`]. With the defaults
//! (λ = 0.5, μ = −0.53, cutoff 10 cm) waves longer than about 19 cm (`k` below the pass band
//! `k_PB = 1/λ + 1/μ ≈ 0.11` at the paper's 13 mm edges) are kept (amplified by at most
//! 0.1 % per iteration) and wrinkles of a few centimetres are removed: about 40 iterations at the
//! paper's resolution, one on a 5 cm-edge toy mesh.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use sartor_core::MeshTopology;

use crate::{Error, Result};

/// Parameters of ρ.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Smoothing {
    /// Shrinking step λ, in (0, 1) (default 0.5).
    pub lambda: f64,
    /// Inflating step μ, with μ < −λ (default −0.53).
    pub mu: f64,
    /// Waves of this wavelength are halved, m (default 0.1).
    pub cutoff_wavelength_m: f64,
    /// Upper bound on the iterations (default 500).
    pub max_iterations: usize,
}

impl Default for Smoothing {
    fn default() -> Self {
        Self {
            lambda: 0.5,
            mu: -0.53,
            cutoff_wavelength_m: 0.1,
            max_iterations: 500,
        }
    }
}

impl Smoothing {
    /// Check the parameters.
    pub fn validate(&self) -> Result<()> {
        if !(self.lambda > 0.0 && self.lambda < 1.0) {
            return Err(Error::invalid(
                "smoothing",
                format!("lambda must be in (0, 1), got {}", self.lambda),
            ));
        }
        if !(self.mu.is_finite() && self.mu < -self.lambda && self.mu > -1.0) {
            return Err(Error::invalid(
                "smoothing",
                format!(
                    "mu must be in (-1, -lambda) = (-1, {}), got {}",
                    -self.lambda, self.mu
                ),
            ));
        }
        if !(self.cutoff_wavelength_m.is_finite() && self.cutoff_wavelength_m > 0.0) {
            return Err(Error::invalid(
                "smoothing",
                format!(
                    "cutoff_wavelength_m must be positive, got {}",
                    self.cutoff_wavelength_m
                ),
            ));
        }
        Ok(())
    }

    /// Iterations that halve waves of the cutoff wavelength on a mesh of mean edge length
    /// `edge_m` (at least 1, at most `max_iterations`).
    pub fn iterations_for(&self, edge_m: f64) -> usize {
        let ratio = (edge_m / self.cutoff_wavelength_m).min(0.5);
        let k = 1.0 - (2.0 * std::f64::consts::PI * ratio).cos();
        let f = ((1.0 - self.lambda * k) * (1.0 - self.mu * k)).abs();
        if f >= 1.0 {
            return self.max_iterations;
        }
        if f <= 0.0 {
            return 1;
        }
        ((0.5f64.ln() / f.ln()).ceil() as usize).clamp(1, self.max_iterations)
    }
}

/// The smoothing ρ of one garment mesh topology, with its neighbourhoods precomputed.
#[derive(Clone, Debug)]
pub struct Smoother {
    params: Smoothing,
    iterations: usize,
    mean_edge_m: f64,
    /// CSR neighbours used for each vertex (boundary vertices: boundary neighbours only).
    offsets: Vec<usize>,
    neighbours: Vec<u32>,
}

impl Smoother {
    /// Prepare ρ for a mesh with `faces` whose reference shape is `positions` (its mean edge
    /// length sets the number of iterations).
    pub fn new(positions: &[Vector3<f64>], faces: &[[u32; 3]], params: Smoothing) -> Result<Self> {
        params.validate()?;
        let n_vertices = positions.len();
        if let Some(f) = faces
            .iter()
            .position(|t| t.iter().any(|&v| v as usize >= n_vertices))
        {
            return Err(Error::invalid(
                "smoothing",
                format!("face {f} indexes past {n_vertices} vertices"),
            ));
        }
        let topology = MeshTopology::new(n_vertices, faces);
        if topology.edges.is_empty() {
            return Err(Error::invalid("smoothing", "the mesh has no edges"));
        }
        let mean_edge_m = topology
            .edges
            .iter()
            .map(|[a, b]| (positions[*a as usize] - positions[*b as usize]).norm())
            .sum::<f64>()
            / topology.edges.len() as f64;
        if !(mean_edge_m.is_finite() && mean_edge_m > 0.0) {
            return Err(Error::invalid(
                "smoothing",
                format!("mean edge length {mean_edge_m} m"),
            ));
        }
        let iterations = params.iterations_for(mean_edge_m);
        let on_boundary = topology.boundary_vertices();
        let boundary_edges = topology.boundary_edges();
        let mut boundary_neighbours: Vec<Vec<u32>> = vec![Vec::new(); n_vertices];
        for [a, b] in &boundary_edges {
            boundary_neighbours[*a as usize].push(*b);
            boundary_neighbours[*b as usize].push(*a);
        }
        let mut offsets = Vec::with_capacity(n_vertices + 1);
        offsets.push(0);
        let mut neighbours = Vec::new();
        for v in 0..n_vertices {
            if on_boundary[v] {
                let mut b = boundary_neighbours[v].clone();
                b.sort_unstable();
                neighbours.extend(b);
            } else {
                neighbours.extend_from_slice(topology.neighbours(v));
            }
            offsets.push(neighbours.len());
        }
        Ok(Self {
            params,
            iterations,
            mean_edge_m,
            offsets,
            neighbours,
        })
    }

    /// The parameters.
    pub fn params(&self) -> Smoothing {
        self.params
    }

    /// λ|μ iterations per application.
    pub fn iterations(&self) -> usize {
        self.iterations
    }

    /// Mean edge length of the reference shape, m.
    pub fn mean_edge_m(&self) -> f64 {
        self.mean_edge_m
    }

    /// Vertices of the mesh.
    pub fn n_vertices(&self) -> usize {
        self.offsets.len() - 1
    }

    fn laplacian_step(&self, x: &[Vector3<f64>], out: &mut [Vector3<f64>], step: f64) {
        for (v, o) in out.iter_mut().enumerate() {
            let ns = &self.neighbours[self.offsets[v]..self.offsets[v + 1]];
            *o = if ns.is_empty() {
                x[v]
            } else {
                let mean =
                    ns.iter().map(|&n| x[n as usize]).sum::<Vector3<f64>>() / ns.len() as f64;
                x[v] + (mean - x[v]) * step
            };
        }
    }

    /// `ρ(positions)`.
    pub fn apply(&self, positions: &[Vector3<f64>]) -> Result<Vec<Vector3<f64>>> {
        if positions.len() != self.n_vertices() {
            return Err(Error::invalid(
                "smoothing",
                format!(
                    "{} positions for a mesh of {} vertices",
                    positions.len(),
                    self.n_vertices()
                ),
            ));
        }
        if let Some(i) = positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(Error::invalid(
                "smoothing",
                format!("vertex {i} is not finite"),
            ));
        }
        let mut x = positions.to_vec();
        let mut tmp = x.clone();
        for _ in 0..self.iterations {
            self.laplacian_step(&x, &mut tmp, self.params.lambda);
            self.laplacian_step(&tmp, &mut x, self.params.mu);
        }
        Ok(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed-ish grid: an n × n sheet in the xz plane with unit spacing.
    fn sheet(n: usize) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let mut p = Vec::new();
        for i in 0..n {
            for j in 0..n {
                p.push(Vector3::new(i as f64, 0.0, j as f64));
            }
        }
        let mut f = Vec::new();
        for i in 0..n - 1 {
            for j in 0..n - 1 {
                let a = (i * n + j) as u32;
                let (b, c, d) = (a + 1, a + n as u32, a + n as u32 + 1);
                f.push([a, c, b]);
                f.push([b, c, d]);
            }
        }
        (p, f)
    }

    #[test]
    fn removes_high_frequency_and_keeps_low_frequency() {
        let n = 33;
        let (flat, faces) = sheet(n);
        // Unit edges: waves of 6 edges are halved, the 2-edge ripple is gone.
        let params = Smoothing {
            cutoff_wavelength_m: 6.0,
            ..Smoothing::default()
        };
        let smoother = Smoother::new(&flat, &faces, params).expect("valid");
        // Wrinkles: a 2-edge-period ripple; the fit: a 32-edge-period bulge.
        let ripple = |p: &Vector3<f64>| 0.1 * (std::f64::consts::PI * p.x).cos();
        let bulge = |p: &Vector3<f64>| (std::f64::consts::PI * p.x / 32.0).sin();
        let mut wavy = flat.clone();
        for p in &mut wavy {
            p.y = ripple(p) + bulge(p);
        }
        let smooth = smoother.apply(&wavy).expect("finite");
        // Away from the boundary, what is left is the bulge alone: the ripple (amplitude 0.1)
        // is gone and the bulge (amplitude 1) is kept.
        let mut deviation = 0.0f64;
        for (i, p) in smooth.iter().enumerate() {
            if (4..n - 4).contains(&(i / n)) && (4..n - 4).contains(&(i % n)) {
                deviation = deviation.max((p.y - bulge(&flat[i])).abs());
            }
        }
        assert!(
            deviation < 0.01,
            "largest deviation from the bulge: {deviation}"
        );
        // Plain Laplacian smoothing (μ = 0 in effect) would shrink the bulge measurably.
        let centre = (n / 2) * n + n / 2;
        assert!(smooth[centre].y > 0.99, "bulge top {}", smooth[centre].y);
    }

    #[test]
    fn a_flat_sheet_is_a_fixed_point_and_boundaries_stay_on_their_line() {
        let (flat, faces) = sheet(9);
        let params = Smoothing {
            cutoff_wavelength_m: 3.0,
            ..Smoothing::default()
        };
        let smoother = Smoother::new(&flat, &faces, params).expect("valid");
        let out = smoother.apply(&flat).expect("finite");
        for (a, b) in flat.iter().zip(&out) {
            assert!(a.y == 0.0 && b.y.abs() < 1e-12);
        }
        // A boundary vertex mid-way along the edge x = 0 stays on it (it is smoothed along the
        // boundary only; just the sheet's corners get rounded, which reaches it as a tiny drift).
        // With its interior neighbours it would be pulled inwards by a good part of an edge.
        assert!(out[4].x.abs() < 1e-3, "{:?}", out[4]);
    }

    #[test]
    fn iterations_follow_the_mesh_resolution() {
        let p = Smoothing::default();
        // The paper's 13 mm edges: tens of iterations; a 5 cm toy mesh: one.
        let fine = p.iterations_for(0.013);
        assert!((20..80).contains(&fine), "{fine}");
        assert_eq!(p.iterations_for(0.05), 1);
        assert!(p.iterations_for(0.005) > fine);
    }

    #[test]
    fn bad_parameters_and_inputs_are_errors() {
        let (flat, faces) = sheet(4);
        let bad = Smoothing {
            mu: -0.4,
            ..Smoothing::default()
        };
        assert!(Smoother::new(&flat, &faces, bad).is_err());
        assert!(Smoother::new(&flat[..3], &faces, Smoothing::default()).is_err());
        let s = Smoother::new(&flat, &faces, Smoothing::default()).expect("valid");
        assert!(s.apply(&flat[..5]).is_err());
        let mut nan = flat.clone();
        nan[2].x = f64::NAN;
        assert!(s.apply(&nan).is_err());
    }
}
