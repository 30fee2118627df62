//! The try-on's logic on the shipped model: shapes, motions as the command line loads them,
//! playing, seeking, timing.

use nalgebra::Vector3;
use sartor_core::BodyDistance;
use sartor_motion::{
    ClearanceJob, ClearanceOptions, ClearanceProgress, MotionSourceOptions, RetargetBody,
    load_motion,
};
use sartor_runtime::Precision;
use sartor_web::{BODY_FILES, LimbsWorker, PhenotypeSliders, PostWorker, TryOn, TryOnOptions};

use crate::common::{
    files_of, load, playing_02_02, playing_02_02_with, repo, shipped_arm_clearance, shipped_files,
    stored_clip,
};

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
    let stored = stored_clip(&t, "07_01");
    assert_eq!(
        stored.frames(),
        load_motion("cmu/07_01", &options).expect("cli").frames()
    );
    let bvh_path = repo().join("crates/sartor-motion/tests/data/cmu/09_01.bvh");
    let text = std::fs::read_to_string(&bvh_path).expect("bvh");
    let dropped = t.motion_bvh("09_01.bvh", &text).expect("bvh");
    let cli = load_motion(bvh_path.to_str().expect("utf-8"), &options).expect("cli");
    assert_eq!(dropped.frames(), cli.frames());
    // The same file as Mixamo names its joints: matched by its structure, the same frames
    // (but the fingers', which no other tool names alike).
    let mixamo = text
        .replace("ROOT ", "ROOT mixamorig:")
        .replace("JOINT ", "JOINT mixamorig:");
    let dropped = t.motion_bvh("mixamo.bvh", &mixamo).expect("Mixamo's names");
    assert_eq!(dropped.n_frames(), cli.n_frames());
    let fingers = ["Finger", "Thumb"];
    for (a, b) in dropped.frames().iter().zip(cli.frames()) {
        assert_eq!(a.root_translation_m, b.root_translation_m);
        for ((p, q), name) in a
            .local_rotations
            .iter()
            .zip(&b.local_rotations)
            .zip(cli.joint_names())
        {
            if !fingers.iter().any(|f| name.contains(f)) {
                assert_eq!(p, q, "{name}");
            }
        }
    }

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

/// Per cent of the garment's vertices inside the body (the whole posed body's winding number,
/// eval's collision measure) over `frames` frames played from `start`.
fn inside_percent(t: &mut TryOn, start: usize, frames: usize) -> f64 {
    let faces: Vec<[u32; 3]> = t
        .body_faces()
        .chunks(3)
        .map(|f| [f[0], f[1], f[2]])
        .collect();
    let points = |flat: Vec<f32>| -> Vec<Vector3<f64>> {
        flat.chunks(3)
            .map(|p| Vector3::new(p[0].into(), p[1].into(), p[2].into()))
            .collect()
    };
    t.seek(start).expect("seek");
    let (mut inside, mut total) = (0, 0);
    for k in 0..frames {
        if k > 0 {
            t.step().expect("step");
        }
        let distance = BodyDistance::new(&points(t.body_vertices()), &faces).expect("body");
        let garment = points(t.garment_vertices());
        inside += garment
            .iter()
            .filter(|p| distance.query(p).inside())
            .count();
        total += garment.len();
    }
    100.0 * inside as f64 / total as f64
}

#[test]
fn real_mocap_plays_with_the_arms_held_as_the_model_was_trained() {
    // CMU 02_02, a walk: on the MakeHuman body its hands brush the hips and the hanging upper
    // arms sink into the torso's sides, with the shirt caught between. The page holds the arms
    // out as the shipped model's experiment held them in its training motions.
    let clearance = shipped_arm_clearance();
    let play = |arm_clearance: Option<ClearanceOptions>| {
        let mut t = TryOn::load(
            shipped_files(),
            TryOnOptions {
                clock: Some(sartor_web::now_ms),
                arm_clearance,
                ..TryOnOptions::default()
            },
        )
        .expect("load");
        let clip = stored_clip(&t, "02_02");
        t.set_motion(clip).expect("play");
        t
    };
    let (mut raw, mut held) = (play(None), play(Some(clearance)));
    let frames = 24;
    let before = inside_percent(&mut raw, 8, frames);
    let after = inside_percent(&mut held, 8, frames);
    eprintln!("02_02, nominal: {before:.3} % inside as it comes, {after:.3} % held");
    assert!(
        before > 1.0,
        "the clip no longer shows the fault: {before:.3} %"
    );
    assert!(after <= 0.1, "{after:.3} % inside with the arms held out");
    assert_eq!(raw.arm_turn_deg(), 0.0);
    assert_eq!(raw.times().arms_ms, 0.0);
    assert!(held.times().arms_ms > 0.0, "{:?}", held.times());

    // A wider body: the arms held out anew for it, farther.
    let turn = |t: &mut TryOn| {
        (8..8 + frames)
            .map(|f| {
                t.seek(f).expect("seek");
                t.arm_turn_deg()
            })
            .fold(0.0, f64::max)
    };
    let nominal_turn = turn(&mut held);
    held.set_betas(&[0.0, 2.0]).expect("shape");
    raw.set_betas(&[0.0, 2.0]).expect("shape");
    let wide_turn = turn(&mut held);
    assert!(
        wide_turn > nominal_turn && wide_turn < 57.3,
        "{nominal_turn:.1}° → {wide_turn:.1}°"
    );
    let before = inside_percent(&mut raw, 8, frames);
    let after = inside_percent(&mut held, 8, frames);
    eprintln!("02_02, β₁ = 2: {before:.3} % inside as it comes, {after:.3} % held");
    assert!(after <= 0.1 && after < before, "{before:.3} → {after:.3} %");
}

