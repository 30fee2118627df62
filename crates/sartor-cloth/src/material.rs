//! Cloth materials: ARCSim's tabulated ("data-driven elastic", Wang et al. 2011) membrane and
//! bending models, a plain StVK membrane for tests, and material files.
//!
//! # Membrane energy
//!
//! Every membrane model is, *for a given stiffness*, a quadratic form in the Green strain
//! `G = ½ (FᵀF − I)` (2 × 2, in the material frame u, v) with `g = (G00, G11, G01)`:
//!
//! ```text
//! ψ = ½ k_uu G00² + k_uv G00 G11 + ½ k_vv G11² + ½ k_shear G01²      (J/m², per rest area)
//! ```
//!
//! - Tabulated (ARCSim `use_dde`): `(k_uu, k_uv, k_vv) = (k0, k1, k2)` and **`k_shear = 2 k3`**,
//!   where `k0..k3` come from [`TabulatedMembrane::arcsim_stiffness`]. ARCSim's
//!   `stretching_energy` (a diagnostic) writes the shear term as `½ k3 G01²`, but its
//!   `stretching_force` — the force the simulation integrates — has `2 k3 G01 ∂G01/∂x`, the
//!   gradient of `k3 G01²`. We follow the force, so the simulated material is the one that
//!   produced ARCSim's (and the paper's) data.
//! - StVK: `ψ = μ G:G + λ/2 tr(G)²`, i.e. `k_uu = k_vv = 2μ + λ`, `k_uv = λ`, `k_shear = 4μ`.
//!
//! The tabulated stiffness depends on the strain. As ARCSim does, the simulator looks it up
//! once per step from the strain at the start of the step and treats it as a constant for
//! the gradient and Hessian; the energies in [`crate::energy`] are therefore exact for the
//! quadratic form with the stiffness frozen, and the finite-difference tests check that.
//!
//! # ARCSim's stretching lookup (`dde.cpp`), reproduced
//!
//! When a material file is loaded, ARCSim builds `data.d[2][5]`: `d[0][·]` = row 0 (small
//! strain) for every angle, `d[1][a]` = row `a + 1` (principal stretch `1 + 1/6` at angle
//! `a · 22.5°`). It then samples a 30 × 30 × 30 grid over `G00, G11 ∈ −0.25 + i/30` and
//! `G01 ∈ k/30` (`evaluate_stretching_samples`); each sample:
//!
//! 1. `C = 2G + I`, largest eigenvalue `l1` and its eigenvector `V` (ARCSim's closed-form 2 × 2
//!    eigen decomposition); principal stretch `w = √l1`;
//! 2. angle weight `|atan2(V1, V0)| / π · 8`, clamped to `[0, 4 − 1e-6]` (0 = along u, 4 = along
//!    v), split into an index and a fraction;
//! 3. strain weight `s = (w − 1) · 6` clamped to `[0, 1 − 1e-6]` (ARCSim forces the strain index
//!    to 0, so it only ever interpolates between row 0 and the angle rows);
//! 4. `k = (1 − s) · row0 + s · lerp(angle rows)`; negatives clamped to 0; every value doubled.
//!
//! At run time `stretching_stiffness(G)` interpolates the grid trilinearly at
//! `((G00 + 0.25)·30, (G11 + 0.25)·30, |G01|·30)`, each clamped to `[0, 29 − 1e-5]` (strains
//! outside the grid use the boundary samples). ARCSim computes the angle with `atan2f` /
//! `fabsf` in single precision; we use f64 (differences ~1e-7 relative).
//!
//! # ARCSim's bending lookup (`dde.cpp` `bending_stiffness`), reproduced
//!
//! `curv = θ · l / (A0 + A1)` (θ the signed dihedral angle, `l` the current edge length, `A0 + A1`
//! the rest areas of the two faces), `value = curv / 2 · 0.2` (the table has columns every
//! 5 m⁻¹ of `curv / 2`), clamped above at 4, index `trunc(value)` clamped to `[0, 3]`, fraction
//! `value − index`. The direction is the edge's angle in the material frame, folded to
//! `[0°, 90°]` and mapped to rows 0°/45°/90°. The result is clamped to be non-negative, and the
//! hinge uses the minimum over its two faces. Note a quirk we keep: for `θ < 0`, `value` is
//! negative, the index is 0 and the fraction negative, so ARCSim *extrapolates* the first table
//! segment (and clamps at 0) — folds of the two signs get different stiffnesses.

