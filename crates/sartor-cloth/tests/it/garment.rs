//! Garment templates: remeshing, the procedural T-shirt, import, the file format.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use sartor_cloth::{
    Garment, GarmentConfig, GarmentProvenance, GarmentReport, MeshQuality, ObjImportOptions,
    RemeshOptions, RestSource, SourceKind, TshirtRecipe, build_garment, build_tshirt,
    import_obj_garment, material_u_axes, remesh_isotropic, remesh_to_count,
};
use sartor_core::{MeshProximity, TriMesh};

/// A fresh empty folder under the system's temporary folder.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sartor-garment-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temporary folder");
    dir
}

/// An open cylinder of radius `r` around +Y (height `h`), `nu × nv` quads: deliberately
/// anisotropic cells (wide and short), outward normals. Two boundary loops.
fn cylinder(r: f64, h: f64, nu: usize, nv: usize) -> TriMesh {
    let mut p = Vec::new();
    for j in 0..=nv {
        for i in 0..nu {
            let a = i as f64 / nu as f64 * std::f64::consts::TAU;
            p.push(Vector3::new(
                r * a.sin(),
                h * j as f64 / nv as f64,
                r * a.cos(),
            ));
        }
    }
    let id = |i: usize, j: usize| (j * nu + i % nu) as u32;
    let mut f = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    TriMesh::new(p, f).expect("valid cylinder")
}

/// A spherical cap of radius `r` (polar angle up to `max_polar`), built from a polar grid
/// (very uneven triangles near the pole). One boundary loop.
fn sphere_cap(r: f64, max_polar: f64, rings: usize, segments: usize) -> TriMesh {
    let mut p = vec![Vector3::new(0.0, r, 0.0)];
    for j in 1..=rings {
        let polar = max_polar * j as f64 / rings as f64;
        for i in 0..segments {
            let a = i as f64 / segments as f64 * std::f64::consts::TAU;
            p.push(r * Vector3::new(polar.sin() * a.sin(), polar.cos(), polar.sin() * a.cos()));
        }
    }
    let id = |i: usize, j: usize| (1 + (j - 1) * segments + i % segments) as u32;
    let mut f = Vec::new();
    for i in 0..segments {
        f.push([0, id(i, 1), id(i + 1, 1)]);
    }
    for j in 1..rings {
        for i in 0..segments {
            f.push([id(i, j), id(i, j + 1), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i + 1, j)]);
        }
    }
    TriMesh::new(p, f).expect("valid cap")
}

/// Largest distance from the vertices of `a` to the surface `b`.
fn one_sided_distance(a: &TriMesh, b: &TriMesh) -> f64 {
    let prox = MeshProximity::new(b.positions(), b.faces()).expect("valid surface");
    a.positions()
        .iter()
        .map(|p| prox.closest(p).signed_distance_m.abs())
        .fold(0.0, f64::max)
}

fn check_remesh(input: &TriMesh, target: usize, loops: usize) -> MeshQuality {
    let out = remesh_to_count(input, &RemeshOptions::new(target)).expect("remeshed");
    let q = MeshQuality::of(&out);
    assert_eq!(q.triangles, target);
    assert!(q.manifold);
    assert_eq!(q.components, 1);
    assert_eq!(q.boundary_loops, loops);
    // Every output vertex lies on the input surface.
    assert!(one_sided_distance(&out, input) < 1e-9);
    // The output covers the input: input vertices are within the sagitta of an output edge.
    let l = q.edge_length.max_mm * 1e-3;
    assert!(one_sided_distance(input, &out) < 0.25 * l, "{q:?}");
    // Area preserved to within the faceting of the two meshes.
    let area_in: f64 = input.face_areas().iter().sum();
    assert!(
        (q.area_m2 / area_in - 1.0).abs() < 0.01,
        "{} vs {area_in}",
        q.area_m2
    );
    q
}

#[test]
fn remeshing_a_cylinder_hits_the_exact_count_with_good_triangles() {
    // 0.6 m tall, radius 0.15 m: about a torso; 64 × 6 long thin quads.
    let input = cylinder(0.15, 0.6, 64, 6);
    for target in [1500, 1501] {
        let q = check_remesh(&input, target, 2);
        assert!(q.min_angle_deg >= 30.0, "{q:?}");
        assert!(q.p1_min_angle_deg >= 35.0, "{q:?}");
        assert!(q.fraction_below_30_deg < 0.01, "{q:?}");
        assert!(q.edge_length.p95_over_p5 < 1.8, "{q:?}");
        assert!(q.edge_length.max_over_min < 3.5, "{q:?}");
    }
}