#[test]
fn a_crouch_plays_with_the_legs_held_out_of_the_shirt() {
    // CMU 02_06 crouches (frames 272–283 of the stored clip): the retargeted thighs sink some
    // 78 mm into the body's belly, with the shirt's front caught between. The page holds the
    // legs out as well as the arms; with the arms alone held, as in the training motions, they
    // stay in. With them held the hem lies on the tops of the thighs, by the groin, where no
    // leg is held (`cargo xtask demo --beta 0 --motion cmu/02_06@274+8`, looked at).
    let play = |legs: bool| {
        let arms = ClearanceOptions {
            leg_clearance_m: None,
            ..shipped_arm_clearance()
        };
        let mut t = TryOn::load(
            shipped_files(),
            TryOnOptions {
                arm_clearance: Some(if legs { shipped_arm_clearance() } else { arms }),
                ..TryOnOptions::default()
            },
        )
        .expect("load");
        let clip = stored_clip(&t, "02_06");
        t.set_motion(clip).expect("play");
        t
    };
    assert!(shipped_arm_clearance().leg_clearance_m.is_some());
    let (mut arms_only, mut legs_too) = (play(false), play(true));
    let frames = 8;
    let before = inside_percent(&mut arms_only, 274, frames);
    let after = inside_percent(&mut legs_too, 274, frames);
    eprintln!(
        "02_06 crouch, nominal: {before:.3} % inside with the arms held, \
         {after:.3} % with the legs too"
    );
    assert!(
        before > 1.0,
        "the clip no longer shows the fault: {before:.3} %"
    );
    assert!(
        after < before / 10.0,
        "{before:.3} → {after:.3} % inside with the legs held out"
    );
}

/// [`playing_02_02`] at frame 20.
fn at_frame_20() -> TryOn {
    let mut t = playing_02_02();
    t.seek(20).expect("seek");
    t
}

#[test]
fn a_preview_shows_the_new_shape_with_the_arms_held_for_the_last_and_leaves_no_trace() {
    // As a slider moves, the page previews each shape: body and garment anew, the arms as held
    // for the shape last set (CMU 02_02 holds them in every frame); the release sets the shape.
    let play = at_frame_20;
    let mut t = play();
    let (garment, body, turn) = (t.garment_vertices(), t.body_vertices(), t.arm_turn_deg());
    assert!(turn > 0.0, "frame 20 holds the arms");
    let wide = [0.0, 2.0];
    assert_eq!(t.preview_betas(&wide).expect("preview")[..2], wide);
    assert_eq!(t.frame(), 20);
    assert!(max_abs_diff(&garment, &t.garment_vertices()) > 0.01);
    assert!(max_abs_diff(&body, &t.body_vertices()) > 0.01);
    assert_eq!(
        t.arm_turn_deg(),
        turn,
        "the arms as held for the last shape"
    );
    let previewed = t.garment_vertices();
    // Another preview, then the release.
    t.preview_betas(&[0.0, 1.0]).expect("preview");
    t.set_betas(&wide).expect("shape");
    assert!(
        t.arm_turn_deg() > turn,
        "held anew, farther out, for the wider body"
    );
    let mut direct = play();
    direct.set_betas(&wide).expect("shape");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert_eq!(t.body_vertices(), direct.body_vertices());
    assert!(max_abs_diff(&previewed, &direct.garment_vertices()) > 0.0);
    // Bad input loses nothing: the shape in use stays.
    assert!(t.preview_betas(&[f64::NAN]).is_err());
    assert_eq!(t.betas()[..2], wide);
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
}

