//! Free fall, energy behaviour, coming to rest, Newton iterations, the two linear solvers and
//! determinism.

use nalgebra::Vector3;
use sartor_cloth::{Cloth, LinearSolver, Material, Parallelism, SimConfig, Simulator};

use crate::common::{horizontal_sheet, simulator, stvk};

const G: f64 = 9.81;

#[test]
fn free_fall_matches_implicit_euler() {
    // Backward Euler on a rigidly falling sheet: v_n = −g n h, y_n = y0 − g h² n (n + 1) / 2,
    // i.e. exactly g t² / 2 + g h t / 2 below the start. We test
    // |y − (y0 − g t²/2)| = g h t / 2 to 1e-9 relative (and x, z unchanged).
    for material in [Material::gray_interlock(), stvk()] {
        let cloth = horizontal_sheet(0.2, 6, 1.0, material);
        let mut sim = simulator(cloth, SimConfig::default());
        let start = sim.positions().to_vec();
        let h = 1.0 / 300.0;
        let steps = 90;
        for _ in 0..steps {
            sim.step(h, &[]).expect("stable");
        }
        let t = h * steps as f64;
        let bound = G * h * t / 2.0;
        for (p, p0) in sim.positions().iter().zip(&start) {
            let error = (p.y - (p0.y - 0.5 * G * t * t)).abs();
            assert!(
                (error - bound).abs() <= 1e-9 * bound,
                "error {error:.6e} vs implicit Euler's {bound:.6e}"
            );
            assert!((p.x - p0.x).abs() < 1e-12 && (p.z - p0.z).abs() < 1e-12);
        }
    }
}

/// A sheet pinned along one edge swings for `seconds` without damping; returns the largest
/// increase of the total energy over its initial value, the largest increase from one step to
/// the next, and the energy scale `m g L`.
fn swing(material: Material, seconds: f64) -> (f64, f64, f64) {
    let size = 0.2;
    let cloth = horizontal_sheet(size, 8, 0.0, material);
    let config = SimConfig {
        self_collision: false,
        ..SimConfig::default()
    };
    let mut sim = simulator(cloth, config);
    let edge: Vec<usize> = (0..sim.positions().len())
        .filter(|&i| (sim.positions()[i].x + 0.5 * size).abs() < 1e-9)
        .collect();
    assert_eq!(edge.len(), 9);
    for &i in &edge {
        let p = sim.positions()[i];
        sim.pin(i, p).expect("valid pin");
    }
    let e0 = sim.energy().total_j();
    let scale = sim.cloth().total_mass_kg() * G * size;
    let h = 1.0 / 300.0;
    let mut worst: f64 = f64::NEG_INFINITY;
    let mut worst_step: f64 = f64::NEG_INFINITY;
    let mut previous = e0;
    let mut lowest = f64::INFINITY;
    for _ in 0..(seconds / h).round() as usize {
        sim.step(h, &[]).expect("stable");
        let e = sim.energy().total_j();
        worst = worst.max(e - e0);
        worst_step = worst_step.max(e - previous);
        previous = e;
        lowest = lowest.min(e);
    }
    assert!(
        lowest < e0 - 0.01 * scale,
        "the sheet should swing down and dissipate"
    );
    (worst, worst_step, scale)
}

#[test]
fn undamped_swing_never_gains_energy() {
    // Implicit Euler is dissipative: kinetic + gravity + elastic energy never rises above its
    // initial value over 10 s, and never rises from one step to the next by more than 1e-6 m g L
    // (StVK with constant bending: a true potential).
    let (gain, step_gain, scale) = swing(stvk(), 10.0);
    eprintln!(
        "StVK swing: largest gain over E0 {gain:.3e} J, largest step-to-step gain {step_gain:.3e} J, m g L = {scale:.3e} J"
    );
    assert!(
        gain <= 0.0,
        "energy rose above its initial value by {gain:.3e} J"
    );
    assert!(
        step_gain <= 1e-6 * scale,
        "energy rose by {step_gain:.3e} J in one step"
    );
    // Gray-interlock's stiffness depends on the strain (frozen per step, as ARCSim), so its
    // "energy" is not exactly a Lyapunov function; over 3 s it stays below E0 and per-step rises
    // stay below 1e-4 m g L.
    let (gain, step_gain, scale) = swing(Material::gray_interlock(), 3.0);
    eprintln!(
        "gray-interlock swing: largest gain over E0 {gain:.3e} J, largest step-to-step gain {step_gain:.3e} J"
    );
    assert!(
        gain <= 0.0,
        "energy rose above its initial value by {gain:.3e} J"
    );
    assert!(
        step_gain <= 1e-4 * scale,
        "energy rose by {step_gain:.3e} J in one step"
    );
}

