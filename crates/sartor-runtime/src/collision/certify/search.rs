//! The certified query's search: for each point, the region faces within its nearest distance
//! plus a slack (see the parent module's docs for the proof the answers feed).
//!
//! The region's faces form a tree rebuilt per frame ([`Tree`]): the spatial clusters of [`CLUSTER`]
//! faces of [`Frame`] (fixed at rest, by median splits), in groups of [`GROUP`]; each level is a
//! block of [`W`] boxes stored lane by lane, so that a point tests a whole group of clusters, or a
//! whole cluster's faces (a bound from the plane and the edges' planes:
//! [`FaceBlock::distance2`]), in a few vector instructions. A point starts from the face it was
//! nearest last frame: the distance to it bounds the search at once. The points are then taken in
//! packets of up to [`PACKET`] whose warm faces lie in the same or the next clusters (a counting
//! sort by that cluster): a packet walks the two upper levels once, for the box of its points and
//! the largest of their reaches, and each of its points tests only the clusters that walk gathered
//! (every cluster within the point's own reach is among them). A packet that gathers more than
//! [`PACKET_CLUSTERS`] (points far apart or far from the body) walks the tree point by point, as do
//! points without a warm face. A cloth vertex then tests one or two blocks of gathered cluster
//! boxes and about three clusters, and computes the distance of about one face besides its warm
//! face's (8,710-triangle run: 0.9 per point). Per point the search keeps its nearest distance `b`
//! in f32 and every face within `b` + [`SLACK_M`]: the f32 distances are within a micrometre of the
//! f64 ones, so that list holds every face the f64 query could return, and
//! [`sartor_core::MeshProximity::nearest_among`] on it is the exact query's answer (same faces,
//! same arithmetic, same tie rule). A point with more near-ties than a list holds, or only sliver
//! faces near, is searched against every face.
//!
//! It replaces a sweep of the face clusters over a grid of the cloth vertices, with reaches of 2, 4
//! and 15 cm (cluster-major): on the shipped model's walk the point-major tree search made the
//! post-process 12–15 % faster per frame (no second and third reach for its loose cloth), on the
//! trained 8,710-triangle export it measured the same as the sweep. It cost about 250 ns per point
//! on the AMD EPYC VM. The packets took the shipped model's post-process from 0.89–0.90 to
//! 0.84–0.85 ms (`cargo bench --bench postprocess`, two rounds of alternating builds) and the
//! certified one of `cargo xtask bench runtime --triangles 8710` from 2.00–2.01 to 1.63–1.90 ms
//! (two rounds; the frames' own post-process 5–10 % faster); packets of 8 or 32 points, or a cap of
//! 32 or 128 clusters, measured the same. With the box and the plane alone about 3.4 faces per
//! point passed the bound and needed their distance, 1.3 of them close enough to stay
//! (8,710-triangle run); the edges' planes cut them to 0.9: the shipped model's post-process
//! 0.83–0.84 → 0.75–0.76 ms, the 8,710-triangle one 1.70–1.76 → 1.20–1.47 ms (two rounds each,
//! alternating builds). The faces' own boxes then bounded nothing the planes did not (dropped: the
//! same 0.65 ms on the shipped model, 1.26–1.27 → 1.20 ms at 8,710 triangles). Tried and not kept:
//! keeping each list 4 mm wider within the margin, so that a pushed vertex's next pass could reuse
//! it (the wider first pass cost more than the later passes saved: 1.40 → 1.49 ms on the shipped
//! walk), visiting points in the order of their warm face's cluster without sharing the walk (no
//! change), and the search compiled for AVX-512 (no faster on the Intel Xeon VM; on the AMD EPYC Zen 5 VM
//! 1–3 % faster, so it is built for the widest vectors present).
//!
//! # The sweep
//!
//! In the first pass most vertices are proven beyond the margin, and for them the list is more than
//! the proof needs. A vertex with a warm face is first *swept* ([`Tree::sweep`]): over the clusters
//! within its reach (the warm face's distance plus the slack), every face whose bound lies within
//! the reach must have the vertex in front of its plane by more than the guard and a bound beyond
//! the margin (both read from the lanes the bound is computed in; a sliver is never clear). Every
//! face within the nearest distance plus the slack is among them, so this is the parent module's
//! proof over more faces; where it holds no face distance is computed and no list is kept, and
//! where it fails the vertex is searched as above. A crease face in reach (where buried faces are
//! sought) fails it, as it fails the list's certificate. On the shipped model's walk it proves 84 %
//! of the vertices; the post-process 491–504 → 405–420 µs and the int8 frame 527–533 → 440–443 µs
//! (`cargo bench --bench postprocess`, alternating builds, two rounds); at 8,710 triangles the
//! certified post-process of `cargo xtask bench runtime --triangles 8710` 0.87 → 0.76 ms, with the
//! same answers as the exact query.
//!
//! The search serves the vertices of one frame (the first pass), the vertices a pass moved
//! (the later ones), and any points a report asks about; it reads the face data of [`Frame`]
//! (relative f32 corners, planes, and the faces in cluster order). Where buried faces are sought
//! the tree also keeps each face's box in lanes, for [`Tree::axis_ray`] and [`Tree::within_ball`]
//! (the parent module's rays and ways out), which the search itself never reads.
//! Buried faces (where [`Frame`] seeks them) are out of the tree's search and never on a list.

use nalgebra::Vector3;

use super::{Faces, Frame, GUARD_M, fmax, fmin};
use crate::kernels::LaneMask;

/// Faces per cluster of the search (see [`Frame`]'s `cluster_faces`).
pub(super) const CLUSTER: usize = 16;
/// Faces kept per vertex within its nearest distance plus the slack.
const LIST: usize = 8;
/// A face within this of a vertex's nearest f32 distance stays on its list, metres: f32
/// distances of corners within metres of the region's corner are within a micrometre of the f64
/// ones.
const SLACK_M: f32 = GUARD_M;

/// What the tree's bounds read of a face: its plane and corners (relative).
#[cfg(test)]
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SearchFace {
    pub(super) plane: [f32; 4],
    pub(super) tri: [[f32; 3]; 3],
}

/// One vertex's nearest f32 distance and the faces within it plus the slack.
#[derive(Clone, Copy, Debug)]
struct Near {
    best2: f32,
    /// The face at `best2` (`u32::MAX`: none yet).
    best_face: u32,
    /// `(best + slack)²`: what a face must be within to stay.
    reach2: f32,
    /// `(face, distance²)` (a lower bound for a sliver face); more than [`LIST`]: overflow.
    list: [(u32, f32); LIST],
    len: u8,
    /// The face offered first (the point's warm face): the search does not offer it again.
    warm: u32,
}

impl Near {
    fn new(limit2: f32) -> Self {
        Self {
            best2: limit2,
            best_face: u32::MAX,
            reach2: limit2,
            list: [(u32::MAX, f32::INFINITY); LIST],
            len: 0,
            warm: u32::MAX,
        }
    }

    /// [`Near::new`] with the point's warm face offered first (when it is a face of the
    /// region and not buried); the search does not offer it again.
    #[inline(always)]
    fn from_warm(frame: &Frame, x: &[f32; 3], warm: u32, limit2: f32) -> Self {
        let mut near = Self::new(limit2);
        if (warm as usize) < frame.faces.len() && !frame.buried[warm as usize] {
            let (d2, exact) = frame.distance2(warm, x);
            near.offer(warm, d2, exact);
            near.warm = warm;
        }
        near
    }

    /// Offer face `f` at distance² `d2` (`exact`: a true distance, else a lower bound that
    /// never tightens the reach).
    #[inline(always)]
    fn offer(&mut self, f: u32, d2: f32, exact: bool) {
        if d2 > self.reach2 || self.len as usize > LIST {
            return;
        }
        if exact && d2 < self.best2 {
            self.best2 = d2;
            self.best_face = f;
            let r = d2.sqrt() + SLACK_M;
            self.reach2 = r * r;
        }
        if self.len as usize == LIST {
            // Drop the faces the tighter reach has left behind, then overflow if still full.
            let reach2 = self.reach2;
            let mut kept = 0;
            for k in 0..LIST {
                if self.list[k].1 <= reach2 {
                    self.list[kept] = self.list[k];
                    kept += 1;
                }
            }
            self.len = kept as u8;
            if kept == LIST {
                self.len = LIST as u8 + 1;
                return;
            }
        }
        self.list[self.len as usize] = (f, d2);
        self.len += 1;
    }

    fn overflowed(&self) -> bool {
        self.len as usize > LIST
    }

    /// [`Near::from_warm`] (limit `f32::MAX`) again from what it left in `best`: a warm face
    /// at an exact distance is the best and the list's one face; otherwise made anew.
    #[inline(always)]
    fn from_best(best: Best, frame: &Frame, x: &[f32; 3], warm: u32) -> Self {
        if best.face == u32::MAX {
            return Self::from_warm(frame, x, warm, f32::MAX);
        }
        let mut near = Self::new(f32::MAX);
        (near.best2, near.best_face, near.reach2) = (best.best2, best.face, best.reach2);
        near.list[0] = (best.face, best.best2);
        near.len = 1;
        near.warm = best.face;
        near
    }
}

/// What a point's search keeps of its [`Near`]: its nearest f32 distance², the face at it, and
/// its reach. Apart from the lists, so that the per-point state every point reads and writes
/// (the sweep's, for most of them) stays small: 12 bytes, not the list's 80.
#[derive(Clone, Copy, Debug)]
struct Best {
    best2: f32,
    face: u32,
    reach2: f32,
}

impl From<&Near> for Best {
    fn from(near: &Near) -> Self {
        Self {
            best2: near.best2,
            face: near.best_face,
            reach2: near.reach2,
        }
    }
}

/// The range of a point swept ([`Search::swept`]): it has no list.
const SWEPT: (u32, u32) = (u32::MAX, u32::MAX);

