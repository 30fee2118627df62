//! A deforming triangle-mesh obstacle (a body), on sartor-core's closest-point query.

use nalgebra::Vector3;
use sartor_core::{ClosestPoint, MeshProximity, NearFaces};

use crate::collider::{Collider, Contact, MotionBound};
use crate::{Error, Result};

/// A triangle-mesh obstacle, typically the posed body. Closest points and the inside/outside
/// sign come from [`MeshProximity`] (BVH, angle-weighted pseudo-normals: the mesh must be closed
/// and outward-oriented for "inside" to mean anything); the surface velocity at the closest
/// point is the barycentric blend of per-vertex velocities.
///
/// For a moving body, call [`MeshCollider::move_to`] with the pose at the *end* of the next
/// substep before each `Simulator::step`: it refits the tree and sets the vertex velocities to
/// `(new − old) / dt`. A body that moves linearly through several substeps (a frame's poses
/// interpolated) can instead be given the move once ([`MeshCollider::set_span`]) and moved along
/// it ([`MeshCollider::move_on_span`]): the boxes are interpolated instead of refitted, with the
/// same answers and velocities.
#[derive(Debug)]
pub struct MeshCollider {
    proximity: MeshProximity,
    velocities: Vec<Vector3<f64>>,
    search_depth_m: f64,
    /// This collider's identity for [`Collider::motion_bound`] (a clone gets a new one).
    identity: u64,
    /// The sum over every move of the mean vertex displacement, m.
    translation_m: Vector3<f64>,
    /// The sum over every move of the largest vertex displacement from the mean, m.
    travel_m: f64,
    /// The start and the end of the linear move set by [`MeshCollider::set_span`] (empty
    /// before), and the positions of the last point on it.
    span: [Vec<Vector3<f64>>; 2],
    on_span: Vec<Vector3<f64>>,
}

/// Identities of mesh colliders, unique within the process.
static NEXT_IDENTITY: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

