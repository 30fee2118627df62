//! The certified query of the post-process ([`super::CollisionQuery::Certified`]): for every
//! cloth vertex, either a proof that the exact per-vertex query would not push it, or the exact
//! query's own answer — found among a few candidate faces instead of a tree.
//!
//! # The proof
//!
//! The exact query pushes a vertex `p` when its signed distance is below the margin. Let `C` be
//! the faces within `p`'s nearest distance `d*` plus a slack (the search's list, `search.rs`):
//! it holds the exact query's face `f*` and, more, *every* face that holds its closest point
//! `c*` (each is at `d*` too). The sign is that of `(p − c*)·ñ`, where the pseudo-normal `ñ` is
//! a positive blend of the normals of the faces holding `c*`: the face itself, the two faces of
//! an edge, or the faces around a vertex. Each of those faces `k` is in `C`, and `c*` lies on
//! it, so `(p − c*)·n_k = min_j (p − v_j)·n_k` over its corners. If `p` is beyond the margin
//! (`d*` ≥ margin) and in front of the plane of every face of `C` (`min_j (p − v_j)·n_k > 0`),
//! the sign is positive and the distance at least the margin: no push. The test reads the body
//! as posed this frame only — no motion bound, no earlier frame — so it holds on the open,
//! self-intersecting region as the exact query sees it (its sign, not "inside the body").
//! Otherwise the vertex gets `MeshProximity::nearest_among(C)`: `f*` is in `C` and every other
//! face is farther, so it is the exact query's answer (same faces, same arithmetic, same tie
//! rule).
//!
//! An earlier version asked `p` to be in front of every face around every vertex of `C` (the
//! *fans*), which holds the same proof for a list that holds `f*` only. The list holds every
//! face at `d*`, so the faces' own planes suffice: the shipped model's post-process 0.59–0.60
//! → 0.53 ms (`cargo bench --bench postprocess`, two rounds of alternating builds), the same
//! pushes.
//!
//! # Buried faces
//!
//! The region the proof and the answers read is the *exposed* surface: per frame, a face whose
//! centroid lies inside another part (the winding number along an axis ray on its normal's side,
//! walked through the search's tree) is taken out of the search, so no candidate list holds it,
//! while the pseudo-normals stay those of the whole region. A closest point on an edge or a corner
//! of a buried face also lies on an exposed face that shares a vertex with it (a crease face), and
//! a vertex with a crease face among its candidates is never certified: the proof above needs
//! every face holding the closest point on the list. Its answer is checked by the same ray test
//! (`Frame::settle`): inside, it gets the nearest way out whose landing point the ray test reads
//! as outside.
//!
//! The region is open where the garment's body region is cut (neck, waist, arms); for the ray
//! tests each cut is closed by a fan of triangles from its boundary loop to the loop's centre,
//! so that a ray leaving through a cut still counts its crossing.
//!
//! # The work
//!
//! Per frame, the posed region's faces get f32 planes and corners relative to a corner of its box
//! (boxes and centroids too where buried faces are sought: the rays read them), and
//! a three-level tree of boxes over its spatial clusters of 16 faces (`search.rs`),
//! both in one pass over the clusters, lane by lane (`search::build`; face by face and then the
//! tree, the same bits, took 74 µs of the shipped model's 556 µs post-process, and the one pass
//! took that post-process to 513–516 µs from 546–562, `cargo bench --bench postprocess`,
//! alternating builds).
//! Each cloth vertex searches it, started from the face it was nearest last frame, and keeps its
//! f32 nearest distance and every face within it plus 10 µm: that list is `C` above (f32 distances
//! are within a micrometre of the f64 ones). The certificate is tested over the list's faces, and a
//! vertex that fails it gets `MeshProximity::nearest_among` of the list. Before that, a vertex with
//! a warm face is *swept* (`search.rs`): the same certificate over every face whose bound lies
//! within the warm face's distance, tested in the search's lanes without a list, which proves most
//! vertices at a fraction of the cost (never one with a crease face in reach). The later passes and
//! the reports search the points they ask about the same way. Only where buried faces are sought
//! does the tree also keep each face's box, 16 to a block: the rays and the way out of a part walk
//! it (until 2026-12-08 they walked a uniform grid of the faces, rebuilt per frame for them alone:
//! see [`Frame::axis_winding`]).
//!
//! The f32 arithmetic is covered by a 10 µm guard on every comparison (coordinates relative to
//! the region's box, within metres; f32 rounding of the planes and distances is below a
//! micrometre for faces that are not slivers, and slivers never pass a certificate nor end a
//! search).
//!
//! The first pass (every cloth vertex, or every triangle's centroid) is split over rayon's
//! threads under `Parallelism::Rayon`, in parts of the points with their own search and
//! scratch; each point's answer is its own, so the split changes no bit. So are the later
//! passes from [`MIN_SPLIT_LATER`] points (the points a pass moved; one part a thread, the
//! answers visited in order after): the shipped model's walk moves some 310 vertices a frame,
//! and on the 2-core Intel Xeon VM its post-process on two threads took 437–465 → 413–435 µs
//! and the int8 frame 439–483 → 417–457 (`cargo bench --bench postprocess`, alternating
//! builds, six rounds). The frame's update runs on one thread. Costs on the shipped model:
//! `cargo bench -p sartor-runtime --bench postprocess`.

mod search;

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{
    ClosestFeature, ClosestPoint, MeshProximity, MeshTopology, NearestFace, Parallelism,
};
use search::{Search, Sweeps};

/// Slack on every f32 comparison of the certificates, metres.
const GUARD_M: f32 = 1e-5;
/// The region's relative coordinates start this far below its box, metres: the f32 rounding of
/// every plane, box and ray is that of this corner.
const ORIGIN_PAD_M: f32 = 0.02;
/// A face whose normal is less reliable than this (|e1 × e2| below this fraction of
/// |e1| |e2|: an angle under 3°, a sliver) never passes the plane test.
const MIN_SINE: f32 = 0.05;
/// How far the winding tests' rays run, metres: unbounded (every face ahead of the ray's start
/// is tested), which takes every ray out of the closed region. A cap of
/// 0.5 m cut short the rays that run the length of a limb or the torso inside it: over the
/// 272 frames of extreme bodies in the runtime's tests it missed 90 buried faces (12,963
/// found), each of which reads inside along all six axis directions; without the cap, rays
/// along the normals and along the axes agree on every face there, at no measurable cost
/// (`cargo bench -p sartor-runtime --bench postprocess`, `certified-buried` 3.81 → 3.84 ms).
const BURIED_RAY_M: f32 = f32::INFINITY;
/// How far from a cloth vertex inside another part [`Frame::settle`] looks for the surface
/// that takes it out, metres.
const SETTLE_M: f32 = 0.08;
/// [`Frame::settle`] checks that the point this far beyond an exit lies outside, metres.
const EXIT_CHECK_M: f64 = 1e-3;
/// Each cap's box is grown by this, metres: far beyond the f32 rounding of a ray's crossing
/// (coordinates within metres), so the box test never drops a crossing the triangle test would
/// count.
const CAP_BOX_PAD_M: f32 = 1e-6;
/// The buried-face test's ray starts this far in front of the face's centroid, metres (off the
/// face itself).
const BURIED_START_M: f32 = 1e-4;

/// The posed region's faces relative to the region's corner ([`Frame`]'s `origin`), in f32.
#[derive(Clone, Debug, Default)]
struct Faces {
    /// `(n, o)`: `n·x − o = min_j (x − v_j)·n` over the corners, `o = +∞` for a sliver.
    plane: Vec<[f32; 4]>,
    /// Written only where buried faces are sought (the rays start there).
    centroid: Vec<[f32; 3]>,
}

/// Per-task scratch: dedup stamps and the candidate list.
#[derive(Clone, Debug)]
pub(crate) struct Scratch {
    vertex_stamp: Vec<u32>,
    stamp: u32,
    candidates: Vec<u32>,
    /// [`Frame::settle`]'s exits to try: each face's nearest point; the faces met beyond the
    /// ball tried so far; per face, the stamp of the last vertex that met it (apart from
    /// `face_stamp`, which the rays that check each exit mark).
    exits: Vec<NearestFace>,
    pending: Vec<NearestFace>,
    exit_stamp: Vec<u32>,
}

impl Scratch {
    /// Scratch sized for `frame`'s region.
    pub(crate) fn for_frame(frame: &Frame) -> Self {
        Self::new(frame.faces.len(), frame.rel.len())
    }

    fn new(n_faces: usize, n_vertices: usize) -> Self {
        Self {
            vertex_stamp: vec![0; n_vertices],
            stamp: 0,
            candidates: Vec::with_capacity(n_faces),
            exits: Vec::with_capacity(n_faces),
            pending: Vec::with_capacity(n_faces),
            exit_stamp: vec![0; n_faces],
        }
    }

    /// A new stamp (clearing the arrays when the counter wraps).
    fn next(&mut self) -> u32 {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.vertex_stamp.fill(0);
            self.exit_stamp.fill(0);
            self.stamp = 1;
        }
        self.stamp
    }
}

/// What the certified pass found for one cloth vertex.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Outcome {
    /// Proven not to need a push.
    Certified,
    /// The exact closest point.
    Exact(ClosestPoint),
}

/// What one run found for its points: per point its kind, and the exact answers apart, in
/// point order. A run writes a record for every cloth vertex, most of them certified: one byte
/// each, not an `Option<Outcome>`'s 96 (some 400 KB a frame at 8,710 triangles, written and
/// read again).
#[derive(Clone, Debug, Default)]
struct Outcomes {
    /// Per point: [`NO_FACE`], [`CERTIFIED`] or [`EXACT`].
    kind: Vec<u8>,
    /// `(point, answer)` of each point of kind [`EXACT`], in point order.
    exact: Vec<(u32, ClosestPoint)>,
}

/// [`Outcomes::kind`]: no face near enough to answer (`None`), [`Outcome::Certified`],
/// [`Outcome::Exact`].
const NO_FACE: u8 = 0;
const CERTIFIED: u8 = 1;
const EXACT: u8 = 2;

impl Outcomes {
    fn resize(&mut self, n: usize) {
        self.kind.resize(n, NO_FACE);
    }

    /// `visit(point, outcome)` for every point, in order.
    fn visit(&self, mut visit: impl FnMut(usize, Option<Outcome>)) {
        let mut exact = self.exact.iter();
        for (i, &kind) in self.kind.iter().enumerate() {
            let outcome = match kind {
                CERTIFIED => Some(Outcome::Certified),
                EXACT => {
                    let &(k, c) = exact.next().expect("an exact answer per exact point");
                    debug_assert_eq!(k as usize, i);
                    Some(Outcome::Exact(c))
                }
                _ => None,
            };
            visit(i, outcome);
        }
    }
}

