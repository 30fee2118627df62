//! Central finite-difference checks of every energy's gradient and exact Hessian, on seeded
//! random elements. Tolerance: max |FD − analytic| ≤ 1e-5 · max |analytic| (per quantity).

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::Rng;
use sartor_cloth::energy::{
    BendingHessian, BendingRest, CRUSHED_AREA_FRACTION, ElementDerivatives, MembraneRest,
    ObstacleContact, Penalty, PenaltyProfile, Projection, SelfContact, dihedral_angle,
};
use sartor_cloth::{
    BendingModel, BendingTable, Collider, GRAY_INTERLOCK_BENDING, Material, Plane, Sphere,
};

use crate::common::rng;

const RELATIVE_TOLERANCE: f64 = 1e-5;

fn max_abs<const N: usize>(g: &[Vector3<f64>; N]) -> f64 {
    g.iter().map(|v| v.amax()).fold(0.0, f64::max)
}

/// Check `gradient` against central differences of `energy` and `hessian` against central
/// differences of `gradient`, with step `eps` (m).
fn check<const N: usize>(
    x: &[Vector3<f64>; N],
    eps: f64,
    derivatives: impl Fn(&[Vector3<f64>; N]) -> ElementDerivatives<N>,
    what: &str,
) {
    let d0 = derivatives(x);
    let g_scale = max_abs(&d0.gradient);
    let h_scale = d0
        .hessian
        .iter()
        .flatten()
        .map(|m| m.amax())
        .fold(0.0, f64::max);
    assert!(g_scale > 0.0 && h_scale > 0.0, "{what}: trivial element");
    let mut g_err: f64 = 0.0;
    let mut h_err: f64 = 0.0;
    for b in 0..N {
        for c in 0..3 {
            let mut xp = *x;
            let mut xm = *x;
            xp[b][c] += eps;
            xm[b][c] -= eps;
            let (dp, dm) = (derivatives(&xp), derivatives(&xm));
            let fd_g = (dp.energy_j - dm.energy_j) / (2.0 * eps);
            g_err = g_err.max((fd_g - d0.gradient[b][c]).abs());
            for a in 0..N {
                let fd_col = (dp.gradient[a] - dm.gradient[a]) / (2.0 * eps);
                let col = d0.hessian[a][b].column(c).into_owned();
                h_err = h_err.max((fd_col - col).amax());
            }
        }
    }
    assert!(
        g_err <= RELATIVE_TOLERANCE * g_scale,
        "{what}: gradient error {g_err:.3e} vs scale {g_scale:.3e}"
    );
    assert!(
        h_err <= RELATIVE_TOLERANCE * h_scale,
        "{what}: Hessian error {h_err:.3e} vs scale {h_scale:.3e}"
    );
}

fn random_vector(r: &mut impl Rng, scale: f64) -> Vector3<f64> {
    Vector3::new(
        r.random_range(-1.0..1.0),
        r.random_range(-1.0..1.0),
        r.random_range(-1.0..1.0),
    ) * scale
}

fn is_psd<const N: usize>(h: &[[Matrix3<f64>; N]; N]) -> bool {
    let m = nalgebra::DMatrix::from_fn(3 * N, 3 * N, |i, j| h[i / 3][j / 3][(i % 3, j % 3)]);
    let scale = m.amax();
    m.symmetric_eigen()
        .eigenvalues
        .iter()
        .all(|&l| l >= -1e-10 * scale)
}

/// A random rest triangle (about 1 cm) in the XY plane, a random rigid motion plus a random
/// ±20 % deformation.
fn random_triangle(r: &mut impl Rng) -> ([Vector3<f64>; 3], [Vector3<f64>; 3]) {
    let rest = [
        Vector3::zeros(),
        Vector3::new(
            r.random_range(0.008..0.012),
            r.random_range(-0.002..0.002),
            0.0,
        ),
        Vector3::new(
            r.random_range(0.002..0.006),
            r.random_range(0.008..0.012),
            0.0,
        ),
    ];
    let rotation = Rotation3::new(random_vector(r, 3.0));
    let shift = random_vector(r, 0.1);
    let x = rest.map(|p| rotation * (p + random_vector(r, 0.002)) + shift);
    (rest, x)
}

