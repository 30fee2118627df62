//! Obstacles: a sheet dropped on a sphere and on a floor comes to rest outside them (no vertex
//! more than 1 mm inside); on a slope below atan(μ) it sticks, above it slides.

use nalgebra::Vector3;
use sartor_cloth::{
    Cloth, Collider, Contact, FrictionModel, Material, MeshCollider, MotionBound, Plane, SimConfig,
    Sphere, rectangle_sheet,
};

use crate::common::{horizontal_sheet, simulator, uv_sphere};

const DT: f64 = 1.0 / 300.0;

fn min_distance(positions: &[Vector3<f64>], collider: &dyn Collider) -> f64 {
    positions
        .iter()
        .map(|p| collider.closest(*p).expect("answers").distance_m)
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn sheet_drapes_on_sphere_and_rests() {
    // The draped corners swing slowly (barely damped by implicit Euler): light air drag
    // (mass damping α = 2/s) lets the test reach rest in 3 s.
    let sphere = Sphere::new(Vector3::zeros(), 0.08);
    let cloth = horizontal_sheet(0.3, 14, 0.095, Material::gray_interlock());
    let config = SimConfig {
        mass_damping_per_s: 2.0,
        ..SimConfig::default()
    };
    let mut sim = simulator(cloth, config);
    let colliders = [&sphere as &dyn Collider];
    let mut projected = 0;
    let mut last = Default::default();
    for step in 0..900 {
        last = sim.step(DT, &colliders).expect("stable");
        if step >= 450 {
            projected += last.projected_vertices;
        }
    }
    let d = min_distance(sim.positions(), &sphere);
    eprintln!(
        "sphere: min distance {:.2} mm, {} contacts, {} self-contacts, max speed {:.4} m/s",
        d * 1e3,
        last.obstacle_contacts,
        last.self_contacts,
        last.max_speed_m_per_s
    );
    assert!(
        d > -1e-3,
        "a vertex is {:.2} mm inside the sphere",
        -d * 1e3
    );
    assert!(
        last.obstacle_contacts > 0,
        "the sheet should touch the sphere"
    );
    assert_eq!(
        projected, 0,
        "the projection fallback fired in the second second"
    );
    // Draped: the corners hang below the sphere's top.
    let lowest = sim
        .positions()
        .iter()
        .map(|p| p.y)
        .fold(f64::INFINITY, f64::min);
    assert!(lowest < 0.03, "lowest point {lowest}");
    assert!(
        last.max_speed_m_per_s < 0.01,
        "still moving at {} m/s",
        last.max_speed_m_per_s
    );
}

#[test]
fn sheet_rests_on_floor() {
    let floor = Plane::horizontal(0.0);
    let cloth = horizontal_sheet(0.2, 8, 0.02, Material::gray_interlock());
    let mut sim = simulator(cloth, SimConfig::default());
    let colliders = [&floor as &dyn Collider];
    let mut last = Default::default();
    for _ in 0..300 {
        last = sim.step(DT, &colliders).expect("stable");
    }
    let d = min_distance(sim.positions(), &floor);
    eprintln!(
        "floor: min distance {:.3} mm, max speed {:.2e} m/s",
        d * 1e3,
        last.max_speed_m_per_s
    );
    assert!(d > -1e-3, "{:.2} mm below the floor", -d * 1e3);
    // It rests near the repulsion thickness (5 mm), not on the floor itself.
    assert!(d > 3e-3 && d < 5e-3, "rest distance {d}");
    assert!(
        last.max_speed_m_per_s < 1e-2,
        "still moving at {}",
        last.max_speed_m_per_s
    );
    assert_eq!(last.projected_vertices, 0);
}

/// Place a sheet on a slope tilted by `tilt_rad` (just touching: distance = thickness), let it
/// go for one second and return how far its centroid moved downhill.
fn slide_distance(tilt_rad: f64, friction_model: FrictionModel) -> f64 {
    let config = SimConfig {
        friction_model,
        ..SimConfig::default()
    };
    let thickness = config.contact_penalty.thickness_m;
    let plane = Plane::tilted(Vector3::zeros(), tilt_rad);
    let n = plane.normal();
    let down = plane.downhill();
    let across = n.cross(&down);
    let size = 0.15;
    let corner = n * thickness - down * (0.5 * size) - across * (0.5 * size);
    let mesh = rectangle_sheet(corner, down * size, across * size, 6, 6).expect("valid");
    let cloth = Cloth::new(mesh, Material::gray_interlock(), None).expect("valid");
    let mut sim = simulator(cloth, config);
    let centroid = |p: &[Vector3<f64>]| p.iter().sum::<Vector3<f64>>() / p.len() as f64;
    let start = centroid(sim.positions());
    let colliders = [&plane as &dyn Collider];
    for _ in 0..300 {
        sim.step(DT, &colliders).expect("stable");
    }
    let d = min_distance(sim.positions(), &plane);
    assert!(d > -1e-3, "{:.2} mm inside the slope", -d * 1e3);
    (centroid(sim.positions()) - start).dot(&down)
}

#[test]
fn friction_sticks_below_and_slides_above_the_friction_angle() {
    for model in [FrictionModel::Impulse, FrictionModel::Implicit] {
        sticks_below_and_slides_above(model);
    }
}

fn sticks_below_and_slides_above(model: FrictionModel) {
    // μ = 0.3: atan(μ) = 16.7°.
    let (below, above) = (10f64.to_radians(), 30f64.to_radians());
    let stick = slide_distance(below, model);
    eprintln!("{model:?}: 10° slope: moved {:.3} mm in 1 s", stick * 1e3);
    let slide = slide_distance(above, model);
    eprintln!("{model:?}: 30° slope: moved {:.1} mm in 1 s", slide * 1e3);
    let held = match model {
        FrictionModel::Impulse => 3e-3,
        // ARCSim's damper creeps at `g sin α · Δt` (see `sartor_cloth::energy`): 5.7 mm in
        // the second; a damper any weaker (or Coulomb's force lost) slides far more.
        FrictionModel::Implicit => 1.2 * 9.81 * below.sin() * DT,
    };
    assert!(
        stick.abs() < held,
        "moved {:.2} mm at 10° (at most {:.2})",
        stick * 1e3,
        held * 1e3
    );
    // Free sliding with Coulomb friction: ½ g (sin α − μ cos α) t² ≈ 1.2 m in 1 s.
    let expected = 0.5 * 9.81 * (above.sin() - 0.3 * above.cos());
    assert!(
        slide > 0.9 * expected,
        "slid {slide} m at 30°, less than frictional sliding ({expected} m)"
    );
    assert!(
        slide < 1.1 * expected,
        "slid {slide} m, more than frictional sliding allows"
    );
}

#[test]
fn the_friction_damper_gives_coulomb_force_while_sliding_and_never_more_than_a_stop() {
    use sartor_cloth::energy::friction_damping;
    let n = Vector3::new(0.0, 1.0, 0.0);
    let (mu, fn_, m, h) = (0.3, 2.0, 0.01, 0.01);
    // Sliding at 1 m/s (the normal part of the velocity plays no role): `c |v_t| = μ f_n`.
    for v in [Vector3::new(1.0, 0.0, 0.0), Vector3::new(0.6, 5.0, 0.8)] {
        let c = friction_damping(&v, &n, mu, fn_, m, h);
        assert!((c * 1.0 - mu * fn_).abs() < 1e-12, "c = {c} at {v:?}");
    }
    // Slow (0.1 m/s, Coulomb's force would stop it in less than a step) or at rest: the
    // damper is capped at `m / h`, which halves the tangential velocity in one implicit step.
    for v in [Vector3::new(0.1, 0.0, 0.0), Vector3::zeros()] {
        let c = friction_damping(&v, &n, mu, fn_, m, h);
        assert!((c - m / h).abs() < 1e-12, "c = {c} at {v:?}");
    }
    // No normal force or no friction: no damper.
    let v = Vector3::new(1.0, 0.0, 0.0);
    assert_eq!(friction_damping(&v, &n, mu, 0.0, m, h), 0.0);
    assert_eq!(friction_damping(&v, &n, mu, -1.0, m, h), 0.0);
    assert_eq!(friction_damping(&v, &n, 0.0, fn_, m, h), 0.0);
}

/// A sheet resting on a floor is given a horizontal speed `v0`: Coulomb friction stops it
/// after `v0² / (2 μ g)` (the penalty carries the sheet's weight).
#[test]
fn a_sheet_sliding_on_a_floor_stops_where_coulomb_says() {
    let v0 = 0.5;
    let expected = v0 * v0 / (2.0 * 0.3 * 9.81);
    for model in [FrictionModel::Impulse, FrictionModel::Implicit] {
        let floor = Plane::horizontal(0.0);
        let cloth = horizontal_sheet(0.2, 8, 0.0045, Material::gray_interlock());
        let config = SimConfig {
            friction_model: model,
            ..SimConfig::default()
        };
        let mut sim = simulator(cloth, config);
        let colliders = [&floor as &dyn Collider];
        for _ in 0..150 {
            sim.step(DT, &colliders).expect("stable");
        }
        let centroid = |p: &[Vector3<f64>]| p.iter().sum::<Vector3<f64>>() / p.len() as f64;
        let start = centroid(sim.positions());
        let v: Vec<_> = sim
            .velocities()
            .iter()
            .map(|v| v + Vector3::new(v0, 0.0, 0.0))
            .collect();
        sim.set_velocities(&v).expect("valid");
        let mut last = Default::default();
        for _ in 0..150 {
            last = sim.step(DT, &colliders).expect("stable");
        }
        let moved = centroid(sim.positions()) - start;
        eprintln!(
            "{model:?}: slid {:.1} mm (Coulomb: {:.1} mm), still at {:.2e} m/s",
            moved.x * 1e3,
            expected * 1e3,
            last.max_speed_m_per_s
        );
        assert!(
            (moved.x - expected).abs() < 0.1 * expected,
            "{model:?}: slid {:.1} mm, Coulomb says {:.1} mm",
            moved.x * 1e3,
            expected * 1e3
        );
        assert!(
            moved.z.abs() < 1e-3,
            "{model:?}: drifted sideways {moved:?}"
        );
        assert!(last.max_speed_m_per_s < 0.01, "{model:?}: still moving");
    }
}

#[test]
fn mesh_collider_agrees_with_the_analytic_sphere() {
    let (center, radius) = (Vector3::new(0.0, 0.1, 0.0), 0.1);
    let (p, f) = uv_sphere(center, radius, 24);
    let mut mesh = MeshCollider::new(&p, &f, 0.05).expect("valid mesh");
    let sphere = Sphere::new(center, radius);
    // The chord error of a 24-ring sphere of radius 10 cm is below 1 mm.
    for q in [
        Vector3::new(0.0, 0.205, 0.0),
        Vector3::new(0.07, 0.17, 0.03),
        Vector3::new(0.02, 0.12, -0.01), // deep inside
        Vector3::new(0.0, 0.098, 0.099), // just inside, near the equator
    ] {
        let (a, b) = (
            mesh.closest(q).expect("found"),
            sphere.closest(q).expect("found"),
        );
        assert!((a.distance_m - b.distance_m).abs() < 1e-3, "{a:?} vs {b:?}");
        assert!(a.normal.dot(&b.normal) > 0.95, "{a:?} vs {b:?}");
    }
    // Bounded search: far points are not reported, deep ones (within the search depth) are.
    assert!(
        mesh.closest_within(Vector3::new(0.0, 0.3, 0.0), 5e-3)
            .is_none()
    );
    assert!(
        mesh.closest_within(center + Vector3::new(0.0, 0.07, 0.0), 0.0)
            .is_some()
    );
    // Moving it gives the surface velocity.
    let moved: Vec<_> = p
        .iter()
        .map(|q| q + Vector3::new(0.0, 0.002, 0.0))
        .collect();
    mesh.move_to(&moved, 0.01).expect("valid");
    let c = mesh.closest(Vector3::new(0.03, 0.25, 0.0)).expect("found");
    assert!((c.velocity_m_per_s - Vector3::new(0.0, 0.2, 0.0)).norm() < 1e-9);
}

#[test]
fn moving_mesh_body_lifts_the_sheet() {
    // A sheet resting on a mesh sphere; the sphere rises at 0.2 m/s for 0.5 s and carries the
    // sheet up without letting it through.
    let (center, radius) = (Vector3::zeros(), 0.08);
    let (p, f) = uv_sphere(center, radius, 16);
    let mut body = MeshCollider::new(&p, &f, 0.05).expect("valid mesh");
    let cloth = horizontal_sheet(0.2, 8, radius + 0.006, Material::gray_interlock());
    let mut sim = simulator(cloth, SimConfig::default());
    let mut offset = Vector3::zeros();
    for _ in 0..150 {
        offset += Vector3::new(0.0, 0.2 * DT, 0.0);
        let moved: Vec<_> = p.iter().map(|q| q + offset).collect();
        body.move_to(&moved, DT).expect("valid");
        sim.step(DT, &[&body as &dyn Collider]).expect("stable");
    }
    let d = min_distance(sim.positions(), &body);
    assert!(d > -1e-3, "{:.2} mm inside the moving body", -d * 1e3);
    // The centre vertex rides on top of the sphere, near the repulsion thickness (5 mm).
    let top = radius + offset.y;
    let gap = sim.positions()[40].y - top;
    assert!(
        gap > 3e-3 && gap < 6e-3,
        "centre vertex {:.2} mm above the top",
        gap * 1e3
    );
}

/// A collider that forwards to another and counts its queries; with `forward_motion` false it
/// reports no motion bound, so the simulator queries every vertex every time.
struct Counting<'a> {
    inner: &'a MeshCollider,
    forward_motion: bool,
    queries: std::sync::atomic::AtomicUsize,
}

