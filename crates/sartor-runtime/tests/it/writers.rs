//! Output writers: OBJ sequences read back, glTF parsed and validated by the `gltf` crate, the
//! rasterizer's pixels.

use nalgebra::Vector3;
use sartor_runtime::{
    Camera, MeshSequence, Panel, Projection, RenderMesh, render, write_gltf, write_obj_sequence,
};

/// A unit square in the z = 0 plane, moving up by 0.1 m per frame.
fn square(frames: usize) -> MeshSequence {
    let base = [
        Vector3::new(0.0f32, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
    ];
    let frames = (0..frames)
        .map(|t| {
            base.iter()
                .map(|p| p + Vector3::new(0.0, 0.1 * t as f32, 0.0))
                .collect()
        })
        .collect();
    MeshSequence::new(
        "square".into(),
        vec![[0, 1, 2], [0, 2, 3]],
        frames,
        [0.8, 0.2, 0.1],
    )
    .expect("valid")
}

#[test]
fn sequences_are_validated() {
    let good = square(2);
    let f = good.frames().to_vec();
    let faces = good.faces().to_vec();
    assert!(MeshSequence::new("a b".into(), faces.clone(), f.clone(), [0.5; 3]).is_err());
    assert!(MeshSequence::new("a".into(), vec![[0, 1, 4]], f.clone(), [0.5; 3]).is_err());
    assert!(MeshSequence::new("a".into(), faces.clone(), f.clone(), [1.5, 0.0, 0.0]).is_err());
    assert!(MeshSequence::new("a".into(), faces.clone(), Vec::new(), [0.5; 3]).is_err());
    let mut ragged = f.clone();
    ragged[1].pop();
    assert!(MeshSequence::new("a".into(), faces.clone(), ragged, [0.5; 3]).is_err());
    let mut nan = f;
    nan[1][2].x = f32::NAN;
    assert!(MeshSequence::new("a".into(), faces, nan, [0.5; 3]).is_err());
}

#[test]
fn obj_sequence_reads_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = square(3);
    let paths = write_obj_sequence(dir.path(), &seq).expect("write");
    assert_eq!(paths.len(), 3);
    assert!(paths[2].ends_with("square_00002.obj"));
    let mesh = sartor_core::read_obj(&paths[2]).expect("read back");
    assert_eq!(mesh.faces(), seq.faces());
    assert!((mesh.positions()[2].y - 1.2).abs() < 1e-6);
}

#[test]
fn gltf_parses_validates_and_animates() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scene.glb");
    let garment = square(4);
    let body = MeshSequence::new(
        "body".into(),
        vec![[0, 1, 2]],
        vec![vec![
            Vector3::new(0.0, 0.0, -0.1),
            Vector3::new(1.0, 0.0, -0.1),
            Vector3::new(0.0, 1.0, -0.1),
        ]],
        [0.7, 0.7, 0.7],
    )
    .expect("valid");
    write_gltf(&path, &[garment.clone(), body.clone()], 30.0).expect("write");
    let bytes = std::fs::read(&path).expect("read");
    // `from_slice` validates the document against the glTF 2.0 schema rules.
    let doc = gltf::Gltf::from_slice(&bytes).expect("a valid glTF");
    let blob = doc.blob.as_deref().expect("GLB binary chunk");
    assert_eq!(doc.meshes().count(), 2);
    let mesh = doc.meshes().next().expect("garment mesh");
    assert_eq!(mesh.name(), Some("square"));
    let primitive = mesh.primitives().next().expect("primitive");
    assert_eq!(primitive.morph_targets().count(), 3);
    let reader = primitive.reader(|_| Some(blob));
    let base: Vec<[f32; 3]> = reader.read_positions().expect("positions").collect();
    assert_eq!(base[2], [1.0, 1.0, 0.0]);
    let indices: Vec<u32> = reader.read_indices().expect("indices").into_u32().collect();
    assert_eq!(indices, vec![0, 1, 2, 0, 2, 3]);
    // Target 2 is frame 3 − frame 0: up by 0.3 m.
    let (deltas, _, _) = reader.read_morph_targets().nth(2).expect("target 2");
    let d: Vec<[f32; 3]> = deltas.expect("position deltas").collect();
    assert!(d.iter().all(|v| v[0] == 0.0 && (v[1] - 0.3).abs() < 1e-6));
    // One channel for the animated mesh (the static body has none), keyframes at 1/30 s.
    let animation = doc.animations().next().expect("animation");
    let channels: Vec<_> = animation.channels().collect();
    assert_eq!(channels.len(), 1);
    assert_eq!(channels[0].target().node().index(), 0);
    let channel_reader = channels[0].reader(|_| Some(blob));
    let times: Vec<f32> = channel_reader.read_inputs().expect("times").collect();
    assert_eq!(times.len(), 4);
    assert!((times[3] - 0.1).abs() < 1e-6);
    // A static body has no targets.
    let body_mesh = doc.meshes().nth(1).expect("body");
    assert_eq!(
        body_mesh
            .primitives()
            .next()
            .expect("p")
            .morph_targets()
            .count(),
        0
    );
    // Mismatched frame counts are refused.
    assert!(write_gltf(&path, &[garment, square(3)], 30.0).is_err());
    assert!(write_gltf(&path, &[body], 0.0).is_err());
}

