//! Body-model tensors: any bytes as `model.safetensors`, under a header whose hash matches them
//! (so the fuzzer reaches every tensor check, not just the hash), → a model or an error.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let names: Vec<String> = sartor_motion::CMU_MB_JOINTS.iter().take(3).map(|(n, _)| format!("{n:?}")).collect();
    let header = format!(
        r#"{{"format":"sartor-body","version":1,"name":"f","units":"m","axes":"","n_vertices":4,"n_faces":4,
           "n_betas":2,"joint_names":[{}],"parents":[null,0,1],
           "provenance":{{"source":"","licence":"","notes":""}},"tensors_sha256":"{}"}}"#,
        names.join(","),
        sartor_core::io::sha256_hex(data)
    );
    let _ = sartor_core::BodyModel::from_bytes(Path::new("fuzz"), header.as_bytes(), data.to_vec());
    if let Ok(file) = sartor_core::io::TensorFile::from_bytes(Path::new("fuzz.safetensors"), data.to_vec()) {
        for name in file.names() {
            let _ = file.f32(&name, &[None]);
            let _ = file.i32(&name, &[None, None]);
        }
    }
});