use std::path::Path;

use nalgebra::Matrix2;
use serde::{Deserialize, Serialize};

use crate::energy::{F64x4, Real};
use crate::{Error, Result};

/// Number of samples per axis of ARCSim's stretching-stiffness grid.
pub const STRAIN_GRID_SAMPLES: usize = 30;

/// The stiffness of a membrane quadratic form in the Green strain (see the module docs):
/// `ψ = ½ k_uu G00² + k_uv G00 G11 + ½ k_vv G11² + ½ k_shear G01²`, N/m.
///
/// `T` is `f64`, or [`crate::energy::F64x4`] for four triangles' stiffnesses side by side.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StrainStiffness<T = f64> {
    /// Warp (u) stiffness.
    pub k_uu: T,
    /// u–v coupling.
    pub k_uv: T,
    /// Weft (v) stiffness.
    pub k_vv: T,
    /// Shear stiffness (multiplies `½ G01²`).
    pub k_shear: T,
}

impl<T: Real> StrainStiffness<T> {
    /// Energy density ψ (J/m²) of the Green strain `g`.
    #[inline(always)]
    pub fn energy_density(&self, g: &Matrix2<T>) -> T {
        let (g00, g11, g01) = (g[(0, 0)], g[(1, 1)], g[(0, 1)]);
        let half = T::splat(0.5);
        half * self.k_uu * g00 * g00
            + self.k_uv * g00 * g11
            + half * self.k_vv * g11 * g11
            + half * self.k_shear * g01 * g01
    }

    /// Second Piola–Kirchhoff stress `S = ∂ψ/∂G` (N/m), symmetric 2 × 2.
    #[inline(always)]
    pub fn stress(&self, g: &Matrix2<T>) -> Matrix2<T> {
        let (g00, g11, g01) = (g[(0, 0)], g[(1, 1)], g[(0, 1)]);
        let s00 = self.k_uu * g00 + self.k_uv * g11;
        let s11 = self.k_uv * g00 + self.k_vv * g11;
        // ∂ψ/∂G01 = k_shear G01 is shared by the two symmetric entries.
        let s01 = T::splat(0.5) * self.k_shear * g01;
        Matrix2::new(s00, s01, s01, s11)
    }
}

impl StrainStiffness {
    /// Four triangles' stiffnesses side by side.
    #[inline(always)]
    pub(crate) fn lanes(k: [&Self; 4]) -> StrainStiffness<F64x4> {
        StrainStiffness {
            k_uu: F64x4(k.map(|k| k.k_uu)),
            k_uv: F64x4(k.map(|k| k.k_uv)),
            k_vv: F64x4(k.map(|k| k.k_vv)),
            k_shear: F64x4(k.map(|k| k.k_shear)),
        }
    }
}

/// ARCSim's stretching table: row 0 = small-strain `(k0, k1, k2, k3)`, rows 1–5 = at principal
/// stretch `1 + 1/6` along 0°, 22.5°, 45°, 67.5°, 90° from the u axis. Raw file values (ARCSim
/// doubles them and clamps negatives when sampling).
#[derive(Clone, Debug, PartialEq)]
pub struct StretchingTable {
    /// The six rows `(k0, k1, k2, k3)`.
    pub rows: [[f64; 4]; 6],
}

/// ARCSim's bending table: `ke` (N·m) by edge direction (rows 0°, 45°, 90° from the u axis) and
/// curvature (columns 0, 5, 10, 15, 20 m⁻¹).
#[derive(Clone, Debug, PartialEq)]
pub struct BendingTable {
    /// `ke[direction][curvature]`, N·m.
    pub ke: [[f64; 5]; 3],
}

