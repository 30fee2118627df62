//! Uniaxial stretch of a gray-interlock sheet reproduces the table's stress–strain curve along
//! the warp (u), the weft (v) and at 45°.
//!
//! The boundary of a 10 cm sheet is pinned to the affine uniaxial-strain deformation
//! `x = (λ X, Y)`; the interior starts perturbed and is relaxed by large implicit steps
//! (gravity off). The force needed to hold the right edge must equal the analytic
//! `λ (R S Rᵀ)_xx · H`, with `S` the second Piola–Kirchhoff stress of the table-evaluated
//! stiffness at the analytic Green strain, `R` the material frame and `H` the edge's length:
//! within 2 %.

use nalgebra::{Matrix2, Vector3};
use rand::Rng;
use sartor_cloth::{Cloth, Material, SimConfig, rectangle_sheet};

use crate::common::{rng, simulator};

fn reaction_and_analytic(stretch: f64, angle_rad: f64, seed: u64) -> (f64, f64) {
    let (width, n) = (0.1, 6);
    let mesh = rectangle_sheet(
        Vector3::zeros(),
        Vector3::new(width, 0.0, 0.0),
        Vector3::new(0.0, width, 0.0),
        n,
        n,
    )
    .expect("valid");
    let u = Vector3::new(angle_rad.cos(), angle_rad.sin(), 0.0);
    let axes = vec![u; mesh.n_faces()];
    let material = Material::gray_interlock();
    let cloth = Cloth::new(mesh, material.clone(), Some(&axes)).expect("valid");
    let config = SimConfig {
        gravity_m_per_s2: Vector3::zeros(),
        newton_iterations: 10,
        newton_tolerance_m_per_s: 1e-12,
        self_collision: false,
        ..SimConfig::default()
    };
    let mut sim = simulator(cloth, config);
    let mut r = rng(seed);
    let rest = sim.positions().to_vec();
    let mut start = Vec::with_capacity(rest.len());
    for (i, p) in rest.iter().enumerate() {
        let target = Vector3::new(stretch * p.x, p.y, 0.0);
        let boundary = p.x.abs() < 1e-9
            || (p.x - width).abs() < 1e-9
            || p.y.abs() < 1e-9
            || (p.y - width).abs() < 1e-9;
        if boundary {
            sim.pin(i, target).expect("valid pin");
            start.push(target);
        } else {
            start.push(
                target
                    + Vector3::new(
                        r.random_range(-1e-3..1e-3),
                        r.random_range(-1e-3..1e-3),
                        r.random_range(-1e-3..1e-3),
                    ),
            );
        }
    }
    sim.set_positions(&start).expect("finite");
    // Each step converges Newton for the stiffness frozen at its start; the stiffness itself
    // converges to its equilibrium value linearly from step to step (ARCSim's scheme), hence
    // the number of steps.
    for _ in 0..60 {
        sim.step(0.05, &[]).expect("stable");
        sim.set_velocities(&vec![Vector3::zeros(); rest.len()])
            .expect("finite");
    }
    let forces = sim.elastic_forces();
    let reaction: f64 = rest
        .iter()
        .zip(&forces)
        .filter(|(p, _)| (p.x - width).abs() < 1e-9)
        .map(|(_, f)| -f.x)
        .sum();
    // Analytic: F = diag(λ, 1) in the world, material frame R = [u v].
    let rot = Matrix2::new(
        angle_rad.cos(),
        -angle_rad.sin(),
        angle_rad.sin(),
        angle_rad.cos(),
    );
    let f_world = Matrix2::new(stretch, 0.0, 0.0, 1.0);
    let f_material = f_world * rot;
    let g = (f_material.transpose() * f_material - Matrix2::identity()) * 0.5;
    let s = material.membrane().stiffness(&g).stress(&g);
    let analytic = stretch * (rot * s * rot.transpose())[(0, 0)] * width;
    (reaction, analytic)
}

#[test]
fn gray_interlock_uniaxial_stress_strain() {
    for (angle_deg, name) in [(0.0, "warp"), (90.0, "weft"), (45.0, "45°")] {
        for (k, stretch) in [1.02, 1.05, 1.10, 1.15].into_iter().enumerate() {
            let (reaction, analytic) =
                reaction_and_analytic(stretch, f64::to_radians(angle_deg), k as u64);
            assert!(analytic > 0.0);
            let error = (reaction - analytic).abs() / analytic;
            eprintln!(
                "{name} λ = {stretch}: {reaction:.5} N vs {analytic:.5} N ({:.2e} relative)",
                error
            );
            assert!(
                error < 0.02,
                "{name} at stretch {stretch}: reaction {reaction:.5} N vs table {analytic:.5} N ({:.2} %)",
                error * 100.0
            );
        }
    }
}
