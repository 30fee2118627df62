//! Closest points on a triangle mesh, with signed distance: the one closest-point query of
//! sartor, used for cloth binding, body contact, the runtime's collision post-process and garment
//! checks.
//!
//! A bounding-volume hierarchy over the triangles (eight children to a node, f32 boxes that only
//! prune, every answer computed in f64: [`wide`]) answers "closest point to p", with the
//! triangle, barycentric coordinates and a signed distance whose sign comes from angle-weighted
//! pseudo-normals (Bærentzen & Aanæs 2005): negative inside a closed, outward-oriented surface.
//! The tree can be refitted to moved vertices without rebuilding (for an animated body)
//! ([`MeshProximity::update_positions`]). A caller that finds its candidate triangles itself can
//! move the vertices without refitting ([`MeshProximity::update_positions_lazy`]): the
//! pseudo-normals are then computed per answer (bitwise the same), and the tree queries test
//! every triangle until the next refit.

use nalgebra::Vector3;

use crate::tree::MedianTree;
use crate::{Error, Result};

mod wide;

use wide::WideTree;

const LEAF_SIZE: usize = 4;

/// The answer to a closest-point query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestPoint {
    /// Index of the closest triangle (into the faces given at construction).
    pub face: u32,
    /// The closest point on the surface.
    pub point: Vector3<f64>,
    /// Barycentric coordinates of `point` in `face`.
    pub barycentric: [f64; 3],
    /// Distance to the surface, negative when `p` is inside (behind the pseudo-normal).
    pub signed_distance_m: f64,
    /// Unit pseudo-normal of the closest feature (face, edge or vertex).
    pub normal: Vector3<f64>,
}

/// A closest-point structure over a triangle mesh (or any subset of its faces).
#[derive(Clone, Debug)]
pub struct MeshProximity {
    faces: Vec<[u32; 3]>,
    positions: Vec<Vector3<f64>>,
    /// The hierarchy over the faces (its structure and order), and its boxes: eight children to
    /// a node, in f32 ([`wide`]), refitted to every move.
    tree: MedianTree,
    wide: WideTree,
    face_normals: Vec<Vector3<f64>>,
    /// Per face, pseudo-normal of edges (v0 v1), (v1 v2), (v2 v0).
    edge_normals: Vec<[Vector3<f64>; 3]>,
    vertex_normals: Vec<Vector3<f64>>,
    /// Per face and corner edge k: the neighbour face across it (or u32::MAX).
    neighbours: Vec<[u32; 3]>,
    /// Per vertex (CSR), the `(face, corner)` pairs that use it, in face order: the terms of its
    /// angle-weighted normal in the order `update_normals` adds them.
    corner_offsets: Vec<u32>,
    corners: Vec<(u32, u8)>,
    /// Whether the stored normals belong to the current positions; if not, `answer` computes
    /// the one it needs.
    normals_current: bool,
    /// Whether the tree's boxes belong to the current positions; if not, the tree queries test
    /// every triangle.
    tree_current: bool,
}

