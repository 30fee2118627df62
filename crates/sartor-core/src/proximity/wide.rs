//! The closest-point query's hierarchy, eight children to a node, in f32: the median tree's top
//! three levels below each node collapsed into one node, whose children's boxes are stored lane
//! by lane, so that one point tests all eight in a few vector instructions. A leaf keeps its
//! faces' own boxes the same way: of a leaf within reach, only the faces whose box is within
//! reach are offered (on the simulator's walk a hinted query tested 14–23 faces in f64 before).
//!
//! The boxes are refitted in f32 from the vertices: each vertex relative to the lowest corner of
//! all of them, rounded to nearest (a monotone map, so each face's f32 box is its f64 box
//! rounded), then each lane the union of its faces or its child's lanes. This replaced a binary
//! tree of f64 boxes, refitted too and read by the three queries: on the simulator's walk the
//! body's refit per substep went back below what that tree alone cost.
//!
//! The f32 boxes only prune: a child is skipped when its box lies farther than the best
//! distance so far (or the radius asked) plus a bound on the f32 rounding, and every triangle
//! that is not skipped is tested by the caller in f64. The answer is therefore the one every
//! triangle would give: the nearest triangle, ties to the lowest index, whichever order the
//! triangles are visited in.

use nalgebra::Vector3;

use crate::bounding_box;
use crate::tree::MedianTree;

/// Children per node.
const W: usize = 8;
/// Relative bound on the f32 rounding of a box distance (a few units of 2⁻²⁴, with room).
const REL: f64 = 1e-6;
/// Nodes waiting on the traversal stack at most: eight per level, and a median tree over
/// 2³² triangles has fewer than 12 levels of eight.
const STACK: usize = 128;

#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct Node {
    lo: [[f32; W]; 3],
    hi: [[f32; W]; 3],
    /// Per lane: a leaf's index in `leaves`, or an inner child's node.
    child: [u32; W],
    /// The lanes in use, as bits.
    used: u32,
    /// The lanes holding a leaf, as bits.
    leaf: u32,
}

/// Faces per leaf block (at least the median tree's leaf size).
const LEAF: usize = 4;

/// A leaf's faces: their boxes lane by lane, and where they sit in the median tree's order.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
struct Leaf {
    lo: [[f32; LEAF]; 3],
    hi: [[f32; LEAF]; 3],
    start: u32,
    count: u32,
}

/// The eight-wide hierarchy (see the module docs). Empty for a tree without nodes.
#[derive(Clone, Debug, Default)]
pub(super) struct WideTree {
    nodes: Vec<Node>,
    /// The vertices relative to `origin`, in f32 (scratch of the refit).
    rel: Vec<Vector3<f32>>,
    /// The leaves, each face's own box: a leaf within reach offers only its faces within it.
    leaves: Vec<Leaf>,
    /// The vertices' lowest corner: the origin of the f32 boxes.
    origin: Vector3<f64>,
    /// The vertices' box's largest side, m.
    extent: f64,
    /// The boxes of a linear move ([`WideTree::fit_span`]): at its start, and the change to
    /// its end (zero where they agree, lanes at infinity included).
    span: Span,
}

/// Every leaf's and node's box coordinates at a span's start, flat (a leaf's or node's `lo`
/// then `hi`, as stored), and their changes to its end.
#[derive(Clone, Debug, Default)]
struct Span {
    leaves: [Vec<f32>; 2],
    nodes: [Vec<f32>; 2],
    /// The origin and extent the span's boxes are relative to (a refit since may have moved
    /// the tree's).
    origin: Vector3<f64>,
    extent: f64,
}

/// The padding of an interpolated box, relative to the extent: the rounding of the f32
/// interpolation (a few units of 2⁻²⁴ of the extent) several times over.
const SPAN_PAD: f64 = 1.0 / (1u64 << 20) as f64;

/// A leaf's box coordinates (`lo` then `hi`).
const LEAF_COORDS: usize = 6 * LEAF;
/// A node's.
const NODE_COORDS: usize = 6 * W;