#[test]
fn remeshing_a_sphere_cap_hits_the_exact_count_with_good_triangles() {
    let input = sphere_cap(0.2, 2.0, 12, 40);
    let q = check_remesh(&input, 2001, 1);
    assert!(q.min_angle_deg >= 30.0, "{q:?}");
    assert!(q.fraction_below_30_deg < 0.01, "{q:?}");
    assert!(q.edge_length.p95_over_p5 < 1.8, "{q:?}");
}

#[test]
fn remeshing_keeps_the_corners_of_a_square() {
    let input = sartor_cloth::rectangle_sheet(
        Vector3::zeros(),
        Vector3::new(0.5, 0.0, 0.0),
        Vector3::new(0.0, 0.0, -0.3),
        5,
        3,
    )
    .unwrap();
    let out = remesh_to_count(&input, &RemeshOptions::new(700)).unwrap();
    assert_eq!(out.n_faces(), 700);
    assert!(MeshQuality::of(&out).min_angle_deg >= 30.0);
    for corner in [
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(0.5, 0.0, 0.0),
        Vector3::new(0.5, 0.0, -0.3),
        Vector3::new(0.0, 0.0, -0.3),
    ] {
        assert!(out.positions().iter().any(|p| (p - corner).norm() < 1e-12));
    }
    assert!(out.positions().iter().all(|p| p.y.abs() < 1e-12));
}

