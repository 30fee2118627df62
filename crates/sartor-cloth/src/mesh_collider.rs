//! A deforming triangle-mesh obstacle (a body), on sartor-core's closest-point query.

use nalgebra::Vector3;
use sartor_core::MeshProximity;

use crate::collider::{Collider, Contact};
use crate::{Error, Result};

/// A triangle-mesh obstacle, typically the posed body. Closest points and the inside/outside
/// sign come from [`MeshProximity`] (BVH, angle-weighted pseudo-normals: the mesh must be closed
/// and outward-oriented for "inside" to mean anything); the surface velocity at the closest
/// point is the barycentric blend of per-vertex velocities.
///
/// For a moving body, call [`MeshCollider::move_to`] with the pose at the *end* of the next
/// substep before each `Simulator::step`: it refits the tree and sets the vertex velocities to
/// `(new − old) / dt`.
#[derive(Clone, Debug)]
pub struct MeshCollider {
    proximity: MeshProximity,
    velocities: Vec<Vector3<f64>>,
    search_depth_m: f64,
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
        })
    }

    /// Move the mesh to `positions` over `dt_secs` (velocities `(new − old) / dt`).
    pub fn move_to(&mut self, positions: &[Vector3<f64>], dt_secs: f64) -> Result<()> {
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
        for ((v, new), old) in self
            .velocities
            .iter_mut()
            .zip(positions)
            .zip(self.proximity.positions())
        {
            *v = (new - old) / dt_secs;
        }
        self.proximity.update_positions(positions)?;
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

    fn contact(&self, p: Vector3<f64>, max_distance_m: f64) -> Option<Contact> {
        let radius = max_distance_m.max(0.0).max(self.search_depth_m);
        let c = self.proximity.closest_within(&p, radius)?;
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

impl Collider for MeshCollider {
    fn closest(&self, p: Vector3<f64>) -> Option<Contact> {
        self.contact(p, f64::INFINITY)
    }

    fn closest_within(&self, p: Vector3<f64>, max_distance_m: f64) -> Option<Contact> {
        self.contact(p, max_distance_m)
    }
}
