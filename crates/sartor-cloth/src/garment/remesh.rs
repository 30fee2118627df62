//! Isotropic remeshing (Botsch & Kobbelt 2004, "A remeshing approach to multiresolution
//! modeling") with an exact triangle budget.
//!
//! One iteration at target edge length `L`:
//!
//! 1. split every edge longer than `4/3 L` at its midpoint (projected onto the input);
//! 2. collapse every edge shorter than `4/5 L` unless that would create an edge longer than
//!    `4/3 L`, turn a triangle by more than 60°, change the topology (link condition), move a
//!    boundary vertex off the boundary or remove a boundary corner;
//! 3. flip edges that bring the valences closer to 6 (4 on the boundary);
//! 4. tangential relaxation: each interior vertex moves towards the area-weighted centroid of
//!    its one-ring triangles, within its tangent plane; each boundary vertex moves towards the
//!    midpoint of its two boundary neighbours along the boundary; corners stay;
//! 5. projection back onto the input: interior vertices onto the closest point of the input
//!    triangles (`sartor_core::MeshProximity`), boundary vertices onto their own input
//!    boundary loop. A move that would flip one of the vertex's triangles, or make the
//!    smallest angle around the vertex smaller than both 30° and its current value, is
//!    dropped.
//!
//! [`remesh_to_count`] picks `L` from the input's area (a near-equilateral mesh has
//! `F ≈ A / (√3/4 · L²)` triangles) and runs up to three rounds of iterations, correcting `L`
//! from the count reached (`L ∝ 1/√F`). The remaining difference is then spread over four
//! passes of splits of the longest edges or collapses of the shortest (at most one per
//! neighbourhood per pass, each pass followed by valence flips and relaxation), and the exact
//! count is reached with a last few such operations (an interior split adds two triangles, a
//! boundary split one; an interior collapse removes two, a boundary collapse one). The finish
//! keeps the count: Delaunay flips (sum of opposite angles above π) alternating with
//! relaxation, and the removal of caps (angles above 170°).
//!
//! Everything is deterministic: elements are visited in index order and no hash map is used.

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{MeshProximity, TriMesh};

use super::halfedge::{EditMesh, NONE};
use crate::{Error, Result};

/// Settings of [`remesh_to_count`].
#[derive(Clone, Debug, PartialEq)]
pub struct RemeshOptions {
    /// The exact number of triangles wanted.
    pub target_triangles: usize,
    /// Remeshing iterations in the first round (later rounds use half as many).
    pub iterations: usize,
    /// A boundary vertex whose boundary turns by more than this angle is a corner: it is
    /// never moved or removed, deg.
    pub corner_angle_deg: f64,
}

impl RemeshOptions {
    /// Defaults for a given triangle count: 10 iterations, corners above 60°.
    pub fn new(target_triangles: usize) -> Self {
        Self {
            target_triangles,
            iterations: 10,
            corner_angle_deg: 60.0,
        }
    }
}

