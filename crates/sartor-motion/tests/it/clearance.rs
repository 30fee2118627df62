//! Arm clearance on real motion capture: a CMU walk retargeted onto a wide body swings the
//! forearms through the hips; [`ArmClearance::apply`] takes them out and changes nothing else.

use nalgebra::Vector3;
use sartor_core::{BodyDistance, BodyModel, BodyPoser, BoneTransform, Pose, vertex_normals};
use sartor_motion::{
    ArmClearance, ClearanceJob, ClearanceOnDemand, ClearanceOptions, ClearanceProgress,
    LEG_CLEARANCE_M, UPPER_ARM_MIN_LEVER, load_motion,
};

use crate::motion_library::library_options;
use crate::motion_sources::builtin_model_dir;

#[test]
fn a_walk_on_a_wide_body_keeps_its_hands_out_of_the_hips_and_the_rest_as_it_was() {
    let body = BodyModel::load(&builtin_model_dir()).expect("built-in body");
    let clearance = ArmClearance::new(&body).expect("arms and torso");
    let betas = [0.0, 2.0];
    // A sequence of the CMU experiment that failed to simulate on this shape.
    let walk = load_motion("cmu/02_02@8+60", &library_options()).expect("clip");
    let before = clearance
        .depths(&body, &betas, walk.frames(), &ClearanceOptions::default())
        .expect("depths");
    let deepest = before.iter().copied().fold(0.0, f64::max);
    assert!(deepest > 0.02, "deepest {:.1} mm", deepest * 1e3);

    let options = ClearanceOptions::default();
    let (poses, report) = clearance
        .apply(&body, &betas, walk.frames(), &options)
        .expect("apply");
    assert_eq!(poses.len(), walk.frames().len());
    assert!((report.max_depth_before_m - deepest).abs() < 1e-9);
    let after = clearance
        .depths(&body, &betas, &poses, &options)
        .expect("depths");
    let deepest_after = after.iter().copied().fold(0.0, f64::max);
    assert!(
        deepest_after < 1e-3,
        "still {:.1} mm inside",
        deepest_after * 1e3
    );
    assert_eq!(report.max_depth_after_m, deepest_after);
    assert!(report.max_angle_rad > 0.0 && report.max_angle_rad <= options.max_angle_rad);

    // Only the upper arms turn, and only near frames that needed it.
    let names = body.skeleton().names();
    let mut changed = 0;
    for (t, (got, was)) in poses.iter().zip(walk.frames()).enumerate() {
        assert_eq!(got.root_translation_m, was.root_translation_m);
        assert_eq!(got.root_orientation, was.root_orientation);
        let mut moved = false;
        for j in turned_joints(got, was) {
            assert!(
                names[j] == "LeftArm" || names[j] == "RightArm",
                "frame {t}: {} changed",
                names[j]
            );
            moved = true;
        }
        if moved {
            changed += 1;
            let near = (t.saturating_sub(options.ramp_frames)
                ..(t + options.ramp_frames + 1).min(before.len()))
                .any(|s| before[s] > 0.0);
            assert!(near, "frame {t} changed, nothing within reach needed it");
        }
        if before[t] > 0.0 {
            assert!(moved, "frame {t} was {:.1} mm inside", before[t] * 1e3);
        }
    }
    assert_eq!(changed, report.frames_changed);

    // The easing: neighbouring frames' upper arms differ by a bounded angle (no jump).
    let arm = body.skeleton().index_of("LeftArm").expect("LeftArm");
    for pair in poses.windows(2).zip(walk.frames().windows(2)) {
        let turned = |p: &Pose, q: &Pose| p.local_rotations[arm].angle_to(&q.local_rotations[arm]);
        let step = turned(&pair.0[1], &pair.0[0]);
        let was = turned(&pair.1[1], &pair.1[0]);
        assert!(
            step <= was + report.max_angle_rad / options.ramp_frames as f64 * 2.0 + 1e-9,
            "the upper arm jumps {:.1}° in a frame (the motion's own {:.1}°)",
            step.to_degrees(),
            was.to_degrees()
        );
    }
}

