//! Stored clips (`datasets/motions/cmu`), clip sets and windows.

use std::path::{Path, PathBuf};

use sartor_motion::{
    Bvh, CMU_ACKNOWLEDGEMENT, MotionSourceOptions, MotionWindow, RetargetBody,
    RetargetCheckOptions, StoredClip, check_bvh_retarget, expand_motion_set, load_motion,
    load_stored_clip,
};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn motions_dir() -> PathBuf {
    workspace_root().join("datasets/motions")
}

/// The stored library with the built-in body.
pub(crate) fn library_options() -> MotionSourceOptions {
    options(motions_dir())
}

fn options(motions_dir: PathBuf) -> MotionSourceOptions {
    MotionSourceOptions {
        motions_dir,
        body: Some(
            RetargetBody::load(&crate::motion_sources::builtin_model_dir()).expect("built-in body"),
        ),
        ..MotionSourceOptions::default()
    }
}

#[test]
fn the_cmu_set_holds_every_imported_clip_in_name_order() {
    let names = expand_motion_set(&motions_dir(), "cmu/*").expect("set");
    assert_eq!(names.len(), 60);
    assert_eq!(names[0], "cmu/01_07");
    assert_eq!(names[59], "cmu/09_11");
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(sorted, names);
    assert!(expand_motion_set(&motions_dir(), "cmu").is_err());
    assert!(expand_motion_set(&motions_dir(), "nothing/*").is_err());
    // A set is not one motion.
    let e = load_motion("cmu/*", &options(motions_dir())).expect_err("a set");
    assert!(e.to_string().contains("set"), "{e}");
}

#[test]
fn every_imported_clip_retargets_like_its_own_fk() {
    let body =
        RetargetBody::load(&crate::motion_sources::builtin_model_dir()).expect("built-in body");
    for name in expand_motion_set(&motions_dir(), "cmu/*").expect("set") {
        let bvh = load_stored_clip(&motions_dir(), &name).expect("stored clip");
        assert!((1.0 / bvh.frame_time_secs() - 30.0).abs() < 1e-9, "{name}");
        let check =
            check_bvh_retarget(&bvh, &body, &RetargetCheckOptions::default()).expect("check");
        assert!(check.passed(), "{name}: {:?}", check.failures);
        // The T-pose frame was dropped at import: the first stored frame is not one.
        assert!(
            check.tpose_frame.as_ref().is_none_or(|t| !t.is_added_tpose),
            "{name}: {:?}",
            check.tpose_frame
        );
    }
}

#[test]
fn a_stored_clip_loads_like_its_bvh() {
    // Store the walk excerpt (30 fps: every frame kept) and load it both ways.
    let dir = tempfile::tempdir().expect("tmp");
    let excerpt = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cmu/07_01.bvh");
    let bvh = Bvh::load(&excerpt).expect("excerpt");
    let clip = StoredClip::from_bvh(&bvh, "test/07_01", "0123", CMU_ACKNOWLEDGEMENT).expect("clip");
    assert!(clip.header.tpose_frame_dropped);
    assert_eq!(clip.header.source_frame_step, 1);
    assert_eq!(clip.header.frames, bvh.n_frames() - 1);
    clip.save(&dir.path().join("test")).expect("save");
    // Deterministic bytes.
    let (json, st) = clip.to_bytes().expect("bytes");
    assert_eq!(
        std::fs::read(dir.path().join("test/07_01.json")).expect("json"),
        json
    );
    assert_eq!(
        std::fs::read(dir.path().join("test/07_01.safetensors")).expect("st"),
        st
    );
    let opts = options(dir.path().to_path_buf());
    let stored = load_motion("test/07_01", &opts).expect("stored");
    let direct = load_motion(excerpt.to_str().expect("utf8"), &opts).expect("bvh");
    assert_eq!(stored.name(), "test/07_01");
    assert_eq!(stored.n_frames(), direct.n_frames());
    for (a, b) in stored.frames().iter().zip(direct.frames()) {
        assert!((a.root_translation_m - b.root_translation_m).norm() < 1e-5);
        assert!(a.root_orientation.angle_to(&b.root_orientation) < 1e-5);
        for (p, q) in a.local_rotations.iter().zip(&b.local_rotations) {
            assert!(p.angle_to(q) < 1e-5);
        }
    }
    // A corrupted tensor file is refused, naming it.
    let st_path = dir.path().join("test/07_01.safetensors");
    let mut bytes = std::fs::read(&st_path).expect("st");
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&st_path, &bytes).expect("write");
    let e = load_motion("test/07_01", &opts).expect_err("hash");
    assert!(e.to_string().contains("07_01.safetensors"), "{e}");
}