fn new_identity() -> u64 {
    NEXT_IDENTITY.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

impl Clone for MeshCollider {
    fn clone(&self) -> Self {
        Self {
            proximity: self.proximity.clone(),
            velocities: self.velocities.clone(),
            search_depth_m: self.search_depth_m,
            identity: new_identity(),
            translation_m: self.translation_m,
            travel_m: self.travel_m,
            span: self.span.clone(),
            on_span: self.on_span.clone(),
        }
    }
}

impl MeshCollider {
    /// A resting mesh obstacle. `search_depth_m` bounds how deep inside a cloth vertex is still
    /// found (deeper vertices are ignored by contacts and the projection fallback); 5 cm is a
    /// sensible value for bodies.
    pub fn new(
        positions: &[Vector3<f64>],
        faces: &[[u32; 3]],
        search_depth_m: f64,
    ) -> Result<Self> {
        if !(search_depth_m.is_finite() && search_depth_m >= 0.0) {
            return Err(Error::invalid(
                "mesh collider",
                format!("search depth must be finite and ≥ 0, got {search_depth_m}"),
            ));
        }
        Ok(Self {
            proximity: MeshProximity::new(positions, faces)?,
            velocities: vec![Vector3::zeros(); positions.len()],
            search_depth_m,
            identity: new_identity(),
            translation_m: Vector3::zeros(),
            travel_m: 0.0,
            span: [Vec::new(), Vec::new()],
            on_span: Vec::new(),
        })
    }

    /// Move the mesh to `positions` over `dt_secs` (velocities `(new − old) / dt`).
    pub fn move_to(&mut self, positions: &[Vector3<f64>], dt_secs: f64) -> Result<()> {
        self.record_move(positions, dt_secs)?;
        // Normals with each answer: a substep asks about a few thousand cloth vertices, and the
        // body region has about ten thousand triangles.
        self.proximity.update_positions_refit(positions)?;
        Ok(())
    }

    /// Move the mesh to `start` over `dt_secs`, as [`Self::move_to`], and begin a linear move
    /// from `start` to `end` that [`Self::move_on_span`] follows: the tree's boxes are fitted
    /// at both ends once, and interpolated at each point of the way instead of refitted (the
    /// same answers to every query; see `MeshProximity::set_span`). A frame of a simulation
    /// moves the body this way through its substeps.
    pub fn set_span(
        &mut self,
        start: &[Vector3<f64>],
        end: &[Vector3<f64>],
        dt_secs: f64,
    ) -> Result<()> {
        if end.len() != start.len() {
            return Err(Error::invalid(
                "mesh collider",
                format!("a span from {} to {} positions", start.len(), end.len()),
            ));
        }
        self.record_move(start, dt_secs)?;
        self.proximity.set_span(start, end)?;
        for (kept, given) in self.span.iter_mut().zip([start, end]) {
            kept.clear();
            kept.extend_from_slice(given);
        }
        Ok(())
    }

    /// Move the mesh over `dt_secs` to `start + (end − start) · a` of the last
    /// [`Self::set_span`] (`end` itself at `a = 1`), `a` in `[0, 1]`; velocities as
    /// [`Self::move_to`].
    pub fn move_on_span(&mut self, a: f64, dt_secs: f64) -> Result<()> {
        let [start, end] = &self.span;
        if start.is_empty() {
            return Err(Error::invalid(
                "mesh collider",
                "a move on a span before set_span",
            ));
        }
        let mut next = std::mem::take(&mut self.on_span);
        next.clear();
        if a == 1.0 {
            next.extend_from_slice(end);
        } else {
            next.extend(start.iter().zip(end).map(|(p, q)| p + (q - p) * a));
        }
        let moved = self.record_move(&next, dt_secs).and_then(|()| {
            self.proximity
                .update_positions_on_span(&next, a)
                .map_err(Error::from)
        });
        self.on_span = next;
        moved
    }

    /// The velocities `(new − old) / dt` of a move to `positions`, and the move's share of
    /// the motion bound; the mesh itself is moved by the caller.
    fn record_move(&mut self, positions: &[Vector3<f64>], dt_secs: f64) -> Result<()> {
        if !(dt_secs.is_finite() && dt_secs > 0.0) {
            return Err(Error::invalid(
                "mesh collider",
                format!("time step must be finite and positive, got {dt_secs}"),
            ));
        }
        if positions.len() != self.velocities.len() {
            return Err(Error::invalid(
                "mesh collider",
                format!(
                    "{} positions for {} vertices",
                    positions.len(),
                    self.velocities.len()
                ),
            ));
        }
        let mut mean = Vector3::zeros();
        for ((v, new), old) in self
            .velocities
            .iter_mut()
            .zip(positions)
            .zip(self.proximity.positions())
        {
            let step = new - old;
            mean += step;
            *v = step / dt_secs;
        }
        mean /= positions.len().max(1) as f64;
        let largest2 = positions
            .iter()
            .zip(self.proximity.positions())
            .map(|(new, old)| (new - old - mean).norm_squared())
            .fold(0.0, f64::max);
        // A point of a triangle moves by a convex combination of its vertices' moves, so it
        // departs from the mean move by at most the largest vertex departure (with a margin
        // for rounding).
        self.translation_m += mean;
        self.travel_m += largest2.sqrt() * (1.0 + 1e-9) + 1e-12;
        Ok(())
    }

    /// The vertex positions.
    pub fn positions(&self) -> &[Vector3<f64>] {
        self.proximity.positions()
    }

    /// The vertex velocities, m/s.
    pub fn velocities(&self) -> &[Vector3<f64>] {
        &self.velocities
    }

    /// How far the tree search of a query with `max_distance_m` reaches: deep enough inside.
    fn search_radius(&self, max_distance_m: f64) -> f64 {
        max_distance_m.max(0.0).max(self.search_depth_m)
    }

    fn contact(&self, p: Vector3<f64>, max_distance_m: f64, hint: &mut u32) -> Option<Contact> {
        let radius = self.search_radius(max_distance_m);
        let c = self.proximity.closest_within_hinted(&p, radius, hint)?;
        self.to_contact(p, max_distance_m, c)
    }

    /// The contact of the query answer `c` at `p` (`None` beyond `max_distance_m` outside).
    fn to_contact(&self, p: Vector3<f64>, max_distance_m: f64, c: ClosestPoint) -> Option<Contact> {
        if c.signed_distance_m > max_distance_m {
            return None;
        }
        // The distance gradient: away from the surface outside, towards it inside; the
        // pseudo-normal on (or extremely near) the surface.
        let offset = p - c.point;
        let normal = if offset.norm() > 1e-9 {
            offset.normalize() * c.signed_distance_m.signum()
        } else {
            c.normal
        };
        let face = self.proximity.faces()[c.face as usize];
        let velocity = (0..3)
            .map(|k| self.velocities[face[k] as usize] * c.barycentric[k])
            .sum();
        Some(Contact {
            distance_m: c.signed_distance_m,
            normal,
            velocity_m_per_s: velocity,
        })
    }
}

/// The hint of a query without one.
const NO_HINT: u32 = u32::MAX;

impl Collider for MeshCollider {
    fn closest(&self, p: Vector3<f64>) -> Option<Contact> {
        let mut hint = NO_HINT;
        self.contact(p, f64::INFINITY, &mut hint)
    }

    fn closest_within(&self, p: Vector3<f64>, max_distance_m: f64) -> Option<Contact> {
        let mut hint = NO_HINT;
        self.contact(p, max_distance_m, &mut hint)
    }

    fn closest_within_hinted(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
    ) -> Option<Contact> {
        self.contact(p, max_distance_m, hint)
    }

    fn closest_within_listing(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
        margin_m: f64,
        near: &mut NearFaces,
    ) -> Option<Contact> {
        let radius = self.search_radius(max_distance_m);
        let c = (self.proximity).closest_within_listing(&p, radius, hint, margin_m, near)?;
        self.to_contact(p, max_distance_m, c)
    }

    fn closest_within_near(
        &self,
        p: Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
        near: &NearFaces,
    ) -> Option<Contact> {
        let radius = self.search_radius(max_distance_m);
        let c = (self.proximity).closest_within_near(&p, radius, hint, near)?;
        self.to_contact(p, max_distance_m, c)
    }

    fn motion_bound(&self) -> Option<MotionBound> {
        Some(MotionBound {
            identity: self.identity,
            translation_m: self.translation_m,
            travel_m: self.travel_m,
        })
    }
}