#[test]
fn the_rest_pose_needs_nothing_and_bad_options_are_refused() {
    let body = BodyModel::load(&builtin_model_dir()).expect("built-in body");
    let clearance = ArmClearance::new(&body).expect("arms and torso");
    let rest = vec![Pose::rest(body.skeleton().n_joints()); 3];
    let (poses, report) = clearance
        .apply(&body, &[1.0, 1.0], &rest, &ClearanceOptions::default())
        .expect("apply");
    assert_eq!(poses, rest);
    assert_eq!(report.frames_changed, 0);
    assert_eq!(report.max_depth_before_m, 0.0);
    for bad in [
        ClearanceOptions {
            clearance_m: f64::NAN,
            ..ClearanceOptions::default()
        },
        ClearanceOptions {
            max_angle_rad: 0.0,
            ..ClearanceOptions::default()
        },
        ClearanceOptions {
            upper_arm_clearance_m: Some(-1e-3),
            ..ClearanceOptions::default()
        },
        ClearanceOptions {
            leg_clearance_m: Some(f64::INFINITY),
            ..ClearanceOptions::default()
        },
    ] {
        let e = clearance
            .apply(&body, &[0.0], &rest, &bad)
            .expect_err("refused");
        assert!(e.to_string().contains("arm clearance"), "{e}");
    }
}

/// The joints whose local rotation differs between two poses.
fn turned_joints<'a>(got: &'a Pose, was: &'a Pose) -> impl Iterator<Item = usize> + 'a {
    (got.local_rotations.iter().zip(&was.local_rotations))
        .enumerate()
        .filter(|(_, (a, b))| a != b)
        .map(|(j, _)| j)
}

/// The built-in body and its limbs, with the arms held as the shipped model's experiment held
/// them, and the same with the legs held as the players hold them.
fn shipped_limbs() -> (BodyModel, ArmClearance, ClearanceOptions, ClearanceOptions) {
    let body = BodyModel::load(&builtin_model_dir()).expect("built-in body");
    let clearance = ArmClearance::new(&body).expect("arms, legs and torso");
    let arms = ClearanceOptions {
        upper_arm_clearance_m: Some(0.005),
        ..ClearanceOptions::default()
    };
    let legs = arms.clone().with_player_legs();
    assert_eq!(legs.leg_clearance_m, Some(LEG_CLEARANCE_M));
    (body, clearance, arms, legs)
}