impl MeshProximity {
    /// Build over `faces` (indices into `positions`, which may hold unused vertices — e.g. a body
    /// region given as a subset of the body's faces).
    pub fn new(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Result<Self> {
        if faces.is_empty() {
            return Err(Error::invalid("proximity mesh", "no triangles"));
        }
        if let Some(f) = faces
            .iter()
            .position(|t| t.iter().any(|&i| i as usize >= positions.len()))
        {
            return Err(Error::invalid(
                "proximity mesh",
                format!("triangle {f} indexes past {} vertices", positions.len()),
            ));
        }
        if !positions.iter().all(|p| p.iter().all(|c| c.is_finite())) {
            return Err(Error::invalid("proximity mesh", "non-finite vertex"));
        }
        let topo = crate::MeshTopology::new(positions.len(), faces);
        let mut neighbours = vec![[u32::MAX; 3]; faces.len()];
        for (f, edges) in topo.face_edges.iter().enumerate() {
            for k in 0..3 {
                let around = &topo.edge_faces[edges[k] as usize];
                if around.len() == 2 {
                    neighbours[f][k] = if around[0] as usize == f {
                        around[1]
                    } else {
                        around[0]
                    };
                }
            }
        }
        let mut corner_offsets = vec![0u32; positions.len() + 1];
        for t in faces {
            for &v in t {
                corner_offsets[v as usize + 1] += 1;
            }
        }
        for v in 0..positions.len() {
            corner_offsets[v + 1] += corner_offsets[v];
        }
        let mut corners = vec![(0u32, 0u8); faces.len() * 3];
        let mut fill = corner_offsets.clone();
        for (f, t) in faces.iter().enumerate() {
            for (k, &v) in t.iter().enumerate() {
                corners[fill[v as usize] as usize] = (f as u32, k as u8);
                fill[v as usize] += 1;
            }
        }
        let mut s = Self {
            faces: faces.to_vec(),
            positions: positions.to_vec(),
            tree: MedianTree::new(&[], LEAF_SIZE),
            wide: WideTree::default(),
            face_normals: Vec::new(),
            edge_normals: Vec::new(),
            vertex_normals: Vec::new(),
            neighbours,
            corner_offsets,
            corners,
            normals_current: false,
            tree_current: true,
        };
        let centroids: Vec<Vector3<f64>> = faces
            .iter()
            .map(|t| s.tri(t).iter().sum::<Vector3<f64>>() / 3.0)
            .collect();
        s.tree = MedianTree::new(&centroids, LEAF_SIZE);
        s.wide = WideTree::new(&s.tree);
        s.refit_tree();
        s.update_normals();
        Ok(s)
    }

    fn tri(&self, t: &[u32; 3]) -> [Vector3<f64>; 3] {
        t.map(|i| self.positions[i as usize])
    }

    /// Face `f`'s corners where they lie, for the distance tests: a copy ([`Self::tri`])
    /// returned by value was copied on in 16-byte pieces across the 24-byte vectors just
    /// stored, each piece waiting for its two stores to retire (a store-to-load forwarding
    /// failure, 5 % of the listing walk's samples).
    #[inline(always)]
    fn face_corners(&self, f: u32) -> [&Vector3<f64>; 3] {
        self.faces[f as usize].map(|i| &self.positions[i as usize])
    }

    fn update_normals(&mut self) {
        let n_f = self.faces.len();
        self.face_normals.clear();
        for t in &self.faces {
            self.face_normals.push(face_normal(self.tri(t)));
        }
        self.vertex_normals.clear();
        self.vertex_normals
            .resize(self.positions.len(), Vector3::zeros());
        for (t, n) in self.faces.iter().zip(&self.face_normals) {
            let p = self.tri(t);
            for k in 0..3 {
                self.vertex_normals[t[k] as usize] += corner_angle(&p, k) * n;
            }
        }
        for n in &mut self.vertex_normals {
            *n = n.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
        }
        self.edge_normals.clear();
        self.edge_normals.resize(n_f, [Vector3::zeros(); 3]);
        for f in 0..n_f {
            for k in 0..3 {
                let g = self.neighbours[f][k];
                let other = (g != u32::MAX).then(|| self.face_normals[g as usize]);
                self.edge_normals[f][k] = edge_normal(&self.face_normals[f], other.as_ref());
            }
        }
        self.normals_current = true;
    }

    /// The unit normal of face `f` at the current positions (zero for a degenerate face): the
    /// stored one, or computed with the same arithmetic.
    fn face_normal_now(&self, f: u32) -> Vector3<f64> {
        if self.normals_current {
            self.face_normals[f as usize]
        } else {
            face_normal(self.tri(&self.faces[f as usize]))
        }
    }

    /// The pseudo-normal of `feature` of `face` at the current positions: the stored one, or
    /// computed term by term in the order [`Self::update_normals`] uses (bitwise the same).
    fn feature_normal(&self, face: u32, feature: ClosestFeature) -> Vector3<f64> {
        let t = self.faces[face as usize];
        if self.normals_current {
            return match feature {
                ClosestFeature::Face => self.face_normals[face as usize],
                ClosestFeature::Edge(k) => self.edge_normals[face as usize][k],
                ClosestFeature::Vertex(k) => self.vertex_normals[t[k] as usize],
            };
        }
        match feature {
            ClosestFeature::Face => self.face_normal_now(face),
            ClosestFeature::Edge(k) => {
                let g = self.neighbours[face as usize][k];
                let other = (g != u32::MAX).then(|| self.face_normal_now(g));
                edge_normal(&self.face_normal_now(face), other.as_ref())
            }
            ClosestFeature::Vertex(k) => {
                let v = t[k] as usize;
                let (a, b) = (
                    self.corner_offsets[v] as usize,
                    self.corner_offsets[v + 1] as usize,
                );
                let mut sum = Vector3::zeros();
                for &(f, corner) in &self.corners[a..b] {
                    let p = self.tri(&self.faces[f as usize]);
                    sum += corner_angle(&p, corner as usize) * face_normal(p);
                }
                sum.try_normalize(0.0).unwrap_or_else(Vector3::zeros)
            }
        }
    }

    /// Move the vertices (same count as at construction) and refit the tree and the normals.
    /// No allocation.
    pub fn update_positions(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.refit(positions)?;
        self.update_normals();
        Ok(())
    }

    /// Move the vertices and refit the tree, but leave the pseudo-normals to be computed with
    /// each answer (bitwise equal to the ones [`Self::update_positions`] would store, as with
    /// [`Self::update_positions_lazy`]): for callers asking a few answers per move, such as a
    /// simulator's substep over a body of many more triangles than contacts. No allocation.
    pub fn update_positions_refit(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.refit(positions)?;
        self.normals_current = false;
        Ok(())
    }

    /// Start a linear move of the vertices from `start` to `end` (both as many as at
    /// construction): the tree's boxes are fitted at both ends, once, and
    /// [`Self::update_positions_on_span`] then moves the vertices to any point of the way with
    /// boxes interpolated between the two instead of refitted. The vertices are moved to
    /// `start`. As with [`Self::update_positions_refit`], the pseudo-normals are left to the
    /// answers. No allocation after the first span.
    pub fn set_span(&mut self, start: &[Vector3<f64>], end: &[Vector3<f64>]) -> Result<()> {
        self.check_positions(start)?;
        self.check_positions(end)?;
        self.positions.copy_from_slice(start);
        self.wide
            .fit_span(start, end, &self.faces, self.tree.order());
        self.tree_current = true;
        self.normals_current = false;
        Ok(())
    }

    /// Move the vertices to `positions`, which must be `start + (end − start) · a` of the
    /// last [`Self::set_span`] (`start` itself at `a = 0`, `end` itself at `a = 1`), `a` in
    /// `[0, 1]`: the tree's boxes are interpolated between the span's ends, padded by their
    /// rounding, not refitted (`wide::WideTree::interpolate`). The answers are those after
    /// [`Self::update_positions_refit`]: the boxes only prune, and every triangle they keep
    /// is tested exactly. Not checked: `positions` off the span may miss triangles.
    pub fn update_positions_on_span(&mut self, positions: &[Vector3<f64>], a: f64) -> Result<()> {
        self.check_positions(positions)?;
        if !(0.0..=1.0).contains(&a) {
            return Err(Error::invalid(
                "proximity mesh",
                format!("a span's fraction must lie in [0, 1], got {a}"),
            ));
        }
        if !self.wide.interpolate(a) {
            return Err(Error::invalid(
                "proximity mesh",
                "a move on a span before set_span",
            ));
        }
        self.positions.copy_from_slice(positions);
        self.tree_current = true;
        self.normals_current = false;
        Ok(())
    }

    /// Move the vertices without refitting the tree or recomputing the pseudo-normals: for
    /// callers that find their candidate triangles themselves and ask [`Self::closest_among`] /
    /// [`Self::distance_to_face`], which answer for the new positions at once (each answer
    /// computes the normal of its closest feature, bitwise equal to the stored one
    /// [`Self::update_positions`] would give). Until the next [`Self::update_positions`], the
    /// tree queries ([`Self::closest`], [`Self::closest_within`], [`Self::faces_within`],
    /// [`Self::for_each_face_near`]) test every triangle: the same answers, slower. No
    /// allocation.
    pub fn update_positions_lazy(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.check_positions(positions)?;
        self.positions.copy_from_slice(positions);
        self.normals_current = false;
        self.tree_current = false;
        Ok(())
    }

    fn check_positions(&self, positions: &[Vector3<f64>]) -> Result<()> {
        if positions.len() != self.positions.len() {
            return Err(Error::invalid(
                "proximity mesh",
                format!(
                    "{} positions for {} vertices",
                    positions.len(),
                    self.positions.len()
                ),
            ));
        }
        if !positions.iter().all(|p| p.iter().all(|c| c.is_finite())) {
            return Err(Error::invalid("proximity mesh", "non-finite vertex"));
        }
        Ok(())
    }

    /// Copy the positions and refit the tree's boxes.
    fn refit(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.check_positions(positions)?;
        self.positions.copy_from_slice(positions);
        self.refit_tree();
        self.tree_current = true;
        Ok(())
    }

    /// The tree's boxes from the current positions.
    fn refit_tree(&mut self) {
        self.wide
            .refit(&self.positions, &self.faces, self.tree.order());
    }

    /// The vertex positions currently used.
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// The triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Closest point on the surface to `p`.
    pub fn closest(&self, p: &Vector3<f64>) -> ClosestPoint {
        self.closest_within(p, f64::INFINITY)
            .expect("an unbounded search always finds a triangle")
    }

    /// Closest point on the surface to `p` if it is within `max_distance_m`.
    pub fn closest_within(&self, p: &Vector3<f64>, max_distance_m: f64) -> Option<ClosestPoint> {
        let mut best_d2 = max_distance_m * max_distance_m;
        let mut best: Option<(u32, Vector3<f64>, [f64; 3], ClosestFeature)> = None;
        if !self.tree_current {
            for f in 0..self.faces.len() as u32 {
                self.consider(p, f, &mut best_d2, &mut best);
            }
            let (face, point, barycentric, feature) = best?;
            return Some(self.answer(p, face, point, barycentric, feature));
        }
        self.wide
            .search(p, self.tree.order(), &mut best_d2, |f, best_d2| {
                self.consider(p, f, best_d2, &mut best)
            });
        let (face, point, barycentric, feature) = best?;
        Some(self.answer(p, face, point, barycentric, feature))
    }

    /// [`Self::closest_within`] started from a hint: `hint` is a face that is likely close
    /// to `p` (typically the answer of the previous query of the same moving point;
    /// `u32::MAX` or an index out of range: none). The distance to it bounds the search from
    /// the start, which prunes most of the tree at once; the answer is exactly that of
    /// [`Self::closest_within`] (same face, tie rule and sign), whatever the hint. On a hit,
    /// `hint` becomes the face found.
    pub fn closest_within_hinted(
        &self,
        p: &Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
    ) -> Option<ClosestPoint> {
        let mut bound = max_distance_m;
        if (*hint as usize) < self.faces.len() {
            let tri = self.face_corners(*hint);
            let d = (closest_on_triangle(p, tri).0 - p).norm();
            // Slightly above the distance, so that the face itself passes the bound test: every
            // face the unbounded search could return is within it.
            bound = bound.min(d * (1.0 + 1e-9) + 1e-12);
        }
        let hit = self.closest_within(p, bound);
        if let Some(c) = &hit {
            *hint = c.face;
        }
        hit
    }

    /// [`Self::closest_within_hinted`] that also lists, in `near`, every face within the
    /// answer's distance plus `margin_m` of `p`, nearest first (ties by face index): with them
    /// [`Self::closest_within_near`] answers the queries that follow at a point that has moved,
    /// relative to the mesh, by at most `margin_m / 2`. One walk of the tree, bounded by the
    /// hint's distance plus the margin. `near` is left empty when there is no answer, no
    /// usable hint, or more faces than fit.
    pub fn closest_within_listing(
        &self,
        p: &Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
        margin_m: f64,
        near: &mut NearFaces,
    ) -> Option<ClosestPoint> {
        near.len = 0;
        if !self.tree_current || (*hint as usize) >= self.faces.len() {
            return self.closest_within_hinted(p, max_distance_m, hint);
        }
        let tri = self.face_corners(*hint);
        let d = (closest_on_triangle(p, tri).0 - p).norm();
        // `closest_within_hinted`'s bound, and every face within it plus the margin.
        let bound = max_distance_m.min(d * (1.0 + 1e-9) + 1e-12);
        let reach = bound + margin_m;
        let reach2 = reach * reach;
        let mut found = [(0.0f64, 0u32); GATHER];
        let mut n = 0;
        let mut fits = true;
        let mut best_d2 = bound * bound;
        let mut best: Option<(u32, Vector3<f64>, [f64; 3], ClosestFeature)> = None;
        self.for_each_face_near(p, reach, |f| {
            let tri = self.face_corners(f);
            let (q, bary, feature) = closest_on_triangle(p, tri);
            let d2 = (q - p).norm_squared();
            if d2 > reach2 {
                return;
            }
            // `consider`'s rule, without its box test (the face is computed anyway).
            take_if_better((f, q, bary, feature), d2, &mut best_d2, &mut best);
            if n == GATHER {
                fits = false;
                return;
            }
            found[n] = (d2, f);
            n += 1;
        });
        let (face, point, barycentric, feature) = best?;
        *hint = face;
        if fits {
            let keep = (best_d2.sqrt() + margin_m).powi(2);
            let found = &mut found[..n];
            found.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let kept = found.iter().take_while(|e| e.0 <= keep).count();
            if kept <= NearFaces::CAPACITY {
                for (slot, &(_, f)) in near.faces.iter_mut().zip(found[..kept].iter()) {
                    *slot = f;
                }
                near.len = kept as u8;
            }
        }
        Some(self.answer(p, face, point, barycentric, feature))
    }

    /// The answer of [`Self::closest_within_hinted`] from the faces `near` listed by
    /// [`Self::closest_within_listing`] alone, no tree walk. The same answer (face, tie rule,
    /// sign), provided that since the listing the point has moved by at most half the listing's
    /// margin relative to the mesh: by at most `m / 2` plus the farthest any point of the mesh
    /// has moved, with `m` the margin. (Each face's distance then changed by at most `m / 2`:
    /// the face listed nearest is still within `d + m / 2`, an unlisted one still beyond it.)
    /// `hint` becomes the face found.
    pub fn closest_within_near(
        &self,
        p: &Vector3<f64>,
        max_distance_m: f64,
        hint: &mut u32,
        near: &NearFaces,
    ) -> Option<ClosestPoint> {
        let nearest = self.nearest_among(p, near.faces())?;
        // `closest_within`'s acceptance: the squared distance within the squared bound.
        if nearest.distance_sq > max_distance_m * max_distance_m {
            return None;
        }
        *hint = nearest.face;
        Some(self.signed(p, &nearest))
    }

    /// Closest point to `p` among the triangles `faces` only (indices into [`Self::faces`]),
    /// with the same tie rule, sign and normal as [`Self::closest`]; `None` when `faces` is
    /// empty. For callers that know in advance which few triangles can be closest (e.g. a
    /// cloth vertex and the body triangles near it at rest): no tree walk.
    ///
    /// # Panics
    /// If a face index is out of range.
    pub fn closest_among(&self, p: &Vector3<f64>, faces: &[u32]) -> Option<ClosestPoint> {
        let nearest = self.nearest_among(p, faces)?;
        Some(self.signed(p, &nearest))
    }

    /// The nearest of the triangles `faces` to `p`, with the tie rule of [`Self::closest`], but
    /// not its sign and normal (no pseudo-normal is computed): for callers that decide from the
    /// distance and the feature whether they need them. `None` when `faces` is empty. Faces
    /// are tested in the order given: put the likely nearest first.
    ///
    /// # Panics
    /// If a face index is out of range.
    pub fn nearest_among(&self, p: &Vector3<f64>, faces: &[u32]) -> Option<NearestFace> {
        let mut best_d2 = f64::INFINITY;
        let mut best: Option<(u32, Vector3<f64>, [f64; 3], ClosestFeature)> = None;
        for &f in faces {
            self.consider(p, f, &mut best_d2, &mut best);
        }
        let (face, point, barycentric, feature) = best?;
        Some(NearestFace {
            face,
            point,
            barycentric,
            feature,
            distance_sq: best_d2,
        })
    }

    /// The full answer for a [`NearestFace`] of `p` (sign and pseudo-normal):
    /// `closest_among(p, faces) == nearest_among(p, faces).map(|n| signed(p, &n))`.
    pub fn signed(&self, p: &Vector3<f64>, nearest: &NearestFace) -> ClosestPoint {
        self.answer(
            p,
            nearest.face,
            nearest.point,
            nearest.barycentric,
            nearest.feature,
        )
    }

    /// Test face `f` against the best so far (smaller distance wins, ties go to the smaller
    /// face index; with no best yet, any face within `best_d2` is taken).
    #[inline]
    fn consider(
        &self,
        p: &Vector3<f64>,
        f: u32,
        best_d2: &mut f64,
        best: &mut Option<(u32, Vector3<f64>, [f64; 3], ClosestFeature)>,
    ) {
        let tri = self.face_corners(f);
        // The triangle's box is a cheap lower bound: skip triangles that cannot beat the best
        // so far (same results, a fraction of the work).
        if triangle_box_distance_sq(p, tri) > *best_d2 {
            return;
        }
        let (q, bary, feature) = closest_on_triangle(p, tri);
        take_if_better((f, q, bary, feature), (q - p).norm_squared(), best_d2, best);
    }

    /// Every triangle within `radius_m` of `p`, as `(face, distance_m)` sorted by distance
    /// (ties by face index). Allocates the result.
    pub fn faces_within(&self, p: &Vector3<f64>, radius_m: f64) -> Vec<(u32, f64)> {
        let r2 = radius_m * radius_m;
        let mut found = Vec::new();
        if !self.tree_current {
            for f in 0..self.faces.len() as u32 {
                let tri = self.face_corners(f);
                let d2 = (closest_on_triangle(p, tri).0 - p).norm_squared();
                if d2 <= r2 {
                    found.push((f, d2.sqrt()));
                }
            }
            found.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            return found;
        }
        let mut reach2 = r2;
        self.wide.search(p, self.tree.order(), &mut reach2, |f, _| {
            let tri = self.face_corners(f);
            let d2 = (closest_on_triangle(p, tri).0 - p).norm_squared();
            if d2 <= r2 {
                found.push((f, d2.sqrt()));
            }
        });
        found.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        found
    }

    /// Visit every triangle whose axis-aligned box the half-line `p + t d` (`t ≥ 0`) may meet
    /// (a superset: the boxes are padded by their f32 rounding), in no set order; `visit`
    /// returning `None` stops the walk, which then returns `None`. No allocation.
    pub(crate) fn for_each_face_on_ray(
        &self,
        p: &Vector3<f64>,
        d: &Vector3<f64>,
        visit: impl FnMut(u32) -> Option<()>,
    ) -> Option<()> {
        if !self.tree_current {
            return (0..self.faces.len() as u32).try_for_each(visit);
        }
        self.wide.ray(p, d, self.tree.order(), visit)
    }

    /// Visit every triangle whose axis-aligned box lies within `radius_m` of `p` (a superset of
    /// the triangles within `radius_m`: the box is a lower bound of the distance), nearer parts
    /// of the tree first. No allocation. For callers that gather the few triangles near a group of points
    /// once and then test them themselves.
    pub fn for_each_face_near(&self, p: &Vector3<f64>, radius_m: f64, mut visit: impl FnMut(u32)) {
        let r2 = radius_m * radius_m;
        // A NaN point visits nothing.
        if p.iter().any(|c| c.is_nan()) {
            return;
        }
        if !self.tree_current {
            for f in 0..self.faces.len() as u32 {
                if triangle_box_distance_sq(p, self.face_corners(f)) <= r2 {
                    visit(f);
                }
            }
            return;
        }
        let mut reach2 = r2;
        self.wide.search(p, self.tree.order(), &mut reach2, |f, _| {
            if triangle_box_distance_sq(p, self.face_corners(f)) <= r2 {
                visit(f);
            }
        });
    }

    /// Unsigned distance from `p` to triangle `face` (the distance [`Self::closest`] compares).
    ///
    /// # Panics
    /// If `face` is out of range.
    pub fn distance_to_face(&self, p: &Vector3<f64>, face: u32) -> f64 {
        let tri = self.face_corners(face);
        (closest_on_triangle(p, tri).0 - p).norm()
    }

    /// The query result for the closest `point` of `face` (on `feature`) to `p`.
    fn answer(
        &self,
        p: &Vector3<f64>,
        face: u32,
        point: Vector3<f64>,
        barycentric: [f64; 3],
        feature: ClosestFeature,
    ) -> ClosestPoint {
        let normal = self.feature_normal(face, feature);
        let d = (p - point).norm();
        let sign = if (p - point).dot(&normal) < 0.0 {
            -1.0
        } else {
            1.0
        };
        ClosestPoint {
            face,
            point,
            barycentric,
            signed_distance_m: sign * d,
            normal,
        }
    }
}

/// The closest-point rule of every query: face `candidate` at squared distance `d2` becomes
/// the best if it is nearer than `best_d2`, or as near with a smaller index; with no best yet,
/// any face within `best_d2` (the query's bound) is taken.
#[inline]
fn take_if_better(
    candidate: (u32, Vector3<f64>, [f64; 3], ClosestFeature),
    d2: f64,
    best_d2: &mut f64,
    best: &mut Option<(u32, Vector3<f64>, [f64; 3], ClosestFeature)>,
) {
    let better = d2 < *best_d2 || (d2 == *best_d2 && best.is_some_and(|b| candidate.0 < b.0));
    if better || (best.is_none() && d2 <= *best_d2) {
        *best_d2 = d2;
        *best = Some(candidate);
    }
}

/// The most faces [`MeshProximity::closest_within_listing`] gathers within its reach.
const GATHER: usize = 32;

/// The faces of a mesh near a point, nearest first, as [`MeshProximity::closest_within_listing`]
/// lists them for [`MeshProximity::closest_within_near`]; at most [`NearFaces::CAPACITY`] (a
/// cache line with the count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NearFaces {
    len: u8,
    faces: [u32; Self::CAPACITY],
}

