//! A half-edge triangle mesh with the local operators of incremental remeshing: edge split,
//! halfedge collapse and edge flip (the connectivity updates follow the pmp-library's
//! `SurfaceMesh`). Deleted elements are only flagged; [`EditMesh::to_parts`] compacts them in
//! index order, so results are deterministic.
//!
//! Half-edges come in pairs: the twin of `h` is `h ^ 1`, and edge `e` owns half-edges `2e` and
//! `2e + 1`. Boundary half-edges have no face and are linked into the boundary loops by
//! `next`/`prev`; a boundary vertex's outgoing half-edge is always its boundary half-edge.

use std::collections::BTreeMap;

use nalgebra::Vector3;

/// "No element".
pub(crate) const NONE: u32 = u32::MAX;

#[derive(Clone, Debug)]
pub(crate) struct EditMesh {
    pub pos: Vec<Vector3<f64>>,
    v_out: Vec<u32>,
    v_deleted: Vec<bool>,
    he_to: Vec<u32>,
    he_next: Vec<u32>,
    he_prev: Vec<u32>,
    he_face: Vec<u32>,
    e_deleted: Vec<bool>,
    f_he: Vec<u32>,
    f_deleted: Vec<bool>,
    live_faces: usize,
}

impl EditMesh {
    /// Build from a consistently oriented 2-manifold (checked by the caller) in which every
    /// vertex belongs to a triangle.
    pub fn new(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Self {
        let n_v = positions.len();
        let mut edge_of: BTreeMap<(u32, u32), u32> = BTreeMap::new();
        let mut m = Self {
            pos: positions.to_vec(),
            v_out: vec![NONE; n_v],
            v_deleted: vec![false; n_v],
            he_to: Vec::new(),
            he_next: Vec::new(),
            he_prev: Vec::new(),
            he_face: Vec::new(),
            e_deleted: Vec::new(),
            f_he: Vec::with_capacity(faces.len()),
            f_deleted: vec![false; faces.len()],
            live_faces: faces.len(),
        };
        for (f, t) in faces.iter().enumerate() {
            let mut hs = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                let e = match edge_of.get(&key) {
                    Some(&e) => e,
                    None => {
                        let h = m.new_edge(key.0, key.1);
                        edge_of.insert(key, h / 2);
                        h / 2
                    }
                };
                hs[k] = if a < b { 2 * e } else { 2 * e + 1 };
                m.he_face[hs[k] as usize] = f as u32;
                m.v_out[a as usize] = hs[k];
            }
            for k in 0..3 {
                m.set_next(hs[k], hs[(k + 1) % 3]);
            }
            m.f_he.push(hs[0]);
        }
        // Link boundary half-edges into loops: each boundary vertex has exactly one outgoing
        // boundary half-edge on a manifold.
        let n_he = m.he_to.len() as u32;
        let mut boundary_out = vec![NONE; n_v];
        for h in 0..n_he {
            if m.he_face[h as usize] == NONE {
                boundary_out[m.from(h) as usize] = h;
            }
        }
        for h in 0..n_he {
            if m.he_face[h as usize] == NONE {
                let next = boundary_out[m.he_to[h as usize] as usize];
                m.set_next(h, next);
            }
        }
        for v in 0..n_v {
            if boundary_out[v] != NONE {
                m.v_out[v] = boundary_out[v];
            }
        }
        m
    }

    /// New edge `a → b` (half-edge `2e`) and `b → a` (`2e + 1`), both without face; returns the
    /// half-edge `a → b`.
    fn new_edge(&mut self, a: u32, b: u32) -> u32 {
        let h = self.he_to.len() as u32;
        self.he_to.extend([b, a]);
        self.he_next.extend([NONE, NONE]);
        self.he_prev.extend([NONE, NONE]);
        self.he_face.extend([NONE, NONE]);
        self.e_deleted.push(false);
        h
    }

    fn new_vertex(&mut self, p: Vector3<f64>) -> u32 {
        self.pos.push(p);
        self.v_out.push(NONE);
        self.v_deleted.push(false);
        (self.pos.len() - 1) as u32
    }

    fn new_face(&mut self) -> u32 {
        self.f_he.push(NONE);
        self.f_deleted.push(false);
        self.live_faces += 1;
        (self.f_he.len() - 1) as u32
    }

    fn set_next(&mut self, h: u32, n: u32) {
        self.he_next[h as usize] = n;
        self.he_prev[n as usize] = h;
    }