#[test]
fn a_released_slider_holds_the_arms_in_steps_and_shows_what_setting_the_shape_shows() {
    // The page's release: a preview of the shape, then the arms held anew a few looks at a
    // time between display frames, paused and while playing; then the frame `set_betas` gives.
    let wide = [0.0, 2.0];
    let mut t = at_frame_20();
    let turn = t.arm_turn_deg();
    t.preview_betas(&wide).expect("preview");
    let previewed = t.garment_vertices();
    let mut calls = 0;
    while !t.settle(3).expect("settle") {
        calls += 1;
        // The frame shown keeps the arms as held before until the new ones take over.
        assert_eq!(t.arm_turn_deg(), turn);
        assert_eq!(t.garment_vertices(), previewed);
    }
    // CMU 02_02's 16 frames shown after a jump depend on 73 frames, several looks each.
    assert!(calls > 20, "{calls} calls of three looks");
    assert!(t.arm_turn_deg() > turn, "held anew for the wider body");
    let mut direct = at_frame_20();
    direct.set_betas(&wide).expect("shape");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert_eq!(t.body_vertices(), direct.body_vertices());
    assert_eq!(t.arm_turn_deg(), direct.arm_turn_deg());
    assert!(t.settle(3).expect("settled"), "nothing left to do");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());

    // While the clip plays, and after a second preview that starts the work again: the frame
    // reached when the arms take over is the one the shape set at once shows there.
    let narrow = [0.0, -1.0];
    let mut t = at_frame_20();
    t.preview_betas(&wide).expect("preview");
    for _ in 0..5 {
        t.settle(3).expect("settle");
        t.step().expect("step");
    }
    t.preview_betas(&narrow).expect("preview");
    // A playing frame asks about one look a pass of a frame not yet looked at: the steps
    // must leave room for more to catch up.
    let mut steps = 0;
    while !t.settle(8).expect("settle") {
        t.step().expect("step");
        steps += 1;
    }
    let frame = t.frame();
    assert!(steps > 5, "{steps} frames played while settling");
    assert_eq!(
        frame,
        25 + steps,
        "played on while settling ({} frames)",
        t.n_frames()
    );
    let mut direct = at_frame_20();
    direct.set_betas(&narrow).expect("shape");
    direct.seek(frame).expect("seek");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert_eq!(t.arm_turn_deg(), direct.arm_turn_deg());
    // Playing on, the frames are those of the shape set at once.
    for _ in 0..3 {
        t.step().expect("step");
        direct.step().expect("step");
        assert_eq!(t.garment_vertices(), direct.garment_vertices());
    }

    // A shopper's measurements, shown at once and settled the same way.
    let text = "female, 1.68 m, chest_cm=92, waist_cm=76, hips_cm=100";
    let mut t = at_frame_20();
    let betas = t.preview_phenotype_text(text).expect("fit");
    while !t.settle(8).expect("settle") {}
    let mut direct = at_frame_20();
    assert_eq!(direct.set_phenotype_text(text).expect("fit"), betas);
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert!(
        t.preview_phenotype_text("female, 1.68 m, waist_cm=130x")
            .is_err()
    );
    assert_eq!(t.garment_vertices(), direct.garment_vertices());

    // Without held arms there is nothing to settle.
    let mut plain = load();
    plain.preview_betas(&wide).expect("preview");
    assert!(plain.settle(0).expect("settle"));
}

#[test]
fn a_scrub_computes_the_held_arms_of_its_frame_a_few_looks_at_a_time() {
    // The page's scrub bar: the held arms a jump needs computed between display frames, then
    // the jump, which then looks at no frame and shows what a jump at once shows.
    let mut t = at_frame_20();
    let shown = t.garment_vertices();
    let target = t.n_frames() - 10;
    let mut calls = 0;
    while !t.prepare_seek(target, 3).expect("prepare") {
        calls += 1;
        assert_eq!(t.frame(), 20, "the frame shown stays");
    }
    assert!(calls > 20, "{calls} calls of three looks");
    assert!(t.prepare_seek(target, 0).expect("prepared"), "nothing left");
    assert_eq!(t.garment_vertices(), shown);
    t.seek(target).expect("seek");
    let mut direct = at_frame_20();
    direct.seek(target).expect("seek");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert_eq!(t.arm_turn_deg(), direct.arm_turn_deg());
    // A frame past the end is the last, as `seek` takes it (not an error).
    while !t.prepare_seek(usize::MAX, 3).expect("clamped") {}
    t.seek(usize::MAX).expect("seek");
    assert_eq!(t.frame(), t.n_frames() - 1);
    // Without held arms a jump needs nothing.
    assert!(load().prepare_seek(0, 0).expect("prepare"));
}

