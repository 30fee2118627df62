//! The collision post-process of Santesteban et al. 2019: a cloth vertex inside the body, or
//! closer to it than a margin (2 mm in the paper), is pushed along the normal of the closest
//! body primitive until it lies at the margin (20 µm beyond it: `PUSH_BEYOND_M`):
//! `p ← p + (margin + 20 µm − d) n`, with `d` the signed distance and `n` the angle-weighted
//! pseudo-normal of the closest face, edge or vertex
//! ([`sartor_core::MeshProximity`], the one closest-point query of the workspace).
//!
//! Only the body region the garment can touch is used ([`BodyRegion`]): its vertices are the
//! only body vertices skinned per frame, and the query structure is built over its faces only.
//!
//! # Finding the closest body primitive ([`CollisionQuery`])
//!
//! - [`CollisionQuery::Bvh`] (the default, exact with an infinite radius): a bounding-volume
//!   hierarchy over the region, refitted every frame. Each cloth vertex starts its search from
//!   the distance to the face it was closest to in its previous query (temporal coherence: the
//!   same answer, less work).
//! - [`CollisionQuery::BvhBand`]: exact within a band around the surface, a sign test against
//!   the last closest face outside it, an exact query per vertex every few frames.
//! - [`CollisionQuery::Candidates`]: when the shape is set, each cloth vertex (at `T̄_c + Δ_G`)
//!   keeps the region faces within `radius_m` of it on the shaped body `T_b(β)` in rest pose;
//!   per frame only those are tested. Exact only while each vertex stays near the body part it
//!   was near at rest: it misses the collisions that matter most — a sleeve pressed into the
//!   torso when the arm comes down — because the other part's faces were never candidates.
//! - [`CollisionQuery::GuardedCandidates`]: the candidates, plus a per-part bounding-box guard
//!   that sends a vertex to the exact BVH query whenever a body part none of its candidates
//!   belongs to comes within the margin.
//!
//! # Body parts that interpenetrate
//!
//! A posed body sinks into itself where parts press together (an arm into the side of a heavy
//! torso, at shapes beyond the training range). There the closest region face of a cloth
//! vertex inside one part can be a face of the other part buried in it, whose pseudo-normal
//! reads the vertex as outside: the BVH query never pushes it. The certified query, the
//! default, finds the buried faces each frame (by default only beyond the training shapes:
//! [`Interpenetration`]) (a ray along each face's normal, counted by the
//! winding number along it) and answers from the exposed surface only; a vertex whose closest
//! exposed face touches a buried one ("crease") is checked by the same ray test (three rays,
//! with the region's cuts capped) and, inside, pushed out through the nearest exposed face
//! within 8 cm whose far side the ray test reads as outside: a push along the crease's
//! pseudo-normal often ends in the other part. A body part outside the region (a hand sunk into
//! the belly) stays invisible to the post-process.
//!
//! `cargo xtask bench runtime` compares them on the 8,710-triangle T-shirt walking
//! (`docs/reports/bench-runtime.json`: int8 network, one thread, CPU time, the 2-core Intel Xeon
//! VM; "inside" counts cloth vertex-frames left inside the body, of 533,640, 16,179 before the
//! post-process). Post-process cost per frame and inside after: certified (the default) 5.6 ms,
//! 0, the same garment as the exact BVH's vertex for vertex; exact BVH 11.0 ms, 0; guarded
//! candidates (2 cm, 8) 10.9 ms, 92; band (5 mm, refresh 16) 8.3 ms, 2,692; plain candidates
//! (2 cm, 8) 4.2 ms, 16,179 (none pushed out). Posing and refitting the region alone costs
//! 1.8 ms there. A run minutes earlier measured 4.8 and 11.2 ms for the first two: this machine
//! is noisy. The approximate queries are there for levels of detail that trade contact accuracy
//! for time; on this garment none of them beats the certified query.

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{BodyModel, BoneTransform, MeshProximity, Parallelism, SkinWeights, skin_points};

use crate::error::{Error, Result};

mod certify;

pub use certify::CertifyStats;
use certify::{Certifier, Later, Outcome};

/// Distance kept between cloth and body, metres: the paper's 2 mm.
pub const DEFAULT_MARGIN_M: f64 = 0.002;

/// A later pass pushes a vertex again only when it lies more than this inside the margin,
/// metres. When a push took a vertex exactly to the margin, storing it in f32 left it a little
/// short (3 nm typically on the shipped model's walk), and without the slack about half the
/// pushed vertices were pushed again in every later pass, by that much. A push now lands
/// [`PUSH_BEYOND_M`] beyond the margin; the slack still keeps a vertex that another face's push
/// leaves a rounding short from a push of nanometres.
const REPUSH_SLACK_M: f64 = 1e-6;

/// A push takes a vertex this far beyond the margin, metres: twice the certified query's f32
/// guard, so that a later pass's sweep proves a pushed vertex beyond the margin from the face it
/// was pushed off, as the first pass proves most vertices. A vertex left exactly at the margin
/// had to be searched with a list in every later pass (no f32 bound proves a point at the margin
/// beyond it). On the shipped model's walk and the held-out clips at both garment resolutions
/// the later passes now sweep 91–97 % of their vertices instead of none; the post-process
/// measured 8–10 % faster (`cargo bench --bench postprocess`, eight alternating rounds, 8 of 8
/// faster). 20 µm is 1 % of the paper's 2 mm margin.
const PUSH_BEYOND_M: f64 = 2e-5;

