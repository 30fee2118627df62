//! Self-collision candidates: vertex–triangle proximity by a dense uniform grid of the vertices.
//!
//! The vertices are binned into the cells of a grid over their bounding box (one cell each);
//! each triangle visits the cells its bounding box, inflated by the search radius, overlaps and
//! tests the vertices there. A pair counts when the vertex projects inside the triangle
//! (barycentric weights ≥ −1e-6, as ARCSim's `add_proximity`) within the search radius of its
//! plane, and the triangle does not touch the vertex or its one-ring (those are neighbours
//! through the surface, not contacts). As in ARCSim, each vertex keeps the closest triangle on
//! each side (the lowest-numbered one among equally close ones). Results are sorted by vertex and
//! side, independent of the thread count.
//!
//! The search is split in two. A *build* lists, per triangle, the vertices that could pass its
//! test in the next few substeps: those within its box inflated by the radius plus a skin
//! (half the radius), minus the triangle's corners and their one-rings. Every call then checks
//! only its lists, and the lists serve while no vertex has moved more than half the skin along
//! an axis since the build, not counting a move all vertices share ([`moves_within_skin`]):
//! then a vertex inside a triangle's test box now was inside its build box then. The pairs
//! found are exactly those a full search finds, and in the same order of triangles, so the
//! contacts are the same bits. A full search spent most of its work on the one-ring exclusion,
//! now done at the build only: about 7.6 vertices per triangle pass its box, 0.1 of them
//! outside its one-ring.
//!
//! Measured, one thread, the same cloth hashes, builds before and after alternated (`cargo
//! xtask bench sim --frames 10 --single-thread-only`): the lists took self-collision 72 → 29
//! ms per frame at 8,710 triangles and 20 → 7.4 at 4,210 (2-core Intel Xeon VM); not counting
//! the common move then cut the builds from 19.0 to 12.7 % of the substeps at 8,710 triangles
//! (4,210: 25.9 → 16.7 %; 26,066: 9.3 → 7.5 %) and self-collision 21 → 16 ms per frame there
//! (2-core AMD EPYC VM). `self_collision_builds_percent` in `bench-sim.json` reports the
//! builds.
//!
//! The build's grid: the cell is at least the mean edge and the diameter of the inflated reach,
//! and grows until the grid has at most four cells per vertex, so clearing and summing the
//! cells stays small. Binning the vertices rather than the triangles keeps the one serial part
//! small: a counting sort of one entry per vertex, with the positions copied in sorted order so
//! that a row of cells is one contiguous run. The triangles are the parallel part, in blocks of
//! [`FACE_BLOCK`], each block listing its triangles' candidates and, at every call, the pairs
//! it found; those few pairs are then merged in triangle order. It replaces a hash table of the
//! triangles' cells, whose serial counting sort of ~15 entries per triangle kept the search on
//! one core. A vertex outside a triangle's inflated box is dropped before the one-ring test:
//! first [`LANES`] vertices at a time in f32 (coordinates relative to the grid's corner,
//! rounded to nearest: a monotone map, so it drops only vertices the f64 box drops), then in
//! f64.

use std::ops::Range;

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{MeshTopology, Parallelism};

use crate::energy::SelfContact;

/// Scratch buffers of the grid, kept between steps.
#[derive(Debug, Default)]
pub(crate) struct SelfCollisionGrid {
    /// Per cell (x fastest), its vertices `sorted[start[c]..start[c + 1]]`, ascending.
    start: Vec<u32>,
    sorted: Vec<u32>,
    /// The vertices' positions in `sorted` order (one contiguous run per row of cells).
    sorted_x: Vec<Vector3<f64>>,
    /// The same relative to the grid's corner in f32, coordinate by coordinate, padded with
    /// [`LANES`] NaNs: the box test's first pass, [`LANES`] vertices at a time.
    sorted_f32: [Vec<f32>; 3],
    /// Per vertex, its cell.
    cell_of_vertex: Vec<u32>,
    /// Per block of [`FACE_BLOCK`] faces, the pairs it found, in face order.
    found: Vec<Vec<Found>>,
    /// Per block of [`FACE_BLOCK`] faces, its faces' candidate vertices (see [`Candidates`]).
    lists: Vec<Candidates>,
    /// The positions the lists were built at, and for what: vertex count, face count and
    /// address, radius (`None`: no lists yet).
    built_at: Vec<Vector3<f64>>,
    built_for: Option<(usize, usize, usize, f64)>,
    /// Per block, a stamp per vertex: `stamp[v] == f` marks the corners of face `f` and their
    /// one-rings while `f` searches. Kept between calls (a face marks the same set every time,
    /// so old marks never mislead).
    stamps: Vec<Vec<u32>>,
    closest: Vec<[Option<(u32, f64)>; 2]>,
}

