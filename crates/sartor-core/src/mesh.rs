//! Triangle meshes: validated construction, normals and topology.

use nalgebra::Vector3;

use crate::{Error, Result};

/// A validated triangle mesh in metres (f64).
///
/// Invariants, checked by [`TriMesh::new`]: every position is finite, every face indexes three
/// distinct existing vertices, and no triangle is degenerate (area above `1e-12` of the squared
/// bounding-box diagonal).
#[derive(Clone, Debug, PartialEq)]
pub struct TriMesh {
    positions: Vec<Vector3<f64>>,
    faces: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Build a mesh, checking the invariants above.
    pub fn new(positions: Vec<Vector3<f64>>, faces: Vec<[u32; 3]>) -> Result<Self> {
        validate_faces(positions.len(), &faces)?;
        if let Some(i) = positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(Error::invalid(
                "mesh",
                format!("vertex {i} has a non-finite coordinate"),
            ));
        }
        let diag2 = bounding_box(&positions).map_or(0.0, |(lo, hi)| (hi - lo).norm_squared());
        let min_double_area = 2e-12 * diag2;
        for (f, tri) in faces.iter().enumerate() {
            let [a, b, c] = tri.map(|i| positions[i as usize]);
            let double_area = (b - a).cross(&(c - a)).norm();
            if double_area <= min_double_area {
                return Err(Error::invalid(
                    "mesh",
                    format!(
                        "triangle {f} ({}, {}, {}) has zero area",
                        tri[0], tri[1], tri[2]
                    ),
                ));
            }
        }
        Ok(Self { positions, faces })
    }

    /// A closed, outward-oriented UV sphere of radius `radius_m` around `center` with `rings`
    /// rings of latitude (≥ 2) and `2 · rings` segments of longitude: an analytic body stand-in
    /// for contact and distance tests whose answers are known.
    pub fn uv_sphere(center: Vector3<f64>, radius_m: f64, rings: usize) -> Result<Self> {
        if rings < 2 || !radius_m.is_finite() || radius_m <= 0.0 {
            return Err(Error::invalid(
                "sphere",
                format!("{rings} rings of radius {radius_m} m"),
            ));
        }
        let n = rings;
        let mut p = vec![center + Vector3::new(0.0, radius_m, 0.0)];
        for i in 1..n {
            let th = std::f64::consts::PI * i as f64 / n as f64;
            for k in 0..2 * n {
                let ph = std::f64::consts::PI * k as f64 / n as f64;
                let dir = Vector3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
                p.push(center + dir * radius_m);
            }
        }
        p.push(center - Vector3::new(0.0, radius_m, 0.0));
        let ring = |i: usize, k: usize| (1 + (i - 1) * 2 * n + k % (2 * n)) as u32;
        let mut f = Vec::new();
        for k in 0..2 * n {
            f.push([0, ring(1, k + 1), ring(1, k)]);
            for i in 1..n - 1 {
                f.push([ring(i, k), ring(i, k + 1), ring(i + 1, k)]);
                f.push([ring(i, k + 1), ring(i + 1, k + 1), ring(i + 1, k)]);
            }
            f.push([(p.len() - 1) as u32, ring(n - 1, k), ring(n - 1, k + 1)]);
        }
        Self::new(p, f)
    }

    /// Vertex positions.
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Triangles, counter-clockwise seen from outside.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.positions.len()
    }

    /// The first vertex that belongs to no triangle, if any (a garment, a cloth or a remeshing
    /// input must have none).
    pub fn first_unused_vertex(&self) -> Option<usize> {
        let mut used = vec![false; self.n_vertices()];
        for &v in self.faces.iter().flatten() {
            used[v as usize] = true;
        }
        used.iter().position(|u| !u)
    }

    /// Number of triangles.
    pub fn n_faces(&self) -> usize {
        self.faces.len()
    }

    /// The same connectivity with new positions (validated again).
    pub fn with_positions(&self, positions: Vec<Vector3<f64>>) -> Result<Self> {
        if positions.len() != self.positions.len() {
            return Err(Error::invalid(
                "mesh",
                format!(
                    "{} positions for a mesh of {} vertices",
                    positions.len(),
                    self.positions.len()
                ),
            ));
        }
        Self::new(positions, self.faces.clone())
    }

    /// Unit face normals (counter-clockwise winding).
    pub fn face_normals(&self) -> Vec<Vector3<f64>> {
        face_normals(&self.positions, &self.faces)
    }

    /// Area-weighted unit vertex normals; isolated vertices get zero.
    pub fn vertex_normals(&self) -> Vec<Vector3<f64>> {
        vertex_normals(&self.positions, &self.faces)
    }

    /// Face areas in m².
    pub fn face_areas(&self) -> Vec<f64> {
        self.faces
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .collect()
    }

    /// Axis-aligned bounds `(min, max)`; `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vector3<f64>, Vector3<f64>)> {
        bounding_box(&self.positions)
    }

    /// Edges, vertex neighbours, boundary and components.
    pub fn topology(&self) -> MeshTopology {
        MeshTopology::new(self.positions.len(), &self.faces)
    }
}