/// [`CollisionOptions::faces`] leaves a triangle whose centroid is deeper than this inside the
/// body as the vertex passes left it, metres. Skin between cloth vertices sits shallow (the
/// sagitta of a body curve over a cloth edge: a few millimetres); a centroid deeper in lies
/// between body parts pressed together (an arm against the torso), where pushing the whole
/// triangle along one part's normal tore the sleeve into spikes.
const FACE_DEPTH_M: f64 = 0.005;

/// [`CollisionOptions::faces`] moves a triangle whose centroid lies closer to the body than this
/// fraction of the margin (or inside it, not deeper than [`FACE_DEPTH_M`]), until the centroid is
/// at the margin. Cloth that the vertex passes leave at the margin over a convex body sags
/// towards it between its vertices (the sagitta of a cloth edge over the body's curve, a few
/// tenths of a millimetre), so most centroids near the body lie a little inside the margin, not
/// in the body. On the try-on page's heavy 1.90 m body dancing CMU 05_06 (`cargo bench -p
/// sartor-runtime --bench postprocess -- certified-heavy-cmu-faces`, a throwaway count) 1,110
/// centroids a frame were answered exactly with the trigger at the margin and 1,083 pushed, 890
/// of them lying between 1 and 2 mm out and 65 inside (on the shipped model's walk 463 answered,
/// 412 between 1 and 2 mm). Pushing those by under a millimetre did nothing the pass is for: with
/// the trigger at half the margin `sartor demo` (its defaults: the strain limit, the limbs held)
/// over the whole of CMU 05_06, 05_10, 02_02 and 06_06 on the 1.75 m and the heavy 1.90 m male
/// at 4,210 triangles, and of 05_06, 05_10 and 02_02 on the heavy male and the light 1.60 m
/// female at 8,710, left the vertices inside the body within two vertex-frames of the whole
/// margin's in every run and the triangles inside within 0.0005 percentage points, the longest
/// edges the same or shorter, and the frame took 3–9 % less (`ms_per_frame`, the mean of two
/// rounds of the two builds in turn, Intel Xeon VM, 2026-12-06). A quarter of the margin read
/// the same. Pushing the triangles only to the trigger, not to the margin, left more inside (the
/// 1.75 m body's 05_06: 0.334 → 0.342 % of triangle-frames at half the margin, 0.476 % at the
/// body's surface). The page's own frames gained less: see the README ("Limits").
const FACE_TRIGGER: f64 = 0.5;

/// How the closest body primitive of each cloth vertex is found (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CollisionQuery {
    /// Exact, and the default: the same pushes as [`CollisionQuery::EXACT_BVH`], with most
    /// cloth vertices proven to need none by a test on the faces near them; the others get the
    /// exact closest point from those faces, found by a search of a tree of the region's faces
    /// per vertex (see the module docs). Under [`Parallelism::Rayon`] the first pass splits the
    /// vertices over the threads (the same pushes: each vertex's answer is its own), and so do
    /// the later passes where they move 64 vertices or more; the region's face data and tree
    /// are built on one thread. Where body
    /// parts interpenetrate it also leaves out the
    /// faces buried inside another part, and takes a vertex that lies inside a part out of it
    /// (see the module docs): there it pushes more than the BVH query.
    Certified,
    /// A BVH over the body region, refitted per frame: the exact closest point among the
    /// region points within `radius_m` ([`f64::INFINITY`]: everywhere). A vertex with no body
    /// point within the radius is left alone: it is either farther out than the radius or deeper
    /// inside than it.
    Bvh {
        /// Search radius, metres.
        radius_m: f64,
    },
    /// The BVH, exact within a band around the body surface, and a sign test outside it: a
    /// vertex with a body point within `band_m` gets the exact answer; one without is taken to be
    /// outside unless it lies behind the face it was last closest to (then it gets the exact
    /// query). Every `refresh_every` frames each vertex gets the exact query (in turns), which
    /// refreshes its last face. Misses only a vertex that passes deeper than the band into a body
    /// part other than its last closest one within one frame, until its next refresh.
    BvhBand {
        /// Width of the exact band, metres.
        band_m: f64,
        /// Frames between two exact queries of one vertex (at least 1).
        refresh_every: usize,
    },
    /// [`CollisionQuery::Candidates`] guarded by body parts: the region's faces are grouped by
    /// the joint that moves them most; per frame each part gets a bounding box, and a vertex gets
    /// the exact BVH query when the box of a part none of its candidates belongs to comes within
    /// the margin (another body part may touch it: the sleeve and the torso). Otherwise its
    /// candidates answer: they cover its own parts, whose faces move with it.
    GuardedCandidates {
        /// Faces within this distance of the vertex at rest are candidates, metres.
        radius_m: f64,
        /// At most this many candidates per vertex, nearest first.
        max_per_vertex: usize,
    },
    /// Per cloth vertex, the region faces near it at rest (chosen when the shape is set).
    Candidates {
        /// Faces within this distance of the vertex at rest are candidates, metres.
        radius_m: f64,
        /// At most this many candidates per vertex, nearest first.
        max_per_vertex: usize,
    },
}

impl CollisionQuery {
    /// The BVH searching everywhere: exact (the default).
    pub const EXACT_BVH: Self = Self::Bvh {
        radius_m: f64::INFINITY,
    };

    /// `(radius_m, max_per_vertex)` of the two candidate queries.
    fn candidates(&self) -> Option<(f64, usize)> {
        match *self {
            Self::Candidates {
                radius_m,
                max_per_vertex,
            }
            | Self::GuardedCandidates {
                radius_m,
                max_per_vertex,
            } => Some((radius_m, max_per_vertex)),
            Self::Certified | Self::Bvh { .. } | Self::BvhBand { .. } => None,
        }
    }

