//! The signed distance of a point (a cloth vertex) to the posed body: **the** collision measure
//! of sartor. The simulator's end-of-frame check, the runtime post-process's tests and the
//! evaluation's collision counts all use [`BodyDistance`].
//!
//! # Why not the pseudo-normal sign
//!
//! [`MeshProximity`] signs its distance with the angle-weighted pseudo-normal of the closest
//! feature. That is exact for a closed, manifold, outward-oriented mesh without
//! self-intersections, and none of the three holds where it matters:
//!
//! - a body *region* (the triangles near the garment) is open: behind its cut edges the closest
//!   feature is a boundary edge or vertex whose pseudo-normal points sideways, and a point
//!   outside the body can read as inside (or the reverse);
//! - posed bodies intersect themselves where parts press together (the arm sunk into the
//!   torso at the armpit, the thighs): a point inside the torso whose closest surface is the
//!   arm's (itself inside the torso) reads as outside, and a point between two parts that meet
//!   in a crease may take the sign of the wrong one;
//! - the body mesh itself may have small holes.
//!
//! # What is used instead
//!
//! - **Inside**: the generalized winding number of the whole posed body at the point
//!   (Jacobson et al. 2013), `w(p) = Σ_t Ω_t(p) / 4π` with `Ω_t` the signed solid angle of
//!   triangle `t`: 1 inside a closed outward-oriented surface, 0 outside, 2 where two closed
//!   parts overlap, and a smooth value near a hole that is far from 0.5 away from it. A point is
//!   inside when `w > 0.5`. It is evaluated on a bounding-volume tree with the far-field dipole
//!   approximation of each cluster (Barill et al. 2018): exact solid angles near the point,
//!   one dipole per distant cluster (accuracy `|Δw| < 0.02`, tested against the exact sum).
//!   A query first counts the crossings of rays ([`BodyDistance::winding_number_fast`]): on a
//!   closed body one ray's count is the winding number; on an open one two rays that agree
//!   give it, and only where they disagree is the sum evaluated. The rays walk the
//!   closest-point query's eight-wide tree of f32 boxes, padded by their rounding, and the
//!   dipole clusters are fitted to a pose only when a point of it needs the sum (half the poses
//!   of the arm clearance's runs).
//! - **Distance**: the exact distance to the closest point of the whole body ([`MeshProximity`]),
//!   with the sign of the inside test. Inside an overlap of two parts this is the distance to
//!   the nearest surface of either (a lower bound of the depth).
//!
//! The region a garment can reach is only a speed-up for callers that need the closest point
//! often (the simulator's contacts, the runtime's post-process); here the whole body is used,
//! so the answer does not depend on any region. One query costs a few microseconds (both trees
//! are logarithmic in the body's size).

use std::sync::{Mutex, OnceLock};

use nalgebra::Vector3;

use crate::Result;
use crate::proximity::{ClosestPoint, MeshProximity};
use crate::tree::MedianTree;

/// Clusters farther than this many times their radius use their dipole (Barill et al.'s β).
const FAR_FIELD_RATIO: f64 = 2.5;
/// Triangles per leaf of the winding-number tree.
const LEAF_SIZE: usize = 8;

/// The answer of [`BodyDistance::query`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyPoint {
    /// Distance to the body surface, negative inside the body (by the winding number), m.
    pub signed_distance_m: f64,
    /// The generalized winding number of the body at the point (≈ 0 outside, ≈ 1 inside, ≈ 2
    /// inside two overlapping parts).
    pub winding_number: f64,
    /// The closest point of the body surface (its pseudo-normal sign is *not* used).
    pub closest: ClosestPoint,
}

impl BodyPoint {
    /// Whether the point is inside the body.
    pub fn inside(&self) -> bool {
        self.signed_distance_m < 0.0
    }
}

#[derive(Clone, Copy, Debug)]
struct Cluster {
    /// Σ over the cluster's triangles of `½ (b − a) × (c − a)` (area × unit normal), m².
    dipole: Vector3<f64>,
    /// Area-weighted centroid, m.
    center: Vector3<f64>,
    /// Every vertex of the cluster is within this distance of `center`, m.
    radius_m: f64,
    /// Total area, m².
    area_m2: f64,
    /// Axis-aligned bounds of the cluster's vertices, m.
    lo: Vector3<f64>,
    hi: Vector3<f64>,
}