fn validate_faces(n_vertices: usize, faces: &[[u32; 3]]) -> Result<()> {
    for (f, tri) in faces.iter().enumerate() {
        if let Some(&i) = tri.iter().find(|&&i| i as usize >= n_vertices) {
            return Err(Error::invalid(
                "mesh",
                format!("triangle {f} references vertex {i}, but there are only {n_vertices}"),
            ));
        }
        if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
            return Err(Error::invalid(
                "mesh",
                format!("triangle {f} repeats a vertex: {tri:?}"),
            ));
        }
    }
    Ok(())
}

/// The vertices `faces` use (ascending, out of `n_vertices`) and the faces re-indexed into
/// that list: a part of a mesh over its own vertices.
pub fn compact_faces(faces: &[[u32; 3]], n_vertices: usize) -> (Vec<u32>, Vec<[u32; 3]>) {
    let mut index = vec![u32::MAX; n_vertices];
    let mut used: Vec<u32> = faces.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    for (k, &v) in used.iter().enumerate() {
        index[v as usize] = k as u32;
    }
    let faces = faces.iter().map(|t| t.map(|v| index[v as usize])).collect();
    (used, faces)
}

/// The signed volume a closed, outward-oriented triangle mesh bounds (divergence theorem: the
/// sum of the tetrahedra from the origin to each face), m³; negative for an inward-oriented one.
pub fn enclosed_volume(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> f64 {
    faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| positions[i as usize]);
            a.dot(&b.cross(&c)) / 6.0
        })
        .sum()
}

/// Axis-aligned bounds of a point set.
pub fn bounding_box(points: &[Vector3<f64>]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let first = *points.first()?;
    Some(
        points
            .iter()
            .fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p))),
    )
}

/// The axis-aligned box `[lo, hi]` as a closed mesh: 8 corners (bit 0 of the index picks
/// `hi.x`, bit 1 `hi.y`, bit 2 `hi.z`) and 12 triangles, counter-clockwise seen from outside,
/// two per side in the order −z, +z, −y, +y, −x, +x.
pub fn box_mesh(lo: Vector3<f64>, hi: Vector3<f64>) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
    let corners = (0..8)
        .map(|i| Vector3::from_fn(|k, _| if i >> k & 1 == 1 { hi[k] } else { lo[k] }))
        .collect();
    let faces = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ]
    .iter()
    .flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]])
    .collect();
    (corners, faces)
}

/// Unit face normals of any indexed triangle set (zero for degenerate faces).
pub fn face_normals(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    faces
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            (b - a)
                .cross(&(c - a))
                .try_normalize(0.0)
                .unwrap_or_else(Vector3::zeros)
        })
        .collect()
}

/// Area-weighted unit vertex normals of any indexed triangle set.
pub fn vertex_normals(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    let mut normals = vec![Vector3::zeros(); positions.len()];
    for t in faces {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let n = (b - a).cross(&(c - a)); // length = 2 × area: area weighting
        for &i in t {
            normals[i as usize] += n;
        }
    }
    for n in &mut normals {
        *n = n.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
    }
    normals
}