    /// Candidate faces within 2 cm of each vertex at rest, at most 8 (see the module docs for
    /// what it misses).
    pub const DEFAULT_CANDIDATES: Self = Self::Candidates {
        radius_m: 0.02,
        max_per_vertex: 8,
    };
}

/// Options of the collision post-process.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionOptions {
    /// Cloth vertices closer to the body than this (or inside it) are pushed out to it, metres.
    pub margin_m: f64,
    /// How the closest body primitive is found.
    pub query: CollisionQuery,
    /// Passes (the paper makes one). A vertex pushed out of one body part can land in another
    /// where two parts nearly touch or interpenetrate (armpit, between the legs); each further
    /// pass re-checks only the vertices the previous pass moved, and pushes them onto the
    /// line where the planes of both pushes meet. Only a vertex between two parts that
    /// face each other and overlap has no valid place nearby and may stay inside one of them.
    /// `0` poses the region but pushes nothing: for reports that count collisions before the
    /// post-process ([`crate::GarmentAnimator::collision_count`]).
    pub passes: usize,
    /// When the certified query looks for body parts sunk into each other (see the module
    /// docs); the other queries never do.
    pub interpenetration: Interpenetration,
    /// Also push out the cloth triangles' centroids. The vertex passes leave every vertex
    /// outside, but where the body is curved more tightly than the cloth is fine (a shoulder
    /// under a raised arm) skin pokes through a triangle between them; this pass queries each
    /// triangle's centroid after the vertex passes and moves a triangle whose centroid is
    /// inside the body or closer than half the margin out by the centroid's push to the margin
    /// (each vertex by the largest push of its triangles), then re-checks the moved vertices as
    /// a later pass does. Off by default: it triples the queries.
    pub faces: bool,
}

/// When the certified query finds the region faces buried inside another body part each frame
/// and answers from the exposed surface (see the module docs). The test costs a ray per region
/// face per frame: at the shipped model's size, more than the rest of the post-process.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Interpenetration {
    /// Never: the paper's post-process.
    Ignore,
    /// When the avatar's shape lies outside the model's training shapes (a model that records
    /// none counts as within), where heavy bodies sink an arm or a hand into the torso; within
    /// them the body is taken to keep its parts apart.
    #[default]
    BeyondTrainingShapes,
    /// At every shape (the armpit of a walking body at the mean shape sinks a little too).
    Always,
}

impl Default for CollisionOptions {
    /// 2 mm, the certified query (exact), 4 passes, interpenetration handled beyond the
    /// training shapes.
    fn default() -> Self {
        Self {
            margin_m: DEFAULT_MARGIN_M,
            query: CollisionQuery::Certified,
            passes: 4,
            interpenetration: Interpenetration::default(),
            faces: false,
        }
    }
}

impl CollisionOptions {
    pub(crate) fn validate(&self) -> Result<()> {
        if !(self.margin_m.is_finite() && self.margin_m >= 0.0) {
            return Err(Error::invalid(
                "collision options",
                format!("margin must be finite and ≥ 0, got {}", self.margin_m),
            ));
        }
        if let CollisionQuery::BvhBand {
            band_m,
            refresh_every,
        } = self.query
            && !(band_m.is_finite() && band_m >= 0.0 && refresh_every > 0)
        {
            return Err(Error::invalid(
                "collision options",
                format!(
                    "the band must be finite and ≥ 0 and the refresh at least 1 frame, got \
                     {band_m} m and {refresh_every}"
                ),
            ));
        }
        if let CollisionQuery::Bvh { radius_m } = self.query
            && (radius_m.is_nan() || radius_m <= 0.0)
        {
            return Err(Error::invalid(
                "collision options",
                format!("the BVH search radius must be positive, got {radius_m}"),
            ));
        }
        if let Some((radius_m, max_per_vertex)) = self.query.candidates()
            && !(radius_m.is_finite() && radius_m > 0.0 && max_per_vertex > 0)
        {
            return Err(Error::invalid(
                "collision options",
                format!(
                    "candidates need a finite positive radius and at least one face per vertex, \
                     got {radius_m} m and {max_per_vertex}"
                ),
            ));
        }
        Ok(())
    }
}

/// The body region a garment can touch, as a mesh of its own: the body vertices its faces use
/// (ascending), the faces re-indexed into them, and those vertices' skin weights.
#[derive(Clone, Debug)]
pub struct BodyRegion {
    vertices: Vec<u32>,
    faces: Vec<[u32; 3]>,
    skin_weights: SkinWeights,
    /// Per face, its body part (0..64): the joint with the largest summed weight over its
    /// vertices, numbered in order of first appearance. `None` when the region spans more than
    /// 64 parts (the guarded query then always searches the tree).
    face_parts: Option<Vec<u8>>,
    n_parts: usize,
}