#[test]
fn a_new_clip_plays_once_its_first_frames_are_held_while_the_last_one_plays_on() {
    // The page's choice of a clip: the clip playing plays on while the new one's first frames
    // get their arms held a few looks at a time; then it plays from its first frame as if
    // set at once.
    let mut t = at_frame_20();
    let clip = stored_clip(&t, "05_06");
    t.begin_motion(clip.clone()).expect("begin");
    let mut steps = 0;
    while !t.settle(3).expect("settle") {
        assert_eq!(t.motion_name(), "cmu/02_02");
        t.step().expect("step");
        steps += 1;
    }
    assert!(steps > 3, "{steps} frames of the last clip while waiting");
    assert_eq!((t.motion_name(), t.frame()), ("cmu/05_06", 0));
    let mut direct = at_frame_20();
    direct.set_motion(clip.clone()).expect("play");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    for _ in 0..3 {
        t.step().expect("step");
        direct.step().expect("step");
    }
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert!(t.settle(0).expect("settled"), "nothing left to do");

    // A shape previewed while the clip waits: the clip plays with the arms held for it.
    let wide = [0.0, 2.0];
    let mut t = at_frame_20();
    t.begin_motion(clip.clone()).expect("begin");
    assert!(!t.settle(3).expect("settle"));
    t.preview_betas(&wide).expect("preview");
    while !t.settle(3).expect("settle") {}
    let mut direct = at_frame_20();
    direct.set_betas(&wide).expect("shape");
    direct.set_motion(clip.clone()).expect("play");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert_eq!(t.arm_turn_deg(), direct.arm_turn_deg());

    // A clip set at once replaces the one begun; a clip for another skeleton is refused and
    // begins nothing.
    let mut t = at_frame_20();
    t.begin_motion(clip).expect("begin");
    t.set_motion(stored_clip(&t, "02_10")).expect("play");
    assert!(t.settle(0).expect("nothing waits"));
    assert_eq!(t.motion_name(), "cmu/02_10");
    let other = sartor_motion::Motion::new(
        "other".into(),
        30.0,
        vec!["root".into()],
        vec![sartor_core::Pose::rest(1)],
    )
    .expect("a one-joint motion");
    let e = t.begin_motion(other).expect_err("another skeleton");
    assert!(e.to_string().contains("another skeleton"), "{e}");
    assert!(t.settle(0).expect("nothing waits"));
    assert_eq!(t.motion_name(), "cmu/02_10");
}

/// The page's worker for the held limbs: the body alone, the limbs held as the page holds them.
fn limbs_worker() -> LimbsWorker {
    let body = files_of(&[(&BODY_FILES[..], "datasets/body/makehuman")]);
    LimbsWorker::load(body, shipped_arm_clearance()).expect("the body loads")
}

/// One round of the page's worker: `t`'s job (none: `false`) computed by `worker` and taken up.
fn worker_round(t: &mut TryOn, worker: &mut LimbsWorker, seek: Option<usize>) -> bool {
    let Some(job) = t.arms_job(seek).expect("job") else {
        return false;
    };
    let answer = worker.run(&job).expect("computed");
    assert!(t.absorb_arms(&answer).expect("answer"), "of use");
    true
}

#[test]
fn held_limbs_computed_in_a_worker_show_what_the_page_computes_itself() {
    // The page hands the held limbs it waits on to a worker and takes up the answer: after a
    // slider's release, a scrub and a new clip, its own calls then compute no look and show
    // the frames of a shape, jump or clip set at once.
    let wide = [0.0, 2.0];
    let mut worker = limbs_worker();
    let mut t = at_frame_20();
    t.preview_betas(&wide).expect("preview");
    let previewed = t.garment_vertices();
    let job = t.arms_job(None).expect("job").expect("the arms wait");
    // A shape previewed since: the answer is of no use, and nothing changes.
    let mut moved = at_frame_20();
    moved.preview_betas(&[0.0, 1.0]).expect("preview");
    let stale = worker.run(&job).expect("computed");
    assert!(!moved.absorb_arms(&stale).expect("an answer"), "stale");
    assert!(!moved.settle(0).expect("settle"), "nothing taken up");
    assert!(t.absorb_arms(&stale).expect("an answer"));
    assert_eq!(
        t.garment_vertices(),
        previewed,
        "the frame shown waits for settle"
    );
    assert!(t.settle(0).expect("settle"), "no look of its own");
    let mut direct = at_frame_20();
    direct.set_betas(&wide).expect("shape");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    assert_eq!(t.arm_turn_deg(), direct.arm_turn_deg());
    assert_eq!(t.arms_job(None).expect("job"), None, "nothing waits");

    // While the clip plays on: the frames played while the worker computed are a few looks
    // more, which the page's own slices take.
    let mut t = at_frame_20();
    t.preview_betas(&wide).expect("preview");
    assert!(worker_round(&mut t, &mut worker, None));
    for _ in 0..5 {
        t.step().expect("step");
    }
    let mut calls = 1;
    while !t.settle(8).expect("settle") {
        t.step().expect("step");
        calls += 1;
    }
    assert!(calls <= 3, "{calls} calls of eight looks");
    let mut direct = at_frame_20();
    direct.set_betas(&wide).expect("shape");
    direct.seek(t.frame()).expect("seek");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());

    // A scrub: the jump's held arms from the worker, then the jump a direct jump shows.
    let mut t = at_frame_20();
    let target = t.n_frames() - 10;
    assert!(worker_round(&mut t, &mut worker, Some(target)));
    assert!(
        t.prepare_seek(target, 0).expect("prepared"),
        "no look of its own"
    );
    assert_eq!(t.arms_job(Some(target)).expect("job"), None);
    t.seek(target).expect("seek");
    let mut direct = at_frame_20();
    direct.seek(target).expect("seek");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());

    // A clip begun: its first frames from the worker, then it plays as if set at once.
    let mut t = at_frame_20();
    let clip = stored_clip(&t, "05_06");
    t.begin_motion(clip.clone()).expect("begin");
    assert!(worker_round(&mut t, &mut worker, None));
    assert!(t.settle(0).expect("settle"), "no look of its own");
    assert_eq!((t.motion_name(), t.frame()), ("cmu/05_06", 0));
    let mut direct = at_frame_20();
    direct.set_motion(clip).expect("play");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());

    // Without held arms the page waits on nothing.
    let mut plain = load();
    plain.preview_betas(&wide).expect("preview");
    assert_eq!(plain.arms_job(None).expect("job"), None);
    assert_eq!(plain.arms_job(Some(3)).expect("job"), None);
}

