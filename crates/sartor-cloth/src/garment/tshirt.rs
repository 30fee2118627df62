//! The procedural T-shirt, cut from the template body (β = 0, rest A-pose).
//!
//! 1. **Cut.** The body surface is clipped (exactly, along the cut surfaces, splitting
//!    triangles) by four cuts: the hem, a horizontal plane `hem_below_hips_m` below the `Hips`
//!    joint; the neck, a plane `neck_depth_m` below the `Neck` joint tilted forward by
//!    `neck_front_tilt_deg` (a lower neckline in front); and one cut per sleeve, the plane
//!    perpendicular to the upper-arm bone (`LeftArm → LeftForeArm`) at `sleeve_fraction` of
//!    its length, limited to a disk around the bone whose radius separates the arm's vertices
//!    from the torso's (found from the skin weights). The largest connected piece is kept,
//!    ears (triangles with two boundary edges) are trimmed, and the piece must have exactly
//!    four boundary loops: neck, hem and two sleeve openings. The openings are smoothed along
//!    themselves (in their cut planes), so the garment bridges the body's concavities there
//!    (the top of the gluteal cleft notches the hem) instead of following them.
//! 2. **Ease.** Every vertex moves out by `ease_m` along its vertex normal, smoothed over the
//!    surface (so the offset does not fold in the armpit's concavity); then, a few times, any
//!    vertex closer to the body than `ease_m` is pushed out to `ease_m` (from its closest body
//!    point) and the displacement field is smoothed again.
//! 3. **Remesh** isotropically to exactly `triangles` triangles on that offset surface.
//! 4. **Check.** Every vertex must lie at least `ease_m / 2` outside the body (signed distance
//!    with angle-weighted pseudo-normals), vertices that do not are pushed out first; the
//!    result must not intersect itself.
//!
//! Material frames follow [`super::material_u_axes`].

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{BodyModel, MeshProximity, TriMesh};
use serde::{Deserialize, Serialize};

use super::frame::{Arm, body_arms};
use super::intersect::self_intersections;
use super::remesh::{RemeshOptions, remesh_to_count};
use crate::{Error, Result};

/// The recipe of a procedural T-shirt (`configs/garments/tshirt*.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TshirtRecipe {
    /// The garment's name (its folder under `datasets/garments/`).
    pub name: String,
    /// Folder of the body model, relative to the workspace root; `None` for the built-in body.
    #[serde(default)]
    pub body: Option<String>,
    /// Exact number of triangles.
    pub triangles: usize,
    /// Distance between the body and the garment, m (1–2 cm for a T-shirt).
    pub ease_m: f64,
    /// Height of the hem below the `Hips` joint, m (negative: above).
    pub hem_below_hips_m: f64,
    /// Where the sleeves end, as a fraction of the upper-arm bone from the shoulder joint
    /// (0.5 = mid upper arm).
    pub sleeve_fraction: f64,
    /// Depth of the neck cut below the `Neck` joint, at the neck's centre line, m.
    pub neck_depth_m: f64,
    /// Forward tilt of the neck cut (its front is lower than its back), deg.
    pub neck_front_tilt_deg: f64,
    /// Smoothing passes over the offset normals and displacements.
    #[serde(default = "default_smoothing")]
    pub offset_smoothing_iterations: usize,
    /// Remeshing iterations.
    #[serde(default = "default_remesh_iterations")]
    pub remesh_iterations: usize,
}

fn default_smoothing() -> usize {
    30
}

fn default_remesh_iterations() -> usize {
    10
}