/// Counts of the certified query in one frame (for reports and tests).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CertifyStats {
    /// Cloth vertices proven not to need a push.
    pub certified: usize,
    /// Of those, the ones proven by the search's sweep from their warm face, without a list
    /// of candidate faces (see `certify/search.rs`).
    pub swept: usize,
    /// Cloth vertices that got the exact closest point (from their candidate faces).
    pub exact: usize,
    /// Candidate faces over all cloth vertices of the first pass.
    pub candidates: usize,
    /// Region faces buried inside another body part, left out of the query.
    pub buried_faces: usize,
}

impl CertifyStats {
    /// The counts of two parts of one frame's points (the buried faces are the frame's).
    fn merged(self, other: Self) -> Self {
        Self {
            certified: self.certified + other.certified,
            swept: self.swept + other.swept,
            exact: self.exact + other.exact,
            candidates: self.candidates + other.candidates,
            buried_faces: self.buried_faces.max(other.buried_faces),
        }
    }
}

/// The region as posed this frame: faces, fans, the search's tree.
#[derive(Clone, Debug)]
pub(crate) struct Frame {
    faces: Vec<[u32; 3]>,
    /// The faces in spatial clusters of [`search::CLUSTER`] (the last one shorter), and each
    /// cluster's box this frame (relative).
    cluster_faces: Vec<u32>,
    cluster_box: Vec<([f32; 3], [f32; 3])>,
    /// Per face, its slot in `cluster_faces` (its cluster is `slot / CLUSTER`).
    face_slot: Vec<u32>,
    /// The same faces as the search's tree (boxes and planes in lanes).
    tree: search::Tree,
    /// Per region vertex, the faces around it (CSR).
    fan_offsets: Vec<u32>,
    fan: Vec<u32>,
    /// The corner the relative coordinates start from (f64), and the region's vertices
    /// relative to it.
    origin: Vector3<f64>,
    rel: Vec<[f32; 3]>,
    data: Faces,
    /// Whether [`Frame::mark_buried`] runs.
    find_buried: bool,
    /// Per face, buried inside another body part this frame (see [`Frame::mark_buried`]).
    buried: Vec<bool>,
    n_buried: usize,
    /// Per face, exposed but sharing a vertex with a buried face (see [`Frame::settle`]).
    crease: Vec<bool>,
    /// Scratch of [`Frame::mark_buried`]: per vertex, whether a buried face uses it.
    vertex_touches_buried: Vec<bool>,
    /// The region's cuts closed for the ray tests: per boundary edge `(a, b, loop)`, the cap
    /// triangle `(b, a, centre of loop)` (oriented as the face it borders).
    caps: Vec<[u32; 3]>,
    /// Per boundary loop, its vertices (CSR).
    loop_offsets: Vec<u32>,
    loop_vertices: Vec<u32>,
    /// Per boundary loop, the mean of its vertices and the box of its caps (relative, this
    /// frame; grown by [`CAP_BOX_PAD_M`] as the caps' own).
    loop_centre: Vec<[f32; 3]>,
    loop_box: Vec<([f32; 3], [f32; 3])>,
    /// Per boundary loop, its range of `caps` (`caps` is sorted by loop).
    loop_caps: Vec<u32>,
    /// Per cap, its box this frame (relative), grown by [`CAP_BOX_PAD_M`]: a ray that misses
    /// it meets no cap there.
    cap_box: Vec<([f32; 3], [f32; 3])>,
}

/// The certified query's state (see the module docs).
#[derive(Clone, Debug)]
pub(crate) struct Certifier {
    frame: Frame,
    scratch: Scratch,
    search: Search,
    /// The search's per cloth vertex warm faces and outcomes, and its points (relative).
    vertex_warm: Vec<u32>,
    vertex_outcomes: Outcomes,
    points: Vec<[f32; 3]>,
    /// The same for the cloth triangles' centroids ([`Certifier::run_points`]), sized on first
    /// use.
    face_warm: Vec<u32>,
    face_outcomes: Outcomes,
    /// Per part of a pass split over threads (the first pass, or a later one), its own
    /// search, points and scratch (made on the first split pass).
    parts: Vec<Part>,
    /// A split later pass's answers, visited in order after it ([`Certifier::later_points`]).
    later: Vec<Option<Later>>,
}

/// The state of one part of a pass split over threads.
#[derive(Clone, Debug)]
struct Part {
    search: Search,
    points: Vec<[f32; 3]>,
    scratch: Scratch,
    /// Its points' exact answers (appended to the run's in part order).
    exact: Vec<(u32, ClosestPoint)>,
}

/// A first pass is split over threads only from this many points: at about 250 ns of search
/// a point (`search.rs`), some 60 µs of work, well above a hand-off between threads (not tuned
/// further; the garments split here have 2,168 vertices and more).
const MIN_SPLIT_POINTS: usize = 256;

/// The threads a pass may split over under `par`.
fn threads(par: Parallelism) -> usize {
    match par {
        Parallelism::Sequential => 1,
        Parallelism::Rayon => rayon::current_num_threads(),
    }
}

/// The length of each of `n_parts` parts of `n` points, with one of `parts` for each (made
/// for `frame`'s region).
fn split(parts: &mut Vec<Part>, frame: &Frame, n: usize, n_parts: usize) -> usize {
    let chunk = n.div_ceil(n_parts);
    if parts.len() < n_parts {
        parts.resize_with(n_parts, || Part {
            search: Search::default(),
            points: Vec::with_capacity(chunk),
            scratch: Scratch::for_frame(frame),
            exact: Vec::new(),
        });
    }
    chunk
}

/// A later pass is split over threads only from this many points (one part a thread: its
/// points are the few the pass before moved, each near the body).
const MIN_SPLIT_LATER: usize = 64;

/// Parts per thread of a split first pass (cloth vertices near the body cost more than far
/// ones, so more parts than threads even the load).
const PARTS_PER_THREAD: usize = 4;

impl Certifier {
    /// For a region of `faces` over vertices at `region_rest`, and a garment whose rest shape is
    /// `cloth_rest`. `buried`: find the faces buried inside another part each frame (see the
    /// module docs).
    pub(crate) fn new(
        region_rest: &[Vector3<f64>],
        faces: &[[u32; 3]],
        cloth_rest: &[Vector3<f32>],
        buried: bool,
    ) -> Self {
        let n_vertices = region_rest.len();
        // The faces in spatial clusters of the search, by their centroids at rest.
        let centroids: Vec<Vector3<f32>> = faces
            .iter()
            .map(|t| {
                (t.iter()
                    .map(|&v| region_rest[v as usize])
                    .sum::<Vector3<f64>>()
                    / 3.0)
                    .cast()
            })
            .collect();
        let mut cluster_faces = groups(&centroids, search::CLUSTER);
        cluster_faces.retain(|&f| f != u32::MAX);
        let n_clusters = faces.len().div_ceil(search::CLUSTER);
        let mut face_slot = vec![0u32; faces.len()];
        for (k, &f) in cluster_faces.iter().enumerate() {
            face_slot[f as usize] = k as u32;
        }
        let mut fan_offsets = vec![0u32; n_vertices + 1];
        for t in faces {
            for &v in t {
                fan_offsets[v as usize + 1] += 1;
            }
        }
        for v in 0..n_vertices {
            fan_offsets[v + 1] += fan_offsets[v];
        }
        let mut fill = fan_offsets.clone();
        let mut fan = vec![0u32; faces.len() * 3];
        for (f, t) in faces.iter().enumerate() {
            for &v in t {
                fan[fill[v as usize] as usize] = f as u32;
                fill[v as usize] += 1;
            }
        }
        let n_f = faces.len();
        let (caps, loop_offsets, loop_vertices) = caps(n_vertices, faces);
        let n_loops = loop_offsets.len() - 1;
        let caps_len = caps.len();
        let mut loop_caps = vec![0u32; n_loops + 1];
        for c in &caps {
            loop_caps[c[2] as usize + 1] += 1;
        }
        for l in 0..n_loops {
            loop_caps[l + 1] += loop_caps[l];
        }
        Self {
            frame: Frame {
                faces: faces.to_vec(),
                cluster_faces,
                face_slot,
                cluster_box: vec![([0.0; 3], [0.0; 3]); n_clusters],
                tree: search::Tree::default(),
                fan_offsets,
                fan,
                origin: Vector3::zeros(),
                rel: vec![[0.0; 3]; n_vertices],
                data: Faces {
                    plane: vec![[0.0; 4]; n_f],
                    centroid: vec![[0.0; 3]; n_f],
                },
                find_buried: buried,
                buried: vec![false; n_f],
                n_buried: 0,
                crease: vec![false; n_f],
                vertex_touches_buried: vec![false; n_vertices],
                caps,
                loop_offsets,
                loop_vertices,
                loop_centre: vec![[0.0; 3]; n_loops],
                loop_box: vec![([0.0; 3], [0.0; 3]); n_loops],
                loop_caps,
                cap_box: vec![([0.0; 3], [0.0; 3]); caps_len],
            },
            scratch: Scratch::new(n_f, n_vertices),
            search: Search::default(),
            vertex_warm: vec![u32::MAX; cloth_rest.len()],
            vertex_outcomes: Outcomes {
                kind: vec![NO_FACE; cloth_rest.len()],
                exact: Vec::new(),
            },
            points: Vec::with_capacity(cloth_rest.len()),
            face_warm: Vec::new(),
            face_outcomes: Outcomes::default(),
            parts: Vec::new(),
            later: Vec::new(),
        }
    }

    /// Start from `old`'s warm faces, per cloth vertex and triangle (a certifier of the same
    /// region and cloth, for another body shape): they only start the searches, so the answers
    /// are those of a cold start.
    pub(crate) fn warm_from(&mut self, old: &Certifier) {
        if old.vertex_warm.len() == self.vertex_warm.len() {
            self.vertex_warm.copy_from_slice(&old.vertex_warm);
            self.face_warm.clone_from(&old.face_warm);
        }
    }

    /// Rebuild the face data and the search's tree from the posed region, and find the buried
    /// faces where they are sought. Allocation-free.
    pub(crate) fn update(&mut self, posed: &[Vector3<f64>]) {
        self.frame.update(posed);
    }

    /// The posed region.
    #[cfg(test)]
    pub(crate) fn frame(&self) -> &Frame {
        &self.frame
    }
}

