//! The collision post-process of Santesteban et al. 2019: a cloth vertex inside the body, or
//! closer to it than a margin (2 mm in the paper), is pushed along the normal of the closest
//! body primitive until it lies at the margin: `p ← p + (margin − d) n`, with `d` the signed
//! distance and `n` the angle-weighted pseudo-normal of the closest face, edge or vertex
//! ([`sartor_body::MeshProximity`], the one closest-point query of the workspace).
//!
//! Only the body region the garment can touch is used ([`BodyRegion`]): its vertices are the
//! only body vertices skinned per frame, and the query structure is built over its faces only.
//!
//! # Two ways to find the closest body primitive ([`CollisionQuery`])
//!
//! - [`CollisionQuery::Bvh`]: a bounding-volume hierarchy over the region, refitted every frame;
//!   exact (the true closest point of the region).
//! - [`CollisionQuery::Candidates`]: when the shape is set, each cloth vertex (at `T̄_c + Δ_G`)
//!   keeps the region faces within `radius_m` of it on the shaped body `T_b(β)` in rest pose,
//!   at most `max_per_vertex` of them, nearest first; per frame only those are tested. Cloth and
//!   body share their skinning, so the faces near a vertex at rest stay near it in every pose;
//!   the answer can differ from the BVH's only when a vertex moves more than about `radius_m`
//!   relative to the body (large wrinkles), or when more than `max_per_vertex` faces lie within
//!   the radius. A vertex with no face within the radius is never tested. The `bench runtime`
//!   command measures speed and misses against the BVH (see ARCHITECTURE.md for the numbers).

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_body::{BodyModel, BoneTransform, MeshProximity, Par, SkinWeights, skin_points};

use crate::error::{Error, Result};

/// Distance kept between cloth and body, metres: the paper's 2 mm.
pub const DEFAULT_MARGIN_M: f64 = 0.002;

/// How the closest body primitive of each cloth vertex is found (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CollisionQuery {
    /// A BVH over the body region, refitted per frame: exact.
    Bvh,
    /// Per cloth vertex, the region faces near it at rest (chosen when the shape is set).
    Candidates {
        /// Faces within this distance of the vertex at rest are candidates, metres.
        radius_m: f64,
        /// At most this many candidates per vertex, nearest first.
        max_per_vertex: usize,
    },
}

impl CollisionQuery {
    /// The candidate strategy with the defaults the runtime benchmark settled on: faces within
    /// 2 cm, at most 8 per vertex.
    pub const DEFAULT_CANDIDATES: Self = Self::Candidates {
        radius_m: 0.02,
        max_per_vertex: 8,
    };
}

/// Options of the collision post-process.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionOptions {
    /// Cloth vertices closer to the body than this (or inside it) are pushed out to it, metres.
    pub margin_m: f64,
    /// How the closest body primitive is found.
    pub query: CollisionQuery,
    /// Passes (the paper makes one). A vertex pushed out of one body part can land in another
    /// where two parts nearly touch or interpenetrate (armpit, between the legs); each further
    /// pass re-checks only the vertices the previous pass moved. A vertex squeezed between two
    /// parts closer than twice the margin has no valid place and may stay inside one of them.
    /// `0` poses the region but pushes nothing: for reports that count collisions before the
    /// post-process ([`crate::GarmentAnimator::collision_count`]).
    pub passes: usize,
}

impl Default for CollisionOptions {
    /// 2 mm, the default query, 2 passes.
    fn default() -> Self {
        Self {
            margin_m: DEFAULT_MARGIN_M,
            query: CollisionQuery::DEFAULT_CANDIDATES,
            passes: 2,
        }
    }
}

impl CollisionOptions {
    pub(crate) fn validate(&self) -> Result<()> {
        if !(self.margin_m.is_finite() && self.margin_m >= 0.0) {
            return Err(Error::invalid(
                "collision options",
                format!("margin must be finite and ≥ 0, got {}", self.margin_m),
            ));
        }
        if let CollisionQuery::Candidates {
            radius_m,
            max_per_vertex,
        } = self.query
            && !(radius_m.is_finite() && radius_m > 0.0 && max_per_vertex > 0)
        {
            return Err(Error::invalid(
                "collision options",
                format!(
                    "candidates need a finite positive radius and at least one face per vertex, \
                     got {radius_m} m and {max_per_vertex}"
                ),
            ));
        }
        Ok(())
    }
}