impl BodyRegion {
    /// Extract `region_faces` (indices into the body's faces) from `body`.
    pub fn new(body: &BodyModel, region_faces: &[u32]) -> Result<Self> {
        let body_faces = body.faces();
        let mut index = vec![u32::MAX; body.n_vertices()];
        let mut vertices = Vec::new();
        for &f in region_faces {
            let t = body_faces.get(f as usize).ok_or_else(|| {
                Error::invalid(
                    "body region",
                    format!("face {f} is past the body's {} faces", body_faces.len()),
                )
            })?;
            for &v in t {
                index[v as usize] = 0;
            }
        }
        for (v, slot) in index.iter_mut().enumerate() {
            if *slot == 0 {
                *slot = vertices.len() as u32;
                vertices.push(v as u32);
            }
        }
        let faces: Vec<[u32; 3]> = region_faces
            .iter()
            .map(|&f| body_faces[f as usize].map(|v| index[v as usize]))
            .collect();
        let (offsets, joints, weights) = body.skin_weights().csr();
        let mut sub_offsets = Vec::with_capacity(vertices.len() + 1);
        sub_offsets.push(0u32);
        let (mut sub_joints, mut sub_weights) = (Vec::new(), Vec::new());
        for &v in &vertices {
            let (a, b) = (
                offsets[v as usize] as usize,
                offsets[v as usize + 1] as usize,
            );
            sub_joints.extend_from_slice(&joints[a..b]);
            sub_weights.extend_from_slice(&weights[a..b]);
            sub_offsets.push(sub_joints.len() as u32);
        }
        let skin_weights = SkinWeights::new(
            sub_offsets,
            sub_joints,
            sub_weights,
            body.skin_weights().n_joints(),
        )?;
        let (face_parts, n_parts) = Self::parts(&faces, &skin_weights);
        Ok(Self {
            vertices,
            faces,
            skin_weights,
            face_parts,
            n_parts,
        })
    }

    /// Group the faces by dominant joint (see [`BodyRegion`]'s `face_parts`).
    fn parts(faces: &[[u32; 3]], weights: &SkinWeights) -> (Option<Vec<u8>>, usize) {
        let mut part_of_joint = vec![u8::MAX; weights.n_joints()];
        let mut n_parts = 0usize;
        let mut face_parts = Vec::with_capacity(faces.len());
        for joint in weights.face_dominant_joints(faces) {
            if part_of_joint[joint] == u8::MAX {
                if n_parts == 64 {
                    return (None, 0);
                }
                part_of_joint[joint] = n_parts as u8;
                n_parts += 1;
            }
            face_parts.push(part_of_joint[joint]);
        }
        (Some(face_parts), n_parts)
    }

    /// Body vertex index of each region vertex, ascending.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// Region faces, indexing [`BodyRegion::vertices`].
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
}

/// Per-avatar collision state: the region at the avatar's shape, its posed copy and the query
/// structure (and the candidate lists, for [`CollisionQuery::Candidates`]).
#[derive(Clone, Debug)]
pub(crate) struct Collider {
    margin_m: f64,
    passes: usize,
    /// Per cloth vertex: the pass state and the last closest face.
    vertices: Vec<VertexState>,
    rest: Vec<Vector3<f64>>,
    posed: Vec<Vector3<f64>>,
    proximity: MeshProximity,
    /// BVH search radius (unused by the candidate query).
    radius_m: f64,
    query: CollisionQuery,
    /// Frames posed so far (turns of the band query's refresh).
    frame: usize,
    /// Per cloth vertex, the parts of its candidate faces (bit `g`: part `g`).
    own_parts: Vec<u64>,
    /// Per body part, the box of its posed faces (`min`, `max`); empty unless guarded.
    part_boxes: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// CSR candidate faces per cloth vertex (empty for the BVH query).
    offsets: Vec<u32>,
    candidates: Vec<u32>,
    /// The certified query's state (`None` for the other queries).
    certifier: Option<Certifier>,
    /// What the certified query did in the last frame.
    stats: CertifyStats,
    /// A later pass's moved vertices, their positions and warm faces (scratch).
    moved: Vec<u32>,
    moved_points: Vec<Vector3<f32>>,
    moved_warm: Vec<u32>,
    /// The certified query's: the vertices whose state a pass of this frame may have set
    /// (moved, or a plane; duplicates allowed); every other vertex's state is clear, so the
    /// passes touch only these and the vertices answered exactly.
    dirty: Vec<u32>,
    /// [`CollisionOptions::faces`], and its scratch: per cloth vertex the largest push of its
    /// triangles.
    faces: bool,
    face_push: Vec<Vector3<f64>>,
}

/// What the post-process remembers of a cloth vertex.
#[derive(Clone, Copy, Debug)]
struct VertexState {
    /// Moved by the current pass.
    moved: bool,
    /// The closest region face found last (`u32::MAX`: none yet). The BVH query starts from
    /// the distance to it, which prunes most of the tree at once (temporal coherence; the
    /// answer is the same as without it).
    last_face: u32,
    /// The plane this frame's last push put the vertex on (`n·x = b`, `n` the outward normal),
    /// to keep while a later pass pushes it out of another body part.
    plane: Option<(Vector3<f64>, f64)>,
}

impl Default for VertexState {
    fn default() -> Self {
        Self {
            moved: false,
            last_face: u32::MAX,
            plane: None,
        }
    }
}

/// [`push`] takes a vertex to the crease of two planes only when the point on both planes is
/// at most this many times the longer of the two pushes away; farther (planes near parallel),
/// it goes as for parallel planes. Until 2026-12-05 only planes within 0.57° of parallel did:
/// two nearly facing parts (an arm against the torso, normals 178° apart, on CMU 05_10) sent a
/// vertex 3.6 mm inside one of them 90 mm along their crease, and one 66 mm inside 292 mm
/// (normals 167° apart): spikes 30 times their edges' rest length.
const CREASE_REACH: f64 = 4.0;