#[test]
fn a_raised_thigh_is_held_out_of_the_belly_and_a_walk_keeps_its_legs() {
    // A dance whose performer lifts a knee higher than the body's belly lets it (CMU 05_08,
    // frames 12–35: the thigh 46 mm into the torso at frame 28), and a walk.
    let (body, clearance, arms, legs) = shipped_limbs();
    // Every held vertex's depth, the legs' among them (the arms, held at 25 mm, are out).
    let inside = ClearanceOptions {
        clearance_m: 0.0,
        leg_clearance_m: Some(0.0),
        ..arms.clone()
    };
    let deepest = |poses: &[Pose]| {
        clearance
            .depths(&body, &[0.0, 0.0], poses, &inside)
            .expect("depths")
            .into_iter()
            .fold(0.0, f64::max)
    };
    let dance = load_motion("cmu/05_08@12+24", &library_options()).expect("clip");
    let (arms_held, _) = clearance
        .apply(&body, &[0.0, 0.0], dance.frames(), &arms)
        .expect("apply");
    let before = deepest(&arms_held);
    assert!(before > 0.04, "the thigh {:.1} mm inside", before * 1e3);
    let (held, report) = clearance
        .apply(&body, &[0.0, 0.0], dance.frames(), &legs)
        .expect("apply");
    let after = deepest(&held);
    assert!(after < 1e-3, "still {:.1} mm inside", after * 1e3);
    assert!(report.max_depth_before_m >= before);
    assert!(report.max_angle_rad <= legs.max_angle_rad * legs.max_passes as f64);
    // Only the hips turn besides the shoulders (whose fixes see the torso the hips move), and
    // the feet, which turn back: each foot keeps its orientation in the world (the skeleton's
    // own forward kinematics of both poses).
    let skeleton = body.skeleton();
    let names = skeleton.names();
    let rest = body.shaped_joints(&[0.0, 0.0]).expect("joints");
    let world = |pose: &Pose| {
        let n = skeleton.n_joints();
        let mut joints = vec![nalgebra::Vector3::zeros(); n];
        let mut transforms = vec![BoneTransform::identity(); n];
        (skeleton.forward_kinematics_into(&rest, pose, &mut joints, &mut transforms))
            .expect("forward kinematics");
        transforms
    };
    let mut hips_turned = 0;
    for (got, was) in held.iter().zip(&arms_held) {
        assert_eq!(got.root_orientation, was.root_orientation);
        let (got_world, was_world) = (world(got), world(was));
        for j in turned_joints(got, was) {
            let foot = names[j].ends_with("Foot");
            assert!(
                names[j].ends_with("UpLeg") || names[j].ends_with("Arm") || foot,
                "{} turned",
                names[j]
            );
            hips_turned += usize::from(names[j].ends_with("UpLeg"));
            if foot {
                let turned = got_world[j].linear.transpose() * was_world[j].linear;
                let off = (turned - nalgebra::Matrix3::identity()).abs().max();
                assert!(off < 1e-9, "{}'s orientation moved by {off:e}", names[j]);
            }
        }
    }
    assert!(hips_turned > 0);

    // A walk's legs never come near the belly: the same poses, bit for bit.
    let walk = load_motion("cmu/02_02@8+60", &library_options()).expect("clip");
    let with = clearance.apply(&body, &[0.0, 2.0], walk.frames(), &legs);
    let without = clearance.apply(&body, &[0.0, 2.0], walk.frames(), &arms);
    assert_eq!(with.expect("apply").0, without.expect("apply").0);
}

#[test]
fn held_out_upper_arms_leave_no_pocket_between_arm_and_torso() {
    // A CMU clip on the heavy shape of the 8,710-triangle experiment (β₀ = 2), the frames where
    // its hanging upper arms sank into the torso's sides and the shirt between stayed inside
    // the arm in the simulation.
    let body = BodyModel::load(&builtin_model_dir()).expect("built-in body");
    let clearance = ArmClearance::new(&body).expect("arms and torso");
    let betas = [2.0];
    let clip = load_motion("cmu/05_18@184+90", &library_options()).expect("clip");
    let poses = &clip.frames()[40..56];
    let options = ClearanceOptions {
        upper_arm_clearance_m: Some(0.005),
        ..ClearanceOptions::default()
    };
    let (corrected, report) = clearance
        .apply(&body, &betas, poses, &options)
        .expect("apply");
    assert!(
        report.max_depth_before_m > 0.01,
        "{:.1} mm",
        report.max_depth_before_m * 1e3
    );
    assert_eq!(report.max_depth_after_m, 0.0, "{report:?}");
    // A small turn, not arms held out: under 15°.
    assert!(report.max_angle_rad < 15f64.to_radians(), "{report:?}");

    // Independently of the torso surface the correction uses: 2 mm outside the skin of the
    // upper arm beyond UPPER_ARM_MIN_LEVER of its length, the whole body's winding number (the
    // collision measure) finds no other body part.
    let names = body.skeleton().names();
    let upper: Vec<(usize, usize)> = (0..body.n_vertices())
        .filter_map(|v| {
            let j = body.skin_weights().dominant_joint(v);
            let upper_arm = names[j].ends_with("Arm") && !names[j].ends_with("ForeArm");
            upper_arm.then_some((v, j))
        })
        .collect();
    let pockets = |poses: &[Pose]| -> usize {
        let mut poser = BodyPoser::new(&body);
        let mut posed = vec![Vector3::zeros(); body.n_vertices()];
        let mut count = 0;
        for pose in poses {
            poser
                .pose_into(&[2.0, 0.0], pose, &mut posed)
                .expect("pose");
            let joints = poser.posed_joints().to_vec();
            let distance = BodyDistance::new(&posed, body.faces()).expect("distance");
            let normals = vertex_normals(&posed, body.faces());
            for &(v, j) in &upper {
                let elbow = (0..names.len())
                    .filter(|&c| body.skeleton().parents()[c] == Some(j))
                    .map(|c| (joints[c] - joints[j]).norm())
                    .fold(0.0, f64::max);
                if (posed[v] - joints[j]).norm() < UPPER_ARM_MIN_LEVER * elbow {
                    continue;
                }
                let outside = posed[v] + normals[v] * 2e-3;
                count += usize::from(distance.winding_number(&outside) > 0.5);
            }
        }
        count
    };
    let before = pockets(poses);
    assert!(before > 0, "the clip's upper arms were inside the torso");
    assert_eq!(pockets(&corrected), 0, "{before} pocket points before");
}

