//! Self-collision candidates: vertex–triangle proximity by a uniform spatial hash.
//!
//! Triangles are binned by their bounding boxes inflated by the search radius; a vertex looks
//! up its own cell. A pair counts when the vertex projects inside the triangle (barycentric
//! weights ≥ −1e-6, as ARCSim's `add_proximity`) within the search radius of its plane, and
//! the triangle does not touch the vertex or its one-ring (those are neighbours through the
//! surface, not contacts). As in ARCSim, each vertex keeps the closest triangle on each side.
//! Results are sorted by vertex and side, independent of the thread count.
//!
//! The cells are a hash table filled by a counting sort (no comparison sort of the entries),
//! each bucket listing its faces in ascending order, so a vertex meets its candidates in the
//! order of a sorted list; a candidate whose inflated box misses the vertex is dropped before
//! the one-ring and plane tests (it cannot pass them).

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{MeshTopology, Parallelism};

use crate::energy::SelfContact;

/// Scratch buffers of the spatial hash, kept between steps.
#[derive(Debug, Default)]
pub(crate) struct SelfCollisionGrid {
    /// `(cell tag, face)` per face and covered cell ([`tag_of`]), per block of
    /// [`FACE_BLOCK`] faces; in face order read block after block.
    entries: Vec<Vec<(u32, u32)>>,
    /// The entries grouped by bucket (`bucket_start` its CSR offsets), faces ascending.
    buckets: Vec<(u32, u32)>,
    bucket_start: Vec<u32>,
    /// Per face, its box inflated by the radius (and a rounding margin): min, max.
    boxes: Vec<[Vector3<f64>; 2]>,
    closest: Vec<[Option<(u32, f64)>; 2]>,
    /// One stamp array per part of the vertex search ([`SEARCH_PARTS`] per thread): `stamp[w]
    /// == v` marks `v` and its one-ring while `v` searches. Kept between calls (a vertex marks
    /// the same set every time, so old marks never mislead).
    stamps: Vec<Vec<u32>>,
}

/// What a part of the vertex search writes: its vertices' closest faces, with its stamps.
type PartOut<'a> = (&'a mut [[Option<(u32, f64)>; 2]], &'a mut Vec<u32>);

/// Parts of the vertex search per thread of the pool (contiguous vertex ranges, each with its
/// own stamp array; a few per thread so that an uneven part does not hold up the others).
const SEARCH_PARTS: usize = 4;

/// Faces per block of the parallel binning.
const FACE_BLOCK: usize = 512;

/// What binning a block of faces writes: their test boxes and their entries.
type BlockOut<'a> = (&'a mut [[Vector3<f64>; 2]], &'a mut Vec<(u32, u32)>);

/// The bucket of a cell (its [`tag_of`]) in a table of `2^bits` buckets.
fn bucket_of(tag: u32, bits: u32) -> usize {
    (u64::from(tag).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - bits)) as usize
}

/// A cell's 32-bit tag: the low half of its key. Two cells of one bucket rarely share one; when
/// they do, a vertex also tests the other cell's faces, which the box and plane tests then
/// judge: the tag is a filter, never an answer.
fn tag_of(key: u64) -> u32 {
    key as u32
}