/// Signed distance to a posed body (see the [module docs](self)): build once per body mesh,
/// [`BodyDistance::update_positions`] per pose, then [`BodyDistance::query`] per point
/// (`&self`: queries may run on several threads).
#[derive(Debug)]
pub struct BodyDistance {
    proximity: MeshProximity,
    /// Every edge is shared by at least two triangles (no boundary).
    closed: bool,
    /// The vertices of the faces, each once.
    vertices: Vec<u32>,
    /// The box of those vertices as last posed.
    bounds: (Vector3<f64>, Vector3<f64>),
    /// The hierarchy over the faces, and each node's cluster (indexed like its nodes).
    tree: MedianTree,
    /// Per node, the vertices of a leaf's faces, each once (CSR over the nodes; none for an
    /// inner node): a leaf's radius and box read each vertex once, not once per face.
    leaf_vertex_offsets: Vec<u32>,
    leaf_vertices: Vec<u32>,
    /// Fitted to the current positions when the hierarchical winding number first needs them
    /// after a move ([`BodyDistance::clusters`]): the rays answer most points without them, and
    /// their refit was some 16 % of the arm clearance's time.
    clusters: OnceLock<Vec<Cluster>>,
    /// The storage of the last fit, for the next (no allocation once warm).
    spare: Mutex<Vec<Cluster>>,
}

impl Clone for BodyDistance {
    fn clone(&self) -> Self {
        Self {
            proximity: self.proximity.clone(),
            closed: self.closed,
            vertices: self.vertices.clone(),
            bounds: self.bounds,
            tree: self.tree.clone(),
            leaf_vertex_offsets: self.leaf_vertex_offsets.clone(),
            leaf_vertices: self.leaf_vertices.clone(),
            clusters: self.clusters.clone(),
            spare: Mutex::default(),
        }
    }
}