/// An interior edge with its two triangles (see [`MeshTopology::hinges`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hinge {
    /// `[x0, x1, x2, x3]`: the edge `x0 → x1` as oriented in `faces[0]`, then the vertex opposite
    /// it in `faces[0]` and in `faces[1]`.
    pub vertices: [u32; 4],
    /// The two triangles.
    pub faces: [u32; 2],
}

/// Connectivity of a triangle mesh: unique edges, the faces around each edge, vertex
/// neighbourhoods (CSR), boundary loops and connected components.
#[derive(Clone, Debug)]
pub struct MeshTopology {
    /// Unique undirected edges `(a, b)` with `a < b`, sorted.
    pub edges: Vec<[u32; 2]>,
    /// For each edge, the one or more faces that contain it.
    pub edge_faces: Vec<Vec<u32>>,
    /// For each face, the index of its edges `(v0 v1, v1 v2, v2 v0)` in [`Self::edges`].
    pub face_edges: Vec<[u32; 3]>,
    neighbour_offsets: Vec<usize>,
    neighbours: Vec<u32>,
    n_faces: usize,
    faces: Vec<[u32; 3]>,
}

impl MeshTopology {
    /// Build the topology of `faces` over `n_vertices` vertices. Face indices must be valid.
    pub fn new(n_vertices: usize, faces: &[[u32; 3]]) -> Self {
        let mut directed: Vec<([u32; 2], u32, u8)> = Vec::with_capacity(faces.len() * 3);
        for (f, t) in faces.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                directed.push(([a.min(b), a.max(b)], f as u32, k as u8));
            }
        }
        directed.sort_unstable();
        let mut edges: Vec<[u32; 2]> = Vec::new();
        let mut edge_faces: Vec<Vec<u32>> = Vec::new();
        let mut face_edges = vec![[0u32; 3]; faces.len()];
        for (e, f, k) in directed {
            if edges.last() != Some(&e) {
                edges.push(e);
                edge_faces.push(Vec::new());
            }
            let id = edges.len() - 1;
            edge_faces[id].push(f);
            face_edges[f as usize][k as usize] = id as u32;
        }
        let mut degree = vec![0usize; n_vertices];
        for [a, b] in &edges {
            degree[*a as usize] += 1;
            degree[*b as usize] += 1;
        }
        let mut neighbour_offsets = vec![0usize; n_vertices + 1];
        for v in 0..n_vertices {
            neighbour_offsets[v + 1] = neighbour_offsets[v] + degree[v];
        }
        let mut fill = neighbour_offsets.clone();
        let mut neighbours = vec![0u32; neighbour_offsets[n_vertices]];
        for [a, b] in &edges {
            neighbours[fill[*a as usize]] = *b;
            fill[*a as usize] += 1;
            neighbours[fill[*b as usize]] = *a;
            fill[*b as usize] += 1;
        }
        for v in 0..n_vertices {
            neighbours[neighbour_offsets[v]..neighbour_offsets[v + 1]].sort_unstable();
        }
        Self {
            edges,
            edge_faces,
            face_edges,
            neighbour_offsets,
            neighbours,
            n_faces: faces.len(),
            faces: faces.to_vec(),
        }
    }

    /// Sorted neighbours of vertex `v`.
    pub fn neighbours(&self, v: usize) -> &[u32] {
        &self.neighbours[self.neighbour_offsets[v]..self.neighbour_offsets[v + 1]]
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.neighbour_offsets.len() - 1
    }

    /// Edges on the boundary (exactly one face).
    pub fn boundary_edges(&self) -> Vec<[u32; 2]> {
        self.edges
            .iter()
            .zip(&self.edge_faces)
            .filter(|(_, f)| f.len() == 1)
            .map(|(e, _)| *e)
            .collect()
    }

    /// Vertices on the boundary.
    pub fn boundary_vertices(&self) -> Vec<bool> {
        let mut on = vec![false; self.n_vertices()];
        for [a, b] in self.boundary_edges() {
            on[a as usize] = true;
            on[b as usize] = true;
        }
        on
    }

    /// Boundary loops as ordered vertex cycles (only meaningful on a manifold mesh).
    pub fn boundary_loops(&self) -> Vec<Vec<u32>> {
        // Follow directed boundary half-edges: on a consistently oriented manifold each boundary
        // vertex has exactly one outgoing boundary half-edge.
        let mut next = std::collections::BTreeMap::new();
        for (e, fs) in self.edges.iter().zip(&self.edge_faces) {
            if fs.len() != 1 {
                continue;
            }
            let t = self.faces[fs[0] as usize];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if [a.min(b), a.max(b)] == *e {
                    next.insert(a, b);
                }
            }
        }
        let mut loops = Vec::new();
        let mut seen = std::collections::BTreeSet::new();
        for (&start, _) in next.iter() {
            if seen.contains(&start) {
                continue;
            }
            let mut cycle = vec![start];
            seen.insert(start);
            let mut v = start;
            while let Some(&n) = next.get(&v) {
                if n == start || !seen.insert(n) {
                    break;
                }
                cycle.push(n);
                v = n;
            }
            loops.push(cycle);
        }
        loops
    }

    /// Bending hinges: every interior edge with its two triangles, in the order of
    /// [`Self::edges`]. Vertices are `[x0, x1, x2, x3]` where the first face contains the
    /// directed edge `x0 → x1` and `x2`, `x3` are the vertices opposite the edge in the first and
    /// second face.
    pub fn hinges(&self) -> Vec<Hinge> {
        let mut hinges = Vec::new();
        for (edge, edge_faces) in self.edges.iter().zip(&self.edge_faces) {
            let &[fa, fb] = edge_faces.as_slice() else {
                continue;
            };
            let directed = |f: u32, p: u32, q: u32| {
                let t = self.faces[f as usize];
                (0..3).any(|k| t[k] == p && t[(k + 1) % 3] == q)
            };
            let (x0, x1) = if directed(fa, edge[0], edge[1]) {
                (edge[0], edge[1])
            } else {
                (edge[1], edge[0])
            };
            let opposite = |f: u32| {
                self.faces[f as usize]
                    .into_iter()
                    .find(|&v| v != x0 && v != x1)
            };
            if let (Some(x2), Some(x3)) = (opposite(fa), opposite(fb)) {
                hinges.push(Hinge {
                    vertices: [x0, x1, x2, x3],
                    faces: [fa, fb],
                });
            }
        }
        hinges
    }

    /// Connected components of the faces (by shared edges); returns a component id per face and
    /// the number of components.
    pub fn face_components(&self) -> (Vec<u32>, usize) {
        let mut component = vec![u32::MAX; self.n_faces];
        let mut n = 0;
        let mut stack = Vec::new();
        for seed in 0..self.n_faces {
            if component[seed] != u32::MAX {
                continue;
            }
            component[seed] = n;
            stack.push(seed);
            while let Some(f) = stack.pop() {
                for &e in &self.face_edges[f] {
                    for &g in &self.edge_faces[e as usize] {
                        if component[g as usize] == u32::MAX {
                            component[g as usize] = n;
                            stack.push(g as usize);
                        }
                    }
                }
            }
            n += 1;
        }
        (component, n as usize)
    }

    /// Check that the mesh is an oriented 2-manifold (possibly with boundary): every edge has one
    /// or two faces, neighbouring faces agree on orientation, and every vertex's faces form a
    /// single fan. Returns the first fault found.
    pub fn check_manifold(&self) -> Result<()> {
        for (e, fs) in self.edges.iter().zip(&self.edge_faces) {
            if fs.len() > 2 {
                return Err(Error::invalid(
                    "mesh",
                    format!(
                        "edge ({}, {}) is shared by {} triangles (non-manifold)",
                        e[0],
                        e[1],
                        fs.len()
                    ),
                ));
            }
            if fs.len() == 2 {
                let dir = |f: u32| {
                    let t = self.faces[f as usize];
                    (0..3).any(|k| t[k] == e[0] && t[(k + 1) % 3] == e[1])
                };
                if dir(fs[0]) == dir(fs[1]) {
                    return Err(Error::invalid(
                        "mesh",
                        format!(
                            "triangles {} and {} have opposite orientation across edge ({}, {})",
                            fs[0], fs[1], e[0], e[1]
                        ),
                    ));
                }
            }
        }
        // Vertex manifoldness: the faces around each vertex are connected through edges at it.
        let mut vertex_faces: Vec<Vec<u32>> = vec![Vec::new(); self.n_vertices()];
        for (f, t) in self.faces.iter().enumerate() {
            for &v in t {
                vertex_faces[v as usize].push(f as u32);
            }
        }
        for (v, fs) in vertex_faces.iter().enumerate() {
            if fs.len() <= 1 {
                continue;
            }
            let mut reached = vec![false; fs.len()];
            reached[0] = true;
            let mut stack = vec![0usize];
            while let Some(i) = stack.pop() {
                for &e in &self.face_edges[fs[i] as usize] {
                    let [a, b] = self.edges[e as usize];
                    if a as usize != v && b as usize != v {
                        continue;
                    }
                    for &g in &self.edge_faces[e as usize] {
                        if let Some(j) = fs.iter().position(|&h| h == g)
                            && !reached[j]
                        {
                            reached[j] = true;
                            stack.push(j);
                        }
                    }
                }
            }
            if reached.iter().any(|r| !r) {
                return Err(Error::invalid(
                    "mesh",
                    format!("vertex {v} joins separate fans (non-manifold)"),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compact_faces_reindexes() {
        let (used, faces) = compact_faces(&[[5, 2, 9], [9, 2, 7]], 10);
        assert_eq!(used, vec![2, 5, 7, 9]);
        assert_eq!(faces, vec![[1, 0, 3], [3, 0, 2]]);
    }

    fn square() -> TriMesh {
        let p = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(1.0, 1.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        TriMesh::new(p, vec![[0, 1, 2], [0, 2, 3]]).expect("valid square")
    }

    #[test]
    fn square_topology() {
        let m = square();
        let t = m.topology();
        assert_eq!(t.edges.len(), 5);
        assert_eq!(t.boundary_edges().len(), 4);
        assert_eq!(t.neighbours(0), &[1, 2, 3]);
        assert_eq!(t.boundary_loops(), vec![vec![0, 1, 2, 3]]);
        assert_eq!(t.face_components().1, 1);
        // One interior edge (0, 2): face 0 = [0, 1, 2] holds it as 2 → 0.
        assert_eq!(
            t.hinges(),
            vec![Hinge {
                vertices: [2, 0, 1, 3],
                faces: [0, 1]
            }]
        );
        t.check_manifold().expect("manifold");
        let n = m.vertex_normals();
        assert!((n[0] - Vector3::z()).norm() < 1e-12);
        assert!((m.face_areas().iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_meshes() {
        let p = vec![Vector3::zeros(), Vector3::x(), Vector3::y()];
        assert!(TriMesh::new(p.clone(), vec![[0, 1, 3]]).is_err());
        assert!(TriMesh::new(p.clone(), vec![[0, 1, 1]]).is_err());
        let mut nan = p.clone();
        nan[1].x = f64::NAN;
        assert!(TriMesh::new(nan, vec![[0, 1, 2]]).is_err());
        let collinear = vec![
            Vector3::zeros(),
            Vector3::x(),
            2.0 * Vector3::x(),
            Vector3::y(),
        ];
        let err = TriMesh::new(collinear, vec![[0, 1, 2]])
            .unwrap_err()
            .to_string();
        assert!(err.contains("zero area"), "{err}");
    }

    #[test]
    fn detects_non_manifold_and_flipped() {
        // Three triangles on edge (0, 1).
        let t = MeshTopology::new(5, &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]);
        assert!(t.check_manifold().is_err());
        // Two triangles with inconsistent winding.
        let t = MeshTopology::new(5, &[[0, 1, 2], [0, 1, 3]]);
        assert!(
            t.check_manifold()
                .unwrap_err()
                .to_string()
                .contains("orientation")
        );
        // Bow-tie vertex.
        let t = MeshTopology::new(5, &[[0, 1, 2], [0, 3, 4]]);
        assert!(t.check_manifold().unwrap_err().to_string().contains("fans"));
    }
}