/// The region's faces as a three-level tree rebuilt per frame: groups of [`GROUP`] clusters,
/// clusters of [`CLUSTER`] faces (the spatial clusters of [`Frame`]'s `cluster_faces`), and the
/// faces. Each level is stored in blocks of [`W`] boxes (for the faces, planes and edge planes),
/// lane by lane, so that one point tests a whole cluster, or a whole group of clusters, at once,
/// from a few adjacent cache lines.
#[derive(Clone, Debug, Default)]
pub(super) struct Tree {
    /// Per cluster, its faces' planes `(n, o)` and edge planes (padded with faces out of every
    /// search; zero for a sliver, which its planes bound nothing).
    faces: Vec<FaceBlock>,
    /// Per group, its clusters' boxes (padded).
    clusters: Vec<BoxBlock>,
    /// The groups' boxes (padded).
    groups: Vec<BoxBlock>,
    /// How the lane tests make their masks on this CPU.
    mask: LaneMask,
    /// Per cluster, `+∞` for its crease faces this frame, zero for the others (the sweep
    /// proves no point with one in reach; see the parent module); empty where no buried faces
    /// are sought. f32 lanes, so that the sweep's test stays in vector registers.
    crease: Vec<[f32; W]>,
    /// Per cluster, its faces' boxes (padding lanes at infinity), where the region's boxes are
    /// built (buried faces sought): the axis rays and the scans for a way out walk the tree.
    face_boxes: Vec<BoxBlock>,
}

/// Lanes of the tree's tests: one cluster's faces, one group's clusters.
const W: usize = 16;
/// Clusters per group of the tree's top level.
const GROUP: usize = 16;
/// Points per packet of the search (see [`Search::gather`]).
const PACKET: usize = 16;
/// Most clusters a packet gathers; past it its points search the tree one by one.
const PACKET_CLUSTERS: usize = 64;

/// `W` boxes, lane by lane.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct BoxBlock {
    lo: [[f32; W]; 3],
    hi: [[f32; W]; 3],
}

impl Default for BoxBlock {
    /// Boxes at infinity: never within any reach.
    fn default() -> Self {
        Self {
            lo: [[f32::INFINITY; W]; 3],
            hi: [[f32::INFINITY; W]; 3],
        }
    }
}

impl BoxBlock {
    /// Distance² from `x` to each box.
    #[inline(always)]
    fn distance2(&self, x: &[f32; 3]) -> [f32; W] {
        self.distance2_box(x, x)
    }

    /// Distance² from the box `[lo, hi]` to each box.
    #[inline(always)]
    fn distance2_box(&self, lo: &[f32; 3], hi: &[f32; 3]) -> [f32; W] {
        let mut d2 = [0.0f32; W];
        for k in 0..3 {
            let (l, h) = (&self.lo[k], &self.hi[k]);
            for j in 0..W {
                let d = fmax(fmax(l[j] - hi[k], lo[k] - h[j]), 0.0);
                d2[j] += d * d;
            }
        }
        d2
    }

    fn set(&mut self, l: usize, lo: &[f32; 3], hi: &[f32; 3]) {
        for k in 0..3 {
            self.lo[k][l] = lo[k];
            self.hi[k][l] = hi[k];
        }
    }

    /// Grow box `l` to hold `[lo, hi]`.
    fn grow(&mut self, l: usize, lo: &[f32; 3], hi: &[f32; 3]) {
        for k in 0..3 {
            // A box at infinity (not set yet) takes the first one as it is.
            let fresh = self.lo[k][l] == f32::INFINITY;
            self.lo[k][l] = if fresh {
                lo[k]
            } else {
                self.lo[k][l].min(lo[k])
            };
            self.hi[k][l] = if fresh {
                hi[k]
            } else {
                self.hi[k][l].max(hi[k])
            };
        }
    }
}

/// A cluster's faces: planes and edge planes, lane by lane.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct FaceBlock {
    /// Per face `(n, o)`: `n·x − o` its distance from its plane (see [`Frame`]'s planes);
    /// `n`, `o` zero for a sliver (it bounds nothing) and `o` at −∞ for a face out of every
    /// search (a padding lane, a buried face).
    plane: [[f32; W]; 4],
    /// Per edge `(m, c)`: `m` the unit normal of the edge in the face's plane, pointing away
    /// from the face, and `c` the larger of `m·v` over the edge's ends, so that
    /// `m·x − c` bounds the distance of `x`'s projection from the face (zero for a sliver).
    edges: [[[f32; W]; 4]; 3],
}

impl Default for FaceBlock {
    /// Every lane out of every search.
    fn default() -> Self {
        let mut plane = [[0.0; W]; 4];
        plane[3] = [f32::NEG_INFINITY; W];
        Self {
            plane,
            edges: [[[0.0; W]; 4]; 3],
        }
    }
}

impl FaceBlock {
    /// A lower bound of the distance² from `x` to each face: the plane's distance with the
    /// projection's distance beyond the farthest edge (for any point `y` of the face,
    /// `|x − y|² = h² + |P(x − y)|²` with `P` the projection onto the plane, and
    /// `|P(x − y)| ≥ m·(x − y) ≥ m·x − c` for each edge); zero for a sliver, `+∞` for a face out
    /// of the search.
    #[inline(always)]
    fn distance2(&self, x: &[f32; 3]) -> [f32; W] {
        self.bound_and_height(x).0
    }

    /// [`FaceBlock::distance2`] and the height of `x` over each face's plane, `n·x − o`
    /// (`+∞` for a face out of the search, zero for a sliver).
    #[inline(always)]
    fn bound_and_height(&self, x: &[f32; 3]) -> ([f32; W], [f32; W]) {
        let mut lb2 = [0.0f32; W];
        let mut height = [0.0f32; W];
        let [nx, ny, nz, o] = &self.plane;
        let edge = |[mx, my, mz, c]: &[[f32; W]; 4], l: usize| {
            mx[l] * x[0] + my[l] * x[1] + mz[l] * x[2] - c[l]
        };
        for l in 0..W {
            let h = nx[l] * x[0] + ny[l] * x[1] + nz[l] * x[2] - o[l];
            let [e0, e1, e2] = &self.edges;
            let s = fmax(fmax(fmax(edge(e0, l), edge(e1, l)), edge(e2, l)), 0.0);
            lb2[l] = h * h + s * s;
            height[l] = h;
        }
        (lb2, height)
    }

    /// Set the lanes' planes and edge planes from `faces` (at most [`W`]; zero for a sliver,
    /// whose planes bound nothing). The edges are computed lane by lane, so that the square
    /// roots and divisions vectorise.
    #[cfg(test)]
    fn set_faces(&mut self, faces: impl Iterator<Item = SearchFace>) {
        // Per corner, per axis, the lanes.
        let mut t = [[[0.0f32; W]; 3]; 3];
        for (l, sf) in faces.take(W).enumerate() {
            let plane = if sf.plane[3].is_finite() {
                sf.plane
            } else {
                [0.0; 4]
            };
            for j in 0..4 {
                self.plane[j][l] = plane[j];
            }
            for (k, corner) in t.iter_mut().enumerate() {
                for j in 0..3 {
                    corner[j][l] = sf.tri[k][j];
                }
            }
        }
        self.set_edges(&t);
    }

    /// The edge planes from the lanes' corners `t` (per corner, per axis) and the planes'
    /// normals (zero for a sliver and a padding lane: then zero too). Computed lane by lane,
    /// so that the square roots and divisions vectorise.
    #[inline(always)]
    fn set_edges(&mut self, t: &[[[f32; W]; 3]; 3]) {
        let [nx, ny, nz, _] = &self.plane;
        for (k, edge) in self.edges.iter_mut().enumerate() {
            let (a, b) = (&t[k], &t[(k + 1) % 3]);
            for l in 0..W {
                let e = [b[0][l] - a[0][l], b[1][l] - a[1][l], b[2][l] - a[2][l]];
                let m = [
                    e[1] * nz[l] - e[2] * ny[l],
                    e[2] * nx[l] - e[0] * nz[l],
                    e[0] * ny[l] - e[1] * nx[l],
                ];
                let len2 = m[0] * m[0] + m[1] * m[1] + m[2] * m[2];
                // Zero for a sliver's zero normal and for the padding lanes.
                let inv = if len2 > 0.0 { 1.0 / len2.sqrt() } else { 0.0 };
                let m = m.map(|v| v * inv);
                let at = |p: &[[f32; W]; 3]| m[0] * p[0][l] + m[1] * p[1][l] + m[2] * p[2][l];
                edge[0][l] = m[0];
                edge[1][l] = m[1];
                edge[2][l] = m[2];
                edge[3][l] = fmax(at(a), at(b));
            }
        }
    }
}

impl Tree {
    /// The tree of the faces `ids` (in cluster order; `face(f)` what it reads of face `f`)
    /// whose clusters have boxes `clusters`: the reference for [`build`], which makes the same
    /// tree from the corners in one pass.
    #[cfg(test)]
    pub(super) fn refit(
        &mut self,
        ids: &[u32],
        face: impl Fn(u32) -> SearchFace,
        clusters: &[([f32; 3], [f32; 3])],
    ) {
        self.size(clusters.len());
        for (block, ids) in self.faces.iter_mut().zip(ids.chunks(CLUSTER)) {
            block.set_faces(ids.iter().map(|&f| face(f)));
        }
        self.refit_boxes(clusters);
    }

    /// Blocks for `n_clusters` clusters (the clusters never change: every lane of a face is
    /// set each frame, and the padding lanes stay out of every search, planes at −∞ and boxes
    /// at infinity, from the first frame).
    fn size(&mut self, n_clusters: usize) {
        self.mask = LaneMask::detect();
        let n_groups = n_clusters.div_ceil(GROUP);
        if self.faces.len() != n_clusters {
            self.faces.clear();
            self.faces.resize(n_clusters, FaceBlock::default());
            self.clusters.clear();
            self.clusters.resize(n_groups, BoxBlock::default());
            self.face_boxes.clear();
        }
        self.groups.clear();
        self.groups
            .resize(n_groups.div_ceil(W), BoxBlock::default());
    }