/// ARCSim's tabulated membrane with its precomputed 30³ stiffness grid.
#[derive(Clone, Debug)]
pub struct TabulatedMembrane {
    table: StretchingTable,
    /// `samples[(i · 30 + j) · 30 + k]` = `(k0, k1, k2, k3)` at `G00 = −0.25 + i/30`,
    /// `G11 = −0.25 + j/30`, `G01 = k/30`.
    samples: Vec<[f64; 4]>,
}

impl TabulatedMembrane {
    /// Build the grid from a table (all values must be finite).
    pub fn new(table: StretchingTable) -> Result<Self> {
        if let Some((r, row)) = table
            .rows
            .iter()
            .enumerate()
            .find(|(_, row)| !row.iter().all(|v| v.is_finite()))
        {
            return Err(Error::invalid(
                "stretching table",
                format!("row {r} has a non-finite value: {row:?}"),
            ));
        }
        let n = STRAIN_GRID_SAMPLES;
        let mut samples = Vec::with_capacity(n * n * n);
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let g00 = -0.25 + i as f64 / n as f64;
                    let g11 = -0.25 + j as f64 / n as f64;
                    let g01 = k as f64 / n as f64;
                    let g = Matrix2::new(g00, g01, g01, g11);
                    samples.push(evaluate_stretching_sample(&g, &table));
                }
            }
        }
        Ok(Self { table, samples })
    }

    /// The raw table.
    pub fn table(&self) -> &StretchingTable {
        &self.table
    }

    /// ARCSim's `stretching_stiffness(G)`: `(k0, k1, k2, k3)` by trilinear interpolation of the
    /// sample grid (see the module docs).
    #[inline(always)]
    pub fn arcsim_stiffness(&self, g: &Matrix2<f64>) -> [f64; 4] {
        let n = STRAIN_GRID_SAMPLES;
        let top = n as f64 - 1.0 - 1e-5;
        let coord = |x: f64| -> (usize, f64) {
            let x = x.clamp(0.0, top);
            // x ∈ [0, 29): its floor, the cast's truncation (a call to libm's `floor` on
            // x86-64's baseline), is an index in [0, 28].
            let i = (x as usize).min(n - 2);
            (i, x - i as f64)
        };
        let (ai, a) = coord((g[(0, 0)] + 0.25) * n as f64);
        let (bi, b) = coord((g[(1, 1)] + 0.25) * n as f64);
        let (ci, c) = coord(g[(0, 1)].abs() * n as f64);
        let mut k = [0.0; 4];
        for (di, wa) in [(0, 1.0 - a), (1, a)] {
            for (dj, wb) in [(0, 1.0 - b), (1, b)] {
                for (dk, wc) in [(0, 1.0 - c), (1, c)] {
                    let w = wa * wb * wc;
                    let s = &self.samples[((ai + di) * n + bi + dj) * n + ci + dk];
                    for l in 0..4 {
                        k[l] += s[l] * w;
                    }
                }
            }
        }
        k
    }
}

/// ARCSim's `evaluate_stretching_sample` (one grid sample; see the module docs).
fn evaluate_stretching_sample(g: &Matrix2<f64>, table: &StretchingTable) -> [f64; 4] {
    // C = 2G + I; ARCSim's closed-form eigen decomposition of a symmetric 2 × 2.
    let c = g * 2.0 + Matrix2::identity();
    let (a, b, d) = (c[(0, 0)], c[(1, 0)], c[(1, 1)]);
    let det = (4.0 * b * b + (a - d) * (a - d)).sqrt();
    let l1 = 0.5 * (a + d + det);
    let v = if b != 0.0 {
        let (v0, v1) = (l1 - d, b);
        let norm = (v0 * v0 + v1 * v1).sqrt();
        (v0 / norm, v1 / norm)
    } else if a >= d {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let stretch = l1.sqrt();
    let angle = ((v.1.atan2(v.0) / std::f64::consts::PI).abs() * 8.0).clamp(0.0, 4.0 - 1e-6);
    let angle_id = angle.floor() as usize;
    let angle_w = angle - angle_id as f64;
    let strain_w = ((stretch - 1.0) * 6.0).clamp(0.0, 1.0 - 1e-6);
    let small = &table.rows[0];
    let (lo, hi) = (&table.rows[angle_id + 1], &table.rows[angle_id + 2]);
    let mut k = [0.0; 4];
    for l in 0..4 {
        let large = lo[l] * (1.0 - angle_w) + hi[l] * angle_w;
        let value = small[l] * (1.0 - strain_w) + large * strain_w;
        k[l] = value.max(0.0) * 2.0;
    }
    k
}

/// A plain Saint Venant–Kirchhoff membrane, `ψ = μ G:G + λ/2 tr(G)²` (Lamé parameters of the
/// sheet, N/m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StvkMembrane {
    /// First Lamé parameter λ, N/m.
    pub lambda_n_per_m: f64,
    /// Shear modulus μ, N/m.
    pub mu_n_per_m: f64,
}

