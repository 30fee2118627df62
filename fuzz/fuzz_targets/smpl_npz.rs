//! SMPL .npz loader: any bytes → a body model or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.npz");
    if let Ok(npz) = sartor_motion::npz::NpzFile::from_bytes(path, data.to_vec()) {
        if let Ok(model) = sartor_import::smpl_from_npz(npz, None) {
            let _ = model.posed_vertices(&[], &sartor_core::Pose::rest(model.skeleton().n_joints()));
        }
    }
});