#[test]
fn remeshing_rejects_what_it_cannot_do() {
    // Three triangles on one edge.
    let p = vec![
        Vector3::zeros(),
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        -Vector3::y(),
    ];
    let nm = TriMesh::new(p, vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap();
    let e = remesh_to_count(&nm, &RemeshOptions::new(100)).unwrap_err();
    assert!(e.to_string().contains("non-manifold"), "{e}");
    // A closed mesh has an even triangle count.
    let tetra = TriMesh::new(
        vec![Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    )
    .unwrap();
    let e = remesh_to_count(&tetra, &RemeshOptions::new(101)).unwrap_err();
    assert!(e.to_string().contains("odd"), "{e}");
    let out = remesh_to_count(&tetra, &RemeshOptions::new(100)).unwrap();
    assert_eq!(out.n_faces(), 100);
}

fn provenance() -> GarmentProvenance {
    GarmentProvenance {
        kind: SourceKind::Recipe,
        path: "tests".into(),
        sha256: "0".repeat(64),
        body: None,
    }
}

fn assert_frames_orthonormal(g: &Garment) {
    let normals = g.mesh().face_normals();
    for ((u, v), n) in g.frame_u().iter().zip(g.frame_v()).zip(&normals) {
        assert!((u.norm() - 1.0).abs() < 1e-6);
        assert!((v.norm() - 1.0).abs() < 1e-6);
        assert!(u.dot(v).abs() < 1e-6);
        assert!(u.dot(n).abs() < 1e-6 && v.dot(n).abs() < 1e-6);
        assert!((u.cross(v) - n).norm() < 1e-5);
    }
    for (dm, a) in g.rest_dm().iter().zip(g.rest_area_m2()) {
        assert!(dm.determinant() > 0.0);
        assert!((0.5 * dm.determinant() - a).abs() < 1e-6 * a.max(1e-9));
    }
}

/// Size and SHA-256 of `garment.safetensors` for the remeshed tube below.
const GOLDEN_TUBE_BYTES: usize = 37192;
const GOLDEN_TUBE_SHA256: &str = "a4bee94945c39582b035cd354a70cecff9ad9f035ed4ece541dd602e2909b6c4";

#[test]
fn garment_files_round_trip_identically_and_deterministically() {
    let mesh = remesh_to_count(&cylinder(0.15, 0.3, 24, 4), &RemeshOptions::new(400)).unwrap();
    let axes = material_u_axes(&mesh, None).unwrap();
    let g = Garment::from_surface("tube", &mesh, &axes, provenance()).unwrap();
    assert_frames_orthonormal(&g);
    assert_eq!(g.rest_source(), RestSource::Surface);
    // Torso rule on a vertical tube: v is +Y, up to the tilt of the chords.
    let min_vy = g.frame_v().iter().map(|v| v.y).fold(1.0, f64::min);
    assert!(min_vy > 0.98, "{min_vy}");
    assert_eq!(g.hinges().len(), g.rest_dihedral_rad().len());
    // Rest angles of a 24-sided prism: its vertical edges bend by 2π/24 (ARCSim's sign:
    // negative for a convex hinge with outward normals), every other hinge is flat.
    let prism = cylinder(0.15, 0.3, 24, 4);
    let prism_axes = material_u_axes(&prism, None).unwrap();
    let pg = Garment::from_surface("prism", &prism, &prism_axes, provenance()).unwrap();
    let step = std::f64::consts::TAU / 24.0;
    let bent = pg
        .rest_dihedral_rad()
        .iter()
        .filter(|a| (**a + step).abs() < 1e-5)
        .count();
    let flat = pg
        .rest_dihedral_rad()
        .iter()
        .filter(|a| a.abs() < 1e-5)
        .count();
    assert_eq!(bent, 24 * 4);
    assert_eq!(bent + flat, pg.hinges().len());

    let dir = temp_dir("round-trip");
    g.save(&dir).unwrap();
    let back = Garment::load(&dir).unwrap();
    assert_eq!(back, g);
    let bytes = |d: &Path| {
        ["garment.safetensors", "garment.json", "garment.obj"]
            .map(|f| std::fs::read(d.join(f)).unwrap())
    };
    let first = bytes(&dir);
    back.save(&dir).unwrap();
    assert_eq!(bytes(&dir), first);
    assert_eq!(g.to_bytes().unwrap().0, first[0]);
    // Golden (size, hash) of the tensor file: the remesher and the format are deterministic.
    assert_eq!(
        (first[0].len(), sartor_core::io::sha256_hex(&first[0])),
        (GOLDEN_TUBE_BYTES, GOLDEN_TUBE_SHA256.to_string()),
        "the tube garment changed: update the golden pair if that is intended"
    );

    // A tampered tensor file is caught by the hash; a bad header names the file.
    let mut t = first[0].clone();
    let last = t.len() - 1;
    t[last] ^= 1;
    let e = Garment::from_bytes(&dir, &first[1], t)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("garment.safetensors") && e.contains("hash"),
        "{e}"
    );
    let e = Garment::from_bytes(&dir, b"{}", first[0].clone())
        .unwrap_err()
        .to_string();
    assert!(e.contains("garment.json"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);

    // The relaxation hook keeps the rest metric.
    let moved: Vec<Vector3<f64>> = g.positions().iter().map(|p| p * 1.01).collect();
    let relaxed = g.with_template_positions(moved).unwrap();
    assert_eq!(relaxed.rest_dm(), g.rest_dm());
    assert_eq!(relaxed.rest_dihedral_rad(), g.rest_dihedral_rad());
    assert_frames_orthonormal(&relaxed);
}

/// OBJ text of a 2 × 1 quad strip bent into a half-tube, with a pattern whose `vt` are in
/// centimetres and a seam: vertex 2 has two texture coordinates.
fn pattern_obj() -> String {
    let mut s = String::new();
    for (x, y, z) in [
        (0.0, 0.0, 0.0),
        (0.1, 0.0, 0.05),
        (0.2, 0.0, 0.0),
        (0.0, 0.1, 0.0),
        (0.1, 0.1, 0.05),
        (0.2, 0.1, 0.0),
    ] {
        s += &format!("v {x} {y} {z}\n");
    }
    for (u, v) in [
        (0.0, 0.0),
        (11.0, 0.0),
        (0.0, 10.0),
        (11.0, 10.0),
        // Second piece (mirrored: clockwise in the pattern).
        (30.0, 0.0),
        (19.0, 0.0),
        (30.0, 10.0),
        (19.0, 10.0),
    ] {
        s += &format!("vt {u} {v}\n");
    }
    s += "f 1/1 2/2 5/4\nf 1/1 5/4 4/3\nf 2/5 3/6 6/8\nf 2/5 6/8 5/7\n";
    s
}

#[test]
fn imports_a_garment_with_a_sewing_pattern() {
    let dir = temp_dir("pattern");
    let path = dir.join("strip.obj");
    std::fs::write(&path, pattern_obj()).unwrap();
    let options = ObjImportOptions {
        name: "strip".into(),
        pattern_scale_m: Some(0.01),
    };
    let g = import_obj_garment(&path, &options, None).unwrap();
    assert_eq!(g.rest_source(), RestSource::Pattern);
    assert_eq!(g.provenance().kind, SourceKind::Obj);
    assert_eq!(g.provenance().sha256.len(), 64);
    assert_frames_orthonormal(&g);
    let area: f64 = g.rest_area_m2().iter().sum();
    assert!((area - 2.0 * 0.11 * 0.1).abs() < 1e-7, "{area}");
    assert!(g.rest_dihedral_rad().iter().all(|a| *a == 0.0));
    // The same OBJ without the pattern: rest = 3D.
    let options3d = ObjImportOptions {
        name: "strip".into(),
        pattern_scale_m: None,
    };
    let g3 = import_obj_garment(&path, &options3d, None).unwrap();
    let area3: f64 = g3.rest_area_m2().iter().sum();
    let expected = 2.0 * 0.1 * (0.1f64.powi(2) + 0.05f64.powi(2)).sqrt();
    assert!((area3 - expected).abs() < 1e-7, "{area3}");
    // A pattern scale that is off by 100 is caught.
    let wrong = ObjImportOptions {
        name: "strip".into(),
        pattern_scale_m: Some(1.0),
    };
    let e = import_obj_garment(&path, &wrong, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("strip.obj") && e.contains("scale"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_garment_objs_are_rejected_naming_the_file() {
    let dir = temp_dir("bad");
    let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";
    let cases = [
        (
            "non-manifold.obj",
            format!("{quad}v 0.5 0.5 1\nv 0.5 0.5 -1\nf 1 2 3\nf 2 1 5\nf 1 2 6\n"),
            "non-manifold",
        ),
        (
            "zero-area.obj",
            format!("{quad}v 2 0 0\nf 1 2 3\nf 1 2 5\n"),
            "zero area",
        ),
        (
            "two-pieces.obj",
            format!("{quad}v 5 0 0\nv 6 0 0\nv 5 1 0\nf 1 2 3\nf 1 3 4\nf 5 6 7\n"),
            "disconnected",
        ),
        (
            "nan.obj",
            format!("{quad}v nan 0 0\nf 1 2 3\n"),
            "not finite",
        ),
        (
            "closed.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n".into(),
            "closed",
        ),
        (
            "unused-vertex.obj",
            format!("{quad}v 9 9 9\nf 1 2 3\nf 1 3 4\n"),
            "no triangle",
        ),
    ];
    let options = ObjImportOptions {
        name: "bad".into(),
        pattern_scale_m: None,
    };
    for (name, text, needle) in &cases {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let e = import_obj_garment(&path, &options, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
    }
    // Pattern faults: a degenerate pattern triangle, faces without vt.
    let pattern = ObjImportOptions {
        name: "bad".into(),
        pattern_scale_m: Some(1.0),
    };
    let vt_cases = [
        (
            "flat-vt.obj",
            format!("{quad}vt 0 0\nvt 1 0\nvt 2 0\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"),
            "zero area in the pattern",
        ),
        (
            "missing-vt.obj",
            format!("{quad}vt 0 0\nvt 1 0\nvt 1 1\nf 1/1 2/2 3/3\nf 1 3 4\n"),
            "texture coordinates",
        ),
        (
            "bad-vt-index.obj",
            format!("{quad}vt 0 0\nf 1/1 2/2 3/3\n"),
            "out of range",
        ),
    ];
    for (name, text, needle) in &vt_cases {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let e = import_obj_garment(&path, &pattern, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn configs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/garments")
}

#[test]
fn recipes_parse_and_reject_unknown_fields() {
    for name in [
        "tshirt.json",
        "tshirt-tiny.json",
        "tshirt-4210.json",
        "tshirt-8710.json",
        "tshirt-17710.json",
        "tshirt-26066.json",
    ] {
        let path = configs_dir().join(name);
        let recipe = TshirtRecipe::load(&path).unwrap();
        assert_eq!(
            GarmentConfig::load(&path).unwrap(),
            GarmentConfig::Tshirt(recipe)
        );
    }
    let path = Path::new("bad.json");
    let text = std::fs::read(configs_dir().join("tshirt-tiny.json")).unwrap();
    let mut value: serde_json::Value = serde_json::from_slice(&text).unwrap();
    value["colour"] = "red".into();
    let e = TshirtRecipe::from_json(value.to_string().as_bytes(), path).unwrap_err();
    assert!(
        e.to_string().contains("bad.json") && e.to_string().contains("colour"),
        "{e}"
    );
    value.as_object_mut().unwrap().remove("colour");
    value["ease_m"] = (-0.01).into();
    let e = TshirtRecipe::from_json(value.to_string().as_bytes(), path).unwrap_err();
    assert!(e.to_string().contains("ease_m"), "{e}");
}

#[test]
fn the_tiny_tshirt_fits_the_template_body() {
    let body = crate::common::load_builtin().expect("the built-in body (datasets/body/makehuman)");
    let recipe = TshirtRecipe::load(&configs_dir().join("tshirt-tiny.json")).unwrap();
    let surface = build_tshirt(&body, &recipe).unwrap();
    let mesh = &surface.mesh;
    assert_eq!(mesh.n_faces(), recipe.triangles);
    let axes = material_u_axes(mesh, Some(&body)).unwrap();
    let g = Garment::from_surface(&recipe.name, mesh, &axes, provenance()).unwrap();
    assert_frames_orthonormal(&g);
    let prox = MeshProximity::new(body.template().positions(), body.faces()).unwrap();
    let report = GarmentReport::measure(&g, Some(&prox));
    assert!(report.mesh.manifold);
    assert_eq!(report.mesh.components, 1);
    assert_eq!(report.mesh.boundary_loops, 4);
    assert!(report.mesh.min_angle_deg >= 30.0, "{report:?}");
    assert_eq!(report.self_intersecting_pairs, 0);
    let fit = report.body.clone().unwrap();
    assert_eq!(fit.vertices_inside, 0);
    assert!(
        fit.ease_min_mm >= 0.5 * recipe.ease_m * 1e3 - 1e-3,
        "{fit:?}"
    );
    assert!((5.0..=30.0).contains(&fit.ease_mean_mm), "{fit:?}");
    // About a T-shirt: 0.4–1.0 m² of cloth.
    assert!((0.4..1.0).contains(&report.mesh.area_m2), "{report:?}");
    // Sleeves exist: some triangles use the arm rule (v far from vertical).
    assert!(g.frame_v().iter().any(|v| v.y < 0.9));
}

#[test]
fn isotropic_remeshing_brings_edges_into_the_band() {
    let input = cylinder(0.15, 0.6, 64, 6);
    let out = remesh_isotropic(&input, 0.02, 10).unwrap();
    let q = MeshQuality::of(&out);
    assert!(q.manifold && q.boundary_loops == 2 && q.components == 1);
    // Splits and collapses keep edges within [4/5, 4/3] of the target; the relaxation that
    // ends each iteration moves them a little.
    let e = &q.edge_length;
    assert!(e.p5_mm > 0.7 * 20.0 && e.max_mm < 1.4 * 20.0, "{q:?}");
    assert!((e.p50_mm - 20.0).abs() < 2.0, "{q:?}");
    assert!(remesh_isotropic(&input, 0.0, 10).is_err());
}

#[test]
fn an_obj_config_builds_a_pattern_garment() {
    let dir = temp_dir("obj-config");
    let obj = dir.join("strip.obj");
    std::fs::write(&obj, pattern_obj()).unwrap();
    let config_path = dir.join("strip.json");
    let text = format!(
        "{{\"name\": \"strip\", \"obj\": {:?}, \"pattern_scale_m\": 0.01}}",
        obj.display().to_string()
    );
    let config = GarmentConfig::from_json(text.as_bytes(), &config_path).unwrap();
    assert_eq!(config.name(), "strip");
    let body = crate::common::load_builtin().expect("the built-in body (datasets/body/makehuman)");
    let build = build_garment(&config, &config_path, text.as_bytes(), &body).unwrap();
    assert_eq!(build.garment.rest_source(), RestSource::Pattern);
    assert!(build.tshirt.is_none());
    // Unknown fields are errors that name the file.
    let bad = text.replace("\"name\"", "\"colour\": 1, \"name\"");
    let e = GarmentConfig::from_json(bad.as_bytes(), &config_path).unwrap_err();
    assert!(
        e.to_string().contains("strip.json") && e.to_string().contains("colour"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