    // ---- queries -------------------------------------------------------------------------

    pub fn n_vertex_slots(&self) -> usize {
        self.pos.len()
    }
    pub fn n_edge_slots(&self) -> usize {
        self.e_deleted.len()
    }
    pub fn vertex_deleted(&self, v: u32) -> bool {
        self.v_deleted[v as usize]
    }
    pub fn edge_deleted(&self, e: u32) -> bool {
        self.e_deleted[e as usize]
    }
    /// Number of live faces.
    pub fn n_faces(&self) -> usize {
        self.live_faces
    }
    pub fn to(&self, h: u32) -> u32 {
        self.he_to[h as usize]
    }
    pub fn from(&self, h: u32) -> u32 {
        self.he_to[(h ^ 1) as usize]
    }
    pub fn next(&self, h: u32) -> u32 {
        self.he_next[h as usize]
    }
    pub fn prev(&self, h: u32) -> u32 {
        self.he_prev[h as usize]
    }
    pub fn face(&self, h: u32) -> u32 {
        self.he_face[h as usize]
    }
    pub fn is_boundary_he(&self, h: u32) -> bool {
        self.he_face[h as usize] == NONE
    }
    pub fn is_boundary_edge(&self, e: u32) -> bool {
        self.is_boundary_he(2 * e) || self.is_boundary_he(2 * e + 1)
    }
    pub fn is_boundary_vertex(&self, v: u32) -> bool {
        let h = self.v_out[v as usize];
        h != NONE && self.is_boundary_he(h)
    }
    /// Next outgoing half-edge of the same vertex (clockwise).
    fn cw(&self, h: u32) -> u32 {
        self.next(h ^ 1)
    }

