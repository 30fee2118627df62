//! Material files: a fixture in ARCSim's material-file layout (`tests/data/gray-interlock.json`,
//! holding only the published gray-interlock measurements: density, stretching and bending
//! tables) loads into exactly the built-in default material; a missing file is an I/O error
//! naming it.

use std::path::Path;

use nalgebra::Matrix2;
use sartor_cloth::{Error, Material};

#[test]
fn arcsim_gray_interlock_file_is_the_builtin_material() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gray-interlock.json");
    let file = Material::from_json_file(&path).expect("ARCSim's file loads");
    let builtin = Material::gray_interlock();
    assert_eq!(file.name(), "gray-interlock");
    assert_eq!(file.to_file(), builtin.to_file());
    // Same stiffness lookups.
    for g in [
        Matrix2::new(0.01, 0.002, 0.002, -0.01),
        Matrix2::new(0.08, -0.03, -0.03, 0.02),
        Matrix2::new(-0.1, 0.0, 0.0, 0.3),
    ] {
        assert_eq!(
            file.membrane().stiffness(&g),
            builtin.membrane().stiffness(&g)
        );
    }
    let missing = Path::new("no/such/material.json");
    let err = Material::from_json_file(missing).expect_err("missing file");
    assert!(matches!(err, Error::Io { .. }) && err.to_string().contains("material.json"));
}