#[test]
fn rasterizer_draws_in_front_and_side_by_side() {
    // A red square at z = 0 behind a smaller green one at z = 0.5, seen from +Z.
    let red = square(1);
    let green: Vec<Vector3<f32>> = red.frames()[0]
        .iter()
        .map(|p| Vector3::new(0.25 + 0.5 * p.x, 0.25 + 0.5 * p.y, 0.5))
        .collect();
    let meshes = vec![
        RenderMesh {
            positions: &red.frames()[0],
            faces: red.faces(),
            color: [1.0, 0.0, 0.0],
        },
        RenderMesh {
            positions: &green,
            faces: red.faces(),
            color: [0.0, 1.0, 0.0],
        },
    ];
    let ortho = Camera::framing(&meshes, Vector3::z(), false);
    assert!(matches!(ortho.projection, Projection::Orthographic { .. }));
    let persp = Camera::framing(&meshes, Vector3::z(), true);
    let panels = [
        Panel {
            meshes: meshes.clone(),
            camera: ortho,
        },
        Panel {
            meshes,
            camera: persp,
        },
    ];
    let image = render(&panels, 64, 64, [1.0, 1.0, 1.0]).expect("render");
    assert_eq!((image.width, image.height), (64 * 2 + 8, 64));
    for x0 in [0, 64 + 8] {
        let centre = image.pixel(x0 + 32, 32);
        assert!(
            centre[1] > 100 && centre[0] < 50,
            "green in front: {centre:?}"
        );
        let red_ring = image.pixel(x0 + 32, 18);
        assert!(
            red_ring[0] > 100 && red_ring[1] < 50,
            "red behind: {red_ring:?}"
        );
        assert_eq!(image.pixel(x0 + 1, 1), [255, 255, 255, 255], "background");
    }
    assert_eq!(image.pixel(64 + 3, 32), [255, 255, 255, 255], "gap");
    // Seen from behind, the red square is in front.
    let back = Camera::framing(&panels[0].meshes, -Vector3::z(), false);
    let image = render(
        &[Panel {
            meshes: panels[0].meshes.clone(),
            camera: back,
        }],
        64,
        64,
        [1.0; 3],
    )
    .expect("render");
    assert!(image.pixel(32, 32)[0] > 100);
    #[cfg(feature = "png")]
    {
        let bytes = image.png_bytes().expect("png");
        assert_eq!(&bytes[1..4], b"PNG");
    }
    assert!(render(&[], 64, 64, [1.0; 3]).is_err());
}

/// Bounding box `(x0, y0, x1, y1)` of the non-background pixels of panel `k` (panels of `w`
/// pixels, 8 apart).
fn drawn_box(image: &sartor_runtime::Image, k: u32, w: u32) -> Option<(u32, u32, u32, u32)> {
    let mut b: Option<(u32, u32, u32, u32)> = None;
    for y in 0..image.height {
        for x in 0..w {
            if image.pixel(k * (w + 8) + x, y) != [255, 255, 255, 255] {
                b = Some(match b {
                    None => (x, y, x, y),
                    Some((x0, y0, x1, y1)) => (x0.min(x), y0.min(y), x1.max(x), y1.max(y)),
                });
            }
        }
    }
    b
}