/// Where a push takes `q`: onto the plane `n·x = b` of the body part it is inside or too close
/// to (`n` unit). When an earlier pass of the same frame pushed it out of another part (to the
/// plane `earlier`) and this push would take it back behind that plane, it goes to the nearest
/// point on both planes instead: the crease where the two parts meet. One pass then settles a
/// vertex squeezed between two interpenetrating parts (armpit, crotch) that alternate pushes
/// between them would move only a little per pass. A crease farther than [`CREASE_REACH`] times
/// the pushes (planes near parallel) is not gone to: the vertex goes halfway between two facing
/// planes, or onto the farther of two facing the same way.
fn push(
    q: &Vector3<f64>,
    n: &Vector3<f64>,
    b: f64,
    earlier: Option<(Vector3<f64>, f64)>,
) -> Vector3<f64> {
    let single = q + n * (b - n.dot(q));
    let Some((m, c)) = earlier else {
        return single;
    };
    if m.dot(&single) >= c {
        return single;
    }
    let cos = n.dot(&m);
    let det = 1.0 - cos * cos;
    let (rn, rm) = (b - n.dot(q), c - m.dot(q));
    if det >= 1e-4 {
        let crease = n * ((rn - cos * rm) / det) + m * ((rm - cos * rn) / det);
        if crease.norm() <= CREASE_REACH * rn.abs().max(rm.abs()) {
            return q + crease;
        }
    }
    // Planes (near) parallel: their crease is far away. Facing each other (a gap narrower than
    // twice the margin), the vertex goes halfway, as far from one part as from the other, which
    // is outside both where they do not overlap; facing the same way, the farther plane holds
    // both.
    let t = if cos < 0.0 {
        (rn - rm) / (1.0 - cos)
    } else {
        rn.max(rm / cos)
    };
    q + n * t
}

/// Where a push takes `q`, whose closest body point is `c`: [`PUSH_BEYOND_M`] beyond the margin
/// along `c`'s normal ([`push`], keeping the plane `earlier` of this frame's earlier push), and
/// the plane it lands on. Every pass and query pushes through here.
fn push_out(
    q: &Vector3<f64>,
    c: &sartor_core::ClosestPoint,
    margin_m: f64,
    earlier: Option<(Vector3<f64>, f64)>,
) -> (Vector3<f32>, (Vector3<f64>, f64)) {
    let b = c.normal.dot(q) + margin_m + PUSH_BEYOND_M - c.signed_distance_m;
    (push(q, &c.normal, b, earlier).cast::<f32>(), (c.normal, b))
}

/// Cloth vertices per parallel task.
const CHUNK: usize = 256;

impl Collider {
    /// Start from `old`'s warm faces (the closest region face of each cloth vertex, and the
    /// certified query's per vertex and triangle): `old` is the collider of another body shape
    /// of the same region and cloth. They only start the searches (the answers are those of a
    /// cold start), so the first frame on a new shape does not search every vertex from
    /// nothing.
    pub(crate) fn warm_from(&mut self, old: &Collider) {
        if old.vertices.len() != self.vertices.len() {
            return;
        }
        for (state, was) in self.vertices.iter_mut().zip(&old.vertices) {
            state.last_face = was.last_face;
        }
        if let (Some(new), Some(old)) = (&mut self.certifier, &old.certifier) {
            new.warm_from(old);
        }
    }

    /// Set up for a body of shape `shaped_body` (`T_b(β)`, every body vertex) and a garment whose
    /// unposed rest shape is `cloth_rest` (`T̄_c + Δ_G`); `beyond_training` says whether the
    /// shape lies outside the model's training shapes ([`Interpenetration`]).
    pub(crate) fn new(
        region: &BodyRegion,
        shaped_body: &[Vector3<f64>],
        cloth_rest: &[Vector3<f32>],
        options: &CollisionOptions,
        beyond_training: bool,
    ) -> Result<Self> {
        let rest: Vec<Vector3<f64>> = region
            .vertices
            .iter()
            .map(|&v| shaped_body[v as usize])
            .collect();
        let proximity = MeshProximity::new(&rest, &region.faces)?;
        let (mut offsets, mut candidates, mut own_parts) = (Vec::new(), Vec::new(), Vec::new());
        if let Some((radius_m, max_per_vertex)) = options.query.candidates() {
            offsets.reserve(cloth_rest.len() + 1);
            offsets.push(0u32);
            for p in cloth_rest {
                let near = proximity.faces_within(&p.cast::<f64>(), radius_m);
                let mine = &near[..near.len().min(max_per_vertex)];
                candidates.extend(mine.iter().map(|&(f, _)| f));
                offsets.push(candidates.len() as u32);
                if let Some(parts) = &region.face_parts {
                    own_parts.push(
                        mine.iter()
                            .fold(0u64, |m, &(f, _)| m | (1u64 << parts[f as usize])),
                    );
                }
            }
        }
        let guarded = matches!(options.query, CollisionQuery::GuardedCandidates { .. });
        let part_boxes = if guarded && region.face_parts.is_some() {
            vec![(Vector3::zeros(), Vector3::zeros()); region.n_parts]
        } else {
            Vec::new()
        };
        let radius_m = match options.query {
            CollisionQuery::Bvh { radius_m } => radius_m,
            _ => f64::INFINITY,
        };
        let certifier = (options.query == CollisionQuery::Certified).then(|| {
            let buried = match options.interpenetration {
                Interpenetration::Ignore => false,
                Interpenetration::BeyondTrainingShapes => beyond_training,
                Interpenetration::Always => true,
            };
            Certifier::new(&rest, &region.faces, cloth_rest, buried)
        });
        Ok(Self {
            margin_m: options.margin_m,
            passes: options.passes,
            radius_m,
            query: options.query,
            frame: 0,
            vertices: vec![VertexState::default(); cloth_rest.len()],
            posed: rest.clone(),
            rest,
            proximity,
            offsets,
            candidates,
            own_parts,
            part_boxes,
            certifier,
            stats: CertifyStats::default(),
            moved: Vec::with_capacity(cloth_rest.len()),
            moved_points: Vec::with_capacity(cloth_rest.len()),
            moved_warm: Vec::with_capacity(cloth_rest.len()),
            // At most every vertex pushed by the first pass and by the triangles' pass.
            dirty: Vec::with_capacity(2 * cloth_rest.len()),
            faces: options.faces,
            face_push: vec![Vector3::zeros(); cloth_rest.len()],
        })
    }

