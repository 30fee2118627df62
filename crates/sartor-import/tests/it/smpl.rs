//! The SMPL .npz loader, on a small synthetic file in SMPL's layout written here.

use std::path::Path;

use npyz::WriterBuilder;
use rand::Rng;
use sartor_core::Pose;
use sartor_import::load_smpl_npz;

use crate::core_fixtures::{random_pose, rng, sphere};

struct Arrays {
    entries: Vec<(String, Vec<u64>, Vec<f64>)>,
}

impl Arrays {
    fn add(&mut self, name: &str, shape: &[u64], data: Vec<f64>) {
        self.entries.push((name.into(), shape.to_vec(), data));
    }
    fn write(&self, path: &Path, as_f32: &[&str]) {
        let mut zip = zip::ZipWriter::new(std::fs::File::create(path).expect("create"));
        for (name, shape, data) in &self.entries {
            zip.start_file(format!("{name}.npy"), zip::write::FileOptions::default())
                .expect("entry");
            if as_f32.contains(&name.as_str()) {
                let mut w = npyz::WriteOptions::<f32>::new()
                    .default_dtype()
                    .shape(shape)
                    .writer(&mut zip)
                    .begin_nd()
                    .expect("begin");
                w.extend(data.iter().map(|&x| x as f32)).expect("write");
                w.finish().expect("finish");
            } else {
                let mut w = npyz::WriteOptions::<f64>::new()
                    .default_dtype()
                    .shape(shape)
                    .writer(&mut zip)
                    .begin_nd()
                    .expect("begin");
                w.extend(data.iter().copied()).expect("write");
                w.finish().expect("finish");
            }
        }
        zip.finish().expect("the archive's directory");
    }
}

/// SMPL-layout arrays: 3 joints (root, spine, arm) on a sphere mesh.
fn smpl_arrays() -> Arrays {
    let mesh = sphere(6);
    let (v, j, b) = (mesh.n_vertices(), 3usize, 4usize);
    let mut r = rng(11);
    let mut a = Arrays {
        entries: Vec::new(),
    };
    a.add(
        "v_template",
        &[v as u64, 3],
        mesh.positions()
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .collect(),
    );
    a.add(
        "f",
        &[mesh.n_faces() as u64, 3],
        mesh.faces().iter().flatten().map(|&i| i as f64).collect(),
    );
    a.add(
        "shapedirs",
        &[v as u64, 3, b as u64],
        (0..v * 3 * b)
            .map(|_| 0.01 * (r.random::<f64>() - 0.5))
            .collect(),
    );
    let mut reg = vec![0.0; j * v];
    for (jj, verts) in [[0usize, 1, 2], [5, 6, 7], [20, 21, 22]].iter().enumerate() {
        for &vv in verts {
            reg[jj * v + vv] = 1.0 / 3.0;
        }
    }
    a.add("J_regressor", &[j as u64, v as u64], reg);
    let mut w = vec![0.0; v * j];
    for vv in 0..v {
        let x: f64 = r.random();
        w[vv * j] = x;
        w[vv * j + 1] = (1.0 - x) * 0.5;
        w[vv * j + 2] = (1.0 - x) * 0.5;
    }
    a.add("weights", &[v as u64, j as u64], w);
    a.add(
        "kintree_table",
        &[2, j as u64],
        vec![4294967295.0, 0.0, 1.0, 0.0, 1.0, 2.0],
    );
    a.add("posedirs", &[v as u64, 3, 9], vec![0.0; v * 27]);
    a
}

#[test]
fn loads_a_synthetic_smpl_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("smpl_synthetic.npz");
    let arrays = smpl_arrays();
    arrays.write(&path, &["shapedirs", "weights"]);
    let m = load_smpl_npz(&path, Some(2)).expect("loads");
    assert_eq!(m.n_betas(), 2);
    assert_eq!(m.skeleton().n_joints(), 3);
    assert_eq!(m.skeleton().parents(), &[None, Some(0), Some(1)]);
    // The folded joint basis equals the regressor applied to the shaped mesh.
    let betas = [0.7, -1.2];
    let verts = m.shaped_vertices(&betas).expect("valid");
    let joints = m.shaped_joints(&betas).expect("valid");
    let expected = (verts[5] + verts[6] + verts[7]) / 3.0;
    assert!(
        (joints[1] - expected).norm() < 1e-6,
        "{} vs {}",
        joints[1],
        expected
    );
    // Skinning works end to end.
    let mut r = rng(12);
    let posed = m
        .posed_vertices(&betas, &random_pose(&mut r, 3, 1.0))
        .expect("valid");
    assert!(posed.iter().all(|p| p.iter().all(|c| c.is_finite())));
    let rest = m.posed_vertices(&betas, &Pose::rest(3)).expect("valid");
    let d = rest
        .iter()
        .zip(&verts)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(d < 1e-6, "rest pose moved a vertex by {d} m");
}

#[test]
fn malformed_smpl_files_are_errors_naming_the_file_and_fault() {
    let dir = tempfile::tempdir().expect("temp dir");
    type Mutation = Box<dyn Fn(&mut Arrays)>;
    let cases: Vec<(&str, Mutation, &str)> = vec![
        (
            "missing",
            Box::new(|a: &mut Arrays| a.entries.retain(|e| e.0 != "J_regressor")),
            "missing array \"J_regressor\"",
        ),
        (
            "badshape",
            Box::new(|a: &mut Arrays| {
                a.entries
                    .iter_mut()
                    .filter(|e| e.0 == "weights")
                    .for_each(|e| {
                        e.1 = vec![e.2.len() as u64];
                    })
            }),
            "weights",
        ),
        (
            "nan",
            Box::new(|a: &mut Arrays| a.entries[0].2[4] = f64::NAN),
            "non-finite",
        ),
        (
            "badface",
            Box::new(|a: &mut Arrays| a.entries[1].2[0] = 1e6),
            "triangle 0",
        ),
        (
            "badtree",
            Box::new(|a: &mut Arrays| {
                a.entries
                    .iter_mut()
                    .filter(|e| e.0 == "kintree_table")
                    .for_each(|e| e.2[2] = 2.0)
            }),
            "kintree_table",
        ),
        (
            "badweights",
            Box::new(|a: &mut Arrays| {
                a.entries
                    .iter_mut()
                    .filter(|e| e.0 == "weights")
                    .for_each(|e| e.2[0] = -1.0)
            }),
            "weight",
        ),
    ];
    for (name, mutate, needle) in cases {
        let mut a = smpl_arrays();
        mutate(&mut a);
        let path = dir.path().join(format!("{name}.npz"));
        a.write(&path, &[]);
        let e = load_smpl_npz(&path, None).unwrap_err().to_string();
        assert!(
            e.contains(&format!("{name}.npz")) && e.contains(needle),
            "{name}: {e}"
        );
    }
    // Truncated archive.
    let path = dir.path().join("good.npz");
    smpl_arrays().write(&path, &[]);
    let bytes = std::fs::read(&path).expect("read");
    let cut = dir.path().join("cut.npz");
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).expect("write");
    let e = load_smpl_npz(&cut, None).unwrap_err().to_string();
    assert!(e.contains("cut.npz"), "{e}");
    assert!(
        load_smpl_npz(&path, Some(99))
            .unwrap_err()
            .to_string()
            .contains("shape components")
    );
}