    /// The two upper levels from the clusters' boxes.
    fn refit_boxes(&mut self, clusters: &[([f32; 3], [f32; 3])]) {
        for (c, (lo, hi)) in clusters.iter().enumerate() {
            let g = c / GROUP;
            self.clusters[g].set(c % GROUP, lo, hi);
            self.groups[g / W].grow(g % W, lo, hi);
        }
    }

    /// Face slot `k`'s box in the lanes the rays read.
    #[cfg(test)]
    pub(super) fn face_box(&self, k: usize) -> ([f32; 3], [f32; 3]) {
        let (block, l) = (&self.face_boxes[k / CLUSTER], k % CLUSTER);
        (
            [0, 1, 2].map(|j| block.lo[j][l]),
            [0, 1, 2].map(|j| block.hi[j][l]),
        )
    }

    /// Take face slot `k` out of every search (until the next refit).
    pub(super) fn take_out(&mut self, k: usize) {
        self.faces[k / CLUSTER].plane[3][k % CLUSTER] = f32::NEG_INFINITY;
    }

    /// No crease faces (before [`Tree::mark_crease`] marks this frame's).
    pub(super) fn clear_creases(&mut self) {
        self.crease.clear();
        self.crease.resize(self.faces.len(), [0.0; W]);
    }

    /// Face slot `k` is a crease face this frame: the sweep proves no point with it in reach.
    pub(super) fn mark_crease(&mut self, k: usize) {
        self.crease[k / CLUSTER][k % CLUSTER] = f32::INFINITY;
    }

    /// Offer `near` every face within its reach of `x`: the groups within it, their clusters
    /// within it, their faces within it, each tested against the reach as it stands (it
    /// shrinks as faces are found). Stops when the list overflows.
    #[inline(always)]
    fn search(&self, frame: &Frame, x: &[f32; 3], near: &mut Near) {
        for (top, block) in self.groups.iter().enumerate() {
            let glb2 = block.distance2(x);
            let mut groups = self.within(&glb2, near.reach2);
            while groups != 0 {
                let g = groups.trailing_zeros() as usize;
                groups &= groups - 1;
                if glb2[g] > near.reach2 {
                    continue;
                }
                let group = top * W + g;
                let cluster = |c: usize| group * GROUP + c;
                if self.search_block(frame, &self.clusters[group], cluster, x, near) {
                    return;
                }
            }
        }
    }

    /// [`Tree::search`] over the clusters `clusters` (whose boxes `boxes` holds in lanes)
    /// only: every cluster within the point's reach must be among them.
    #[inline(always)]
    fn search_among(
        &self,
        frame: &Frame,
        clusters: &[u32],
        boxes: &[BoxBlock],
        x: &[f32; 3],
        near: &mut Near,
    ) {
        for (b, block) in boxes.iter().enumerate() {
            let cluster = |l: usize| clusters[b * W + l] as usize;
            if self.search_block(frame, block, cluster, x, near) {
                return;
            }
        }
    }

    /// Search the clusters of `block` (cluster boxes; lane `l` is cluster `cluster(l)`) within
    /// the reach, in lane order; `true` when the list overflowed.
    #[inline(always)]
    fn search_block(
        &self,
        frame: &Frame,
        block: &BoxBlock,
        cluster: impl Fn(usize) -> usize,
        x: &[f32; 3],
        near: &mut Near,
    ) -> bool {
        let lb2 = block.distance2(x);
        let mut hit = self.within(&lb2, near.reach2);
        while hit != 0 {
            let l = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            // The reach may have shrunk since the mask was taken.
            if lb2[l] <= near.reach2 && self.search_cluster(frame, cluster(l), x, near) {
                return true;
            }
        }
        false
    }

    /// Push onto `out` every cluster whose box lies within `reach2` (squared) of the box
    /// `[lo, hi]`, in the tree's order; `false` (and `out` partial) past [`PACKET_CLUSTERS`].
    #[inline(always)]
    fn clusters_near(&self, lo: &[f32; 3], hi: &[f32; 3], reach2: f32, out: &mut Vec<u32>) -> bool {
        for (top, block) in self.groups.iter().enumerate() {
            let mut groups = self.within(&block.distance2_box(lo, hi), reach2);
            while groups != 0 {
                let g = groups.trailing_zeros() as usize;
                groups &= groups - 1;
                let group = top * W + g;
                let mut clusters = self.within(&self.clusters[group].distance2_box(lo, hi), reach2);
                while clusters != 0 {
                    let c = clusters.trailing_zeros() as usize;
                    clusters &= clusters - 1;
                    if out.len() == PACKET_CLUSTERS {
                        return false;
                    }
                    out.push((group * GROUP + c) as u32);
                }
            }
        }
        true
    }

    /// Cluster `c`'s box.
    #[inline(always)]
    fn cluster_box(&self, c: usize) -> ([f32; 3], [f32; 3]) {
        let (block, l) = (&self.clusters[c / GROUP], c % GROUP);
        (
            [0, 1, 2].map(|k| block.lo[k][l]),
            [0, 1, 2].map(|k| block.hi[k][l]),
        )
    }

    /// [`Tree::search`] within cluster `c`; `true` when the list overflowed.
    #[inline(always)]
    fn search_cluster(&self, frame: &Frame, c: usize, x: &[f32; 3], near: &mut Near) -> bool {
        let lb2 = self.faces[c].distance2(x);
        let e = c * CLUSTER;
        let mut hit = self.within(&lb2, near.reach2);
        while hit != 0 {
            let l = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            // The reach may have shrunk since the mask was taken.
            if lb2[l] > near.reach2 {
                continue;
            }
            let f = frame.cluster_faces[e + l];
            if f == near.warm {
                continue;
            }
            let (d2, exact) = frame.distance2(f, x);
            near.offer(f, d2, exact);
            if near.overflowed() {
                return true;
            }
        }
        false
    }
}

impl Tree {
    /// Visit the cluster slot (`cluster * CLUSTER + lane`) of every face whose box holds the
    /// axis-`k` line through `o` and reaches `o`'s side towards `+∞` (`positive`) or `−∞`:
    /// every face the ray from `o` along that axis can cross (buried faces included).
    #[inline(always)]
    pub(super) fn axis_ray(
        &self,
        o: &[f32; 3],
        k: usize,
        positive: bool,
        visit: impl FnMut(usize),
    ) {
        match (k, positive) {
            (0, true) => self.axis_ray_along::<0, true>(o, visit),
            (0, false) => self.axis_ray_along::<0, false>(o, visit),
            (1, true) => self.axis_ray_along::<1, true>(o, visit),
            (1, false) => self.axis_ray_along::<1, false>(o, visit),
            (_, true) => self.axis_ray_along::<2, true>(o, visit),
            (_, false) => self.axis_ray_along::<2, false>(o, visit),
        }
    }

    /// Visit `(slot, bound²)` of every face whose bound (its box's distance and its plane's
    /// height over `x`, the larger) lies within `r2` of `x` (a face out of the search never).
    #[inline(always)]
    pub(super) fn within_ball(&self, x: &[f32; 3], r2: f32, mut visit: impl FnMut(usize, f32)) {
        for (top, block) in self.groups.iter().enumerate() {
            let mut groups = self.within(&block.distance2(x), r2);
            while groups != 0 {
                let g = top * W + groups.trailing_zeros() as usize;
                groups &= groups - 1;
                let mut clusters = self.within(&self.clusters[g].distance2(x), r2);
                while clusters != 0 {
                    let c = g * GROUP + clusters.trailing_zeros() as usize;
                    clusters &= clusters - 1;
                    let boxes = self.face_boxes[c].distance2(x);
                    let [nx, ny, nz, o] = &self.faces[c].plane;
                    let mut lb2 = [0.0f32; W];
                    for l in 0..W {
                        let h = fmax(nx[l] * x[0] + ny[l] * x[1] + nz[l] * x[2] - o[l], 0.0);
                        lb2[l] = fmax(boxes[l], h * h);
                    }
                    let mut faces = self.within(&lb2, r2);
                    while faces != 0 {
                        let l = faces.trailing_zeros() as usize;
                        faces &= faces - 1;
                        visit(c * CLUSTER + l, lb2[l]);
                    }
                }
            }
        }
    }