impl BodyDistance {
    /// Over the whole body: every face of `faces` (indices into `positions`).
    pub fn new(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Result<Self> {
        let proximity = MeshProximity::new(positions, faces)?;
        let centroids: Vec<Vector3<f64>> = faces
            .iter()
            .map(|t| {
                t.iter()
                    .map(|&v| positions[v as usize])
                    .sum::<Vector3<f64>>()
                    / 3.0
            })
            .collect();
        let closed = crate::MeshTopology::new(positions.len(), faces)
            .edge_faces
            .iter()
            .all(|f| f.len() >= 2);
        let tree = MedianTree::new(&centroids, LEAF_SIZE);
        let mut leaf_vertex_offsets = vec![0u32];
        let mut leaf_vertices = Vec::new();
        for node in tree.nodes() {
            if node.is_leaf() {
                let mut leaf: Vec<u32> = tree
                    .leaf_items(node)
                    .iter()
                    .flat_map(|&f| faces[f as usize])
                    .collect();
                leaf.sort_unstable();
                leaf.dedup();
                leaf_vertices.extend(leaf);
            }
            leaf_vertex_offsets.push(leaf_vertices.len() as u32);
        }
        let mut vertices: Vec<u32> = faces.iter().flatten().copied().collect();
        vertices.sort_unstable();
        vertices.dedup();
        let mut s = Self {
            proximity,
            closed,
            vertices,
            bounds: (Vector3::zeros(), Vector3::zeros()),
            tree,
            leaf_vertex_offsets,
            leaf_vertices,
            clusters: OnceLock::new(),
            spare: Mutex::default(),
        };
        s.refit();
        Ok(s)
    }

    /// After a move: the box anew, the clusters left to be fitted when needed.
    fn refit(&mut self) {
        let positions = self.proximity.positions();
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for &v in &self.vertices {
            lo = lo.inf(&positions[v as usize]);
            hi = hi.sup(&positions[v as usize]);
        }
        self.bounds = (lo, hi);
        if let Some(clusters) = self.clusters.take() {
            *self.spare.get_mut().unwrap_or_else(|e| e.into_inner()) = clusters;
        }
    }

    /// Every node's cluster at the current positions, fitted on first use after a move.
    fn clusters(&self) -> &[Cluster] {
        self.clusters.get_or_init(|| {
            let mut clusters =
                std::mem::take(&mut *self.spare.lock().unwrap_or_else(|e| e.into_inner()));
            self.fit_clusters(&mut clusters);
            clusters
        })
    }

    /// Every cluster's dipole, center, radius and box from the current positions into
    /// `clusters` (children before parents).
    fn fit_clusters(&self, clusters: &mut Vec<Cluster>) {
        let empty = Cluster {
            dipole: Vector3::zeros(),
            center: Vector3::zeros(),
            radius_m: 0.0,
            area_m2: 0.0,
            lo: Vector3::zeros(),
            hi: Vector3::zeros(),
        };
        clusters.clear();
        clusters.resize(self.tree.nodes().len(), empty);
        let positions = self.proximity.positions();
        let faces = self.proximity.faces();
        for id in (0..clusters.len()).rev() {
            let node = self.tree.nodes()[id];
            let (dipole, center, area, radius, lo, hi) = if node.is_leaf() {
                let tris = self.tree.leaf_items(&node);
                let mut dipole = Vector3::zeros();
                let mut weighted = Vector3::zeros();
                let mut area = 0.0;
                for &f in tris {
                    let [a, b, d] = faces[f as usize].map(|v| positions[v as usize]);
                    let n = (b - a).cross(&(d - a)) * 0.5;
                    let ar = n.norm();
                    dipole += n;
                    weighted += (a + b + d) * (ar / 3.0);
                    area += ar;
                }
                let center = if area > 0.0 {
                    weighted / area
                } else {
                    let v = faces[tris[0] as usize][0];
                    positions[v as usize]
                };
                // Over the leaf's vertices each once (a maximum and a box do not depend on
                // repeats or order). One root of the largest square (the root is monotone:
                // the same bits as the largest root).
                let range = self.leaf_vertex_offsets[id] as usize
                    ..self.leaf_vertex_offsets[id + 1] as usize;
                let (mut lo, mut hi) = (
                    Vector3::repeat(f64::INFINITY),
                    Vector3::repeat(f64::NEG_INFINITY),
                );
                let mut largest = 0.0f64;
                for &v in &self.leaf_vertices[range] {
                    let p = positions[v as usize];
                    largest = largest.max((p - center).norm_squared());
                    lo = lo.inf(&p);
                    hi = hi.sup(&p);
                }
                let radius = largest.sqrt();
                (dipole, center, area, radius, lo, hi)
            } else {
                let (l, r) = (clusters[node.left as usize], clusters[node.right as usize]);
                let area = l.area_m2 + r.area_m2;
                let center = if area > 0.0 {
                    (l.center * l.area_m2 + r.center * r.area_m2) / area
                } else {
                    l.center
                };
                let (lo, hi) = (l.lo.inf(&r.lo), l.hi.sup(&r.hi));
                // Two bounds on the distance from the center to the cluster's vertices: through
                // the children's spheres, and to the farthest corner of the box.
                let corner = (center - lo).abs().sup(&(hi - center).abs()).norm();
                let radius = (l.radius_m + (l.center - center).norm())
                    .max(r.radius_m + (r.center - center).norm())
                    .min(corner);
                (l.dipole + r.dipole, center, area, radius, lo, hi)
            };
            let c = &mut clusters[id];
            c.dipole = dipole;
            c.center = center;
            c.area_m2 = area;
            c.radius_m = radius;
            c.lo = lo;
            c.hi = hi;
        }
    }

    /// Move the body's vertices (same count as at construction) and refit both trees. No
    /// allocation.
    pub fn update_positions(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.proximity.update_positions(positions)?;
        self.refit();
        Ok(())
    }

    /// Move the body's vertices and refit both trees, but leave the closest-point
    /// pseudo-normals to be computed with each answer ([`MeshProximity::update_positions_refit`]:
    /// the same answers, bitwise), for callers that ask for few closest points per move. No
    /// allocation.
    pub fn update_positions_refit(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.proximity.update_positions_refit(positions)?;
        self.refit();
        Ok(())
    }

    /// The axis-aligned box of the body's faces as last posed (`lo`, `hi`). A point outside it
    /// is outside the body whatever the mesh: a plane of the box separates it from every
    /// triangle, so the surface subtends at most a hemisphere from it and its (generalized)
    /// winding number is at most ½ in magnitude, never the `> ½` of inside.
    pub fn bounds(&self) -> (Vector3<f64>, Vector3<f64>) {
        self.bounds
    }

    /// The body's vertex positions.
    pub fn positions(&self) -> &[Vector3<f64>] {
        self.proximity.positions()
    }

    /// The body's triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        self.proximity.faces()
    }

    /// The closest-point structure over the whole body (its sign is the pseudo-normal's).
    pub fn proximity(&self) -> &MeshProximity {
        &self.proximity
    }