impl NearFaces {
    /// The most faces a list holds.
    pub const CAPACITY: usize = 15;

    /// No list.
    pub const EMPTY: Self = Self {
        len: 0,
        faces: [0; Self::CAPACITY],
    };

    /// The faces listed (none: no list).
    pub fn faces(&self) -> &[u32] {
        &self.faces[..self.len as usize]
    }

    /// Whether nothing is listed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Forget the list.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

/// The feature of a triangle its closest point lies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClosestFeature {
    /// The interior: the pseudo-normal is the face's normal.
    Face,
    /// Edge `k` = corners `(k, k + 1 mod 3)`: the mean of its faces' normals.
    Edge(usize),
    /// Corner `k`: the angle-weighted normal of the faces around that vertex.
    Vertex(usize),
}

/// The nearest triangle to a point among some, before the sign ([`MeshProximity::nearest_among`];
/// [`MeshProximity::signed`] completes it into a [`ClosestPoint`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearestFace {
    /// Index of the triangle.
    pub face: u32,
    /// The closest point on it.
    pub point: Vector3<f64>,
    /// Barycentric coordinates of `point`.
    pub barycentric: [f64; 3],
    /// The feature `point` lies on.
    pub feature: ClosestFeature,
    /// Squared distance from the query point, m².
    pub distance_sq: f64,
}

