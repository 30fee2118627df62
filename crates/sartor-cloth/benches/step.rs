//! One frame (10 substeps of 1/300 s) of a ~4,400-vertex gray-interlock sheet draped on a
//! sphere, with the sparse Cholesky solver and with block-Jacobi PCG, each on the calling
//! thread and on rayon's pool.
//!
//! `cargo bench -p sartor-cloth --bench step -- --warm-up-time 1 --measurement-time 5`
//!
//! Before measuring, the sheet is dropped onto the sphere and simulated for 20 frames so the
//! benchmark runs on a draped, contact-rich state; the per-substep statistics of one frame
//! (CG iterations, residual, assembly and solve times) are printed for each solver.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use sartor_cloth::{
    Cloth, Collider, LinearSolver, Material, Parallelism, SimConfig, Simulator, Sphere, StepStats,
    rectangle_sheet,
};

const DT: f64 = 1.0 / 300.0;
const SUBSTEPS: usize = 10;

fn sheet() -> Cloth {
    // 65 × 65 quads: 4,356 vertices, 8,450 triangles, 12.3 mm edges (the paper's T-shirt:
    // 4,424 vertices, 13.2 mm median edge).
    let size = 0.8;
    let mesh = rectangle_sheet(
        Vector3::new(-0.5 * size, 0.26, 0.5 * size),
        Vector3::new(size, 0.0, 0.0),
        Vector3::new(0.0, 0.0, -size),
        65,
        65,
    )
    .expect("valid sheet");
    Cloth::new(mesh, Material::gray_interlock(), None).expect("valid cloth")
}

fn config(linear_solver: LinearSolver) -> SimConfig {
    SimConfig {
        linear_solver,
        parallelism: Parallelism::Rayon,
        ..SimConfig::default()
    }
}

fn frame(sim: &mut Simulator, colliders: &[&dyn Collider]) -> Vec<StepStats> {
    (0..SUBSTEPS)
        .map(|_| sim.step(DT, colliders).expect("stable"))
        .collect()
}

fn report(name: &str, stats: &[StepStats]) {
    let n = stats.len() as f64;
    let mean = |f: &dyn Fn(&StepStats) -> f64| stats.iter().map(f).sum::<f64>() / n;
    println!(
        "{name}: per substep {:.1} ms total = assemble {:.1} + solve {:.1} + collision {:.1} ms; \
         CG iterations {:.0}, relative residual {:.1e}; contacts {:.0} obstacle, {:.0} self",
        mean(&|s| s.total_secs) * 1e3,
        mean(&|s| s.assemble_secs) * 1e3,
        mean(&|s| s.solve_secs) * 1e3,
        mean(&|s| s.collision_secs) * 1e3,
        mean(&|s| s.linear.iterations as f64),
        mean(&|s| s.linear.relative_residual),
        mean(&|s| s.obstacle_contacts as f64),
        mean(&|s| s.self_contacts as f64),
    );
}

fn bench(c: &mut Criterion) {
    let sphere = Sphere::new(Vector3::zeros(), 0.25);
    let colliders = [&sphere as &dyn Collider];
    // Drape once, then start both solvers from the same state.
    let mut drape = Simulator::new(sheet(), config(LinearSolver::Cholesky)).expect("valid");
    for _ in 0..20 {
        frame(&mut drape, &colliders);
    }
    let solvers = [
        ("cholesky", LinearSolver::Cholesky),
        (
            "pcg",
            LinearSolver::ConjugateGradient {
                max_iterations: 2000,
                relative_tolerance: 1e-8,
                fallback_to_cholesky: true,
            },
        ),
    ];
    let mut group = c.benchmark_group("frame_4356_vertices_on_sphere");
    for (name, solver) in solvers {
        for (par_name, par) in [
            ("seq", Parallelism::Sequential),
            ("rayon", Parallelism::Rayon),
        ] {
            let name = format!("{name}_{par_name}");
            let config = SimConfig {
                parallelism: par,
                ..config(solver)
            };
            let mut sim = Simulator::new(sheet(), config).expect("valid");
            sim.set_positions(drape.positions()).expect("finite");
            sim.set_velocities(drape.velocities()).expect("finite");
            report(&name, &frame(&mut sim, &colliders));
            group.bench_function(&name, |b| b.iter(|| frame(&mut sim, &colliders)));
        }
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