impl TshirtRecipe {
    /// Check every field's range.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid("T-shirt recipe", m));
        if self.name.is_empty() || self.name.contains(['/', '\\']) {
            return bad(format!(
                "name {:?} must be non-empty, without slashes",
                self.name
            ));
        }
        if !(100..=2_000_000).contains(&self.triangles) {
            return bad(format!(
                "triangles = {} is outside [100, 2000000]",
                self.triangles
            ));
        }
        let ranges = [
            ("ease_m", self.ease_m, 0.001, 0.1),
            ("hem_below_hips_m", self.hem_below_hips_m, -0.3, 0.3),
            ("sleeve_fraction", self.sleeve_fraction, 0.15, 0.95),
            ("neck_depth_m", self.neck_depth_m, -0.05, 0.2),
            ("neck_front_tilt_deg", self.neck_front_tilt_deg, -45.0, 60.0),
        ];
        for (name, value, lo, hi) in ranges {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return bad(format!("{name} = {value} is outside [{lo}, {hi}]"));
            }
        }
        if self.offset_smoothing_iterations > 1000 || self.remesh_iterations > 100 {
            return bad(format!(
                "offset_smoothing_iterations = {} (at most 1000), remesh_iterations = {} (at most 100)",
                self.offset_smoothing_iterations, self.remesh_iterations
            ));
        }
        Ok(())
    }

    /// Parse and validate a recipe from JSON text; `path` names the file in errors.
    pub fn from_json(bytes: &[u8], path: &Path) -> Result<Self> {
        let recipe: Self = serde_json::from_slice(bytes)
            .map_err(|e| Error::format(path, format!("line {}: {e}", e.line())))?;
        recipe.validate().map_err(|e| match e {
            Error::Invalid { what, message } => {
                Error::format(path, format!("invalid {what}: {message}"))
            }
            other => other,
        })?;
        Ok(recipe)
    }

    /// Read and validate a recipe file.
    pub fn load(path: &Path) -> Result<Self> {
        Self::from_json(&sartor_core::io::read_file(path)?, path)
    }
}

/// The T-shirt surface and what was measured while building it.
#[derive(Clone, Debug)]
pub struct TshirtSurface {
    /// The remeshed garment surface (template positions, exactly the recipe's triangle count).
    pub mesh: TriMesh,
    /// The cut body surface before the offset (on the body).
    pub cut: TriMesh,
    /// Figures of the build.
    pub stats: TshirtStats,
}

/// Figures measured while building a T-shirt.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TshirtStats {
    /// Triangles of the cut body surface.
    pub cut_triangles: usize,
    /// Area of the cut body surface, m².
    pub cut_area_m2: f64,
    /// Radius of the disk of each sleeve cut (left, right), m.
    pub sleeve_cut_radius_m: [f64; 2],
    /// Smallest signed distance of an offset vertex to the body before remeshing, mm.
    pub offset_min_distance_mm: f64,
    /// Vertices of the remeshed surface pushed out because they were closer than half the
    /// ease.
    pub pushed_out_vertices: usize,
}

/// One clipping surface: keep where `value(p) <= 0`.
enum Cut {
    /// Keep the side of the plane opposite to `normal`.
    Plane {
        point: Vector3<f64>,
        normal: Vector3<f64>,
    },
    /// Remove what lies beyond `t_m` along `axis` from `origin`, within `radius_m` of the axis.
    Disk {
        origin: Vector3<f64>,
        axis: Vector3<f64>,
        t_m: f64,
        radius_m: f64,
    },
}

impl Cut {
    fn value(&self, p: &Vector3<f64>) -> f64 {
        match self {
            Cut::Plane { point, normal } => (p - point).dot(normal),
            Cut::Disk {
                origin,
                axis,
                t_m,
                radius_m,
            } => {
                let d = p - origin;
                let t = d.dot(axis);
                let r = (d - axis * t).norm();
                if r <= *radius_m {
                    t - t_m
                } else {
                    // Outside the disk: never removed.
                    -1.0
                }
            }
        }
    }
}

