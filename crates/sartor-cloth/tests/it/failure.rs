//! Failure detection (the step reports an error and leaves the state untouched instead of
//! producing NaNs) and clear errors for meshes that cannot be a cloth.

use nalgebra::Vector3;
use sartor_cloth::{Cloth, Error, LinearSolver, Material, SimConfig, StepFailure};

use crate::common::{horizontal_sheet, simulator, stvk};

fn assert_unchanged(before: &[Vector3<f64>], after: &[Vector3<f64>]) {
    assert_eq!(before, after, "a failed step must not change the state");
}

#[test]
fn absurd_time_step_is_an_energy_blow_up() {
    let mut sim = simulator(horizontal_sheet(0.2, 4, 0.0, stvk()), SimConfig::default());
    let before = sim.positions().to_vec();
    let err = sim.step(1e3, &[]).expect_err("must fail");
    assert!(
        matches!(err.step_failure(), Some(StepFailure::EnergyBlowUp { .. })),
        "{err}"
    );
    assert_unchanged(&before, sim.positions());
    // The state is still usable: a sane step succeeds.
    sim.step(1.0 / 300.0, &[])
        .expect("a normal step works after a failure");
    assert!(sim.step(f64::NAN, &[]).is_err());
}

#[test]
fn absurd_stiffness_is_reported_not_propagated() {
    let huge = Material::stvk(0.2, 0.0, f64::MAX / 4.0, 0.0).expect("finite parameters");
    let mut sim = simulator(horizontal_sheet(0.2, 4, 0.0, huge), SimConfig::default());
    // Compress one vertex so the membrane force overflows.
    let mut p = sim.positions().to_vec();
    p[12].x += 0.01;
    sim.set_positions(&p).expect("finite");
    let before = sim.positions().to_vec();
    let err = sim.step(1.0 / 300.0, &[]).expect_err("must fail");
    assert!(
        matches!(
            err.step_failure(),
            Some(StepFailure::NonFinite { .. } | StepFailure::Factorization { .. })
        ),
        "{err}"
    );
    assert_unchanged(&before, sim.positions());
    assert!(
        sim.positions()
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite()))
    );
}

#[test]
fn conjugate_gradient_cap_hands_the_solve_to_cholesky() {
    let run = |linear_solver| {
        let config = SimConfig {
            linear_solver,
            ..SimConfig::default()
        };
        let mut sim = simulator(
            horizontal_sheet(0.2, 6, 0.0, Material::gray_interlock()),
            config,
        );
        sim.pin(0, sim.positions()[0]).expect("valid pin");
        let stats = sim.step(1.0 / 300.0, &[]).expect("the fallback solves it");
        (stats, sim.positions().to_vec())
    };
    let (capped, x_capped) = run(LinearSolver::ConjugateGradient {
        max_iterations: 2,
        relative_tolerance: 1e-12,
        fallback_to_cholesky: true,
    });
    assert_eq!(capped.cholesky_fallbacks, 1);
    let (direct, x_direct) = run(LinearSolver::Cholesky);
    assert_eq!(direct.cholesky_fallbacks, 0);
    // The same system solved directly either way.
    assert_eq!(x_capped, x_direct);
    let (converged, _) = run(LinearSolver::ConjugateGradient {
        max_iterations: 1000,
        relative_tolerance: 1e-8,
        fallback_to_cholesky: true,
    });
    assert_eq!(converged.cholesky_fallbacks, 0);
    // Without the fallback the cap is a step failure, and the state is left as it was.
    let config = SimConfig {
        linear_solver: LinearSolver::ConjugateGradient {
            max_iterations: 2,
            relative_tolerance: 1e-12,
            fallback_to_cholesky: false,
        },
        ..SimConfig::default()
    };
    let mut sim = simulator(
        horizontal_sheet(0.2, 6, 0.0, Material::gray_interlock()),
        config,
    );
    sim.pin(0, sim.positions()[0]).expect("valid pin");
    let before = sim.positions().to_vec();
    let err = sim.step(1.0 / 300.0, &[]).expect_err("must fail");
    assert!(
        matches!(
            err.step_failure(),
            Some(StepFailure::SolverNotConverged { iterations: 2, .. })
        ),
        "{err}"
    );
    assert_unchanged(&before, sim.positions());
}

fn cloth_error(positions: Vec<Vector3<f64>>, faces: Vec<[u32; 3]>) -> String {
    match Cloth::from_parts(positions, faces, stvk(), None) {
        Ok(_) => panic!("accepted a bad cloth mesh"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_cloth_meshes_are_rejected_clearly() {
    let quad = vec![
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
    ];
    // Non-manifold: three triangles on edge (0, 1).
    let mut p = quad.clone();
    p.push(Vector3::new(0.5, -1.0, 0.0));
    p.push(Vector3::new(0.5, 0.0, 1.0));
    let err = cloth_error(p, vec![[0, 1, 2], [1, 0, 4], [0, 1, 5]]);
    assert!(err.contains("non-manifold"), "{err}");
    // Inconsistent orientation.
    let err = cloth_error(quad.clone(), vec![[0, 1, 2], [0, 2, 3], [0, 3, 2]]);
    assert!(
        err.contains("non-manifold") || err.contains("orientation"),
        "{err}"
    );
    // Zero-area triangle.
    let mut p = quad.clone();
    p[2] = Vector3::new(2.0, 0.0, 0.0);
    let err = cloth_error(p, vec![[0, 1, 2], [0, 1, 3]]);
    assert!(err.contains("zero area"), "{err}");
    // NaN.
    let mut p = quad.clone();
    p[3].y = f64::NAN;
    let err = cloth_error(p, vec![[0, 1, 2], [0, 2, 3]]);
    assert!(err.contains("non-finite"), "{err}");
    // Disconnected parts.
    let mut p = quad.clone();
    p.extend([
        Vector3::new(5.0, 0.0, 0.0),
        Vector3::new(6.0, 0.0, 0.0),
        Vector3::new(5.0, 1.0, 0.0),
    ]);
    let err = cloth_error(p, vec![[0, 1, 2], [0, 2, 3], [4, 5, 6]]);
    assert!(err.contains("disconnected"), "{err}");
    // A vertex in no triangle.
    let err = cloth_error(quad.clone(), vec![[0, 1, 2]]);
    assert!(err.contains("vertex 3"), "{err}");
    // Material frames: wrong count, or normal to the triangle.
    let mesh = sartor_core::TriMesh::new(quad.clone(), vec![[0, 1, 2], [0, 2, 3]]).expect("valid");
    let err = Cloth::new(mesh.clone(), stvk(), Some(&[Vector3::x()])).expect_err("must fail");
    assert!(matches!(err, Error::Invalid { .. }), "{err}");
    let err = Cloth::new(mesh, stvk(), Some(&[Vector3::z(), Vector3::x()])).expect_err("must fail");
    assert!(err.to_string().contains("normal"), "{err}");
}