/// The body region a garment can touch, as a mesh of its own: the body vertices its faces use
/// (ascending), the faces re-indexed into them, and those vertices' skin weights.
#[derive(Clone, Debug)]
pub struct BodyRegion {
    vertices: Vec<u32>,
    faces: Vec<[u32; 3]>,
    skin_weights: SkinWeights,
}

impl BodyRegion {
    /// Extract `region_faces` (indices into the body's faces) from `body`.
    pub fn new(body: &BodyModel, region_faces: &[u32]) -> Result<Self> {
        let body_faces = body.faces();
        let mut index = vec![u32::MAX; body.n_vertices()];
        let mut vertices = Vec::new();
        for &f in region_faces {
            let t = body_faces.get(f as usize).ok_or_else(|| {
                Error::invalid(
                    "body region",
                    format!("face {f} is past the body's {} faces", body_faces.len()),
                )
            })?;
            for &v in t {
                index[v as usize] = 0;
            }
        }
        for (v, slot) in index.iter_mut().enumerate() {
            if *slot == 0 {
                *slot = vertices.len() as u32;
                vertices.push(v as u32);
            }
        }
        let faces = region_faces
            .iter()
            .map(|&f| body_faces[f as usize].map(|v| index[v as usize]))
            .collect();
        let (offsets, joints, weights) = body.skin_weights().csr();
        let mut sub_offsets = Vec::with_capacity(vertices.len() + 1);
        sub_offsets.push(0u32);
        let (mut sub_joints, mut sub_weights) = (Vec::new(), Vec::new());
        for &v in &vertices {
            let (a, b) = (
                offsets[v as usize] as usize,
                offsets[v as usize + 1] as usize,
            );
            sub_joints.extend_from_slice(&joints[a..b]);
            sub_weights.extend_from_slice(&weights[a..b]);
            sub_offsets.push(sub_joints.len() as u32);
        }
        let skin_weights = SkinWeights::new(
            sub_offsets,
            sub_joints,
            sub_weights,
            body.skin_weights().n_joints(),
        )?;
        Ok(Self {
            vertices,
            faces,
            skin_weights,
        })
    }

    /// Body vertex index of each region vertex, ascending.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// Region faces, indexing [`BodyRegion::vertices`].
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
}

/// Per-avatar collision state: the region at the avatar's shape, its posed copy and the query
/// structure (and the candidate lists, for [`CollisionQuery::Candidates`]).
#[derive(Clone, Debug)]
pub(crate) struct Collider {
    margin_m: f64,
    passes: usize,
    /// Per cloth vertex: moved by the current pass.
    moved: Vec<bool>,
    rest: Vec<Vector3<f64>>,
    posed: Vec<Vector3<f64>>,
    proximity: MeshProximity,
    /// CSR candidate faces per cloth vertex (empty for the BVH query).
    offsets: Vec<u32>,
    candidates: Vec<u32>,
}

/// Cloth vertices per parallel task.
const CHUNK: usize = 256;

impl Collider {
    /// Set up for a body of shape `shaped_body` (`T_b(β)`, every body vertex) and a garment whose
    /// unposed rest shape is `cloth_rest` (`T̄_c + Δ_G`).
    pub(crate) fn new(
        region: &BodyRegion,
        shaped_body: &[Vector3<f64>],
        cloth_rest: &[Vector3<f32>],
        options: &CollisionOptions,
    ) -> Result<Self> {
        let rest: Vec<Vector3<f64>> = region
            .vertices
            .iter()
            .map(|&v| shaped_body[v as usize])
            .collect();
        let proximity = MeshProximity::new(&rest, &region.faces)?;
        let (mut offsets, mut candidates) = (Vec::new(), Vec::new());
        if let CollisionQuery::Candidates {
            radius_m,
            max_per_vertex,
        } = options.query
        {
            offsets.reserve(cloth_rest.len() + 1);
            offsets.push(0u32);
            for p in cloth_rest {
                let near = proximity.faces_within(&p.cast::<f64>(), radius_m);
                candidates.extend(near.iter().take(max_per_vertex).map(|&(f, _)| f));
                offsets.push(candidates.len() as u32);
            }
        }
        Ok(Self {
            margin_m: options.margin_m,
            passes: options.passes,
            moved: vec![false; cloth_rest.len()],
            posed: rest.clone(),
            rest,
            proximity,
            offsets,
            candidates,
        })
    }

