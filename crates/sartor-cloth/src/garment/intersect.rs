//! Self-intersection checks: a box-overlap tree over triangles and an exact
//! triangle–triangle crossing test. (Closest points and signed distances are
//! `sartor_core::MeshProximity`, the project's one closest-point query.)

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::TriMesh;
use sartor_core::tree::MedianTree;

const LEAF_SIZE: usize = 4;

/// A bounding-volume hierarchy over the triangles of a mesh for box-overlap queries: the
/// project's one [`MedianTree`] over the triangles' box centres, and each node's box.
#[derive(Clone, Debug)]
struct OverlapTree {
    positions: Vec<Vector3<f64>>,
    faces: Vec<[u32; 3]>,
    tree: MedianTree,
    /// Per node, `(lo, hi)` of its triangles' boxes.
    bounds: Vec<(Vector3<f64>, Vector3<f64>)>,
}

impl OverlapTree {
    fn new(positions: Vec<Vector3<f64>>, faces: Vec<[u32; 3]>) -> Self {
        let boxes: Vec<(Vector3<f64>, Vector3<f64>)> = faces
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| positions[i as usize]);
                (a.inf(&b).inf(&c), a.sup(&b).sup(&c))
            })
            .collect();
        let centroids: Vec<Vector3<f64>> = boxes.iter().map(|(lo, hi)| 0.5 * (lo + hi)).collect();
        let tree = MedianTree::new(&centroids, LEAF_SIZE);
        // Children come after their parents: fill the boxes in reverse.
        let mut bounds = vec![(Vector3::zeros(), Vector3::zeros()); tree.nodes().len()];
        for id in (0..tree.nodes().len()).rev() {
            let node = tree.nodes()[id];
            bounds[id] = if node.is_leaf() {
                tree.leaf_items(&node)
                    .iter()
                    .map(|&f| boxes[f as usize])
                    .fold(
                        (
                            Vector3::repeat(f64::INFINITY),
                            Vector3::repeat(f64::NEG_INFINITY),
                        ),
                        |(lo, hi), (a, b)| (lo.inf(&a), hi.sup(&b)),
                    )
            } else {
                let ((l0, h0), (l1, h1)) =
                    (bounds[node.left as usize], bounds[node.right as usize]);
                (l0.inf(&l1), h0.sup(&h1))
            };
        }
        Self {
            positions,
            faces,
            tree,
            bounds,
        }
    }

    /// Call `visit` with every triangle whose bounding box overlaps the box `[lo, hi]`, in a
    /// fixed order.
    fn for_each_overlapping(
        &self,
        lo: &Vector3<f64>,
        hi: &Vector3<f64>,
        mut visit: impl FnMut(u32),
    ) {
        if self.tree.nodes().is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let (nlo, nhi) = &self.bounds[i as usize];
            let overlaps = (0..3).all(|k| nlo[k] <= hi[k] && lo[k] <= nhi[k]);
            if !overlaps {
                continue;
            }
            let node = &self.tree.nodes()[i as usize];
            if node.is_leaf() {
                for &f in self.tree.leaf_items(node) {
                    let [a, b, c] = self.faces[f as usize].map(|v| self.positions[v as usize]);
                    let (tlo, thi) = (a.inf(&b).inf(&c), a.sup(&b).sup(&c));
                    if (0..3).all(|k| tlo[k] <= hi[k] && lo[k] <= thi[k]) {
                        visit(f);
                    }
                }
            } else {
                stack.push(node.right);
                stack.push(node.left);
            }
        }
    }
}

/// Whether segment `[p, q]` crosses triangle `(a, b, c)` (Möller–Trumbore; a segment lying in
/// the triangle's plane counts as not crossing).
pub fn segment_crosses_triangle(
    p: &Vector3<f64>,
    q: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> bool {
    let dir = q - p;
    let e1 = b - a;
    let e2 = c - a;
    let h = dir.cross(&e2);
    let det = e1.dot(&h);
    let scale = e1.norm() * e2.norm() * dir.norm();
    if det.abs() <= 1e-12 * scale {
        return false;
    }
    let inv = 1.0 / det;
    let s = p - a;
    let u = inv * s.dot(&h);
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let qv = s.cross(&e1);
    let v = inv * dir.dot(&qv);
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let t = inv * e2.dot(&qv);
    (0.0..=1.0).contains(&t)
}

/// Whether two triangles intersect (an edge of one crosses the other). Coplanar overlaps are
/// not reported.
pub fn triangles_intersect(x: &[Vector3<f64>; 3], y: &[Vector3<f64>; 3]) -> bool {
    (0..3).any(|k| segment_crosses_triangle(&x[k], &x[(k + 1) % 3], &y[0], &y[1], &y[2]))
        || (0..3).any(|k| segment_crosses_triangle(&y[k], &y[(k + 1) % 3], &x[0], &x[1], &x[2]))
}

/// Pairs `(f, g)` with `f < g` of triangles of a mesh that intersect and share no vertex,
/// sorted. An empty result means the mesh does not intersect itself (up to coplanar contact
/// and triangles touching at a shared vertex).
pub fn self_intersections(mesh: &TriMesh) -> Vec<(u32, u32)> {
    let bvh = OverlapTree::new(mesh.positions().to_vec(), mesh.faces().to_vec());
    let positions = mesh.positions();
    let faces = mesh.faces();
    let mut pairs: Vec<(u32, u32)> = (0..faces.len())
        .into_par_iter()
        .flat_map_iter(|f| {
            let t = faces[f];
            let x = t.map(|i| positions[i as usize]);
            let (lo, hi) = (x[0].inf(&x[1]).inf(&x[2]), x[0].sup(&x[1]).sup(&x[2]));
            let mut found = Vec::new();
            bvh.for_each_overlapping(&lo, &hi, |g| {
                if g as usize <= f {
                    return;
                }
                let u = faces[g as usize];
                if u.iter().any(|v| t.contains(v)) {
                    return;
                }
                let y = u.map(|i| positions[i as usize]);
                if triangles_intersect(&x, &y) {
                    found.push((f as u32, g));
                }
            });
            found
        })
        .collect();
    pairs.sort_unstable();
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An octahedron of radius 1 (closed, outward normals).
    fn octahedron() -> TriMesh {
        let p = vec![
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ];
        let f = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        TriMesh::new(p, f).unwrap()
    }

    #[test]
    fn detects_crossing_triangles_only() {
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        let crossing = [
            Vector3::new(0.2, 0.2, -1.0),
            Vector3::new(0.2, 0.2, 1.0),
            Vector3::new(0.5, 5.0, 0.0),
        ];
        let apart = crossing.map(|p| p + Vector3::new(0.0, 0.0, 3.0));
        assert!(triangles_intersect(&x, &crossing));
        assert!(!triangles_intersect(&x, &apart));
        assert!(self_intersections(&octahedron()).is_empty());
        let two = TriMesh::new(
            x.iter().chain(crossing.iter()).copied().collect(),
            vec![[0, 1, 2], [3, 4, 5]],
        )
        .unwrap();
        assert_eq!(self_intersections(&two), vec![(0, 1)]);
    }
}