/// The in-plane (membrane) model of a material.
#[derive(Clone, Debug)]
pub enum MembraneModel {
    /// ARCSim's tabulated orthotropic model.
    Tabulated(Box<TabulatedMembrane>),
    /// Saint Venant–Kirchhoff.
    Stvk(StvkMembrane),
}

impl MembraneModel {
    /// The quadratic-form stiffness at Green strain `g` (the tabulated model looks it up; StVK
    /// is constant).
    #[inline(always)]
    pub fn stiffness(&self, g: &Matrix2<f64>) -> StrainStiffness {
        match self {
            Self::Tabulated(t) => {
                let [k0, k1, k2, k3] = t.arcsim_stiffness(g);
                StrainStiffness {
                    k_uu: k0,
                    k_uv: k1,
                    k_vv: k2,
                    k_shear: 2.0 * k3,
                }
            }
            Self::Stvk(s) => StrainStiffness {
                k_uu: 2.0 * s.mu_n_per_m + s.lambda_n_per_m,
                k_uv: s.lambda_n_per_m,
                k_vv: 2.0 * s.mu_n_per_m + s.lambda_n_per_m,
                k_shear: 4.0 * s.mu_n_per_m,
            },
        }
    }

    /// [`Self::stiffness`] lane by lane (each lane's strain looked up alone).
    #[inline(always)]
    pub(crate) fn stiffness_lanes<T: Real>(&self, g: &Matrix2<T>) -> StrainStiffness<T> {
        let mut k = [StrainStiffness::default(); 4];
        for (l, k) in k.iter_mut().enumerate().take(T::LANES) {
            *k = self.stiffness(&g.map(|v| v.lane(l)));
        }
        StrainStiffness {
            k_uu: T::from_fn(|l| k[l].k_uu),
            k_uv: T::from_fn(|l| k[l].k_uv),
            k_vv: T::from_fn(|l| k[l].k_vv),
            k_shear: T::from_fn(|l| k[l].k_shear),
        }
    }
}

/// The bending model of a material.
#[derive(Clone, Debug, PartialEq)]
pub enum BendingModel {
    /// ARCSim's tabulated model.
    Tabulated(BendingTable),
    /// A constant `ke`, N·m.
    Constant {
        /// Bending stiffness, N·m.
        ke_n_m: f64,
    },
}

impl BendingModel {
    /// `ke` (N·m) for one side of a hinge: ARCSim's `bending_stiffness` (see the module docs).
    ///
    /// `theta_rad` is the signed dihedral angle, `edge_length_m` the current edge length,
    /// `area_sum_m2` the sum of the rest areas of the two faces and `edge_angle_rad` the edge's
    /// direction in this face's material frame (`atan2(v, u)`).
    #[inline(always)]
    pub fn stiffness(
        &self,
        theta_rad: f64,
        edge_length_m: f64,
        area_sum_m2: f64,
        edge_angle_rad: f64,
    ) -> f64 {
        match self {
            Self::Constant { ke_n_m } => *ke_n_m,
            Self::Tabulated(table) => {
                let curv = theta_rad * edge_length_m / area_sum_m2;
                let mut value = (curv / 2.0 * 0.2).min(4.0);
                // C's `(int)` truncates toward zero, as the cast does; then the index is clamped
                // to [0, 3].
                let value_i = (value as i64).clamp(0, 3);
                value -= value_i as f64;
                let mut bias = (edge_angle_rad * 4.0 / std::f64::consts::PI).abs();
                if bias > 4.0 {
                    bias = 8.0 - bias;
                }
                if bias > 2.0 {
                    bias = 4.0 - bias;
                }
                let bias_id = (bias as i64).clamp(0, 1);
                bias -= bias_id as f64;
                let (b, v) = (bias_id as usize, value_i as usize);
                let d = &table.ke;
                let ke = d[b][v] * (1.0 - bias) * (1.0 - value)
                    + d[b + 1][v] * bias * (1.0 - value)
                    + d[b][v + 1] * (1.0 - bias) * value
                    + d[b + 1][v + 1] * bias * value;
                ke.max(0.0)
            }
        }
    }
}