impl Frame {
    /// [`Certifier::update`].
    fn update(&mut self, posed: &[Vector3<f64>]) {
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for p in posed {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        self.origin = lo - Vector3::repeat(f64::from(ORIGIN_PAD_M));
        for (r, p) in self.rel.iter_mut().zip(posed) {
            let d = p - self.origin;
            *r = [d.x as f32, d.y as f32, d.z as f32];
        }
        // The cuts' caps serve the ray tests of buried faces only.
        let loops = if self.find_buried {
            self.loop_centre.len()
        } else {
            0
        };
        for (l, (centre, bounds)) in self
            .loop_centre
            .iter_mut()
            .zip(&mut self.loop_box)
            .enumerate()
            .take(loops)
        {
            let vs = &self.loop_vertices
                [self.loop_offsets[l] as usize..self.loop_offsets[l + 1] as usize];
            let mut sum = [0.0f32; 3];
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for &v in vs {
                let r = self.rel[v as usize];
                sum = [0, 1, 2].map(|k| sum[k] + r[k]);
                lo = [0, 1, 2].map(|k| lo[k].min(r[k]));
                hi = [0, 1, 2].map(|k| hi[k].max(r[k]));
            }
            *centre = sum.map(|x| x / vs.len().max(1) as f32);
            // Grown as its caps' boxes are, so that it holds them.
            *bounds = (
                [0, 1, 2].map(|k| lo[k].min(centre[k]) - CAP_BOX_PAD_M),
                [0, 1, 2].map(|k| hi[k].max(centre[k]) + CAP_BOX_PAD_M),
            );
            let caps = self.loop_caps[l] as usize..self.loop_caps[l + 1] as usize;
            for (&[a, b, _], cap_box) in self.caps[caps.clone()].iter().zip(&mut self.cap_box[caps])
            {
                let (a, b) = (self.rel[a as usize], self.rel[b as usize]);
                *cap_box = (
                    [0, 1, 2].map(|k| fmin(fmin(a[k], b[k]), centre[k]) - CAP_BOX_PAD_M),
                    [0, 1, 2].map(|k| fmax(fmax(a[k], b[k]), centre[k]) + CAP_BOX_PAD_M),
                );
            }
        }
        search::build(
            &mut self.tree,
            &self.cluster_faces,
            &self.faces,
            &self.rel,
            posed,
            &mut self.data,
            &mut self.cluster_box,
            // The faces' boxes and centroids for the rays and the ways out only.
            self.find_buried,
        );
        if self.find_buried {
            self.mark_buried();
            // The search never reaches a buried face, and the sweep proves no point near a
            // crease face.
            self.tree.clear_creases();
            for (k, &f) in self.cluster_faces.iter().enumerate() {
                if self.buried[f as usize] {
                    self.tree.take_out(k);
                }
                if self.crease[f as usize] {
                    self.tree.mark_crease(k);
                }
            }
        }
    }

    /// Find the faces buried inside another body part (the caller takes them out of the
    /// search's tree): the query then answers from the exposed surface only. Where body parts
    /// interpenetrate (an arm sunk into the torso of a heavy body, two thighs), the closest
    /// region face of a cloth vertex inside one part can be a face of the other part buried in
    /// the first, whose pseudo-normal reads the vertex as outside: it would never be pushed.
    ///
    /// A face is buried when the ray from just in front of its centroid, along the axis nearest
    /// its outward normal, leaves the region through more faces than it enters it by
    /// ([`Frame::ray_starts_inside`]): it started inside a part. The region's cuts are closed
    /// for the rays (see the module docs).
    ///
    /// The rays ran along the normals until 2026-11-30, each through a grid of the faces to its
    /// edge. Rays along the axes ([`Frame::axis_winding`]) agreed with them on every face of 1.6
    /// million rays (18,390 buried) over the runtime's tests, and of the demos of the 1.90 m
    /// heavy body on `cmu/05_06` and the 1.45 m heavy one on `cmu/02_01` (both read side by
    /// side in one build).
    fn mark_buried(&mut self) {
        self.n_buried = 0;
        let mut buried = std::mem::take(&mut self.buried);
        self.n_buried = buried_faces(self, &mut buried);
        self.buried = buried;
        self.crease.fill(false);
        if self.n_buried == 0 {
            return;
        }
        // Exposed faces that share a vertex with a buried one: they cross into the other part,
        // so the sign of their pseudo-normal can be wrong there.
        let mut touches = std::mem::take(&mut self.vertex_touches_buried);
        touches.fill(false);
        for (t, &b) in self.faces.iter().zip(&self.buried) {
            if b {
                for &v in t {
                    touches[v as usize] = true;
                }
            }
        }
        for (f, t) in self.faces.iter().enumerate() {
            self.crease[f] = !self.buried[f] && t.iter().any(|&v| touches[v as usize]);
        }
        self.vertex_touches_buried = touches;
    }

    /// Whether the ray from just in front of face `f`'s centroid, along the axis nearest its
    /// normal, starts inside another part (a winding number above zero).
    #[inline(always)]
    fn ray_starts_inside(&self, f: usize) -> bool {
        let [nx, ny, nz, o] = self.data.plane[f];
        let d = if o.is_finite() {
            // The unit normal of the face's plane (the exact query's edges, rounded once).
            [nx, ny, nz]
        } else {
            // A sliver: its plane is unset; the normal of its corners here.
            let [a, b, c] = self.faces[f].map(|v| self.rel[v as usize]);
            let n = cross(sub(b, a), sub(c, a));
            let len = dot(n, n).sqrt();
            if len.is_nan() || len <= 0.0 {
                return false;
            }
            n.map(|x| x / len)
        };
        let centroid = self.data.centroid[f];
        let o = [0, 1, 2].map(|k| centroid[k] + d[k] * BURIED_START_M);
        // Along the axis nearest the normal, on its side (at most 55° from the normal): the
        // winding number of a closed surface is the same along every ray.
        let k = (0..3).fold(0, |m, k| if d[k].abs() > d[m].abs() { k } else { m });
        self.axis_winding(o, k, d[k] > 0.0, f as u32) > 0
    }

    /// The region's winding number at `o` (relative) counted along the ray from `o` along axis
    /// `k` (towards `+∞` when `positive`): the faces it leaves through minus those it enters
    /// through (`skip` not counted), as the tests' reference `Frame::ray_winding` counts it. The
    /// faces tested are those whose box holds the ray's line and reaches its side of `o`,
    /// found by the search's tree (`search::Tree::axis_ray`: groups, clusters and faces, 16 boxes
    /// at a time), buried faces included; a face the ray crosses at `x` has a box holding `x`.
    ///
    /// Until 2026-12-08 the rays walked a uniform grid of the faces (3 cm cells, each face in
    /// every cell its box overlaps), one row of cells from the start to the row's last face.
    /// The grid was rebuilt every frame for the rays and the ways out alone (some 0.45 ms of a
    /// 3 ms post-process beyond the training shapes); the tree is rebuilt anyway, for the
    /// search, and now keeps its faces' boxes too. Its rays test more boxes (2 blocks of group
    /// boxes, then 3.2 of cluster boxes and 2.3 of face boxes a ray, against 3.1 blocks of entry
    /// boxes in 2.7 cells) and cost some 0.15 ms a frame more than the grid's, but the grid's
    /// build is gone: over the 1.90 m and 1.45 m heavy, the 1.60 m light and the nominal bodies
    /// on CMU 05_06, 02_02 and 05_10 (120 frames each, with the page's options and with the
    /// buried faces sought always), the post-process took 0.931 of the time, the old and new
    /// code in one process in turn, with the same garments bit for bit (2-core AMD EPYC Zen 3
    /// VM). The rays in the clusters' order instead of the faces' measured the same (1.008).
    #[inline(always)]
    fn axis_winding(&self, o: [f32; 3], k: usize, positive: bool, skip: u32) -> i32 {
        let mut d = [0.0f32; 3];
        d[k] = if positive { 1.0 } else { -1.0 };
        let mut winding = 0;
        let mut cross = |leaves: bool| winding += if leaves { 1 } else { -1 };
        let (a, b) = match k {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let meets = |(lo, hi): &([f32; 3], [f32; 3])| {
            let ahead = if positive {
                hi[k] >= o[k]
            } else {
                lo[k] <= o[k]
            };
            (lo[a] <= o[a]) & (o[a] <= hi[a]) & (lo[b] <= o[b]) & (o[b] <= hi[b]) & ahead
        };
        self.cross_caps(o, d, meets, &mut cross);
        self.tree.axis_ray(&o, k, positive, |slot| {
            let g = self.cluster_faces[slot];
            if g == skip {
                return;
            }
            let [p, q, r] = self.faces[g as usize].map(|v| self.rel[v as usize]);
            if let Some((t, leaves)) = ray_triangle(o, d, p, q, r)
                && t < BURIED_RAY_M
            {
                cross(leaves);
            }
        });
        winding
    }

    /// Tell `cross` of each crossing of the ray `o + t d` (`t` up to [`BURIED_RAY_M`]) through
    /// the caps that close the region's cuts, and whether it leaves through it; `meets`: whether
    /// the ray meets a cap's box or a loop's (a cap whose box it misses is not tested; a loop's
    /// box holds its caps' boxes).
    #[inline(always)]
    fn cross_caps(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        meets: impl Fn(&([f32; 3], [f32; 3])) -> bool,
        cross: &mut impl FnMut(bool),
    ) {
        for (l, loop_box) in self.loop_box.iter().enumerate() {
            if !meets(loop_box) {
                continue;
            }
            let centre = self.loop_centre[l];
            let range = self.loop_caps[l] as usize..self.loop_caps[l + 1] as usize;
            for (&[a, b, _], cap_box) in self.caps[range.clone()].iter().zip(&self.cap_box[range]) {
                if !meets(cap_box) {
                    continue;
                }
                let (pa, pb) = (self.rel[a as usize], self.rel[b as usize]);
                if let Some((t, leaves)) = ray_triangle(o, d, pb, pa, centre)
                    && t < BURIED_RAY_M
                {
                    cross(leaves);
                }
            }
        }
    }

    /// The region's winding number at `o` (relative) counted along the ray `o + t d` (`d`
    /// unit, `t` up to [`BURIED_RAY_M`]): the faces it leaves through minus those it enters
    /// through (`skip` not counted), every face and cap tested. Exact for a closed surface
    /// whatever the number of layers it crosses. The queries' rays run along the axes since
    /// 2026-11-30 ([`Frame::axis_winding`]); this general ray is the tests' reference.
    #[cfg(test)]
    fn ray_winding(&self, o: [f32; 3], d: [f32; 3], skip: u32) -> i32 {
        let mut winding = 0;
        let mut cross = |leaves: bool| winding += if leaves { 1 } else { -1 };
        let inv = d.map(|x| 1.0 / x);
        self.cross_caps(o, d, |(lo, hi)| ray_meets_box(&o, &inv, lo, hi), &mut cross);
        for (g, t) in self.faces.iter().enumerate() {
            let [p, q, r] = t.map(|v| self.rel[v as usize]);
            if g as u32 != skip
                && let Some((t, leaves)) = ray_triangle(o, d, p, q, r)
                && t < BURIED_RAY_M
            {
                cross(leaves);
            }
        }
        winding
    }

    /// `p` relative to the region's corner, in f32.
    fn relative(&self, p: &Vector3<f32>) -> [f32; 3] {
        let d = p.cast::<f64>() - self.origin;
        [d.x as f32, d.y as f32, d.z as f32]
    }

    /// Whether the exact query's answer at `x` (relative), whose nearest face is `nearest`, is
    /// outside at a distance² of at least `limit2`: far enough, in front of every face of its
    /// pseudo-normal, and that face not a crease (so [`Frame::settle`] keeps it).
    #[inline(always)]
    fn proven_beyond(&self, x: &[f32; 3], nearest: &NearestFace, limit2: f64) -> bool {
        nearest.distance_sq >= limit2
            && !self.crease[nearest.face as usize]
            && self.feature_in_front(x, nearest, GUARD_M)
    }

    /// Whether `x` (relative) is in front of every face whose normal enters the pseudo-normal
    /// of `nearest`'s feature, by more than `front`: then that pseudo-normal, a positive blend
    /// of those normals, has the exact query's sign positive.
    fn feature_in_front(&self, x: &[f32; 3], nearest: &NearestFace, front: f32) -> bool {
        let t = self.faces[nearest.face as usize];
        let in_front = |k: u32| {
            let [nx, ny, nz, o] = self.data.plane[k as usize];
            nx * x[0] + ny * x[1] + nz * x[2] - o > front
        };
        let fan = |v: u32| {
            let v = v as usize;
            &self.fan[self.fan_offsets[v] as usize..self.fan_offsets[v + 1] as usize]
        };
        match nearest.feature {
            ClosestFeature::Face => in_front(nearest.face),
            ClosestFeature::Edge(k) => {
                let (va, vb) = (t[k], t[(k + 1) % 3]);
                fan(va)
                    .iter()
                    .filter(|&&g| self.faces[g as usize].contains(&vb))
                    .all(|&g| in_front(g))
            }
            ClosestFeature::Vertex(k) => fan(t[k]).iter().all(|&g| in_front(g)),
        }
    }

    /// Whether `x` (relative) lies in front of face `g`'s plane by more than `front` (never
    /// for a sliver).
    fn in_front(&self, g: u32, x: &[f32; 3], front: f32) -> bool {
        let [nx, ny, nz, o] = self.data.plane[g as usize];
        nx * x[0] + ny * x[1] + nz * x[2] - o > front
    }

    /// Whether `x` (relative) lies inside the region by a vote of three rays (along the
    /// horizontal axis nearest `d` on its side, up and down: [`Frame::axis_winding`]): one ray
    /// grazing an edge can miss a crossing. Until 2026-11-30 the first ray ran along `d`
    /// itself. The third ray is cast only when the first two disagree (the vote is the same).
    fn inside_by_rays(&self, x: [f32; 3], d: [f32; 3]) -> bool {
        let k = if d[0].abs() >= d[1].abs() { 0 } else { 1 };
        let inside = |(k, positive): (usize, bool)| self.axis_winding(x, k, positive, u32::MAX) > 0;
        let first = inside((k, d[k] > 0.0));
        if first == inside((2, true)) {
            return first;
        }
        inside((2, false))
    }

    /// The answer `c` for `q`, unless `c`'s face is a crease face (exposed, next to a buried
    /// one) and `q` lies inside a body part by the rays' vote ([`Frame::inside_by_rays`], the
    /// first ray on the side of `c`'s normal): then the
    /// way out, the nearest point of an exposed face within [`SETTLE_M`] whose landing point
    /// ([`EXIT_CHECK_M`] beyond it, away from `q`) lies outside by the same ray test. Its
    /// answer reads `q` as inside by that distance, along the direction to it. `c` if no exit
    /// is found.
    ///
    /// A crease face's pseudo-normal reads the sign wrongly in either way there (a vertex in
    /// the overlap of two parts is "outside" one of them), and a push along it can end inside
    /// the other part: the exit is checked, not assumed.
    fn settle(
        &self,
        proximity: &MeshProximity,
        q: &Vector3<f64>,
        c: ClosestPoint,
        s: &mut Scratch,
    ) -> ClosestPoint {
        if !self.crease[c.face as usize] {
            return c;
        }
        let d = q - self.origin;
        let x = [d.x as f32, d.y as f32, d.z as f32];
        let n = [c.normal.x as f32, c.normal.y as f32, c.normal.z as f32];
        if !self.inside_by_rays(x, n) {
            return c;
        }
        // Growing balls: most such vertices are within a few centimetres of the way out. The
        // exposed faces within `reach`, nearest first; the first whose landing point is outside.
        // Each face's nearest point is computed once (one stamp for all the balls): a face
        // beyond one ball waits in `pending` for the ball that reaches it. A face `q` lies in
        // front of is no way out, and gets none: its nearest point `p` has `(p − q)·n ≤ −h`
        // for `h` the plane's distance (its corners' least), and past `GUARD_M` the f32 exit
        // test below reads that sign whatever the rounding (at most 8 cm away, `−h / dist`
        // is below −1e-4; `x`, the corners and the test are rounded by under 1e-6).
        let mut reach = SETTLE_M / 8.0;
        let stamp = s.next();
        s.pending.clear();
        loop {
            self.scan(&x, reach, |f, _| {
                let g = f as usize;
                if s.exit_stamp[g] == stamp || self.buried[g] {
                    return;
                }
                s.exit_stamp[g] = stamp;
                if !self.in_front(f, &x, GUARD_M)
                    && let Some(near) = proximity.nearest_among(q, &[f])
                {
                    s.pending.push(near);
                }
            });
            let (pending, exits) = (&mut s.pending, &mut s.exits);
            exits.clear();
            pending.retain(|near| {
                let within = near.distance_sq.sqrt() <= f64::from(reach);
                if within {
                    exits.push(*near);
                }
                !within
            });
            s.exits.sort_unstable_by(|a, b| {
                a.distance_sq
                    .total_cmp(&b.distance_sq)
                    .then(a.face.cmp(&b.face))
            });
            for k in 0..s.exits.len() {
                let near = s.exits[k];
                let f = near.face;
                let dist = near.distance_sq.sqrt();
                let out = if dist > 1e-9 {
                    (near.point - q) / dist
                } else {
                    proximity.signed(q, &near).normal
                };
                // An exit leaves through the face: from behind its plane to in front of it.
                let [nx, ny, nz, _] = self.data.plane[f as usize];
                if (out.x as f32) * nx + (out.y as f32) * ny + (out.z as f32) * nz <= 0.0 {
                    continue;
                }
                let land = near.point + out * EXIT_CHECK_M - self.origin;
                let l = [land.x as f32, land.y as f32, land.z as f32];
                let o = [out.x as f32, out.y as f32, out.z as f32];
                if !self.inside_by_rays(l, o) {
                    return ClosestPoint {
                        face: f,
                        point: near.point,
                        barycentric: near.barycentric,
                        signed_distance_m: -dist,
                        normal: out,
                    };
                }
            }
            if reach >= SETTLE_M {
                return c;
            }
            reach = (reach * 2.0).min(SETTLE_M);
        }
    }
}

impl Certifier {
    /// Certify or answer every cloth vertex (read back with [`Certifier::for_each_exact`]):
    /// one search of the region's faces per vertex (see `search.rs`); under
    /// [`Parallelism::Rayon`] the vertices are split over the threads (each vertex's outcome is
    /// its own, so the split changes no bit).
    pub(crate) fn run(
        &mut self,
        proximity: &MeshProximity,
        cloth: &[Vector3<f32>],
        margin_m: f64,
        par: Parallelism,
    ) -> CertifyStats {
        self.certify_into(proximity, cloth, false, (margin_m, None), par)
    }

    /// `visit(vertex, outcome)` for every cloth vertex of the last [`Certifier::run`], in a
    /// fixed order.
    #[cfg(test)]
    pub(crate) fn for_each_outcome(&self, visit: impl FnMut(usize, Option<Outcome>)) {
        self.vertex_outcomes.visit(visit);
    }

    /// `visit(vertex, answer)` for every cloth vertex of the last [`Certifier::run`] answered
    /// exactly (not certified), in vertex order: the others need no push.
    pub(crate) fn for_each_exact(&self, mut visit: impl FnMut(usize, &ClosestPoint)) {
        for (v, c) in &self.vertex_outcomes.exact {
            visit(*v as usize, c);
        }
    }
}

impl Certifier {
    /// [`Frame::certify`] of `points` with the cloth vertices' warm faces and outcomes, or
    /// (`triangles`) the triangles': every point's faces within its nearest distance (plus the
    /// slack) from the search of the region's faces, then the certificate (the point beyond the
    /// margin, in front of the plane of each of those faces, none of them a crease)
    /// or the exact answer from those faces. Split over threads under [`Parallelism::Rayon`]
    /// from [`MIN_SPLIT_POINTS`] points.
    fn certify_into(
        &mut self,
        proximity: &MeshProximity,
        points: &[Vector3<f32>],
        triangles: bool,
        limits: Limits,
        par: Parallelism,
    ) -> CertifyStats {
        let (warm, outcomes) = if triangles {
            (&mut self.face_warm[..], &mut self.face_outcomes)
        } else {
            (&mut self.vertex_warm[..], &mut self.vertex_outcomes)
        };
        outcomes.exact.clear();
        let threads = threads(par);
        let frame = &self.frame;
        if threads < 2 || points.len() < MIN_SPLIT_POINTS {
            let state = AnswerState {
                search: &mut self.search,
                points: &mut self.points,
                scratch: &mut self.scratch,
            };
            let out = (warm, &mut outcomes.kind[..], &mut outcomes.exact, 0);
            return frame.certify(state, proximity, points, out, limits);
        }
        let chunk = split(
            &mut self.parts,
            frame,
            points.len(),
            PARTS_PER_THREAD * threads,
        );
        let stats = points
            .par_chunks(chunk)
            .zip(warm.par_chunks_mut(chunk))
            .zip(outcomes.kind.par_chunks_mut(chunk))
            .zip(self.parts.par_iter_mut())
            .enumerate()
            .map(|(k, (((points, warm), kind), part))| {
                let state = AnswerState {
                    search: &mut part.search,
                    points: &mut part.points,
                    scratch: &mut part.scratch,
                };
                part.exact.clear();
                let out = (warm, kind, &mut part.exact, k * chunk);
                frame.certify(state, proximity, points, out, limits)
            })
            .reduce(CertifyStats::default, CertifyStats::merged);
        for part in &self.parts[..points.len().div_ceil(chunk)] {
            outcomes.exact.extend_from_slice(&part.exact);
        }
        stats
    }

    /// [`Certifier::run`] for other points than the cloth vertices: the cloth triangles'
    /// centroids, `points[k]` that of triangle `k` (each triangle keeps its own warm face from
    /// frame to frame); `visit(k, outcome)` for each, in order. A point farther than `far_m`
    /// from every face of the region (`far_m` at least `margin_m`) is certified whichever side
    /// of the body it lies on: for a caller that leaves a point that deep inside alone (the
    /// triangles' pass, [`super::FACE_DEPTH_M`]).
    pub(crate) fn run_points(
        &mut self,
        proximity: &MeshProximity,
        points: &[Vector3<f32>],
        (margin_m, far_m): (f64, f64),
        par: Parallelism,
        visit: impl FnMut(usize, Option<Outcome>),
    ) {
        self.face_warm.resize(points.len(), u32::MAX);
        self.face_outcomes.resize(points.len());
        self.certify_into(proximity, points, true, (margin_m, Some(far_m)), par);
        self.face_outcomes.visit(visit);
    }

    /// For each of `points` (`warm`: a face to start from per point, `u32::MAX` for none),
    /// visited in order: [`Later::Beyond`] where the exact query's signed distance is proven at
    /// least `beyond_m`, its exact answer otherwise; for the later passes, which push only
    /// points inside `beyond_m`. Under [`Parallelism::Rayon`], from [`MIN_SPLIT_LATER`] points,
    /// split over the threads as the first pass is (each point's answer is its own), the
    /// answers kept and visited in order after. Allocation-free (once the buffers have grown).
    pub(crate) fn later_points(
        &mut self,
        proximity: &MeshProximity,
        points: &[Vector3<f32>],
        warm: &[u32],
        beyond_m: f64,
        par: Parallelism,
        mut visit: impl FnMut(usize, Option<Later>),
    ) {
        let threads = threads(par);
        if threads < 2 || points.len() < MIN_SPLIT_LATER {
            let state = AnswerState {
                search: &mut self.search,
                points: &mut self.points,
                scratch: &mut self.scratch,
            };
            self.frame
                .answer_points(state, proximity, points, warm, Some(beyond_m), visit);
            return;
        }
        let chunk = split(&mut self.parts, &self.frame, points.len(), threads);
        let mut later = std::mem::take(&mut self.later);
        later.clear();
        later.resize(points.len(), None);
        let frame = &self.frame;
        points
            .par_chunks(chunk)
            .zip(warm.par_chunks(chunk))
            .zip(later.par_chunks_mut(chunk))
            .zip(self.parts.par_iter_mut())
            .for_each(|(((points, warm), out), part)| {
                let state = AnswerState {
                    search: &mut part.search,
                    points: &mut part.points,
                    scratch: &mut part.scratch,
                };
                frame.answer_points(state, proximity, points, warm, Some(beyond_m), |k, hit| {
                    out[k] = hit;
                });
            });
        for (k, hit) in later.iter().enumerate() {
            visit(k, *hit);
        }
        self.later = later;
    }

    /// The exact query's answer for each of `points` from `warm` faces (tests).
    #[cfg(test)]
    pub(crate) fn exact_points(
        &mut self,
        proximity: &MeshProximity,
        points: &[Vector3<f32>],
        warm: &[u32],
        mut visit: impl FnMut(usize, Option<ClosestPoint>),
    ) {
        let state = AnswerState {
            search: &mut self.search,
            points: &mut self.points,
            scratch: &mut self.scratch,
        };
        self.frame
            .answer_points(state, proximity, points, warm, None, |k, hit| {
                visit(k, hit.map(Later::exact))
            });
    }

    /// The exact query's answer for each of `points`, without a starting face, with scratch of
    /// its own (for reports).
    pub(crate) fn exact_each(
        &self,
        proximity: &MeshProximity,
        points: &[Vector3<f32>],
        mut visit: impl FnMut(usize, Option<ClosestPoint>),
    ) {
        let mut search = Search::default();
        let state = AnswerState {
            search: &mut search,
            points: &mut Vec::new(),
            scratch: &mut Scratch::for_frame(&self.frame),
        };
        let warm = vec![u32::MAX; points.len()];
        self.frame
            .answer_points(state, proximity, points, &warm, None, |k, hit| {
                visit(k, hit.map(Later::exact))
            });
    }
}

impl Frame {
    /// Certify or answer each of `cloth` (see [`Certifier::certify_into`]), starting from and
    /// updating `warm`, writing each point's kind into `kinds` and its exact answer, if any, onto
    /// `exact` (`cloth[i]` is point `offset + i` there).
    fn certify(
        &self,
        state: AnswerState<'_>,
        proximity: &MeshProximity,
        cloth: &[Vector3<f32>],
        (warm, kinds, exact, offset): PointOutcomes<'_>,
        (margin_m, far_m): Limits,
    ) -> CertifyStats {
        let AnswerState {
            search,
            points,
            scratch: s,
        } = state;
        points.clear();
        points.extend(cloth.iter().map(|p| self.relative(p)));
        let front2 = (margin_m as f32 + GUARD_M).powi(2);
        let far2 = far_m.map(|f| (f as f32 + GUARD_M).powi(2));
        let by = Sweeps {
            sweep: Some(front2),
            far: far2,
        };
        search.run(self, points, warm, by);
        let margin2 = margin_m * margin_m;
        let mut stats = CertifyStats::default();
        for (i, (kind, warm)) in kinds.iter_mut().zip(warm.iter_mut()).enumerate() {
            if search.swept(i) {
                // Proven beyond the margin from the warm face, which stays.
                *kind = CERTIFIED;
                stats.certified += 1;
                stats.swept += 1;
                continue;
            }
            let x = &points[i];
            let (best2, best_face) = search.best(i);
            search.faces_into(i, &mut s.candidates);
            stats.candidates += s.candidates.len();
            // A vertex with a crease face among its candidates is never certified (`settle`).
            let crease = s.candidates.iter().any(|&g| self.crease[g as usize]);
            if !crease
                && best2 >= front2
                && s.candidates.iter().all(|&g| self.in_front(g, x, GUARD_M))
            {
                *kind = CERTIFIED;
                *warm = best_face;
                stats.certified += 1;
                continue;
            }
            let q = cloth[i].cast::<f64>();
            *kind = match proximity.nearest_among(&q, &s.candidates) {
                None => NO_FACE,
                Some(nearest) => {
                    *warm = nearest.face;
                    if !crease && self.proven_beyond(x, &nearest, margin2) {
                        stats.certified += 1;
                        CERTIFIED
                    } else {
                        stats.exact += 1;
                        let c = proximity.signed(&q, &nearest);
                        exact.push(((offset + i) as u32, self.settle(proximity, &q, c, s)));
                        EXACT
                    }
                }
            };
        }
        CertifyStats {
            buried_faces: self.n_buried,
            ..stats
        }
    }
}

/// The margin a certified point lies beyond, and the distance beyond which a point needs no
/// answer whichever side of the body it lies on (`None`: every point within or inside the margin
/// gets its answer), metres.
type Limits = (f64, Option<f64>);

/// Where [`Frame::certify`] reads and writes per point: the warm faces, the kinds, the exact
/// answers, and the first point's index among the run's.
type PointOutcomes<'a> = (
    &'a mut [u32],
    &'a mut [u8],
    &'a mut Vec<(u32, ClosestPoint)>,
    usize,
);

/// What [`Frame::answer_points`] works in: the search, the relative points, scratch.
struct AnswerState<'a> {
    search: &'a mut Search,
    points: &'a mut Vec<[f32; 3]>,
    scratch: &'a mut Scratch,
}