#[test]
fn membrane_stvk_and_tabulated() {
    let mut r = rng(1);
    let stvk = Material::stvk(0.2, 15.0, 25.0, 1e-5).expect("valid");
    let gray = Material::gray_interlock();
    for trial in 0..20 {
        let (rest, x) = random_triangle(&mut r);
        let angle: f64 = r.random_range(0.0..std::f64::consts::PI);
        let (u, v) = (
            Vector3::new(angle.cos(), angle.sin(), 0.0),
            Vector3::new(-angle.sin(), angle.cos(), 0.0),
        );
        let el = MembraneRest::new(&rest, &u, &v).expect("non-degenerate");
        for material in [&stvk, &gray] {
            // Freeze the stiffness at the deformed state, as the simulator does.
            let k = material.membrane().stiffness(&el.green_strain(&x));
            check(
                &x,
                1e-7,
                |y| el.derivatives(y, &k, Projection::Exact),
                &format!("membrane {} #{trial}", material.name()),
            );
            let psd = el.derivatives(&x, &k, Projection::Psd);
            assert!(
                is_psd(&psd.hessian),
                "projected membrane Hessian is not PSD"
            );
            assert_eq!(
                psd.gradient,
                el.derivatives(&x, &k, Projection::Exact).gradient
            );
        }
    }
    // In tension (S ⪰ 0, K ⪰ 0) the projection is exact.
    let (rest, _) = random_triangle(&mut r);
    let el = MembraneRest::new(&rest, &Vector3::x(), &Vector3::y()).expect("valid");
    let stretched = rest.map(|p| Vector3::new(1.1 * p.x, 1.05 * p.y, 0.0));
    let k = stvk.membrane().stiffness(&el.green_strain(&stretched));
    let exact = el.derivatives(&stretched, &k, Projection::Exact);
    let psd = el.derivatives(&stretched, &k, Projection::Psd);
    for a in 0..3 {
        for b in 0..3 {
            assert!((exact.hessian[a][b] - psd.hessian[a][b]).amax() < 1e-9 * k.k_uu);
        }
    }
    // The energy is the StVK formula.
    let g = el.green_strain(&stretched);
    let (lambda, mu) = (15.0, 25.0);
    let expect = el.area_m2 * (mu * (g.transpose() * g).trace() + 0.5 * lambda * g.trace().powi(2));
    assert!((exact.energy_j - expect).abs() < 1e-12 * expect.abs());
}

/// ARCSim's bending gradient (`physics.cpp` `bending_force`): `dθ/dx2 = n0/h0`,
/// `dθ/dx3 = n1/h1`, `dθ/dx0 = −(w00 n0/h0 + w10 n1/h1)`, `dθ/dx1 = −(w01 n0/h0 + w11 n1/h1)`,
/// with heights `h` and barycentric weights of the opposite vertices' projections on the edge.
fn arcsim_dtheta(x: &[Vector3<f64>; 4]) -> [Vector3<f64>; 4] {
    let (x0, x1, x2, x3) = (x[0], x[1], x[2], x[3]);
    let distance = |p: Vector3<f64>| {
        let e = x1 - x0;
        let along = e * e.dot(&(p - x0)) / e.dot(&e);
        ((p - x0) - along).norm()
    };
    let weights = |p: Vector3<f64>| {
        let e = x1 - x0;
        let t = e.dot(&(p - x0)) / e.dot(&e);
        (1.0 - t, t)
    };
    let n0 = (x1 - x0).cross(&(x2 - x0)).normalize();
    let n1 = (x0 - x1).cross(&(x3 - x1)).normalize();
    let (h0, h1) = (distance(x2), distance(x3));
    let (w0, w1) = (weights(x2), weights(x3));
    [
        -(n0 * (w0.0 / h0) + n1 * (w1.0 / h1)),
        -(n0 * (w0.1 / h0) + n1 * (w1.1 / h1)),
        n0 / h0,
        n1 / h1,
    ]
}