impl Collider for Counting<'_> {
    fn closest(&self, p: Vector3<f64>) -> Option<Contact> {
        self.queries
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.inner.closest(p)
    }

    fn closest_within_hinted(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
    ) -> Option<Contact> {
        self.queries
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.inner.closest_within_hinted(p, max_distance_m, hint)
    }

    fn motion_bound(&self) -> Option<MotionBound> {
        self.forward_motion
            .then(|| self.inner.motion_bound())
            .flatten()
    }
}

#[test]
fn skipping_the_queries_of_far_vertices_changes_no_step() {
    // A sheet draped over a sphere that travels sideways and breathes (its radius changes, so
    // the motion is not a pure translation): the steps with queries skipped by the collider's
    // motion bound equal, bit for bit, the steps that query every vertex every time.
    let (center, radius) = (Vector3::zeros(), 0.08);
    let (p, f) = uv_sphere(center, radius, 16);
    let mut body = MeshCollider::new(&p, &f, 0.05).expect("valid mesh");
    let cloth = horizontal_sheet(0.3, 16, radius + 0.004, Material::gray_interlock());
    let mut skipping = simulator(cloth.clone(), SimConfig::default());
    let mut querying = simulator(cloth, SimConfig::default());
    let (mut skipped_queries, mut all_queries) = (0, 0);
    for step in 0..120 {
        let t = step as f64 * DT;
        let shift = Vector3::new(0.3 * t, 0.0, 0.1 * t);
        let scale = 1.0 + 0.05 * (20.0 * t).sin();
        let moved: Vec<_> = p
            .iter()
            .map(|q| (q - center) * scale + center + shift)
            .collect();
        body.move_to(&moved, DT).expect("valid");
        for (sim, forward_motion, count) in [
            (&mut skipping, true, &mut skipped_queries),
            (&mut querying, false, &mut all_queries),
        ] {
            let collider = Counting {
                inner: &body,
                forward_motion,
                queries: 0.into(),
            };
            sim.step(DT, &[&collider as &dyn Collider]).expect("stable");
            *count += collider.queries.into_inner();
        }
        assert_eq!(skipping.positions(), querying.positions(), "step {step}");
        assert_eq!(skipping.velocities(), querying.velocities(), "step {step}");
    }
    // The bound skipped most queries of the vertices hanging away from the sphere.
    assert!(
        (skipped_queries as f64) < 0.3 * all_queries as f64,
        "{skipped_queries} of {all_queries} queries made"
    );
}

