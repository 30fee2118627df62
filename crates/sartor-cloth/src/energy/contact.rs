//! Contact: one-sided penalties against obstacles and between the cloth's own vertices and
//! triangles, and Coulomb friction.
//!
//! # Penalty
//!
//! A vertex closer than the thickness `h` to a surface (signed distance `d < h`) has the
//! violation `v = h − d > 0` and the energy `E = φ(v)`, scaled by the vertex's rest area `a`
//! (ARCSim scales by `min(area(node), area(face))`; against an obstacle that is the node):
//!
//! - [`PenaltyProfile::Cubic`] (ARCSim's `IneqCon`): `φ = k a v³ / (6h)` — force `k a v²/(2h)`,
//!   stiffness `k a v / h`, which grows smoothly from zero at `d = h` (C² energy, friendlier to
//!   Newton).
//! - [`PenaltyProfile::Quadratic`]: `φ = ½ k a v²` — force `k a v`, stiffness `k a` (a jump at
//!   `d = h`).
//!
//! Both reach the stiffness `k a` at full penetration (`d = 0`), so `k` (N/m³) means the same in
//! both; ARCSim's body scenes used `k = 1e6`.
//!
//! Obstacle contacts use the distance linearised at the query point, `d(x) = d0 + n·(x − x_q)`
//! (exact for a plane); its Hessian `φ'' n nᵀ` drops the obstacle's curvature term (which is
//! negative for convex obstacles), making it PSD. Self-contacts use the exact distance of the
//! vertex to its triangle's plane, `d = s · (p − t0)·n̂(t0, t1, t2)` with the side `s = ±1` frozen
//! when the pair is detected; its exact Hessian is projected to PSD like the bending one.
//!
//! # Friction
//!
//! Two models ([`FrictionModel`]), both Coulomb's law with the same budget per step, `μ f_n Δt`
//! (`f_n` the normal penalty force):
//!
//! - [`FrictionModel::Impulse`]: applied after the velocity solve, as a velocity-level impulse
//!   (Bridson et al. 2002): the tangential velocity relative to the obstacle is reduced by at
//!   most `μ f_n Δt / m`. The rest of the cloth does not see it within the step: a vertex the
//!   body drags stops or jerks alone, and with long steps its neighbours buckle (the CMU crouch
//!   crumpled the 4,210-triangle T-shirt at 14 substeps per frame, 7 % of hinges folded).
//! - [`FrictionModel::Implicit`]: ARCSim's linearised friction inside the solve, a tangential
//!   damper `f = −c T (v⁺ − v_obstacle)` (`T = I − n nᵀ`) with
//!   `c = min(μ f_n / |v_t|, m / Δt)` frozen at the start of the substep
//!   ([`friction_damping`]): the whole cloth answers it in the same solve, and the crouch
//!   stays smooth with steps twice as long. The price is ARCSim's: a damper cannot hold a
//!   vertex at rest, so under a tangential force `F_t` below the Coulomb limit the vertex
//!   creeps at `F_t Δt / m` (on a slope, `g sin α · Δt`: 5.7 mm/s at 10° with 3.3 ms steps).
//!   Adding back the impulse with what the damper left of the budget stopped the creep but
//!   brought back the crumpling (the crouch at 20 substeps: 1.7 % of hinges folded against
//!   0.4 %), as did a stiffer cap (`4 m / Δt`: 0.7 %, and more vertices through the fallback).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::diff::{Scalar9, expand_to_vertices};
use super::membrane::{ElementDerivatives, Projection};
use super::psd::project_psd;

/// Shape of the contact penalty (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PenaltyProfile {
    /// ARCSim's `k a v³ / (6h)`.
    #[default]
    Cubic,
    /// `½ k a v²`.
    Quadratic,
}

/// A contact penalty: stiffness, thickness and profile.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Penalty {
    /// `k`, N/m³ (multiplied by the vertex area, m², it is a spring stiffness in N/m).
    pub stiffness_n_per_m3: f64,
    /// Repulsion thickness `h`, m.
    pub thickness_m: f64,
    /// Profile of the energy in the violation.
    pub profile: PenaltyProfile,
}