#[test]
fn hanging_sheet_comes_to_rest() {
    // A vertical sheet pinned at its two top corners sags, buckles out of plane (the top edge
    // is in compression) and stops. Its slowest modes (a ~1 Hz out-of-plane swing) are barely
    // damped by implicit Euler (rate ω² h / 2 ≈ 0.07/s), so a light air drag (mass damping
    // α = 2/s) brings it to rest within the test's 5 s: every vertex slower than 1 mm/s.
    let size = 0.2;
    let mesh = sartor_cloth::rectangle_sheet(
        Vector3::new(-0.5 * size, 0.0, 0.0),
        Vector3::new(size, 0.0, 0.0),
        Vector3::new(0.0, -size, 0.0),
        8,
        8,
    )
    .expect("valid");
    let cloth = sartor_cloth::Cloth::new(mesh, Material::gray_interlock(), None).expect("valid");
    let config = SimConfig {
        mass_damping_per_s: 2.0,
        ..SimConfig::default()
    };
    let mut sim = simulator(cloth, config);
    for i in [0, 8] {
        let p = sim.positions()[i];
        sim.pin(i, p).expect("valid pin");
    }
    let h = 1.0 / 300.0;
    let mut stats = Default::default();
    let mut fastest: f64 = 0.0;
    for _ in 0..1500 {
        stats = sim.step(h, &[]).expect("stable");
        fastest = fastest.max(stats.max_speed_m_per_s);
    }
    assert!(
        fastest > 0.03,
        "the sheet should have moved ({fastest} m/s)"
    );
    assert!(
        stats.max_speed_m_per_s < 1e-3,
        "still moving at {} m/s after 5 s",
        stats.max_speed_m_per_s
    );
    // It hangs: the bottom edge is below the start, the pins did not move.
    assert!(sim.positions()[80].y < -size);
    assert!((sim.positions()[0] - Vector3::new(-0.5 * size, 0.0, 0.0)).norm() < 1e-12);
}

/// Simulate a swinging sheet for 0.2 s with the given settings; returns the final positions.
fn swing_positions(config: SimConfig, h: f64) -> Vec<Vector3<f64>> {
    let cloth = horizontal_sheet(0.2, 6, 0.0, Material::gray_interlock());
    let mut sim = simulator(cloth, config);
    for i in 0..7 {
        let p = sim.positions()[i * 7];
        sim.pin(i * 7, p).expect("valid pin");
    }
    for _ in 0..(0.2 / h).round() as usize {
        sim.step(h, &[]).expect("stable");
    }
    sim.positions().to_vec()
}

fn max_difference(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}

#[test]
fn newton_iterations_and_solvers_agree() {
    let h = 1.0 / 300.0;
    let one = swing_positions(SimConfig::default(), h);
    let newton = swing_positions(
        SimConfig {
            newton_iterations: 5,
            newton_tolerance_m_per_s: 1e-9,
            ..SimConfig::default()
        },
        h,
    );
    let fine = swing_positions(
        SimConfig {
            newton_iterations: 5,
            ..SimConfig::default()
        },
        h / 4.0,
    );
    let (d_newton, d_one_fine, d_newton_fine) = (
        max_difference(&one, &newton),
        max_difference(&one, &fine),
        max_difference(&newton, &fine),
    );
    eprintln!(
        "0.2 s swing: 1 vs 5 Newton iterations {:.3} mm; vs h/4 reference: 1 it {:.3} mm, 5 it {:.3} mm",
        d_newton * 1e3,
        d_one_fine * 1e3,
        d_newton_fine * 1e3
    );
    // The single linearised step is a good approximation of the converged implicit step.
    assert!(d_newton < 5e-3, "{d_newton}");
    let cg = swing_positions(
        SimConfig {
            linear_solver: LinearSolver::ConjugateGradient {
                max_iterations: 2000,
                relative_tolerance: 1e-10,
                fallback_to_cholesky: true,
            },
            ..SimConfig::default()
        },
        h,
    );
    let d_cg = max_difference(&one, &cg);
    assert!(d_cg < 1e-7, "Cholesky and CG differ by {d_cg} m");
}

#[test]
fn parallel_runs_are_identical() {
    let run = |par: Parallelism| {
        let config = SimConfig {
            linear_solver: LinearSolver::ConjugateGradient {
                max_iterations: 1000,
                relative_tolerance: 1e-9,
                fallback_to_cholesky: true,
            },
            parallelism: par,
            ..SimConfig::default()
        };
        let cloth = horizontal_sheet(0.2, 24, 0.0, Material::gray_interlock());
        let mut sim: Simulator = simulator(cloth, config);
        sim.pin(0, sim.positions()[0]).expect("valid pin");
        for _ in 0..5 {
            sim.step(1.0 / 300.0, &[]).expect("stable");
        }
        sim.positions().to_vec()
    };
    let sequential = run(Parallelism::Sequential);
    assert_eq!(sequential, run(Parallelism::Rayon));
    // The parallel assembly splits the rows into one share per thread of the pool the
    // simulator is made in: any split sums the same numbers in the same order.
    for threads in [1, 3, 5] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        assert_eq!(
            sequential,
            pool.install(|| run(Parallelism::Rayon)),
            "{threads} threads"
        );
    }
}