/// Remesh `mesh` isotropically to exactly `options.target_triangles` triangles.
///
/// The input must be an oriented 2-manifold (boundaries allowed) in which every vertex belongs
/// to a triangle. The output has the same connected components and the same boundary loops
/// (each input loop becomes one output loop; corners are kept), and every vertex lies on the
/// input surface (interior vertices) or on its input boundary loop (boundary vertices).
///
/// # Errors
/// A non-manifold input, an input with no triangles, a target below 4 triangles per boundary
/// loop, an odd target for a closed mesh (every split or collapse of a closed mesh changes the
/// count by two), or a count that cannot be reached.
pub fn remesh_to_count(mesh: &TriMesh, options: &RemeshOptions) -> Result<TriMesh> {
    let mut r = Remesher::new(mesh, options.corner_angle_deg)?;
    let target = options.target_triangles;
    let n_loops = r.loops.len();
    if target < 4 * n_loops.max(1) {
        return Err(Error::invalid(
            "remeshing target",
            format!("{target} triangles are too few for a mesh with {n_loops} boundary loops"),
        ));
    }
    if n_loops == 0 && target % 2 == 1 {
        return Err(Error::invalid(
            "remeshing target",
            format!("a closed mesh always has an even number of triangles, {target} is odd"),
        ));
    }
    let area: f64 = mesh.face_areas().iter().sum();
    let mut length = (4.0 * area / (3f64.sqrt() * target as f64)).sqrt();
    let mut iterations = options.iterations.max(1);
    for _round in 0..3 {
        for _ in 0..iterations {
            r.iterate(length);
        }
        let ratio = r.m.n_faces() as f64 / target as f64;
        if (ratio - 1.0).abs() < 0.02 {
            break;
        }
        length *= ratio.sqrt();
        iterations = (iterations / 2).max(3);
    }
    // Spread the remaining difference over a few relaxation passes, then make it exact.
    const CORRECTION_PASSES: usize = 4;
    for pass in 0..CORRECTION_PASSES {
        let missing = target as i64 - r.m.n_faces() as i64;
        let goal = r.m.n_faces() as i64 + missing / (CORRECTION_PASSES - pass) as i64;
        // Collapses may create edges up to 1.25 × the usual limit here; relaxation evens
        // them out (a perfectly regular lattice has no collapse within the usual limit).
        r.change_count(goal as usize, 1.25 * length, true);
        r.flip_valences();
        r.relax_and_project();
    }
    r.reach_count(target, length)?;
    // Angle-optimal finish: Delaunay flips and relaxation keep the count.
    for _ in 0..FINAL_PASSES {
        r.delaunay_flips();
        r.relax_and_project();
    }
    r.remove_caps();
    r.delaunay_flips();
    r.finish()
}

/// Remesh `mesh` isotropically towards edge length `target_edge_m` for a given number of
/// iterations, without controlling the triangle count. Same input requirements and guarantees
/// as [`remesh_to_count`].
pub fn remesh_isotropic(mesh: &TriMesh, target_edge_m: f64, iterations: usize) -> Result<TriMesh> {
    if !(target_edge_m.is_finite() && target_edge_m > 0.0) {
        return Err(Error::invalid(
            "remeshing target",
            format!("edge length {target_edge_m} m is not positive"),
        ));
    }
    let mut r = Remesher::new(mesh, 60.0)?;
    for _ in 0..iterations {
        r.iterate(target_edge_m);
    }
    r.remove_caps();
    r.finish()
}

/// Relaxation moves may lower the worst angle around a vertex only while it stays above this,
/// rad (30°).
const MIN_ANGLE_GUARD: f64 = std::f64::consts::PI / 6.0;

/// Delaunay-flip and relaxation passes after the exact count is reached.
const FINAL_PASSES: usize = 4;

struct Remesher {
    m: EditMesh,
    /// Input boundary loop of each boundary vertex (`NONE` for interior vertices).
    loop_of: Vec<u32>,
    /// Boundary corners: never moved or removed.
    corner: Vec<bool>,
    /// Input boundary loops as segments.
    loops: Vec<Vec<[Vector3<f64>; 2]>>,
    reference: MeshProximity,
}

impl Remesher {
    fn new(mesh: &TriMesh, corner_angle_deg: f64) -> Result<Self> {
        if mesh.n_faces() == 0 {
            return Err(Error::invalid(
                "remeshing input",
                "the mesh has no triangles",
            ));
        }
        let topology = mesh.topology();
        topology.check_manifold()?;
        if let Some(v) = mesh.first_unused_vertex() {
            return Err(Error::invalid(
                "remeshing input",
                format!("vertex {v} belongs to no triangle"),
            ));
        }
        let p = mesh.positions();
        let mut loop_of = vec![NONE; mesh.n_vertices()];
        let mut corner = vec![false; mesh.n_vertices()];
        let cos_corner = (std::f64::consts::PI - corner_angle_deg.to_radians()).cos();
        let mut loops = Vec::new();
        for (i, lp) in topology.boundary_loops().iter().enumerate() {
            let n = lp.len();
            let mut segments = Vec::with_capacity(n);
            for k in 0..n {
                let (a, b, c) = (lp[(k + n - 1) % n], lp[k], lp[(k + 1) % n]);
                loop_of[b as usize] = i as u32;
                segments.push([p[b as usize], p[c as usize]]);
                // Interior angle of the polyline at b; a corner turns by more than the limit.
                let (u, w) = (p[a as usize] - p[b as usize], p[c as usize] - p[b as usize]);
                let cos = u.dot(&w) / (u.norm() * w.norm());
                if cos > cos_corner {
                    corner[b as usize] = true;
                }
            }
            loops.push(segments);
        }
        Ok(Self {
            m: EditMesh::new(p, mesh.faces()),
            loop_of,
            corner,
            loops,
            reference: MeshProximity::new(p, mesh.faces())?,
        })
    }