#[test]
fn frames_played_take_their_held_limbs_from_a_worker_that_computed_them_ahead() {
    // While a clip plays, the page's worker computes the held limbs of the frames ahead: the
    // frames then played compute no look of their own and are the frames played without it.
    let mut worker = limbs_worker();
    let mut t = at_frame_20();
    let mut direct = at_frame_20();
    let job = t
        .arms_ahead_job(15, 60)
        .expect("job")
        .expect("frames ahead lack them");
    assert!(
        t.absorb_arms(&worker.run(&job).expect("computed"))
            .expect("answer")
    );
    assert_eq!(
        t.arms_ahead_job(15, 60).expect("job"),
        None,
        "computed ahead"
    );
    let looks = t.arm_looks();
    for _ in 0..45 {
        t.step().expect("step");
        direct.step().expect("step");
        assert_eq!(t.garment_vertices(), direct.garment_vertices());
        assert_eq!(t.arm_turn_deg(), direct.arm_turn_deg());
    }
    assert_eq!(t.arm_looks(), looks, "no look of its own for 45 frames");
    assert!(direct.arm_looks() > looks, "the frames need looks");
    // Near the end the frames ahead run to it, then from the start, where the clip loops (on
    // a new shape, whose held arms of the clip's start are not computed yet).
    t.set_betas(&[0.0, 2.0]).expect("shape");
    let n = t.n_frames();
    t.seek(n - 5).expect("seek");
    let mut rounds = 0;
    while let Some(job) = t.arms_ahead_job(15, 60).expect("job") {
        assert!(
            t.absorb_arms(&worker.run(&job).expect("computed"))
                .expect("answer")
        );
        rounds += 1;
        assert!(rounds <= 2, "{rounds} jobs");
    }
    assert!(rounds >= 1, "the clip's start lacked them");
    let looks = t.arm_looks();
    for _ in 0..10 {
        t.step().expect("step");
    }
    assert_eq!(t.frame(), 5, "looped");
    assert_eq!(t.arm_looks(), looks, "no look of its own over the loop");
    // Nothing ahead while a shape waits for its held arms, nor without arm clearance.
    let mut t = at_frame_20();
    assert!(t.arms_ahead_job(15, 60).expect("job").is_some(), "as above");
    t.preview_betas(&[0.0, 1.0]).expect("preview");
    assert_eq!(t.arms_ahead_job(15, 60).expect("job"), None);
    assert_eq!(load().arms_ahead_job(15, 60).expect("job"), None);
}