    /// Depth-first over the tree: `enter(cluster)` says whether to enter a node; an entered
    /// leaf hands its triangles to `triangle`, an entered inner node its two children to the
    /// walk. `triangle` returning `None` stops the walk, which then returns `None`.
    fn walk(
        &self,
        mut enter: impl FnMut(&Cluster) -> bool,
        mut triangle: impl FnMut(&[Vector3<f64>; 3]) -> Option<()>,
    ) -> Option<()> {
        let positions = self.proximity.positions();
        let faces = self.proximity.faces();
        let clusters = self.clusters();
        let mut stack = [0u32; 64];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let id = stack[top] as usize;
            let node = &self.tree.nodes()[id];
            if !enter(&clusters[id]) {
                continue;
            }
            if node.is_leaf() {
                for &f in self.tree.leaf_items(node) {
                    triangle(&faces[f as usize].map(|v| positions[v as usize]))?;
                }
            } else {
                stack[top] = node.left;
                stack[top + 1] = node.right;
                top += 2;
            }
        }
        Some(())
    }

    /// The generalized winding number of the body at `p` (hierarchical; see the module docs).
    pub fn winding_number(&self, p: &Vector3<f64>) -> f64 {
        // One sum, in the walk's order, of the dipoles of far clusters and the exact solid
        // angles of near triangles.
        let solid_angle = std::cell::Cell::new(0.0);
        let far = |c: &Cluster| {
            let offset = c.center - p;
            let d2 = offset.norm_squared();
            let is_far = d2 > (FAR_FIELD_RATIO * c.radius_m).powi(2);
            if is_far {
                solid_angle.set(solid_angle.get() + offset.dot(&c.dipole) / (d2 * d2.sqrt()));
            }
            !is_far
        };
        self.walk(far, |tri| {
            solid_angle.set(solid_angle.get() + triangle_solid_angle(p, tri));
            Some(())
        });
        solid_angle.get() / (4.0 * std::f64::consts::PI)
    }

    /// The winding number of the body at `p` as the signed count of surface crossings along a
    /// ray (+1 leaving through a triangle's front, −1 entering): exact for a closed mesh, with
    /// or without self-intersections. `None` when the ray grazes an edge or vertex, lies in a
    /// triangle's plane at a crossing, or starts on the surface (then another ray is needed).
    ///
    /// The triangles are those whose box the ray may meet in the closest-point query's wide
    /// tree ([`MeshProximity::for_each_face_on_ray`]); a triangle whose box it misses is no
    /// crossing.
    fn ray_winding(&self, p: &Vector3<f64>, direction: &Vector3<f64>) -> Option<i32> {
        let positions = self.proximity.positions();
        let faces = self.proximity.faces();
        let mut crossings = 0i32;
        self.proximity.for_each_face_on_ray(p, direction, |f| {
            crossings += ray_crossing(
                p,
                direction,
                &faces[f as usize].map(|v| positions[v as usize]),
            )?;
            Some(())
        })?;
        Some(crossings)
    }

    /// [`Self::ray_winding`] over this tree's own clusters: its walk until 2026-12-04, the
    /// tests' reference.
    #[cfg(test)]
    fn ray_winding_clusters(&self, p: &Vector3<f64>, direction: &Vector3<f64>) -> Option<i32> {
        let inverse = direction.map(|d| 1.0 / d);
        let mut crossings = 0i32;
        self.walk(
            |c| ray_meets_box(p, &inverse, &c.lo, &c.hi),
            |tri| {
                crossings += ray_crossing(p, direction, tri)?;
                Some(())
            },
        )?;
        Some(crossings)
    }

    /// Whether `p` is inside the body, and its winding number: two rays in fixed directions
    /// (more where one is ambiguous) that agree give it exactly; where they disagree (a hole
    /// in the mesh lets one through) the generalized winding number decides.
    pub fn winding_number_fast(&self, p: &Vector3<f64>) -> f64 {
        // First a ray away from the body's vertical axis (through the box's centre), which
        // leaves a body after few crossings; then fixed directions.
        let centre = (self.bounds.0 + self.bounds.1) * 0.5;
        let (rx, rz) = (p.x - centre.x, p.z - centre.z);
        let radial = (rx * rx + rz * rz).sqrt();
        let outward = (radial > 1e-6).then(|| {
            Vector3::new(rx + 0.31 * radial, 0.23 * radial, rz + 0.17 * radial).normalize()
        });
        let mut first: Option<i32> = None;
        for direction in outward.iter().chain(&RAY_DIRECTIONS) {
            let Some(w) = self.ray_winding(p, direction) else {
                continue;
            };
            if self.closed {
                // On a closed surface one ray's count is the winding number.
                return f64::from(w);
            }
            match first {
                None => first = Some(w),
                Some(v) if v == w => return f64::from(w),
                Some(_) => break,
            }
        }
        self.winding_number(p)
    }

    /// The exact winding number (every triangle's solid angle; for tests and checks).
    pub fn winding_number_exact(&self, p: &Vector3<f64>) -> f64 {
        let positions = self.proximity.positions();
        self.proximity
            .faces()
            .iter()
            .map(|t| triangle_solid_angle(p, &t.map(|v| positions[v as usize])))
            .sum::<f64>()
            / (4.0 * std::f64::consts::PI)
    }

    /// The signed distance of `p` to the body, with its closest point and winding number.
    pub fn query(&self, p: &Vector3<f64>) -> BodyPoint {
        let mut hint = u32::MAX;
        self.query_hinted(p, &mut hint)
    }

    /// [`BodyDistance::query`] with a closest-face hint kept per point between calls
    /// ([`MeshProximity::closest_within_hinted`]: the same answer, less work; start at
    /// `u32::MAX`).
    pub fn query_hinted(&self, p: &Vector3<f64>, hint: &mut u32) -> BodyPoint {
        let closest = self
            .proximity
            .closest_within_hinted(p, f64::INFINITY, hint)
            .unwrap_or_else(|| self.proximity.closest(p));
        let winding_number = self.winding_number_fast(p);
        let distance = (p - closest.point).norm();
        BodyPoint {
            signed_distance_m: if winding_number > 0.5 {
                -distance
            } else {
                distance
            },
            winding_number,
            closest,
        }
    }

    /// The signed distance of `p` to the body, m (negative inside).
    pub fn signed_distance_m(&self, p: &Vector3<f64>) -> f64 {
        self.query(p).signed_distance_m
    }
}

