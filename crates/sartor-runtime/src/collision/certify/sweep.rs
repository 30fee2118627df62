//! The certified query without a face grid: the region's faces sweep a grid of the cloth
//! vertices instead (see the parent module's docs for the proof the answers feed).
//!
//! A cloth frame is a thin shell around the body: every vertex of the shipped T-shirt on its
//! walk lies within 4 cm of the region and most within 1 cm. So instead of each vertex scanning
//! a ball of face-grid cells as large as its distance, the faces visit the cloth vertices: a
//! cluster of [`CLUSTER`] faces gathers the vertices within the sweep's reach ([`SWEEP_M`]) of
//! its box from a grid of the vertices rebuilt per call (one entry per vertex: a counting sort
//! of a few thousand points), then each of its faces tests them eight at a time, by box and
//! plane bound against each vertex's own reach. Per vertex the sweep keeps its nearest distance
//! `b` in f32 (started from the face it was nearest last frame) and every face within
//! `b` + [`SLACK_M`]: the f32 distances are within a micrometre of the f64 ones, so that list
//! holds every face the f64 query could return, and [`MeshProximity::nearest_among`] on it is
//! the exact query's answer (same faces, same arithmetic, same tie rule). A vertex with no face
//! within the last reach, or more near-ties than a list holds, is searched against every face.
//!
//! The sweep serves the vertices of one frame (the first pass), the vertices a pass moved (the
//! later ones), and any points a report asks about; it reads the face data of [`Frame`]
//! (relative f32 corners, boxes, planes, in cluster order) but never its grid. Buried faces
//! (where [`Frame`] seeks them) have a box at infinity there and are never on a list.

use super::{Frame, GUARD_M, LANES, fmax, lanes};

/// The sweep's reaches, metres: every point is swept within the first; a point with no face
/// that close is swept again within the next (few are: a loose garment's), and one with none
/// within the last is searched against every face.
const SWEEP_M: [f32; 3] = [0.02, 0.04, 0.15];
/// Faces per cluster of the sweep (see [`Frame`]'s `cluster_faces`).
pub(super) const CLUSTER: usize = 16;
/// Smallest cell edge of the cloth grid, metres.
const CELL_M: f32 = 0.02;
/// Points per cell of the cloth grid on average over its box (measured on the shipped model's
/// walk: 1, 3, 8 and 20 took 3.6, 2.9, 2.9 and 3.5 ms per frame).
const POINTS_PER_CELL: f32 = 3.0;
/// At most this many cells in the cloth grid (the cell grows beyond).
const MAX_CELLS: usize = 1 << 18;
/// Faces kept per vertex within its nearest distance plus the slack.
const LIST: usize = 8;
/// A face within this of a vertex's nearest f32 distance stays on its list, metres: f32
/// distances of corners within metres of the grid corner are within a micrometre of the f64
/// ones.
const SLACK_M: f32 = GUARD_M;

/// What the sweep reads of a face: its box, plane and corners (relative), and its index.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SweepFace {
    pub(super) lo: [f32; 3],
    pub(super) hi: [f32; 3],
    pub(super) plane: [f32; 4],
    pub(super) tri: [[f32; 3]; 3],
    pub(super) face: u32,
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
    /// The face offered first (the point's warm face): the sweep does not offer it again.
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

    /// The faces still within reach.
    fn faces(&self) -> impl Iterator<Item = u32> + '_ {
        let reach2 = self.reach2;
        self.list[..(self.len as usize).min(LIST)]
            .iter()
            .filter(move |e| e.1 <= reach2)
            .map(|e| e.0)
    }
}