/// What a later pass learns of a point ([`Certifier::later_points`]).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Later {
    /// Proven outside and at least the asked distance from the region (the test of the first
    /// pass's certificate on the exact nearest face: in front of every face whose normal
    /// enters its pseudo-normal, and that face not a crease), with a face to start its next
    /// search from: the nearest one, or, where the sweep proved it, its warm face.
    Beyond { face: u32 },
    /// The exact closest point.
    Exact(ClosestPoint),
}

impl Later {
    /// The exact answer (`Beyond` is only given where one was asked for).
    fn exact(self) -> ClosestPoint {
        match self {
            Later::Exact(c) => c,
            Later::Beyond { .. } => unreachable!("no distance was asked for"),
        }
    }
}

impl Frame {
    /// The exact query's answer for each of `points` from `warm` faces, by the search; with
    /// `beyond_m`, [`Later::Beyond`] where it is proven at least that, which skips the
    /// pseudo-normal and [`Frame::settle`] (a later pass leaves such a point where it is).
    fn answer_points(
        &self,
        state: AnswerState<'_>,
        proximity: &MeshProximity,
        points: &[Vector3<f32>],
        warm: &[u32],
        beyond_m: Option<f64>,
        mut visit: impl FnMut(usize, Option<Later>),
    ) {
        let AnswerState {
            search,
            points: rel,
            scratch: s,
        } = state;
        rel.clear();
        rel.extend(points.iter().map(|p| self.relative(p)));
        // The sweep proves points beyond `beyond_m` as the first pass's beyond the margin.
        let sweep = beyond_m.map(|b| (b as f32 + GUARD_M).powi(2));
        search.run(self, rel, warm, Sweeps { sweep, far: None });
        for (k, p) in points.iter().enumerate() {
            if search.swept(k) {
                visit(
                    k,
                    Some(Later::Beyond {
                        face: search.best(k).1,
                    }),
                );
                continue;
            }
            search.faces_into(k, &mut s.candidates);
            let q = p.cast::<f64>();
            let hit = proximity.nearest_among(&q, &s.candidates).map(|nearest| {
                // Positive by the planes of the faces of its pseudo-normal, and no crease (so
                // `settle` keeps it): the exact answer's signed distance is the distance.
                if let Some(limit) = beyond_m
                    && self.proven_beyond(&rel[k], &nearest, limit * limit)
                {
                    return Later::Beyond { face: nearest.face };
                }
                let c = proximity.signed(&q, &nearest);
                Later::Exact(self.settle(proximity, &q, c, s))
            });
            visit(k, hit);
        }
    }
}