/// Unit normal of a triangle (zero when degenerate).
#[inline]
fn face_normal([a, b, c]: [Vector3<f64>; 3]) -> Vector3<f64> {
    (b - a)
        .cross(&(c - a))
        .try_normalize(0.0)
        .unwrap_or_else(Vector3::zeros)
}

/// The angle of triangle `p` at corner `k`, radians (the weight of its normal in the vertex's
/// pseudo-normal).
#[inline]
fn corner_angle(p: &[Vector3<f64>; 3], k: usize) -> f64 {
    let e1 = (p[(k + 1) % 3] - p[k])
        .try_normalize(0.0)
        .unwrap_or_else(Vector3::zeros);
    let e2 = (p[(k + 2) % 3] - p[k])
        .try_normalize(0.0)
        .unwrap_or_else(Vector3::zeros);
    e1.dot(&e2).clamp(-1.0, 1.0).acos()
}

/// The pseudo-normal of an edge: the mean of its two faces' normals (its face's alone on a
/// boundary, or when they cancel).
#[inline]
fn edge_normal(face: &Vector3<f64>, other: Option<&Vector3<f64>>) -> Vector3<f64> {
    let sum = match other {
        Some(g) => face + g,
        None => *face,
    };
    sum.try_normalize(0.0).unwrap_or(*face)
}

