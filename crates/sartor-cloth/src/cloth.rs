//! A cloth: validated rest mesh, material, per-triangle material frames and the rest data of
//! every element (membrane triangles, bending hinges, lumped masses).

use nalgebra::Vector3;
use sartor_core::{MeshTopology, TriMesh};

use crate::energy::{BendingRest, MembraneRest, dihedral_angle};
use crate::garment::Garment;
use crate::material::Material;
use crate::{Error, Result};

/// A cloth ready to simulate. Invariants (checked by [`Cloth::new`]): the rest mesh is a valid,
/// oriented, connected 2-manifold (with boundary) in which every vertex belongs to a triangle,
/// and every triangle has a non-degenerate material frame.
#[derive(Clone, Debug)]
pub struct Cloth {
    rest: TriMesh,
    topology: MeshTopology,
    material: Material,
    u_axes: Vec<Vector3<f64>>,
    membranes: Vec<MembraneRest>,
    hinges: Vec<BendingRest>,
    mass_kg: Vec<f64>,
    area_m2: Vec<f64>,
}

impl Cloth {
    /// Build a cloth from positions and faces (validated as a [`TriMesh`] first, so NaNs,
    /// bad indices and zero-area triangles are reported here too). See [`Cloth::new`].
    pub fn from_parts(
        positions: Vec<Vector3<f64>>,
        faces: Vec<[u32; 3]>,
        material: Material,
        u_axes: Option<&[Vector3<f64>]>,
    ) -> Result<Self> {
        Self::new(TriMesh::new(positions, faces)?, material, u_axes)
    }

    /// Build a cloth from its rest mesh.
    ///
    /// `u_axes` gives, per triangle, the material's u direction ("around" the body; v is
    /// "vertical", `v = n × u`); each is projected onto its triangle's plane. When `None`, a
    /// triangle's u axis is its first edge `x1 − x0`.
    pub fn new(rest: TriMesh, material: Material, u_axes: Option<&[Vector3<f64>]>) -> Result<Self> {
        let topology = rest.topology();
        topology.check_manifold()?;
        let (_, n_components) = topology.face_components();
        if n_components != 1 {
            return Err(Error::invalid(
                "cloth mesh",
                format!(
                    "the mesh has {n_components} disconnected parts; a cloth must be one piece"
                ),
            ));
        }
        let positions = rest.positions();
        let faces = rest.faces();
        if let Some(v) = rest.first_unused_vertex() {
            return Err(Error::invalid(
                "cloth mesh",
                format!("vertex {v} belongs to no triangle"),
            ));
        }
        if let Some(axes) = u_axes
            && axes.len() != faces.len()
        {
            return Err(Error::invalid(
                "material frames",
                format!("{} u axes for {} triangles", axes.len(), faces.len()),
            ));
        }

        let mut frames = Vec::with_capacity(faces.len());
        let mut membranes = Vec::with_capacity(faces.len());
        for (f, t) in faces.iter().enumerate() {
            let x = t.map(|i| positions[i as usize]);
            let normal = (x[1] - x[0]).cross(&(x[2] - x[0])).normalize();
            let wanted = u_axes.map_or(x[1] - x[0], |a| a[f]);
            let in_plane = wanted - normal * normal.dot(&wanted);
            let u = in_plane
                .try_normalize(1e-9 * wanted.norm())
                .filter(|u| u.iter().all(|c| c.is_finite()))
                .ok_or_else(|| {
                    Error::invalid(
                        "material frames",
                        format!("the u axis {wanted:?} of triangle {f} is zero or normal to it"),
                    )
                })?;
            let v = normal.cross(&u);
            let rest_data = MembraneRest::new(&x, &u, &v).ok_or_else(|| {
                Error::invalid("cloth mesh", format!("triangle {f} is degenerate"))
            })?;
            frames.push((u, v));
            membranes.push(rest_data);
        }

        let mut hinges = Vec::new();
        for hinge in topology.hinges() {
            let vertices = hinge.vertices;
            let [fa, fb] = hinge.faces.map(|f| f as usize);
            let x = vertices.map(|i| positions[i as usize]);
            let e = x[1] - x[0];
            let angle_in = |f: usize| {
                let (u, v) = frames[f];
                v.dot(&e).atan2(u.dot(&e))
            };
            hinges.push(BendingRest {
                vertices,
                rest_angle_rad: dihedral_angle(&x),
                area_sum_m2: membranes[fa].area_m2 + membranes[fb].area_m2,
                edge_angle_rad: [angle_in(fa), angle_in(fb)],
            });
        }

        let (area_m2, mass_kg) = lumped_areas_and_masses(&rest, &membranes, &material);
        Ok(Self {
            u_axes: frames.iter().map(|(u, _)| *u).collect(),
            rest,
            topology,
            material,
            membranes,
            hinges,
            mass_kg,
            area_m2,
        })
    }