/// A vertex–triangle pair within the radius: vertex, side (0: in front), face, |distance|.
#[derive(Clone, Copy, Debug)]
struct Found {
    vertex: u32,
    side: u8,
    face: u32,
    distance_m: f64,
}

/// One block's candidate lists: face `k` of the block has `vertices[offsets[k]..offsets[k + 1]]`,
/// ascending in the grid's sorted order, never a vertex of the face or its one-ring.
#[derive(Clone, Debug, Default)]
struct Candidates {
    offsets: Vec<u32>,
    vertices: Vec<u32>,
}

/// The skin, as a fraction of the radius: the lists hold every vertex within a face's test box
/// inflated by the skin, and serve until the vertices' moves since they were built span more
/// than the skin along an axis.
const SKIN_OVER_RADIUS: f64 = 0.5;

/// Vertices per step of the box test's f32 pass.
const LANES: usize = 8;

/// Faces per block of the parallel search.
const FACE_BLOCK: usize = 256;

/// The grid has at most this many cells per vertex (at least [`MIN_CELLS`]); the cell grows
/// until it fits, so that clearing and summing the cells stays small against the search.
const CELLS_PER_VERTEX: usize = 4;
const MIN_CELLS: usize = 4096;

/// Signed distance of `p` to the plane of `t` and whether its projection is inside `t`.
#[inline(always)]
fn vertex_triangle(p: &Vector3<f64>, t: &[Vector3<f64>; 3]) -> Option<f64> {
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    let n = e1.cross(&e2);
    let n2 = n.norm_squared();
    if n2 == 0.0 {
        return None;
    }
    let r = p - t[0];
    // Barycentric coordinates of the projection.
    let w1 = r.cross(&e2).dot(&n) / n2;
    let w2 = e1.cross(&r).dot(&n) / n2;
    let w0 = 1.0 - w1 - w2;
    (w0.min(w1).min(w2) >= -1e-6).then(|| r.dot(&n) / n2.sqrt())
}

/// The uniform grid over the vertices' box.
#[derive(Clone, Copy, Debug)]
struct Cells {
    origin: Vector3<f64>,
    inv_cell: f64,
    dims: [usize; 3],
}

impl Cells {
    /// The grid of cell edge `cell` (or larger, to stay within the cell budget) over `x`.
    fn new(x: &[Vector3<f64>], mut cell: f64) -> Self {
        let (mut lo, mut hi) = (x[0], x[0]);
        for p in x {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let budget = (CELLS_PER_VERTEX * x.len()).max(MIN_CELLS);
        loop {
            let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / cell).floor().max(0.0) as usize + 1);
            if dims[0].saturating_mul(dims[1]).saturating_mul(dims[2]) <= budget {
                return Self {
                    origin: lo,
                    inv_cell: 1.0 / cell,
                    dims,
                };
            }
            cell *= 1.25;
        }
    }

    fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// The cell coordinates of `p`, clamped to the grid.
    #[inline(always)]
    fn coords(&self, p: &Vector3<f64>) -> [usize; 3] {
        [0, 1, 2].map(|k| {
            // Clamped at 0 first, the cast's truncation is the floor (and NaN lands in cell 0).
            let c = ((p[k] - self.origin[k]) * self.inv_cell).max(0.0);
            (c as usize).min(self.dims[k] - 1)
        })
    }

    #[inline(always)]
    fn index(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }
}

