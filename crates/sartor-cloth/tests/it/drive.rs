//! The moving-body driver and its sequence files, on the committed 500-triangle T-shirt and
//! the built-in body: penetration, the body region, determinism, the MCAP round trip, failures
//! and retries, relaxation.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nalgebra::Vector3;
use sartor_cloth::{
    Cloth, ClothSequence, DriveConfig, Error, FrictionModel, Garment,
    IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME, LinearSolver, Material, Phase, RelaxConfig,
    STABLE_STEP_PER_EDGE_S_PER_M, SequenceFailure, StepFailure, contact_region,
    folded_hinge_percent, relax_on_body, simulate_sequence,
};
use sartor_core::{BodyModel, MeshProximity};
use sartor_motion::{ClearanceOptions, Motion, MotionSourceOptions, RetargetBody, load_motion};

fn body() -> &'static BodyModel {
    static BODY: OnceLock<BodyModel> = OnceLock::new();
    BODY.get_or_init(|| crate::common::load_builtin().expect("the built-in body"))
}

fn tshirt() -> Garment {
    Garment::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/garments/tshirt-tiny"),
    )
    .expect("datasets/garments/tshirt-tiny")
}

/// A fresh empty folder under the system's temporary folder.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sartor-drive-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temporary folder");
    dir
}

/// A short, quick sequence setting: 3 blend and 2 rest frames, a preview every 2 frames.
fn quick_config() -> DriveConfig {
    let mut c = DriveConfig {
        blend_frames: 3,
        rest_frames: 2,
        ..DriveConfig::default()
    };
    c.preview.every_n_frames = 2;
    c
}

/// Eight frames from the middle of a fast clip (the arms swing through the sleeves).
fn clip() -> Motion {
    let m = sartor_motion::procedural::clip("arm_circles_fast").expect("procedural clip");
    m.slice(40..48).expect("frames")
}

fn simulate(
    betas: &[f64],
    motion: Option<&Motion>,
    config: &DriveConfig,
) -> sartor_cloth::Result<ClothSequence> {
    simulate_sequence(
        body(),
        &tshirt(),
        &Material::gray_interlock(),
        betas,
        motion,
        config,
        &mut |_, _| {},
    )
}

fn betas(first: f64) -> Vec<f64> {
    let mut b = vec![0.0; body().n_betas()];
    b[0] = first;
    b
}