#[test]
fn frames_asked_for_one_at_a_time_are_the_whole_clips_poses_bit_for_bit() {
    // As the try-on page asks: a jump into the middle, playing on to the end, then from the
    // start again; on the shapes and options the shipped model was trained with. And the same
    // work done a few looks at a time, as the page does after a change of shape (`prepare`).
    let (body, clearance, options, with_legs) = shipped_limbs();
    let bits = |pose: &Pose| -> Vec<u64> {
        std::iter::once(&pose.root_orientation)
            .chain(&pose.local_rotations)
            .flat_map(|q| q.coords.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
            .chain(pose.root_translation_m.iter().map(|c| c.to_bits()))
            .collect()
    };
    let mut turned = 0;
    // And with the legs held, as the try-on page holds them.
    for (clip, betas, options) in [
        ("cmu/02_02@8+60", [0.0, 2.0], &options),
        ("cmu/05_06@0+40", [0.0, 0.0], &options),
        ("cmu/05_08@12+24", [0.0, 0.0], &with_legs),
    ] {
        let motion = load_motion(clip, &library_options()).expect("clip");
        let poses = motion.frames();
        let (whole, report) = clearance
            .apply(&body, &betas, poses, options)
            .expect("apply");
        let new = || {
            ClearanceOnDemand::new(&clearance, &body, &betas, poses.to_vec(), options)
                .expect("on demand")
        };
        let (mut on_demand, mut stepwise) = (new(), new());
        let n = poses.len();
        let order = (n / 2..n).chain(0..n / 2);
        let mut halted = 0;
        for t in order {
            let pose = on_demand.pose(&body, t).expect("pose");
            assert_eq!(bits(&pose), bits(&whole[t]), "{clip} frame {t}");
            // At most three looks a call: a call that stops short took all three.
            const LOOKS: usize = 3;
            loop {
                let looks = stepwise.looks();
                let done = stepwise.prepare(&body, t, LOOKS).expect("prepare");
                let took = stepwise.looks() - looks;
                assert!(
                    took == LOOKS || (done && took < LOOKS),
                    "{clip} frame {t}: {took}"
                );
                if done {
                    break;
                }
                halted += 1;
            }
            let looks = stepwise.looks();
            assert_eq!(bits(&stepwise.pose(&body, t).expect("pose")), bits(&pose));
            assert_eq!(
                stepwise.looks(),
                looks,
                "{clip} frame {t}: prepared, no look left"
            );
            let angle = on_demand.angle_rad(&body, t).expect("angle");
            assert!(angle <= options.max_angle_rad, "{angle}");
            assert_eq!(
                angle > 0.0,
                bits(&pose) != bits(&poses[t]),
                "{clip} frame {t}"
            );
            turned += usize::from(angle > 0.0);
        }
        // Every frame looked at once at least, each pass's look only where a pass before
        // turned the frame.
        let looks = on_demand.looks();
        assert!(looks >= n, "{clip}: {looks} looks");
        assert!(looks <= n * options.max_passes, "{clip}: {looks} looks");
        if report.frames_changed == 0 {
            assert_eq!(
                looks, n,
                "{clip}: nothing turned, every frame looked at once"
            );
        }
        // The same looks, split or not.
        assert_eq!(stepwise.looks(), looks, "{clip}");
        assert!(halted > 0, "{clip}: no call ran out of looks");
        let e = on_demand.pose(&body, n).expect_err("past the end");
        assert!(e.to_string().contains("frame"), "{e}");
        let e = stepwise.prepare(&body, n, 1).expect_err("past the end");
        assert!(e.to_string().contains("frame"), "{e}");
    }
    assert!(turned > 0, "neither clip was turned: nothing compared");
}

#[test]
fn held_limbs_computed_elsewhere_are_taken_up_bit_for_bit() {
    // The try-on page computes a jump's held limbs in a worker and hands them to the page's
    // own `ClearanceOnDemand` as bytes: that one then computes no look and gives the poses it
    // would have computed itself.
    let (body, clearance, _, with_legs) = shipped_limbs();
    let motion = load_motion("cmu/02_02@8+60", &library_options()).expect("clip");
    let poses = motion.frames();
    let betas = [0.0, 2.0];
    let new = |betas: &[f64], options: &ClearanceOptions| {
        ClearanceOnDemand::new(&clearance, &body, betas, poses.to_vec(), options)
            .expect("on demand")
    };
    let (mut worker, mut page, mut alone) = (
        new(&betas, &with_legs),
        new(&betas, &with_legs),
        new(&betas, &with_legs),
    );
    assert_eq!(worker.fingerprint(), page.fingerprint());
    // The page's job, as bytes: the worker's own `ClearanceOnDemand` is of the same motion,
    // shape and options.
    let job = ClearanceJob::from_bytes(&page.job(30..32, true).to_bytes()).expect("read back");
    assert_eq!(job, page.job(30..32, true));
    assert_eq!(job.betas, betas);
    assert_eq!(job.poses.as_deref(), Some(poses));
    assert_eq!(job.motion, ClearanceOnDemand::motion_fingerprint_of(poses));
    assert!(
        job.known.iter().all(|k| !k),
        "the page computed nothing yet"
    );
    assert_eq!(
        ClearanceOnDemand::fingerprint_of(&body, &job.betas, job.motion, &with_legs),
        page.fingerprint()
    );
    // A later job of the same motion names the poses by their fingerprint alone.
    let named = page.job(30..32, false);
    assert_eq!(named.poses, None);
    let named_bytes = named.to_bytes();
    assert_eq!(
        ClearanceJob::from_bytes(&named_bytes).expect("read back"),
        named
    );
    // (Bits that do not fill their last byte.)
    let odd = ClearanceJob {
        known: [
            true, false, true, true, false, false, false, false, true, false, true,
        ]
        .to_vec(),
        ..named.clone()
    };
    assert_eq!(
        ClearanceJob::from_bytes(&odd.to_bytes()).expect("read back"),
        odd
    );
    assert!(
        20 * named_bytes.len() < job.to_bytes().len(),
        "{} bytes without the poses",
        named_bytes.len()
    );
    for t in job.frames {
        assert!(worker.prepare(&body, t, usize::MAX).expect("prepare"));
    }
    let bytes = worker.progress().to_bytes();
    let progress = ClearanceProgress::from_bytes(&bytes).expect("read back");
    assert_eq!(progress, worker.progress());
    assert!(!page.is_computed(30), "not yet");
    // What the page computed meanwhile is left out of the answer.
    assert!(!page.prepare(&body, 30, 5).expect("five looks"));
    let known = page.job(30..32, false).known;
    assert!(known.iter().any(|&k| k), "the page computed some");
    let beyond = worker.progress_beyond(&known);
    assert!(!beyond.is_empty() && beyond.len() < progress.len());
    let taken = page
        .absorb(&ClearanceProgress::from_bytes(&beyond.to_bytes()).expect("read back"))
        .expect("the same motion, shape and options");
    assert_eq!(taken, beyond.len(), "every entry the answer holds");
    assert_eq!(page.absorb(&progress).expect("again"), 0, "nothing new");
    for t in [30, 31] {
        assert!(worker.is_computed(t) && page.is_computed(t), "frame {t}");
        assert!(page.prepare(&body, t, 0).expect("prepared"), "frame {t}");
        let pose = page.pose(&body, t).expect("pose");
        assert_eq!(pose, alone.pose(&body, t).expect("pose"), "frame {t}");
    }
    assert_eq!(page.looks(), 5, "no look of its own but the five");
    assert!(alone.looks() > 5);

    // Of another shape, options or motion: refused, and nothing taken.
    let mut other_shape = new(&[0.0, 1.0], &with_legs);
    let mut other_options = new(&betas, &ClearanceOptions::default());
    let mut shorter =
        ClearanceOnDemand::new(&clearance, &body, &betas, poses[..40].to_vec(), &with_legs)
            .expect("on demand");
    for held in [&mut other_shape, &mut other_options, &mut shorter] {
        assert_ne!(held.fingerprint(), progress.fingerprint());
        let e = held.absorb(&progress).expect_err("another");
        assert!(e.to_string().contains("another motion"), "{e}");
    }
    assert!(!other_shape.prepare(&body, 30, 0).expect("nothing taken"));

    // Bytes cut short, lengthened, of another format or with a value that is not finite.
    let mut not_finite = bytes.clone();
    // After the magic, the fingerprint, three counts and a bit an entry (3 passes of 60
    // frames, twice), the first value.
    let first_value = 28 + (2 * 3 * 60_usize).div_ceil(8);
    not_finite[first_value..first_value + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    let nan_fault = format!("a value of NaN at byte {first_value}");
    let mut no_frames = bytes.clone();
    no_frames[20..24].copy_from_slice(&0u32.to_le_bytes());
    let mut huge = bytes.clone();
    huge[20..24].copy_from_slice(&u32::MAX.to_le_bytes());
    let longer = [bytes.as_slice(), &[0]].concat();
    assert_refused(
        ClearanceProgress::from_bytes,
        "arm clearance progress",
        &[
            (&bytes[..bytes.len() - 1], "cut short"),
            (&longer, "after the end"),
            (b"sartorX1", "not one of sartor's (no `sartorC2`"),
            (&not_finite, &nan_fault),
            (&no_frames, "3 passes of 0 frames"),
            (&huge, "cut short"),
        ],
    );
    let job = page.job(0..60, true).to_bytes();
    // After the magic and three counts, the shape's two values, the motion's fingerprint and
    // the poses' flag.
    let mut not_finite = job.clone();
    not_finite[20..28].copy_from_slice(&f64::INFINITY.to_le_bytes());
    let mut beyond = job.clone();
    beyond[12..16].copy_from_slice(&61u32.to_le_bytes());
    let mut named_wrong = job.clone();
    named_wrong[36] ^= 1;
    let mut flag = job.clone();
    flag[44] = 7;
    let longer = [job.as_slice(), &[0]].concat();
    assert_refused(
        ClearanceJob::from_bytes,
        "arm clearance job",
        &[
            (&job[..job.len() - 3], "cut short"),
            (&longer, "after the end"),
            (b"sartorC2", "not one of sartor's (no `sartorJ2`"),
            (&not_finite, "a value of inf at byte 20"),
            (&beyond, "frames 0..61 of 60"),
            (&named_wrong, "poses of fingerprint"),
            (&flag, "poses flag 7 at byte 44"),
        ],
    );
}

/// Each case's bytes refused by `read` with a message naming its fault and `what`.
fn assert_refused<T: std::fmt::Debug>(
    read: impl Fn(&[u8]) -> sartor_core::Result<T>,
    what: &str,
    cases: &[(&[u8], &str)],
) {
    for (bad, fault) in cases {
        let message = read(bad).expect_err(fault).to_string();
        assert!(message.contains(fault), "{message}");
        assert!(message.contains(what), "{message}");
    }
}