#[test]
fn bending_gradient_hessian_and_arcsim_gradient() {
    let mut r = rng(2);
    let model = BendingModel::Tabulated(BendingTable {
        ke: GRAY_INTERLOCK_BENDING,
    });
    for trial in 0..30 {
        let l = 0.01;
        let fold: f64 = r.random_range(-2.0..2.0);
        let x = [
            Vector3::zeros(),
            Vector3::new(l, 0.0, 0.0),
            Vector3::new(
                r.random_range(0.002..0.008),
                r.random_range(0.006..0.012),
                0.0,
            ),
            Vector3::new(
                r.random_range(0.002..0.008),
                -r.random_range(0.006..0.012) * fold.cos(),
                r.random_range(0.006..0.012) * fold.sin(),
            ),
        ];
        let rotation = Rotation3::new(random_vector(&mut r, 3.0));
        let x = x.map(|p| rotation * (p + random_vector(&mut r, 0.001)));
        let hinge = BendingRest {
            vertices: [0, 1, 2, 3],
            rest_angle_rad: r.random_range(-0.5..0.5),
            area_sum_m2: 1e-4,
            edge_angle_rad: [0.3, 0.3],
        };
        // The frozen coefficient is ARCSim's ke l² / (8 (A0 + A1)) (the energy is checked for any
        // fixed value; a negative-θ lookup may clamp ke to 0, so check with a fixed one).
        let l_now = (x[1] - x[0]).norm();
        let theta_now = dihedral_angle(&x);
        let ke = model.stiffness(theta_now, l_now, hinge.area_sum_m2, 0.3);
        let expect = ke * l_now * l_now / (8.0 * hinge.area_sum_m2);
        assert!((hinge.coefficient(&x, &model) - expect).abs() <= 1e-15);
        let c = 1e-3;
        check(
            &x,
            1e-7,
            |y| hinge.derivatives(y, c, BendingHessian::Exact),
            &format!("bending #{trial}"),
        );
        // ARCSim's Bridson-style gradient of θ equals ours: dE/dx = 2c (θ − θ̄) dθ/dx.
        let d = hinge.derivatives(&x, c, BendingHessian::Exact);
        let theta = dihedral_angle(&x);
        let factor = 2.0 * c * (theta - hinge.rest_angle_rad);
        let arcsim = arcsim_dtheta(&x);
        for a in 0..4 {
            let err = (d.gradient[a] - arcsim[a] * factor).norm();
            assert!(err <= 1e-8 * max_abs(&d.gradient), "vertex {a}: {err:.3e}");
        }
        let psd = hinge.derivatives(&x, c, BendingHessian::ProjectedExact);
        assert!(is_psd(&psd.hessian));
        let gn = hinge.derivatives(&x, c, BendingHessian::GaussNewton);
        assert!(is_psd(&gn.hessian));
        // Gauss–Newton: the exact gradient, and the Hessian 2c ∇θ ∇θᵀ with ARCSim's ∇θ.
        let gn_scale = max_abs_hessian(&gn.hessian);
        for a in 0..4 {
            let err = (gn.gradient[a] - d.gradient[a]).norm();
            assert!(
                err <= 1e-10 * max_abs(&d.gradient),
                "GN gradient {a}: {err:.3e}"
            );
            for b in 0..4 {
                let expected = arcsim[a] * arcsim[b].transpose() * (2.0 * c);
                let err = (gn.hessian[a][b] - expected).amax();
                assert!(err <= 1e-8 * gn_scale, "GN block ({a}, {b}): {err:.3e}");
                assert_eq!(gn.hessian[a][b], gn.hessian[b][a].transpose());
            }
        }
    }
    // The sign convention: folding x3 towards face A's normal side gives θ > 0.
    let x = [
        Vector3::zeros(),
        Vector3::x(),
        Vector3::new(0.5, 1.0, 0.0),
        Vector3::new(0.5, -1.0, 0.3),
    ];
    assert!(dihedral_angle(&x) > 0.0);
    let flat = [x[0], x[1], x[2], Vector3::new(0.5, -1.0, 0.0)];
    assert!(dihedral_angle(&flat).abs() < 1e-15);
}

#[test]
fn a_crushed_hinge_drops_out_of_bending() {
    // Face A (x0 x1 x2) flattened onto the shared edge: its height h, against a rest area sum
    // of 1e-4 m² (twice the area of face A is l·h).
    let hinge = BendingRest {
        vertices: [0, 1, 2, 3],
        rest_angle_rad: 0.0,
        area_sum_m2: 1e-4,
        edge_angle_rad: [0.0, 0.0],
    };
    let l = 0.01;
    let x = |h: f64| {
        [
            Vector3::zeros(),
            Vector3::new(l, 0.0, 0.0),
            Vector3::new(0.004, h, 0.2 * h),
            Vector3::new(0.005, -0.01, 0.003),
        ]
    };
    let twice_area = |h: f64| l * h * (1.0f64 + 0.04).sqrt();
    let limit = CRUSHED_AREA_FRACTION * hinge.area_sum_m2;
    let (crushed, open) = (0.5 * limit / twice_area(1.0), 2.0 * limit / twice_area(1.0));
    assert!(hinge.crushed(&x(crushed)) && !hinge.crushed(&x(open)));
    let c = 1e-3;
    for kind in [BendingHessian::GaussNewton, BendingHessian::ProjectedExact] {
        let d = hinge.derivatives(&x(crushed), c, kind);
        assert_eq!(d.energy_j, 0.0);
        assert!(d.gradient.iter().all(|g| *g == Vector3::zeros()));
        assert_eq!(max_abs_hessian(&d.hessian), 0.0);
        assert_eq!(hinge.energy(&x(crushed), c), 0.0);
        // Just above the limit the hinge bends as usual, with the derivatives checked.
        let d = hinge.derivatives(&x(open), c, kind);
        assert!(d.energy_j > 0.0 && max_abs_hessian(&d.hessian) > 0.0);
    }
    check(
        &x(open),
        1e-9,
        |y| hinge.derivatives(y, c, BendingHessian::Exact),
        "bending near the crushed limit",
    );
}