    /// Outgoing half-edges of `v`, starting from its stored one (the boundary one for a
    /// boundary vertex).
    pub fn outgoing(&self, v: u32) -> Outgoing<'_> {
        let start = self.v_out[v as usize];
        Outgoing {
            mesh: self,
            start,
            current: start,
        }
    }

    pub fn valence(&self, v: u32) -> usize {
        self.outgoing(v).count()
    }

    pub fn find_halfedge(&self, a: u32, b: u32) -> Option<u32> {
        self.outgoing(a).find(|&h| self.to(h) == b)
    }

    /// The corners of face `f`, counter-clockwise, starting at the origin of its half-edge.
    pub fn face_vertices(&self, f: u32) -> [u32; 3] {
        let h = self.f_he[f as usize];
        [self.from(h), self.to(h), self.to(self.next(h))]
    }

    /// Non-unit normal (twice the area) of face `f` with vertex `moved` at `p`.
    pub fn face_normal_with(&self, f: u32, moved: u32, p: &Vector3<f64>) -> Vector3<f64> {
        let x = self
            .face_vertices(f)
            .map(|v| if v == moved { *p } else { self.pos[v as usize] });
        (x[1] - x[0]).cross(&(x[2] - x[0]))
    }

    pub fn face_normal(&self, f: u32) -> Vector3<f64> {
        let x = self.face_vertices(f).map(|v| self.pos[v as usize]);
        (x[1] - x[0]).cross(&(x[2] - x[0]))
    }

    pub fn edge_length(&self, e: u32) -> f64 {
        (self.pos[self.to(2 * e) as usize] - self.pos[self.from(2 * e) as usize]).norm()
    }

    // ---- operators -----------------------------------------------------------------------

    /// Split edge `e` at a new vertex placed at `p`; returns the new vertex. An interior edge
    /// gains two triangles, a boundary edge one.
    pub fn split(&mut self, e: u32, p: Vector3<f64>) -> u32 {
        let v = self.new_vertex(p);
        let h0 = 2 * e;
        let o0 = h0 ^ 1;
        let v2 = self.to(o0);
        let e1 = self.new_edge(v, v2);
        let t1 = e1 ^ 1;
        let f0 = self.face(h0);
        let f3 = self.face(o0);
        self.v_out[v as usize] = h0;
        self.he_to[o0 as usize] = v;

        if f0 != NONE {
            let h1 = self.next(h0);
            let h2 = self.next(h1);
            let v1 = self.to(h1);
            let e0 = self.new_edge(v, v1);
            let t0 = e0 ^ 1;
            let f1 = self.new_face();
            self.f_he[f0 as usize] = h0;
            self.f_he[f1 as usize] = h2;
            self.he_face[h1 as usize] = f0;
            self.he_face[t0 as usize] = f0;
            self.he_face[h0 as usize] = f0;
            self.he_face[h2 as usize] = f1;
            self.he_face[t1 as usize] = f1;
            self.he_face[e0 as usize] = f1;
            self.set_next(h0, h1);
            self.set_next(h1, t0);
            self.set_next(t0, h0);
            self.set_next(e0, h2);
            self.set_next(h2, t1);
            self.set_next(t1, e0);
        } else {
            let p0 = self.prev(h0);
            self.set_next(p0, t1);
            self.set_next(t1, h0);
        }

        if f3 != NONE {
            let o1 = self.next(o0);
            let o2 = self.next(o1);
            let v3 = self.to(o1);
            let e2 = self.new_edge(v, v3);
            let t2 = e2 ^ 1;
            let f2 = self.new_face();
            self.f_he[f2 as usize] = o1;
            self.f_he[f3 as usize] = o0;
            self.he_face[o1 as usize] = f2;
            self.he_face[t2 as usize] = f2;
            self.he_face[e1 as usize] = f2;
            self.he_face[o2 as usize] = f3;
            self.he_face[o0 as usize] = f3;
            self.he_face[e2 as usize] = f3;
            self.set_next(e1, o1);
            self.set_next(o1, t2);
            self.set_next(t2, e1);
            self.set_next(o0, e2);
            self.set_next(e2, o2);
            self.set_next(o2, o0);
        } else {
            let n0 = self.next(o0);
            self.set_next(e1, n0);
            self.set_next(o0, e1);
            self.v_out[v as usize] = e1;
        }

        if self.v_out[v2 as usize] == h0 {
            self.v_out[v2 as usize] = t1;
        }
        v
    }

    /// Whether collapsing half-edge `h` (its origin into its target) keeps the mesh a
    /// manifold with the same topology (the link condition; Dey et al., pmp's
    /// `is_collapse_ok`).
    pub fn is_collapse_ok(&self, h: u32) -> bool {
        let o = h ^ 1;
        let v0 = self.from(h);
        let v1 = self.to(h);
        let mut vl = NONE;
        let mut vr = NONE;
        if !self.is_boundary_he(h) {
            let h1 = self.next(h);
            let h2 = self.next(h1);
            vl = self.to(h1);
            if self.is_boundary_he(h1 ^ 1) && self.is_boundary_he(h2 ^ 1) {
                return false;
            }
        }
        if !self.is_boundary_he(o) {
            let o1 = self.next(o);
            let o2 = self.next(o1);
            vr = self.to(o1);
            if self.is_boundary_he(o1 ^ 1) && self.is_boundary_he(o2 ^ 1) {
                return false;
            }
        }
        if vl == vr {
            return false;
        }
        if self.is_boundary_vertex(v0)
            && self.is_boundary_vertex(v1)
            && !self.is_boundary_he(h)
            && !self.is_boundary_he(o)
        {
            return false;
        }
        for hv in self.outgoing(v0) {
            let vv = self.to(hv);
            if vv != v1 && vv != vl && vv != vr && self.find_halfedge(vv, v1).is_some() {
                return false;
            }
        }
        true
    }

    /// Collapse half-edge `h`: its origin is removed and merged into its target. The caller
    /// checks [`Self::is_collapse_ok`] first.
    pub fn collapse(&mut self, h: u32) {
        let h0 = h;
        let h1 = self.prev(h0);
        let o0 = h0 ^ 1;
        let o1 = self.next(o0);
        self.remove_edge_helper(h0);
        if self.next(self.next(h1)) == h1 {
            self.remove_loop_helper(h1);
        }
        if self.next(self.next(o1)) == o1 {
            self.remove_loop_helper(o1);
        }
    }

    fn remove_edge_helper(&mut self, h: u32) {
        let hn = self.next(h);
        let hp = self.prev(h);
        let o = h ^ 1;
        let on = self.next(o);
        let op = self.prev(o);
        let fh = self.face(h);
        let fo = self.face(o);
        let vh = self.to(h);
        let vo = self.to(o);
        let incoming: Vec<u32> = self.outgoing(vo).map(|hc| hc ^ 1).collect();
        for hc in incoming {
            self.he_to[hc as usize] = vh;
        }
        self.set_next(hp, hn);
        self.set_next(op, on);
        if fh != NONE {
            self.f_he[fh as usize] = hn;
        }
        if fo != NONE {
            self.f_he[fo as usize] = on;
        }
        if self.v_out[vh as usize] == o {
            self.v_out[vh as usize] = hn;
        }
        self.adjust_outgoing(vh);
        self.v_out[vo as usize] = NONE;
        self.v_deleted[vo as usize] = true;
        self.e_deleted[(h / 2) as usize] = true;
    }

    fn remove_loop_helper(&mut self, h: u32) {
        let h0 = h;
        let h1 = self.next(h0);
        let o0 = h0 ^ 1;
        let o1 = h1 ^ 1;
        let v0 = self.to(h0);
        let v1 = self.to(h1);
        let fh = self.face(h0);
        let fo = self.face(o0);
        let n = self.next(o0);
        self.set_next(h1, n);
        let p = self.prev(o0);
        self.set_next(p, h1);
        self.he_face[h1 as usize] = fo;
        self.v_out[v0 as usize] = h1;
        self.adjust_outgoing(v0);
        self.v_out[v1 as usize] = o1;
        self.adjust_outgoing(v1);
        if fo != NONE && self.f_he[fo as usize] == o0 {
            self.f_he[fo as usize] = h1;
        }
        if fh != NONE {
            self.f_deleted[fh as usize] = true;
            self.live_faces -= 1;
        }
        self.e_deleted[(h0 / 2) as usize] = true;
    }

    /// Make a boundary vertex's stored outgoing half-edge its boundary one.
    fn adjust_outgoing(&mut self, v: u32) {
        let start = self.v_out[v as usize];
        if start == NONE {
            return;
        }
        let mut h = start;
        loop {
            if self.is_boundary_he(h) {
                self.v_out[v as usize] = h;
                return;
            }
            h = self.cw(h);
            if h == start {
                return;
            }
        }
    }

    /// Whether interior edge `e` can be flipped without creating a duplicate edge.
    pub fn is_flip_ok(&self, e: u32) -> bool {
        if self.is_boundary_edge(e) {
            return false;
        }
        let v0 = self.to(self.next(2 * e));
        let v1 = self.to(self.next(2 * e + 1));
        v0 != v1 && self.find_halfedge(v0, v1).is_none()
    }

    /// The two vertices a flip of `e` would join.
    pub fn flip_opposites(&self, e: u32) -> [u32; 2] {
        [self.to(self.next(2 * e)), self.to(self.next(2 * e + 1))]
    }

    /// Flip interior edge `e` (checked by [`Self::is_flip_ok`]).
    pub fn flip(&mut self, e: u32) {
        let a0 = 2 * e;
        let b0 = a0 ^ 1;
        let a1 = self.next(a0);
        let a2 = self.next(a1);
        let b1 = self.next(b0);
        let b2 = self.next(b1);
        let va0 = self.to(a0);
        let va1 = self.to(a1);
        let vb0 = self.to(b0);
        let vb1 = self.to(b1);
        let fa = self.face(a0);
        let fb = self.face(b0);
        self.he_to[a0 as usize] = va1;
        self.he_to[b0 as usize] = vb1;
        self.set_next(a0, a2);
        self.set_next(a2, b1);
        self.set_next(b1, a0);
        self.set_next(b0, b2);
        self.set_next(b2, a1);
        self.set_next(a1, b0);
        self.he_face[a1 as usize] = fb;
        self.he_face[b1 as usize] = fa;
        self.f_he[fa as usize] = a0;
        self.f_he[fb as usize] = b0;
        // a0 started at vb0 and b0 at va0; a1 now starts at va0 and b1 at vb0.
        if self.v_out[va0 as usize] == b0 {
            self.v_out[va0 as usize] = a1;
        }
        if self.v_out[vb0 as usize] == a0 {
            self.v_out[vb0 as usize] = b1;
        }
    }

    /// Compact: live vertices and faces in index order. Returns positions, faces and, for each
    /// new vertex, its old index.
    pub fn to_parts(&self) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>, Vec<u32>) {
        let mut new_index = vec![NONE; self.pos.len()];
        let mut old_index = Vec::new();
        let mut positions = Vec::new();
        for v in 0..self.pos.len() {
            if !self.v_deleted[v] && self.v_out[v] != NONE {
                new_index[v] = positions.len() as u32;
                positions.push(self.pos[v]);
                old_index.push(v as u32);
            }
        }
        let faces = (0..self.f_he.len() as u32)
            .filter(|&f| !self.f_deleted[f as usize])
            .map(|f| self.face_vertices(f).map(|v| new_index[v as usize]))
            .collect();
        (positions, faces, old_index)
    }

    /// Check the half-edge invariants (tests and debug builds).
    #[cfg(test)]
    pub fn check(&self) {
        for h in 0..self.he_to.len() as u32 {
            if self.e_deleted[(h / 2) as usize] {
                continue;
            }
            assert_eq!(self.prev(self.next(h)), h, "prev/next of {h}");
            assert_eq!(self.to(h), self.from(self.next(h)), "chain at {h}");
            let f = self.face(h);
            if f != NONE {
                assert!(!self.f_deleted[f as usize], "half-edge {h} on deleted face");
                assert_eq!(
                    self.next(self.next(self.next(h))),
                    h,
                    "face {f} not a triangle"
                );
                assert_eq!(self.face(self.next(h)), f);
            }
            assert!(
                !self.v_deleted[self.to(h) as usize],
                "half-edge {h} to deleted vertex"
            );
        }
        for v in 0..self.pos.len() as u32 {
            if self.v_deleted[v as usize] {
                continue;
            }
            let h = self.v_out[v as usize];
            assert_ne!(h, NONE, "vertex {v} isolated");
            assert_eq!(self.from(h), v, "outgoing of {v}");
            let boundary = self.outgoing(v).any(|h| self.is_boundary_he(h));
            assert_eq!(boundary, self.is_boundary_he(h), "boundary flag of {v}");
        }
    }
}