/// The sweep's state: the cloth grid and per-point answers, reused between calls.
#[derive(Clone, Debug, Default)]
pub(crate) struct Sweep {
    /// Per point, relative to the frame's grid corner.
    x: Vec<[f32; 3]>,
    /// The points of the current sweep, and its reach.
    subset: Vec<u32>,
    radius: f32,
    near: Vec<Near>,
    /// The cloth grid: corner, cell, dims; per cell its slots `[start[c], start[c + 1])`.
    lo: [f32; 3],
    cell: f32,
    dims: [usize; 3],
    start: Vec<u32>,
    /// Per slot (cell order), its point and position.
    point: Vec<u32>,
    sx: Vec<f32>,
    sy: Vec<f32>,
    sz: Vec<f32>,
    /// Per slot, its point's reach² (a copy of [`Near::reach2`] where the sweep reads it;
    /// [`LANES`] padding slots far away).
    sreach2: Vec<f32>,
    /// A cluster's points within reach of its box: their slots, positions and reach² (with
    /// [`LANES`] padding that never passes).
    cand: Vec<u32>,
    cx: Vec<f32>,
    cy: Vec<f32>,
    cz: Vec<f32>,
    creach2: Vec<f32>,
    /// Per point, its range of `spill` when its list overflowed even against every face
    /// (`(0, 0)`: none); the faces within reach, unbounded.
    spilled: Vec<(u32, u32)>,
    spill: Vec<u32>,
}

impl Sweep {
    /// For each of `points` (relative to `frame`'s grid corner), the faces within its nearest
    /// distance plus the slack, read back with [`Sweep::faces`] and [`Sweep::best2`]; `warm`:
    /// per point, a face to start from (`u32::MAX`: none).
    pub(crate) fn run(&mut self, frame: &Frame, points: &[[f32; 3]], warm: &[u32]) {
        let n = points.len();
        self.x.clear();
        self.x.extend_from_slice(points);
        self.near.clear();
        self.near.resize(n, Near::new(0.0));
        if n == 0 {
            return;
        }
        self.subset.clear();
        self.subset.extend(0..n as u32);
        for radius in SWEEP_M {
            for &i in &self.subset {
                let (i, w) = (i as usize, warm[i as usize]);
                let mut near = Near::new(radius * radius);
                if (w as usize) < frame.faces.len() && !frame.buried[w as usize] {
                    let (d2, exact) = frame.distance2(w, &self.x[i]);
                    near.offer(w, d2, exact);
                    near.warm = w;
                }
                self.near[i] = near;
            }
            // No point reaches farther than its start: the sweep need not either.
            let widest = self
                .subset
                .iter()
                .map(|&i| self.near[i as usize].reach2)
                .fold(0.0f32, f32::max);
            self.radius = radius.min(widest.sqrt());
            self.build_grid();
            self.sweep(frame);
            // The points with no exact distance within the reach (a sliver's box bound proves
            // nothing about the faces beyond it) go on.
            let near = &self.near;
            self.subset.retain(|&i| {
                near[i as usize].best_face == u32::MAX && !near[i as usize].overflowed()
            });
            if self.subset.is_empty() {
                break;
            }
        }
        self.spilled.clear();
        self.spilled.resize(n, (0, 0));
        self.spill.clear();
        for i in 0..n {
            let near = &self.near[i];
            // No exact distance within the sweeps' reach, or more near-ties than the list holds.
            if near.overflowed() || near.best_face == u32::MAX {
                let near = search_all(frame, &self.x[i], warm[i]);
                if near.overflowed() {
                    // More near-ties than a list holds (a point at a region vertex of high
                    // valence): every face within reach, unbounded.
                    let start = self.spill.len() as u32;
                    for f in 0..frame.faces.len() as u32 {
                        if !frame.buried[f as usize]
                            && frame.distance2(f, &self.x[i]).0 <= near.reach2
                        {
                            self.spill.push(f);
                        }
                    }
                    self.spilled[i] = (start, self.spill.len() as u32);
                }
                self.near[i] = near;
            }
        }
    }