/// Ray directions of the inside test: unit vectors off every axis and plane of symmetry (a ray
/// along an axis would meet the edges of axis-aligned meshes).
const RAY_DIRECTIONS: [Vector3<f64>; 6] = [
    Vector3::new(0.5393592479303883, 0.700896363750486, 0.46672892448755765),
    Vector3::new(-0.6124003125805976, 0.32368452468971287, -0.721244886032186),
    Vector3::new(0.26726124191240297, -0.5345224838248059, 0.8017837257373088),
    Vector3::new(-0.48280833938552037, -0.65500187768212, -0.5812646967197417),
    Vector3::new(0.8183011707760782, 0.09092235230846425, -0.5675529224285566),
    Vector3::new(
        -0.09950569501219005,
        0.8955512551102105,
        0.43368948123129253,
    ),
];

/// Whether the half-line from `p` with direction `1 / inverse` (no zero component) meets the
/// box (slab test, with a relative margin against rounding).
#[cfg(test)]
fn ray_meets_box(
    p: &Vector3<f64>,
    inverse: &Vector3<f64>,
    lo: &Vector3<f64>,
    hi: &Vector3<f64>,
) -> bool {
    let margin = 1e-9 * (hi - lo).amax() + 1e-12;
    let (mut t_in, mut t_out) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        let a = (lo[k] - margin - p[k]) * inverse[k];
        let b = (hi[k] + margin - p[k]) * inverse[k];
        t_in = t_in.max(a.min(b));
        t_out = t_out.min(a.max(b));
    }
    t_in <= t_out
}

/// The signed crossing of the half-line `p + t d` (`t > 0`) with triangle `t`: +1 through its
/// front (along its counter-clockwise normal), −1 through its back, 0 if it misses; `None` when
/// the hit is too close to an edge, a vertex, the start point or the triangle's plane to
/// count reliably.
fn ray_crossing(p: &Vector3<f64>, d: &Vector3<f64>, t: &[Vector3<f64>; 3]) -> Option<i32> {
    const EDGE: f64 = 1e-9;
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    let pvec = d.cross(&e2);
    let det = e1.dot(&pvec);
    let scale = e1.norm() * e2.norm();
    let tvec = p - t[0];
    if det.abs() <= 1e-12 * scale {
        // Parallel to the plane: no transversal crossing, unless the ray runs inside it.
        let off_plane = tvec.dot(&e1.cross(&e2)).abs();
        return if off_plane <= 1e-12 * scale * tvec.norm().max(1e-300) {
            None
        } else {
            Some(0)
        };
    }
    let inv = 1.0 / det;
    let u = tvec.dot(&pvec) * inv;
    if !(-EDGE..=1.0 + EDGE).contains(&u) {
        return Some(0);
    }
    let qvec = tvec.cross(&e1);
    let v = d.dot(&qvec) * inv;
    if v < -EDGE || u + v > 1.0 + EDGE {
        return Some(0);
    }
    let distance = e2.dot(&qvec) * inv;
    let size = scale.sqrt();
    if distance < -EDGE * size {
        return Some(0);
    }
    if distance <= EDGE * size || u <= EDGE || v <= EDGE || u + v >= 1.0 - EDGE {
        return None;
    }
    // det = −d · (e1 × e2): leaving through the front when det < 0.
    Some(if det < 0.0 { 1 } else { -1 })
}