#[test]
fn a_tshirt_follows_a_fast_clip_without_penetration() {
    let motion = clip();
    let config = quick_config();
    let betas = betas(1.0);
    let seq = simulate(&betas, Some(&motion), &config).expect("simulates");
    let h = &seq.header;
    assert_eq!(seq.frames.len(), 3 + 2 + motion.n_frames());
    assert_eq!(h.motion_frames, motion.n_frames());
    assert_eq!(seq.phase_frames(Phase::Blend).count(), 3);
    assert_eq!(seq.frames[5].motion_frame, Some(0));
    assert_eq!(seq.frames[4].betas, betas, "the blend ends at β");
    assert!(seq.frames[0].betas[0] > 0.0 && seq.frames[0].betas[0] < 1.0);
    assert_eq!(seq.frames[7].pose, motion.frames()[2]);

    // The region: far fewer triangles than the body, and every excluded one stays farther than
    // the contact thickness from the cloth in every frame. Penetration, measured against the
    // whole body posed from the β and pose stored with each frame: at most 1 mm.
    let kept = contact_region(body(), &tshirt(), &betas, Some(&motion), &config).expect("region");
    let n_faces = body().faces().len();
    assert_eq!(kept.len(), h.region.faces_kept);
    assert!(
        kept.len() < n_faces / 2 && kept.len() > n_faces / 20,
        "{} of {n_faces}",
        kept.len()
    );
    let mut is_kept = vec![false; n_faces];
    kept.iter().for_each(|&f| is_kept[f as usize] = true);
    let excluded: Vec<[u32; 3]> = body()
        .faces()
        .iter()
        .zip(&is_kept)
        .filter(|(_, k)| !**k)
        .map(|(t, _)| *t)
        .collect();
    let thickness = config.sim.contact_penalty.thickness_m;
    let mut deepest: f64 = 0.0;
    let mut closest_excluded = f64::INFINITY;
    for (i, frame) in seq.frames.iter().enumerate() {
        let posed = body()
            .posed_vertices(&frame.betas, &frame.pose)
            .expect("pose");
        let whole = MeshProximity::new(&posed, body().faces()).expect("body");
        let outside = MeshProximity::new(&posed, &excluded).expect("excluded");
        for p in frame.positions_vec3() {
            let p: Vector3<f64> = p.cast();
            assert!(p.iter().all(|c| c.is_finite()), "frame {i}");
            deepest = deepest.max(-whole.closest(&p).signed_distance_m);
            closest_excluded = closest_excluded.min(outside.closest(&p).signed_distance_m.abs());
        }
    }
    assert!(deepest <= 1e-3 + 1e-6, "{:.3} mm inside", deepest * 1e3);
    assert!(
        closest_excluded > thickness,
        "{:.2} mm from an excluded triangle",
        closest_excluded * 1e3
    );
    assert!(
        h.solver.max_obstacle_contacts > 0,
        "the cloth touches the body"
    );
    // The stored identities: the garment's is the hash in its garment.json.
    assert_eq!(h.body.asset.sha256, body().content_sha256().expect("hash"));
    let garment_json: serde_json::Value = serde_json::from_slice(
        &std::fs::read(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../datasets/garments/tshirt-tiny/garment.json"),
        )
        .expect("garment.json"),
    )
    .expect("json");
    assert_eq!(
        garment_json["tensors_sha256"],
        h.garment.asset.sha256.as_str()
    );
    assert_eq!(
        h.garment.asset.sha256,
        tshirt().content_sha256().expect("hash")
    );
}

