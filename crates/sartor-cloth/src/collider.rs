//! Obstacles the cloth collides with.
//!
//! A [`Collider`] answers one question: for a point, where is the closest point of the
//! obstacle's surface, on which side is the point, and how fast does the surface move there.
//! The simulator queries every cloth vertex against the obstacle's pose at the *end* of the
//! substep (the caller moves the obstacle before calling `step`), so a moving obstacle pushes the
//! cloth within the same substep; the surface velocity enters friction.

use nalgebra::Vector3;
use sartor_core::NearFaces;

/// The closest surface point of an obstacle to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Signed distance from the surface, m: positive outside, negative inside.
    pub distance_m: f64,
    /// Unit outward normal at the closest point (for a point outside, the direction from the
    /// surface to the point; inside, the pseudo-normal of the closest feature).
    pub normal: Vector3<f64>,
    /// Velocity of the surface at the closest point, m/s.
    pub velocity_m_per_s: Vector3<f64>,
}

/// An obstacle. Implementations must be usable from several threads (queries run in parallel).
///
/// [`crate::MeshCollider`] implements it for a deforming triangle mesh (a body) with sartor-core's
/// BVH closest-point query, whose inside/outside sign comes from angle-weighted pseudo-normals,
/// and the barycentric blend of the vertex velocities of the closest triangle.
pub trait Collider: Sync {
    /// The closest surface point to `p`, or `None` when the obstacle has nothing to say (e.g.
    /// outside its domain).
    fn closest(&self, p: Vector3<f64>) -> Option<Contact>;

    /// Like [`Collider::closest`], but may return `None` for points farther than
    /// `max_distance_m` outside the surface; implementations with an acceleration structure
    /// should override it to prune their search.
    fn closest_within(&self, p: Vector3<f64>, max_distance_m: f64) -> Option<Contact> {
        self.closest(p).filter(|c| c.distance_m <= max_distance_m)
    }

    /// [`Collider::closest_within`] with a hint the caller keeps per query point between
    /// calls (start it at `u32::MAX`; its meaning is the collider's). The answer must be the
    /// same as without the hint; only the work may differ. [`crate::MeshCollider`] keeps the
    /// point's last closest triangle in it, which bounds its tree search from the start.
    fn closest_within_hinted(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
    ) -> Option<Contact> {
        let _ = hint;
        self.closest_within(p, max_distance_m)
    }

    /// [`Collider::closest_within_hinted`] that also lists in `near` what the queries that
    /// follow at nearly the same point need: every feature within the answer's distance plus
    /// `margin_m` (see [`Collider::closest_within_near`]). The default lists nothing.
    fn closest_within_listing(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
        margin_m: f64,
        near: &mut NearFaces,
    ) -> Option<Contact> {
        let _ = margin_m;
        near.clear();
        self.closest_within_hinted(p, max_distance_m, hint)
    }

    /// The answer of [`Collider::closest_within_hinted`] from the features `near` listed by
    /// [`Collider::closest_within_listing`] (not empty). Exact while, since the listing, the
    /// point has moved by at most half the listing's margin relative to the obstacle: with a
    /// [`MotionBound`] read `(T₀, R₀)` at the listing and `(T, R)` now, while
    /// `|Δx − (T − T₀)| + (R − R₀)` is at most that.
    fn closest_within_near(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
        near: &NearFaces,
    ) -> Option<Contact> {
        let _ = near;
        self.closest_within_hinted(p, max_distance_m, hint)
    }

    /// A bound on the obstacle's motion, for callers that skip the queries of points known to
    /// be far from it (see [`MotionBound`]). `None` (the default): unknown, query always.
    fn motion_bound(&self) -> Option<MotionBound> {
        None
    }
}