    /// [`Tree::axis_ray`] along axis `K`, towards `+∞` where `POSITIVE`: each axis and side its
    /// own code (with the axis and side read at run time inside the lane test, the post-process
    /// of bodies beyond the training shapes took 1.14 of the grid's time instead of 1.04, the
    /// grid's build left in for that comparison; see the parent module's `Frame::axis_winding`).
    #[inline(always)]
    fn axis_ray_along<const K: usize, const POSITIVE: bool>(
        &self,
        o: &[f32; 3],
        mut visit: impl FnMut(usize),
    ) {
        let (a, b) = match K {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let (oa, ob, ok) = (o[a], o[b], o[K]);
        // Each condition `x ≤ y` as `x − y ≤ 0` (the sign of an IEEE difference is exact): a
        // box is met where the largest of the five differences is at most 0.
        let meets = |block: &BoxBlock| {
            let mut worst = [0.0f32; W];
            let (la, ha, lb, hb) = (&block.lo[a], &block.hi[a], &block.lo[b], &block.hi[b]);
            let along = if POSITIVE { &block.hi[K] } else { &block.lo[K] };
            for l in 0..W {
                let ahead = if POSITIVE {
                    ok - along[l]
                } else {
                    along[l] - ok
                };
                let across = fmax(fmax(la[l] - oa, oa - ha[l]), fmax(lb[l] - ob, ob - hb[l]));
                worst[l] = fmax(across, ahead);
            }
            self.mask.at_most(&worst, 0.0)
        };
        for (top, block) in self.groups.iter().enumerate() {
            let mut groups = meets(block);
            while groups != 0 {
                let g = top * W + groups.trailing_zeros() as usize;
                groups &= groups - 1;
                let mut clusters = meets(&self.clusters[g]);
                while clusters != 0 {
                    let c = g * GROUP + clusters.trailing_zeros() as usize;
                    clusters &= clusters - 1;
                    let mut faces = meets(&self.face_boxes[c]);
                    while faces != 0 {
                        visit(c * CLUSTER + faces.trailing_zeros() as usize);
                        faces &= faces - 1;
                    }
                }
            }
        }
    }

    /// The sweep: whether every face whose bound lies within `reach2` of `x` has `x` in front
    /// of its plane by more than the guard and a bound of at least `front2` (see
    /// [`Search::run`]); over the whole tree. `one_mask`: the form of the cluster test
    /// ([`Tree::any_unclear`]), [`LaneMask::prefers_one_mask`] read once per run by the caller.
    #[inline(always)]
    fn sweep(&self, one_mask: bool, x: &[f32; 3], reach2: f32, front2: f32) -> bool {
        for (top, block) in self.groups.iter().enumerate() {
            let mut groups = self.within(&block.distance2(x), reach2);
            while groups != 0 {
                let g = groups.trailing_zeros() as usize;
                groups &= groups - 1;
                let group = top * W + g;
                let cluster = |c: usize| group * GROUP + c;
                let block = &self.clusters[group];
                // The form chosen per block, not per cluster (see `Tree::any_unclear`). Written
                // here and in `Tree::sweep_among`: one `#[inline(always)]` method for the choice
                // took the trained 8,710-triangle walk 749–760 → 775–781 µs (2026-12-06).
                let clear = if one_mask {
                    self.sweep_block::<true>(block, cluster, x, reach2, front2)
                } else {
                    self.sweep_block::<false>(block, cluster, x, reach2, front2)
                };
                if !clear {
                    return false;
                }
            }
        }
        true
    }

    /// [`Tree::sweep`] over the clusters `clusters` (whose boxes `boxes` holds in lanes) only:
    /// every cluster within `reach2` of `x` must be among them.
    #[inline(always)]
    fn sweep_among(
        &self,
        one_mask: bool,
        clusters: &[u32],
        boxes: &[BoxBlock],
        x: &[f32; 3],
        reach2: f32,
        front2: f32,
    ) -> bool {
        for (b, block) in boxes.iter().enumerate() {
            let cluster = |l: usize| clusters[b * W + l] as usize;
            let clear = if one_mask {
                self.sweep_block::<true>(block, cluster, x, reach2, front2)
            } else {
                self.sweep_block::<false>(block, cluster, x, reach2, front2)
            };
            if !clear {
                return false;
            }
        }
        true
    }

    /// [`Tree::sweep`] over the clusters of `block` (lane `l` is cluster `cluster(l)`).
    #[inline(always)]
    fn sweep_block<const ONE_MASK: bool>(
        &self,
        block: &BoxBlock,
        cluster: impl Fn(usize) -> usize,
        x: &[f32; 3],
        reach2: f32,
        front2: f32,
    ) -> bool {
        let mut hit = self.within(&block.distance2(x), reach2);
        while hit != 0 {
            let l = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            let c = cluster(l);
            let (lb2, height) = self.faces[c].bound_and_height(x);
            // No crease face is clear (none when no buried faces are sought).
            let crease = self.crease.get(c).unwrap_or(&[0.0; W]);
            if self.any_unclear::<ONE_MASK>(&lb2, &height, crease, reach2, front2) {
                return false;
            }
        }
        true
    }

    /// Whether a face of a cluster is within reach and not clear: either not in front of its
    /// plane by more than the guard or its bound within `front2`, or a crease face. A sliver
    /// (zero plane: height 0) is never clear; a face out of the search (bound at infinity)
    /// never within reach.
    ///
    /// Two forms, the same answers, chosen per build by [`LaneMask::prefers_one_mask`] (read once
    /// per run; the sweeps pick `ONE_MASK` per block of clusters, so each form is its own code: a
    /// branch between them inside this test took the AVX-512 build's trained 8,710-triangle walk
    /// from 0.77–0.78 to 1.47 ms). As booleans (`false`), which compile to vector compares and one
    /// test with AVX-512 and SSE. As one difference per lane (`true`), at most 0 where the face is
    /// within reach and not clear (the sign of an IEEE difference is exact, so each test is its
    /// difference's against 0), read by one mask; a bound exactly at `front2` counts as not clear
    /// there (the point is then searched instead of swept, with the same answer). In WebAssembly
    /// the try-on page's post-process, back to back in the browser test: 3.36 and 3.46 → 2.88 and
    /// 3.01 ms at 4,210 triangles, 5.38 and 5.29 → 4.97 and 4.84 at 8,710 (two runs of each page in
    /// turn, Intel Xeon VM, the same garments); with AVX2 the trained 8,710-triangle walk 692–744 →
    /// 683–694 µs (three rounds of the two builds in turn, same VM). With AVX-512 the mask measured
    /// slower (the same walk 710–713 → 761–772 µs), and with SSE too.
    #[inline(always)]
    fn any_unclear<const ONE_MASK: bool>(
        &self,
        lb2: &[f32; W],
        height: &[f32; W],
        crease: &[f32; W],
        reach2: f32,
        front2: f32,
    ) -> bool {
        if ONE_MASK {
            let mut worst = [0.0f32; W];
            for k in 0..W {
                let clear = fmin(height[k] - crease[k] - GUARD_M, lb2[k] - front2);
                worst[k] = fmax(lb2[k] - reach2, clear);
            }
            return self.mask.at_most(&worst, 0.0) != 0;
        }
        let mut bad = false;
        for k in 0..W {
            let clear = height[k] - crease[k] > GUARD_M && lb2[k] >= front2;
            bad |= lb2[k] <= reach2 && !clear;
        }
        bad
    }
}

impl Tree {
    /// A face to start the search of a point `x` that has no usable warm face from (the first
    /// frame of an avatar, a warm face buried this frame): in the group whose box is nearest,
    /// the cluster whose box is nearest, its usable face (`usable`) of least bound; `None` when
    /// that cluster has none. Any face serves (its distance bounds the nearest face's, as a
    /// warm face's does), so the answers do not depend on it; a near one gives the point a
    /// short reach and its packet (not the sweep: see [`Search::run`]'s loop). Without it the
    /// search of such a point started unbounded, in the tree's order: an avatar's first frame,
    /// where no cloth vertex or triangle has a warm face, took the shipped model's post-process
    /// 34–42 ms, now 6.9–7.0, and the trained 8,710-triangle one's 65–76 ms, now 15.3–15.6
    /// (`cargo bench -p sartor-runtime --bench postprocess -- first-frame`, two rounds of the
    /// two builds in turn, AMD EPYC VM); the later frames' work is unchanged (the same garments
    /// over 200 frames of the walk, 1 % fewer instructions a frame by callgrind).
    fn seed(&self, frame: &Frame, x: &[f32; 3], usable: impl Fn(u32) -> bool) -> Option<u32> {
        let nearest = |lb2: [f32; W]| {
            let mut best = (f32::INFINITY, usize::MAX);
            for (l, &d2) in lb2.iter().enumerate() {
                if d2 < best.0 {
                    best = (d2, l);
                }
            }
            best
        };
        let mut group = (f32::INFINITY, usize::MAX);
        for (top, block) in self.groups.iter().enumerate() {
            let (d2, g) = nearest(block.distance2(x));
            if d2 < group.0 {
                group = (d2, top * W + g);
            }
        }
        if group.1 == usize::MAX {
            return None;
        }
        let (d2, c) = nearest(self.clusters[group.1].distance2(x));
        if d2 == f32::INFINITY {
            return None;
        }
        let c = group.1 * GROUP + c;
        let lb2 = self.faces[c].distance2(x);
        let mut seed: Option<(f32, u32)> = None;
        for (l, &d2) in lb2.iter().enumerate() {
            // (The last cluster's padding lanes, at infinity, have no face.)
            if d2.is_finite()
                && seed.is_none_or(|(b, _)| d2 < b)
                && let Some(&f) = frame.cluster_faces.get(c * CLUSTER + l)
                && usable(f)
            {
                seed = Some((d2, f));
            }
        }
        seed.map(|(_, f)| f)
    }

