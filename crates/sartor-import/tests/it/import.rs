//! The built-in MakeHuman body: the committed files, their reproduction from the raw assets,
//! the phenotype space and the T-pose.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use sartor_core::{
    BodyModel, MODEL_HEADER, PHENOTYPE_HEADER, PHENOTYPE_TENSORS, Phenotype, PhenotypeRequest,
    PhenotypeSpace,
};

use crate::common::{builtin_model_dir, load_builtin};
use sartor_import::{BONE_FRAMES_FILE, BoneFrames, IMPORT_FILES, ImportOptions, import_makehuman};
use sartor_motion::{TPOSE_FILE, load_tpose};

/// `<workspace>/../shared/makehuman`: where CI and developers keep the raw assets.
fn raw_assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/makehuman")
}

fn space() -> PhenotypeSpace {
    PhenotypeSpace::load(&builtin_model_dir()).expect("committed phenotype space loads")
}

#[test]
fn reimport_reproduces_the_committed_files() {
    let from = raw_assets();
    if !from.join("3dobjs/base.obj").exists() {
        println!("skipped: ../shared/makehuman not present");
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let report = import_makehuman(&ImportOptions::new(from, dir.path().to_path_buf()))
        .expect("import succeeds");
    assert_eq!(report.mesh.n_vertices, 13380);
    for name in IMPORT_FILES {
        let fresh = std::fs::read(dir.path().join(name)).expect("written");
        let committed = std::fs::read(builtin_model_dir().join(name)).expect("committed");
        assert!(
            fresh == committed,
            "{name} differs from the committed file: run `cargo xtask import-body`"
        );
    }
}

#[test]
fn mean_adult_is_an_adult_and_joints_follow_shape() {
    let model = load_builtin().expect("built-in model loads");
    assert_eq!(model.n_vertices(), 13380);
    assert_eq!(model.n_betas(), 10);
    assert_eq!(model.skeleton().n_joints(), 31);
    let h = model.height_m(&[]).expect("valid");
    assert!((1.60..=1.85).contains(&h), "mean adult is {h} m tall");
    let j0 = model.shaped_joints(&[]).expect("valid");
    let j1 = model.shaped_joints(&[1.0]).expect("valid");
    let moved = j0
        .iter()
        .zip(&j1)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(moved > 1e-3, "joints moved {moved} m for beta_0 = 1");
    model
        .template()
        .topology()
        .check_manifold()
        .expect("the body mesh is an oriented manifold");
}

/// Bone lengths stay positive over β = ±3 on every component. Hips, LHipJoint and RHipJoint
/// are all the head of a bone at the `joint-pelvis` cube, so the two hip joints coincide
/// with Hips exactly (zero-length bones); they must stay coincident, the others longer than
/// 5 mm.
#[test]
fn bone_lengths_stay_positive_over_the_shape_space() {
    let model = load_builtin().expect("built-in model loads");
    let s = model.skeleton();
    let coincident = |parent: &str, child: &str| {
        parent == "Hips" && (child == "LHipJoint" || child == "RHipJoint")
    };
    let mut shapes = vec![vec![0.0; 10]];
    for k in 0..10 {
        for v in [-3.0, 3.0] {
            let mut b = vec![0.0; 10];
            b[k] = v;
            shapes.push(b);
        }
    }
    for betas in &shapes {
        let j = model.shaped_joints(betas).expect("valid");
        for (c, p) in s.parents().iter().enumerate() {
            let Some(p) = *p else { continue };
            let (pn, cn) = (&s.names()[p], &s.names()[c]);
            let len = (j[c] - j[p]).norm();
            if coincident(pn, cn) {
                assert!(
                    len < 1e-6,
                    "{pn}->{cn} should coincide, {len} m at {betas:?}"
                );
            } else {
                assert!(len > 5e-3, "{pn}->{cn} is {len} m long at {betas:?}");
            }
        }
        assert!(model.height_m(betas).expect("valid") > 1.2);
    }
}

#[test]
fn phenotype_requests_reach_their_height() {
    let model = load_builtin().expect("built-in model loads");
    let space = space();
    for text in [
        "female, 1.70 m, heavy",
        "male,1.90m,light,muscular,old",
        "165 cm",
    ] {
        let request: PhenotypeRequest = text.parse().expect("valid request");
        let (phenotype, betas) = space.betas_for(&model, &request).expect("reachable");
        let want = request.height_m.expect("a height was given");
        let got = model.height_m(&betas).expect("valid");
        assert!((got - want).abs() < 0.01, "{text}: {got} m");
        phenotype.validate().expect("sliders in range");
    }
    let err = space
        .betas_for(&model, &"female, 2.45 m".parse().expect("parses"))
        .expect_err("out of reach");
    assert!(err.to_string().contains("outside the range"), "{err}");
}

#[test]
fn phenotype_sliders_change_the_shape() {
    let space = space();
    let female = space
        .betas(&Phenotype {
            gender: 0.0,
            ..Phenotype::default()
        })
        .expect("valid");
    let male = space
        .betas(&Phenotype {
            gender: 1.0,
            ..Phenotype::default()
        })
        .expect("valid");
    let d: f64 = female.iter().zip(&male).map(|(a, b)| (a - b).powi(2)).sum();
    assert!(d.sqrt() > 1.0, "female {female:?} vs male {male:?}");
    // Taller slider, taller body.
    let model = load_builtin().expect("built-in model loads");
    let h = |height: f64| {
        let b = space
            .betas(&Phenotype {
                height,
                ..Phenotype::default()
            })
            .expect("valid");
        model.height_m(&b).expect("valid")
    };
    assert!(h(0.3) < h(0.5) && h(0.5) < h(0.7));
    let err = space
        .betas(&Phenotype {
            weight: f64::NAN,
            ..Phenotype::default()
        })
        .expect_err("NaN slider");
    assert!(err.to_string().contains("weight"), "{err}");
}

#[test]
fn tpose_raises_the_arms_to_horizontal() {
    let model = load_builtin().expect("built-in model loads");
    let pose = load_tpose(&builtin_model_dir()).expect("committed T-pose loads");
    let j0 = model.shaped_joints(&[]).expect("valid");
    let (posed, _) = model
        .skeleton()
        .forward_kinematics(&j0, &pose)
        .expect("valid pose");
    let s = model.skeleton();
    let idx = |n: &str| s.index_of(n).expect("joint exists");
    for (a, b) in [("LeftArm", "LeftForeArm"), ("RightArm", "RightForeArm")] {
        let d = posed[idx(b)] - posed[idx(a)];
        let deg = (d.y / d.norm()).asin().to_degrees();
        assert!(deg.abs() < 10.0, "{a}->{b} is {deg}° from horizontal");
        let rest = j0[idx(b)] - j0[idx(a)];
        assert!(
            (rest.y / rest.norm()).asin().to_degrees() < -30.0,
            "rest is an A-pose"
        );
    }
    for (a, b) in [("LeftUpLeg", "LeftLeg"), ("RightLeg", "RightFoot")] {
        let before = j0[idx(b)] - j0[idx(a)];
        let after = posed[idx(b)] - posed[idx(a)];
        assert!(before.angle(&after).to_degrees() < 10.0, "{a}->{b} moved");
    }
}

#[test]
fn bone_frames_point_along_the_bones() {
    let model = load_builtin().expect("built-in model loads");
    let frames = BoneFrames::load(&builtin_model_dir()).expect("committed frames load");
    assert_eq!(frames.names(), model.skeleton().names());
    let j0 = model.shaped_joints(&[]).expect("valid");
    for (j, r) in frames.world_from_bone().iter().enumerate() {
        let along = (frames.tails_m()[j] - frames.heads_m()[j]).normalize();
        assert!((r * Vector3::y() - along).norm() < 1e-5, "bone {j}");
        assert!((frames.heads_m()[j] - j0[j]).norm() < 1e-5, "head {j}");
    }
}

fn copy_builtin() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    for name in IMPORT_FILES {
        std::fs::copy(builtin_model_dir().join(name), dir.path().join(name)).expect("copy");
    }
    dir
}