/// Build the T-shirt surface of `recipe` on `body`'s template.
pub fn build_tshirt(body: &BodyModel, recipe: &TshirtRecipe) -> Result<TshirtSurface> {
    recipe.validate()?;
    let skeleton = body.skeleton();
    let joints = body.joint_template();
    let joint = |name: &str| {
        skeleton
            .index_of(name)
            .map(|j| joints[j])
            .ok_or_else(|| Error::invalid("body model", format!("no joint named {name:?}")))
    };
    let hips = joint("Hips")?;
    let neck = joint("Neck")?;
    let body_positions = body.template().positions();
    let arms = body_arms(body)?;

    let tilt = recipe.neck_front_tilt_deg.to_radians();
    let mut cuts = vec![
        Cut::Plane {
            point: Vector3::new(0.0, hips.y - recipe.hem_below_hips_m, 0.0),
            normal: -Vector3::y(),
        },
        Cut::Plane {
            point: neck - Vector3::y() * recipe.neck_depth_m,
            normal: Vector3::new(0.0, tilt.cos(), tilt.sin()),
        },
    ];
    let mut sleeve_radius = [0.0; 2];
    for (k, arm) in arms.iter().enumerate() {
        let (cut, radius) = sleeve_cut(arm, body_positions, recipe.sleeve_fraction)?;
        sleeve_radius[k] = radius;
        cuts.push(cut);
    }

    let (mut positions, mut faces) = (body_positions.to_vec(), body.faces().to_vec());
    for cut in &cuts {
        (positions, faces) = clip(&positions, &faces, cut);
    }
    let cut = smooth_openings(&clean_piece(positions, faces)?)?;
    let n_loops = cut.topology().boundary_loops().len();
    if n_loops != 4 {
        return Err(Error::invalid(
            "T-shirt",
            format!(
                "the cut body surface has {n_loops} openings, expected 4 (neck, hem, sleeves); \
                 adjust the recipe's cut heights"
            ),
        ));
    }

    let proximity = MeshProximity::new(body_positions, body.faces())?;
    let (offset, offset_min) = offset_surface(
        &cut,
        &proximity,
        recipe.ease_m,
        recipe.offset_smoothing_iterations,
    )?;
    let mut options = RemeshOptions::new(recipe.triangles);
    options.iterations = recipe.remesh_iterations;
    // The openings are smooth curves: no boundary corner to keep.
    options.corner_angle_deg = 180.0;
    let remeshed = remesh_to_count(&offset, &options)?;
    let (mesh, pushed) = push_out(&remeshed, &proximity, 0.5 * recipe.ease_m)?;
    let crossings = self_intersections(&mesh);
    if let Some((f, g)) = crossings.first() {
        return Err(Error::invalid(
            "T-shirt",
            format!(
                "the garment intersects itself ({} triangle pairs, first {f} and {g}); \
                 try more offset smoothing or less ease",
                crossings.len()
            ),
        ));
    }
    Ok(TshirtSurface {
        stats: TshirtStats {
            cut_triangles: cut.n_faces(),
            cut_area_m2: cut.face_areas().iter().sum(),
            sleeve_cut_radius_m: sleeve_radius,
            offset_min_distance_mm: offset_min * 1e3,
            pushed_out_vertices: pushed,
        },
        mesh,
        cut,
    })
}

/// The disk cut of one sleeve and its radius: halfway between the farthest arm vertex and the
/// nearest torso vertex from the bone axis, near the cut.
fn sleeve_cut(arm: &Arm, positions: &[Vector3<f64>], fraction: f64) -> Result<(Cut, f64)> {
    let bone = arm.elbow - arm.shoulder;
    let length = bone.norm();
    let axis = bone / length;
    let t_m = fraction * length;
    let band = 0.1 * length;
    let mut arm_r: f64 = 0.0;
    let mut torso_r = f64::INFINITY;
    for (p, w) in positions.iter().zip(&arm.weight) {
        let d = p - arm.shoulder;
        let t = d.dot(&axis);
        if (t - t_m).abs() > band {
            continue;
        }
        let r = (d - axis * t).norm();
        if *w >= 0.5 {
            arm_r = arm_r.max(r);
        } else if *w <= 0.05 {
            torso_r = torso_r.min(r);
        }
    }
    if arm_r == 0.0 || arm_r >= torso_r {
        return Err(Error::invalid(
            "T-shirt",
            format!(
                "the sleeve cut at {fraction} of the upper arm cannot separate the arm \
                 (radius {arm_r:.3} m) from the torso (from {torso_r:.3} m); choose another \
                 sleeve_fraction"
            ),
        ));
    }
    let radius_m = (0.5 * (arm_r + torso_r)).min(2.0 * arm_r);
    Ok((
        Cut::Disk {
            origin: arm.shoulder,
            axis,
            t_m,
            radius_m,
        },
        radius_m,
    ))
}

/// Clip a triangle set to `cut.value(p) <= 0`, splitting the triangles that straddle the cut.
/// Vertices within 5 % of an edge from a crossing are first moved onto it, so no sliver
/// triangle is created. Unused vertices are dropped.
fn clip(
    positions: &[Vector3<f64>],
    faces: &[[u32; 3]],
    cut: &Cut,
) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
    let mut p = positions.to_vec();
    let mut s: Vec<f64> = p.iter().map(|x| cut.value(x)).collect();
    // Snap near-crossing vertices onto the cut (in face order: deterministic).
    for t in faces {
        for k in 0..3 {
            let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
            if s[a] * s[b] < 0.0 {
                let u = s[a] / (s[a] - s[b]);
                let (snap, other, w) = if u < 0.05 {
                    (a, b, u)
                } else if u > 0.95 {
                    (b, a, 1.0 - u)
                } else {
                    continue;
                };
                let moved = p[snap] + (p[other] - p[snap]) * w;
                p[snap] = moved;
                s[snap] = 0.0;
            }
        }
    }
    let mut crossing: BTreeMap<(u32, u32), u32> = BTreeMap::new();
    let mut out_faces = Vec::new();
    for t in faces {
        let mut poly: Vec<u32> = Vec::with_capacity(4);
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let (sa, sb) = (s[a as usize], s[b as usize]);
            if sa <= 0.0 {
                poly.push(a);
            }
            if (sa < 0.0 && sb > 0.0) || (sa > 0.0 && sb < 0.0) {
                let key = (a.min(b), a.max(b));
                let v = *crossing.entry(key).or_insert_with(|| {
                    let (i, j) = (key.0 as usize, key.1 as usize);
                    let u = s[i] / (s[i] - s[j]);
                    p.push(p[i] + (p[j] - p[i]) * u);
                    s.push(0.0);
                    (p.len() - 1) as u32
                });
                poly.push(v);
            }
        }
        for k in 1..poly.len().saturating_sub(1) {
            out_faces.push([poly[0], poly[k], poly[k + 1]]);
        }
    }
    compact(&p, &out_faces)
}