/// Points in groups of up to `size`, spatially compact (median splits along the longest axis,
/// at multiples of `size`); `size` slots per group,
/// `u32::MAX` for an empty one. Deterministic.
fn groups(rest: &[Vector3<f32>], size: usize) -> Vec<u32> {
    fn split(idx: &mut [u32], rest: &[Vector3<f32>], size: usize, out: &mut Vec<u32>) {
        let n = idx.len();
        if n <= size {
            out.extend_from_slice(idx);
            out.extend(std::iter::repeat_n(u32::MAX, size - n));
            return;
        }
        let (mut lo, mut hi) = (
            Vector3::repeat(f32::INFINITY),
            Vector3::repeat(f32::NEG_INFINITY),
        );
        for &i in idx.iter() {
            lo = lo.inf(&rest[i as usize]);
            hi = hi.sup(&rest[i as usize]);
        }
        let axis = (hi - lo).imax();
        let mid = (n.div_ceil(size) / 2) * size;
        idx.select_nth_unstable_by(mid, |&a, &b| {
            rest[a as usize][axis]
                .total_cmp(&rest[b as usize][axis])
                .then(a.cmp(&b))
        });
        let (left, right) = idx.split_at_mut(mid);
        split(left, rest, size, out);
        split(right, rest, size, out);
    }
    let mut idx: Vec<u32> = (0..rest.len() as u32).collect();
    let mut out = Vec::with_capacity(rest.len() + size);
    split(&mut idx, rest, size, &mut out);
    out
}