    fn finish(&self) -> Result<TriMesh> {
        let (positions, faces, _) = self.m.to_parts();
        Ok(TriMesh::new(positions, faces)?)
    }

    fn iterate(&mut self, length: f64) {
        let (lo, hi) = (0.8 * length, 4.0 / 3.0 * length);
        self.split_long(hi);
        self.collapse_short(lo, hi);
        self.flip_valences();
        self.relax_and_project();
    }

    /// Where `p` lands when vertex `v` is projected: its boundary loop or the input surface.
    fn project(&self, v: u32, p: &Vector3<f64>) -> Vector3<f64> {
        let l = self.loop_of[v as usize];
        if l == NONE {
            return self.reference.closest(p).point;
        }
        let mut best = (*p, f64::INFINITY);
        for [a, b] in &self.loops[l as usize] {
            let q = closest_on_segment(p, a, b);
            let d = (q - p).norm_squared();
            if d < best.1 {
                best = (q, d);
            }
        }
        best.0
    }

    fn split_edge(&mut self, e: u32) {
        let (a, b) = (self.m.from(2 * e), self.m.to(2 * e));
        let boundary = self.m.is_boundary_edge(e);
        let mid = 0.5 * (self.m.pos[a as usize] + self.m.pos[b as usize]);
        let l = if boundary {
            self.loop_of[a as usize]
        } else {
            NONE
        };
        self.loop_of.push(l);
        self.corner.push(false);
        let v = self.m.split(e, mid);
        let projected = self.project(v, &mid);
        self.m.pos[v as usize] = projected;
    }

    fn split_long(&mut self, hi: f64) {
        for _pass in 0..10 {
            let mut any = false;
            let n = self.m.n_edge_slots() as u32;
            for e in 0..n {
                if !self.m.edge_deleted(e) && self.m.edge_length(e) > hi {
                    self.split_edge(e);
                    any = true;
                }
            }
            if !any {
                break;
            }
        }
    }

    /// Whether collapsing half-edge `h` (origin into target) is allowed by the boundary and
    /// corner rules, the link condition, the normals and (when given) the longest new edge.
    fn collapse_allowed(&self, h: u32, hi: Option<f64>) -> bool {
        let (v0, v1) = (self.m.from(h), self.m.to(h));
        if self.corner[v0 as usize] {
            return false;
        }
        let (b0, b1) = (self.m.is_boundary_vertex(v0), self.m.is_boundary_vertex(v1));
        if b0 && !(b1 && self.m.is_boundary_edge(h / 2)) {
            return false;
        }
        if !self.m.is_collapse_ok(h) {
            return false;
        }
        let target = self.m.pos[v1 as usize];
        for g in self.m.outgoing(v0) {
            let w = self.m.to(g);
            if let Some(hi) = hi
                && (self.m.pos[w as usize] - target).norm() > hi
            {
                return false;
            }
            let f = self.m.face(g);
            if f == NONE {
                continue;
            }
            let t = self.m.face_vertices(f);
            if t.contains(&v1) {
                continue;
            }
            let before = self.m.face_normal(f);
            let after = self.m.face_normal_with(f, v0, &target);
            let (nb, na) = (before.norm(), after.norm());
            if na <= 1e-12 * nb || before.dot(&after) < 0.5 * na * nb {
                return false;
            }
        }
        true
    }