fn max_abs_hessian(h: &[[Matrix3<f64>; 4]; 4]) -> f64 {
    h.iter().flatten().map(|m| m.amax()).fold(0.0, f64::max)
}

#[test]
fn obstacle_contact_both_profiles() {
    let mut r = rng(3);
    for profile in [PenaltyProfile::Cubic, PenaltyProfile::Quadratic] {
        let penalty = Penalty {
            stiffness_n_per_m3: 1e6,
            thickness_m: 5e-3,
            profile,
        };
        for trial in 0..10 {
            let tilt = r.random_range(-0.6..0.6);
            let plane = Plane::tilted(Vector3::new(0.0, 0.1, 0.0), tilt);
            // A point 0.5–4.5 mm from the plane (inside the thickness, away from the kink at h).
            let depth: f64 = r.random_range(0.5e-3..4.5e-3);
            let x0 = plane.point()
                + plane.normal() * depth
                + random_vector(&mut r, 0.05).cross(&plane.normal());
            let area = 1.5e-4;
            let energy_at = |y: &[Vector3<f64>; 1]| {
                let c = plane.closest(y[0]).expect("a plane always answers");
                let contact = ObstacleContact {
                    vertex: 0,
                    collider: 0,
                    query_point: y[0],
                    distance_m: c.distance_m,
                    normal: c.normal,
                    velocity_m_per_s: c.velocity_m_per_s,
                    area_m2: area,
                };
                contact.derivatives(&y[0], &penalty)
            };
            check(
                &[x0],
                1e-8,
                energy_at,
                &format!("plane {profile:?} #{trial}"),
            );
        }
        // Sphere: the gradient is exact (∇d = n); the Hessian drops the curvature term.
        let sphere = Sphere::new(Vector3::zeros(), 0.1);
        let x0 = Vector3::new(0.03, 0.09, 0.02).normalize() * 0.103;
        let c = sphere.closest(x0).expect("answers");
        let contact = ObstacleContact {
            vertex: 0,
            collider: 0,
            query_point: x0,
            distance_m: c.distance_m,
            normal: c.normal,
            velocity_m_per_s: c.velocity_m_per_s,
            area_m2: 1e-4,
        };
        let g = contact.derivatives(&x0, &penalty).gradient[0];
        let eps = 1e-8;
        for k in 0..3 {
            let e = |s: f64| {
                let mut y = x0;
                y[k] += s;
                penalty
                    .evaluate(sphere.closest(y).expect("answers").distance_m, 1e-4)
                    .0
            };
            let fd = (e(eps) - e(-eps)) / (2.0 * eps);
            assert!(
                (fd - g[k]).abs() <= RELATIVE_TOLERANCE * g.amax(),
                "sphere gradient"
            );
        }
    }
}

#[test]
fn self_contact_both_profiles() {
    let mut r = rng(4);
    for profile in [PenaltyProfile::Cubic, PenaltyProfile::Quadratic] {
        let penalty = Penalty {
            stiffness_n_per_m3: 1e6,
            thickness_m: 5e-3,
            profile,
        };
        for trial in 0..20 {
            let (_, t) = random_triangle(&mut r);
            let n = (t[1] - t[0]).cross(&(t[2] - t[0])).normalize();
            let side = if r.random_bool(0.5) { 1.0 } else { -1.0 };
            let centroid = (t[0] + t[1] + t[2]) / 3.0;
            let p = centroid
                + n * (side * r.random_range(0.5e-3..4.5e-3))
                + random_vector(&mut r, 5e-4).cross(&n);
            let x = [p, t[0], t[1], t[2]];
            let contact = SelfContact {
                vertex: 0,
                triangle: [1, 2, 3],
                side,
                area_m2: 1e-4,
            };
            assert!(contact.distance(&x) > 0.0 && contact.distance(&x) < 5e-3);
            check(
                &x,
                1e-8,
                |y| contact.derivatives(y, &penalty, Projection::Exact),
                &format!("self contact {profile:?} #{trial}"),
            );
            assert!(is_psd(
                &contact.derivatives(&x, &penalty, Projection::Psd).hessian
            ));
        }
    }
}
