//! JSON inputs: a motion file and a body-model header → a value or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = sartor_motion::Motion::from_json_bytes(Path::new("fuzz.json"), data);
    let _ = sartor_core::BodyModel::from_bytes(Path::new("fuzz"), data, Vec::new());
});