    /// A cloth made of a garment template: it starts at the template positions, with the
    /// garment's own rest metric — rest edge matrices and areas, material frames, rest dihedral
    /// angles — which for a template relaxed on the body (or a sewing pattern) differs from the
    /// template shape. [`Cloth::new`] would instead take the template shape itself as the rest
    /// state.
    pub fn from_garment(garment: &Garment, material: Material) -> Result<Self> {
        let rest = garment.mesh().clone();
        let topology = rest.topology();
        let faces = rest.faces();
        let membranes: Vec<MembraneRest> = garment
            .rest_dm()
            .iter()
            .zip(garment.rest_area_m2())
            .enumerate()
            .map(|(f, (dm, &area_m2))| {
                dm.try_inverse()
                    .filter(|inv| inv.iter().all(|v| v.is_finite()) && area_m2 > 0.0)
                    .map(|inv_dm| MembraneRest { inv_dm, area_m2 })
                    .ok_or_else(|| {
                        Error::invalid(
                            "garment",
                            format!("triangle {f} has a degenerate rest shape"),
                        )
                    })
            })
            .collect::<Result<_>>()?;
        let hinges_in = topology.hinges();
        if hinges_in.len() != garment.hinges().len() {
            return Err(Error::invalid(
                "garment",
                format!(
                    "{} hinges stored for {} interior edges",
                    garment.hinges().len(),
                    hinges_in.len()
                ),
            ));
        }
        let mut hinges = Vec::with_capacity(hinges_in.len());
        for (i, (hinge, &rest_angle_rad)) in hinges_in
            .iter()
            .zip(garment.rest_dihedral_rad())
            .enumerate()
        {
            let vertices = hinge.vertices;
            if vertices != garment.hinges()[i] {
                return Err(Error::invalid(
                    "garment",
                    format!("hinge {i} does not match the mesh's interior edge"),
                ));
            }
            let [fa, fb] = hinge.faces.map(|f| f as usize);
            // The edge x0 → x1 in each face's rest (u, v) coordinates: corner k of face f sits
            // at 0, Dm[:, 0], Dm[:, 1].
            let angle_in = |f: usize| -> Result<f64> {
                let t = faces[f];
                let dm = garment.rest_dm()[f];
                let corner = |v: u32| {
                    t.iter().position(|&c| c == v).map(|k| match k {
                        0 => nalgebra::Vector2::zeros(),
                        _ => dm.column(k - 1).into_owned(),
                    })
                };
                match (corner(vertices[0]), corner(vertices[1])) {
                    (Some(a), Some(b)) => {
                        let e = b - a;
                        Ok(e.y.atan2(e.x))
                    }
                    _ => Err(Error::invalid(
                        "garment",
                        format!("hinge {i}: its edge is not in face {f}"),
                    )),
                }
            };
            hinges.push(BendingRest {
                vertices,
                rest_angle_rad,
                area_sum_m2: membranes[fa].area_m2 + membranes[fb].area_m2,
                edge_angle_rad: [angle_in(fa)?, angle_in(fb)?],
            });
        }
        let (area_m2, mass_kg) = lumped_areas_and_masses(&rest, &membranes, &material);
        Ok(Self {
            u_axes: garment.frame_u().to_vec(),
            rest,
            topology,
            material,
            membranes,
            hinges,
            mass_kg,
            area_m2,
        })
    }