/// Iterator over the outgoing half-edges of a vertex.
pub(crate) struct Outgoing<'a> {
    mesh: &'a EditMesh,
    start: u32,
    current: u32,
}

impl Iterator for Outgoing<'_> {
    type Item = u32;
    fn next(&mut self) -> Option<u32> {
        if self.current == NONE {
            return None;
        }
        let h = self.current;
        let n = self.mesh.cw(h);
        self.current = if n == self.start { NONE } else { n };
        Some(h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sartor_core::MeshTopology;

    fn grid(n: usize) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let mut p = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                p.push(Vector3::new(i as f64, j as f64, 0.0));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut f = Vec::new();
        for j in 0..n {
            for i in 0..n {
                f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (p, f)
    }

    fn assert_manifold(m: &EditMesh, loops: usize) {
        m.check();
        let (p, f, _) = m.to_parts();
        assert_eq!(f.len(), m.n_faces());
        let t = MeshTopology::new(p.len(), &f);
        t.check_manifold().unwrap();
        assert_eq!(t.boundary_loops().len(), loops);
        assert_eq!(t.face_components().1, 1);
    }

    #[test]
    fn operators_keep_a_valid_manifold() {
        let (p, f) = grid(4);
        let mut m = EditMesh::new(&p, &f);
        assert_manifold(&m, 1);
        assert_eq!(m.n_faces(), 32);
        // Split every edge once (interior +2, boundary +1).
        let n_e = m.n_edge_slots() as u32;
        let mut expected = 32;
        for e in 0..n_e {
            expected += if m.is_boundary_edge(e) { 1 } else { 2 };
            let mid = 0.5 * (m.pos[m.to(2 * e) as usize] + m.pos[m.from(2 * e) as usize]);
            m.split(e, mid);
        }
        assert_eq!(m.n_faces(), expected);
        assert_manifold(&m, 1);
        // Flip everything that can be flipped, several times over, checking every step.
        let mut flips = 0;
        for _ in 0..3 {
            for e in 0..m.n_edge_slots() as u32 {
                if !m.edge_deleted(e) && m.is_flip_ok(e) {
                    m.flip(e);
                    flips += 1;
                    m.check();
                }
            }
        }
        assert!(flips > 100);
        assert_manifold(&m, 1);
        // Collapse whatever passes the link condition, both interior and boundary.
        let mut collapsed = 0;
        for e in 0..m.n_edge_slots() as u32 {
            if m.edge_deleted(e) || e % 2 == 1 {
                continue;
            }
            let h = 2 * e;
            if m.is_collapse_ok(h) && (!m.is_boundary_vertex(m.from(h)) || m.is_boundary_edge(e)) {
                let before = m.n_faces();
                let boundary = m.is_boundary_edge(e);
                m.collapse(h);
                collapsed += 1;
                assert_eq!(m.n_faces(), before - if boundary { 1 } else { 2 });
                m.check();
            }
        }
        assert!(collapsed > 10);
        assert_manifold(&m, 1);
    }
}