fn edit(dir: &Path, name: &str, from: &str, to: &str) {
    let path = dir.join(name);
    let text = std::fs::read_to_string(&path).expect("read");
    assert!(text.contains(from), "{name} has no {from:?}");
    std::fs::write(&path, text.replacen(from, to, 1)).expect("write");
}

fn edit_json(dir: &Path, name: &str, change: impl FnOnce(&mut serde_json::Value)) {
    let path = dir.join(name);
    let mut json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).expect("read")).expect("JSON");
    change(&mut json);
    std::fs::write(&path, serde_json::to_vec(&json).expect("JSON")).expect("write");
}

#[test]
fn malformed_files_give_clear_errors() {
    // Phenotype header: an unknown label, a wrong format, broken JSON.
    let dir = copy_builtin();
    edit_json(dir.path(), PHENOTYPE_HEADER, |j| {
        j["targets"][5]["labels"][0] = serde_json::json!("purple");
    });
    let err = PhenotypeSpace::load(dir.path())
        .expect_err("bad label")
        .to_string();
    assert!(
        err.contains(PHENOTYPE_HEADER) && err.contains("\"purple\""),
        "{err}"
    );
    let dir = copy_builtin();
    edit_json(dir.path(), PHENOTYPE_HEADER, |j| {
        j["variables"][3]["parts"][1]["from"] = serde_json::json!(0.4);
    });
    let err = PhenotypeSpace::load(dir.path())
        .expect_err("bad rule")
        .to_string();
    assert!(
        err.contains(PHENOTYPE_HEADER) && err.contains("tile"),
        "{err}"
    );
    let dir = copy_builtin();
    edit(
        dir.path(),
        PHENOTYPE_HEADER,
        "\"n_betas\": 10",
        "\"n_betas\": 12",
    );
    let err = PhenotypeSpace::load(dir.path())
        .expect_err("bad shape")
        .to_string();
    assert!(
        err.contains(PHENOTYPE_TENSORS) && err.contains("target_betas"),
        "{err}"
    );
    let dir = copy_builtin();
    edit(dir.path(), PHENOTYPE_HEADER, "{", "[");
    let err = PhenotypeSpace::load(dir.path())
        .expect_err("bad JSON")
        .to_string();
    assert!(err.contains(PHENOTYPE_HEADER), "{err}");
    // Phenotype tensors: changed bytes break the hash.
    let dir = copy_builtin();
    let path = dir.path().join(PHENOTYPE_TENSORS);
    let mut bytes = std::fs::read(&path).expect("read");
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&path, bytes).expect("write");
    let err = PhenotypeSpace::load(dir.path())
        .expect_err("bad hash")
        .to_string();
    assert!(
        err.contains(PHENOTYPE_TENSORS) && err.contains("hash"),
        "{err}"
    );
    // Missing file.
    let dir = copy_builtin();
    std::fs::remove_file(dir.path().join(PHENOTYPE_TENSORS)).expect("remove");
    let err = PhenotypeSpace::load(dir.path())
        .expect_err("missing")
        .to_string();
    assert!(err.contains(PHENOTYPE_TENSORS), "{err}");
    // Model header.
    let dir = copy_builtin();
    edit(
        dir.path(),
        MODEL_HEADER,
        "\"units\": \"m\"",
        "\"units\": \"dm\"",
    );
    let err = BodyModel::load(dir.path())
        .expect_err("bad units")
        .to_string();
    assert!(err.contains(MODEL_HEADER) && err.contains("units"), "{err}");
    // T-pose: a non-unit quaternion; bone frames: not a rotation.
    let dir = copy_builtin();
    edit(dir.path(), TPOSE_FILE, "1.0", "2.0");
    let err = load_tpose(dir.path()).expect_err("bad pose").to_string();
    assert!(err.contains(TPOSE_FILE) && err.contains("unit"), "{err}");
    let dir = copy_builtin();
    edit_json(dir.path(), BONE_FRAMES_FILE, |j| {
        j["bones"][3]["world_from_bone"][0] = serde_json::json!([7.0, 0.0, 0.0]);
    });
    let err = BoneFrames::load(dir.path())
        .expect_err("bad frame")
        .to_string();
    assert!(
        err.contains(BONE_FRAMES_FILE) && err.contains("LeftLeg") && err.contains("rotation"),
        "{err}"
    );
}