/// A validated cloth material.
#[derive(Clone, Debug)]
pub struct Material {
    name: String,
    density_kg_per_m2: f64,
    membrane: MembraneModel,
    bending: BendingModel,
}

/// The gray-interlock knit (60 % cotton, 40 % polyester) of ARCSim's `materials/gray-interlock.json`,
/// the T-shirt material of the paper.
pub const GRAY_INTERLOCK_STRETCHING: [[f64; 4]; 6] = [
    [16.593832, -14.695990, 34.477123, 36.860302],
    [46.364765, 53.694656, 261.013855, -29.691301],
    [49.285110, 87.596100, 206.373993, 22.768457],
    [123.989220, 105.181770, 365.966217, 44.217571],
    [139.686325, 73.592560, 413.553162, -174.43853],
    [127.443810, 85.848587, 405.872833, 32.238411],
];

/// Bending table of gray-interlock (N·m), rows 0°/45°/90°, columns 0, 5, 10, 15, 20 m⁻¹.
pub const GRAY_INTERLOCK_BENDING: [[f64; 5]; 3] = [
    [
        23.191698e-6,
        32.932217e-6,
        34.406498e-6,
        39.014420e-6,
        23.382786e-6,
    ],
    [
        24.749964e-6,
        18.651314e-6,
        16.370552e-6,
        25.095791e-6,
        8.860165e-6,
    ],
    [
        14.267624e-6,
        7.052906e-6,
        14.515154e-6,
        24.665127e-6,
        19.383726e-6,
    ],
];

/// Area density of gray-interlock, kg/m².
pub const GRAY_INTERLOCK_DENSITY_KG_PER_M2: f64 = 0.187;

impl Material {
    /// Build a material, checking that the density is finite and positive, StVK parameters are
    /// finite with `μ > 0` and `λ ≥ 0`, and bending stiffnesses are finite and non-negative.
    pub fn new(
        name: impl Into<String>,
        density_kg_per_m2: f64,
        membrane: MembraneModel,
        bending: BendingModel,
    ) -> Result<Self> {
        if !(density_kg_per_m2.is_finite() && density_kg_per_m2 > 0.0) {
            return Err(Error::invalid(
                "material",
                format!("density must be finite and positive, got {density_kg_per_m2}"),
            ));
        }
        if let MembraneModel::Stvk(s) = &membrane
            && !(s.mu_n_per_m.is_finite()
                && s.mu_n_per_m > 0.0
                && s.lambda_n_per_m.is_finite()
                && s.lambda_n_per_m >= 0.0)
        {
            return Err(Error::invalid(
                "material",
                format!(
                    "StVK needs finite μ > 0 and λ ≥ 0, got μ = {}, λ = {}",
                    s.mu_n_per_m, s.lambda_n_per_m
                ),
            ));
        }
        match &bending {
            BendingModel::Constant { ke_n_m } if !(ke_n_m.is_finite() && *ke_n_m >= 0.0) => {
                return Err(Error::invalid(
                    "material",
                    format!("bending stiffness must be finite and ≥ 0, got {ke_n_m}"),
                ));
            }
            BendingModel::Tabulated(t)
                if !t.ke.iter().flatten().all(|v| v.is_finite() && *v >= 0.0) =>
            {
                return Err(Error::invalid(
                    "material",
                    "bending table values must be finite and ≥ 0",
                ));
            }
            _ => {}
        }
        Ok(Self {
            name: name.into(),
            density_kg_per_m2,
            membrane,
            bending,
        })
    }