    fn collapse_short(&mut self, lo: f64, hi: f64) {
        let n = self.m.n_edge_slots() as u32;
        for e in 0..n {
            if self.m.edge_deleted(e) || self.m.edge_length(e) >= lo {
                continue;
            }
            self.collapse_edge(e, Some(hi));
        }
    }

    /// Collapse edge `e` in the better allowed direction (keeping the vertex of higher
    /// valence); returns the vertex kept, or `None` when neither direction is allowed.
    fn collapse_edge(&mut self, e: u32, hi: Option<f64>) -> Option<u32> {
        let h = 2 * e;
        let (v0, v1) = (self.m.from(h), self.m.to(h));
        // Keep the vertex of higher valence: try removing the other one first.
        let order = if self.m.valence(v0) < self.m.valence(v1) {
            [h, h ^ 1]
        } else {
            [h ^ 1, h]
        };
        for g in order {
            if self.collapse_allowed(g, hi) {
                let kept = self.m.to(g);
                self.m.collapse(g);
                return Some(kept);
            }
        }
        None
    }

    fn target_valence(&self, v: u32) -> i64 {
        if self.m.is_boundary_vertex(v) { 4 } else { 6 }
    }

    /// Whether flipping `e` keeps both new triangles facing the same way as the old ones.
    fn flip_keeps_orientation(&self, e: u32) -> bool {
        let h = 2 * e;
        let (a, b) = (self.m.from(h), self.m.to(h));
        let [c, d] = self.m.flip_opposites(e);
        let p = |v: u32| self.m.pos[v as usize];
        let n1 = (p(b) - p(a)).cross(&(p(c) - p(a)));
        let n2 = (p(a) - p(b)).cross(&(p(d) - p(b)));
        let n3 = (p(d) - p(a)).cross(&(p(c) - p(a)));
        let n4 = (p(b) - p(d)).cross(&(p(c) - p(d)));
        let tiny = 1e-12 * (n1.norm() + n2.norm());
        n3.norm() > tiny
            && n4.norm() > tiny
            && n3.dot(&n4) > 0.0
            && n3.dot(&n1) > 0.0
            && n3.dot(&n2) > 0.0
            && n4.dot(&n1) > 0.0
            && n4.dot(&n2) > 0.0
    }

    /// Flip, in index order, every live interior edge (ends `[a, b]`, opposite corners
    /// `[c, d]`) for which `wants(self, [a, b], [c, d])` holds, when the flip is valid and
    /// keeps the orientation. Whether any edge flipped.
    fn flip_edges_where(&mut self, wants: impl Fn(&Self, [u32; 2], [u32; 2]) -> bool) -> bool {
        let mut any = false;
        let n = self.m.n_edge_slots() as u32;
        for e in 0..n {
            if self.m.edge_deleted(e) || self.m.is_boundary_edge(e) {
                continue;
            }
            let ends = [self.m.from(2 * e), self.m.to(2 * e)];
            if wants(self, ends, self.m.flip_opposites(e))
                && self.m.is_flip_ok(e)
                && self.flip_keeps_orientation(e)
            {
                self.m.flip(e);
                any = true;
            }
        }
        any
    }

    /// Flip edges where that brings the four vertices' valences closer to their targets.
    fn flip_valences(&mut self) {
        self.flip_edges_where(|r, [a, b], [c, d]| {
            let val = |v: u32| r.m.valence(v) as i64;
            let (va, vb, vc, vd) = (val(a), val(b), val(c), val(d));
            let min_val = |v: u32| if r.m.is_boundary_vertex(v) { 2 } else { 3 };
            if va - 1 < min_val(a) || vb - 1 < min_val(b) {
                return false;
            }
            let dev = |x: i64, v: u32| (x - r.target_valence(v)).pow(2);
            let before = dev(va, a) + dev(vb, b) + dev(vc, c) + dev(vd, d);
            let after = dev(va - 1, a) + dev(vb - 1, b) + dev(vc + 1, c) + dev(vd + 1, d);
            after < before
        });
    }