    /// Point `i`'s faces within its nearest distance plus the slack (never empty for a region
    /// with a face).
    pub(crate) fn faces(&self, i: usize) -> impl Iterator<Item = u32> + '_ {
        let (a, b) = self.spilled[i];
        let list = if a < b {
            None
        } else {
            Some(self.near[i].faces())
        };
        list.into_iter()
            .flatten()
            .chain(self.spill[a as usize..b as usize].iter().copied())
    }

    /// Point `i`'s nearest f32 distance² (`∞` if only sliver faces are near: their distance is
    /// not trusted) and the face at it.
    pub(crate) fn best(&self, i: usize) -> (f32, u32) {
        (self.near[i].best2, self.near[i].best_face)
    }

    /// The grid of the points: a counting sort into cells of [`CELL_M`] (larger for a huge
    /// spread).
    fn build_grid(&mut self) {
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for x in self.subset.iter().map(|&i| &self.x[i as usize]) {
            for k in 0..3 {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
        }
        // About [`POINTS_PER_CELL`] points per cell of the points' box, at least [`CELL_M`].
        let volume: f32 = (0..3).map(|k| (hi[k] - lo[k]).max(CELL_M)).product();
        let mut cell = (volume * POINTS_PER_CELL / self.subset.len() as f32)
            .cbrt()
            .max(CELL_M);
        let dims = loop {
            let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / cell) as usize + 1);
            if dims[0] * dims[1] * dims[2] <= MAX_CELLS {
                break dims;
            }
            cell *= 2.0;
        };
        let (lo_, cell_) = (lo, cell);
        let index = |x: &[f32; 3]| {
            let c = [0, 1, 2].map(|k| (((x[k] - lo_[k]) / cell_) as usize).min(dims[k] - 1));
            (c[2] * dims[1] + c[1]) * dims[0] + c[0]
        };
        let n_cells = dims[0] * dims[1] * dims[2];
        self.start.clear();
        self.start.resize(n_cells + 1, 0);
        for &i in &self.subset {
            self.start[index(&self.x[i as usize]) + 1] += 1;
        }
        for c in 0..n_cells {
            self.start[c + 1] += self.start[c];
        }
        let n = self.subset.len();
        self.point.clear();
        self.point.resize(n, 0);
        for v in [&mut self.sx, &mut self.sy, &mut self.sz] {
            v.clear();
            v.resize(n + LANES, f32::INFINITY);
        }
        self.sreach2.clear();
        self.sreach2.resize(n + LANES, 0.0);
        for &i in &self.subset {
            let (i, x) = (i as usize, &self.x[i as usize]);
            let c = index(x);
            let slot = self.start[c] as usize;
            self.start[c] += 1;
            self.point[slot] = i as u32;
            self.sx[slot] = x[0];
            self.sy[slot] = x[1];
            self.sz[slot] = x[2];
            self.sreach2[slot] = self.near[i].reach2;
        }
        for c in (1..=n_cells).rev() {
            self.start[c] = self.start[c - 1];
        }
        self.start[0] = 0;
        (self.lo, self.cell, self.dims) = (lo, cell, dims);
    }

    /// [`Sweep::sweep_impl`], compiled for AVX2 when the CPU has it (the same arithmetic).
    #[allow(unsafe_code)]
    fn sweep(&mut self, frame: &Frame) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn avx2(sweep: &mut Sweep, frame: &Frame) {
                sweep.sweep_impl(frame);
            }
            if is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2 (checked just above).
                unsafe { avx2(self, frame) };
                return;
            }
        }
        self.sweep_impl(frame);
    }

    /// Every face offers itself to the points within the reach of its box, a cluster of faces
    /// at a time: the points within reach of the cluster's box are gathered once from the grid,
    /// then each face of the cluster tests them eight at a time.
    #[inline(always)]
    fn sweep_impl(&mut self, frame: &Frame) {
        let [nx, ny, nz] = self.dims;
        // The reach can exceed the sweep's radius by the slack.
        let r = self.radius + 2.0 * SLACK_M;
        let span = |lo: f32, hi: f32, k: usize, n: usize| -> Option<(usize, usize)> {
            let a = (lo - r - self.lo[k]) / self.cell;
            let b = (hi + r - self.lo[k]) / self.cell;
            if b < 0.0 || a >= n as f32 {
                return None;
            }
            Some((a.max(0.0) as usize, (b as usize).min(n - 1)))
        };
        let box2 = |lo: &[f32; 3], hi: &[f32; 3], x: f32, y: f32, z: f32| {
            let dx = fmax(fmax(lo[0] - x, x - hi[0]), 0.0);
            let dy = fmax(fmax(lo[1] - y, y - hi[1]), 0.0);
            let dz = fmax(fmax(lo[2] - z, z - hi[2]), 0.0);
            dx * dx + dy * dy + dz * dz
        };
        for (c, (clo, chi)) in frame.cluster_box.iter().enumerate() {
            let (Some((x0, x1)), Some((y0, y1)), Some((z0, z1))) = (
                span(clo[0], chi[0], 0, nx),
                span(clo[1], chi[1], 1, ny),
                span(clo[2], chi[2], 2, nz),
            ) else {
                continue;
            };
            self.cand.clear();
            self.cx.clear();
            self.cy.clear();
            self.cz.clear();
            self.creach2.clear();
            for z in z0..=z1 {
                for y in y0..=y1 {
                    let row = (z * ny + y) * nx;
                    let (s0, s1) = (
                        self.start[row + x0] as usize,
                        self.start[row + x1 + 1] as usize,
                    );
                    for s in s0..s1 {
                        let (px, py, pz) = (self.sx[s], self.sy[s], self.sz[s]);
                        if box2(clo, chi, px, py, pz) <= self.sreach2[s] {
                            self.cand.push(s as u32);
                            self.cx.push(px);
                            self.cy.push(py);
                            self.cz.push(pz);
                            self.creach2.push(self.sreach2[s]);
                        }
                    }
                }
            }
            let n = self.cand.len();
            if n == 0 {
                continue;
            }
            for v in [&mut self.cx, &mut self.cy, &mut self.cz] {
                v.extend([f32::INFINITY; LANES]);
            }
            self.creach2.extend([-1.0; LANES]);
            let end = ((c + 1) * CLUSTER).min(frame.cluster_faces.len());
            for sf in &frame.sweep_faces[c * CLUSTER..end] {
                let SweepFace {
                    lo,
                    hi,
                    plane: [pnx, pny, pnz, po],
                    tri,
                    face: f,
                } = *sf;
                let sliver = po.is_infinite();
                // A sliver's plane (zero normal, infinite offset) bounds nothing.
                let (po, plane_on) = if sliver { (0.0, 0.0) } else { (po, 1.0) };
                let mut e = 0;
                while e < n {
                    let (px, py, pz) = (lanes(&self.cx, e), lanes(&self.cy, e), lanes(&self.cz, e));
                    let reach2 = lanes(&self.creach2, e);
                    // The plane's distance on either side (a triangle is flat: its corners'
                    // offsets agree to rounding, far below the slack); none for a sliver.
                    let mut lb2 = [0.0f32; LANES];
                    for l in 0..LANES {
                        let dx = fmax(fmax(lo[0] - px[l], px[l] - hi[0]), 0.0);
                        let dy = fmax(fmax(lo[1] - py[l], py[l] - hi[1]), 0.0);
                        let dz = fmax(fmax(lo[2] - pz[l], pz[l] - hi[2]), 0.0);
                        let h = (pnx * px[l] + pny * py[l] + pnz * pz[l] - po) * plane_on;
                        lb2[l] = fmax(dx * dx + dy * dy + dz * dz, h * h);
                    }
                    let mut hit = 0u32;
                    for l in 0..LANES {
                        hit |= u32::from(lb2[l] <= reach2[l]) << l;
                    }
                    while hit != 0 {
                        let l = hit.trailing_zeros() as usize;
                        hit &= hit - 1;
                        let k = e + l;
                        let s = self.cand[k] as usize;
                        let near = &mut self.near[self.point[s] as usize];
                        if near.warm == f {
                            continue;
                        }
                        let p = [self.cx[k], self.cy[k], self.cz[k]];
                        if sliver {
                            near.offer(f, box2(&lo, &hi, p[0], p[1], p[2]), false);
                        } else {
                            near.offer(f, distance2(&p, &tri), true);
                        }
                        self.creach2[k] = near.reach2;
                        self.sreach2[s] = near.reach2;
                    }
                    e += LANES;
                }
            }
        }
    }
}