    /// The mesh the simulation starts from: the rest shape for [`Cloth::new`], the garment
    /// template for [`Cloth::from_garment`] (faces and topology are the same either way).
    pub fn rest_mesh(&self) -> &TriMesh {
        &self.rest
    }

    /// The median length of the rest mesh's edges (each edge once), m; 0 without faces.
    pub fn median_rest_edge_m(&self) -> f64 {
        let p = self.rest.positions();
        let mut lengths: Vec<f64> = self
            .topology
            .edges
            .iter()
            .map(|&[a, b]| (p[a as usize] - p[b as usize]).norm())
            .collect();
        if lengths.is_empty() {
            return 0.0;
        }
        let mid = lengths.len() / 2;
        *lengths.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    /// Triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        self.rest.faces()
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.rest.n_vertices()
    }

    /// Topology of the rest mesh.
    pub fn topology(&self) -> &MeshTopology {
        &self.topology
    }

    /// The material.
    pub fn material(&self) -> &Material {
        &self.material
    }

    /// Per-triangle material u axis (unit, in the rest triangle's plane).
    pub fn u_axes(&self) -> &[Vector3<f64>] {
        &self.u_axes
    }

    /// Per-triangle membrane rest data.
    pub fn membranes(&self) -> &[MembraneRest] {
        &self.membranes
    }

    /// Bending hinges (one per interior edge).
    pub fn hinges(&self) -> &[BendingRest] {
        &self.hinges
    }

    /// Lumped vertex masses (density × area / 3 from each triangle), kg.
    pub fn masses_kg(&self) -> &[f64] {
        &self.mass_kg
    }

    /// Lumped vertex rest areas, m².
    pub fn vertex_areas_m2(&self) -> &[f64] {
        &self.area_m2
    }

    /// Total mass, kg.
    pub fn total_mass_kg(&self) -> f64 {
        self.mass_kg.iter().sum()
    }