/// Signed solid angle of triangle `t` seen from `p` (Van Oosterom & Strackee 1983): positive
/// when `p` is behind the triangle (on the side opposite its counter-clockwise normal).
fn triangle_solid_angle(p: &Vector3<f64>, t: &[Vector3<f64>; 3]) -> f64 {
    let (a, b, c) = (t[0] - p, t[1] - p, t[2] - p);
    let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
    let numerator = a.dot(&b.cross(&c));
    let denominator = la * lb * lc + a.dot(&b) * lc + b.dot(&c) * la + c.dot(&a) * lb;
    if numerator == 0.0 && denominator <= 0.0 {
        // On the triangle's plane (outside it: 0; on it: undefined, taken as 0).
        return 0.0;
    }
    2.0 * numerator.atan2(denominator)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A UV sphere of radius `r` at `c`, outward-oriented and closed.
    fn sphere(c: Vector3<f64>, r: f64, n: usize) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let mut p = vec![c + Vector3::new(0.0, r, 0.0)];
        for i in 1..n {
            let theta = std::f64::consts::PI * i as f64 / n as f64;
            for j in 0..2 * n {
                let phi = std::f64::consts::PI * j as f64 / n as f64;
                p.push(
                    c + Vector3::new(
                        r * theta.sin() * phi.cos(),
                        r * theta.cos(),
                        -r * theta.sin() * phi.sin(),
                    ),
                );
            }
        }
        p.push(c - Vector3::new(0.0, r, 0.0));
        let ring = |i: usize, j: usize| (1 + (i - 1) * 2 * n + j % (2 * n)) as u32;
        let last = (p.len() - 1) as u32;
        let mut f = Vec::new();
        for j in 0..2 * n {
            f.push([0, ring(1, j), ring(1, j + 1)]);
            f.push([ring(n - 1, j), last, ring(n - 1, j + 1)]);
        }
        for i in 1..n - 1 {
            for j in 0..2 * n {
                f.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
                f.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
            }
        }
        (p, f)
    }

    fn merge(
        a: (Vec<Vector3<f64>>, Vec<[u32; 3]>),
        b: (Vec<Vector3<f64>>, Vec<[u32; 3]>),
    ) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let offset = a.0.len() as u32;
        let mut p = a.0;
        p.extend(b.0);
        let mut f = a.1;
        f.extend(b.1.iter().map(|t| t.map(|v| v + offset)));
        (p, f)
    }

    #[test]
    fn a_sphere_inside_and_outside() {
        let (p, f) = sphere(Vector3::new(0.1, 0.2, 0.3), 0.5, 24);
        let body = BodyDistance::new(&p, &f).expect("valid");
        for (q, inside) in [
            (Vector3::new(0.1, 0.2, 0.3), true),
            (Vector3::new(0.1, 0.2, 0.75), true),
            (Vector3::new(0.1, 0.2, 0.85), false),
            (Vector3::new(2.0, 0.0, 0.0), false),
            (Vector3::new(0.45, 0.5, 0.3), true),
        ] {
            let a = body.query(&q);
            assert_eq!(a.inside(), inside, "{q}: {a:?}");
            let w = a.winding_number;
            assert!(
                (w - f64::from(u8::from(inside))).abs() < 0.02,
                "{q}: w = {w}"
            );
            assert!((a.signed_distance_m.abs() - (a.closest.point - q).norm()).abs() < 1e-15);
        }
        // Near the surface, on both sides (the polygonal surface is within 0.5 % of the sphere).
        let d = body.signed_distance_m(&Vector3::new(0.1, 0.2, 0.3 + 0.49));
        assert!(d < 0.0 && d > -0.013, "{d}");
        let d = body.signed_distance_m(&Vector3::new(0.1, 0.2, 0.3 + 0.51));
        assert!(d > 0.0 && d < 0.011, "{d}");
    }

    #[test]
    fn the_wide_tree_ray_counts_what_the_clusters_counted() {
        // The built-in body with an arm pressed into the torso (two parts overlapping), whole
        // and as an open torso band; rays from points spread over its box, from just in front
        // of and behind every tenth vertex (the crossings that matter, near the surface) and
        // from the middles of edges (rays that graze: `None`), along the fixed directions, an
        // outward one and the axes (which the slab test takes apart).
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman");
        let b = crate::BodyModel::load(&dir).expect("the built-in body");
        let mut pose = crate::Pose::rest(b.skeleton().n_joints());
        pose.local_rotations[b.skeleton().index_of("LeftArm").expect("joint")] =
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -1.2);
        let positions = b
            .posed_vertices(&vec![0.0; b.n_betas()], &pose)
            .expect("posed");
        // The band: faces whose centroid lies between the hips and the neck joints.
        let joints = b.shaped_joints(&vec![0.0; b.n_betas()]).expect("joints");
        let y_of = |name: &str| joints[b.skeleton().index_of(name).expect("joint")].y;
        let heights = y_of("Hips")..y_of("Neck");
        let mut band = b.faces().to_vec();
        band.retain(|t| {
            heights.contains(&(t.iter().map(|&v| positions[v as usize].y).sum::<f64>() / 3.0))
        });
        let normals = crate::vertex_normals(&positions, b.faces());
        let mut directions: Vec<Vector3<f64>> = RAY_DIRECTIONS.to_vec();
        directions.extend([Vector3::x(), -Vector3::y(), Vector3::z()]);
        directions.push(Vector3::new(0.8, 0.0, -0.6));
        let (mut compared, mut crossed, mut unclear) = (0usize, 0usize, 0usize);
        for faces in [b.faces(), &band[..]] {
            let body = BodyDistance::new(&positions, faces).expect("valid");
            let (lo, hi) = body.bounds();
            let mut points: Vec<Vector3<f64>> = (0..2000)
                .map(|i| {
                    let x = i as f64 * 0.618_033_988_75;
                    let u = Vector3::new(x.fract(), (x * 1.37).fract(), (x * 2.71).fract());
                    lo + (hi - lo).component_mul(&u)
                })
                .collect();
            for v in (0..positions.len()).step_by(10) {
                for side in [2e-3, -2e-3] {
                    points.push(positions[v] + normals[v] * side);
                }
            }
            for t in faces.iter().step_by(50) {
                points.push((positions[t[0] as usize] + positions[t[1] as usize]) * 0.5);
            }
            for p in &points {
                for d in &directions {
                    let (new, old) = (body.ray_winding(p, d), body.ray_winding_clusters(p, d));
                    assert_eq!(new, old, "{p} along {d}");
                    compared += 1;
                    crossed += usize::from(new.is_some_and(|w| w != 0));
                    unclear += usize::from(new.is_none());
                }
            }
        }
        println!("{compared} rays: {crossed} crossed, {unclear} unclear");
        // Both kinds of answer are exercised.
        assert!(
            crossed > 1000 && unclear > 0,
            "{compared} rays: {crossed} crossed, {unclear} unclear"
        );
    }

    #[test]
    fn the_hierarchy_matches_the_exact_sum() {
        let (p, f) = sphere(Vector3::zeros(), 0.3, 40);
        let body = BodyDistance::new(&p, &f).expect("valid");
        let mut worst: f64 = 0.0;
        for i in 0..400 {
            let x = i as f64 * 0.731;
            let q = Vector3::new(x.sin(), (1.7 * x).cos(), (0.37 * x).sin()) * 0.45;
            worst = worst.max((body.winding_number(&q) - body.winding_number_exact(&q)).abs());
        }
        assert!(worst < 0.02, "largest difference {worst}");
    }

    #[test]
    fn pressed_together_parts_and_open_patches() {
        // Two overlapping spheres (an arm sunk into a torso): the overlap is inside (w = 2),
        // and so is a point inside the big one whose closest surface is the small one's, which
        // the pseudo-normal of the closest point calls outside.
        let big = sphere(Vector3::zeros(), 0.3, 24);
        let small = sphere(Vector3::new(0.3, 0.0, 0.0), 0.1, 16);
        let (p, f) = merge(big, small);
        let body = BodyDistance::new(&p, &f).expect("valid");
        let overlap = body.query(&Vector3::new(0.25, 0.0, 0.0));
        assert!(overlap.inside() && (overlap.winding_number - 2.0).abs() < 0.02);
        let q = Vector3::new(0.17, 0.0, 0.0); // 0.13 inside the big one, 0.03 from the small one
        let a = body.query(&q);
        assert!(a.inside(), "{a:?}");
        assert!((a.signed_distance_m + 0.03).abs() < 2e-3, "{a:?}");
        let pseudo = body.proximity().closest(&q);
        assert!(
            pseudo.signed_distance_m > 0.0,
            "the case the pseudo-normal gets wrong: {pseudo:?}"
        );
        // A sphere with a cap cut away (an open region boundary): points well inside and well
        // outside keep their side; behind the cut edge, outside.
        let (p, f) = sphere(Vector3::zeros(), 0.3, 24);
        let open: Vec<[u32; 3]> = f
            .iter()
            .filter(|t| t.iter().all(|&v| p[v as usize].y < 0.25))
            .copied()
            .collect();
        let body = BodyDistance::new(&p, &open).expect("valid");
        assert!(body.query(&Vector3::new(0.0, -0.1, 0.0)).inside());
        assert!(!body.query(&Vector3::new(0.0, -0.5, 0.0)).inside());
        assert!(!body.query(&Vector3::new(0.25, -0.25, 0.0)).inside());
    }

    #[test]
    fn outside_its_bounds_no_point_is_inside() {
        let (p, f) = sphere(Vector3::zeros(), 0.3, 24);
        // A bowl: the sphere's lower half, open at the top. Just above the middle of its
        // opening, outside its box, it fills almost half the view: a winding number just
        // below ½, never above.
        let bowl: Vec<[u32; 3]> = f
            .iter()
            .filter(|t| t.iter().all(|&v| p[v as usize].y <= 1e-9))
            .copied()
            .collect();
        for faces in [&f, &bowl] {
            let mut body = BodyDistance::new(&p, faces).expect("valid");
            let (lo, hi) = body.bounds();
            if faces.len() == bowl.len() {
                assert!(hi.y.abs() < 1e-9 && (lo.y + 0.3).abs() < 1e-9, "{lo} {hi}");
                let w = body.winding_number_exact(&Vector3::new(0.0, 1e-3, 0.0));
                assert!(w > 0.45 && w <= 0.5, "{w}");
            }
            // Just outside each side of the box, on a grid over it: never inside.
            for k in 0..3 {
                for (side, out) in [(lo[k], -1e-6), (hi[k], 1e-6)] {
                    for i in 0..=6 {
                        for j in 0..=6 {
                            let (a, b) = ((k + 1) % 3, (k + 2) % 3);
                            let mut q = Vector3::zeros();
                            q[k] = side + out;
                            q[a] = lo[a] + (hi[a] - lo[a]) * i as f64 / 6.0;
                            q[b] = lo[b] + (hi[b] - lo[b]) * j as f64 / 6.0;
                            let w = body.winding_number_exact(&q);
                            assert!(w <= 0.5, "{q}: {w}");
                            assert!(!body.query(&q).inside(), "{q}");
                        }
                    }
                }
            }
            // The box follows the body.
            let moved: Vec<Vector3<f64>> =
                p.iter().map(|v| v + Vector3::new(1.0, 0.0, 0.0)).collect();
            body.update_positions_refit(&moved).expect("same size");
            let (lo2, hi2) = body.bounds();
            assert!((lo2 - lo - Vector3::x()).norm() < 1e-12, "{lo2}");
            assert!((hi2 - hi - Vector3::x()).norm() < 1e-12, "{hi2}");
        }
    }

    #[test]
    fn refits_and_rejects_bad_meshes() {
        let (p, f) = sphere(Vector3::zeros(), 0.3, 12);
        let mut body = BodyDistance::new(&p, &f).expect("valid");
        let q = Vector3::new(1.0, 0.0, 0.0);
        assert!(!body.query(&q).inside());
        let moved: Vec<Vector3<f64>> = p.iter().map(|v| v + Vector3::new(1.0, 0.0, 0.0)).collect();
        body.update_positions(&moved).expect("same size");
        let a = body.query(&q);
        assert!(
            a.inside() && (a.signed_distance_m + 0.3).abs() < 0.01,
            "{a:?}"
        );
        assert!(body.update_positions(&moved[..3]).is_err());
        assert!(BodyDistance::new(&p, &[]).is_err());
        assert!(BodyDistance::new(&p, &[[0, 1, 9999]]).is_err());
    }

    #[test]
    fn a_refit_without_normals_answers_bit_for_bit_as_a_full_update() {
        // An open, squashed, moved sphere: closest points on faces, edges and vertices, inside
        // and outside, near the cut and far.
        let (p, f) = sphere(Vector3::zeros(), 0.3, 16);
        let open: Vec<[u32; 3]> = f
            .iter()
            .filter(|t| t.iter().all(|&v| p[v as usize].y < 0.2))
            .copied()
            .collect();
        let moved: Vec<Vector3<f64>> = p
            .iter()
            .map(|v| Vector3::new(v.x * 1.3 + 0.05, v.y * 0.8, v.z + 0.02 * v.x))
            .collect();
        let mut full = BodyDistance::new(&p, &open).expect("valid");
        let mut refit = full.clone();
        full.update_positions(&moved).expect("same size");
        refit.update_positions_refit(&moved).expect("same size");
        for i in 0..9 {
            for j in 0..9 {
                for k in 0..9 {
                    let q = Vector3::new(i as f64, j as f64, k as f64) * 0.1 - Vector3::repeat(0.4)
                        + Vector3::new(0.013, 0.007, 0.003);
                    let (a, b) = (full.query(&q), refit.query(&q));
                    assert_eq!(format!("{a:?}"), format!("{b:?}"), "at {q:?}");
                    assert!(b.closest.normal.norm() > 0.99, "{b:?}");
                }
            }
        }
        assert!(refit.update_positions_refit(&moved[..3]).is_err());
    }
}