impl Leaf {
    fn coords(&self) -> impl Iterator<Item = f32> + '_ {
        self.lo.iter().chain(&self.hi).flatten().copied()
    }
}

impl Node {
    fn coords(&self) -> impl Iterator<Item = f32> + '_ {
        self.lo.iter().chain(&self.hi).flatten().copied()
    }
}

/// `lo` and `hi` of `N` lanes at `start + change · t` (both flat, `lo` then `hi`), padded
/// outwards by `pad`.
#[inline(always)]
fn interpolate_lanes<const N: usize>(
    lo: &mut [[f32; N]; 3],
    hi: &mut [[f32; N]; 3],
    start: &[f32],
    change: &[f32],
    t: f32,
    pad: f32,
) {
    for k in 0..3 {
        for l in 0..N {
            let (a, b) = (k * N + l, (3 + k) * N + l);
            lo[k][l] = start[a] + change[a] * t - pad;
            hi[k][l] = start[b] + change[b] * t + pad;
        }
    }
}

impl WideTree {
    /// The wide form of `tree` (boxes empty until [`WideTree::refit`]).
    pub(super) fn new(tree: &MedianTree) -> Self {
        let mut wide = Self::default();
        if !tree.nodes().is_empty() {
            wide.build(tree, 0);
        }
        wide
    }

    /// Add the node whose children are the descendants of median-tree node `id` three levels
    /// down (fewer below a leaf); returns its index.
    fn build(&mut self, tree: &MedianTree, id: u32) -> u32 {
        let nodes = tree.nodes();
        let mut lanes = vec![id];
        // Split the first inner node until eight lanes are full or only leaves are left.
        while lanes.len() < W {
            let Some(k) = lanes.iter().position(|&n| !nodes[n as usize].is_leaf()) else {
                break;
            };
            let n = nodes[lanes[k] as usize];
            lanes.splice(k..=k, [n.left, n.right]);
        }
        let index = self.nodes.len();
        self.nodes.push(Node {
            lo: [[f32::INFINITY; W]; 3],
            hi: [[f32::INFINITY; W]; 3],
            child: [u32::MAX; W],
            used: (1u32 << lanes.len()) - 1,
            leaf: 0,
        });
        for (l, &n) in lanes.iter().enumerate() {
            let node = nodes[n as usize];
            let child = if node.is_leaf() {
                assert!(
                    node.count as usize <= LEAF,
                    "leaves of at most {LEAF} faces"
                );
                self.leaves.push(Leaf {
                    lo: [[f32::INFINITY; LEAF]; 3],
                    hi: [[f32::INFINITY; LEAF]; 3],
                    start: node.start,
                    count: node.count,
                });
                self.nodes[index].leaf |= 1 << l;
                self.leaves.len() as u32 - 1
            } else {
                self.build(tree, n)
            };
            self.nodes[index].child[l] = child;
        }
        index as u32
    }

    /// The boxes for the vertices at `positions` (of which `faces` are the triangles, in the
    /// median tree's `order`): each vertex relative to the lowest corner of all of them, in f32
    /// (rounded to nearest, a monotone map, so a face's f32 box is its f64 box rounded), each
    /// face's box from its corners, each node's lanes the union of their faces or children.
    pub(super) fn refit(&mut self, positions: &[Vector3<f64>], faces: &[[u32; 3]], order: &[u32]) {
        if self.nodes.is_empty() {
            return;
        }
        let Some((lo, hi)) = bounding_box(positions) else {
            return;
        };
        self.origin = lo;
        self.extent = (hi - lo).max();
        self.fit(positions, faces, order);
    }