impl Default for Penalty {
    /// ARCSim's body scenes: `k = 1e6`, `h = 5 mm`, cubic.
    fn default() -> Self {
        Self {
            stiffness_n_per_m3: 1e6,
            thickness_m: 5e-3,
            profile: PenaltyProfile::Cubic,
        }
    }
}

impl Penalty {
    /// Energy and its first and second derivatives with respect to the signed distance `d`
    /// for a vertex of area `area_m2`: `(E, dE/dd, d²E/dd²)`; all zero for `d ≥ h`.
    pub fn evaluate(&self, distance_m: f64, area_m2: f64) -> (f64, f64, f64) {
        let h = self.thickness_m;
        let v = h - distance_m;
        if v <= 0.0 {
            return (0.0, 0.0, 0.0);
        }
        let ka = self.stiffness_n_per_m3 * area_m2;
        match self.profile {
            PenaltyProfile::Cubic => (
                ka * v * v * v / (6.0 * h),
                -ka * v * v / (2.0 * h),
                ka * v / h,
            ),
            PenaltyProfile::Quadratic => (0.5 * ka * v * v, -ka * v, ka),
        }
    }
}

/// A vertex near an obstacle, with the distance linearised at the query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObstacleContact {
    /// The cloth vertex.
    pub vertex: u32,
    /// Index of the collider in the slice given to the simulator.
    pub collider: u32,
    /// Where the query was made, m.
    pub query_point: Vector3<f64>,
    /// Signed distance at the query point, m.
    pub distance_m: f64,
    /// Unit outward normal.
    pub normal: Vector3<f64>,
    /// Obstacle surface velocity, m/s.
    pub velocity_m_per_s: Vector3<f64>,
    /// The vertex's rest area, m².
    pub area_m2: f64,
}

impl ObstacleContact {
    /// The linearised signed distance at `x`.
    pub fn distance_at(&self, x: &Vector3<f64>) -> f64 {
        self.distance_m + self.normal.dot(&(x - self.query_point))
    }

    /// Energy, gradient and Hessian (`φ'' n nᵀ`) at vertex position `x`.
    pub fn derivatives(&self, x: &Vector3<f64>, penalty: &Penalty) -> ElementDerivatives<1> {
        let (e, de, dde) = penalty.evaluate(self.distance_at(x), self.area_m2);
        ElementDerivatives {
            energy_j: e,
            gradient: [self.normal * de],
            hessian: [[self.normal * self.normal.transpose() * dde]],
        }
    }
}

/// A cloth vertex near one of the cloth's triangles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SelfContact {
    /// The vertex.
    pub vertex: u32,
    /// The triangle's vertices (counter-clockwise).
    pub triangle: [u32; 3],
    /// +1 if the vertex was on the side of the triangle's normal when detected, −1 otherwise.
    pub side: f64,
    /// `min(vertex area, triangle rest area)`, m² (ARCSim's scaling).
    pub area_m2: f64,
}

/// Signed distance of `p` to the plane of `t` on the side `side`, with its exact derivatives in
/// `z = (p − t0, t1 − t0, t2 − t0)`. `None` for a degenerate triangle.
fn plane_distance(p: &Vector3<f64>, t: &[Vector3<f64>; 3], side: f64) -> Option<Scalar9> {
    let z = [p - t[0], t[1] - t[0], t[2] - t[0]];
    let uu = Scalar9::dot(&z, 1, 1);
    let ww = Scalar9::dot(&z, 2, 2);
    let uw = Scalar9::dot(&z, 1, 2);
    // |(t1 − t0) × (t2 − t0)|² by Lagrange's identity.
    let n2 = uu.mul(&ww).sub(&uw.mul(&uw));
    if n2.v.is_nan() || n2.v <= 1e-24 * (uu.v * ww.v).max(1e-300) {
        return None;
    }
    Some(Scalar9::triple(&z).mul(&n2.sqrt().recip()).scale(side))
}