/// Squared distance from `p` to the axis-aligned box of the triangle. Comparisons instead of
/// `f64::min` / `max`, whose NaN rule costs a blend per call: the same value for finite input,
/// and a NaN point still gives a box distance of 0 (its triangle distance is NaN, which never
/// wins).
#[inline]
fn triangle_box_distance_sq(p: &Vector3<f64>, [a, b, c]: [&Vector3<f64>; 3]) -> f64 {
    let min = |x: f64, y: f64| if x < y { x } else { y };
    let max = |x: f64, y: f64| if x > y { x } else { y };
    let mut d2 = 0.0;
    for k in 0..3 {
        let lo = min(min(a[k], b[k]), c[k]);
        let hi = max(max(a[k], b[k]), c[k]);
        let d = max(max(lo - p[k], p[k] - hi), 0.0);
        d2 += d * d;
    }
    d2
}

/// Closest point on triangle `[a, b, c]` to `p` (Ericson, Real-Time Collision Detection §5.1.5),
/// with barycentrics and the feature it lies on.
///
/// Without branches: every region's answer is computed by Ericson's formula, and the region
/// his tests pick, in his order, indexes them. Which region a face near a point answers from
/// is as good as random (the face under the point from its interior, its neighbours from an
/// edge or a vertex), and his early returns mispredicted. The same numbers: each answer's
/// arithmetic is his, and the unused ones (maybe a division by zero) are dropped.
#[inline(always)]
fn closest_on_triangle(
    p: &Vector3<f64>,
    [a, b, c]: [&Vector3<f64>; 3],
) -> (Vector3<f64>, [f64; 3], ClosestFeature) {
    use std::hint::select_unpredictable as pick;
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    let vc = d1 * d4 - d3 * d2;
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    let vb = d5 * d2 - d1 * d6;
    let va = d3 * d6 - d5 * d4;
    // Ericson's tests, the first that holds deciding (`&`, not `&&`: no branch).
    let tests = [
        (d1 <= 0.0) & (d2 <= 0.0),
        (d3 >= 0.0) & (d4 <= d3),
        (vc <= 0.0) & (d1 >= 0.0) & (d3 <= 0.0),
        (d6 >= 0.0) & (d5 <= d6),
        (vb <= 0.0) & (d2 >= 0.0) & (d6 <= 0.0),
        (va <= 0.0) & ((d4 - d3) >= 0.0) & ((d5 - d6) >= 0.0),
    ];
    let mut region = tests.len();
    for (k, &holds) in tests.iter().enumerate().rev() {
        region = pick(holds, k, region);
    }
    let v_ab = d1 / (d1 - d3);
    let w_ac = d2 / (d2 - d6);
    let w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    let points = [
        *a,
        *b,
        a + ab * v_ab,
        *c,
        a + ac * w_ac,
        b + (c - b) * w_bc,
        a + ab * v + ac * w,
    ];
    let barycentric = [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0 - v_ab, v_ab, 0.0],
        [0.0, 0.0, 1.0],
        [1.0 - w_ac, 0.0, w_ac],
        [0.0, 1.0 - w_bc, w_bc],
        [1.0 - v - w, v, w],
    ];
    let features = [
        ClosestFeature::Vertex(0),
        ClosestFeature::Vertex(1),
        ClosestFeature::Edge(0),
        ClosestFeature::Vertex(2),
        ClosestFeature::Edge(2),
        ClosestFeature::Edge(1),
        ClosestFeature::Face,
    ];
    (points[region], barycentric[region], features[region])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ericson's closest point with his early returns: the oracle of the branchless version.
    fn closest_on_triangle_branching(
        p: &Vector3<f64>,
        [a, b, c]: [&Vector3<f64>; 3],
    ) -> (Vector3<f64>, [f64; 3], ClosestFeature) {
        let (ab, ac, ap) = (b - a, c - a, p - a);
        let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
        if d1 <= 0.0 && d2 <= 0.0 {
            return (*a, [1.0, 0.0, 0.0], ClosestFeature::Vertex(0));
        }
        let bp = p - b;
        let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
        if d3 >= 0.0 && d4 <= d3 {
            return (*b, [0.0, 1.0, 0.0], ClosestFeature::Vertex(1));
        }
        let vc = d1 * d4 - d3 * d2;
        if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            let v = d1 / (d1 - d3);
            return (a + ab * v, [1.0 - v, v, 0.0], ClosestFeature::Edge(0));
        }
        let cp = p - c;
        let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
        if d6 >= 0.0 && d5 <= d6 {
            return (*c, [0.0, 0.0, 1.0], ClosestFeature::Vertex(2));
        }
        let vb = d5 * d2 - d1 * d6;
        if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            let w = d2 / (d2 - d6);
            return (a + ac * w, [1.0 - w, 0.0, w], ClosestFeature::Edge(2));
        }
        let va = d3 * d6 - d5 * d4;
        if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            return (b + (c - b) * w, [0.0, 1.0 - w, w], ClosestFeature::Edge(1));
        }
        let denom = 1.0 / (va + vb + vc);
        let (v, w) = (vb * denom, vc * denom);
        (
            a + ab * v + ac * w,
            [1.0 - v - w, v, w],
            ClosestFeature::Face,
        )
    }

    #[test]
    fn the_branchless_closest_point_is_ericson_s_bit_for_bit() {
        // Points around triangles from regular to slivers and degenerate ones (two corners
        // equal, all three on a line), every region answering.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut seen = std::collections::BTreeSet::new();
        for k in 0..20_000 {
            let mut t: [Vector3<f64>; 3] =
                std::array::from_fn(|_| Vector3::new(next(), next(), next()));
            match k % 50 {
                0 => t[1] = t[0],
                1 => t[2] = t[0] + (t[1] - t[0]) * 0.5,
                _ => {}
            }
            let p = Vector3::new(next(), next(), next()) * 2.0;
            let tri = [&t[0], &t[1], &t[2]];
            let (q, bary, feature) = closest_on_triangle(&p, tri);
            let (q0, bary0, feature0) = closest_on_triangle_branching(&p, tri);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(q.as_slice()), bits(q0.as_slice()), "{p} {t:?}");
            assert_eq!(bits(&bary), bits(&bary0), "{p} {t:?}");
            assert_eq!(feature, feature0, "{p} {t:?}");
            seen.insert(format!("{feature:?}"));
        }
        assert_eq!(seen.len(), 7, "every region answered: {seen:?}");
    }

    /// An axis-aligned unit cube centred at the origin, outward-oriented.
    fn cube() -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        crate::box_mesh(Vector3::repeat(-0.5), Vector3::repeat(0.5))
    }

    #[test]
    fn signed_distance_to_a_cube() {
        let (p, f) = cube();
        let m = MeshProximity::new(&p, &f).expect("valid");
        let cases = [
            (Vector3::new(0.0, 0.0, 0.0), -0.5),
            (Vector3::new(0.1, 0.2, 0.45), -0.05),
            (Vector3::new(0.0, 0.0, 0.7), 0.2),
            (Vector3::new(0.7, 0.7, 0.0), (0.08f64).sqrt()), // edge region
            (Vector3::new(0.6, 0.6, 0.6), (0.03f64).sqrt()), // vertex region
            (Vector3::new(0.49, 0.49, 0.0), -0.01),          // inside near an edge
        ];
        for (q, expected) in cases {
            let c = m.closest(&q);
            assert!(
                (c.signed_distance_m - expected).abs() < 1e-12,
                "{q}: {} vs {expected}",
                c.signed_distance_m
            );
            let t = f[c.face as usize];
            let recon: Vector3<f64> = (0..3).map(|k| p[t[k] as usize] * c.barycentric[k]).sum();
            assert!((recon - c.point).norm() < 1e-12);
        }
        assert!(
            m.closest_within(&Vector3::new(0.0, 0.0, 2.0), 1.0)
                .is_none()
        );
    }

    #[test]
    fn matches_brute_force_and_refits() {
        let (p, f) = cube();
        let mut m = MeshProximity::new(&p, &f).expect("valid");
        let moved: Vec<Vector3<f64>> = p
            .iter()
            .map(|v| v * 2.0 + Vector3::new(0.3, 0.0, 0.0))
            .collect();
        m.update_positions(&moved).expect("same size");
        for i in 0..200 {
            let x = i as f64 * 0.37;
            let q = Vector3::new(x.sin() * 2.0, (1.3 * x).cos() * 2.0, (0.7 * x).sin() * 2.0);
            let c = m.closest(&q);
            let brute = f
                .iter()
                .map(|t| {
                    let tri = t.map(|i| moved[i as usize]);
                    (closest_on_triangle(&q, tri.each_ref()).0 - q).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!((c.signed_distance_m.abs() - brute).abs() < 1e-12);
            let inside = (q - Vector3::new(0.3, 0.0, 0.0)).abs().max() < 1.0;
            assert_eq!(c.signed_distance_m < 0.0, inside, "{q}");
        }
        assert!(m.update_positions(&p[..4]).is_err());
    }

    #[test]
    fn a_span_answers_as_a_refit_at_every_point_of_the_way() {
        // A sphere of 1,600 triangles (a tree of several levels) that turns 50°, moves and
        // squashes from start to end.
        let sphere = crate::TriMesh::uv_sphere(Vector3::zeros(), 0.3, 20).expect("sphere");
        let (start, f) = (sphere.positions().to_vec(), sphere.faces().to_vec());
        let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 50f64.to_radians());
        let end: Vec<Vector3<f64>> = start
            .iter()
            .map(|p| turn * Vector3::new(p.x * 1.4, p.y * 0.6, p.z) + Vector3::new(0.2, -0.1, 0.05))
            .collect();
        let mut span = MeshProximity::new(&start, &f).expect("valid");
        let mut refit = span.clone();
        assert!(
            span.update_positions_on_span(&start, 0.0).is_err(),
            "no span yet"
        );
        span.set_span(&start, &end).expect("same sizes");
        // A refit in between (another origin) does not unsettle the span's boxes.
        span.update_positions_refit(&end).expect("same size");
        assert!(span.update_positions_on_span(&start, 1.5).is_err());
        for a in [0.0, 0.13, 0.5, 0.77, 1.0] {
            let at: Vec<Vector3<f64>> = if a == 1.0 {
                end.clone()
            } else {
                start
                    .iter()
                    .zip(&end)
                    .map(|(p, q)| p + (q - p) * a)
                    .collect()
            };
            span.update_positions_on_span(&at, a).expect("on the span");
            assert!(
                span.wide.contains_faces(&at, &f, span.tree.order()),
                "a = {a}"
            );
            refit.update_positions_refit(&at).expect("same size");
            for i in 0..300 {
                let x = i as f64 * 0.31;
                let q = Vector3::new(x.sin() * 0.5, (1.3 * x).cos() * 0.4, (0.7 * x).sin() * 0.4);
                assert_eq!(span.closest(&q), refit.closest(&q), "a = {a}, {q}");
                for r in [0.01, 0.05] {
                    assert_eq!(
                        span.closest_within(&q, r),
                        refit.closest_within(&q, r),
                        "a = {a}, {q}"
                    );
                }
            }
        }
        // The halfway boxes do not hold the faces at the end: they are not simply the whole
        // way's.
        let half: Vec<Vector3<f64>> = start
            .iter()
            .zip(&end)
            .map(|(p, q)| p + (q - p) * 0.5)
            .collect();
        span.update_positions_on_span(&half, 0.5)
            .expect("on the span");
        assert!(!span.wide.contains_faces(&end, &f, span.tree.order()));
    }

    #[test]
    fn normals_with_each_answer_are_the_stored_ones() {
        let (p, f) = cube();
        let moved: Vec<Vector3<f64>> = p
            .iter()
            .map(|v| Vector3::new(v.x * 1.5 + 0.1 * v.y, v.y - 0.2 * v.z, v.z * 0.7))
            .collect();
        let (mut eager, mut refit) = (
            MeshProximity::new(&p, &f).expect("valid"),
            MeshProximity::new(&p, &f).expect("valid"),
        );
        eager.update_positions(&moved).expect("same size");
        refit.update_positions_refit(&moved).expect("same size");
        let all: Vec<u32> = (0..f.len() as u32).collect();
        let mut features = [0usize; 3];
        for i in 0..400 {
            let x = i as f64 * 0.29;
            let q = Vector3::new(x.sin() * 2.0, (1.3 * x).cos() * 1.5, (0.7 * x).sin() * 1.2);
            let (a, b) = (eager.closest(&q), refit.closest(&q));
            assert_eq!(a, b, "{q}");
            let nearest = eager.nearest_among(&q, &all).expect("faces");
            features[match nearest.feature {
                ClosestFeature::Face => 0,
                ClosestFeature::Edge(_) => 1,
                ClosestFeature::Vertex(_) => 2,
            }] += 1;
            assert_eq!(eager.closest_within(&q, 0.3), refit.closest_within(&q, 0.3));
        }
        assert!(features.iter().all(|&n| n > 0), "{features:?}");
    }

    #[test]
    fn closest_among_and_faces_within_agree_with_the_tree() {
        let (p, f) = cube();
        let m = MeshProximity::new(&p, &f).expect("valid");
        let all: Vec<u32> = (0..f.len() as u32).collect();
        for i in 0..100 {
            let x = i as f64 * 0.61;
            let q = Vector3::new(x.sin(), (0.9 * x).cos(), (1.7 * x).sin()) * 0.8;
            assert_eq!(m.closest_among(&q, &all), Some(m.closest(&q)));
            let within = m.faces_within(&q, 0.3);
            let brute: Vec<u32> = (0..f.len() as u32)
                .filter(|&t| {
                    let tri = f[t as usize].map(|i| p[i as usize]);
                    (closest_on_triangle(&q, tri.each_ref()).0 - q).norm() <= 0.3
                })
                .collect();
            let mut got: Vec<u32> = within.iter().map(|w| w.0).collect();
            assert!(within.windows(2).all(|w| w[0].1 <= w[1].1));
            got.sort_unstable();
            assert_eq!(got, brute, "{q}");
            // Among a subset: the best of that subset, not of the mesh.
            if let Some(&(first, _)) = within.first() {
                assert_eq!(m.closest(&q).face, first);
            }
        }
        assert!(m.closest_among(&Vector3::zeros(), &[]).is_none());
        // A hint changes the work, never the answer: any face, none, or out of range.
        for i in 0..100 {
            let x = i as f64 * 0.43;
            let q = Vector3::new(x.cos(), (1.1 * x).sin(), (0.3 * x).cos()) * 0.9;
            for radius in [0.05, 0.4, f64::INFINITY] {
                let exact = m.closest_within(&q, radius);
                for start in [0, 5, 11, u32::MAX, 99] {
                    let mut hint = start;
                    assert_eq!(m.closest_within_hinted(&q, radius, &mut hint), exact);
                    let expected = exact.map_or(start, |c| c.face);
                    assert_eq!(hint, expected);
                }
            }
        }
        let c = m
            .closest_among(&Vector3::new(0.0, 0.0, 0.7), &[0, 1])
            .expect("two faces");
        // The bottom face (z = −0.5, normal −z) seen from above: behind it, 1.2 away.
        assert!(
            c.face < 2 && (c.signed_distance_m + 1.2).abs() < 1e-12,
            "{c:?}"
        );
    }
}