    /// The boxes at both ends of a linear move of the vertices from `start` to `end`, relative
    /// to the lowest corner of both, for [`WideTree::interpolate`]; the current boxes are
    /// `start`'s.
    pub(super) fn fit_span(
        &mut self,
        start: &[Vector3<f64>],
        end: &[Vector3<f64>],
        faces: &[[u32; 3]],
        order: &[u32],
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let (Some((lo0, hi0)), Some((lo1, hi1))) = (bounding_box(start), bounding_box(end)) else {
            return;
        };
        let (lo, hi) = (lo0.inf(&lo1), hi0.sup(&hi1));
        self.origin = lo;
        self.extent = (hi - lo).max();
        (self.span.origin, self.span.extent) = (self.origin, self.extent);
        // The end's boxes first, kept as the changes' ends; then the start's, which stay.
        for (k, positions) in [(1, end), (0, start)] {
            self.fit(positions, faces, order);
            let Span { leaves, nodes, .. } = &mut self.span;
            leaves[k].clear();
            leaves[k].extend(self.leaves.iter().flat_map(Leaf::coords));
            nodes[k].clear();
            nodes[k].extend(self.nodes.iter().flat_map(Node::coords));
        }
        let Span { leaves, nodes, .. } = &mut self.span;
        for [start, end] in [leaves, nodes] {
            for (s, e) in start.iter().zip(end.iter_mut()) {
                *e = if *s == *e { 0.0 } else { *e - s };
            }
        }
    }

    /// The boxes of the vertices at `start + (end − start) a` of the last
    /// [`WideTree::fit_span`], `a` in `[0, 1]`: each face's and node's box interpolated
    /// between its boxes at the two ends, padded by the rounding. A point of a face moves as
    /// a convex combination of its corners, so the face's box at `a` lies within the
    /// interpolation of its boxes at the ends (each lowest coordinate at least the
    /// interpolated lowest ones), and a node's likewise: the boxes still contain their faces,
    /// a little looser where a face turns. Lanes at infinity (unused) stay there. The
    /// positions' own f64 interpolation is the caller's. False (nothing done) when no span
    /// was fitted.
    pub(super) fn interpolate(&mut self, a: f64) -> bool {
        let Span {
            leaves,
            nodes,
            origin,
            extent,
        } = &self.span;
        if leaves[0].len() != self.leaves.len() * LEAF_COORDS {
            return self.nodes.is_empty();
        }
        (self.origin, self.extent) = (*origin, *extent);
        let (t, pad) = (a as f32, (SPAN_PAD * self.extent) as f32);
        for (leaf, (s, d)) in self.leaves.iter_mut().zip(
            leaves[0]
                .chunks_exact(LEAF_COORDS)
                .zip(leaves[1].chunks_exact(LEAF_COORDS)),
        ) {
            interpolate_lanes(&mut leaf.lo, &mut leaf.hi, s, d, t, pad);
        }
        for (node, (s, d)) in self.nodes.iter_mut().zip(
            nodes[0]
                .chunks_exact(NODE_COORDS)
                .zip(nodes[1].chunks_exact(NODE_COORDS)),
        ) {
            interpolate_lanes(&mut node.lo, &mut node.hi, s, d, t, pad);
        }
        true
    }

    /// Whether every face's box contains the face at `positions` (in f64; for tests).
    #[cfg(test)]
    pub(super) fn contains_faces(
        &self,
        positions: &[Vector3<f64>],
        faces: &[[u32; 3]],
        order: &[u32],
    ) -> bool {
        self.leaves.iter().all(|leaf| {
            let start = leaf.start as usize;
            order[start..start + leaf.count as usize]
                .iter()
                .enumerate()
                .all(|(j, &f)| {
                    faces[f as usize].iter().all(|&v| {
                        let q = positions[v as usize] - self.origin;
                        (0..3).all(|k| {
                            f64::from(leaf.lo[k][j]) <= q[k] && q[k] <= f64::from(leaf.hi[k][j])
                        })
                    })
                })
        })
    }