    /// What the certified query did in the last frame (zeros for the other queries).
    pub(crate) fn stats(&self) -> CertifyStats {
        self.stats
    }

    /// The margin, metres.
    pub(crate) fn margin_m(&self) -> f64 {
        self.margin_m
    }

    /// Candidate faces per cloth vertex on average (0 for the BVH query).
    pub(crate) fn mean_candidates(&self) -> f64 {
        if self.offsets.len() < 2 {
            return 0.0;
        }
        self.candidates.len() as f64 / (self.offsets.len() - 1) as f64
    }

    /// Pose the region with the body's skinning transforms and refit the query structure.
    /// Allocation-free.
    pub(crate) fn pose(
        &mut self,
        region: &BodyRegion,
        transforms: &[BoneTransform<f64>],
        par: Parallelism,
    ) -> Result<()> {
        skin_points(
            &self.rest,
            &region.skin_weights,
            transforms,
            &mut self.posed,
            par,
        )?;
        match &mut self.certifier {
            Some(certifier) => {
                // The certified query finds its candidate faces in its own search tree and asks
                // `closest_among` only: no refit of the proximity's tree, normals on demand.
                self.proximity.update_positions_lazy(&self.posed)?;
                certifier.update(&self.posed);
            }
            None => self.proximity.update_positions(&self.posed)?,
        }
        self.frame = self.frame.wrapping_add(1);
        if let (Some(parts), false) = (&region.face_parts, self.part_boxes.is_empty()) {
            self.part_boxes.fill((
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ));
            for (t, &g) in region.faces.iter().zip(parts) {
                let b = &mut self.part_boxes[g as usize];
                for &v in t {
                    b.0 = b.0.inf(&self.posed[v as usize]);
                    b.1 = b.1.sup(&self.posed[v as usize]);
                }
            }
        }
        Ok(())
    }

    /// The region as posed by the last [`Collider::pose`].
    pub(crate) fn posed(&self) -> &[Vector3<f64>] {
        &self.posed
    }

    /// Push every cloth vertex closer than the margin (or inside) out to the margin along the
    /// closest primitive's normal, in up to `passes` passes; returns the number of pushes (a
    /// vertex moved in two passes counts twice). With [`CollisionOptions::faces`], then the
    /// triangles `faces` of the cloth (see there).
    /// Allocation-free (after the first frame with the triangles pushed).
    pub(crate) fn resolve(
        &mut self,
        cloth: &mut [Vector3<f32>],
        faces: &[[u32; 3]],
        par: Parallelism,
    ) -> usize {
        let mut total = self.vertex_passes(true, cloth, par);
        if self.faces && self.passes > 0 {
            let moved = self.face_pass(cloth, faces, par);
            if moved > 0 {
                total += moved + self.vertex_passes(false, cloth, par);
            }
        }
        total
    }

    /// Up to `passes` passes, the first over every vertex when `first`, else only over those
    /// moved before; the number of pushes.
    fn vertex_passes(
        &mut self,
        first: bool,
        cloth: &mut [Vector3<f32>],
        par: Parallelism,
    ) -> usize {
        let mut total = 0;
        for pass in 0..self.passes {
            let moved = self.pass(first && pass == 0, cloth, par);
            total += moved;
            if moved == 0 {
                break;
            }
        }
        total
    }

    /// Push the triangles whose centroid is closer to the body than [`FACE_TRIGGER`] of the
    /// margin out to the margin (see [`CollisionOptions::faces`]); marks the vertices it moves
    /// and returns how many.
    fn face_pass(
        &mut self,
        cloth: &mut [Vector3<f32>],
        faces: &[[u32; 3]],
        par: Parallelism,
    ) -> usize {
        let (margin, trigger) = (self.margin_m, self.margin_m * FACE_TRIGGER);
        self.moved_points.clear();
        for t in faces {
            let c = t.iter().map(|&v| cloth[v as usize]).sum::<Vector3<f32>>() / 3.0;
            self.moved_points.push(c);
        }
        let push = &mut self.face_push;
        let mut visit = |k: usize, hit: Option<sartor_core::ClosestPoint>| {
            if let Some(c) = hit
                && c.signed_distance_m < trigger
                && c.signed_distance_m > -FACE_DEPTH_M
            {
                let d = c.normal * (margin - c.signed_distance_m);
                for &v in &faces[k] {
                    let slot = &mut push[v as usize];
                    if d.norm_squared() > slot.norm_squared() {
                        *slot = d;
                    }
                }
            }
        };
        match self.certifier.as_mut() {
            // Certified like the vertices, beyond the trigger: most centroids need no closest
            // point.
            Some(certifier) => {
                let limits = (trigger, FACE_DEPTH_M.max(trigger));
                certifier.run_points(&self.proximity, &self.moved_points, limits, par, |k, o| {
                    if let Some(Outcome::Exact(c)) = o {
                        visit(k, Some(c));
                    }
                });
            }
            None => {
                for (k, p) in self.moved_points.iter().enumerate() {
                    visit(k, Some(self.proximity.closest(&p.cast::<f64>())));
                }
            }
        }
        let mut moved = 0;
        for (i, ((p, state), d)) in cloth
            .iter_mut()
            .zip(&mut self.vertices)
            .zip(&mut self.face_push)
            .enumerate()
        {
            if *d != Vector3::zeros() {
                *p = (p.cast::<f64>() + *d).cast::<f32>();
                *d = Vector3::zeros();
                state.moved = true;
                state.plane = None;
                moved += 1;
                if self.certifier.is_some() {
                    self.dirty.push(i as u32);
                }
            }
        }
        moved
    }