/// The built-in body at the extremes: β = ±5 on every component with every joint (and the root)
/// rotated by 179°, on a long clip, stays finite; non-finite shape or pose is an error.
#[test]
fn builtin_body_extremes_stay_finite() {
    use nalgebra::UnitQuaternion;
    let model = load_builtin().expect("built-in model loads");
    let n_j = model.skeleton().n_joints();
    let mut pose = sartor_core::Pose::rest(n_j);
    for (j, q) in pose.local_rotations.iter_mut().enumerate() {
        let axis = Vector3::new(1.0, (j as f64).sin(), (j as f64).cos()).normalize();
        *q = UnitQuaternion::from_scaled_axis(axis * 179f64.to_radians());
    }
    pose.root_orientation =
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 179.9f64.to_radians());
    for b in 0..model.n_betas() {
        for s in [-5.0, 5.0] {
            let mut betas = vec![0.0; model.n_betas()];
            betas[b] = s;
            let v = model.posed_vertices(&betas, &pose).expect("finite input");
            assert!(
                v.iter().all(|p| p.iter().all(|c| c.is_finite())),
                "β{b} = {s}"
            );
        }
    }
    assert!(model.posed_vertices(&[f64::NAN], &pose).is_err());
    let mut bad = pose.clone();
    bad.local_rotations[5] =
        UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(f64::INFINITY, 0.0, 0.0, 0.0));
    assert!(model.posed_vertices(&[], &bad).is_err());
}