/// The simulator numbers the vertices its own way inside (near vertices near in memory) and
/// hands everything out in the numbering it was given: shuffling the given numbering moves
/// nothing beyond round-off, and pins, positions, velocities and forces follow the vertices.
#[test]
fn the_given_vertex_numbering_does_not_change_the_motion() {
    let cloth = horizontal_sheet(0.2, 8, 0.0, Material::gray_interlock());
    let n = cloth.n_vertices();
    let rest = cloth.rest_mesh().positions().to_vec();
    // A fixed shuffle: given vertex i is vertex `new_of[i]` of the shuffled cloth.
    let new_of: Vec<usize> = (0..n).map(|i| (i * 37 + 11) % n).collect();
    let mut positions = vec![Vector3::zeros(); n];
    for (i, &k) in new_of.iter().enumerate() {
        positions[k] = rest[i];
    }
    let faces = cloth
        .faces()
        .iter()
        .map(|t| t.map(|v| new_of[v as usize] as u32))
        .collect();
    let shuffled =
        Cloth::from_parts(positions, faces, Material::gray_interlock(), None).expect("valid");
    let run = |cloth: Cloth, label: &dyn Fn(usize) -> usize| {
        let config = SimConfig {
            linear_solver: LinearSolver::ConjugateGradient {
                max_iterations: 2000,
                relative_tolerance: 1e-12,
                fallback_to_cholesky: true,
            },
            ..SimConfig::default()
        };
        let mut sim = simulator(cloth, config);
        for i in 0..9 {
            let v = label(i * 9);
            sim.pin(v, sim.positions()[v]).expect("valid pin");
        }
        for _ in 0..30 {
            sim.step(1.0 / 300.0, &[]).expect("stable");
        }
        (
            sim.positions().to_vec(),
            sim.velocities().to_vec(),
            sim.elastic_forces(),
            sim.pinned().to_vec(),
        )
    };
    let (x, v, f, pinned) = run(cloth, &|i| i);
    let (xs, vs, fs, pinned_s) = run(shuffled, &|i| new_of[i]);
    let mut worst = [0.0f64; 3];
    for (i, &k) in new_of.iter().enumerate() {
        assert_eq!(pinned[i], pinned_s[k], "pin of vertex {i}");
        worst[0] = worst[0].max((x[i] - xs[k]).norm());
        worst[1] = worst[1].max((v[i] - vs[k]).norm());
        worst[2] = worst[2].max((f[i] - fs[k]).norm());
    }
    // The sheet swings by centimetres; the two runs differ by summation order only.
    assert!(
        (x[80] - x[0]).norm() > 0.05 && x[80].y < -0.01,
        "it swings: {:?}",
        x[80]
    );
    assert!(
        worst[0] < 1e-9 && worst[1] < 1e-7,
        "positions {worst:?} apart"
    );
    assert!(
        worst[2] < 1e-6 * f.iter().map(|f| f.norm()).fold(0.0, f64::max),
        "{worst:?}"
    );
    // The pins held, in the given numbering.
    for i in 0..9 {
        assert!((x[i * 9] - rest[i * 9]).norm() < 1e-12, "pin {i} moved");
    }
}

/// Rayleigh stiffness damping `−β K v` slows deformation and nothing else: a sheet gliding at
/// a uniform velocity (no gravity, no pins) keeps it, and a swinging sheet loses more energy
/// with β than without. Three Newton iterations: from the second on, the right-hand side's
/// `β K v⁺` term is not zero.
#[test]
fn stiffness_damping_damps_deformation_only() {
    let damped = SimConfig {
        stiffness_damping_s: 0.01,
        self_collision: false,
        newton_iterations: 3,
        newton_tolerance_m_per_s: 1e-12,
        ..SimConfig::default()
    };
    let v0 = Vector3::new(0.3, -0.2, 0.1);
    let mut glide = simulator(
        horizontal_sheet(0.2, 6, 0.0, stvk()),
        SimConfig {
            gravity_m_per_s2: Vector3::zeros(),
            ..damped.clone()
        },
    );
    glide
        .set_velocities(&vec![v0; glide.positions().len()])
        .expect("valid");
    for _ in 0..20 {
        glide.step(1.0 / 300.0, &[]).expect("stable");
    }
    let drift = glide
        .velocities()
        .iter()
        .map(|v| (v - v0).norm())
        .fold(0.0, f64::max);
    assert!(drift < 1e-9, "a rigid glide changed speed by {drift} m/s");
    let swing_energy = |config: SimConfig| {
        let mut sim = simulator(horizontal_sheet(0.2, 6, 0.0, stvk()), config);
        for i in 0..7 {
            let p = sim.positions()[i * 7];
            sim.pin(i * 7, p).expect("valid pin");
        }
        for _ in 0..90 {
            sim.step(1.0 / 300.0, &[]).expect("stable");
        }
        sim.energy().total_j()
    };
    let (free, with_beta) = (
        swing_energy(SimConfig {
            self_collision: false,
            ..SimConfig::default()
        }),
        swing_energy(damped),
    );
    assert!(
        with_beta < free,
        "energy after 0.3 s: {with_beta} J with β, {free} J without"
    );
}