#[test]
fn a_long_clips_jobs_name_its_poses_and_the_answers_carry_only_what_the_page_lacks() {
    // A shopper's long capture: 20 times CMU 02_02 in a row. The first job carries the poses,
    // the next ones their fingerprint; each answer leaves out what the page computed.
    let mut worker = limbs_worker();
    let mut t = at_frame_20();
    let clip = stored_clip(&t, "02_02");
    let frames: Vec<_> = (0..20)
        .flat_map(|_| clip.frames().iter().cloned())
        .collect();
    let n = frames.len();
    let names = clip.joint_names().to_vec();
    let long = sartor_motion::Motion::new("long".into(), clip.fps(), names, frames).expect("clip");
    t.set_motion(long).expect("play");
    let first = t
        .arms_ahead_job(15, 60)
        .expect("job")
        .expect("frames ahead lack them");
    let job = ClearanceJob::from_bytes(&first).expect("a job");
    assert_eq!(job.poses.as_ref().map(Vec::len), Some(n), "the poses, once");
    assert!(job.known.iter().any(|&k| k), "the page's own first frames");
    let answer = worker.run(&first).expect("computed");
    let progress = ClearanceProgress::from_bytes(&answer).expect("an answer");
    assert!(!progress.is_empty());
    assert!(
        !progress.held().zip(&job.known).any(|(h, &k)| h && k),
        "only what it lacks"
    );
    assert!(t.absorb_arms(&answer).expect("answer"));
    for _ in 0..50 {
        t.step().expect("step");
    }
    let second = t
        .arms_ahead_job(15, 60)
        .expect("job")
        .expect("frames ahead lack them");
    let job = ClearanceJob::from_bytes(&second).expect("a job");
    assert_eq!(job.poses, None, "named by their fingerprint");
    assert!(
        100 * second.len() < first.len(),
        "{} bytes, the first {}",
        second.len(),
        first.len()
    );
    let answer = worker.run(&second).expect("computed");
    let progress = ClearanceProgress::from_bytes(&answer).expect("an answer");
    assert!(
        !progress.held().zip(&job.known).any(|(h, &k)| h && k),
        "only what it lacks"
    );
    assert!(t.absorb_arms(&answer).expect("answer"));
    let looks = t.arm_looks();
    for _ in 0..20 {
        t.step().expect("step");
    }
    assert_eq!(t.arm_looks(), looks, "the frames ahead from the worker");
    // A worker that was never given the poses refuses a job that names them.
    let e = limbs_worker()
        .begin(&second)
        .expect_err("poses never given");
    assert!(e.to_string().contains("which no job gave"), "{e}");
}

#[test]
fn a_limbs_worker_computes_a_few_looks_a_step_and_a_newer_job_takes_over() {
    // The page's worker steps through a job so that a newer one (a scrub that moved on, a clip
    // chosen) replaces it between steps; the last job's answer is what the page takes up.
    let mut worker = limbs_worker();
    let e = worker.answer().expect_err("no job yet");
    assert!(e.to_string().contains("no job"), "{e}");
    assert!(worker.work(3).expect("no job: nothing to do"));
    let mut t = at_frame_20();
    t.preview_betas(&[0.0, 2.0]).expect("preview");
    let first = t.arms_job(None).expect("job").expect("the arms wait");
    worker.begin(&first).expect("a job");
    for _ in 0..4 {
        assert!(
            !worker.work(3).expect("work"),
            "a window is more than a few looks"
        );
    }
    // The shape is set after all; then a scrub far along the clip.
    let mut t = at_frame_20();
    let target = t.n_frames() - 10;
    let scrub = t
        .arms_job(Some(target))
        .expect("job")
        .expect("the jump waits");
    worker.begin(&scrub).expect("a job");
    let mut steps = 1;
    while !worker.work(3).expect("work") {
        steps += 1;
    }
    assert!(steps > 10, "{steps} steps of three looks");
    assert!(
        t.absorb_arms(&worker.answer().expect("answer"))
            .expect("answer")
    );
    assert!(
        t.prepare_seek(target, 0).expect("prepared"),
        "no look of its own"
    );
    t.seek(target).expect("seek");
    let mut direct = at_frame_20();
    direct.seek(target).expect("seek");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
}

#[test]
fn a_limbs_worker_refuses_what_is_not_a_job_and_a_page_what_is_not_an_answer() {
    let mut worker = limbs_worker();
    let mut t = at_frame_20();
    t.preview_betas(&[0.0, 2.0]).expect("preview");
    let job = t.arms_job(None).expect("job").expect("the arms wait");
    let e = worker.run(&job[..job.len() - 1]).expect_err("cut short");
    assert!(e.to_string().contains("arm clearance job"), "{e}");
    let e = t.absorb_arms(&job).expect_err("a job, not an answer");
    assert!(e.to_string().contains("arm clearance progress"), "{e}");
    // A job of another skeleton: the poses of a one-joint motion.
    let poses = vec![sartor_core::Pose::rest(1); 3];
    let one_joint = ClearanceJob {
        betas: vec![0.0; 2],
        motion: sartor_motion::ClearanceOnDemand::motion_fingerprint_of(&poses),
        poses: Some(poses),
        frames: 0..3,
        known: Vec::new(),
    };
    let e = worker
        .run(&one_joint.to_bytes())
        .expect_err("another skeleton");
    assert!(e.to_string().contains("frame 0"), "{e}");
    assert!(e.to_string().contains("joint rotations"), "{e}");
    // Too many shape components for the body.
    let mut wide = ClearanceJob::from_bytes(&job).expect("a job");
    wide.betas = vec![0.0; 1000];
    assert!(worker.run(&wide.to_bytes()).is_err());
    // The worker goes on: the page's job still computes, and the page takes it up.
    let answer = worker.run(&job).expect("computed");
    assert!(t.absorb_arms(&answer).expect("answer"));
    assert!(t.settle(0).expect("settle"));
}