    /// One pass over every vertex (`first`) or over those the previous pass moved; updates the
    /// flags and returns how many moved.
    fn pass(&mut self, first: bool, cloth: &mut [Vector3<f32>], par: Parallelism) -> usize {
        if self.certifier.is_some() {
            return if first {
                self.certified_pass(cloth, par)
            } else {
                self.certified_later_pass(cloth, par)
            };
        }
        let mut states = std::mem::take(&mut self.vertices);
        let this = &*self;
        let task = |start: usize, chunk: &mut [Vector3<f32>], states: &mut [VertexState]| {
            let mut pushed = 0;
            for (k, (p, state)) in chunk.iter_mut().zip(states.iter_mut()).enumerate() {
                if !(first || state.moved) {
                    continue;
                }
                state.moved = false;
                if first {
                    state.plane = None;
                }
                let q = p.cast::<f64>();
                let i = start + k;
                let hit = match this.query {
                    CollisionQuery::Certified | CollisionQuery::Bvh { .. } => {
                        this.closest_from(&q, state)
                    }
                    CollisionQuery::BvhBand {
                        band_m,
                        refresh_every,
                    } => {
                        let refresh = (i + this.frame).is_multiple_of(refresh_every);
                        this.closest_band(&q, state, band_m, refresh)
                    }
                    CollisionQuery::Candidates { .. } => this.closest_candidate(&q, i),
                    CollisionQuery::GuardedCandidates { .. } => {
                        if this.foreign_part_near(&q, i) {
                            this.closest_from(&q, state)
                        } else {
                            this.closest_candidate(&q, i)
                        }
                    }
                };
                let limit = if first {
                    this.margin_m
                } else {
                    this.margin_m - REPUSH_SLACK_M
                };
                if let Some(c) = hit
                    && c.signed_distance_m < limit
                {
                    let (to, plane) = push_out(&q, &c, this.margin_m, state.plane);
                    (*p, state.plane) = (to, Some(plane));
                    state.moved = true;
                    pushed += 1;
                }
            }
            pushed
        };
        let count = match par {
            Parallelism::Sequential => task(0, cloth, &mut states),
            Parallelism::Rayon => cloth
                .par_chunks_mut(CHUNK)
                .zip(states.par_chunks_mut(CHUNK))
                .enumerate()
                .map(|(c, (chunk, states))| task(c * CHUNK, chunk, states))
                .sum(),
        };
        self.vertices = states;
        count
    }

    /// The first pass of the certified query: every vertex certified or answered exactly (see
    /// `certify.rs`) from the unpushed cloth, then the pushes, as the BVH query's first pass
    /// makes them.
    fn certified_pass(&mut self, cloth: &mut [Vector3<f32>], par: Parallelism) -> usize {
        let Some(certifier) = self.certifier.as_mut() else {
            return 0;
        };
        self.stats = certifier.run(&self.proximity, cloth, self.margin_m, par);
        let margin = self.margin_m;
        let mut pushed = 0;
        let states = &mut self.vertices;
        // Last frame's states cleared: a certified vertex needs no push and is not visited.
        for &i in &self.dirty {
            let state = &mut states[i as usize];
            state.moved = false;
            state.plane = None;
        }
        self.dirty.clear();
        let dirty = &mut self.dirty;
        certifier.for_each_exact(|i, c| {
            let (p, state) = (&mut cloth[i], &mut states[i]);
            state.last_face = c.face;
            if c.signed_distance_m < margin {
                let q = p.cast::<f64>();
                let (to, plane) = push_out(&q, c, margin, None);
                (*p, state.plane) = (to, Some(plane));
                state.moved = true;
                dirty.push(i as u32);
                pushed += 1;
            }
        });
        pushed
    }

    /// A later pass of the certified query: the exact answer for each vertex the previous pass
    /// moved (all at once: see `certify.rs`), pushed as the BVH query's later passes push.
    fn certified_later_pass(&mut self, cloth: &mut [Vector3<f32>], par: Parallelism) -> usize {
        let Some(certifier) = self.certifier.as_mut() else {
            return 0;
        };
        let margin = self.margin_m;
        let (moved, points, warm) = (
            &mut self.moved,
            &mut self.moved_points,
            &mut self.moved_warm,
        );
        moved.clear();
        points.clear();
        warm.clear();
        // Only a dirty vertex can have moved; in vertex order, once each.
        self.dirty.sort_unstable();
        self.dirty.dedup();
        for &i in &self.dirty {
            let state = &mut self.vertices[i as usize];
            if state.moved {
                state.moved = false;
                moved.push(i);
                points.push(cloth[i as usize]);
                warm.push(state.last_face);
            }
        }
        let mut pushed = 0;
        let states = &mut self.vertices;
        let beyond = margin - REPUSH_SLACK_M;
        certifier.later_points(&self.proximity, points, warm, beyond, par, |k, hit| {
            let i = moved[k] as usize;
            let (p, state) = (&mut cloth[i], &mut states[i]);
            let c = match hit {
                None => return,
                // Not inside the margin by more than the slack: not pushed again.
                Some(Later::Beyond { face }) => {
                    state.last_face = face;
                    return;
                }
                Some(Later::Exact(c)) => c,
            };
            state.last_face = c.face;
            if c.signed_distance_m < margin - REPUSH_SLACK_M {
                let q = p.cast::<f64>();
                let (to, plane) = push_out(&q, &c, margin, state.plane);
                (*p, state.plane) = (to, Some(plane));
                state.moved = true;
                pushed += 1;
            }
        });
        pushed
    }