#[test]
fn a_window_is_exactly_that_range_of_the_whole_clip() {
    let opts = options(motions_dir());
    let whole = load_motion("cmu/05_11", &opts).expect("whole");
    assert_eq!(whole.name(), "cmu/05_11");
    let window = load_motion("cmu/05_11@40+90", &opts).expect("window");
    assert_eq!(window.name(), "cmu/05_11@40+90");
    assert_eq!(window.fps(), whole.fps());
    assert_eq!(window.frames(), &whole.frames()[40..130]);
    // Windows of every kind of motion; out of range is an error naming the window.
    let p = load_motion("idle", &opts).expect("procedural");
    let w = load_motion("idle@3+5", &opts).expect("procedural window");
    assert_eq!(w.frames(), &p.frames()[3..8]);
    let e = load_motion(&format!("cmu/05_11@{}+1", whole.n_frames()), &opts).expect_err("range");
    assert!(e.to_string().contains("cmu/05_11@"), "{e}");
    assert!(load_motion("cmu/05_11@1+0", &opts).is_err());
    let parsed = MotionWindow::parse("cmu/05_11@40+90")
        .expect("ok")
        .expect("window");
    assert_eq!(parsed.cut(&whole).expect("cut"), window);
}

#[test]
fn import_reproduces_the_committed_clips() {
    let shared = workspace_root().join("../shared/cmu");
    if !shared.join("SHA256SUMS").exists() {
        println!("skipped: {} not found", shared.display());
        return;
    }
    let dir = motions_dir().join("cmu");
    for clip in ["01_07", "05_11", "09_11"] {
        let path = shared.join(format!("{clip}.bvh"));
        let bytes = std::fs::read(&path).expect("source");
        let hash = sartor_core::io::sha256_hex(&bytes);
        let bvh = Bvh::parse(&String::from_utf8(bytes).expect("utf8"), &path).expect("parse");
        let stored = StoredClip::from_bvh(&bvh, &format!("cmu/{clip}"), &hash, CMU_ACKNOWLEDGEMENT)
            .expect("import");
        let (json, st) = stored.to_bytes().expect("bytes");
        assert!(
            json == std::fs::read(dir.join(format!("{clip}.json"))).expect("committed json")
                && st
                    == std::fs::read(dir.join(format!("{clip}.safetensors")))
                        .expect("committed tensors"),
            "re-run `cargo xtask import-motions`: {clip} differs from datasets/motions/cmu"
        );
    }
}

#[test]
fn no_stored_clip_jumps_between_frames() {
    // CMU 07_12 has a blank frame (every channel 0) after the converter's T-pose; kept, it made
    // the body jump 2 m into the performance in one frame. A person moves well under 0.3 m in
    // a 30th of a second.
    for name in expand_motion_set(&motions_dir(), "cmu/*").expect("set") {
        let motion = load_motion(&name, &library_options()).expect("clip");
        for (i, pair) in motion.frames().windows(2).enumerate() {
            let step = (pair[1].root_translation_m - pair[0].root_translation_m).norm();
            assert!(
                step < 0.3,
                "{name}: the root moves {step:.2} m from frame {i}"
            );
        }
    }
}
