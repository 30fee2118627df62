//! OBJ parser: any bytes → a mesh or an error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let path = Path::new("fuzz.obj");
        if let Ok(obj) = sartor_core::ObjData::parse(text, path) {
            if let Ok(mesh) = obj.to_mesh(path) {
                let topo = mesh.topology();
                let _ = topo.check_manifold();
                let _ = topo.boundary_loops();
                let _ = mesh.vertex_normals();
            }
        }
    }
});