    /// The lanes of `lb2` within `reach2`, as bits (never NaN: a bound at infinity is beyond).
    #[inline(always)]
    fn within(&self, lb2: &[f32; W], reach2: f32) -> u32 {
        self.mask.at_most(lb2, reach2)
    }
}

/// Distance² from `x` to the box `[lo, hi]`.
#[inline(always)]
fn box2(lo: &[f32; 3], hi: &[f32; 3], x: &[f32; 3]) -> f32 {
    let d = [0, 1, 2].map(|k| fmax(fmax(lo[k] - x[k], x[k] - hi[k]), 0.0));
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// What [`Search::run`] may prove a point by without its list (squared distances, the guard
/// added as there): beyond the margin by the sweep (`sweep`), and farther than `far` from every
/// face on whichever side (`far`).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Sweeps {
    pub(crate) sweep: Option<f32>,
    pub(crate) far: Option<f32>,
}

/// The search's state: per-point answers, reused between calls.
#[derive(Clone, Debug, Default)]
pub(crate) struct Search {
    best: Vec<Best>,
    /// Per point, its range of `lists` ([`SWEPT`]: swept, no list): the faces within its reach,
    /// in the order the points were searched.
    range: Vec<(u32, u32)>,
    lists: Vec<u32>,
    /// The points in the order of their warm face's cluster, those without one last
    /// ([`Search::sort_by_warm_cluster`]); `n_warm`: how many have one.
    order: Vec<u32>,
    n_warm: usize,
    counts: Vec<u32>,
    /// A packet's clusters within its reach ([`Search::gather`]), and their boxes in lanes.
    packet_clusters: Vec<u32>,
    packet_boxes: Vec<BoxBlock>,
}

impl Search {
    /// For each of `points` (relative to `frame`'s corner), the faces within its nearest
    /// distance plus the slack, read back with [`Search::faces_into`] and [`Search::best`]; `warm`:
    /// per point, a face to start from (`u32::MAX`: none).
    ///
    /// With `by.sweep` (`(margin + guard)²`), a point whose warm face lies within `reach` (and not
    /// within `sweep`, where that face alone fails the test below) is first *swept*: when every
    /// face whose bound ([`FaceBlock::distance2`]) lies within the reach has the point in front
    /// of its plane by more than the guard and a bound of at least `sweep`, the point is proven
    /// beyond the margin ([`Search::swept`]) without a list. The proof is the parent module's,
    /// over more faces than it needs: every face within the nearest distance plus the slack
    /// lies within the reach (the warm face's distance plus the slack bounds the nearest one),
    /// so each face holding the closest point is in front, and the nearest face's bound is
    /// beyond the margin; and no crease face may be in reach (where buried faces are sought),
    /// as the list's certificate asks.
    ///
    /// With `by.far` too (`(far + guard)²`, at least `sweep`), a point whose warm face lies beyond
    /// it is first tested for no face whose bound lies within `far`: then it is farther than
    /// `far` from the region, on whichever side, and counts as swept (for a caller that needs
    /// no answer there, as the triangles' pass beyond its depth).
    pub(crate) fn run(&mut self, frame: &Frame, points: &[[f32; 3]], warm: &[u32], by: Sweeps) {
        search_points(self, frame, points, warm, by);
    }

    /// Whether point `i` of the last [`Search::run`] was proven beyond the margin by the sweep
    /// (its list is then not made; [`Search::best`] is its warm face).
    pub(crate) fn swept(&self, i: usize) -> bool {
        self.range[i] == SWEPT
    }

    #[inline(always)]
    fn run_impl(&mut self, frame: &Frame, points: &[[f32; 3]], warm: &[u32], by: Sweeps) {
        let Sweeps { sweep, far } = by;
        let n = points.len();
        self.best.clear();
        // Finite: a face at infinity (a buried face, a padding slot) never passes. The warm
        // faces' distances in lanes of points (`distance2_lanes`: the same bits as
        // `distance2`, without its branches); a point without a usable warm face, or whose
        // warm face is a sliver, the scalar way.
        for (points, warm) in points.chunks(WARM_LANES).zip(warm.chunks(WARM_LANES)) {
            let usable = |w: u32| {
                (w as usize) < frame.faces.len()
                    && !frame.buried[w as usize]
                    && frame.data.plane[w as usize][3].is_finite()
            };
            let mut p = [[0.0f32; WARM_LANES]; 3];
            let mut t = [[[0.0f32; WARM_LANES]; 3]; 3];
            // The warm face, or where it is not usable a seed ([`Tree::seed`]; `u32::MAX`:
            // none).
            let mut start = [u32::MAX; WARM_LANES];
            for (l, (x, &w)) in points.iter().zip(warm).enumerate() {
                for k in 0..3 {
                    p[k][l] = x[k];
                }
                start[l] = if usable(w) {
                    w
                } else {
                    frame.tree.seed(frame, x, usable).unwrap_or(u32::MAX)
                };
                let w = start[l];
                // (A seed is usable.)
                if w != u32::MAX {
                    for (corner, &v) in t.iter_mut().zip(&frame.faces[w as usize]) {
                        let v = &frame.rel[v as usize];
                        for k in 0..3 {
                            corner[k][l] = v[k];
                        }
                    }
                }
            }
            let d2 = distance2_lanes(&p, &t);
            self.best
                .extend(points.iter().zip(warm).enumerate().map(|(l, (x, &w))| {
                    if start[l] != u32::MAX {
                        // `Near::from_warm`'s answer, from the lanes' distance.
                        let mut near = Near::new(f32::MAX);
                        near.offer(start[l], d2[l], true);
                        Best::from(&near)
                    } else {
                        Best::from(&Near::from_warm(frame, x, w, f32::MAX))
                    }
                }));
        }
        self.range.clear();
        self.range.resize(n, (0, 0));
        self.lists.clear();
        // A point whose warm face lies within `front2` fails the sweep on that face (its bound
        // is at most its distance), so it is not swept: it goes straight to its search. Nor is
        // a point started from a seed ([`Tree::seed`]): its search gives it its nearest face as
        // the warm face of the next frame, where the sweep's reach is the shortest (a seed
        // kept as the warm face of a swept point cost the shipped model's walk 1.6 % more
        // instructions a frame, callgrind).
        let sweepable = |best: Best, front2: f32, warm: u32| {
            best.face != u32::MAX && best.face == warm && best.best2 >= front2
        };
        // A point whose warm face lies beyond `far` is far from the region where no face's
        // bound lies within `far` (the sweep with nothing clear: `front2` at infinity).
        let far_from = |best: Best, warm: u32| match far {
            Some(far2) if sweepable(best, far2, warm) => Some(far2),
            _ => None,
        };
        self.sort_by_warm_cluster(frame);
        let order = std::mem::take(&mut self.order);
        let (mut start, n_warm) = (0, self.n_warm);
        // The sweep's cluster test in its faster form for this build (`Tree::any_unclear`).
        let one_mask = frame.tree.mask.prefers_one_mask();
        while start < n {
            // A packet: points of the same warm cluster, then of the next ones, up to PACKET.
            let end = if start < n_warm {
                (start + PACKET).min(n_warm)
            } else {
                n
            };
            let packet = &order[start..end];
            if start < n_warm && self.gather(frame, points, packet) {
                for &i in packet {
                    let (i, best) = (i as usize, self.best[i as usize]);
                    let x = &points[i];
                    let (clusters, boxes) = (&self.packet_clusters, &self.packet_boxes);
                    let tree = &frame.tree;
                    if let Some(far2) = far_from(best, warm[i])
                        && tree.sweep_among(one_mask, clusters, boxes, x, far2, f32::INFINITY)
                    {
                        self.range[i] = SWEPT;
                        continue;
                    }
                    if let Some(front2) = sweep
                        && sweepable(best, front2, warm[i])
                        && tree.sweep_among(one_mask, clusters, boxes, x, best.reach2, front2)
                    {
                        self.range[i] = SWEPT;
                        continue;
                    }
                    let mut near = Near::from_best(best, frame, x, warm[i]);
                    frame
                        .tree
                        .search_among(frame, clusters, boxes, x, &mut near);
                    self.finish(frame, x, warm[i], i, near);
                }
            } else {
                for &i in packet {
                    let (i, best) = (i as usize, self.best[i as usize]);
                    let x = &points[i];
                    let tree = &frame.tree;
                    if let Some(far2) = far_from(best, warm[i])
                        && tree.sweep(one_mask, x, far2, f32::INFINITY)
                    {
                        self.range[i] = SWEPT;
                        continue;
                    }
                    if let Some(front2) = sweep
                        && sweepable(best, front2, warm[i])
                        && tree.sweep(one_mask, x, best.reach2, front2)
                    {
                        self.range[i] = SWEPT;
                        continue;
                    }
                    let mut near = Near::from_best(best, frame, x, warm[i]);
                    frame.tree.search(frame, x, &mut near);
                    self.finish(frame, x, warm[i], i, near);
                }
            }
            start = end;
        }
        self.order = order;
    }

    /// The points in the order of their warm face's cluster (counting sort, stable), those
    /// without a warm face last: `order`, with `n_warm` the points that have one.
    #[inline(always)]
    fn sort_by_warm_cluster(&mut self, frame: &Frame) {
        let n_clusters = frame.cluster_box.len();
        self.counts.clear();
        self.counts.resize(n_clusters + 2, 0);
        let key = |best: &Best| {
            if best.face == u32::MAX {
                n_clusters
            } else {
                frame.face_slot[best.face as usize] as usize / CLUSTER
            }
        };
        for best in &self.best {
            self.counts[key(best) + 1] += 1;
        }
        for c in 1..self.counts.len() {
            self.counts[c] += self.counts[c - 1];
        }
        self.n_warm = self.counts[n_clusters] as usize;
        self.order.clear();
        self.order.resize(self.best.len(), 0);
        for (i, best) in self.best.iter().enumerate() {
            let slot = &mut self.counts[key(best)];
            self.order[*slot as usize] = i as u32;
            *slot += 1;
        }
    }