    /// Every box from `positions` relative to `self.origin`.
    fn fit(&mut self, positions: &[Vector3<f64>], faces: &[[u32; 3]], order: &[u32]) {
        let lo = self.origin;
        self.rel.clear();
        self.rel
            .extend(positions.iter().map(|p| (p - lo).map(|c| c as f32)));
        for leaf in &mut self.leaves {
            let start = leaf.start as usize;
            for (j, &f) in order[start..start + leaf.count as usize].iter().enumerate() {
                let [a, b, c] = faces[f as usize].map(|v| self.rel[v as usize]);
                for k in 0..3 {
                    leaf.lo[k][j] = fmin(fmin(a[k], b[k]), c[k]);
                    leaf.hi[k][j] = fmax(fmax(a[k], b[k]), c[k]);
                }
            }
        }
        // Children come after their parent: the last node first.
        for id in (0..self.nodes.len()).rev() {
            for l in 0..W {
                if self.nodes[id].used & (1 << l) == 0 {
                    continue;
                }
                let (child, is_leaf) = (
                    self.nodes[id].child[l] as usize,
                    self.nodes[id].leaf & (1 << l) != 0,
                );
                let (mut blo, mut bhi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
                let mut take = |clo: [f32; 3], chi: [f32; 3]| {
                    for k in 0..3 {
                        blo[k] = fmin(blo[k], clo[k]);
                        bhi[k] = fmax(bhi[k], chi[k]);
                    }
                };
                if is_leaf {
                    let leaf = &self.leaves[child];
                    for j in 0..leaf.count as usize {
                        take(leaf.lo.map(|c| c[j]), leaf.hi.map(|c| c[j]));
                    }
                } else {
                    let node = &self.nodes[child];
                    for j in (0..W).filter(|j| node.used & (1 << j) != 0) {
                        take(node.lo.map(|c| c[j]), node.hi.map(|c| c[j]));
                    }
                }
                let node = &mut self.nodes[id];
                for k in 0..3 {
                    node.lo[k][l] = blo[k];
                    node.hi[k][l] = bhi[k];
                }
            }
        }
    }

    /// Offer `visit` every triangle (by index into `order`'s leaves) whose box may lie
    /// within the best distance so far, `best_d2` (which `visit` lowers as it finds closer
    /// triangles): the nearer lanes of a node first, leaves before inner nodes.
    #[inline]
    pub(super) fn search(
        &self,
        p: &Vector3<f64>,
        order: &[u32],
        best_d2: &mut f64,
        mut visit: impl FnMut(u32, &mut f64),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let q = p - self.origin;
        let x = [q.x as f32, q.y as f32, q.z as f32];
        // The f32 box distance errs by at most a few roundings (2⁻²⁴ relative) of numbers as
        // large as the point's and the boxes' coordinates (the boxes' own rounding included).
        let slack = REL * (q.amax() + self.extent) + 1e-12;
        let reach = |d2: f64| -> f32 { up((d2.sqrt() * (1.0 + REL) + slack).powi(2)) };
        let mut reach2 = reach(*best_d2);
        // Nothing within reach of the root's lanes (most of a bounded search's far points):
        // done before the stack is set up.
        let root = &self.nodes[0];
        let lb2 = lane_distance2(&root.lo, &root.hi, &x);
        if root.used & not_beyond(&lb2, reach2) == 0 {
            return;
        }
        let mut stack = [(0u32, 0.0f32); STACK];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let (id, d2) = stack[top];
            if d2 > reach2 {
                continue;
            }
            let node = &self.nodes[id as usize];
            let lb2 = lane_distance2(&node.lo, &node.hi, &x);
            let mut hits = node.used & not_beyond(&lb2, reach2);
            // The lanes within reach, nearest first.
            let mut near = [(0.0f32, 0u8); W];
            let mut n = 0;
            while hits != 0 {
                let l = hits.trailing_zeros() as usize;
                hits &= hits - 1;
                let mut k = n;
                while k > 0 && near[k - 1].0 > lb2[l] {
                    near[k] = near[k - 1];
                    k -= 1;
                }
                near[k] = (lb2[l], l as u8);
                n += 1;
            }
            let mut inner = [(0u32, 0.0f32); W];
            let mut n_inner = 0;
            for &(b, l) in &near[..n] {
                let l = l as usize;
                if node.leaf & (1 << l) == 0 {
                    inner[n_inner] = (node.child[l], b);
                    n_inner += 1;
                    continue;
                }
                if b > reach2 {
                    continue;
                }
                let leaf = &self.leaves[node.child[l] as usize];
                let fb2 = lane_distance2(&leaf.lo, &leaf.hi, &x);
                let start = leaf.start as usize;
                for (j, &f) in order[start..start + leaf.count as usize].iter().enumerate() {
                    if fb2[j] > reach2 {
                        continue;
                    }
                    let before = *best_d2;
                    visit(f, best_d2);
                    if *best_d2 != before {
                        reach2 = reach(*best_d2);
                    }
                }
            }
            // Farthest pushed first: the nearest is searched next.
            for &child in inner[..n_inner].iter().rev() {
                stack[top] = child;
                top += 1;
            }
        }
    }
}