/// [`Near`] for `x` against every face of `frame` (started from face `warm`, if any).
fn search_all(frame: &Frame, x: &[f32; 3], warm: u32) -> Near {
    let mut near = Near::new(f32::INFINITY);
    if (warm as usize) < frame.faces.len() && !frame.buried[warm as usize] {
        let (d2, exact) = frame.distance2(warm, x);
        near.offer(warm, d2, exact);
    }
    let data = &frame.data;
    // A bounded list cannot overflow here by more than exact ties: when it does, every face
    // within reach is kept in a second, unbounded pass below.
    for f in (0..frame.faces.len()).filter(|&f| !frame.buried[f]) {
        let (lo, hi) = (data.lo[f], data.hi[f]);
        let dx = fmax(fmax(lo[0] - x[0], x[0] - hi[0]), 0.0);
        let dy = fmax(fmax(lo[1] - x[1], x[1] - hi[1]), 0.0);
        let dz = fmax(fmax(lo[2] - x[2], x[2] - hi[2]), 0.0);
        let box2 = dx * dx + dy * dy + dz * dz;
        if box2 > near.reach2 {
            continue;
        }
        let (d2, exact) = frame.distance2(f as u32, x);
        near.offer(f as u32, d2, exact);
    }
    near
}

impl Frame {
    /// Distance² from `x` (relative) to face `f` in f32, and whether it is exact (for a sliver,
    /// the distance² to its box: a lower bound).
    pub(super) fn distance2(&self, f: u32, x: &[f32; 3]) -> (f32, bool) {
        let fi = f as usize;
        if self.data.plane[fi][3].is_infinite() {
            let (lo, hi) = (self.data.lo[fi], self.data.hi[fi]);
            let d = [0, 1, 2].map(|k| fmax(fmax(lo[k] - x[k], x[k] - hi[k]), 0.0));
            return (d[0] * d[0] + d[1] * d[1] + d[2] * d[2], false);
        }
        let tri = self.faces[fi].map(|v| self.rel[v as usize]);
        (distance2(x, &tri), true)
    }
}