    /// The clusters within the largest reach of `packet`'s points of their box, into
    /// `packet_clusters` and `packet_boxes`; `false` when more than [`PACKET_CLUSTERS`] are.
    #[inline(always)]
    fn gather(&mut self, frame: &Frame, points: &[[f32; 3]], packet: &[u32]) -> bool {
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        let mut reach2 = 0.0f32;
        for &i in packet {
            let x = &points[i as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
            reach2 = fmax(reach2, self.best[i as usize].reach2);
        }
        self.packet_clusters.clear();
        if !frame
            .tree
            .clusters_near(&lo, &hi, reach2, &mut self.packet_clusters)
        {
            return false;
        }
        let n_blocks = self.packet_clusters.len().div_ceil(W);
        self.packet_boxes.clear();
        self.packet_boxes.resize(n_blocks, BoxBlock::default());
        for (k, &c) in self.packet_clusters.iter().enumerate() {
            let (l, h) = frame.tree.cluster_box(c as usize);
            self.packet_boxes[k / W].set(k % W, &l, &h);
        }
        true
    }

    /// Point `i`'s answer from its tree search `near`: searched against every face where the
    /// tree search overflowed its list or found only slivers; its best, and its faces within
    /// reach onto `lists`.
    fn finish(&mut self, frame: &Frame, x: &[f32; 3], warm: u32, i: usize, mut near: Near) {
        let start = self.lists.len() as u32;
        // More near-ties than a list holds, or only sliver faces near: every face.
        if near.overflowed() || near.best_face == u32::MAX {
            near = search_all(frame, x, warm);
        }
        if near.overflowed() {
            // More near-ties than a list holds (a point at a region vertex of high valence):
            // every face within reach, unbounded.
            for f in 0..frame.faces.len() as u32 {
                if !frame.buried[f as usize] && frame.distance2(f, x).0 <= near.reach2 {
                    self.lists.push(f);
                }
            }
        } else {
            let list = &near.list[..near.len as usize];
            self.lists.extend(
                list.iter()
                    .filter(|&&(_, d2)| d2 <= near.reach2)
                    .map(|&(f, _)| f),
            );
        }
        self.range[i] = (start, self.lists.len() as u32);
        self.best[i] = Best::from(&near);
    }

    /// Point `i`'s faces within its nearest distance plus the slack, into `out` (cleared
    /// first; never empty for a region with a face, unless the point was swept).
    pub(crate) fn faces_into(&self, i: usize, out: &mut Vec<u32>) {
        out.clear();
        let (a, b) = self.range[i];
        if self.range[i] != SWEPT {
            out.extend_from_slice(&self.lists[a as usize..b as usize]);
        }
    }

    /// Point `i`'s nearest f32 distance² (`∞` if only sliver faces are near: their distance is
    /// not trusted) and the face at it (for a swept point, its warm face's).
    pub(crate) fn best(&self, i: usize) -> (f32, u32) {
        (self.best[i].best2, self.best[i].face)
    }
}

crate::kernels::widest_where_present! {
    /// [`Search::run`], built for the widest vectors present (the lane tests vectorise; AVX-512
    /// answers them in mask registers).
    fn search_points(
        search: &mut Search,
        frame: &Frame,
        points: &[[f32; 3]],
        warm: &[u32],
        by: Sweeps,
    ) {
        search.run_impl(frame, points, warm, by);
    }
}

crate::kernels::widest_where_present! {
    /// The frame's face data and the search's tree in one pass over the clusters: for the
    /// faces `ids` (in cluster order) of `faces`, from their corners `rel` (relative, f32) and
    /// `posed` (f64), each face's plane into `data` (see [`super::Faces`]), each cluster's box
    /// into `cluster_box`, and the tree's blocks; with `boxes` also each face's centroid into
    /// `data` and its box into the tree's lanes (the rays' input). The arithmetic runs lane
    /// by lane over a cluster's faces, so that it vectorises; per face it is that of
    /// `face_data` and `FaceBlock::set_faces` (the test references), so the same bits.
    pub(super) fn build(
        tree: &mut Tree,
        ids: &[u32],
        faces: &[[u32; 3]],
        rel: &[[f32; 3]],
        posed: &[Vector3<f64>],
        data: &mut Faces,
        cluster_box: &mut [([f32; 3], [f32; 3])],
        boxes: bool
    ) {
        tree.size(cluster_box.len());
        if boxes && tree.face_boxes.len() != cluster_box.len() {
            tree.face_boxes.resize(cluster_box.len(), BoxBlock::default());
        }
        let blocks = tree.faces.iter_mut().zip(ids.chunks(CLUSTER)).zip(cluster_box.iter_mut());
        for (ci, ((block, slots), bounds)) in blocks.enumerate() {
            // Per corner, per axis, the lanes; the two edges from the first corner in f64,
            // then f32 (the exact query's own positions).
            let mut t = [[[0.0f32; W]; 3]; 3];
            let mut e = [[[0.0f32; W]; 3]; 2];
            for (l, &f) in slots.iter().enumerate() {
                let [u, v, w] = faces[f as usize].map(|i| i as usize);
                for (k, corner) in [u, v, w].into_iter().enumerate() {
                    for j in 0..3 {
                        t[k][j][l] = rel[corner][j];
                    }
                }
                let (e1, e2) = (posed[v] - posed[u], posed[w] - posed[u]);
                for j in 0..3 {
                    e[0][j][l] = e1[j] as f32;
                    e[1][j][l] = e2[j] as f32;
                }
            }
            let mut lo = [[0.0f32; W]; 3];
            let mut hi = [[0.0f32; W]; 3];
            let mut centroid = [[0.0f32; W]; 3];
            let mut plane = [[0.0f32; W]; 4];
            let mut sliver = [false; W];
            let [a, b, c] = &t;
            let [e1, e2] = &e;
            for l in 0..W {
                for k in 0..3 {
                    lo[k][l] = fmin(fmin(a[k][l], b[k][l]), c[k][l]);
                    hi[k][l] = fmax(fmax(a[k][l], b[k][l]), c[k][l]);
                    centroid[k][l] = (a[k][l] + b[k][l] + c[k][l]) / 3.0;
                }
                let n = [
                    e1[1][l] * e2[2][l] - e1[2][l] * e2[1][l],
                    e1[2][l] * e2[0][l] - e1[0][l] * e2[2][l],
                    e1[0][l] * e2[1][l] - e1[1][l] * e2[0][l],
                ];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                let scale = ((e1[0][l] * e1[0][l] + e1[1][l] * e1[1][l] + e1[2][l] * e1[2][l])
                    * (e2[0][l] * e2[0][l] + e2[1][l] * e2[1][l] + e2[2][l] * e2[2][l]))
                    .sqrt();
                let ok = len > super::MIN_SINE * scale && len > 0.0;
                let n = [n[0] / len, n[1] / len, n[2] / len];
                let dot = |p: &[[f32; W]; 3]| n[0] * p[0][l] + n[1] * p[1][l] + n[2] * p[2][l];
                let o = fmax(fmax(dot(a), dot(b)), dot(c));
                sliver[l] = !ok;
                // A sliver's planes bound nothing (zero); the frame's plane marks it with
                // `o = +∞` below.
                for j in 0..3 {
                    plane[j][l] = if ok { n[j] } else { 0.0 };
                }
                plane[3][l] = if ok { o } else { 0.0 };
            }
            for (l, &f) in slots.iter().enumerate() {
                let f = f as usize;
                if boxes {
                    data.centroid[f] = [0, 1, 2].map(|k| centroid[k][l]);
                }
                data.plane[f] = if sliver[l] {
                    [0.0, 0.0, 0.0, f32::INFINITY]
                } else {
                    [0, 1, 2, 3].map(|j| plane[j][l])
                };
            }
            // The padding lanes: out of every search.
            for l in slots.len()..W {
                for j in 0..3 {
                    plane[j][l] = 0.0;
                }
                plane[3][l] = f32::NEG_INFINITY;
            }
            block.plane = plane;
            block.set_edges(&t);
            if boxes {
                // The padding lanes stay at infinity (from `BoxBlock::default`).
                let fb = &mut tree.face_boxes[ci];
                for k in 0..3 {
                    fb.lo[k][..slots.len()].copy_from_slice(&lo[k][..slots.len()]);
                    fb.hi[k][..slots.len()].copy_from_slice(&hi[k][..slots.len()]);
                }
            }
            let (mut l, mut h) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for s in 0..slots.len() {
                l = [0, 1, 2].map(|k| l[k].min(lo[k][s]));
                h = [0, 1, 2].map(|k| h[k].max(hi[k][s]));
            }
            *bounds = (l, h);
        }
        tree.refit_boxes(cluster_box);
    }
}

/// [`Near`] for `x` against every face of `frame` (started from face `warm`, if any).
fn search_all(frame: &Frame, x: &[f32; 3], warm: u32) -> Near {
    let mut near = Near::from_warm(frame, x, warm, f32::INFINITY);
    // A bounded list cannot overflow here by more than exact ties: when it does, every face
    // within reach is kept in a second, unbounded pass below.
    for f in (0..frame.faces.len()).filter(|&f| !frame.buried[f]) {
        if f as u32 == near.warm || {
            let (lo, hi) = frame.face_box(f);
            box2(&lo, &hi, x) > near.reach2
        } {
            continue;
        }
        let (d2, exact) = frame.distance2(f as u32, x);
        near.offer(f as u32, d2, exact);
    }
    near
}

impl Frame {
    /// Face `f`'s box (relative), from its corners: the bits of the box `build` writes into
    /// the tree's lanes where the rays need it (the search reads it only for slivers and the
    /// rare search against every face).
    #[inline(always)]
    pub(super) fn face_box(&self, f: usize) -> ([f32; 3], [f32; 3]) {
        let [a, b, c] = self.faces[f].map(|v| self.rel[v as usize]);
        (
            [0, 1, 2].map(|k| fmin(fmin(a[k], b[k]), c[k])),
            [0, 1, 2].map(|k| fmax(fmax(a[k], b[k]), c[k])),
        )
    }