impl SelfContact {
    /// Signed distance of the vertex to the triangle's plane on the contact's side, m.
    pub fn distance(&self, x: &[Vector3<f64>; 4]) -> f64 {
        let n = (x[2] - x[1]).cross(&(x[3] - x[1]));
        self.side * (x[0] - x[1]).dot(&n) / n.norm()
    }

    /// Energy, gradient and Hessian at `x = [p, t0, t1, t2]`.
    pub fn derivatives(
        &self,
        x: &[Vector3<f64>; 4],
        penalty: &Penalty,
        projection: Projection,
    ) -> ElementDerivatives<4> {
        let Some(d) = plane_distance(&x[0], &[x[1], x[2], x[3]], self.side) else {
            return ElementDerivatives::default();
        };
        let (e, de, dde) = penalty.evaluate(d.v, self.area_m2);
        if e == 0.0 && de == 0.0 {
            return ElementDerivatives::default();
        }
        let energy = d.chain(e, de, dde);
        let h = match projection {
            Projection::Exact => energy.h,
            Projection::Psd => project_psd(&energy.h),
        };
        let (gradient, hessian) = expand_to_vertices(&energy.g, &h, 1, [0, 2, 3]);
        ElementDerivatives {
            energy_j: e,
            gradient,
            hessian,
        }
    }
}

/// How cloth–obstacle friction enters a substep (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum FrictionModel {
    /// A Coulomb impulse after the solve.
    #[default]
    Impulse,
    /// ARCSim's linearised friction: a tangential damper in the solve.
    Implicit,
}

impl FrictionModel {
    /// Whether this is [`FrictionModel::Impulse`] (configs that leave it out keep their hash).
    pub fn is_impulse(&self) -> bool {
        *self == Self::Impulse
    }
}

/// The part of `v` along the surface of unit normal `normal`: `T v`, `T = I − n nᵀ`.
#[inline]
fn tangential(v: &Vector3<f64>, normal: &Vector3<f64>) -> Vector3<f64> {
    v - normal * normal.dot(v)
}

/// The tangential damping coefficient `c` (N·s/m) of [`FrictionModel::Implicit`] for a vertex
/// of mass `mass_kg` pressed with `normal_force_n` against a surface of unit normal `normal`,
/// moving at `relative_velocity` (vertex minus surface) at the start of a step of `h_s`
/// seconds: `min(μ f_n / |v_t|, m / h)` (ARCSim's `f_by_v`), 0 without a normal force.
pub fn friction_damping(
    relative_velocity: &Vector3<f64>,
    normal: &Vector3<f64>,
    mu: f64,
    normal_force_n: f64,
    mass_kg: f64,
    h_s: f64,
) -> f64 {
    if !(normal_force_n > 0.0 && mu > 0.0) {
        return 0.0;
    }
    let vt = tangential(relative_velocity, normal);
    let cap = mass_kg / h_s;
    let speed = vt.norm();
    if speed * cap <= mu * normal_force_n {
        cap
    } else {
        mu * normal_force_n / speed
    }
}

/// Coulomb friction impulse as a velocity change: the tangential part of `relative_velocity`
/// (vertex minus surface) is reduced by at most `mu · normal_impulse / mass` (`normal_impulse`
/// in N·s). Returns the velocity change to add to the vertex.
pub fn friction_velocity_change(
    relative_velocity: &Vector3<f64>,
    normal: &Vector3<f64>,
    mu: f64,
    normal_impulse_n_s: f64,
    mass_kg: f64,
) -> Vector3<f64> {
    let vt = tangential(relative_velocity, normal);
    let speed = vt.norm();
    if speed == 0.0 || normal_impulse_n_s <= 0.0 || mu <= 0.0 {
        return Vector3::zeros();
    }
    let reduction = (mu * normal_impulse_n_s / mass_kg).min(speed);
    -vt * (reduction / speed)
}
