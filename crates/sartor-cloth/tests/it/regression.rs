//! The simulator's regression pins: a short simulation (the committed 500-triangle T-shirt on
//! the built-in body, β₀ = 0.5, 3 blend + 2 rest frames and 4 frames of a fast clip) against its
//! result stored in `tests/data/regression-sim.json`, and the same with
//! [`FrictionModel::Implicit`] in `tests/data/regression-sim-implicit-friction.json`.
//!
//! What the pin depends on: the garment, the body, the material, the drive settings and the
//! simulator's equations. It is independent of the thread count: the same run on the calling
//! thread and on rayon's pool must give bitwise equal frames (deterministic reductions
//! everywhere). It does depend on the platform's `atan2`/`acos` (libm) in their last bits, which
//! is why the comparison is a tolerance and not a hash (the file also records the SHA-256 of the
//! frames, printed on a mismatch to tell "round-off" from "other physics").
//!
//! The linear solves run to a relative residual of 1e-10, not the 1e-5 of
//! `configs/default.json`, so that the pin holds the equations and not one way of solving them
//! approximately: at 1e-5, starting CG from another guess moved vertices by 11 µm after the
//! first frame and by 2.1 mm after the fast frames (measured when the extrapolated start went
//! in), a difference the solver's tolerance allows. At 1e-10 the same change moved no vertex by
//! more than 0.06 µm, about one f32 step of the stored positions.
//!
//! Tolerance: [`TOLERANCE_M`], 2 µm on any vertex in any frame; a change of the equations (a
//! stiffness, a contact rule) moves them by far more.
//!
//! To re-pin after a deliberate change of the physics: `SARTOR_BLESS=1 cargo test -p
//! sartor-cloth --test it regression` rewrites the file; say why in the commit.

use std::path::{Path, PathBuf};

use sartor_cloth::{
    ClothSequence, DriveConfig, FrictionModel, Garment, LinearSolver, Material, simulate_sequence,
};
use sartor_core::Parallelism;
use sartor_core::io::sha256_hex;
use sartor_motion::Motion;
use serde::{Deserialize, Serialize};

/// Largest allowed distance of any vertex in any frame from the pinned result, m.
const TOLERANCE_M: f64 = 2e-6;

#[derive(Serialize, Deserialize)]
struct Pinned {
    /// What was simulated (for the reader).
    description: String,
    /// SHA-256 of every frame's f32 positions (little-endian), in order.
    sha256: String,
    /// Per frame, every vertex (f32 values as stored in the sequence).
    frames: Vec<Vec<[f32; 3]>>,
}

/// The fixture of a friction model.
fn fixture(friction: FrictionModel) -> PathBuf {
    let name = match friction {
        FrictionModel::Impulse => "regression-sim.json",
        FrictionModel::Implicit => "regression-sim-implicit-friction.json",
    };
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn config(parallelism: Parallelism, friction: FrictionModel) -> DriveConfig {
    let mut c = DriveConfig {
        blend_frames: 3,
        rest_frames: 2,
        ..DriveConfig::default()
    };
    c.preview.every_n_frames = 0;
    c.sim.linear_solver = LinearSolver::ConjugateGradient {
        max_iterations: 1000,
        relative_tolerance: 1e-10,
        fallback_to_cholesky: true,
    };
    c.sim.parallelism = parallelism;
    c.sim.friction_model = friction;
    c
}

fn simulate(parallelism: Parallelism, friction: FrictionModel) -> ClothSequence {
    let body = crate::common::load_builtin().expect("the built-in body");
    let garment = Garment::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/garments/tshirt-tiny"),
    )
    .expect("datasets/garments/tshirt-tiny");
    let motion: Motion = sartor_motion::procedural::clip("arm_circles_fast")
        .expect("procedural clip")
        .slice(40..44)
        .expect("frames");
    let mut betas = vec![0.0; body.n_betas()];
    betas[0] = 0.5;
    simulate_sequence(
        &body,
        &garment,
        &Material::gray_interlock(),
        &betas,
        Some(&motion),
        &config(parallelism, friction),
        &mut |_, _| {},
    )
    .expect("simulates")
}

fn frames(seq: &ClothSequence) -> Vec<Vec<[f32; 3]>> {
    seq.frames.iter().map(|f| f.positions.clone()).collect()
}

fn hash(frames: &[Vec<[f32; 3]>]) -> String {
    let bytes: Vec<u8> = frames
        .iter()
        .flatten()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    sha256_hex(&bytes)
}

#[test]
fn a_short_simulation_keeps_its_pinned_result_on_any_thread_count() {
    keeps_its_pinned_result(FrictionModel::Impulse);
}

#[test]
fn with_implicit_friction_a_short_simulation_keeps_its_pinned_result() {
    keeps_its_pinned_result(FrictionModel::Implicit);
}

fn keeps_its_pinned_result(friction: FrictionModel) {
    let seq = frames(&simulate(Parallelism::Sequential, friction));
    let par = frames(&simulate(Parallelism::Rayon, friction));
    assert!(
        seq == par,
        "the calling thread and rayon's pool give different frames"
    );
    if std::env::var_os("SARTOR_BLESS").is_some() {
        let pinned = Pinned {
            description: format!(
                "tshirt-tiny on the built-in body, β0 = 0.5, 3 blend + 2 rest frames, \
                 arm_circles_fast frames 40..44, CG 1e-10, friction {friction:?} \
                 (tests/it/regression.rs)"
            ),
            sha256: hash(&seq),
            frames: seq,
        };
        let mut json = serde_json::to_string(&pinned).expect("json");
        json.push('\n');
        let path = fixture(friction);
        std::fs::create_dir_all(path.parent().expect("tests/data")).expect("folder");
        std::fs::write(path, json).expect("write the fixture");
        return;
    }
    let pinned: Pinned = serde_json::from_slice(
        &std::fs::read(fixture(friction))
            .expect("the fixture in tests/data (SARTOR_BLESS=1 writes it)"),
    )
    .expect("a valid fixture");
    assert_eq!(pinned.frames.len(), seq.len(), "frame count");
    let mut worst = (0.0f64, 0, 0);
    for (f, (a, b)) in seq.iter().zip(&pinned.frames).enumerate() {
        assert_eq!(a.len(), b.len(), "vertex count");
        for (v, (p, q)) in a.iter().zip(b).enumerate() {
            let d = (0..3)
                .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
                .sum::<f64>()
                .sqrt();
            if d > worst.0 {
                worst = (d, f, v);
            }
        }
    }
    let same_bits = hash(&seq) == pinned.sha256;
    println!(
        "largest difference from the pinned result: {:.3} µm (frame {}, vertex {}); bitwise \
         equal: {same_bits}",
        worst.0 * 1e6,
        worst.1,
        worst.2
    );
    assert!(
        worst.0 <= TOLERANCE_M,
        "vertex {} of frame {} is {:.1} µm from the pinned result (tolerance {:.0} µm; bitwise \
         equal: {same_bits})",
        worst.2,
        worst.1,
        worst.0 * 1e6,
        TOLERANCE_M * 1e6
    );
}