    /// Flip interior edges whose two opposite angles sum to more than π (intrinsic Delaunay
    /// criterion), when the flip is valid and keeps the orientation, until none is left (at
    /// most 10 passes). On a fixed vertex set this maximises the smallest angle.
    fn delaunay_flips(&mut self) {
        for _pass in 0..10 {
            let any = self.flip_edges_where(|r, [a, b], corners| {
                let p = |v: u32| r.m.pos[v as usize];
                let opposite: f64 = corners
                    .iter()
                    .map(|&c| (p(a) - p(c)).angle(&(p(b) - p(c))))
                    .sum();
                let min_val = |v: u32| if r.m.is_boundary_vertex(v) { 3 } else { 4 };
                opposite > std::f64::consts::PI + 1e-9
                    && r.m.valence(a) >= min_val(a)
                    && r.m.valence(b) >= min_val(b)
            });
            if !any {
                break;
            }
        }
    }

    /// Flip edges opposite an angle above 170° ("caps") when the flip is valid.
    fn remove_caps(&mut self) {
        let cos_cap = 170f64.to_radians().cos();
        self.flip_edges_where(|r, [a, b], opposite| {
            let p = |v: u32| r.m.pos[v as usize];
            opposite.iter().any(|&c| {
                let (u, w) = (p(a) - p(c), p(b) - p(c));
                u.dot(&w) < cos_cap * u.norm() * w.norm()
            })
        });
    }

    /// The relaxation target of vertex `v` (before projection), or `None` for a corner.
    fn relaxation_target(&self, v: u32) -> Option<Vector3<f64>> {
        if self.corner[v as usize] {
            return None;
        }
        let p = self.m.pos[v as usize];
        if self.m.is_boundary_vertex(v) {
            // The stored outgoing half-edge of a boundary vertex is its boundary one: its
            // target is the next boundary vertex, the origin of its predecessor the previous.
            let h = self.m.outgoing(v).next()?;
            let next = self.m.pos[self.m.to(h) as usize];
            let prev = self.m.pos[self.m.from(self.m.prev(h)) as usize];
            let tangent = (next - prev).try_normalize(0.0)?;
            let mid = 0.5 * (next + prev);
            return Some(p + tangent * tangent.dot(&(mid - p)));
        }
        let mut centroid = Vector3::zeros();
        let mut weight = 0.0;
        let mut normal = Vector3::zeros();
        for h in self.m.outgoing(v) {
            let f = self.m.face(h);
            if f == NONE {
                continue;
            }
            let n = self.m.face_normal(f);
            let area = 0.5 * n.norm();
            let x = self.m.face_vertices(f).map(|u| self.m.pos[u as usize]);
            centroid += area * (x[0] + x[1] + x[2]) / 3.0;
            weight += area;
            normal += n;
        }
        let normal = normal.try_normalize(0.0)?;
        if weight <= 0.0 {
            return None;
        }
        let d = centroid / weight - p;
        Some(p + d - normal * normal.dot(&d))
    }

    /// Smallest angle of face `f` with vertex `moved` at `p`, rad.
    fn min_angle_with(&self, f: u32, moved: u32, p: &Vector3<f64>) -> f64 {
        let x = self.m.face_vertices(f).map(|v| {
            if v == moved {
                *p
            } else {
                self.m.pos[v as usize]
            }
        });
        (0..3)
            .map(|k| (x[(k + 1) % 3] - x[k]).angle(&(x[(k + 2) % 3] - x[k])))
            .fold(f64::INFINITY, f64::min)
    }

