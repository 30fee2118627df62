//! The try-on's logic on the shipped model: shapes, motions as the command line loads them,
//! playing, seeking, timing.

use sartor_motion::{MotionSourceOptions, RetargetBody, load_motion};
use sartor_web::{PhenotypeSliders, TryOn};

use crate::common::{load, repo};

use crate::reference::max_abs_diff;

fn cli_options() -> MotionSourceOptions {
    MotionSourceOptions {
        motions_dir: repo().join("datasets/motions"),
        body: Some(RetargetBody::load(&repo().join("datasets/body/makehuman")).expect("body")),
        ..MotionSourceOptions::default()
    }
}

#[test]
fn phenotypes_give_the_command_lines_shapes_and_different_garments() {
    let mut t = load();
    let sliders = PhenotypeSliders {
        gender: 0.0,
        height_m: 1.70,
        weight: 0.75,
        muscle: 0.5,
        age_years: 25.0,
    };
    let betas = t.set_phenotype(&sliders).expect("phenotype");
    // The same body as the command line's text for it ("female, 1.70 m, heavy" = weight 0.75).
    let mut text = load();
    let from_text = text
        .set_phenotype_text("female, 1.70 m, heavy")
        .expect("text");
    assert_eq!(betas, from_text);
    assert!((t.height_m().expect("height") - 1.70).abs() < 1e-3);
    let garment_a = t.garment_vertices();
    let body_a = t.body_vertices();
    t.set_phenotype(&PhenotypeSliders {
        gender: 1.0,
        height_m: 1.90,
        weight: 0.25,
        ..sliders
    })
    .expect("phenotype");
    assert!((t.height_m().expect("height") - 1.90).abs() < 1e-3);
    let (garment_b, body_b) = (t.garment_vertices(), t.body_vertices());
    assert!(garment_a.iter().chain(&garment_b).all(|v| v.is_finite()));
    assert!(
        max_abs_diff(&garment_a, &garment_b) > 0.05,
        "garments differ"
    );
    assert!(max_abs_diff(&body_a, &body_b) > 0.05, "bodies differ");
    assert_eq!(body_a.len(), 3 * 13380);
    assert_eq!(t.body_faces().len(), 3 * 26756);
    assert_eq!(t.garment_faces().len(), 3 * 4210);
}

#[test]
fn motions_are_the_command_lines_and_frames_advance() {
    let mut t = load();
    let options = cli_options();
    let clip = TryOn::motion_procedural("dance_disco").expect("clip");
    assert_eq!(
        clip.frames(),
        load_motion("dance_disco", &options).expect("cli").frames()
    );
    let walk_bytes = std::fs::read(repo().join("datasets/motions/walk.json")).expect("walk");
    let walk = TryOn::motion_json("walk", &walk_bytes).expect("walk");
    assert_eq!(
        walk.frames(),
        load_motion("walk", &options).expect("cli").frames()
    );
    let dir = repo().join("datasets/motions/cmu");
    let stored = t
        .motion_stored(
            "cmu/07_01",
            &std::fs::read(dir.join("07_01.json")).expect("json"),
            std::fs::read(dir.join("07_01.safetensors")).expect("tensors"),
        )
        .expect("stored clip");
    assert_eq!(
        stored.frames(),
        load_motion("cmu/07_01", &options).expect("cli").frames()
    );
    let bvh_path = repo().join("crates/sartor-motion/tests/data/cmu/09_01.bvh");
    let text = std::fs::read_to_string(&bvh_path).expect("bvh");
    let dropped = t.motion_bvh("09_01.bvh", &text).expect("bvh");
    let cli = load_motion(bvh_path.to_str().expect("utf-8"), &options).expect("cli");
    assert_eq!(dropped.frames(), cli.frames());

    t.set_motion(stored).expect("play");
    assert_eq!(t.frame(), 0);
    let mut previous = t.garment_vertices();
    for k in 1..20 {
        assert_eq!(t.step().expect("step"), k);
        let v = t.garment_vertices();
        assert!(v.iter().all(|x| x.is_finite()));
        assert!(max_abs_diff(&previous, &v) > 0.0, "frame {k} moved");
        previous = v;
    }
    let times = t.times();
    let g = times.garment;
    for ms in [
        g.network_ms,
        g.skinning_ms,
        g.post_process_ms,
        times.body_ms,
    ] {
        assert!(ms.is_finite() && ms >= 0.0, "{times:?}");
    }
    assert!(g.network_ms + g.skinning_ms + g.post_process_ms > 0.0);
    // The end loops back to the start.
    let n = t.n_frames();
    t.seek(n + 10).expect("clamped");
    assert_eq!(t.frame(), n - 1);
    assert_eq!(t.step().expect("loop"), 0);
}

#[test]
fn seeking_replays_the_same_frame() {
    let mut t = load();
    t.set_motion(TryOn::motion_procedural("jumping_jacks").expect("clip"))
        .expect("play");
    t.seek(40).expect("seek");
    let a = t.garment_vertices();
    t.seek(10).expect("seek");
    let b = t.garment_vertices();
    t.seek(40).expect("seek");
    assert_eq!(
        a,
        t.garment_vertices(),
        "same frame, same warm-up, same result"
    );
    assert!(max_abs_diff(&a, &b) > 0.01);
    // A new shape keeps the frame.
    t.set_betas(&[1.0, -1.0]).expect("betas");
    assert_eq!(t.frame(), 40);
    assert_eq!(t.betas()[..3], [1.0, -1.0, 0.0]);
}