    /// ARCSim's gray-interlock (the paper's T-shirt material), the default material.
    pub fn gray_interlock() -> Self {
        let membrane = TabulatedMembrane::new(StretchingTable {
            rows: GRAY_INTERLOCK_STRETCHING,
        })
        .expect("the built-in table is finite");
        Self {
            name: "gray-interlock".into(),
            density_kg_per_m2: GRAY_INTERLOCK_DENSITY_KG_PER_M2,
            membrane: MembraneModel::Tabulated(Box::new(membrane)),
            bending: BendingModel::Tabulated(BendingTable {
                ke: GRAY_INTERLOCK_BENDING,
            }),
        }
    }

    /// A StVK membrane with constant bending (tests and simple scenes).
    pub fn stvk(
        density_kg_per_m2: f64,
        lambda_n_per_m: f64,
        mu_n_per_m: f64,
        bending_ke_n_m: f64,
    ) -> Result<Self> {
        Self::new(
            "stvk",
            density_kg_per_m2,
            MembraneModel::Stvk(StvkMembrane {
                lambda_n_per_m,
                mu_n_per_m,
            }),
            BendingModel::Constant {
                ke_n_m: bending_ke_n_m,
            },
        )
    }

    /// The material's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Area density, kg/m².
    pub fn density_kg_per_m2(&self) -> f64 {
        self.density_kg_per_m2
    }

    /// The membrane model.
    pub fn membrane(&self) -> &MembraneModel {
        &self.membrane
    }

    /// The bending model.
    pub fn bending(&self) -> &BendingModel {
        &self.bending
    }

    /// Read a material file (see [`MaterialFile`]); errors name the file.
    pub fn from_json_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json_str(&text, path)
    }

    /// Parse a material from JSON text; `path` is only used to name the source in errors.
    pub fn from_json_str(text: &str, path: &Path) -> Result<Self> {
        let file: MaterialFile = serde_json::from_str(text)
            .map_err(|e| Error::format(path, format!("line {}: {e}", e.line())))?;
        let default_name = path.file_stem().map_or_else(
            || "material".to_string(),
            |s| s.to_string_lossy().into_owned(),
        );
        file.into_material(default_name).map_err(|e| match e {
            Error::Invalid { what, message } => {
                Error::format(path, format!("invalid {what}: {message}"))
            }
            other => other,
        })
    }

    /// The material as a file (for saving the material actually used next to outputs).
    pub fn to_file(&self) -> MaterialFile {
        let (stretching, stvk) = match &self.membrane {
            MembraneModel::Tabulated(t) => (Some(t.table.rows.to_vec()), None),
            MembraneModel::Stvk(s) => (None, Some(*s)),
        };
        let (bending, bending_stiffness) = match &self.bending {
            BendingModel::Tabulated(t) => (Some(t.ke.iter().map(|r| r.to_vec()).collect()), None),
            BendingModel::Constant { ke_n_m } => (None, Some(*ke_n_m)),
        };
        MaterialFile {
            name: Some(self.name.clone()),
            density: self.density_kg_per_m2,
            stretching,
            bending,
            stvk,
            bending_stiffness,
        }
    }
}

/// A material file: ARCSim's format (`density` in kg/m², `stretching` 6 × 4, `bending` 3 × 5 in
/// N·m) so ARCSim's `materials/*.json` load unchanged, extended with `name`, `stvk`
/// (`{"lambda_n_per_m", "mu_n_per_m"}`, instead of `stretching`) and `bending_stiffness`
/// (constant `ke` in N·m, instead of `bending`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialFile {
    /// Optional name (defaults to the file stem).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Area density, kg/m².
    pub density: f64,
    /// ARCSim stretching table (6 rows of 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stretching: Option<Vec<[f64; 4]>>,
    /// ARCSim bending table (3 rows of 5), N·m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bending: Option<Vec<Vec<f64>>>,
    /// StVK membrane instead of `stretching`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stvk: Option<StvkMembrane>,
    /// Constant bending stiffness instead of `bending`, N·m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bending_stiffness: Option<f64>,
}