    fn relax_and_project(&mut self) {
        let n = self.m.n_vertex_slots() as u32;
        let targets: Vec<(u32, Vector3<f64>)> = (0..n)
            .filter(|&v| !self.m.vertex_deleted(v))
            .filter_map(|v| self.relaxation_target(v).map(|t| (v, t)))
            .collect();
        let projected: Vec<Vector3<f64>> = targets
            .par_iter()
            .map(|(v, t)| self.project(*v, t))
            .collect();
        for ((v, _), q) in targets.iter().zip(projected) {
            let v = *v;
            let mut ok = true;
            let (mut worst_before, mut worst_after) = (f64::INFINITY, f64::INFINITY);
            for h in self.m.outgoing(v) {
                let f = self.m.face(h);
                if f == NONE {
                    continue;
                }
                let before = self.m.face_normal(f);
                let after = self.m.face_normal_with(f, v, &q);
                ok &= after.norm() > 1e-12 * before.norm() && before.dot(&after) > 0.0;
                worst_before = worst_before.min(self.min_angle_with(f, v, &self.m.pos[v as usize]));
                worst_after = worst_after.min(self.min_angle_with(f, v, &q));
            }
            // Never make the worst angle around the vertex worse once it is below 30°.
            if ok && worst_after >= worst_before.min(MIN_ANGLE_GUARD) {
                self.m.pos[v as usize] = q;
            }
        }
    }

    /// Move towards `goal` triangles: split the longest edges or collapse the shortest ones
    /// (without creating edges longer than `4/3 length`), at most one operation per
    /// neighbourhood when `spread`. Stops at the goal or when no candidate is left.
    fn change_count(&mut self, goal: usize, length: f64, spread: bool) {
        let hi = 4.0 / 3.0 * length;
        let n = self.m.n_edge_slots() as u32;
        let mut touched = vec![false; self.m.n_vertex_slots()];
        let mut edges: Vec<(f64, u32)> = (0..n)
            .filter(|&e| !self.m.edge_deleted(e))
            .map(|e| (self.m.edge_length(e), e))
            .collect();
        let faces = self.m.n_faces();
        if faces == goal {
            return;
        }
        let grow = faces < goal;
        // Longest first when splitting, shortest first when collapsing.
        edges.sort_by(|a, b| {
            let by_length = if grow {
                b.0.total_cmp(&a.0)
            } else {
                a.0.total_cmp(&b.0)
            };
            by_length.then(a.1.cmp(&b.1))
        });
        for (_, e) in edges {
            let faces = self.m.n_faces();
            let missing = if grow {
                goal.saturating_sub(faces)
            } else {
                faces.saturating_sub(goal)
            };
            if missing == 0 {
                break;
            }
            if self.m.edge_deleted(e) {
                continue;
            }
            let (a, b) = (self.m.from(2 * e), self.m.to(2 * e));
            let boundary = self.m.is_boundary_edge(e);
            // One triangle to go needs a boundary operation (±1), more an interior one (±2).
            if (missing == 1) != boundary || spread && (touched[a as usize] || touched[b as usize])
            {
                continue;
            }
            if grow {
                self.split_edge(e);
                touched.push(true);
                touched[a as usize] = true;
                touched[b as usize] = true;
            } else if let Some(kept) = self.collapse_edge(e, Some(hi)) {
                touched[kept as usize] = true;
                for h in self.m.outgoing(kept) {
                    touched[self.m.to(h) as usize] = true;
                }
            }
        }
    }

    /// Reach exactly `target` triangles: [`Self::change_count`] without spreading, then
    /// without the length limit, then (for a last odd triangle that no boundary collapse can
    /// remove) a boundary split followed by an interior collapse.
    fn reach_count(&mut self, target: usize, length: f64) -> Result<()> {
        for attempt in 0..8 {
            if self.m.n_faces() == target {
                return Ok(());
            }
            match attempt {
                0..=2 => self.change_count(target, length, false),
                3..=5 => self.change_count(target, 1e3 * length, false),
                _ => {
                    // Parity: one triangle too many and no boundary edge can collapse.
                    let faces = self.m.n_faces();
                    self.change_count(faces + 1, length, false);
                    self.change_count(target, 1e3 * length, false);
                }
            }
        }
        if self.m.n_faces() == target {
            return Ok(());
        }
        Err(Error::invalid(
            "remeshing target",
            format!(
                "could not reach {target} triangles (stuck at {})",
                self.m.n_faces()
            ),
        ))
    }
}

/// The closest point on segment `[a, b]` to `p`.
fn closest_on_segment(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> Vector3<f64> {
    let ab = b - a;
    let len2 = ab.norm_squared();
    if len2 <= 0.0 {
        return *a;
    }
    a + ab * ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
}