#[test]
fn sequence_files_round_trip_and_bad_files_are_named() {
    let dir = temp_dir("round-trip");
    // β shorter than the model's is padded with zeros.
    let seq = simulate(&[-1.0], None, &quick_config()).expect("simulates");
    assert_eq!(seq.header.betas, betas(-1.0));
    assert_eq!(seq.frames.len(), 5);
    assert!(seq.header.motion.is_none());
    let path = dir.join("rest.mcap");
    seq.write(&path).expect("write");
    let back = ClothSequence::read(&path).expect("read back");
    assert_eq!(back.header, seq.header);
    assert_eq!(back.faces, seq.faces);
    assert_eq!(back.frames, seq.frames);
    assert_eq!(back.preview, seq.preview);
    assert!(back.timing.is_none() && seq.timing.is_some());
    let preview = back.preview.expect("a preview every 2 frames");
    assert_eq!(
        preview.frames.iter().map(|p| p.frame).collect::<Vec<_>>(),
        vec![0, 2, 4]
    );
    assert!(!preview.body_faces.is_empty());

    let bytes = std::fs::read(&path).expect("bytes");
    for (name, bad) in [
        ("truncated.mcap", bytes[..bytes.len() * 2 / 3].to_vec()),
        ("empty.mcap", Vec::new()),
        ("text.mcap", b"not an mcap file".to_vec()),
    ] {
        let bad_path = dir.join(name);
        std::fs::write(&bad_path, bad).expect("write");
        let e = ClothSequence::read(&bad_path).expect_err("malformed");
        assert!(e.to_string().contains(name), "{e}");
    }
    // A well-formed MCAP file whose header was tampered with (hash mismatch).
    let mut tampered = seq.clone();
    tampered.header.drive_config.rest_frames += 1;
    let e = tampered
        .to_bytes(&dir.join("x.mcap"))
        .expect_err("inconsistent");
    assert!(e.to_string().contains("drive_config"), "{e}");
    let e = ClothSequence::read(&dir.join("missing.mcap")).expect_err("missing");
    assert!(e.to_string().contains("missing.mcap"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn reruns_give_byte_identical_files() {
    let motion = clip().slice(0..3).expect("frames");
    let path = Path::new("same.mcap");
    let run = |config: &DriveConfig| {
        simulate(&betas(0.5), Some(&motion), config)
            .expect("simulates")
            .to_bytes(path)
            .expect("bytes")
    };
    let (a, b) = (run(&quick_config()), run(&quick_config()));
    assert!(a == b, "two runs differ ({} vs {} bytes)", a.len(), b.len());
    // On threads (the assembly's shares and the frame checks; this shirt is one CG chunk, so
    // the CG team is left to linsolve's tests): the same bytes.
    let mut parallel = quick_config();
    parallel.sim.parallelism = sartor_core::Parallelism::Rayon;
    for threads in [2, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let c = pool.install(|| run(&parallel));
        assert!(
            a == c,
            "{threads} threads differ ({} vs {} bytes)",
            a.len(),
            c.len()
        );
    }
}

#[test]
fn failures_are_retried_then_reported_and_nothing_is_written() {
    let dir = temp_dir("failure");
    let out = dir.join("failed.mcap");
    // A kinetic-energy bound no motion meets: every attempt fails.
    let mut config = quick_config();
    config.sim.max_speed_m_per_s = 1e-9;
    config.retry.max_frame_retries = 1;
    let result = simulate(&betas(0.0), None, &config).and_then(|s| s.write(&out));
    match result {
        Err(Error::SequenceFailed {
            frame,
            attempts,
            reason: SequenceFailure::Step(StepFailure::EnergyBlowUp { .. }),
            ..
        }) => {
            assert_eq!(frame, 0);
            assert_eq!(attempts, 2);
        }
        other => panic!("expected a failed sequence, got {other:?}"),
    }
    assert!(!out.exists(), "a failed sequence must not be written");
    // A NaN shape is refused before simulating.
    let e = simulate(&betas(f64::NAN), None, &quick_config()).expect_err("NaN β");
    assert!(e.to_string().contains("NaN"), "{e}");
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_frame_that_fails_is_redone_with_more_substeps() {
    // Conjugate gradients capped at a few iterations converge on the smaller steps of a retry
    // (the system M + h²K is better conditioned) but not on the configured ones.
    let mut config = quick_config();
    config.blend_frames = 2;
    config.rest_frames = 0;
    config.preview.every_n_frames = 0;
    config.sim.linear_solver = LinearSolver::ConjugateGradient {
        max_iterations: 12,
        relative_tolerance: 1e-4,
        fallback_to_cholesky: false,
    };
    let seq = simulate(&betas(2.0), None, &config).expect("simulates after retries");
    let s = &seq.header.substeps;
    assert!(s.retried_frames > 0 && s.failed_attempts > 0, "{s:?}");
    assert!(s.max > s.base && s.min == s.base || s.min > s.base, "{s:?}");
    assert!(
        seq.frames
            .iter()
            .any(|f| f.substeps > config.substeps_per_frame)
    );
    assert_eq!(
        s.total,
        seq.frames.iter().map(|f| f.substeps).sum::<usize>()
    );
}

#[test]
fn the_relaxed_template_is_at_rest_on_the_template_body() {
    // The committed template was relaxed on the body: simulating it there again (β = 0, rest
    // pose) leaves it where it is, and relaxing it again stops after the minimum frames.
    let garment = tshirt();
    let seq = simulate(&betas(0.0), None, &quick_config()).expect("simulates");
    let last = seq.last_frame().expect("frames").positions_vec3();
    let moved = last
        .iter()
        .zip(garment.positions())
        .map(|(a, b)| (a.cast::<f64>() - b).norm())
        .fold(0.0, f64::max);
    assert!(moved < 2e-3, "moved {:.2} mm", moved * 1e3);

    let config = RelaxConfig {
        min_frames: 3,
        max_frames: 30,
        ..RelaxConfig::default()
    };
    let (relaxed, report) =
        relax_on_body(&garment, body(), &Material::gray_interlock(), &config).expect("relaxes");
    assert!(report.frames < 30, "{report:?}");
    assert_eq!(report.vertices_inside, 0);
    assert_eq!(report.self_intersecting_pairs, 0);
    assert!(report.min_signed_distance_mm > 0.0, "{report:?}");
    assert!(report.max_displacement_mm < 2.0, "{report:?}");
    assert_eq!(
        relaxed.rest_dm(),
        garment.rest_dm(),
        "the rest metric is kept"
    );
    // Too few frames to come to rest is an error that says so.
    let impatient = RelaxConfig {
        min_frames: 1,
        max_frames: 1,
        max_speed_m_per_s: 1e-12,
        ..RelaxConfig::default()
    };
    let e = relax_on_body(&garment, body(), &Material::gray_interlock(), &impatient)
        .expect_err("not at rest");
    assert!(e.to_string().contains("did not come to rest"), "{e}");
}

#[test]
fn a_cloth_from_a_garment_keeps_its_rest_metric() {
    use sartor_cloth::Cloth;
    let garment = tshirt();
    let cloth = Cloth::from_garment(&garment, Material::gray_interlock()).expect("cloth");
    assert_eq!(cloth.rest_mesh().positions(), garment.positions());
    for (m, (dm, area)) in cloth
        .membranes()
        .iter()
        .zip(garment.rest_dm().iter().zip(garment.rest_area_m2()))
    {
        assert!((m.inv_dm * dm - nalgebra::Matrix2::identity()).norm() < 1e-9);
        assert_eq!(m.area_m2, *area);
    }
    // A garment whose template is its rest shape gives the same cloth as `Cloth::new`.
    let unrelaxed = Garment::from_surface(
        garment.name(),
        garment.mesh(),
        garment.frame_u(),
        garment.provenance().clone(),
    )
    .expect("garment");
    let a = Cloth::from_garment(&unrelaxed, Material::gray_interlock()).expect("cloth");
    let b = Cloth::new(
        unrelaxed.mesh().clone(),
        Material::gray_interlock(),
        Some(unrelaxed.frame_u()),
    )
    .expect("cloth");
    for (ha, hb) in a.hinges().iter().zip(b.hinges()) {
        assert_eq!(ha.vertices, hb.vertices);
        assert!((ha.rest_angle_rad - hb.rest_angle_rad).abs() < 1e-6);
        for k in 0..2 {
            let d = (ha.edge_angle_rad[k] - hb.edge_angle_rad[k]).rem_euclid(std::f64::consts::TAU);
            assert!(d.min(std::f64::consts::TAU - d) < 1e-5, "{ha:?} {hb:?}");
        }
    }
    for (ma, mb) in a.masses_kg().iter().zip(b.masses_kg()) {
        assert!((ma - mb).abs() < 1e-6 * mb);
    }
}

/// A few frames with the left arm swung down and into the torso: of the two directions about
/// the forward axis, the one that takes the forearm through the belly.
fn arm_through_torso() -> Motion {
    use nalgebra::UnitQuaternion;
    use sartor_core::Pose;
    let skeleton = body().skeleton();
    let arm = skeleton.index_of("LeftArm").expect("LeftArm");
    let clearance = sartor_motion::ArmClearance::new(body()).expect("arms and torso");
    let frames = |angle: f64| -> Vec<Pose> {
        (0..4)
            .map(|k| {
                let mut p = Pose::rest(skeleton.n_joints());
                p.local_rotations[arm] = UnitQuaternion::from_scaled_axis(
                    Vector3::z() * angle * (0.9 + 0.05 * k as f64),
                );
                p
            })
            .collect()
    };
    let through = [1.4, -1.4]
        .into_iter()
        .map(frames)
        .find(|f| {
            let depths = clearance
                .depths(body(), &[0.0], f, &ClearanceOptions::default())
                .expect("depths");
            depths.iter().all(|&d| d > 0.02)
        })
        .expect("one direction takes the forearm 2 cm into the torso");
    Motion::new(
        "arm-through-torso".into(),
        sartor_core::FPS,
        skeleton.names().to_vec(),
        through,
    )
    .expect("motion")
}

#[test]
fn arm_clearance_simulates_the_corrected_poses_and_stores_them() {
    let motion = arm_through_torso();
    let arm = body().skeleton().index_of("LeftArm").expect("LeftArm");
    let clearance = sartor_motion::ArmClearance::new(body()).expect("arms and torso");
    let mut config = quick_config();
    config.arm_clearance = Some(sartor_motion::ClearanceOptions::default());
    let seq = simulate(&betas(0.0), Some(&motion), &config).expect("simulates");
    let stored: Vec<_> = seq
        .frames
        .iter()
        .filter(|f| f.phase == Phase::Motion)
        .map(|f| f.pose.clone())
        .collect();
    assert_eq!(stored.len(), motion.n_frames());
    for (got, was) in stored.iter().zip(motion.frames()) {
        assert!(got.local_rotations[arm].angle_to(&was.local_rotations[arm]) > 0.05);
        for j in (0..got.local_rotations.len()).filter(|&j| j != arm) {
            assert_eq!(got.local_rotations[j], was.local_rotations[j]);
        }
    }
    let depths = clearance
        .depths(body(), &betas(0.0), &stored, &ClearanceOptions::default())
        .expect("depths");
    assert!(depths.iter().all(|&d| d == 0.0), "{depths:?}");
    // The header keeps the motion's own identity and the option.
    assert_eq!(
        seq.header.motion.as_ref().map(|m| m.name.as_str()),
        Some("arm-through-torso")
    );
    assert!(seq.header.drive_config.arm_clearance.is_some());
}

#[test]
fn cloth_left_behind_by_a_jump_in_the_motion_fails_the_sequence() {
    // Two frames at the origin, then the body 2 m to the side: the jump a blank frame after a
    // BVH file's T-pose once made (cmu/07_12). The cloth cannot follow within the frame, and
    // with nothing inside the body the other checks pass (the sequence simulates without this
    // check).
    use sartor_core::Pose;
    let skeleton = body().skeleton();
    let frames: Vec<Pose> = (0..5)
        .map(|k| {
            let mut p = Pose::rest(skeleton.n_joints());
            if k >= 2 {
                p.root_translation_m.x += 2.0;
            }
            p
        })
        .collect();
    let motion = Motion::new(
        "jump".into(),
        sartor_core::FPS,
        skeleton.names().to_vec(),
        frames,
    )
    .expect("motion");
    let mut config = quick_config();
    config.retry.max_frame_retries = 0;
    match simulate(&betas(0.0), Some(&motion), &config) {
        Err(Error::SequenceFailed {
            frame,
            reason: SequenceFailure::LeftBody { offset_mm, .. },
            ..
        }) => {
            // The jump is at the third motion frame, after the blend and rest frames.
            assert_eq!(frame, config.blend_frames + config.rest_frames + 2);
            assert!(offset_mm > sartor_cloth::LEFT_BODY_M * 1e3, "{offset_mm}");
        }
        other => panic!("expected the cloth to be left behind, got {other:?}"),
    }
    // The same body without the jump simulates.
    let still = Motion::new(
        "still".into(),
        sartor_core::FPS,
        skeleton.names().to_vec(),
        vec![Pose::rest(skeleton.n_joints()); 5],
    )
    .expect("motion");
    simulate(&betas(0.0), Some(&still), &config).expect("no jump, no failure");
}

#[test]
fn the_shipped_tshirts_get_their_stable_substeps_and_start_unfolded() {
    let config = DriveConfig {
        max_step_per_edge_s_per_m: Some(STABLE_STEP_PER_EDGE_S_PER_M),
        ..DriveConfig::default()
    };
    for (name, substeps) in [("tshirt-4210", 28), ("tshirt-8710", 40)] {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../datasets/garments")
            .join(name);
        let garment = Garment::load(&dir).expect(name);
        let cloth = Cloth::from_garment(&garment, Material::gray_interlock()).expect("cloth");
        let edge = cloth.median_rest_edge_m();
        // Independently: the median over every face's three edges (interior ones twice).
        let p = garment.positions();
        let mut all: Vec<f64> = garment
            .faces()
            .iter()
            .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
            .map(|(a, b)| (p[a as usize] - p[b as usize]).norm())
            .collect();
        all.sort_by(f64::total_cmp);
        let twice = all[all.len() / 2];
        assert!(
            (edge - twice).abs() < 0.03 * twice,
            "{name}: {edge} vs {twice}"
        );
        assert_eq!(
            config.substeps_for_edge(edge, sartor_core::FPS),
            substeps,
            "{name}"
        );
        let positions: Vec<[f32; 3]> = p.iter().map(|v| v.cast::<f32>().into()).collect();
        let folded = folded_hinge_percent(&positions, garment.faces());
        assert!(folded < 0.2, "{name}: {folded} % of hinges folded at rest");
    }
}

/// The deepest any cloth vertex of `seq` goes into the whole body, posed from each frame's
/// stored β and pose, m (0 when none is inside).
fn deepest_inside(seq: &ClothSequence) -> f64 {
    let mut deepest: f64 = 0.0;
    for frame in &seq.frames {
        let posed = body()
            .posed_vertices(&frame.betas, &frame.pose)
            .expect("pose");
        let whole = MeshProximity::new(&posed, body().faces()).expect("body");
        for p in frame.positions_vec3() {
            deepest = deepest.max(-whole.closest(&p.cast()).signed_distance_m);
        }
    }
    deepest
}

#[test]
fn both_friction_models_follow_real_motion_capture_at_their_stable_steps() {
    // The CMU crouch (`cmu/02_04`, imported, retargeted onto the body at load) from its
    // start, where the body goes down fastest, with the reference configs' arm clearance.
    let options = MotionSourceOptions {
        motions_dir: Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/motions"),
        body: Some(
            RetargetBody::load(&crate::common::builtin_model_dir()).expect("the built-in body"),
        ),
        ..MotionSourceOptions::default()
    };
    let motion = load_motion("cmu/02_04@0+12", &options).expect("cmu/02_04");
    for model in [FrictionModel::Impulse, FrictionModel::Implicit] {
        let mut config = quick_config();
        config.arm_clearance = Some(ClearanceOptions {
            upper_arm_clearance_m: Some(0.005),
            ..ClearanceOptions::default()
        });
        config.sim.friction_model = model;
        config.max_step_per_edge_s_per_m = Some(config.stable_step_per_edge_s_per_m());
        if model == FrictionModel::Implicit {
            config.substeps_per_frame = IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME;
        }
        let seq = simulate(&betas(0.5), Some(&motion), &config).expect("simulates");
        let h = &seq.header;
        let last = &seq.frames.last().expect("frames").positions;
        let folded = folded_hinge_percent(last, tshirt().faces());
        let deepest = deepest_inside(&seq);
        eprintln!(
            "{model:?}: {} substeps per frame, {} frames retried, {:.2} mm deepest, {folded:.2} % \
             of hinges folded, {} vertex-substeps through the fallback",
            h.substeps.base,
            h.substeps.retried_frames,
            deepest * 1e3,
            h.solver.projected_vertices
        );
        assert!(
            deepest <= config.penetration_tolerance_m + 1e-6,
            "{model:?}: {:.3} mm inside",
            deepest * 1e3
        );
        assert_eq!(h.substeps.retried_frames, 0, "{model:?}: frames redone");
        assert!(folded < 3.0, "{model:?}: {folded} % of hinges folded");
    }
}

/// The largest and the mean distance a vertex moved between two frames, m.
fn moved_between(a: &[[f32; 3]], b: &[[f32; 3]]) -> (f64, f64) {
    let distances = a.iter().zip(b).map(|(p, q)| {
        let d: [f64; 3] = std::array::from_fn(|k| f64::from(q[k] - p[k]));
        Vector3::from(d).norm()
    });
    let (largest, sum) = distances.fold((0.0f64, 0.0), |(m, s), d| (m.max(d), s + d));
    (largest, sum / a.len() as f64)
}

#[test]
fn a_shirt_at_rest_is_held_by_friction() {
    // A shirt on a standing body, watched for 5 s after a second of settling. The impulse's
    // static friction holds every vertex within half the contact layer. ARCSim's damper cannot
    // hold a vertex against a force below the Coulomb limit (it creeps at `F_t Δt / m`, see
    // `contact.rs`): the shirt goes on settling, but ever more slowly, towards where the cloth's
    // own elasticity holds it, rather than sliding steadily.
    let settle = 30;
    let half = 75;
    // With friction: the config's coefficient (ARCSim's cloth–body 0.3).
    let mu = quick_config().sim.friction_coefficient;
    let moved = |model: FrictionModel, mu: f64| {
        let mut config = quick_config();
        config.rest_frames = settle + 2 * half + 1;
        config.preview.every_n_frames = 0;
        config.sim.friction_model = model;
        config.sim.friction_coefficient = mu;
        config.max_step_per_edge_s_per_m = Some(config.stable_step_per_edge_s_per_m());
        if model == FrictionModel::Implicit {
            config.substeps_per_frame = IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME;
        }
        let seq = simulate(&betas(0.0), None, &config).expect("simulates");
        let at = |k: usize| &seq.frames[config.blend_frames + settle + k].positions;
        let first = moved_between(at(0), at(half)).0;
        let second = moved_between(at(half), at(2 * half)).0;
        let (whole, mean) = moved_between(at(0), at(2 * half));
        eprintln!(
            "{model:?}, μ = {mu}: in {:.0} s at rest the shirt moved {:.3} mm at most ({:.3} \
             and {:.3} mm in each half), {:.3} mm on average",
            (2 * half) as f64 / 30.0,
            whole * 1e3,
            first * 1e3,
            second * 1e3,
            mean * 1e3
        );
        (whole, first, second, config.sim.contact_penalty.thickness_m)
    };
    let (impulse, _, _, thickness) = moved(FrictionModel::Impulse, mu);
    let (damper, first, second, _) = moved(FrictionModel::Implicit, mu);
    // The control, printed: without friction the shirt is held by its elasticity alone.
    moved(FrictionModel::Impulse, 0.0);
    assert!(
        impulse < 0.5 * thickness,
        "the impulse let a vertex move {:.2} mm at rest",
        impulse * 1e3
    );
    assert!(
        second < first,
        "with the damper the shirt moved {:.2} mm in the second half, {:.2} in the first \
         ({:.2} in all)",
        second * 1e3,
        first * 1e3,
        damper * 1e3
    );
}

#[test]
fn folded_hinges_are_counted_beyond_a_right_angle_only() {
    // Two triangles on the edge (0, 1), the second turned about it by `angle`.
    let pair = |angle: f64| -> Vec<[f32; 3]> {
        let (s, c) = angle.sin_cos();
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.5, 1.0, 0.0],
            [0.5, -c as f32, s as f32],
        ]
    };
    let faces = [[0u32, 1, 2], [1, 0, 3]];
    assert_eq!(folded_hinge_percent(&pair(0.0), &faces), 0.0);
    assert_eq!(folded_hinge_percent(&pair(80f64.to_radians()), &faces), 0.0);
    assert_eq!(
        folded_hinge_percent(&pair(100f64.to_radians()), &faces),
        100.0
    );
    assert_eq!(
        folded_hinge_percent(&pair(179f64.to_radians()), &faces),
        100.0
    );
    // A lone triangle has no interior edge.
    assert_eq!(folded_hinge_percent(&pair(0.0), &faces[..1]), 0.0);
}
