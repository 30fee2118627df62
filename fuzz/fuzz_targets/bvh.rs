//! BVH parser: any text → a parsed hierarchy with world rotations for every frame and a
//! joint match, or an error.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(bvh) = sartor_motion::Bvh::parse(text, Path::new("fuzz.bvh")) {
            for f in 0..bvh.n_frames().min(64) {
                let _ = bvh.world_rotations(f);
            }
            // Any hierarchy: matched to the rig by name or structure, or refused.
            let _ = sartor_motion::map_bvh_joints(&bvh);
        }
    }
});