/// The model files of `datasets/models/<name>` alone, by the page's names.
fn model_files(name: &str) -> sartor_web::FileSet {
    files_of(&[(
        &sartor_web::MODEL_FILES[..],
        &format!("datasets/models/{name}"),
    )])
}

#[test]
fn another_garment_is_worn_on_the_same_shape_motion_and_frame() {
    // The page's choice of garment: the shipped 8,710-triangle T-shirt put on at frame 20 of
    // CMU 02_02 on a wide body is the garment a page loaded with it shows there, bit for bit;
    // the body, the held arms and the frame do not change, and the first garment comes back.
    let wide = [0.0, 2.0];
    let mut t = at_frame_20();
    t.set_betas(&wide).expect("shape");
    let (garment, body, turn) = (t.garment_vertices(), t.body_vertices(), t.arm_turn_deg());
    assert!(turn > 0.0, "frame 20 holds the arms");
    t.set_garment(model_files("default-8710"))
        .expect("the 8,710-triangle model");
    assert_eq!((t.motion_name(), t.frame()), ("cmu/02_02", 20));
    assert_eq!(t.garment_faces().len(), 3 * 8710);
    assert_eq!(t.body_vertices(), body);
    assert_eq!(t.arm_turn_deg(), turn);
    let fine = t.garment_vertices();
    assert!(fine.iter().all(|v| v.is_finite()));
    let mut direct = playing_02_02_with(files_of(&[
        (&sartor_web::MODEL_FILES[..], "datasets/models/default-8710"),
        (&sartor_web::BODY_FILES[..], "datasets/body/makehuman"),
    ]));
    direct.set_betas(&wide).expect("shape");
    direct.seek(20).expect("seek");
    assert_eq!(fine, direct.garment_vertices());
    // It plays on, and the first garment comes back as it was.
    t.step().expect("step");
    direct.step().expect("step");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
    t.seek(20).expect("seek");
    t.set_garment(model_files("default"))
        .expect("the shipped model");
    assert_eq!(t.garment_faces().len(), 3 * 4210);
    assert_eq!(t.garment_vertices(), garment);

    // Bad files lose nothing: the garment worn stays, with its frame.
    let mut broken = model_files("default-8710");
    let mut bytes = broken.take("model/model.safetensors").expect("present");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x55;
    broken.insert("model/model.safetensors", bytes);
    let e = t.set_garment(broken).expect_err("a corrupt model");
    assert!(e.to_string().contains("model/model.safetensors"), "{e}");
    let mut missing = model_files("default-8710");
    missing.take("model/binding.json").expect("present");
    let e = t.set_garment(missing).expect_err("a missing file");
    assert!(e.to_string().contains("model/binding.json"), "{e}");
    assert_eq!(t.garment_faces().len(), 3 * 4210);
    assert_eq!(t.garment_vertices(), garment);
    assert_eq!(t.frame(), 20);
}

/// The page's worker for the post-process: the shipped model and the body, as the page loads
/// its try-on (f32).
fn post_worker(model: &str) -> PostWorker {
    let files = files_of(&[
        (
            &sartor_web::MODEL_FILES[..],
            &format!("datasets/models/{model}"),
        ),
        (&BODY_FILES[..], "datasets/body/makehuman"),
    ]);
    PostWorker::load(files, Precision::F32, Some(sartor_web::now_ms)).expect("the model loads")
}