/// How far an obstacle's surface has moved since it was made, as a translation and what the
/// translation leaves out: at every move, `translation_m` grows by a translation `T` of the
/// move's choosing and `travel_m` by at least the largest `|Δq − T|` over the points `q` of the
/// surface.
///
/// The distance from a point to the surface is 1-Lipschitz in the point and does not change
/// when point and surface translate together. So if a point was at distance `d` when the bound
/// read `(T₀, R₀)` and the point has since moved by `Δx`, it is now at least
/// `d − |Δx − (T − T₀)| − (R − R₀)` from the surface: a point that moves with the obstacle (a
/// shirt on a walking body) keeps its clearance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionBound {
    /// Names this obstacle: no other obstacle reports the same.
    pub identity: u64,
    /// The sum of the moves' translations, m.
    pub translation_m: Vector3<f64>,
    /// The sum of the moves' largest departures from their translation, m.
    pub travel_m: f64,
}

/// A plane (half-space below it is solid), optionally moving with a constant velocity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    point: Vector3<f64>,
    normal: Vector3<f64>,
    /// Surface velocity, m/s.
    pub velocity_m_per_s: Vector3<f64>,
}

impl Plane {
    /// A plane through `point` with outward normal `normal` (normalised here). `None` for a
    /// zero or non-finite normal.
    pub fn new(point: Vector3<f64>, normal: Vector3<f64>) -> Option<Self> {
        let normal = normal.try_normalize(1e-300)?;
        (point.iter().all(|v| v.is_finite()) && normal.iter().all(|v| v.is_finite())).then_some(
            Self {
                point,
                normal,
                velocity_m_per_s: Vector3::zeros(),
            },
        )
    }

    /// The floor `y = height_m` (normal +Y).
    pub fn horizontal(height_m: f64) -> Self {
        Self {
            point: Vector3::new(0.0, height_m, 0.0),
            normal: Vector3::y(),
            velocity_m_per_s: Vector3::zeros(),
        }
    }

    /// A plane through `point` tilted by `tilt_rad` about the +Z axis: the normal is +Y rotated
    /// towards −X, so the surface rises towards +X (`y = x · tan(tilt)`) and
    /// [`Plane::downhill`] points towards −X.
    pub fn tilted(point: Vector3<f64>, tilt_rad: f64) -> Self {
        Self {
            point,
            normal: Vector3::new(-tilt_rad.sin(), tilt_rad.cos(), 0.0),
            velocity_m_per_s: Vector3::zeros(),
        }
    }

    /// Unit outward normal.
    pub fn normal(&self) -> Vector3<f64> {
        self.normal
    }

    /// A point on the plane.
    pub fn point(&self) -> Vector3<f64> {
        self.point
    }

    /// Move the plane to pass through `point`.
    pub fn set_point(&mut self, point: Vector3<f64>) {
        self.point = point;
    }

    /// The unit in-plane direction of steepest descent under gravity (−Y); zero for a
    /// horizontal plane.
    pub fn downhill(&self) -> Vector3<f64> {
        let g = -Vector3::y();
        let t = g - self.normal * g.dot(&self.normal);
        t.try_normalize(1e-12).unwrap_or_else(Vector3::zeros)
    }
}

impl Collider for Plane {
    fn closest(&self, p: Vector3<f64>) -> Option<Contact> {
        Some(Contact {
            distance_m: (p - self.point).dot(&self.normal),
            normal: self.normal,
            velocity_m_per_s: self.velocity_m_per_s,
        })
    }
}

/// A solid sphere, optionally moving with a constant velocity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre, m.
    pub center: Vector3<f64>,
    /// Radius, m.
    pub radius_m: f64,
    /// Velocity of the centre, m/s.
    pub velocity_m_per_s: Vector3<f64>,
}

impl Sphere {
    /// A resting sphere.
    pub fn new(center: Vector3<f64>, radius_m: f64) -> Self {
        Self {
            center,
            radius_m,
            velocity_m_per_s: Vector3::zeros(),
        }
    }
}

impl Collider for Sphere {
    fn closest(&self, p: Vector3<f64>) -> Option<Contact> {
        let r = p - self.center;
        let len = r.norm();
        // At the centre any direction is closest: pick +Y.
        let normal = if len > 0.0 { r / len } else { Vector3::y() };
        Some(Contact {
            distance_m: len - self.radius_m,
            normal,
            velocity_m_per_s: self.velocity_m_per_s,
        })
    }
}