impl WideTree {
    /// Offer `visit` every triangle (by index into `order`'s leaves) whose box the half-line
    /// `p + t d`, `t ≥ 0`, may meet; `visit` returning `None` stops the walk, which then returns
    /// `None`. Each box is padded by a bound on the f32 rounding ([`ray_lanes`]), so every
    /// triangle the half-line meets, or passes within that bound of, is offered.
    #[inline]
    pub(super) fn ray(
        &self,
        p: &Vector3<f64>,
        d: &Vector3<f64>,
        order: &[u32],
        mut visit: impl FnMut(u32) -> Option<()>,
    ) -> Option<()> {
        if self.nodes.is_empty() {
            return Some(());
        }
        let q = p - self.origin;
        let ray = Ray {
            x: [q.x as f32, q.y as f32, q.z as f32],
            inv: [d.x as f32, d.y as f32, d.z as f32].map(|c| 1.0 / c),
            // As in `search`: a few roundings of numbers as large as the point's and the
            // boxes' coordinates, with room (see `ray_lanes`).
            pad: up(REL * (q.amax() + self.extent) + 1e-12),
        };
        let mut stack = [0u32; STACK];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            let mut hits = ray_lanes(&node.lo, &node.hi, &ray) & node.used;
            while hits != 0 {
                let l = hits.trailing_zeros() as usize;
                hits &= hits - 1;
                if node.leaf & (1 << l) == 0 {
                    stack[top] = node.child[l];
                    top += 1;
                    continue;
                }
                let leaf = &self.leaves[node.child[l] as usize];
                let start = leaf.start as usize;
                let mut faces = ray_lanes(&leaf.lo, &leaf.hi, &ray) & ((1 << leaf.count) - 1);
                while faces != 0 {
                    let j = faces.trailing_zeros() as usize;
                    faces &= faces - 1;
                    visit(order[start + j])?;
                }
            }
        }
        Some(())
    }
}

/// A half-line in a tree's f32 frame: its start, the inverse of its direction per axis
/// (infinite along an axis it does not move on) and the boxes' padding.
struct Ray {
    x: [f32; 3],
    inv: [f32; 3],
    pad: f32,
}