    /// Distance² from `x` (relative) to face `f` in f32, and whether it is exact (for a sliver,
    /// the distance² to its box: a lower bound).
    #[inline(always)]
    pub(super) fn distance2(&self, f: u32, x: &[f32; 3]) -> (f32, bool) {
        let fi = f as usize;
        if self.data.plane[fi][3].is_infinite() {
            let (lo, hi) = self.face_box(fi);
            return (box2(&lo, &hi, x), false);
        }
        let tri = self.faces[fi].map(|v| self.rel[v as usize]);
        (distance2(x, &tri), true)
    }
}

/// Points per call of [`distance2_lanes`].
const WARM_LANES: usize = 16;

/// [`distance2`] of each lane's point `p` to its triangle `t` (per corner, per axis, the lanes):
/// every region's answer computed with `distance2`'s arithmetic, and the first region that
/// holds, in its order, taken — the same bits, without a branch per region, so that it
/// vectorises (a region not taken may divide by zero; its value is dropped).
#[inline(always)]
fn distance2_lanes(
    p: &[[f32; WARM_LANES]; 3],
    t: &[[[f32; WARM_LANES]; 3]; 3],
) -> [f32; WARM_LANES] {
    let mut out = [0.0f32; WARM_LANES];
    let [ta, tb, tc] = t;
    for (l, out) in out.iter_mut().enumerate() {
        let at = |v: &[[f32; WARM_LANES]; 3]| [v[0][l], v[1][l], v[2][l]];
        let (p, a, b, c) = (at(p), at(ta), at(tb), at(tc));
        let sub = |u: &[f32; 3], v: &[f32; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
        let dot = |u: &[f32; 3], v: &[f32; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let norm2 = |u: &[f32; 3]| dot(u, u);
        let ab = sub(&b, &a);
        let ac = sub(&c, &a);
        let ap = sub(&p, &a);
        let d1 = dot(&ab, &ap);
        let d2 = dot(&ac, &ap);
        let bp = sub(&p, &b);
        let d3 = dot(&ab, &bp);
        let d4 = dot(&ac, &bp);
        let vc = d1 * d4 - d3 * d2;
        let cp = sub(&p, &c);
        let d5 = dot(&ab, &cp);
        let d6 = dot(&ac, &cp);
        let vb = d5 * d2 - d1 * d6;
        let va = d3 * d6 - d5 * d4;
        let on_ab = edge2(&ap, &ab, d1 / (d1 - d3));
        let on_ac = edge2(&ap, &ac, d2 / (d2 - d6));
        let on_bc = edge2(&bp, &sub(&c, &b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
        let inside = face2(&ap, &ab, &ac, [va, vb, vc]);
        *out = if d1 <= 0.0 && d2 <= 0.0 {
            norm2(&ap)
        } else if d3 >= 0.0 && d4 <= d3 {
            norm2(&bp)
        } else if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            on_ab
        } else if d6 >= 0.0 && d5 <= d6 {
            norm2(&cp)
        } else if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            on_ac
        } else if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            on_bc
        } else {
            inside
        };
    }
    out
}

/// Distance² from `p` to the triangle `[a, b, c]`, f32 (Ericson's closest point by regions,
/// as sartor-core's f64 `closest_on_triangle`). It only chooses which faces go on a list: every
/// answer the post-process uses still comes from `MeshProximity` in f64 on that list, so the
/// workspace keeps one closest-point query. A copy in f32 because the search's lanes are f32 and
/// sartor-core's is f64 and private; making that one generic is the cleaner fix, not done.
#[inline(always)]
fn distance2(p: &[f32; 3], [a, b, c]: &[[f32; 3]; 3]) -> f32 {
    let sub = |u: &[f32; 3], v: &[f32; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let dot = |u: &[f32; 3], v: &[f32; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let norm2 = |u: &[f32; 3]| dot(u, u);
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(&ab, &ap);
    let d2 = dot(&ac, &ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return norm2(&ap);
    }
    let bp = sub(p, b);
    let d3 = dot(&ab, &bp);
    let d4 = dot(&ac, &bp);
    if d3 >= 0.0 && d4 <= d3 {
        return norm2(&bp);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return edge2(&ap, &ab, d1 / (d1 - d3));
    }
    let cp = sub(p, c);
    let d5 = dot(&ab, &cp);
    let d6 = dot(&ac, &cp);
    if d6 >= 0.0 && d5 <= d6 {
        return norm2(&cp);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return edge2(&ap, &ac, d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return edge2(&bp, &sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    face2(&ap, &ab, &ac, [va, vb, vc])
}

/// `|p − e·t|²`: [`distance2`]'s answer on an edge (`p` from the edge's start, `e` along it).
#[inline(always)]
fn edge2(p: &[f32; 3], e: &[f32; 3], t: f32) -> f32 {
    let r = [p[0] - e[0] * t, p[1] - e[1] * t, p[2] - e[2] * t];
    r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
}

/// [`distance2`]'s answer inside the face, from its barycentric weights `[va, vb, vc]`.
#[inline(always)]
fn face2(ap: &[f32; 3], ab: &[f32; 3], ac: &[f32; 3], [va, vb, vc]: [f32; 3]) -> f32 {
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    let r = [
        ap[0] - ab[0] * v - ac[0] * w,
        ap[1] - ab[1] * v - ac[1] * w,
        ap[2] - ab[2] * v - ac[2] * w,
    ];
    r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// Uniform numbers in [0, 0.1) from `seed`.
    fn uniform(seed: u64) -> impl FnMut() -> f32 {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        move || rng.random_range(0.0..0.1)
    }

    #[test]
    fn the_face_blocks_bound_never_exceeds_the_distance_and_is_tight_beside_an_edge() {
        let mut next = uniform(987654321);
        let (mut tight, mut cases) = (0, 0);
        for _ in 0..2_000 {
            let mut pt = || [0.5 + next(), 0.5 + next(), 0.5 + next()];
            let tri = [pt(), pt(), pt()];
            // The plane as the frame makes it.
            let mut data = super::super::Faces {
                plane: vec![[0.0; 4]],
                centroid: vec![[0.0; 3]],
            };
            let posed = tri.map(|p| Vector3::new(p[0], p[1], p[2]).cast::<f64>());
            let mut boxes = [([0.0; 3], [0.0; 3])];
            super::super::face_data(&[[0, 1, 2]], &tri, &posed, &mut data, &mut boxes);
            if data.plane[0][3].is_infinite() {
                continue; // A sliver: its planes bound nothing.
            }
            let face = SearchFace {
                plane: data.plane[0],
                tri,
            };
            let mut block = FaceBlock::default();
            block.set_faces(std::iter::once(face));
            for _ in 0..20 {
                let p = [
                    0.45 + next() * 2.0,
                    0.45 + next() * 2.0,
                    0.45 + next() * 2.0,
                ];
                let lb = block.distance2(&p)[0].sqrt();
                let d = distance2(&p, &tri).sqrt();
                assert!(lb <= d + 1e-6, "bound {lb} beyond the distance {d}");
                cases += 1;
                tight += usize::from(lb >= d - 1e-6);
            }
        }
        // Exact wherever the nearest point lies on the face or inside an edge (the box
        // and plane alone are exact on the face only).
        assert!(tight * 2 > cases, "tight in {tight} of {cases} cases");
    }

    #[test]
    fn both_forms_of_the_sweeps_cluster_test_agree() {
        // The one-mask form runs in WebAssembly and where the AVX2 build does; this CPU may
        // run the booleans, so both are compared here, with this CPU's lane masks. They differ
        // only where a bound lies exactly at `front2`, which the one mask counts as not clear
        // (the point is then searched, with the same answer).
        let tree = Tree {
            mask: LaneMask::detect(),
            ..Tree::default()
        };
        let mut next = uniform(1357);
        let (mut unclear, mut at_front, mut cases) = (0, 0, 0);
        for round in 0..20_000 {
            let (reach2, front2) = (next() * 0.01, next() * 0.01);
            let (mut lb2, mut height, mut crease) = ([0.0f32; W], [0.0f32; W], [0.0f32; W]);
            for k in 0..W {
                lb2[k] = match (round + k) % 23 {
                    0 => f32::INFINITY, // a face out of the search
                    1 => front2,
                    2 => reach2,
                    _ => next(),
                };
                height[k] = match (round * 7 + k) % 19 {
                    0 => 0.0, // a sliver
                    1 => GUARD_M,
                    _ => next() * 0.02 - 0.0002,
                };
                if (round * 3 + k) % 41 == 0 {
                    crease[k] = f32::INFINITY;
                }
            }
            let one = tree.any_unclear::<true>(&lb2, &height, &crease, reach2, front2);
            let booleans = tree.any_unclear::<false>(&lb2, &height, &crease, reach2, front2);
            cases += 1;
            unclear += usize::from(booleans);
            if one != booleans {
                assert!(
                    one,
                    "round {round}: the one mask proved what the booleans did not"
                );
                assert!(
                    (0..W).any(|k| lb2[k] == front2 && lb2[k] <= reach2),
                    "round {round}: the forms differ with no bound at front2"
                );
                at_front += 1;
            }
        }
        // Both answers occur, and the exact ties too.
        assert!(
            unclear > cases / 10 && unclear < cases * 9 / 10,
            "{unclear} of {cases}"
        );
        assert!(at_front > 0, "no tie at front2 in {cases} cases");
    }

    #[test]
    fn the_lanes_distance_gives_the_bits_of_the_scalar_one() {
        // Random triangles (some with a repeated or collinear corner) and points among them and
        // up to twenty triangle sizes away, sixteen at a time; both near and far points often.
        let mut next = uniform(2468);
        let mut regions = [0usize; 2];
        for round in 0..500 {
            let mut p = [[0.0f32; WARM_LANES]; 3];
            let mut t = [[[0.0f32; WARM_LANES]; 3]; 3];
            let mut tris = Vec::new();
            for l in 0..WARM_LANES {
                let mut tri = [0; 3].map(|_| [next(), next(), next()]);
                match (round + l) % 16 {
                    0 => tri[2] = tri[0],
                    1 => tri[2] = [0, 1, 2].map(|k| 0.5 * (tri[0][k] + tri[1][k])),
                    _ => {}
                }
                let x = [0; 3].map(|_| next() * 3.0 - 0.1);
                for k in 0..3 {
                    p[k][l] = x[k];
                    for (c, corner) in tri.iter().enumerate() {
                        t[c][k][l] = corner[k];
                    }
                }
                tris.push((x, tri));
            }
            let got = distance2_lanes(&p, &t);
            for (l, (x, tri)) in tris.iter().enumerate() {
                let want = distance2(x, tri);
                assert_eq!(got[l].to_bits(), want.to_bits(), "{x:?} {tri:?}");
                regions[usize::from(want < 0.01)] += 1;
            }
        }
        assert!(regions[0] > 1_000 && regions[1] > 1_000, "{regions:?}");
    }

    #[test]
    fn the_rays_and_balls_walk_the_tree_to_every_face_a_scan_of_all_would_find() {
        // 300 faces (19 clusters, the last partial; two groups' worth of top-level lanes) spread
        // over 10 cm, a few slivers, some taken out of the search: the tree's axis rays visit
        // exactly the faces whose box holds the ray's line on its side of the start (buried or
        // not), and its balls exactly the faces in the search whose bound lies within reach.
        let mut next = uniform(77);
        let n = 300;
        let posed: Vec<Vector3<f64>> = (0..3 * n)
            .map(|i| {
                let c = Vector3::new(next(), next(), next());
                // Small faces around a random centre, every third corner near the last.
                if i % 3 == 0 {
                    c.cast::<f64>()
                } else {
                    (c * 0.2).cast::<f64>()
                }
            })
            .collect();
        let mut posed = posed;
        for f in 0..n {
            let base = posed[3 * f];
            posed[3 * f + 1] += base;
            posed[3 * f + 2] += base;
        }
        posed[5] = posed[4];
        let faces: Vec<[u32; 3]> = (0..n as u32)
            .map(|f| [3 * f, 3 * f + 1, 3 * f + 2])
            .collect();
        let rel: Vec<[f32; 3]> = posed
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let ids: Vec<u32> = (0..n as u32).collect();
        let n_clusters = n.div_ceil(CLUSTER);
        let mut data = super::super::Faces {
            plane: vec![[0.0; 4]; n],
            centroid: vec![[0.0; 3]; n],
        };
        let mut cluster_box = vec![([0.0f32; 3], [0.0f32; 3]); n_clusters];
        let mut tree = Tree::default();
        build(
            &mut tree,
            &ids,
            &faces,
            &rel,
            &posed,
            &mut data,
            &mut cluster_box,
            true,
        );
        let out: Vec<usize> = (0..n).step_by(7).collect();
        for &k in &out {
            tree.take_out(k);
        }
        let mut boxes = vec![([0.0f32; 3], [0.0f32; 3]); n];
        let mut reference = super::super::Faces {
            plane: vec![[0.0; 4]; n],
            centroid: vec![[0.0; 3]; n],
        };
        super::super::face_data(&faces, &rel, &posed, &mut reference, &mut boxes);
        let (mut met, mut reached) = (0, 0);
        for _ in 0..500 {
            let o = [
                next() * 1.2 - 0.01,
                next() * 1.2 - 0.01,
                next() * 1.2 - 0.01,
            ];
            for (k, positive) in [
                (0, true),
                (0, false),
                (1, true),
                (1, false),
                (2, true),
                (2, false),
            ] {
                let mut got: Vec<usize> = Vec::new();
                tree.axis_ray(&o, k, positive, |slot| got.push(slot));
                got.sort_unstable();
                let want: Vec<usize> = (0..n)
                    .filter(|&f| {
                        let (lo, hi) = boxes[f];
                        let ahead = if positive {
                            hi[k] >= o[k]
                        } else {
                            lo[k] <= o[k]
                        };
                        ahead
                            && (0..3)
                                .filter(|&j| j != k)
                                .all(|j| lo[j] <= o[j] && o[j] <= hi[j])
                    })
                    .collect();
                assert_eq!(got, want, "ray from {o:?} along {k} {positive}");
                met += want.len();
            }
            let r2 = (next() * 0.3).powi(2);
            let mut got: Vec<(usize, u32)> = Vec::new();
            tree.within_ball(&o, r2, |slot, b| got.push((slot, b.to_bits())));
            got.sort_unstable();
            let want: Vec<(usize, u32)> = (0..n)
                .filter(|f| !out.contains(f))
                .filter_map(|f| {
                    let (lo, hi) = boxes[f];
                    let [nx, ny, nz, off] = reference.plane[f];
                    // A sliver's plane bounds nothing (its `o` is infinite in the face data).
                    let h = if off.is_finite() {
                        fmax(nx * o[0] + ny * o[1] + nz * o[2] - off, 0.0)
                    } else {
                        0.0
                    };
                    let b = fmax(box2(&lo, &hi, &o), h * h);
                    (b <= r2).then_some((f, b.to_bits()))
                })
                .collect();
            assert_eq!(got, want, "ball at {o:?}, r² {r2}");
            reached += want.len();
        }
        assert!(
            met > 1_000 && reached > 1_000,
            "{met} met, {reached} reached"
        );
    }

    #[test]
    fn the_one_pass_build_gives_the_bits_of_the_face_by_face_reference() {
        // 70 triangles (four clusters and a partial one) over 150 corners, with slivers:
        // collinear corners, a repeated corner and a face of zero size.
        let mut next = uniform(4242);
        let mut posed: Vec<Vector3<f64>> = (0..150)
            .map(|_| Vector3::new(0.3 + next(), 0.2 + next(), 0.4 + next()).cast::<f64>())
            .collect();
        posed[2] = posed[0] + (posed[1] - posed[0]) * 0.5;
        posed[5] = posed[4];
        let mut faces: Vec<[u32; 3]> = (0..70)
            .map(|f| [(2 * f) % 150, (2 * f + 1) % 150, (2 * f + 37) % 150].map(|v| v as u32))
            .collect();
        faces[0] = [0, 1, 2];
        faces[1] = [3, 4, 5];
        faces[2] = [6, 6, 6];
        let origin = Vector3::new(0.25, 0.15, 0.35);
        let rel: Vec<[f32; 3]> = posed
            .iter()
            .map(|p| {
                let d = p - origin;
                [d.x as f32, d.y as f32, d.z as f32]
            })
            .collect();
        let ids: Vec<u32> = (0..70u32).rev().collect();
        let n_clusters = 70usize.div_ceil(CLUSTER);
        let empty = |n: usize| super::super::Faces {
            plane: vec![[0.0; 4]; n],
            centroid: vec![[0.0; 3]; n],
        };
        // The reference: face by face, then the tree from the frame's planes.
        let mut want = empty(70);
        let mut want_face_boxes = vec![([0.0f32; 3], [0.0f32; 3]); 70];
        super::super::face_data(&faces, &rel, &posed, &mut want, &mut want_face_boxes);
        let mut want_boxes = vec![([0.0f32; 3], [0.0f32; 3]); n_clusters];
        for (c, b) in want_boxes.iter_mut().enumerate() {
            let (mut l, mut h) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for &f in ids.iter().skip(c * CLUSTER).take(CLUSTER) {
                let (fl, fh) = want_face_boxes[f as usize];
                l = [0, 1, 2].map(|k| l[k].min(fl[k]));
                h = [0, 1, 2].map(|k| h[k].max(fh[k]));
            }
            *b = (l, h);
        }
        let mut want_tree = Tree::default();
        let face = |f: u32| SearchFace {
            plane: want.plane[f as usize],
            tri: faces[f as usize].map(|v| rel[v as usize]),
        };
        want_tree.refit(&ids, face, &want_boxes);
        // The one pass, twice (the second over blocks already sized).
        let mut got = empty(70);
        let mut got_boxes = vec![([0.0f32; 3], [0.0f32; 3]); n_clusters];
        let mut tree = Tree::default();
        for _ in 0..2 {
            build(
                &mut tree,
                &ids,
                &faces,
                &rel,
                &posed,
                &mut got,
                &mut got_boxes,
                true,
            );
        }
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let flat3 = |v: &[[f32; 3]]| bits(v.as_flattened());
        assert_eq!(flat3(&got.centroid), flat3(&want.centroid));
        // Each face's box in the tree's lanes (the padding lanes at infinity).
        for (slot, &f) in ids.iter().enumerate() {
            let (l, h) = tree.face_box(slot);
            let (wl, wh) = want_face_boxes[f as usize];
            assert_eq!(
                (flat3(&[l]), flat3(&[h])),
                (flat3(&[wl]), flat3(&[wh])),
                "face {f}"
            );
        }
        let last = &tree.face_boxes[n_clusters - 1];
        for l in 70 % CLUSTER..W {
            assert!(
                (0..3).all(|k| last.lo[k][l] == f32::INFINITY && last.hi[k][l] == f32::INFINITY)
            );
        }
        assert_eq!(
            bits(got.plane.as_flattened()),
            bits(want.plane.as_flattened())
        );
        assert!(
            want.plane[..3].iter().all(|p| p[3] == f32::INFINITY),
            "three slivers"
        );
        let boxes = |b: &[([f32; 3], [f32; 3])]| {
            b.iter()
                .flat_map(|(l, h)| l.iter().chain(h))
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(boxes(&got_boxes), boxes(&want_boxes));
        let block_bits = |t: &Tree| {
            let mut v = Vec::new();
            for b in &t.faces {
                v.extend(bits(b.plane.as_flattened()));
                for e in &b.edges {
                    v.extend(bits(e.as_flattened()));
                }
            }
            for b in t.clusters.iter().chain(&t.groups) {
                v.extend(bits(b.lo.as_flattened()));
                v.extend(bits(b.hi.as_flattened()));
            }
            v
        };
        assert_eq!(block_bits(&tree), block_bits(&want_tree));
    }

    #[test]
    fn the_f32_distance_matches_the_f64_closest_point() {
        let mut next = uniform(12345);
        for _ in 0..20_000 {
            let mut pt = || [0.5 + next(), 0.5 + next(), 0.5 + next()];
            let (a, b, c, p) = (pt(), pt(), pt(), pt());
            let d2 = distance2(&p, &[a, b, c]);
            let v = |x: [f32; 3]| Vector3::new(x[0], x[1], x[2]).cast::<f64>();
            let mesh =
                sartor_core::MeshProximity::new(&[v(a), v(b), v(c)], &[[0, 1, 2]]).expect("mesh");
            let exact = mesh.nearest_among(&v(p), &[0]).expect("one face");
            let err = (f64::from(d2).sqrt() - exact.distance_sq.sqrt()).abs();
            assert!(err < 1e-6, "{err} at {p:?} for {a:?} {b:?} {c:?}");
        }
    }
}