/// The vertex grid and the mesh a block of faces searches.
struct Table<'a> {
    x: &'a [Vector3<f64>],
    faces: &'a [[u32; 3]],
    topology: &'a MeshTopology,
    cells: Cells,
    start: &'a [u32],
    sorted: &'a [u32],
    sorted_x: &'a [Vector3<f64>],
    sorted_f32: &'a [Vec<f32>; 3],
    radius_m: f64,
}

/// `v − origin` in f32, rounded to nearest. Both steps are monotone, so a point within a box
/// in f64 stays within the box's own image: the f32 test passes every vertex the f64 one does.
#[inline(always)]
fn relative(v: f64, origin: f64) -> f32 {
    (v - origin) as f32
}

/// The box of the face with corners `tx` and how far beyond it a vertex can pass the face's
/// test at radius `r`: a vertex passing the plane test lies within the radius of a point whose
/// barycentrics are ≥ −1e-6, i.e. within 2e-6 of the face's extent outside its box, so this
/// reach keeps every such vertex inside the inflated box.
#[inline(always)]
fn face_box(tx: &[Vector3<f64>; 3], r: f64) -> (Vector3<f64>, Vector3<f64>, f64) {
    let (lo, hi) = (tx[0].inf(&tx[1]).inf(&tx[2]), tx[0].sup(&tx[1]).sup(&tx[2]));
    (lo, hi, r + 1e-5 * (hi - lo).max() + 1e-12)
}

impl Table<'_> {
    /// Append to `list` the vertices of the cells that face `f`'s test box, inflated by `skin`,
    /// overlaps (one contiguous run of vertices per row of cells), that lie in that box and are
    /// neither a corner of `f` nor in a corner's one-ring: every vertex that can pass `f`'s test
    /// ([`check_face`]) while no vertex has moved more than `skin / 2` along an axis.
    #[inline(always)]
    fn list_face(&self, f: usize, skin: f64, stamp: &mut [u32], list: &mut Vec<u32>) {
        let t = self.faces[f];
        for &c in &t {
            stamp[c as usize] = f as u32;
            for &w in self.topology.neighbours(c as usize) {
                stamp[w as usize] = f as u32;
            }
        }
        let tx = t.map(|i| self.x[i as usize]);
        let (lo0, hi0, reach) = face_box(&tx, self.radius_m);
        // Later the corners may have moved `skin / 2` each way: the box grows by up to that on
        // each side and the reach by `1e-5 skin`, and a vertex may come `skin / 2` closer; the
        // `1e-9` covers the rounding of these sums.
        let reach = reach + 1e-5 * skin + skin + 1e-9;
        let (lo, hi) = (lo0.add_scalar(-reach), hi0.add_scalar(reach));
        let (clo, chi) = (self.cells.coords(&lo), self.cells.coords(&hi));
        let o = &self.cells.origin;
        let lo32 = [0, 1, 2].map(|k| relative(lo[k], o[k]));
        let hi32 = [0, 1, 2].map(|k| relative(hi[k], o[k]));
        let [sx, sy, sz] = self.sorted_f32;
        for k in clo[2]..=chi[2] {
            for j in clo[1]..=chi[1] {
                let a = self.start[self.cells.index([clo[0], j, k])] as usize;
                let b = self.start[self.cells.index([chi[0], j, k]) + 1] as usize;
                let mut i = a;
                while i < b {
                    // Most candidates fail the box: [`LANES`] of them tested in f32 at once,
                    // without a branch (the padding's NaNs fail).
                    let lanes =
                        |c: &[f32]| -> [f32; LANES] { c[i..i + LANES].try_into().expect("padded") };
                    let (xs, ys, zs) = (lanes(sx), lanes(sy), lanes(sz));
                    let mut mask = 0u32;
                    for l in 0..LANES {
                        let (x, y, z) = (xs[l], ys[l], zs[l]);
                        let inside = (x >= lo32[0])
                            & (x <= hi32[0])
                            & (y >= lo32[1])
                            & (y <= hi32[1])
                            & (z >= lo32[2])
                            & (z <= hi32[2]);
                        mask |= u32::from(inside) << l;
                    }
                    if b - i < LANES {
                        mask &= (1u32 << (b - i)) - 1;
                    }
                    let base = i;
                    i += LANES;
                    while mask != 0 {
                        let at = base + mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        // The f64 box (the f32 pass may let a vertex on its edge through).
                        let v = self.sorted[at];
                        if in_box(&self.sorted_x[at], &lo, &hi) && stamp[v as usize] != f as u32 {
                            list.push(v);
                        }
                    }
                }
            }
        }
    }
}