fn cell_key(c: [i64; 3]) -> u64 {
    (c[0] as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (c[1] as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (c[2] as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
}

fn cell_of(p: &Vector3<f64>, inv_cell: f64) -> [i64; 3] {
    [
        (p.x * inv_cell).floor() as i64,
        (p.y * inv_cell).floor() as i64,
        (p.z * inv_cell).floor() as i64,
    ]
}

/// Signed distance of `p` to the plane of `t` and whether its projection is inside `t`.
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

impl SelfCollisionGrid {
    /// Find vertex–triangle pairs closer than `radius_m` and append them to `out` (cleared
    /// first). `vertex_area_m2` and `triangle_area_m2` give the contact area scaling.
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
    ) {
        out.clear();
        if faces.is_empty() || radius_m <= 0.0 {
            return;
        }
        // Cell size: the mean edge length, but at least the search diameter.
        let mean_edge = faces
            .iter()
            .map(|t| (x[t[1] as usize] - x[t[0] as usize]).norm())
            .sum::<f64>()
            / faces.len() as f64;
        let cell = mean_edge.max(2.0 * radius_m);
        let inv_cell = 1.0 / cell;
        // Bin the faces, block by block (on rayon's pool when `par` says so).
        self.boxes.resize(faces.len(), [Vector3::zeros(); 2]);
        self.entries
            .resize_with(faces.len().div_ceil(FACE_BLOCK), Vec::new);
        let bin = |(block, (boxes, entries)): (usize, BlockOut<'_>)| {
            entries.clear();
            for (k, b) in boxes.iter_mut().enumerate() {
                let f = block * FACE_BLOCK + k;
                let [a, b0, c] = faces[f].map(|i| x[i as usize]);
                let (lo0, hi0) = (a.inf(&b0).inf(&c), a.sup(&b0).sup(&c));
                let lo = lo0.add_scalar(-radius_m);
                let hi = hi0.add_scalar(radius_m);
                // A vertex passing the plane test lies within the radius of a point whose
                // barycentrics are ≥ −1e-6, i.e. within 2e-6 of the face's extent outside its
                // box: this margin keeps every such vertex inside the test box.
                let slack = radius_m + 1e-5 * (hi0 - lo0).max() + 1e-12;
                *b = [lo0.add_scalar(-slack), hi0.add_scalar(slack)];
                let (clo, chi) = (cell_of(&lo, inv_cell), cell_of(&hi, inv_cell));
                for i in clo[0]..=chi[0] {
                    for j in clo[1]..=chi[1] {
                        for k in clo[2]..=chi[2] {
                            entries.push((tag_of(cell_key([i, j, k])), f as u32));
                        }
                    }
                }
            }
        };
        let blocks = self
            .boxes
            .chunks_mut(FACE_BLOCK)
            .zip(self.entries.iter_mut());
        match par {
            Parallelism::Sequential => blocks.enumerate().for_each(bin),
            Parallelism::Rayon => self
                .boxes
                .par_chunks_mut(FACE_BLOCK)
                .zip(self.entries.par_iter_mut())
                .enumerate()
                .for_each(bin),
        }
        // Counting sort into buckets; within a bucket the faces stay ascending. A cell holds
        // dozens of entries (a face covers about 15 cells at 8,710 triangles, and a cell meets
        // about 50 faces): a bucket per eight entries leaves most cells a bucket of their own
        // in a table that stays in cache while the entries are counted and placed.
        let n_entries: usize = self.entries.iter().map(Vec::len).sum();
        let bits = (n_entries / 8).max(64).next_power_of_two().trailing_zeros();
        let n_buckets = 1usize << bits;
        self.bucket_start.clear();
        self.bucket_start.resize(n_buckets + 1, 0);
        for &(tag, _) in self.entries.iter().flatten() {
            self.bucket_start[bucket_of(tag, bits) + 1] += 1;
        }
        for b in 0..n_buckets {
            self.bucket_start[b + 1] += self.bucket_start[b];
        }
        self.buckets.clear();
        self.buckets.resize(n_entries, (0, 0));
        for &(tag, f) in self.entries.iter().flatten() {
            let slot = &mut self.bucket_start[bucket_of(tag, bits)];
            self.buckets[*slot as usize] = (tag, f);
            *slot += 1;
        }
        // The fill advanced every start to the next bucket's: shift back.
        for b in (1..=n_buckets).rev() {
            self.bucket_start[b] = self.bucket_start[b - 1];
        }
        self.bucket_start[0] = 0;
        self.closest.clear();
        self.closest.resize(x.len(), [None, None]);
        let (buckets, bucket_start, boxes) = (&self.buckets, &self.bucket_start, &self.boxes);
        let search = |stamp: &mut Vec<u32>, v: usize, slot: &mut [Option<(u32, f64)>; 2]| {
            let p = x[v];
            let key = tag_of(cell_key(cell_of(&p, inv_cell)));
            let b = bucket_of(key, bits);
            stamp[v] = v as u32;
            for &w in topology.neighbours(v) {
                stamp[w as usize] = v as u32;
            }
            let range = bucket_start[b] as usize..bucket_start[b + 1] as usize;
            for &(k, f) in &buckets[range] {
                if k != key {
                    continue;
                }
                // One branch for the six comparisons (most candidates fail one of them, in no
                // predictable order).
                let [lo, hi] = &boxes[f as usize];
                let inside = (p.x >= lo.x)
                    & (p.x <= hi.x)
                    & (p.y >= lo.y)
                    & (p.y <= hi.y)
                    & (p.z >= lo.z)
                    & (p.z <= hi.z);
                if !inside {
                    continue;
                }
                let t = faces[f as usize];
                if t.iter().any(|&w| stamp[w as usize] == v as u32) {
                    continue;
                }
                let tx = t.map(|i| x[i as usize]);
                let Some(d) = vertex_triangle(&p, &tx) else {
                    continue;
                };
                if d.abs() >= radius_m {
                    continue;
                }
                let side = usize::from(d < 0.0);
                if slot[side].is_none_or(|(_, best)| d.abs() < best) {
                    slot[side] = Some((f, d.abs()));
                }
            }
        };
        let parts = match par {
            Parallelism::Sequential => 1,
            Parallelism::Rayon => SEARCH_PARTS * rayon::current_num_threads(),
        };
        self.stamps.resize_with(parts, Vec::new);
        for stamp in &mut self.stamps {
            stamp.resize(x.len(), u32::MAX);
        }
        let size = x.len().div_ceil(parts).max(1);
        let part = |(p, (slots, stamp)): (usize, PartOut<'_>)| {
            for (k, slot) in slots.iter_mut().enumerate() {
                search(stamp, p * size + k, slot);
            }
        };
        match par {
            Parallelism::Sequential => self
                .closest
                .chunks_mut(size)
                .zip(self.stamps.iter_mut())
                .enumerate()
                .for_each(part),
            Parallelism::Rayon => self
                .closest
                .par_chunks_mut(size)
                .zip(self.stamps.par_iter_mut())
                .enumerate()
                .for_each(part),
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

    #[test]
    fn the_grid_finds_what_testing_every_pair_finds() {
        // A sheet folded over itself into six layers 4 mm apart, crumpled a little: many pairs
        // within the radius, on both sides, near cell boundaries and at ties; 1,128 faces, more
        // than two blocks of the parallel binning.
        let (nu, nv) = (48usize, 13usize);
        let mut x = Vec::new();
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut jitter = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e-3
        };
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
                let got: Vec<(u32, u8, u32)> = out
                    .iter()
                    .map(|c| {
                        let f = faces.iter().position(|t| *t == c.triangle).expect("a face");
                        (c.vertex, u8::from(c.side < 0.0), f as u32)
                    })
                    .collect();
                assert_eq!(got, expected, "radius {radius}, {par:?}");
            }
        }
    }
}