/// Drop unused vertices (keeping order).
fn compact(positions: &[Vector3<f64>], faces: &[[u32; 3]]) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
    let (used, faces) = sartor_core::compact_faces(faces, positions.len());
    (used.iter().map(|&v| positions[v as usize]).collect(), faces)
}

/// Keep the largest connected piece and trim ears until the piece is a clean manifold.
fn clean_piece(positions: Vec<Vector3<f64>>, faces: Vec<[u32; 3]>) -> Result<TriMesh> {
    let (mut positions, mut faces) = (positions, faces);
    for _round in 0..100 {
        let topology = sartor_core::MeshTopology::new(positions.len(), &faces);
        let (component, n) = topology.face_components();
        let mut size = vec![0usize; n];
        for &c in &component {
            size[c as usize] += 1;
        }
        let largest = (0..n)
            .max_by_key(|&c| (size[c], std::cmp::Reverse(c)))
            .unwrap_or(0) as u32;
        // Ears: triangles with two or three boundary edges.
        let keep: Vec<bool> = (0..faces.len())
            .map(|f| {
                let boundary = topology.face_edges[f]
                    .iter()
                    .filter(|&&e| topology.edge_faces[e as usize].len() == 1)
                    .count();
                component[f] == largest && boundary < 2
            })
            .collect();
        let done = keep.iter().all(|k| *k) && topology.check_manifold().is_ok();
        if done {
            let mesh = TriMesh::new(positions, faces)?;
            return Ok(mesh);
        }
        if keep.iter().all(|k| *k) {
            // Non-manifold vertex: drop the triangles of its smaller fans.
            return Err(Error::invalid(
                "T-shirt",
                format!(
                    "the cut body surface is not a manifold: {}",
                    topology
                        .check_manifold()
                        .err()
                        .map_or(String::new(), |e| e.to_string())
                ),
            ));
        }
        let kept: Vec<[u32; 3]> = faces
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(t, _)| *t)
            .collect();
        (positions, faces) = compact(&positions, &kept);
    }
    Err(Error::invalid(
        "T-shirt",
        "trimming the cut body surface did not converge",
    ))
}

/// Smooth the openings of the cut piece: the cut follows the body into its concavities (the
/// top of the gluteal cleft makes a notch in the hem), which a garment bridges. Each boundary
/// loop (planar: it lies in its cut plane) is smoothed along itself (`OPENING_SMOOTHING`
/// Laplacian passes, which keep it in its plane), and the boundary's displacement is spread
/// over the next rings of interior vertices so no triangle folds.
fn smooth_openings(cut: &TriMesh) -> Result<TriMesh> {
    const OPENING_SMOOTHING: usize = 10;
    const SPREAD_PASSES: usize = 10;
    let topology = cut.topology();
    let p = cut.positions();
    let mut moved = p.to_vec();
    let mut on_boundary = vec![false; p.len()];
    for lp in topology.boundary_loops() {
        let n = lp.len();
        for &v in &lp {
            on_boundary[v as usize] = true;
        }
        for _ in 0..OPENING_SMOOTHING {
            let old: Vec<Vector3<f64>> = lp.iter().map(|&v| moved[v as usize]).collect();
            for k in 0..n {
                let mid = 0.5 * (old[(k + n - 1) % n] + old[(k + 1) % n]);
                moved[lp[k] as usize] = 0.5 * (old[k] + mid);
            }
        }
    }
    // Spread the boundary displacement inwards (boundary values fixed).
    let mut displacement: Vec<Vector3<f64>> = moved.iter().zip(p).map(|(m, q)| m - q).collect();
    for _ in 0..SPREAD_PASSES {
        let old = displacement.clone();
        for v in 0..p.len() {
            if on_boundary[v] {
                continue;
            }
            let nb = topology.neighbours(v);
            let mean = nb.iter().map(|&u| old[u as usize]).sum::<Vector3<f64>>() / nb.len() as f64;
            displacement[v] = 0.5 * (old[v] + mean);
        }
    }
    let positions: Vec<Vector3<f64>> = p.iter().zip(&displacement).map(|(q, d)| q + d).collect();
    let before = cut.face_normals();
    let smoothed = cut.with_positions(positions)?;
    let folded = smoothed
        .face_normals()
        .iter()
        .zip(&before)
        .filter(|(a, b)| a.dot(b) <= 0.0)
        .count();
    if folded > 0 {
        return Err(Error::invalid(
            "T-shirt",
            format!("smoothing the openings folded {folded} triangles of the cut body surface"),
        ));
    }
    Ok(smoothed)
}