impl MaterialFile {
    /// Validate and build the material.
    pub fn into_material(self, default_name: String) -> Result<Material> {
        let invalid = |m: String| Error::invalid("material file", m);
        let membrane = match (self.stretching, self.stvk) {
            (Some(rows), None) => {
                if rows.len() != 6 {
                    return Err(invalid(format!(
                        "\"stretching\" needs 6 rows of 4 values, got {} rows",
                        rows.len()
                    )));
                }
                let mut table = [[0.0; 4]; 6];
                table.copy_from_slice(&rows);
                MembraneModel::Tabulated(Box::new(TabulatedMembrane::new(StretchingTable {
                    rows: table,
                })?))
            }
            (None, Some(stvk)) => MembraneModel::Stvk(stvk),
            (Some(_), Some(_)) => {
                return Err(invalid(
                    "give either \"stretching\" or \"stvk\", not both".into(),
                ));
            }
            (None, None) => {
                return Err(invalid("missing \"stretching\" (or \"stvk\")".into()));
            }
        };
        let bending = match (self.bending, self.bending_stiffness) {
            (Some(rows), None) => {
                if rows.len() != 3 || rows.iter().any(|r| r.len() != 5) {
                    return Err(invalid(format!(
                        "\"bending\" needs 3 rows of 5 values, got {:?}",
                        rows.iter().map(Vec::len).collect::<Vec<_>>()
                    )));
                }
                let mut ke = [[0.0; 5]; 3];
                for (dst, src) in ke.iter_mut().zip(&rows) {
                    dst.copy_from_slice(src);
                }
                BendingModel::Tabulated(BendingTable { ke })
            }
            (None, Some(ke_n_m)) => BendingModel::Constant { ke_n_m },
            (Some(_), Some(_)) => {
                return Err(invalid(
                    "give either \"bending\" or \"bending_stiffness\", not both".into(),
                ));
            }
            (None, None) => {
                return Err(invalid(
                    "missing \"bending\" (or \"bending_stiffness\")".into(),
                ));
            }
        };
        Material::new(
            self.name.unwrap_or(default_name),
            self.density,
            membrane,
            bending,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_strain_stiffness_is_doubled_and_clamped() {
        let m = Material::gray_interlock();
        let MembraneModel::Tabulated(t) = m.membrane() else {
            panic!("gray-interlock is tabulated")
        };
        // Small strain: ARCSim's row 0, doubled, negatives clamped.
        let k = evaluate_stretching_sample(&Matrix2::zeros(), t.table());
        let row0 = GRAY_INTERLOCK_STRETCHING[0];
        assert_eq!(k, [2.0 * row0[0], 0.0, 2.0 * row0[2], 2.0 * row0[3]]);
        // The run-time lookup at a grid node (G00 = G11 = −0.25 + 7/30, G01 = 0: compressed, so
        // pure row 0) returns that sample exactly.
        let g = -0.25 + 7.0 / 30.0;
        let kl = t.arcsim_stiffness(&Matrix2::new(g, 0.0, 0.0, g));
        for l in 0..4 {
            assert!((kl[l] - k[l]).abs() < 1e-9, "{kl:?} vs {k:?}");
        }
    }

    #[test]
    fn large_strain_rows_by_direction() {
        let table = StretchingTable {
            rows: GRAY_INTERLOCK_STRETCHING,
        };
        // Principal stretch 1 + 1/6 along u (G00 = ½((7/6)² − 1)), nothing else: row 1, doubled.
        let g00 = 0.5 * ((7.0f64 / 6.0).powi(2) - 1.0) + 1e-9;
        let k = evaluate_stretching_sample(&Matrix2::new(g00, 0.0, 0.0, 0.0), &table);
        let r = GRAY_INTERLOCK_STRETCHING[1];
        let expect = r.map(|v| (2.0 * v).max(0.0));
        for l in 0..4 {
            // The strain weight is clamped to 1 − 1e-6, so row 0 still weighs 1e-6.
            assert!(
                (k[l] - expect[l]).abs() < 1e-5 * expect[l].abs().max(1.0),
                "{k:?} vs {expect:?}"
            );
        }
        // The same stretch along v: row 5.
        let k = evaluate_stretching_sample(&Matrix2::new(0.0, 0.0, 0.0, g00), &table);
        let r = GRAY_INTERLOCK_STRETCHING[5];
        for l in 0..4 {
            assert!((k[l] - (2.0 * r[l]).max(0.0)).abs() < 1e-3 * r[l].abs().max(1.0));
        }
    }

    #[test]
    fn bending_lookup_matches_table_nodes() {
        let m = BendingModel::Tabulated(BendingTable {
            ke: GRAY_INTERLOCK_BENDING,
        });
        // curv/2 = 10 m⁻¹ → column 2; direction 45° → row 1. curv = θ l / a.
        let (l, a) = (0.01, 1e-4);
        let theta = 20.0 * a / l;
        let ke = m.stiffness(theta, l, a, std::f64::consts::FRAC_PI_4);
        assert!((ke - GRAY_INTERLOCK_BENDING[1][2]).abs() < 1e-12);
        // Along v (90° and −90°) at zero curvature: row 2, column 0.
        for angle in [std::f64::consts::FRAC_PI_2, -std::f64::consts::FRAC_PI_2] {
            let ke = m.stiffness(0.0, l, a, angle);
            assert!((ke - GRAY_INTERLOCK_BENDING[2][0]).abs() < 1e-12);
        }
        // Beyond the last column: clamped to column 4.
        let ke = m.stiffness(100.0, l, a, 0.0);
        assert!((ke - GRAY_INTERLOCK_BENDING[0][4]).abs() < 1e-12);
        // Negative curvature extrapolates the first segment (ARCSim quirk), clamped at 0.
        let theta = -10.0 * a / l; // curv/2 = −5 → value = −1
        let ke = m.stiffness(theta, l, a, 0.0);
        let expect = 2.0 * GRAY_INTERLOCK_BENDING[0][0] - GRAY_INTERLOCK_BENDING[0][1];
        assert!((ke - expect).abs() < 1e-12);
    }

    #[test]
    fn material_file_round_trip_and_errors() {
        let m = Material::gray_interlock();
        let text = serde_json::to_string_pretty(&m.to_file()).expect("serialises");
        let back = Material::from_json_str(&text, Path::new("gi.json")).expect("parses");
        assert_eq!(back.name(), "gray-interlock");
        assert_eq!(back.to_file(), m.to_file());

        let arcsim = r#"{"density": 0.2, "stretching": [[1,2,3,4],[1,2,3,4],[1,2,3,4],[1,2,3,4],[1,2,3,4],[1,2,3,4]],
            "bending": [[1,2,3,4,5],[1,2,3,4,5],[1,2,3,4,5]]}"#;
        let m = Material::from_json_str(arcsim, Path::new("dir/knit.json")).expect("ARCSim format");
        assert_eq!(m.name(), "knit");

        let bad = r#"{"density": -1, "stvk": {"lambda_n_per_m": 1, "mu_n_per_m": 2}, "bending_stiffness": 1e-6}"#;
        let err = Material::from_json_str(bad, Path::new("bad.json"))
            .expect_err("must fail")
            .to_string();
        assert!(err.contains("bad.json") && err.contains("density"), "{err}");
        let short = r#"{"density": 0.1, "stretching": [[1,2,3,4]], "bending_stiffness": 1e-6}"#;
        let err = Material::from_json_str(short, Path::new("short.json"))
            .expect_err("must fail")
            .to_string();
        assert!(
            err.contains("short.json") && err.contains("6 rows"),
            "{err}"
        );
        let err = Material::from_json_str("{\"density\": 0.1,", Path::new("trunc.json"))
            .expect_err("must fail")
            .to_string();
        assert!(err.contains("trunc.json"), "{err}");
    }
}