/// Per box of `N` stored lane by lane, as a bit: whether `ray` meets the box grown by its
/// padding (a lane at infinity, unused, never). The slab test in f32 errs by a few roundings
/// of the coordinates per axis, each at most `2⁻²⁴ (|x| + extent) / |d_k|` in `t`; growing the
/// box by `pad`, some eight times that relative to the coordinates, widens every slab's
/// interval by `pad / |d_k|` on both sides, so a half-line that meets the box itself is never
/// read as missing the grown one.
#[inline(always)]
fn ray_lanes<const N: usize>(lo: &[[f32; N]; 3], hi: &[[f32; N]; 3], ray: &Ray) -> u32 {
    let (mut t0, mut t1) = ([0.0f32; N], [f32::INFINITY; N]);
    let mut outside = [false; N];
    for k in 0..3 {
        let (x, inv, pad) = (ray.x[k], ray.inv[k], ray.pad);
        if inv.is_infinite() {
            // Parallel to the slab: inside it for every `t`, or for none.
            for l in 0..N {
                outside[l] |= !((lo[k][l] - pad <= x) & (x <= hi[k][l] + pad));
            }
            continue;
        }
        for l in 0..N {
            let a = (lo[k][l] - pad - x) * inv;
            let b = (hi[k][l] + pad - x) * inv;
            t0[l] = fmax(t0[l], fmin(a, b));
            t1[l] = fmin(t1[l], fmax(a, b));
        }
    }
    // A lane at infinity: `a` and `b` infinite of one sign, or NaN; `t0 <= t1` fails for both
    // (`t0` infinite, or a NaN compare).
    #[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
    {
        // The same tests four lanes at a time, read out by `bitmask` (with the masks of
        // `not_beyond`, the try-on page's change of shape 157.7–159.5 → 138.3–151.0 ms in the
        // browser test, two runs of each page in turn).
        use core::arch::wasm32::{
            f32x4, f32x4_le, f32x4_ne, f32x4_splat, i32x4, i32x4_bitmask, v128_and, v128_andnot,
        };
        const { assert!(N.is_multiple_of(4) && N <= 32) };
        let mut hits = 0u32;
        for c in 0..N / 4 {
            let at = |v: &[f32; N]| f32x4(v[4 * c], v[4 * c + 1], v[4 * c + 2], v[4 * c + 3]);
            let out = |l: usize| -i32::from(outside[4 * c + l]);
            let met = v128_and(
                f32x4_le(at(&t0), at(&t1)),
                f32x4_ne(at(&lo[0]), f32x4_splat(f32::INFINITY)),
            );
            let met = v128_andnot(met, i32x4(out(0), out(1), out(2), out(3)));
            hits |= u32::from(i32x4_bitmask(met)) << (4 * c);
        }
        hits
    }
    #[cfg(not(all(target_arch = "wasm32", target_feature = "simd128")))]
    {
        let mut hits = 0u32;
        for l in 0..N {
            hits |= u32::from((t0[l] <= t1[l]) & !outside[l] & (lo[0][l] != f32::INFINITY)) << l;
        }
        hits
    }
}

/// Bit `l` set where `v[l]` is not beyond `t` (`!(v[l] > t)`: NaN lanes set), for `N` ≤ 32.
#[inline(always)]
fn not_beyond<const N: usize>(v: &[f32; N], t: f32) -> u32 {
    #[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
    {
        // Four lanes at a time, read out by `bitmask`.
        use core::arch::wasm32::{f32x4, f32x4_gt, f32x4_splat, i32x4_bitmask};
        const { assert!(N.is_multiple_of(4) && N <= 32) };
        let t = f32x4_splat(t);
        let mut beyond = 0u32;
        for c in 0..N / 4 {
            let lanes = f32x4(v[4 * c], v[4 * c + 1], v[4 * c + 2], v[4 * c + 3]);
            beyond |= u32::from(i32x4_bitmask(f32x4_gt(lanes, t))) << (4 * c);
        }
        !beyond & (u32::MAX >> (32 - N))
    }
    #[cfg(not(all(target_arch = "wasm32", target_feature = "simd128")))]
    {
        let mut within = u32::MAX >> (32 - N);
        for (l, &b) in v.iter().enumerate() {
            if b > t {
                within &= !(1u32 << l);
            }
        }
        within
    }
}

/// Squared distance from `x` to each of `N` boxes stored lane by lane (∞ for a lane at
/// infinity: an unused one).
#[inline(always)]
fn lane_distance2<const N: usize>(
    lo: &[[f32; N]; 3],
    hi: &[[f32; N]; 3],
    x: &[f32; 3],
) -> [f32; N] {
    let mut d2 = [0.0f32; N];
    for k in 0..3 {
        for l in 0..N {
            let d = fmax(fmax(lo[k][l] - x[k], x[k] - hi[k][l]), 0.0);
            d2[l] += d * d;
        }
    }
    d2
}

/// `min(a, b)` as one vector instruction (see [`fmax`]).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// `max(a, b)` as one vector instruction (`f32::max`'s NaN rule costs a blend; a NaN here
/// only makes a box nearer, which prunes less).
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// The smallest f32 at or above `v`.
fn up(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v { f.next_up() } else { f }
}