/// Uniform-Laplacian smoothing of a per-vertex vector field (one Jacobi step, weight ½).
fn smooth_field(field: &mut [Vector3<f64>], topology: &sartor_core::MeshTopology) {
    let old = field.to_vec();
    for (v, f) in field.iter_mut().enumerate() {
        let nb = topology.neighbours(v);
        if nb.is_empty() {
            continue;
        }
        let mean = nb.iter().map(|&u| old[u as usize]).sum::<Vector3<f64>>() / nb.len() as f64;
        *f = 0.5 * (old[v] + mean);
    }
}

/// Offset the cut surface by `ease_m` (smoothed normals, then push-out and smoothing rounds).
/// Returns the offset mesh and the smallest signed distance of its vertices to the body.
fn offset_surface(
    cut: &TriMesh,
    body: &MeshProximity,
    ease_m: f64,
    smoothing: usize,
) -> Result<(TriMesh, f64)> {
    let topology = cut.topology();
    let base = cut.positions();
    let mut normals = cut.vertex_normals();
    for _ in 0..smoothing {
        smooth_field(&mut normals, &topology);
        for n in &mut normals {
            *n = n.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
        }
    }
    let mut displacement: Vec<Vector3<f64>> = normals.iter().map(|n| n * ease_m).collect();
    let push = |displacement: &mut [Vector3<f64>], target: f64| {
        let moved: Vec<Option<Vector3<f64>>> = displacement
            .par_iter()
            .zip(base)
            .map(|(d, p)| {
                let q = p + d;
                let hit = body.closest(&q);
                (hit.signed_distance_m < target).then(|| {
                    let dir = if hit.signed_distance_m > 1e-9 {
                        (q - hit.point) / hit.signed_distance_m
                    } else {
                        hit.normal
                    };
                    hit.point + dir * target - p
                })
            })
            .collect();
        for (d, m) in displacement.iter_mut().zip(moved) {
            if let Some(m) = m {
                *d = m;
            }
        }
    };
    for _ in 0..10 {
        push(&mut displacement, ease_m);
        for _ in 0..3 {
            smooth_field(&mut displacement, &topology);
        }
    }
    push(&mut displacement, ease_m);
    let moved: Vec<Vector3<f64>> = base.iter().zip(&displacement).map(|(p, d)| p + d).collect();
    let min = moved
        .par_iter()
        .map(|q| body.closest(q).signed_distance_m)
        .reduce(|| f64::INFINITY, f64::min);
    Ok((cut.with_positions(moved)?, min))
}

/// Push every vertex closer to the body than `min_m` out to `min_m`; returns the mesh and how
/// many vertices moved.
fn push_out(mesh: &TriMesh, body: &MeshProximity, min_m: f64) -> Result<(TriMesh, usize)> {
    let moved: Vec<Option<Vector3<f64>>> = mesh
        .positions()
        .par_iter()
        .map(|q| {
            let hit = body.closest(q);
            (hit.signed_distance_m < min_m).then(|| {
                let dir = if hit.signed_distance_m > 1e-9 {
                    (q - hit.point) / hit.signed_distance_m
                } else {
                    hit.normal
                };
                hit.point + dir * min_m
            })
        })
        .collect();
    let count = moved.iter().filter(|m| m.is_some()).count();
    if count == 0 {
        return Ok((mesh.clone(), 0));
    }
    let positions = mesh
        .positions()
        .iter()
        .zip(moved)
        .map(|(p, m)| m.unwrap_or(*p))
        .collect();
    Ok((mesh.with_positions(positions)?, count))
}
