//! Archives NumPy wrote itself (`tests/data/numpy/make.py`: `np.savez`, entries stored, and
//! `np.savez_compressed`, deflated), not the zip writer of these tests: the reader gets NumPy's
//! values back, recomputed here from the script's formulas.

use std::path::PathBuf;

use sartor_motion::AmassData;
use sartor_motion::npz::NpzFile;

fn archives() -> [PathBuf; 2] {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/numpy");
    ["amass_savez.npz", "amass_savez_compressed.npz"].map(|f| dir.join(f))
}

#[test]
fn numpys_stored_and_deflated_archives_read_back_its_values() {
    for path in archives() {
        let name = path.display();
        let mut npz = NpzFile::open(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(
            npz.names(),
            ["betas", "gender", "mocap_framerate", "poses", "trans"],
            "{name}"
        );
        // f8, [4, 156]: 0.3 sin(0.01 k) in C order.
        let (shape, poses) = npz.array_f64("poses").expect("poses");
        assert_eq!(shape, [4, 156], "{name}");
        for (k, v) in poses.iter().enumerate() {
            let want = 0.3 * (0.01 * k as f64).sin();
            assert!(
                (v - want).abs() <= 1e-15,
                "{name}: poses[{k}] {v} against {want}"
            );
        }
        // f4, [4, 3]: 0.1 k rounded to f32, exactly.
        let (shape, trans) = npz.array_f64("trans").expect("trans");
        assert_eq!(shape, [4, 3], "{name}");
        for (k, v) in trans.iter().enumerate() {
            assert_eq!(*v, f64::from((0.1 * k as f64) as f32), "{name}: trans[{k}]");
        }
        // A 0-d array.
        let (shape, rate) = npz.array_f64("mocap_framerate").expect("rate");
        assert!(
            shape.is_empty() && rate == [60.0],
            "{name}: {shape:?} {rate:?}"
        );
        let (_, betas) = npz.array_f64("betas").expect("betas");
        assert_eq!(betas.len(), 16, "{name}");
        for (k, v) in betas.iter().enumerate() {
            let want = -1.0 + 2.0 * k as f64 / 15.0;
            assert!(
                (v - want).abs() <= 1e-15,
                "{name}: betas[{k}] {v} against {want}"
            );
        }
        // A string array is refused by name, and a missing one named.
        let err = npz.array_f64("gender").expect_err("a string").to_string();
        assert!(err.contains("\"gender\"") && err.contains("dtype"), "{err}");
        let err = npz.array_f64("dmpls").expect_err("missing").to_string();
        assert!(err.contains("missing array \"dmpls\""), "{err}");
        // And as an AMASS motion.
        let data = AmassData::read(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(data.n_frames(), 4, "{name}");
    }
}
