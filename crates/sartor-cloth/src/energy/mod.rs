//! Per-element energies with gradients and Hessians (3 × 3 blocks): membrane (triangle),
//! bending (hinge), obstacle and self-contact penalties, and gravity.
//!
//! Every element energy is exact for its frozen per-step parameters (material stiffness,
//! bending coefficient, contact normal and side); the finite-difference tests check gradients
//! and Hessians against those energies. The Hessians the solver uses are PSD projections,
//! documented per element.

mod bending;
mod contact;
pub(crate) mod diff;
mod lanes;
mod membrane;
mod psd;

pub use bending::{
    BendingHessian, BendingRest, CRUSHED_AREA_FRACTION, GaussNewtonHinge, dihedral_angle,
};
pub use contact::{
    FrictionModel, ObstacleContact, Penalty, PenaltyProfile, SelfContact, friction_damping,
    friction_velocity_change,
};
pub use lanes::{F64x4, Real, gather_lanes};
pub use membrane::{ElementDerivatives, MembraneRest, Projection};
pub use psd::{project_psd, project_psd2};

/// Gravitational acceleration, m/s², along −Y.
pub const GRAVITY_M_PER_S2: f64 = 9.81;

/// Gravitational potential energy `m g y` of one vertex, J (zero at `y = 0`).
pub fn gravity_energy(mass_kg: f64, height_m: f64) -> f64 {
    mass_kg * GRAVITY_M_PER_S2 * height_m
}

/// Uniform numbers in [−½, ½) from a 64-bit LCG seeded by `seed`: the energies' tests draw
/// their random elements from it (the same elements on every run).
#[cfg(test)]
fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}
