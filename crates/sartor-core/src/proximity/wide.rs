//! The closest-point query's hierarchy with eight children to a node, in f32: the median tree's
//! top three levels below each node collapsed into one node, whose children's boxes are stored
//! lane by lane (relative to the root box's corner), so that one point tests all eight in a few
//! vector instructions instead of descending three levels of f64 boxes. A leaf keeps its faces'
//! own boxes the same way: of a leaf within reach, only the faces whose box is within reach are
//! offered (on the simulator's walk a hinted query tested 14-23 faces in f64 before).
//!
//! The f32 boxes only prune: a child is skipped when its box lies farther than the best
//! distance so far plus a bound on the f32 rounding, and every triangle that is not skipped is
//! tested by the caller in f64 as before. The answer is therefore the one the f64 tree gives:
//! the nearest triangle, ties to the lowest index, whichever order the triangles are visited in.

use nalgebra::Vector3;

use super::Aabb;
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
    /// Per lane: a leaf's number of items (0: an inner child).
    count: [u32; W],
    /// The lanes in use, as bits.
    used: u32,
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
    /// Per node and lane, the median tree's node whose box the lane holds.
    source: Vec<[u32; W]>,
    /// The leaves, each face's own box: a leaf within reach offers only its faces within it.
    leaves: Vec<Leaf>,
    /// The root box's lower corner: the origin of the f32 boxes.
    origin: Vector3<f64>,
    /// The root box's largest side, m.
    extent: f64,
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
            count: [0; W],
            used: (1u32 << lanes.len()) - 1,
        });
        self.source.push([u32::MAX; W]);
        for (l, &n) in lanes.iter().enumerate() {
            let node = nodes[n as usize];
            let (child, count) = if node.is_leaf() {
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
                (self.leaves.len() as u32 - 1, node.count)
            } else {
                (self.build(tree, n), 0)
            };
            self.nodes[index].child[l] = child;
            self.nodes[index].count[l] = count;
            self.source[index][l] = n;
        }
        index as u32
    }

    /// Take the boxes of the median tree's nodes (`bounds`, indexed like its nodes) and of its
    /// faces (`face_bounds`, in the tree's order).
    pub(super) fn refit(&mut self, bounds: &[Aabb], face_bounds: &[Aabb]) {
        let Some(root) = bounds.first() else {
            return;
        };
        self.origin = root.min;
        self.extent = (root.max - root.min).max();
        let o = self.origin;
        for (node, source) in self.nodes.iter_mut().zip(&self.source) {
            for (l, &n) in source.iter().enumerate() {
                if n != u32::MAX {
                    let b = &bounds[n as usize];
                    for k in 0..3 {
                        node.lo[k][l] = relative(b.min[k], o[k]);
                        node.hi[k][l] = relative(b.max[k], o[k]);
                    }
                }
            }
        }
        for leaf in &mut self.leaves {
            let start = leaf.start as usize;
            for (j, b) in face_bounds[start..start + leaf.count as usize]
                .iter()
                .enumerate()
            {
                for k in 0..3 {
                    leaf.lo[k][j] = relative(b.min[k], o[k]);
                    leaf.hi[k][j] = relative(b.max[k], o[k]);
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
        let mut stack = [(0u32, 0.0f32); STACK];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let (id, d2) = stack[top];
            if d2 > reach2 {
                continue;
            }
            let node = &self.nodes[id as usize];
            let lb2 = distance2(node, &x);
            let mut hits = node.used;
            for (l, &b) in lb2.iter().enumerate() {
                if b > reach2 {
                    hits &= !(1u32 << l);
                }
            }
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
                if node.count[l] == 0 {
                    inner[n_inner] = (node.child[l], b);
                    n_inner += 1;
                    continue;
                }
                if b > reach2 {
                    continue;
                }
                let leaf = &self.leaves[node.child[l] as usize];
                let fb2 = leaf_distance2(leaf, &x);
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

/// Squared distance from `x` to each lane's box (∞ for an unused lane).
#[inline(always)]
fn distance2(node: &Node, x: &[f32; 3]) -> [f32; W] {
    let mut d2 = [0.0f32; W];
    for k in 0..3 {
        for l in 0..W {
            let d = fmax(fmax(node.lo[k][l] - x[k], x[k] - node.hi[k][l]), 0.0);
            d2[l] += d * d;
        }
    }
    d2
}

/// Squared distance from `x` to each face box of `leaf` (∞ for an unused lane).
#[inline(always)]
fn leaf_distance2(leaf: &Leaf, x: &[f32; 3]) -> [f32; LEAF] {
    let mut d2 = [0.0f32; LEAF];
    for k in 0..3 {
        for j in 0..LEAF {
            let d = fmax(fmax(leaf.lo[k][j] - x[k], x[k] - leaf.hi[k][j]), 0.0);
            d2[j] += d * d;
        }
    }
    d2
}

/// `v − origin` in f32, rounded to nearest: within `extent` · 2⁻²⁴ of the f64 value, which
/// the search's slack covers.
#[inline(always)]
fn relative(v: f64, origin: f64) -> f32 {
    (v - origin) as f32
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