/// A block of faces' candidate lists ([`Table::list_face`]) as a [`crate::isa::Kernel`]: the
/// box tests compiled for AVX2 (eight f32 lanes at once) where the CPU has it; the same lists.
struct ListFaces<'t, 'a> {
    table: &'t Table<'a>,
    faces: Range<usize>,
    skin: f64,
    stamp: &'t mut [u32],
    lists: &'t mut Candidates,
}

impl crate::isa::Kernel for ListFaces<'_, '_> {
    type Output = ();

    #[inline(always)]
    fn call(self) {
        let lists = self.lists;
        lists.offsets.clear();
        lists.vertices.clear();
        lists.offsets.push(0);
        for f in self.faces {
            self.table
                .list_face(f, self.skin, self.stamp, &mut lists.vertices);
            lists.offsets.push(lists.vertices.len() as u32);
        }
    }
}

/// A block of faces against their lists ([`check_face`]) as a [`crate::isa::Kernel`]: compiled
/// for AVX2 where the CPU has it (no fused operations: the same pairs and distances).
struct CheckFaces<'t> {
    x: &'t [Vector3<f64>],
    faces: &'t [[u32; 3]],
    radius_m: f64,
    first: usize,
    lists: &'t Candidates,
    found: &'t mut Vec<Found>,
}

impl crate::isa::Kernel for CheckFaces<'_> {
    type Output = ();

    #[inline(always)]
    fn call(self) {
        self.found.clear();
        for (k, w) in self.lists.offsets.windows(2).enumerate() {
            let list = &self.lists.vertices[w[0] as usize..w[1] as usize];
            check_face(
                self.x,
                self.faces,
                self.radius_m,
                self.first + k,
                list,
                self.found,
            );
        }
    }
}