    /// The margin, metres.
    pub(crate) fn margin_m(&self) -> f64 {
        self.margin_m
    }

    /// Candidate faces per cloth vertex on average (0 for the BVH query).
    pub(crate) fn mean_candidates(&self) -> f64 {
        if self.offsets.len() < 2 {
            return 0.0;
        }
        self.candidates.len() as f64 / (self.offsets.len() - 1) as f64
    }

    /// Pose the region with the body's skinning transforms and refit the query structure.
    /// Allocation-free.
    pub(crate) fn pose(
        &mut self,
        region: &BodyRegion,
        transforms: &[BoneTransform<f64>],
        par: Par,
    ) -> Result<()> {
        skin_points(
            &self.rest,
            &region.skin_weights,
            transforms,
            &mut self.posed,
            par,
        )?;
        self.proximity.update_positions(&self.posed)?;
        Ok(())
    }

    /// The region as posed by the last [`Collider::pose`].
    pub(crate) fn posed(&self) -> &[Vector3<f64>] {
        &self.posed
    }

    /// Push every cloth vertex closer than the margin (or inside) out to the margin along the
    /// closest primitive's normal, in up to `passes` passes; returns the number of pushes (a
    /// vertex moved in two passes counts twice).
    /// Allocation-free.
    pub(crate) fn resolve(&mut self, cloth: &mut [Vector3<f32>], par: Par) -> usize {
        let mut total = 0;
        for pass in 0..self.passes {
            let moved = self.pass(pass == 0, cloth, par);
            total += moved;
            if moved == 0 {
                break;
            }
        }
        total
    }

    /// One pass over every vertex (`first`) or over those the previous pass moved; updates the
    /// flags and returns how many moved.
    fn pass(&mut self, first: bool, cloth: &mut [Vector3<f32>], par: Par) -> usize {
        let mut moved = std::mem::take(&mut self.moved);
        let this = &*self;
        let task = |start: usize, chunk: &mut [Vector3<f32>], flags: &mut [bool]| -> usize {
            let mut pushed = 0;
            for (k, (p, flag)) in chunk.iter_mut().zip(flags.iter_mut()).enumerate() {
                if !(first || *flag) {
                    continue;
                }
                *flag = false;
                let q = p.cast::<f64>();
                let hit = if this.offsets.is_empty() {
                    this.proximity.closest_within(&q, f64::INFINITY)
                } else {
                    let i = start + k;
                    let (a, b) = (this.offsets[i] as usize, this.offsets[i + 1] as usize);
                    this.proximity.closest_among(&q, &this.candidates[a..b])
                };
                if let Some(c) = hit
                    && c.signed_distance_m < this.margin_m
                {
                    *p = (q + c.normal * (this.margin_m - c.signed_distance_m)).cast::<f32>();
                    *flag = true;
                    pushed += 1;
                }
            }
            pushed
        };
        let count = match par {
            Par::Seq => task(0, cloth, &mut moved),
            Par::Rayon => cloth
                .par_chunks_mut(CHUNK)
                .zip(moved.par_chunks_mut(CHUNK))
                .enumerate()
                .map(|(c, (chunk, flags))| task(c * CHUNK, chunk, flags))
                .sum(),
        };
        self.moved = moved;
        count
    }

    /// The closest region point to `p` by the exact (tree) query: signed distance and face.
    pub(crate) fn exact(&self, p: &Vector3<f32>) -> sartor_body::ClosestPoint {
        self.proximity.closest(&p.cast::<f64>())
    }
}