#[test]
fn strip_cameras_follow_each_panel_at_one_scale() {
    // The unit square travels 5 m along X per panel and rises 0.1 m per panel.
    let sq = square(3);
    let moved: Vec<Vec<Vector3<f32>>> = sq
        .frames()
        .iter()
        .enumerate()
        .map(|(t, f)| {
            f.iter()
                .map(|p| p + Vector3::new(5.0 * t as f32, 0.0, 0.0))
                .collect()
        })
        .collect();
    let meshes: Vec<Vec<RenderMesh>> = moved
        .iter()
        .map(|f| {
            vec![RenderMesh {
                positions: f,
                faces: sq.faces(),
                color: [1.0, 0.0, 0.0],
            }]
        })
        .collect();
    let refs: Vec<&[RenderMesh]> = meshes.iter().map(Vec::as_slice).collect();
    for perspective in [false, true] {
        let cameras = Camera::framing_strip(&refs, Vector3::z(), perspective, 1.0);
        assert_eq!(cameras.len(), 3);
        // One scale: the same projection and distance everywhere.
        for c in &cameras[1..] {
            assert_eq!(c.projection, cameras[0].projection);
            let d = |c: &Camera| (c.eye - c.target).norm();
            assert!((d(c) - d(&cameras[0])).abs() < 1e-4);
        }
        let panels: Vec<Panel> = meshes
            .iter()
            .zip(&cameras)
            .map(|(m, c)| Panel {
                meshes: m.clone(),
                camera: *c,
            })
            .collect();
        let w = 64;
        let image = render(&panels, w, w, [1.0; 3]).expect("render");
        let boxes: Vec<_> = (0..3)
            .map(|k| drawn_box(&image, k, w).expect("the square is in every panel"))
            .collect();
        for (x0, _, x1, _) in &boxes {
            // Centred horizontally in its panel.
            assert!((x0 + x1).abs_diff(w - 1) <= 2, "{boxes:?}");
        }
        // Same size; the later squares are drawn higher (smaller row index).
        let size = |b: &(u32, u32, u32, u32)| (b.2 - b.0, b.3 - b.1);
        assert!(
            size(&boxes[0]).0.abs_diff(size(&boxes[2]).0) <= 1,
            "{boxes:?}"
        );
        assert!(boxes[2].1 + 2 <= boxes[0].1, "{boxes:?}");
    }
}

#[test]
fn strip_cameras_keep_a_wide_shape_inside_a_narrow_panel() {
    // Arms spread: 1.8 m wide, 1.7 m tall, 0.3 m deep, in a panel 0.6 times as wide as tall
    // (the PNG previews' 240 × 400). A camera that fits a sphere to the vertical field of view
    // alone cut the hands off.
    let (corners, faces) =
        sartor_core::box_mesh(Vector3::new(-0.9, 0.0, -0.15), Vector3::new(0.9, 1.7, 0.15));
    let positions: Vec<Vector3<f32>> = corners.iter().map(|c| c.cast::<f32>()).collect();
    let mesh = [RenderMesh {
        positions: &positions,
        faces: &faces,
        color: [1.0, 0.0, 0.0],
    }];
    let (w, h) = (60, 100);
    for direction in [Vector3::z(), Vector3::new(0.35, 0.1, 1.0)] {
        for perspective in [false, true] {
            let cameras = Camera::framing_strip(&[&mesh], direction, perspective, 0.6);
            let panels = [Panel {
                meshes: mesh.to_vec(),
                camera: cameras[0],
            }];
            let image = render(&panels, w, h, [1.0; 3]).expect("render");
            let (x0, y0, x1, y1) = drawn_box(&image, 0, w).expect("drawn");
            let case = format!(
                "{direction:?}, perspective {perspective}: {:?}",
                (x0, y0, x1, y1)
            );
            assert!(x0 > 0 && x1 < w - 1, "touches the side: {case}");
            assert!(y0 > 0 && y1 < h - 1, "touches the top or bottom: {case}");
            // Framed, not lost in the middle: the width nearly fills the panel.
            assert!(x1 - x0 >= w * 3 / 4, "too small: {case}");
        }
    }
}