#[test]
fn a_body_moved_along_its_span_steps_as_one_refitted_at_each_substep() {
    // A sheet draped over a sphere that travels, turns and breathes, frame by frame, with six
    // substeps per frame: moved along the frame's span (boxes fitted at the two poses and
    // interpolated) or refitted at each substep's interpolated pose, the cloth is the same to
    // the bit, and so are the body's velocities.
    let (center, radius) = (Vector3::zeros(), 0.08);
    let (p, f) = uv_sphere(center, radius, 16);
    let pose = |frame: usize| -> Vec<Vector3<f64>> {
        let t = frame as f64 / 30.0;
        let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), 2.0 * t).into_inner()
            * (1.0 + 0.1 * (9.0 * t).sin());
        let shift = Vector3::new(0.3 * t, 0.05 * t, 0.1 * t);
        p.iter()
            .map(|q| turn * (q - center) + center + shift)
            .collect()
    };
    let mut spanned = MeshCollider::new(&p, &f, 0.05).expect("valid mesh");
    let mut refitted = spanned.clone();
    assert!(
        spanned.move_on_span(0.5, DT).is_err(),
        "a move before any span"
    );
    assert!(
        spanned.set_span(&p, &p[..10], DT).is_err(),
        "a span of two sizes"
    );
    let cloth = horizontal_sheet(0.3, 16, radius + 0.004, Material::gray_interlock());
    let (mut a, mut b) = (
        simulator(cloth.clone(), SimConfig::default()),
        simulator(cloth, SimConfig::default()),
    );
    let substeps = 6;
    let h = 1.0 / (30.0 * substeps as f64);
    for frame in 0..12 {
        let (prev, next) = (pose(frame), pose(frame + 1));
        spanned.set_span(&prev, &next, h).expect("valid");
        refitted.move_to(&prev, h).expect("valid");
        for s in 1..=substeps {
            let t = s as f64 / substeps as f64;
            spanned.move_on_span(t, h).expect("valid");
            let at: Vec<_> = if s == substeps {
                next.clone()
            } else {
                prev.iter()
                    .zip(&next)
                    .map(|(p, q)| p + (q - p) * t)
                    .collect()
            };
            refitted.move_to(&at, h).expect("valid");
            assert_eq!(spanned.velocities(), refitted.velocities(), "frame {frame}");
            a.step(h, &[&spanned as &dyn Collider]).expect("stable");
            b.step(h, &[&refitted as &dyn Collider]).expect("stable");
            assert_eq!(a.positions(), b.positions(), "frame {frame}, substep {s}");
        }
    }
    assert!(
        min_distance(a.positions(), &spanned) > -1e-3,
        "the sheet stays on the turning sphere"
    );
}