/// Distance² from `p` to the triangle `[a, b, c]`, f32 (Ericson's closest point by regions,
/// as sartor-core's f64 `closest_on_triangle`). It only chooses which faces go on a list: every
/// answer the post-process uses still comes from `MeshProximity` in f64 on that list, so the
/// workspace keeps one closest-point query. A copy in f32 because the sweep's lanes are f32 and
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
        let v = d1 / (d1 - d3);
        return norm2(&[ap[0] - ab[0] * v, ap[1] - ab[1] * v, ap[2] - ab[2] * v]);
    }
    let cp = sub(p, c);
    let d5 = dot(&ab, &cp);
    let d6 = dot(&ac, &cp);
    if d6 >= 0.0 && d5 <= d6 {
        return norm2(&cp);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return norm2(&[ap[0] - ac[0] * w, ap[1] - ac[1] * w, ap[2] - ac[2] * w]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        let bc = sub(c, b);
        return norm2(&[bp[0] - bc[0] * w, bp[1] - bc[1] * w, bp[2] - bc[2] * w]);
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    norm2(&[
        ap[0] - ab[0] * v - ac[0] * w,
        ap[1] - ab[1] * v - ac[1] * w,
        ap[2] - ab[2] * v - ac[2] * w,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn the_f32_distance_matches_the_f64_closest_point() {
        let mut rng = 12345u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f32 / (1u64 << 53) as f32 * 0.1
        };
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