#[test]
fn frames_post_processed_in_a_worker_are_the_frames_the_page_makes_itself() {
    // CMU 02_02 with the arms held, at the nominal shape and on a wide body (β₂ = 2; the
    // triangles pushed too, as on the page): each frame stepped with its post-process in the
    // worker is the frame the page makes itself, bit for bit, through a change of shape, a
    // scrub, the clip's end and another garment.
    let wide = [0.0, 2.0];
    let (mut page, mut direct) = (at_frame_20(), at_frame_20());
    let mut worker = post_worker("default");
    let mut deferred = 0;
    let mut step = |page: &mut TryOn, direct: &mut TryOn, worker: &mut PostWorker| {
        let job = page.step_deferred().expect("step");
        direct.step().expect("step");
        if let Some(job) = job {
            let answer = worker.run(&job).expect("post-processed");
            assert!(
                page.absorb_post(&answer).expect("answer"),
                "the frame's answer"
            );
            deferred += 1;
        }
        assert_eq!(page.frame(), direct.frame());
        assert_eq!(page.garment_vertices(), direct.garment_vertices());
        assert_eq!(page.body_vertices(), direct.body_vertices());
        assert_eq!(page.pushed(), direct.pushed());
    };
    for _ in 0..3 {
        step(&mut page, &mut direct, &mut worker);
    }
    for t in [&mut page, &mut direct] {
        t.set_betas(&wide).expect("shape");
    }
    for _ in 0..3 {
        step(&mut page, &mut direct, &mut worker);
    }
    assert!(page.pushed() > 0, "the frames collide");
    assert!(
        page.times().garment.post_process_ms > 0.0,
        "the worker's time"
    );
    // The end of the clip: its last frame deferred, the first again shown whole (a jump).
    let last = page.n_frames() - 1;
    for t in [&mut page, &mut direct] {
        t.seek(last - 1).expect("seek");
    }
    step(&mut page, &mut direct, &mut worker);
    let job = page.step_deferred().expect("step");
    direct.step().expect("step");
    assert!(job.is_none(), "a jump back to the start is shown whole");
    assert_eq!(
        (page.frame(), page.garment_vertices()),
        (0, direct.garment_vertices())
    );
    for t in [&mut page, &mut direct] {
        t.set_garment(model_files("default-8710"))
            .expect("8,710 triangles");
    }
    let mut fine = post_worker("default-8710");
    for _ in 0..2 {
        step(&mut page, &mut direct, &mut fine);
    }
    assert_eq!(deferred, 9);
}

#[test]
fn a_stale_post_process_answer_changes_nothing() {
    let mut t = at_frame_20();
    let mut worker = post_worker("default");
    let job = t.step_deferred().expect("step").expect("deferred");
    let answer = worker.run(&job).expect("post-processed");
    // A scrub shows another frame whole before the answer comes: the answer is stale.
    t.seek(5).expect("scrub");
    let shown = t.garment_vertices();
    assert!(!t.absorb_post(&answer).expect("an answer"), "stale");
    assert_eq!(t.garment_vertices(), shown);
    // A later job's answer is taken; the earlier one, crossing it, is not.
    let first = t.step_deferred().expect("step").expect("deferred");
    let second = t.step_deferred().expect("step").expect("deferred");
    let unprocessed = t.garment_vertices();
    let (a, b) = (worker.run(&first).unwrap(), worker.run(&second).unwrap());
    assert!(!t.absorb_post(&a).expect("an answer"));
    assert_eq!(t.garment_vertices(), unprocessed);
    assert!(t.absorb_post(&b).expect("an answer"));
    assert!(t.pushed() > 0, "the frame collides");
    assert_ne!(
        t.garment_vertices(),
        unprocessed,
        "the answer's garment shown"
    );
    assert!(!t.absorb_post(&b).expect("an answer"), "taken once");
}

#[test]
fn a_post_worker_refuses_what_is_not_a_job_and_a_page_what_is_not_an_answer() {
    let mut t = at_frame_20();
    let mut worker = post_worker("default");
    let job = t.step_deferred().expect("step").expect("deferred");
    let e = worker.run(&job[..job.len() - 1]).expect_err("cut short");
    assert!(e.to_string().contains("post-process job"), "{e}");
    assert!(e.to_string().contains("cut short"), "{e}");
    let mut longer = job.clone();
    longer.push(0);
    let e = worker.run(&longer).expect_err("too long");
    assert!(e.to_string().contains("1 bytes after the end"), "{e}");
    let e = t.absorb_post(&job).expect_err("a job, not an answer");
    assert!(e.to_string().contains("post-process answer"), "{e}");
    // A coordinate that is not finite (the garment's last one), a garment of the other model,
    // a shape of another component count.
    let mut nan = job.clone();
    let at = nan.len() - 4;
    nan[at..].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = worker.run(&nan).expect_err("NaN");
    assert!(e.to_string().contains("NaN"), "{e}");
    let mut fine = post_worker("default-8710");
    let e = fine.run(&job).expect_err("another garment");
    assert!(e.to_string().contains("garment vertices"), "{e}");
    // The worker goes on: the page's job post-processes, and the page takes it up.
    let answer = worker.run(&job).expect("post-processed");
    let e = t
        .absorb_post(&answer[..answer.len() - 2])
        .expect_err("cut short");
    assert!(e.to_string().contains("post-process answer"), "{e}");
    assert!(t.absorb_post(&answer).expect("answer"));
    let mut direct = at_frame_20();
    direct.step().expect("step");
    assert_eq!(t.garment_vertices(), direct.garment_vertices());
}