impl Frame {
    /// Visit `(face, lower bound²)` for every face whose box and plane bound (the larger) lie
    /// within `reach` of `x` (buried faces never: they are out of the tree's search). Until
    /// 2026-12-08 a scan of the grid's cells (see [`Frame::axis_winding`]), which visited the
    /// same faces (and the buried ones, which the caller skips).
    #[inline(always)]
    fn scan(&self, x: &[f32; 3], reach: f32, mut visit: impl FnMut(u32, f32)) {
        let r = reach + GUARD_M;
        self.tree
            .within_ball(x, r * r, |slot, b| visit(self.cluster_faces[slot], b));
    }
}

crate::kernels::widest_where_present! {
    /// [`Frame::ray_starts_inside`] of every face into `buried`, and how many are: built for
    /// the widest vectors present (the rays' lane box tests).
    fn buried_faces(frame: &Frame, buried: &mut [bool]) -> usize {
        let mut n = 0;
        for (f, b) in buried.iter_mut().enumerate() {
            *b = frame.ray_starts_inside(f);
            n += usize::from(*b);
        }
        n
    }
}

/// The boundary of the region (`faces` over `n_vertices`), to close its cuts: per boundary edge
/// `(a, b, loop)` as its face orders it, sorted by loop, and the vertices of each loop (CSR
/// offsets and vertices), from sartor-core's `MeshTopology::boundary_loops`.
fn caps(n_vertices: usize, faces: &[[u32; 3]]) -> (Vec<[u32; 3]>, Vec<u32>, Vec<u32>) {
    let loops = MeshTopology::new(n_vertices, faces).boundary_loops();
    let mut caps = Vec::new();
    let mut offsets = vec![0u32];
    let mut vertices = Vec::new();
    for (l, cycle) in loops.iter().enumerate() {
        for (k, &a) in cycle.iter().enumerate() {
            caps.push([a, cycle[(k + 1) % cycle.len()], l as u32]);
        }
        vertices.extend_from_slice(cycle);
        offsets.push(vertices.len() as u32);
    }
    (caps, offsets, vertices)
}

#[inline(always)]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Whether the segment `o + t d`, `0 ≤ t ≤` [`BURIED_RAY_M`], meets the box `[lo, hi]` (`inv`:
/// `1 / d` per axis, infinite along an axis `d` does not move on); the tests' general walk.
#[cfg(test)]
#[inline(always)]
fn ray_meets_box(o: &[f32; 3], inv: &[f32; 3], lo: &[f32; 3], hi: &[f32; 3]) -> bool {
    let (mut t0, mut t1) = (0.0f32, BURIED_RAY_M);
    for k in 0..3 {
        let (a, b) = slab(o[k], inv[k], lo[k], hi[k]);
        t0 = t0.max(a);
        t1 = t1.min(b);
    }
    t0 <= t1
}

/// The interval of `t` where the ray `o + t d` (`inv` = 1 / d, per axis) lies within the slab
/// `lo ..= hi`: an axis the ray is parallel to (`inv` infinite) allows every `t` or none.
#[cfg(test)]
#[inline(always)]
fn slab(o: f32, inv: f32, lo: f32, hi: f32) -> (f32, f32) {
    if inv.is_infinite() {
        if o >= lo && o <= hi {
            (f32::NEG_INFINITY, f32::INFINITY)
        } else {
            (f32::INFINITY, f32::NEG_INFINITY)
        }
    } else {
        let (a, b) = ((lo - o) * inv, (hi - o) * inv);
        (a.min(b), a.max(b))
    }
}

