//! The one median-split hierarchy: a binary tree over items (triangles) by their centroids,
//! shared by every tree of the project — the closest-point query ([`MeshProximity`]), the
//! winding-number clusters of [`BodyDistance`] and the simulator's self-intersection check.
//! Each of them keeps its own per-node data (boxes, dipoles) in an array indexed like
//! [`MedianTree::nodes`] and refits it children first.
//!
//! A node holds items `order[start..start + count]` of its subtree. It is split while it holds
//! more than `leaf_size` items: along the longest axis of its items' centroid bounds (the first
//! such axis on a tie), at the median, ties broken by item index, so the tree is a pure function
//! of the centroids. Nodes are stored parents first (pre-order): a node's left child comes right
//! after it.
//!
//! [`MeshProximity`]: crate::MeshProximity
//! [`BodyDistance`]: crate::BodyDistance

use std::ops::Range;

use nalgebra::Vector3;

/// One node of a [`MedianTree`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TreeNode {
    /// First item of the subtree in [`MedianTree::order`].
    pub start: u32,
    /// Leaf: its number of items (> 0); inner node: 0.
    pub count: u32,
    /// Inner node: the left child (always the next node); leaf: 0.
    pub left: u32,
    /// Inner node: the right child; leaf: 0.
    pub right: u32,
}

impl TreeNode {
    /// Whether the node is a leaf.
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }

    /// A leaf's range in [`MedianTree::order`] (empty for an inner node).
    #[inline]
    pub fn items(&self) -> Range<usize> {
        self.start as usize..(self.start + self.count) as usize
    }
}

/// A binary hierarchy over items by median splits of their centroids (see the
/// [module docs](self)).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MedianTree {
    nodes: Vec<TreeNode>,
    order: Vec<u32>,
}

impl MedianTree {
    /// Build over `centroids` (one per item), with at most `leaf_size` (≥ 1) items per leaf.
    /// No items: no nodes.
    pub fn new(centroids: &[Vector3<f64>], leaf_size: usize) -> Self {
        let leaf_size = leaf_size.max(1);
        let n = centroids.len();
        let mut tree = Self {
            nodes: Vec::with_capacity(2 * n / leaf_size + 1),
            order: (0..n as u32).collect(),
        };
        if n > 0 {
            tree.build(0, n, centroids, leaf_size);
        }
        tree
    }

    fn build(&mut self, start: usize, end: usize, centroids: &[Vector3<f64>], leaf: usize) -> u32 {
        let id = self.nodes.len() as u32;
        self.nodes.push(TreeNode {
            start: start as u32,
            count: (end - start) as u32,
            left: 0,
            right: 0,
        });
        if end - start <= leaf {
            return id;
        }
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for &i in &self.order[start..end] {
            lo = lo.inf(&centroids[i as usize]);
            hi = hi.sup(&centroids[i as usize]);
        }
        let axis = (hi - lo).imax();
        let mid = (start + end) / 2;
        self.order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
            centroids[a as usize][axis]
                .total_cmp(&centroids[b as usize][axis])
                .then(a.cmp(&b))
        });
        let left = self.build(start, mid, centroids, leaf);
        let right = self.build(mid, end, centroids, leaf);
        let node = &mut self.nodes[id as usize];
        node.count = 0;
        node.left = left;
        node.right = right;
        id
    }

    /// The nodes, parents first; the root is node 0.
    #[inline]
    pub fn nodes(&self) -> &[TreeNode] {
        &self.nodes
    }

    /// Item indices in leaf order.
    #[inline]
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// The items of leaf `node` (empty for an inner node).
    #[inline]
    pub fn leaf_items(&self, node: &TreeNode) -> &[u32] {
        &self.order[node.items()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(tree: &MedianTree, n: usize, leaf: usize) {
        let mut seen = vec![0u32; n];
        let mut stack = vec![0usize];
        while let Some(id) = stack.pop() {
            let node = tree.nodes()[id];
            if node.is_leaf() {
                assert!(node.count as usize <= leaf);
                for &i in tree.leaf_items(&node) {
                    seen[i as usize] += 1;
                }
            } else {
                assert_eq!(node.left as usize, id + 1, "left child follows its parent");
                assert!(node.right > node.left);
                stack.extend([node.left as usize, node.right as usize]);
            }
        }
        assert!(
            seen.iter().all(|&s| s == 1),
            "every item in exactly one leaf"
        );
    }

    #[test]
    fn every_item_in_one_leaf_and_splits_at_the_median() {
        let pts: Vec<Vector3<f64>> = (0..37)
            .map(|i| Vector3::new((i * 7 % 37) as f64, (i % 5) as f64 * 0.1, 0.0))
            .collect();
        for leaf in [1, 4, 8, 64] {
            check(&MedianTree::new(&pts, leaf), pts.len(), leaf);
        }
        // The root splits along x (the longest axis): every left item is left of every right one.
        let tree = MedianTree::new(&pts, 4);
        let root = tree.nodes()[0];
        let (l, r) = (
            tree.nodes()[root.left as usize],
            tree.nodes()[root.right as usize],
        );
        assert_eq!((l.start, r.start), (0, 18));
        let max_left = tree.order()[..18].iter().map(|&i| pts[i as usize].x);
        let min_right = tree.order()[18..].iter().map(|&i| pts[i as usize].x);
        assert!(max_left.fold(f64::MIN, f64::max) <= min_right.fold(f64::MAX, f64::min));
    }

    #[test]
    fn empty_and_equal_centroids() {
        assert!(MedianTree::new(&[], 4).nodes().is_empty());
        // All centroids equal: ties are broken by index, deterministically.
        let same = vec![Vector3::new(1.0, 1.0, 1.0); 10];
        let a = MedianTree::new(&same, 2);
        check(&a, 10, 2);
        assert_eq!(a, MedianTree::new(&same, 2));
    }
}