/// Whether lists built at `built_at` still serve at `x`: whether, along each axis, the vertices'
/// moves since the build span at most `skin` (`false` for a NaN or a length mismatch).
///
/// The search's tests depend only on where the vertices are relative to each other, so a move
/// common to all of them changes no pair. With `c` the middle of the moves' span along each
/// axis, every vertex is within `skin / 2` of its place at the build shifted by `c`: the shifted
/// build, whose lists are the same, serves as in the single-vertex rule it generalises. On a
/// walk the body, and the cloth with it, travels; only how the vertices move apart counts.
fn moves_within_skin(x: &[Vector3<f64>], built_at: &[Vector3<f64>], skin: f64) -> bool {
    if x.len() != built_at.len() {
        return false;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut nan = false;
    for (p, q) in x.iter().zip(built_at) {
        for k in 0..3 {
            let d = p[k] - q[k];
            nan |= d.is_nan();
            lo[k] = lo[k].min(d);
            hi[k] = hi[k].max(d);
        }
    }
    !nan && (0..3).all(|k| hi[k] - lo[k] <= skin)
}

/// Whether `p` lies in the box `[lo, hi]` (without a branch per coordinate).
#[inline(always)]
fn in_box(p: &Vector3<f64>, lo: &Vector3<f64>, hi: &Vector3<f64>) -> bool {
    (p.x >= lo.x) & (p.x <= hi.x) & (p.y >= lo.y) & (p.y <= hi.y) & (p.z >= lo.z) & (p.z <= hi.z)
}

/// Append to `found` the pairs of face `f` (corners `faces[f]`) with its candidate vertices
/// `list` at positions `x`: those in the face's box inflated by the radius and its slack, that
/// project inside the face within the radius of its plane.
#[inline(always)]
fn check_face(
    x: &[Vector3<f64>],
    faces: &[[u32; 3]],
    radius_m: f64,
    f: usize,
    list: &[u32],
    found: &mut Vec<Found>,
) {
    if list.is_empty() {
        return;
    }
    let tx = faces[f].map(|i| x[i as usize]);
    let (lo, hi, reach) = face_box(&tx, radius_m);
    let (lo, hi) = (lo.add_scalar(-reach), hi.add_scalar(reach));
    // The box test of [`LANES`] candidates into a mask first, without a branch per candidate,
    // then the plane test of those that passed, in list order: the same pairs in the same
    // order. (A branch on each candidate's box test cost more than the tests: self-collision
    // 314 → 221–226 ms per frame at 26,066 triangles and 27.3–28.3 → 24.9–25.3 at 8,710, one
    // thread, alternating builds of `cargo xtask bench sim`, the same cloth.)
    for group in list.chunks(LANES) {
        let mut mask = 0u32;
        for (l, &v) in group.iter().enumerate() {
            mask |= u32::from(in_box(&x[v as usize], &lo, &hi)) << l;
        }
        while mask != 0 {
            let v = group[mask.trailing_zeros() as usize];
            mask &= mask - 1;
            check_pair(x, &tx, radius_m, f, v, found);
        }
    }
}

/// The plane test of vertex `v` against face `f` (corners at `tx`), a pair in `found` if it
/// passes.
#[inline(always)]
fn check_pair(
    x: &[Vector3<f64>],
    tx: &[Vector3<f64>; 3],
    radius_m: f64,
    f: usize,
    v: u32,
    found: &mut Vec<Found>,
) {
    let Some(d) = vertex_triangle(&x[v as usize], tx) else {
        return;
    };
    if d.abs() < radius_m {
        found.push(Found {
            vertex: v,
            side: u8::from(d < 0.0),
            face: f as u32,
            distance_m: d.abs(),
        });
    }
}

impl SelfCollisionGrid {
    /// Build every face's candidate list at positions `x` with reach `radius_m + skin`.
    fn build(
        &mut self,
        x: &[Vector3<f64>],
        faces: &[[u32; 3]],
        topology: &MeshTopology,
        radius_m: f64,
        skin: f64,
        par: Parallelism,
    ) {
        // Cell size: the mean edge length, but at least the search diameter.
        let mean_edge = faces
            .iter()
            .map(|t| (x[t[1] as usize] - x[t[0] as usize]).norm())
            .sum::<f64>()
            / faces.len() as f64;
        let cells = Cells::new(x, mean_edge.max(2.0 * (radius_m + skin)));
        // Counting sort of the vertices into their cells (ascending within one).
        self.start.clear();
        self.start.resize(cells.len() + 1, 0);
        self.cell_of_vertex.clear();
        for p in x {
            let c = cells.index(cells.coords(p));
            self.cell_of_vertex.push(c as u32);
            self.start[c + 1] += 1;
        }
        for c in 0..cells.len() {
            self.start[c + 1] += self.start[c];
        }
        self.sorted.clear();
        self.sorted.resize(x.len(), 0);
        self.sorted_x.clear();
        self.sorted_x.resize(x.len(), Vector3::zeros());
        for (v, &c) in self.cell_of_vertex.iter().enumerate() {
            let slot = &mut self.start[c as usize];
            self.sorted[*slot as usize] = v as u32;
            self.sorted_x[*slot as usize] = x[v];
            *slot += 1;
        }
        for (k, coords) in self.sorted_f32.iter_mut().enumerate() {
            coords.clear();
            coords.extend(
                self.sorted_x
                    .iter()
                    .map(|p| relative(p[k], cells.origin[k])),
            );
            coords.extend([f32::NAN; LANES]);
        }
        // The fill advanced every start to the next cell's: shift back.
        for c in (1..=cells.len()).rev() {
            self.start[c] = self.start[c - 1];
        }
        self.start[0] = 0;
        let table = Table {
            x,
            faces,
            topology,
            cells,
            start: &self.start,
            sorted: &self.sorted,
            sorted_x: &self.sorted_x,
            sorted_f32: &self.sorted_f32,
            radius_m,
        };
        let n_blocks = faces.len().div_ceil(FACE_BLOCK);
        self.lists.resize_with(n_blocks, Candidates::default);
        self.stamps.resize_with(n_blocks, Vec::new);
        for stamp in &mut self.stamps {
            // A face marks the same set every time, so old marks never mislead.
            stamp.resize(x.len(), u32::MAX);
        }
        let block = |(b, (lists, stamp)): (usize, (&mut Candidates, &mut Vec<u32>))| {
            let faces = b * FACE_BLOCK..((b + 1) * FACE_BLOCK).min(faces.len());
            crate::isa::widest(ListFaces {
                table: &table,
                faces,
                skin,
                stamp,
                lists,
            });
        };
        match par {
            Parallelism::Sequential => self
                .lists
                .iter_mut()
                .zip(self.stamps.iter_mut())
                .enumerate()
                .for_each(block),
            Parallelism::Rayon => self
                .lists
                .par_iter_mut()
                .zip(self.stamps.par_iter_mut())
                .enumerate()
                .for_each(block),
        }
    }

    /// Find vertex–triangle pairs closer than `radius_m` and append them to `out` (cleared
    /// first). `vertex_area_m2` and `triangle_area_m2` give the contact area scaling. Returns
    /// whether the candidate lists were rebuilt (else those of an earlier call served).
    pub fn detect(
        &mut self,
        x: &[Vector3<f64>],
        faces: &[[u32; 3]],
        topology: &MeshTopology,
        vertex_area_m2: &[f64],
        triangle_area_m2: &[f64],
        radius_m: f64,
        par: Parallelism,
        out: &mut Vec<SelfContact>,
    ) -> bool {
        out.clear();
        if faces.is_empty() || x.is_empty() || radius_m <= 0.0 {
            return false;
        }
        let skin = SKIN_OVER_RADIUS * radius_m;
        let key = (x.len(), faces.len(), faces.as_ptr() as usize, radius_m);
        let mut built = false;
        if self.built_for != Some(key) || !moves_within_skin(x, &self.built_at, skin) {
            self.build(x, faces, topology, radius_m, skin, par);
            self.built_at.clear();
            self.built_at.extend_from_slice(x);
            self.built_for = Some(key);
            built = true;
        }
        // The faces, block by block, against their lists (on rayon's pool when `par` says so).
        self.found
            .resize_with(faces.len().div_ceil(FACE_BLOCK), Vec::new);
        let block = |(b, (found, lists)): (usize, (&mut Vec<Found>, &Candidates))| {
            crate::isa::widest(CheckFaces {
                x,
                faces,
                radius_m,
                first: b * FACE_BLOCK,
                lists,
                found,
            });
        };
        match par {
            Parallelism::Sequential => self
                .found
                .iter_mut()
                .zip(&self.lists)
                .enumerate()
                .for_each(block),
            Parallelism::Rayon => self
                .found
                .par_iter_mut()
                .zip(self.lists.par_iter())
                .enumerate()
                .for_each(block),
        }
        // Per vertex and side the closest face; faces arrive in ascending order, so the first
        // of equally close ones stays.
        self.closest.clear();
        self.closest.resize(x.len(), [None, None]);
        for found in self.found.iter().flatten() {
            let slot = &mut self.closest[found.vertex as usize][usize::from(found.side)];
            if slot.is_none_or(|(_, best)| found.distance_m < best) {
                *slot = Some((found.face, found.distance_m));
            }
        }
        for (v, slots) in self.closest.iter().enumerate() {
            for (side, slot) in slots.iter().enumerate() {
                if let Some((f, _)) = slot {
                    out.push(SelfContact {
                        vertex: v as u32,
                        triangle: faces[*f as usize],
                        side: if side == 0 { 1.0 } else { -1.0 },
                        area_m2: vertex_area_m2[v].min(triangle_area_m2[*f as usize]),
                    });
                }
            }
        }
        built
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every vertex against every triangle, by the rule of the module docs.
    fn brute_force(
        x: &[Vector3<f64>],
        faces: &[[u32; 3]],
        topology: &MeshTopology,
        radius_m: f64,
    ) -> Vec<(u32, u8, u32)> {
        let mut found = Vec::new();
        for (v, p) in x.iter().enumerate() {
            let ring = topology.neighbours(v);
            let mut best: [Option<(f64, u32)>; 2] = [None, None];
            for (f, t) in faces.iter().enumerate() {
                if t.iter().any(|&w| w as usize == v || ring.contains(&w)) {
                    continue;
                }
                let Some(d) = vertex_triangle(p, &t.map(|i| x[i as usize])) else {
                    continue;
                };
                let side = usize::from(d < 0.0);
                if d.abs() < radius_m && best[side].is_none_or(|(b, _)| d.abs() < b) {
                    best[side] = Some((d.abs(), f as u32));
                }
            }
            for (side, b) in best.iter().enumerate() {
                if let Some((_, f)) = b {
                    found.push((v as u32, side as u8, *f));
                }
            }
        }
        found
    }

    /// Uniform offsets in `[−amplitude / 2, amplitude / 2)` from an xorshift seeded by `seed`.
    fn jitter(mut seed: u64, amplitude: f64) -> impl FnMut() -> f64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * amplitude
        }
    }

    /// A sheet folded over itself into six layers 4 mm apart, crumpled a little: many pairs
    /// within the radius, on both sides, near cell boundaries and at ties; 1,128 faces, more
    /// than two blocks of the parallel binning.
    fn folded_sheet() -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let (nu, nv) = (48usize, 13usize);
        let mut x = Vec::new();
        let mut jitter = jitter(0x9e37_79b9_7f4a_7c15, 1e-3);
        for j in 0..nv {
            for i in 0..nu {
                // Along u: six 8-column layers, each reversed, stacked 4 mm apart.
                let (layer, k) = (i / 8, i % 8);
                let u = if layer % 2 == 0 { k } else { 7 - k } as f64 * 0.01;
                x.push(Vector3::new(
                    u + jitter(),
                    0.004 * layer as f64 + jitter(),
                    j as f64 * 0.01 + jitter(),
                ));
            }
        }
        let mut faces = Vec::new();
        for j in 0..nv - 1 {
            for i in 0..nu - 1 {
                let a = (j * nu + i) as u32;
                faces.push([a, a + 1, a + nu as u32]);
                faces.push([a + 1, a + nu as u32 + 1, a + nu as u32]);
            }
        }
        (x, faces)
    }

    /// `detect`'s pairs as `(vertex, side, face)`.
    fn pairs(out: &[SelfContact], faces: &[[u32; 3]]) -> Vec<(u32, u8, u32)> {
        out.iter()
            .map(|c| {
                let f = faces.iter().position(|t| *t == c.triangle).expect("a face");
                (c.vertex, u8::from(c.side < 0.0), f as u32)
            })
            .collect()
    }

    #[test]
    fn the_grid_finds_what_testing_every_pair_finds() {
        let (x, faces) = folded_sheet();
        let topology = MeshTopology::new(x.len(), &faces);
        let areas = vec![1e-4; x.len()];
        let tri_areas = vec![5e-5; faces.len()];
        let mut grid = SelfCollisionGrid::default();
        for radius in [0.0045, 0.006, 0.0101] {
            let expected = brute_force(&x, &faces, &topology, radius);
            assert!(expected.len() > 50, "{} pairs at {radius}", expected.len());
            for par in [Parallelism::Sequential, Parallelism::Rayon] {
                let mut out = Vec::new();
                grid.detect(
                    &x, &faces, &topology, &areas, &tri_areas, radius, par, &mut out,
                );
                assert_eq!(pairs(&out, &faces), expected, "radius {radius}, {par:?}");
            }
        }
    }

    /// `detect` on the folded sheet at radius 6 mm over 24 calls, the sheet moved by
    /// `step(call, x)` after each: every call must find what testing every pair finds. Returns
    /// how many calls built lists and how many found other pairs than the call before.
    fn follow(
        par: Parallelism,
        mut step: impl FnMut(usize, &mut [Vector3<f64>]),
    ) -> (usize, usize) {
        let (mut x, faces) = folded_sheet();
        let topology = MeshTopology::new(x.len(), &faces);
        let areas = vec![1e-4; x.len()];
        let tri_areas = vec![5e-5; faces.len()];
        let radius = 0.006;
        let mut grid = SelfCollisionGrid::default();
        let (mut builds, mut changed, mut last) = (0, 0, Vec::new());
        for call in 0..24 {
            let mut out = Vec::new();
            builds += usize::from(grid.detect(
                &x, &faces, &topology, &areas, &tri_areas, radius, par, &mut out,
            ));
            let got = pairs(&out, &faces);
            assert_eq!(
                got,
                brute_force(&x, &faces, &topology, radius),
                "call {call}, {par:?}"
            );
            changed += usize::from(got != last);
            last = got;
            step(call, &mut x);
        }
        (builds, changed)
    }

    #[test]
    fn reused_lists_find_what_testing_every_pair_finds_while_the_cloth_moves() {
        // The folded sheet's top layer lifts off 1 mm per call and comes back, while the layers
        // slide against each other 0.3 mm per call, with a jitter: pairs go and come between
        // calls, most calls reuse the lists (the skin allows 1.5 mm), and coming back the top
        // layer's pairs appear in calls that reuse lists built while it was out of reach.
        let mut jitter = jitter(0x2545_f491_4f6c_dd1d, 2e-4);
        for par in [Parallelism::Sequential, Parallelism::Rayon] {
            let (builds, changed) = follow(par, |call, x| {
                let lift = if call < 12 { 1e-3 } else { -1e-3 };
                for p in x {
                    let layer = (p.y / 0.004).round().clamp(0.0, 5.0);
                    if layer == 5.0 && p.y > 0.018 {
                        p.y += lift;
                    }
                    p.x += 3e-4 * (layer - 2.5) / 2.5 + jitter();
                    p.y += jitter();
                    p.z += jitter();
                }
            });
            assert!(changed > 10, "the pairs changed in only {changed} calls");
            assert!(
                builds > 3 && builds < 16,
                "{builds} builds in 24 calls ({par:?})"
            );
        }
    }

    #[test]
    fn a_move_every_vertex_shares_keeps_the_lists() {
        // The folded sheet travels 4 mm per call along a slanted line (more than the skin, so
        // every call would rebuild if each vertex's own move counted), while its layers slide
        // 0.3 mm per call against each other, with a jitter: the pairs change, the lists are
        // rebuilt only when the layers have slid apart by the skin, and every call finds what
        // testing every pair finds.
        let travel = Vector3::new(3e-3, -2e-3, 1.5e-3);
        let mut jitter = jitter(0x5851_f42d_4c95_7f2d, 2e-4);
        let (builds, changed) = follow(Parallelism::Sequential, |call, x| {
            for p in x {
                let layer = ((p.y - travel.y * call as f64) / 0.004)
                    .round()
                    .clamp(0.0, 5.0);
                *p += travel;
                p.x += 3e-4 * (layer - 2.5) / 2.5 + jitter();
                p.y += jitter();
                p.z += jitter();
            }
        });
        assert!(changed > 10, "the pairs changed in only {changed} calls");
        // The layers slide apart by 0.6 mm and the jitter by up to 0.4 mm per call: the 3 mm
        // skin lasts at least three calls.
        assert!(builds > 1 && builds <= 8, "{builds} builds in 24 calls");
    }

    #[test]
    fn lists_serve_while_the_moves_span_at_most_the_skin() {
        let at = vec![Vector3::new(0.1, 0.2, 0.3), Vector3::new(-0.4, 0.5, 0.0)];
        let shift = |d: [Vector3<f64>; 2]| vec![at[0] + d[0], at[1] + d[1]];
        let skin = 1e-3;
        // A common move of any size.
        let far = Vector3::new(0.5, -2.0, 7.0);
        assert!(moves_within_skin(&shift([far, far]), &at, skin));
        // Moves apart by just under and just over the skin, along one axis.
        let (under, over) = (Vector3::x() * 0.9e-3, Vector3::z() * 1.1e-3);
        assert!(moves_within_skin(&shift([far, far + under]), &at, skin));
        assert!(!moves_within_skin(&shift([far, far + over]), &at, skin));
        assert!(!moves_within_skin(&shift([far, far - over]), &at, skin));
        // A NaN, or another cloth.
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert!(!moves_within_skin(
            &shift([nan, Vector3::zeros()]),
            &at,
            skin
        ));
        assert!(!moves_within_skin(&at[..1], &at, skin));
    }
}