    /// The BVH query within the search radius, started from the distance to the vertex's last
    /// closest face (no face is closer than the answer, so the bound changes nothing but the
    /// work); remembers the face found.
    fn closest_from(
        &self,
        q: &Vector3<f64>,
        state: &mut VertexState,
    ) -> Option<sartor_core::ClosestPoint> {
        let mut bound = self.radius_m;
        if state.last_face != u32::MAX
            && let Some(c) = self.proximity.closest_among(q, &[state.last_face])
        {
            // Slightly above the distance, so that the face itself passes the bound test.
            bound = bound.min(c.signed_distance_m.abs() * (1.0 + 1e-9) + 1e-12);
        }
        let hit = self.proximity.closest_within(q, bound);
        if let Some(c) = &hit {
            state.last_face = c.face;
        }
        hit
    }

    /// The closest point among cloth vertex `i`'s candidate faces.
    fn closest_candidate(&self, q: &Vector3<f64>, i: usize) -> Option<sartor_core::ClosestPoint> {
        let (a, b) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        self.proximity.closest_among(q, &self.candidates[a..b])
    }

    /// Whether the box of a body part that none of vertex `i`'s candidates belongs to is within
    /// the margin of `q` (always true without part boxes: the caller then searches the tree).
    fn foreign_part_near(&self, q: &Vector3<f64>, i: usize) -> bool {
        let Some(&own) = self.own_parts.get(i) else {
            return true;
        };
        if self.part_boxes.is_empty() {
            return true;
        }
        let m2 = self.margin_m * self.margin_m;
        self.part_boxes.iter().enumerate().any(|(g, (lo, hi))| {
            own & (1u64 << g) == 0 && {
                let d = (lo - q).sup(&(q - hi)).sup(&Vector3::zeros());
                d.norm_squared() <= m2
            }
        })
    }

    /// The [`CollisionQuery::BvhBand`] query (`refresh`: this vertex's turn for the exact one).
    fn closest_band(
        &self,
        q: &Vector3<f64>,
        state: &mut VertexState,
        band_m: f64,
        refresh: bool,
    ) -> Option<sartor_core::ClosestPoint> {
        if refresh || state.last_face == u32::MAX {
            return self.closest_from(q, state);
        }
        if let Some(c) = self.proximity.closest_within(q, band_m) {
            state.last_face = c.face;
            return Some(c);
        }
        let last = self.proximity.closest_among(q, &[state.last_face])?;
        if last.signed_distance_m < 0.0 {
            self.closest_from(q, state)
        } else {
            None
        }
    }

    /// `visit` the exact query's answer for each of `points` against the region as posed by
    /// the last [`Collider::pose`] (for reports; allocates scratch once per call).
    pub(crate) fn exact_each(
        &self,
        points: &[Vector3<f32>],
        mut visit: impl FnMut(&sartor_core::ClosestPoint),
    ) {
        match &self.certifier {
            Some(certifier) => certifier.exact_each(&self.proximity, points, |_, hit| {
                if let Some(c) = hit {
                    visit(&c);
                }
            }),
            None => {
                for p in points {
                    visit(&self.proximity.closest(&p.cast::<f64>()));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_push_keeps_the_plane_of_the_earlier_one() {
        let q = Vector3::new(-0.01, -0.02, 0.0);
        let x = Vector3::x();
        let y = Vector3::y();
        // Alone, a push goes straight to its plane.
        assert_eq!(push(&q, &x, 0.002, None), Vector3::new(0.002, -0.02, 0.0));
        // Inside two parts meeting at a right angle: to the corner of both planes.
        let corner = push(&q, &x, 0.002, Some((y, 0.002)));
        assert!(
            (corner - Vector3::new(0.002, 0.002, 0.0)).norm() < 1e-15,
            "{corner}"
        );
        // An earlier plane the push does not cross is left alone.
        let p = Vector3::new(-0.01, 0.05, 0.0);
        assert_eq!(
            push(&p, &x, 0.002, Some((y, 0.002))),
            Vector3::new(0.002, 0.05, 0.0)
        );
        // Facing planes 2 mm apart with a 2 mm margin: halfway, 1 mm from each.
        let gap = push(&Vector3::zeros(), &x, 0.002, Some((-x, -0.0)));
        assert!(
            (gap - Vector3::new(0.001, 0.0, 0.0)).norm() < 1e-15,
            "{gap}"
        );
        // Parallel planes facing the same way: the farther one.
        let far = push(&Vector3::zeros(), &x, 0.002, Some((x, 0.005)));
        assert!(
            (far - Vector3::new(0.005, 0.0, 0.0)).norm() < 1e-15,
            "{far}"
        );
    }
}