    /// A vertex order that keeps near vertices near in memory: the rest positions sorted along
    /// a Z-order (Morton) curve of a 1024³ grid over their box, ties by index. Returns `order`
    /// with `order[k]` the vertex that comes `k`-th.
    pub(crate) fn spatial_order(&self) -> Vec<u32> {
        let x = self.rest.positions();
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for p in x {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let scale = 1023.0 / (hi - lo).max().max(f64::MIN_POSITIVE);
        // Spread the 10 bits of `v` to every third bit.
        let spread = |v: u64| {
            let mut v = v & 0x3ff;
            v = (v | (v << 16)) & 0x0300_00ff;
            v = (v | (v << 8)) & 0x0300_f00f;
            v = (v | (v << 4)) & 0x030c_30c3;
            (v | (v << 2)) & 0x0924_9249
        };
        let code = |p: &Vector3<f64>| {
            let c = (p - lo) * scale;
            spread(c.x as u64) | (spread(c.y as u64) << 1) | (spread(c.z as u64) << 2)
        };
        let mut order: Vec<u32> = (0..x.len() as u32).collect();
        order.sort_by_key(|&v| (code(&x[v as usize]), v));
        order
    }

    /// The same cloth with its vertices renumbered and its elements reordered to follow:
    /// vertex `order[k]` of `self` becomes vertex `k` (`order` a permutation of the vertices),
    /// and triangles and hinges are sorted by their first vertex in the new numbering (ties
    /// in their old order), so that consecutive elements touch nearby vertices. Rest data
    /// travel with their elements.
    pub(crate) fn renumbered(&self, order: &[u32]) -> Result<Self> {
        let n = self.n_vertices();
        let mut place = vec![u32::MAX; n];
        for (k, &v) in order.iter().enumerate() {
            place[v as usize] = k as u32;
        }
        if order.len() != n || place.contains(&u32::MAX) {
            return Err(Error::invalid(
                "vertex order",
                format!("not a permutation of the cloth's {n} vertices"),
            ));
        }
        let relabel = |v: &u32| place[*v as usize];
        let first = |vs: &[u32]| vs.iter().map(|&v| place[v as usize]).min().unwrap_or(0);
        let mut tri_order: Vec<usize> = (0..self.faces().len()).collect();
        tri_order.sort_by_key(|&t| (first(&self.faces()[t]), t));
        let mut hinge_order: Vec<usize> = (0..self.hinges.len()).collect();
        hinge_order.sort_by_key(|&e| (first(&self.hinges[e].vertices), e));
        let permute = |values: &[f64]| order.iter().map(|&v| values[v as usize]).collect();
        let rest = TriMesh::new(
            order
                .iter()
                .map(|&v| self.rest.positions()[v as usize])
                .collect(),
            tri_order
                .iter()
                .map(|&t| self.faces()[t].each_ref().map(relabel))
                .collect(),
        )?;
        Ok(Self {
            topology: rest.topology(),
            rest,
            material: self.material.clone(),
            u_axes: tri_order.iter().map(|&t| self.u_axes[t]).collect(),
            membranes: tri_order.iter().map(|&t| self.membranes[t]).collect(),
            hinges: hinge_order
                .iter()
                .map(|&e| {
                    let h = self.hinges[e];
                    BendingRest {
                        vertices: h.vertices.each_ref().map(relabel),
                        ..h
                    }
                })
                .collect(),
            mass_kg: permute(&self.mass_kg),
            area_m2: permute(&self.area_m2),
        })
    }
}

/// Per vertex, a third of the rest area of each adjacent triangle, and that area times the
/// material's density.
fn lumped_areas_and_masses(
    mesh: &TriMesh,
    membranes: &[MembraneRest],
    material: &Material,
) -> (Vec<f64>, Vec<f64>) {
    let mut area_m2 = vec![0.0; mesh.n_vertices()];
    for (t, m) in mesh.faces().iter().zip(membranes) {
        for &v in t {
            area_m2[v as usize] += m.area_m2 / 3.0;
        }
    }
    let mass_kg = area_m2
        .iter()
        .map(|a| a * material.density_kg_per_m2())
        .collect();
    (area_m2, mass_kg)
}

/// A rectangular sheet of `nu × nv` quads split into triangles with alternating diagonals:
/// vertices `corner + i/nu · u_edge + j/nv · v_edge`, index `j · (nu + 1) + i`. Triangles are
/// counter-clockwise seen from `u_edge × v_edge`.
pub fn rectangle_sheet(
    corner: Vector3<f64>,
    u_edge: Vector3<f64>,
    v_edge: Vector3<f64>,
    nu: usize,
    nv: usize,
) -> Result<TriMesh> {
    if nu == 0 || nv == 0 {
        return Err(Error::invalid(
            "sheet",
            format!("needs at least one quad per side, got {nu} × {nv}"),
        ));
    }
    let mut positions = Vec::with_capacity((nu + 1) * (nv + 1));
    for j in 0..=nv {
        for i in 0..=nu {
            positions
                .push(corner + u_edge * (i as f64 / nu as f64) + v_edge * (j as f64 / nv as f64));
        }
    }
    let index = |i: usize, j: usize| (j * (nu + 1) + i) as u32;
    let mut faces = Vec::with_capacity(2 * nu * nv);
    for j in 0..nv {
        for i in 0..nu {
            let (a, b, c, d) = (
                index(i, j),
                index(i + 1, j),
                index(i + 1, j + 1),
                index(i, j + 1),
            );
            if (i + j) % 2 == 0 {
                faces.push([a, b, c]);
                faces.push([a, c, d]);
            } else {
                faces.push([a, b, d]);
                faces.push([b, c, d]);
            }
        }
    }
    Ok(TriMesh::new(positions, faces)?)
}