/// Where the ray `o + t d` (t > 0) meets triangle `(a, b, c)` (Möller and Trumbore), and
/// whether it meets it from behind (along the triangle's normal `(b − a) × (c − a)`).
#[inline(always)]
fn ray_triangle(
    o: [f32; 3],
    d: [f32; 3],
    a: [f32; 3],
    b: [f32; 3],
    c: [f32; 3],
) -> Option<(f32, bool)> {
    let (e1, e2) = (sub(b, a), sub(c, a));
    let p = cross(d, e2);
    // det = −d·((b − a) × (c − a)): negative when the ray runs along the normal.
    let det = dot(e1, p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(o, a);
    let u = dot(s, p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = cross(s, e1);
    let v = dot(d, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t > 0.0).then_some((t, det < 0.0))
}

/// `max` that compiles to one instruction (no NaN handling: a NaN operand gives `b`).
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

#[cfg(test)]
crate::kernels::widest_where_present! {
    /// Each face's centroid and plane (see [`Faces`]) from its corners `rel` (relative, f32)
    /// and `posed` (f64), and its box, face by face: the reference for `search::build`.
    fn face_data(
        faces: &[[u32; 3]],
        rel: &[[f32; 3]],
        posed: &[Vector3<f64>],
        data: &mut Faces,
        boxes: &mut [([f32; 3], [f32; 3])],
    ) {
        for (f, &[u, v, w]) in faces.iter().enumerate() {
            let (u, v, w) = (u as usize, v as usize, w as usize);
            let (a, b, c) = (rel[u], rel[v], rel[w]);
            // Edges from the f64 positions (the exact query's own), then f32: the normal's
            // direction error stays below ~1e-5 for faces that pass the sliver test.
            let (e1, e2) = ((posed[v] - posed[u]).cast::<f32>(), (posed[w] - posed[u]).cast::<f32>());
            let mut l = [0.0f32; 3];
            let mut h = [0.0f32; 3];
            for k in 0..3 {
                l[k] = fmin(fmin(a[k], b[k]), c[k]);
                h[k] = fmax(fmax(a[k], b[k]), c[k]);
            }
            boxes[f] = (l, h);
            data.centroid[f] = [
                (a[0] + b[0] + c[0]) / 3.0,
                (a[1] + b[1] + c[1]) / 3.0,
                (a[2] + b[2] + c[2]) / 3.0,
            ];
            let n = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let scale = ((e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
                * (e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2]))
                .sqrt();
            data.plane[f] = if len > MIN_SINE * scale && len > 0.0 {
                let n = [n[0] / len, n[1] / len, n[2] / len];
                let dot = |v: [f32; 3]| n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
                [n[0], n[1], n[2], fmax(fmax(dot(a), dot(b)), dot(c))]
            } else {
                [0.0, 0.0, 0.0, f32::INFINITY]
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The certified query's exact answer at `q` (as a cloth vertex, in f32).
    fn answer(
        certifier: &mut Certifier,
        proximity: &MeshProximity,
        q: &Vector3<f64>,
    ) -> ClosestPoint {
        let mut out = None;
        certifier.exact_each(proximity, &[q.cast::<f32>()], |_, hit| {
            out = hit;
        });
        out.expect("an answer")
    }

    /// An axis-aligned box (sartor-core's `box_mesh`), appended to `vertices` and `faces`.
    fn cuboid(
        lo: [f64; 3],
        hi: [f64; 3],
        vertices: &mut Vec<Vector3<f64>>,
        faces: &mut Vec<[u32; 3]>,
    ) {
        let base = vertices.len() as u32;
        let (v, f) = sartor_core::box_mesh(lo.into(), hi.into());
        vertices.extend(v);
        faces.extend(f.iter().map(|t| t.map(|k| base + k)));
    }

    #[test]
    fn the_search_answers_as_the_exact_query_near_and_far() {
        // Two boxes; points from inside them to 30 cm away, with no face to start from: the
        // tree search gives the exact query's closest point near and far.
        let (mut v, mut f) = (Vec::new(), Vec::new());
        cuboid([0.0, 0.0, 0.0], [0.2, 0.1, 0.3], &mut v, &mut f);
        cuboid([0.25, 0.0, 0.0], [0.3, 0.05, 0.1], &mut v, &mut f);
        let proximity = MeshProximity::new(&v, &f).expect("mesh");
        let mut certifier = Certifier::new(&v, &f, &[Vector3::zeros()], false);
        certifier.update(&v);
        let mut points = Vec::new();
        for i in 0..23 {
            for j in 0..17 {
                for k in 0..19 {
                    let p = Vector3::new(
                        -0.3 + 0.041 * f64::from(i),
                        -0.3 + 0.043 * f64::from(j),
                        -0.3 + 0.047 * f64::from(k),
                    );
                    points.push(p.cast::<f32>());
                }
            }
        }
        let warm = vec![u32::MAX; points.len()];
        let mut checked = [0usize; 3];
        certifier.exact_points(&proximity, &points, &warm, |k, hit| {
            let c = hit.expect("an answer");
            let exact = proximity.closest(&points[k].cast::<f64>());
            assert_eq!(
                (c.face, c.signed_distance_m),
                (exact.face, exact.signed_distance_m),
                "{:?}",
                points[k]
            );
            let d = c.signed_distance_m.abs();
            checked[usize::from(d > 0.02) + usize::from(d > 0.1)] += 1;
        });
        assert!(checked.iter().all(|&n| n > 100), "{checked:?}");
        // A later pass's answers: proven beyond 2 cm only where the exact query says so.
        let (mut beyond, mut exact_beyond) = (0, 0);
        certifier.later_points(
            &proximity,
            &points,
            &warm,
            0.02,
            Parallelism::Sequential,
            |k, hit| {
                let exact = proximity.closest(&points[k].cast::<f64>());
                match hit.expect("an answer") {
                    Later::Beyond { face } => {
                        assert!(exact.signed_distance_m >= 0.02, "{:?}", points[k]);
                        assert_eq!(face, exact.face);
                        beyond += 1;
                    }
                    Later::Exact(c) => {
                        assert_eq!(
                            (c.face, c.signed_distance_m),
                            (exact.face, exact.signed_distance_m)
                        );
                        exact_beyond += usize::from(c.signed_distance_m >= 0.02);
                    }
                }
            },
        );
        assert!(
            beyond > 100,
            "{beyond} proven beyond, {exact_beyond} answered"
        );
    }

    /// Every certified point lies beyond `margin` by the exact query, with its sign positive;
    /// every other point got the exact query's answer.
    fn check(
        cloth: &[Vector3<f32>],
        outcomes: &[Option<Outcome>],
        proximity: &MeshProximity,
        margin: f64,
    ) {
        for (p, o) in cloth.iter().zip(outcomes) {
            let exact = proximity.closest(&p.cast::<f64>());
            match o.expect("an outcome") {
                Outcome::Certified => assert!(
                    exact.signed_distance_m >= margin,
                    "certified at {p:?}, exact {exact:?}"
                ),
                Outcome::Exact(c) => {
                    assert_eq!(
                        (c.face, c.signed_distance_m),
                        (exact.face, exact.signed_distance_m)
                    )
                }
            }
        }
    }

    /// The certified query run twice over the region `(v, f)`: the second time from the first
    /// run's warm faces, with every cloth point moved up to 3 mm (`next`: uniform in [0, 1)).
    fn warm_second_frame(
        v: &[Vector3<f64>],
        f: &[[u32; 3]],
        cloth: &mut [Vector3<f32>],
        buried: bool,
        margin: f64,
        next: &mut impl FnMut() -> f64,
    ) -> (MeshProximity, Certifier, CertifyStats, Vec<Option<Outcome>>) {
        let proximity = MeshProximity::new(v, f).expect("mesh");
        let mut certifier = Certifier::new(v, f, cloth, buried);
        certifier.update(v);
        certifier.run(&proximity, cloth, margin, Parallelism::Sequential);
        for p in cloth.iter_mut() {
            *p += Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5).cast() * 0.006;
        }
        let stats = certifier.run(&proximity, cloth, margin, Parallelism::Sequential);
        let mut outcomes = vec![None; cloth.len()];
        certifier.for_each_outcome(|k, o| outcomes[k] = o);
        (proximity, certifier, stats, outcomes)
    }

    #[test]
    fn the_sweep_proves_no_point_behind_a_flat_surface() {
        // A flat open grid and points on both sides of it, up to 3 cm away, run twice: the
        // second run sweeps from the first run's faces, with every point moved up to 3 mm.
        // Behind a plane no face lies nearer than the warm one, so a sweep that missed the
        // warm face's own lane (a reach too short) would prove points behind it.
        use rand::{Rng, SeedableRng};
        let n = 20;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut next = move || rng.random::<f64>();
        let v: Vec<Vector3<f64>> = (0..=n)
            .flat_map(|i| {
                (0..=n).map(move |j| Vector3::new(0.01 * f64::from(i), 0.01 * f64::from(j), 0.0))
            })
            .collect();
        let at = |i: u32, j: u32| i * (n + 1) + j;
        let f: Vec<[u32; 3]> = (0..n)
            .flat_map(|i| {
                (0..n).flat_map(move |j| {
                    [
                        [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                        [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                    ]
                })
            })
            .collect();
        let mut cloth: Vec<Vector3<f32>> = (0..5_000)
            .map(|_| {
                let z = 0.06 * (next() - 0.5);
                Vector3::new(0.02 + 0.16 * next(), 0.02 + 0.16 * next(), z).cast()
            })
            .collect();
        let margin = 0.002;
        let (proximity, _, stats, outcomes) =
            warm_second_frame(&v, &f, &mut cloth, false, margin, &mut next);
        check(&cloth, &outcomes, &proximity, margin);
        assert!(stats.swept > 1_500 && stats.exact > 1_500, "{stats:?}");
    }

    #[test]
    fn a_certified_point_is_one_the_exact_query_would_not_push_on_a_rough_surface() {
        // An open, rough height field (saddles, pits and ridges at every vertex) and points
        // above and below it: every point the certificate passes lies beyond the margin with
        // the exact query's sign positive, and every other point gets the exact answer.
        use rand::{Rng, SeedableRng};
        let n = 24;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut next = move || rng.random::<f64>();
        let mut v = Vec::new();
        for i in 0..=n {
            for j in 0..=n {
                let (x, y) = (0.01 * f64::from(i), 0.01 * f64::from(j));
                v.push(Vector3::new(x, y, 0.012 * (next() - 0.5)));
            }
        }
        let at = |i: u32, j: u32| i * (n + 1) + j;
        let mut f = Vec::new();
        for i in 0..n {
            for j in 0..n {
                f.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                f.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        let cloth: Vec<Vector3<f32>> = (0..20_000)
            .map(|_| {
                Vector3::new(
                    -0.02 + 0.28 * next(),
                    -0.02 + 0.28 * next(),
                    -0.03 + 0.06 * next(),
                )
                .cast()
            })
            .collect();
        let proximity = MeshProximity::new(&v, &f).expect("mesh");
        let mut certifier = Certifier::new(&v, &f, &cloth, false);
        certifier.update(&v);
        let margin = 0.002;
        let stats = certifier.run(&proximity, &cloth, margin, Parallelism::Sequential);
        let mut outcomes = vec![None; cloth.len()];
        certifier.for_each_outcome(|k, o| outcomes[k] = o);
        check(&cloth, &outcomes, &proximity, margin);
        // Both ways taken often, points on either side near the surface among them.
        assert!(stats.certified > 5_000 && stats.exact > 5_000, "{stats:?}");
        // Again with warm faces, each point moved up to 4 mm and the surface up to 1 mm:
        // the sweep proves points from their (now stale) warm faces, the rest as above.
        let moved: Vec<Vector3<f32>> = cloth
            .iter()
            .map(|p| p + Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5).cast() * 0.008)
            .collect();
        let v: Vec<Vector3<f64>> = v
            .iter()
            .map(|p| p + Vector3::new(0.0, 0.0, 0.002 * (next() - 0.5)))
            .collect();
        let proximity = MeshProximity::new(&v, &f).expect("mesh");
        certifier.update(&v);
        let stats = certifier.run(&proximity, &moved, margin, Parallelism::Sequential);
        certifier.for_each_outcome(|k, o| outcomes[k] = o);
        check(&moved, &outcomes, &proximity, margin);
        assert!(stats.swept > 5_000 && stats.exact > 5_000, "{stats:?}");
        assert!(stats.certified > stats.swept, "{stats:?}");
    }

    #[test]
    fn more_near_ties_than_a_list_holds_still_give_the_exact_answer() {
        // A cone of 24 faces around one apex, and a box beside it: above the apex every cone
        // face is at the same distance (more than a candidate list holds), so the search falls
        // back to every face and keeps all the ties; the tie rule picks the lowest face.
        let n = 24u32;
        let mut v = vec![Vector3::new(0.0, 0.0, 0.05)];
        for k in 0..n {
            let a = std::f64::consts::TAU * f64::from(k) / f64::from(n);
            v.push(Vector3::new(0.1 * a.cos(), 0.1 * a.sin(), 0.0));
        }
        let mut f: Vec<[u32; 3]> = (0..n).map(|k| [0, 1 + k, 1 + (k + 1) % n]).collect();
        cuboid([0.3, 0.0, 0.0], [0.4, 0.1, 0.1], &mut v, &mut f);
        let proximity = MeshProximity::new(&v, &f).expect("mesh");
        let mut certifier = Certifier::new(&v, &f, &[Vector3::zeros()], false);
        certifier.update(&v);
        let points: Vec<Vector3<f32>> = [[0.0, 0.0, 0.06], [0.0, 0.0, 0.09], [1e-4, 0.0, 0.07]]
            .iter()
            .map(|p| Vector3::new(p[0], p[1], p[2]))
            .collect();
        for warm in [u32::MAX, 3, n] {
            certifier.exact_points(&proximity, &points, &[warm; 3], |k, hit| {
                let c = hit.expect("an answer");
                let exact = proximity.closest(&points[k].cast::<f64>());
                assert_eq!(
                    (c.face, c.signed_distance_m),
                    (exact.face, exact.signed_distance_m),
                    "{:?} from face {warm}",
                    points[k]
                );
            });
        }
        // Above the apex every cone face ties: the list overflowed and was kept in full.
        let rel = certifier.frame.relative(&points[0]);
        let mut search = Search::default();
        search.run(&certifier.frame, &[rel], &[u32::MAX], Sweeps::default());
        let mut faces = Vec::new();
        search.faces_into(0, &mut faces);
        assert_eq!(faces.iter().filter(|&&g| g < n).count(), n as usize);
    }

    #[test]
    fn faces_inside_another_part_are_buried_and_left_out() {
        // Part A, a 6 cm box; part B sunk 3 cm into its +x side; part C, a box inside both
        // (three layers); part D apart.
        let (mut v, mut f) = (Vec::new(), Vec::new());
        cuboid([0.0, 0.0, 0.0], [0.06, 0.06, 0.06], &mut v, &mut f);
        cuboid([0.03, 0.01, 0.01], [0.10, 0.05, 0.05], &mut v, &mut f);
        cuboid([0.035, 0.02, 0.02], [0.055, 0.04, 0.04], &mut v, &mut f);
        cuboid([0.2, 0.0, 0.0], [0.23, 0.03, 0.03], &mut v, &mut f);
        let centroid = |t: &[u32; 3]| t.iter().map(|&i| v[i as usize]).sum::<Vector3<f64>>() / 3.0;
        let inside = |p: Vector3<f64>, lo: [f64; 3], hi: [f64; 3]| {
            (0..3).all(|k| p[k] > lo[k] && p[k] < hi[k])
        };
        let mut certifier = Certifier::new(&v, &f, &[Vector3::zeros()], true);
        certifier.update(&v);
        let frame = certifier.frame();
        let mut n_buried = 0;
        for (i, t) in f.iter().enumerate() {
            let c = centroid(t);
            // Buried: inside a part other than its own (the boxes are open sets).
            let expected =
                inside(c, [0.0; 3], [0.06; 3]) || inside(c, [0.03, 0.01, 0.01], [0.10, 0.05, 0.05]);
            assert_eq!(frame.buried[i], expected, "face {i} at {c:?}");
            n_buried += usize::from(expected);
        }
        // A's +x side (2 faces), B's −x side (2), on each of B's four long sides the triangle
        // whose centroid is in A (4), the whole of C (12).
        assert_eq!((n_buried, frame.n_buried), (20, 20));
        // The boxes the rays read in the tree are those the search reads off the corners.
        for k in 0..f.len() {
            let (lo, hi) = frame.face_box(k);
            let bits = |b: [f32; 3]| b.map(f32::to_bits);
            let (tree_lo, tree_hi) = frame.tree.face_box(frame.face_slot[k] as usize);
            assert_eq!((bits(lo), bits(hi)), (bits(tree_lo), bits(tree_hi)));
        }
        // The query answers from the exposed surface: a point inside B, just in front of A's
        // buried +x side, is inside (the closest exposed face is B's), not 1 mm outside A.
        let proximity = MeshProximity::new(&v, &f).expect("mesh");
        let q = Vector3::new(0.061, 0.03, 0.03);
        let c = answer(&mut certifier, &proximity, &q);
        assert!(c.signed_distance_m < -0.015, "{c:?}");
        assert!(
            proximity.closest(&q).signed_distance_m > 0.0,
            "the full surface reads outside"
        );
    }

    #[test]
    fn with_buried_faces_a_swept_point_is_one_the_exposed_surface_would_not_push() {
        // Two boxes sunk into each other (buried faces, crease faces around them) and points
        // in and around them, run twice: the second run sweeps from the first run's faces,
        // each point moved up to 3 mm. Every certified point lies beyond the margin by the
        // exposed surface's exact answer (`exact_each`, no sweep); every other point got it.
        use rand::{Rng, SeedableRng};
        let (mut v, mut f) = (Vec::new(), Vec::new());
        cuboid([0.0, 0.0, 0.0], [0.06, 0.06, 0.06], &mut v, &mut f);
        cuboid([0.03, 0.01, 0.01], [0.10, 0.05, 0.05], &mut v, &mut f);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut next = move || rng.random::<f64>();
        let mut cloth: Vec<Vector3<f32>> = (0..4_000)
            .map(|_| {
                let p = Vector3::new(
                    0.14 * next() - 0.02,
                    0.1 * next() - 0.02,
                    0.1 * next() - 0.02,
                );
                p.cast()
            })
            .collect();
        let margin = 0.002;
        let (proximity, certifier, stats, outcomes) =
            warm_second_frame(&v, &f, &mut cloth, true, margin, &mut next);
        assert!(stats.buried_faces > 0, "{stats:?}");
        let mut exact = vec![None; cloth.len()];
        certifier.exact_each(&proximity, &cloth, |k, hit| exact[k] = hit);
        for ((p, o), e) in cloth.iter().zip(&outcomes).zip(&exact) {
            let e = e.expect("an answer");
            match o.expect("an outcome") {
                Outcome::Certified => assert!(
                    e.signed_distance_m >= margin,
                    "certified at {p:?}, exposed surface's answer {e:?}"
                ),
                Outcome::Exact(c) => {
                    assert_eq!((c.face, c.signed_distance_m), (e.face, e.signed_distance_m))
                }
            }
        }
        assert!(stats.swept > 100 && stats.exact > 1_000, "{stats:?}");
    }

    #[test]
    fn the_axis_rays_find_the_faces_inside_other_boxes_as_the_normal_rays_do() {
        // Twelve boxes, each turned off the axes, overlapping in a 20 cm cube. A face's start
        // point lies inside as many boxes as the ray's winding number counts (each box is
        // closed and convex, and the start point is in front of its own box), so a face is
        // buried exactly when its start point lies in another box: read off the box itself.
        // The rays along the faces' normals (every face tested) agree.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut next = move || rng.random::<f64>();
        let (mut v, mut f) = (Vec::new(), Vec::new());
        let mut boxes = Vec::new();
        for _ in 0..12 {
            let half = Vector3::new(
                0.02 + 0.05 * next(),
                0.01 + 0.03 * next(),
                0.02 + 0.04 * next(),
            );
            let axis = Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
            let turn = nalgebra::Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(axis),
                0.3 + 1.2 * next(),
            );
            let centre = Vector3::new(next(), next(), next()) * 0.2;
            let start = v.len();
            cuboid((-half).into(), half.into(), &mut v, &mut f);
            for p in &mut v[start..] {
                *p = turn * *p + centre;
            }
            boxes.push((turn, centre, half));
        }
        let mut certifier = Certifier::new(&v, &f, &[Vector3::zeros()], true);
        certifier.update(&v);
        let frame = certifier.frame();
        let (mut n_buried, mut unclear) = (0, 0);
        for (i, t) in f.iter().enumerate() {
            let own = i / 12;
            let [a, b, c] = t.map(|k| v[k as usize]);
            let n = (b - a).cross(&(c - a)).normalize();
            let o = (a + b + c) / 3.0 + n * f64::from(BURIED_START_M);
            // Inside another box, with the distance to its nearest side.
            let depth =
                |(turn, centre, half): &(nalgebra::Rotation3<f64>, Vector3<f64>, Vector3<f64>)| {
                    let local = turn.inverse() * (o - centre);
                    (0..3)
                        .map(|k| half[k] - local[k].abs())
                        .fold(f64::INFINITY, f64::min)
                };
            let depths: Vec<f64> = boxes
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != own)
                .map(|(_, b)| depth(b))
                .collect();
            if depths.iter().any(|d| d.abs() < 1e-5) {
                unclear += 1;
                continue;
            }
            let expected = depths.iter().any(|&d| d > 0.0);
            assert_eq!(frame.buried[i], expected, "face {i}");
            // The normal ray, from the f32 start point the axis ray used.
            let [ra, rb, rc] = t.map(|k| frame.rel[k as usize]);
            let rn = cross(sub(rb, ra), sub(rc, ra));
            let rn = rn.map(|x| x / dot(rn, rn).sqrt());
            let ro = [0, 1, 2].map(|k| frame.data.centroid[i][k] + rn[k] * BURIED_START_M);
            let along_normal = frame.ray_winding(ro, rn, i as u32) > 0;
            assert_eq!(along_normal, expected, "face {i} along its normal");
            n_buried += usize::from(expected);
        }
        assert!(
            n_buried > 20 && unclear < 5,
            "{n_buried} buried, {unclear} unclear"
        );
    }

    #[test]
    fn a_face_deep_inside_a_long_part_is_buried_whatever_the_way_out() {
        // Part A, a limb 1.2 m long; part B, a small box inside it near one end. The rays of
        // B's +x side run 1.05 m inside A before they leave it.
        let (mut v, mut f) = (Vec::new(), Vec::new());
        cuboid([0.0, 0.0, 0.0], [1.2, 0.1, 0.1], &mut v, &mut f);
        let n_a = f.len();
        cuboid([0.05, 0.03, 0.03], [0.15, 0.07, 0.07], &mut v, &mut f);
        let mut certifier = Certifier::new(&v, &f, &[Vector3::zeros()], true);
        certifier.update(&v);
        let frame = certifier.frame();
        assert!(
            frame.buried[..n_a].iter().all(|&b| !b),
            "A's faces are exposed"
        );
        assert!(
            frame.buried[n_a..].iter().all(|&b| b),
            "every face of B is in A"
        );
        assert_eq!(frame.n_buried, f.len() - n_a);
    }

    #[test]
    fn a_cut_region_is_closed_for_the_ray_tests_and_the_way_out_is_checked() {
        // Part A, a 6 cm box open at x = 0 (its −x side removed: the region's cut); part B sunk
        // 3 cm into its +x side.
        let (mut v, mut f) = (Vec::new(), Vec::new());
        cuboid([0.0, 0.0, 0.0], [0.06, 0.06, 0.06], &mut v, &mut f);
        let centroid = |v: &[Vector3<f64>], t: &[u32; 3]| {
            t.iter().map(|&i| v[i as usize]).sum::<Vector3<f64>>() / 3.0
        };
        f.retain(|t| centroid(&v, t).x > 1e-9);
        assert_eq!(f.len(), 10);
        cuboid([0.03, 0.01, 0.01], [0.10, 0.05, 0.05], &mut v, &mut f);
        let mut certifier = Certifier::new(&v, &f, &[Vector3::zeros()], true);
        certifier.update(&v);
        let frame = certifier.frame();
        // B's −x side faces A's cut: its rays leave through the cap.
        let minus_x: Vec<usize> = (10..f.len())
            .filter(|&i| (centroid(&v, &f[i]).x - 0.03).abs() < 1e-9)
            .collect();
        assert_eq!(minus_x.len(), 2);
        assert!(minus_x.iter().all(|&i| frame.buried[i]));
        // Every point of A or B, pushed by its answer, lands outside both.
        let proximity = MeshProximity::new(&v, &f).expect("mesh");
        let margin = 0.002;
        let in_box = |p: &Vector3<f64>, lo: [f64; 3], hi: [f64; 3]| {
            (0..3).all(|k| p[k] > lo[k] && p[k] < hi[k])
        };
        let (a, b) = (
            ([0.0; 3], [0.06; 3]),
            ([0.03, 0.01, 0.01], [0.10, 0.05, 0.05]),
        );
        let mut tested = 0;
        for i in 0..12 {
            for j in 0..6 {
                for k in 0..6 {
                    let q = Vector3::new(
                        0.036 + 0.005 * i as f64,
                        0.012 + 0.007 * j as f64,
                        0.012 + 0.007 * k as f64,
                    );
                    if !(in_box(&q, a.0, a.1) || in_box(&q, b.0, b.1)) {
                        continue;
                    }
                    tested += 1;
                    let c = answer(&mut certifier, &proximity, &q);
                    let landed = q + c.normal * (margin - c.signed_distance_m);
                    assert!(
                        !in_box(&landed, a.0, a.1) && !in_box(&landed, b.0, b.1),
                        "{q:?} lands at {landed:?} ({c:?})"
                    );
                }
            }
        }
        assert!(tested > 300, "{tested}");
    }
}
