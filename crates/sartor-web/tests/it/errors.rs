//! Bad input gives an error that names the fault, never a panic: missing or corrupted files,
//! non-finite or out-of-range shapes, a broken BVH, an unknown clip.

use sartor_web::{PhenotypeSliders, TryOn, TryOnOptions};

use crate::common::{load, shipped_files};

fn load_error(files: sartor_web::FileSet) -> String {
    TryOn::load(files, TryOnOptions::default())
        .expect_err("bad files")
        .to_string()
}

#[test]
fn missing_and_corrupted_files_are_named() {
    let mut files = shipped_files();
    files.take("body/tpose.json").expect("present");
    let msg = load_error(files);
    assert!(msg.contains("missing file \"body/tpose.json\""), "{msg}");

    let mut files = shipped_files();
    let mut bytes = files.take("model/model.safetensors").expect("present");
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x55;
    files.insert("model/model.safetensors", bytes);
    let msg = load_error(files);
    assert!(
        msg.contains("model/model.safetensors") && msg.contains("hash"),
        "{msg}"
    );

    let mut files = shipped_files();
    files.insert("model/binding.json", b"{ not json".to_vec());
    let msg = load_error(files);
    assert!(msg.contains("model/binding.json"), "{msg}");

    let mut files = shipped_files();
    files.insert("body/model.safetensors", vec![1, 2, 3]);
    let msg = load_error(files);
    assert!(msg.contains("body/model.safetensors"), "{msg}");
}

#[test]
fn bad_shapes_are_refused_and_the_avatar_is_kept() {
    let mut t = load();
    let before = t.garment_vertices();
    let msg = t.set_betas(&[f64::NAN]).expect_err("NaN").to_string();
    assert!(
        msg.to_lowercase().contains("finite") || msg.contains("NaN"),
        "{msg}"
    );
    let msg = t.set_betas(&[0.0; 40]).expect_err("too many").to_string();
    assert!(msg.contains("40"), "{msg}");
    let sliders = PhenotypeSliders {
        gender: 0.5,
        height_m: 3.5,
        weight: 0.5,
        muscle: 0.5,
        age_years: 25.0,
    };
    let msg = t.set_phenotype(&sliders).expect_err("too tall").to_string();
    assert!(msg.contains("3.5 m"), "{msg}");
    let msg = t
        .set_phenotype(&PhenotypeSliders {
            weight: f64::NAN,
            height_m: 1.7,
            ..sliders
        })
        .expect_err("NaN slider")
        .to_string();
    assert!(msg.contains("weight"), "{msg}");
    let msg = t
        .set_phenotype_text("female, tall")
        .expect_err("unknown word")
        .to_string();
    assert!(msg.contains("tall"), "{msg}");
    assert_eq!(before, t.garment_vertices());
}

#[test]
fn broken_motions_are_named() {
    let mut t = load();
    let msg = t
        .motion_bvh("broken.bvh", "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n")
        .expect_err("broken")
        .to_string();
    assert!(msg.contains("broken.bvh"), "{msg}");
    let msg = t
        .motion_bvh("empty.bvh", "")
        .expect_err("empty")
        .to_string();
    assert!(msg.contains("empty.bvh"), "{msg}");
    let msg = TryOn::motion_procedural("moonwalk")
        .expect_err("unknown")
        .to_string();
    assert!(
        msg.contains("moonwalk") && msg.contains("dance_disco"),
        "{msg}"
    );
    let msg = TryOn::motion_json("walk.json", b"[1, 2")
        .expect_err("bad json")
        .to_string();
    assert!(msg.contains("walk.json"), "{msg}");
    let msg = t
        .motion_stored("cmu/07_01", b"{}", vec![0; 8])
        .expect_err("bad clip")
        .to_string();
    assert!(msg.contains("cmu/07_01.json"), "{msg}");
    // The motion shown is unchanged by the failures.
    assert_eq!(t.motion_name(), "rest");
    t.step().expect("still plays");
}

#[test]
fn bad_arm_clearance_options_are_refused_naming_them() {
    for (clearance_m, max_angle_rad) in [(f64::NAN, 1.0), (-0.01, 1.0), (0.025, 0.0)] {
        let options = TryOnOptions {
            arm_clearance: Some(sartor_motion::ClearanceOptions {
                clearance_m,
                max_angle_rad,
                ..sartor_motion::ClearanceOptions::default()
            }),
            ..TryOnOptions::default()
        };
        let msg = TryOn::load(shipped_files(), options)
            .expect_err("bad options")
            .to_string();
        assert!(msg.contains("arm clearance"), "{msg}");
    }
}