#[test]
fn a_vertex_inside_one_part_but_nearest_another_is_projected_at_the_frame_end() {
    // Two overlapping boxes as one body, as a forearm pressed into a torso: B's top face at
    // y = 0, A reaching up to `a_top`. A sheet 2 cm above B's top is inside A; at first A's top
    // is 3 cm above it and B's top, 2 cm below, is the nearest: the query reads it outside.
    // A then sinks to 1.6 cm above the sheet: A's top becomes the nearest and the query reads
    // the sheet 1.6 cm inside, although no surface came within 1.6 cm of it. The clearance
    // bound (2 cm less the motion) skips its queries; a step told to query every vertex
    // projects it out, as the drive does at every frame's last substep.
    let body = |a_top: f64| {
        let (mut p, mut f) =
            sartor_core::box_mesh(Vector3::new(-0.5, -0.5, -0.5), Vector3::new(0.5, 0.0, 0.5));
        let (pa, fa) = sartor_core::box_mesh(
            Vector3::new(-0.4, -0.3, -0.4),
            Vector3::new(0.4, a_top, 0.4),
        );
        let offset = p.len() as u32;
        p.extend(pa);
        f.extend(fa.iter().map(|t| t.map(|v| v + offset)));
        (p, f)
    };
    let (start, faces) = body(0.05);
    let (sunk, _) = body(0.036);
    for every in [false, true] {
        let mut collider = MeshCollider::new(&start, &faces, 0.05).expect("valid mesh");
        let cloth = horizontal_sheet(0.01, 2, 0.02, Material::gray_interlock());
        let mut sim = simulator(cloth, SimConfig::default());
        sim.step(DT, &[&collider as &dyn Collider]).expect("stable");
        assert!(
            min_distance(sim.positions(), &collider) > 0.019,
            "read outside at first"
        );
        collider.move_to(&sunk, DT).expect("valid");
        if every {
            sim.query_every_vertex_next_step();
        }
        let stats = sim.step(DT, &[&collider as &dyn Collider]).expect("stable");
        let depth = -min_distance(sim.positions(), &collider);
        if every {
            assert!(
                stats.projected_vertices > 0 && depth <= 1e-3 + 1e-9,
                "{depth}"
            );
        } else {
            // The bound's blind spot, which the frame's last substep closes.
            assert!(depth > 0.015, "{depth}");
        }
    }
}
