//! Driving the simulator with a moving body: the paper's protocol for one (shape, motion)
//! sequence.
//!
//! # Protocol
//!
//! The cloth starts from the garment template at rest, on the body in its rest state (β = 0,
//! rest pose: the state the template was relaxed in). Then, one frame at a time:
//!
//! 1. **Blend** (N = [`DriveConfig::blend_frames`] frames): shape and pose go from the rest
//!    state to (β, the motion's first pose), eased (cubic smoothstep, as
//!    [`sartor_motion::Motion::blended_from_rest`]).
//! 2. **Rest** (M = [`DriveConfig::rest_frames`] frames): the first pose is held while the cloth
//!    settles.
//! 3. **Motion**: one frame per motion frame (its first frame is the held pose).
//!
//! Without a motion (the rest-pose simulation of the garment fit Δ_G) only β is blended, in the
//! rest pose; the last frame is `S_c(β, 0)`.
//!
//! If the motion's first frame is away from the origin, the rest state is moved rigidly to its
//! root position and heading (cloth included), which changes nothing physically: gravity is
//! vertical and the simulation is invariant under such moves.
//!
//! # Body
//!
//! The posed body is computed once per frame with sartor-core's skinning and linearly
//! interpolated for every substep: the collider's tree is fitted at the frame's two poses
//! ([`MeshCollider::set_span`]) and its boxes interpolated at each substep
//! ([`MeshCollider::move_on_span`]; the same answers as a refit), its velocities (for
//! friction) are the interpolation's.
//!
//! Only the body region near the garment takes part ([`RegionConfig`]): the garment template is
//! carried along with the body — shaped by the shape displacement of its closest body point and
//! skinned with skin weights transferred from the body ([`sartor_core::transfer_skin_weights`])
//! — through every frame, and body triangles with a vertex within [`RegionConfig::margin_m`] of
//! it in any frame ([`sartor_core::faces_near`]) are kept. After every frame the cloth is
//! checked against the excluded triangles: a vertex within the contact thickness of one means
//! the region was too small, and the sequence restarts with a doubled margin.
//!
//! # Failures
//!
//! A frame fails on a [`StepFailure`](crate::StepFailure) (NaN, energy blow-up, solver
//! non-convergence) or when a cloth vertex ends it more than
//! [`DriveConfig::penetration_tolerance_m`] inside the body region, or the garment has moved
//! more than [`LEFT_BODY_M`] away from the body (left behind by a jump in the motion). The frame is then redone from its start with
//! [`RetryConfig::substep_factor`] times more substeps, up to
//! [`RetryConfig::max_frame_retries`] times; the following frames go back to the configured
//! substeps. A frame that still fails fails the sequence
//! ([`Error::SequenceFailed`]); nothing is written.
//!
//! # Determinism
//!
//! With [`SimConfig::parallelism`] = [`Parallelism::Sequential`] (the default; callers
//! parallelise across sequences) the same inputs give bit-identical outputs, retries included:
//! a retry restarts from the saved state of the frame and depends on nothing else.

use std::time::Instant;

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::io::sha256_hex;
use sartor_core::{
    BodyDistance, BodyModel, BodyPoser, MeshProximity, Parallelism, Pose, SurfaceAnchors,
    compact_faces, faces_near, interpolate_pose, skin_points, split_heading,
    transfer_skin_weights_on,
};
use sartor_motion::{ArmClearance, ClearanceOptions, Motion};
use serde::{Deserialize, Serialize};

use crate::cloth::Cloth;
use crate::collider::Collider;
use crate::error::SequenceFailure;
use crate::garment::Garment;
use crate::material::Material;
use crate::mesh_collider::MeshCollider;
use crate::sequence::{
    BodyId, ClothSequence, GarmentId, MotionId, Phase, PreviewFrame, RegionStats, SEQUENCE_FORMAT,
    SequenceFrame, SequenceHeader, SequencePreview, SequenceTiming, SolverTotals, SubstepStats,
};
use crate::solver::{SimConfig, Simulator};
use crate::{Error, Result};

/// Which body triangles take part in contact.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RegionConfig {
    /// Use every body triangle (no selection). Default `false`: a T-shirt does not need the
    /// legs, and fewer triangles make every contact query and refit cheaper.
    pub whole_body: bool,
    /// Keep body triangles with a vertex within this distance of the garment carried along with
    /// the body in any frame, m. Default 0.1 m: the cloth hangs up to a few centimetres off its
    /// skinned template (folds, a flaring hem or sleeve) and limbs move between frames; the
    /// excluded-region check after every frame catches a margin that is too small.
    pub margin_m: f64,
    /// How deep inside the body a cloth vertex is still found by contacts, the projection
    /// fallback and the penetration check, m ([`MeshCollider::new`]). Default 0.05 m: deeper
    /// than any penetration a substep can make, shallower than the half-thickness of the torso.
    pub search_depth_m: f64,
    /// After every frame, fail the frame if a cloth vertex is within the contact thickness of an
    /// excluded body triangle (the sequence then restarts with a doubled margin). Default
    /// `true`.
    pub check_excluded: bool,
}

impl Default for RegionConfig {
    fn default() -> Self {
        Self {
            whole_body: false,
            margin_m: 0.1,
            search_depth_m: 0.05,
            check_excluded: true,
        }
    }
}

/// What to do when a frame fails.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RetryConfig {
    /// Times a failed frame is redone, each time with `substep_factor` times more substeps.
    /// Default 3 (up to 8 × the substeps: 80 per frame, a 0.42 ms step at 30 fps).
    pub max_frame_retries: usize,
    /// Substep multiplier per retry. Default 2.
    pub substep_factor: usize,
    /// Restarts of the whole sequence with a doubled region margin when the cloth reaches an
    /// excluded body triangle. Default 2.
    pub max_region_restarts: usize,
}

impl Default for RetryConfig {
    fn default() -> Self {
        Self {
            max_frame_retries: 3,
            substep_factor: 2,
            max_region_restarts: 2,
        }
    }
}

/// The Foxglove preview written with each sequence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PreviewConfig {
    /// Write the cloth and the body region every this many frames (0: no preview). Default 10:
    /// 3 previews per second at 30 fps, enough to see the motion, about a tenth of the file.
    pub every_n_frames: usize,
}

impl Default for PreviewConfig {
    fn default() -> Self {
        Self { every_n_frames: 10 }
    }
}

/// Settings of [`simulate_sequence`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DriveConfig {
    /// Substeps per frame. Default 10: a 3.33 ms step at 30 fps, the paper's.
    pub substeps_per_frame: usize,
    /// N, frames over which shape and pose blend from the rest state. Default 30 (1 s): slow
    /// enough that the cloth follows a body growing by several centimetres without being
    /// thrown.
    pub blend_frames: usize,
    /// M, frames the first pose is held before the motion. Default 30 (1 s): the cloth loses
    /// the blend's motion (friction, the integrator's damping) before the motion starts.
    pub rest_frames: usize,
    /// After every frame no cloth vertex may be deeper inside the body region than this, m.
    /// Default 1 mm (the issue's guarantee); at least [`SimConfig::max_penetration_m`].
    pub penetration_tolerance_m: f64,
    /// The body region that takes part.
    pub region: RegionConfig,
    /// Retries.
    pub retry: RetryConfig,
    /// The preview.
    pub preview: PreviewConfig,
    /// The simulator (defaults: ARCSim's body scenes).
    pub sim: SimConfig,
    /// Keep the forearms and hands out of the torso of the simulated shape
    /// ([`ArmClearance`]): the motion's poses are corrected before the simulation and the
    /// sequence holds the corrected ones. Default `None` (the motion as given; a sequence
    /// written without this field reads as `None`, its hash unchanged). Retargeted motion
    /// capture needs it: a forearm through the hips leaves cloth caught there no position
    /// outside the body.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub arm_clearance: Option<ClearanceOptions>,
    /// Raise the substeps per frame until the step is at most this many seconds per metre of
    /// the cloth's median rest edge ([`DriveConfig::substeps_for_edge`]);
    /// [`STABLE_STEP_PER_EDGE_S_PER_M`] is the value measured to keep the T-shirt smooth. The
    /// one linearised implicit step per substep is stable only for steps short against the
    /// triangle size: at 10 substeps per frame the 8,710- and 26,066-triangle T-shirts crumple
    /// within a second of the walk, and in a crouch the 4,210-triangle one does too. Default `None` (exactly
    /// `substeps_per_frame`; a config written without this field reads as `None`, its hash
    /// unchanged).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_step_per_edge_s_per_m: Option<f64>,
}

/// The step, seconds per metre of median rest edge, at which the T-shirt stays smooth with one
/// Newton iteration per substep: measured on the 4,210- and 8,710-triangle T-shirts (median
/// edges 18.3 and 12.8 mm) by rendering them and counting their hinges folded beyond 90°
/// (`bench sim --pictures`), on the walk and on a CMU crouch (`cmu/02_04`, 60 frames after
/// 30 blend and 30 rest frames). At 10 substeps (0.18 and 0.26 s/m) the walk already crumples
/// the 8,710-triangle shirt (and the 26,066 one, 0.45 s/m); at 0.135 the walk stays smooth but
/// the crouch crumples both shirts and pushes them up the back (14.5 and 9.7 % of hinges
/// folded); at 0.066, 28 and 40 substeps, both stay smooth (1.7 and 1.2 %), as 30 and 40
/// substeps did at 8,710 triangles. 0.066 gives 28, 40 and 69 substeps per frame at 30 fps at
/// 4,210, 8,710 and 26,066 triangles.
pub const STABLE_STEP_PER_EDGE_S_PER_M: f64 = 0.066;

/// [`STABLE_STEP_PER_EDGE_S_PER_M`] for [`FrictionModel::Implicit`](crate::FrictionModel),
/// measured the same way. The crumpling at long steps came from the friction impulse, which
/// the rest of the cloth does not see within the step (at 14 substeps per frame the crouch
/// folded 7.1 % of the 4,210-triangle T-shirt's hinges with it, 1.0 % without friction, 0.9 %
/// with the damper in the solve). With the damper, 0.135 s/m (20 and 34 substeps per frame at
/// 8,710 and 26,066 triangles) keeps the walk and the crouch as smooth as 0.066 did with the
/// impulse; at 4,210 triangles the edge rule alone gives 14, where the crouch pushed 904
/// vertex-substeps through the fallback: [`IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME`] sets the
/// fewest.
pub const IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M: f64 = 0.135;

/// The fewest substeps per frame at 30 fps that go with [`IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M`]
/// (a step of 1.7 ms): in the crouch the body's surface moves up to ~1.5 m/s, 2.5 mm per
/// substep, half the repulsion thickness; at 14 substeps the fallback moved 0.08 % of the
/// 4,210-triangle shirt's vertex-substeps, at 20 (21 by the edge rule) 0.003 %.
pub const IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME: usize = 20;

impl Default for DriveConfig {
    fn default() -> Self {
        Self {
            substeps_per_frame: 10,
            blend_frames: 30,
            rest_frames: 30,
            penetration_tolerance_m: 1e-3,
            region: RegionConfig::default(),
            retry: RetryConfig::default(),
            preview: PreviewConfig::default(),
            sim: SimConfig::default(),
            arm_clearance: None,
            max_step_per_edge_s_per_m: None,
        }
    }
}

/// Most substeps a frame may take (retries included).
const MAX_SUBSTEPS_PER_FRAME: usize = 10_000;

impl DriveConfig {
    /// Check the settings.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid("drive config", m));
        self.sim.validate()?;
        if let Some(c) = &self.arm_clearance {
            c.validate()?;
        }
        if self.substeps_per_frame == 0 {
            return bad("substeps_per_frame must be at least 1".into());
        }
        if let Some(k) = self.max_step_per_edge_s_per_m
            && !(k.is_finite() && k > 0.0)
        {
            return bad(format!(
                "max_step_per_edge_s_per_m must be finite and > 0, got {k}"
            ));
        }
        if self.retry.max_frame_retries > 0 && self.retry.substep_factor < 2 {
            return bad("retry.substep_factor must be at least 2".into());
        }
        let most = (0..self.retry.max_frame_retries).try_fold(self.substeps_per_frame, |n, _| {
            n.checked_mul(self.retry.substep_factor)
        });
        if most.is_none_or(|n| n > MAX_SUBSTEPS_PER_FRAME) {
            return bad(format!(
                "{} substeps × {}^{} retries exceeds {MAX_SUBSTEPS_PER_FRAME} per frame",
                self.substeps_per_frame, self.retry.substep_factor, self.retry.max_frame_retries
            ));
        }
        if !(self.penetration_tolerance_m.is_finite()
            && self.penetration_tolerance_m >= self.sim.max_penetration_m)
        {
            return bad(format!(
                "penetration_tolerance_m {} must be finite and ≥ sim.max_penetration_m {}",
                self.penetration_tolerance_m, self.sim.max_penetration_m
            ));
        }
        for (name, value) in [
            ("region.margin_m", self.region.margin_m),
            ("region.search_depth_m", self.region.search_depth_m),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return bad(format!("{name} must be finite and ≥ 0, got {value}"));
            }
        }
        Ok(())
    }

    /// Substeps per frame for a cloth of median rest edge `median_edge_m` at `fps` frames per
    /// second: `substeps_per_frame`, raised by [`DriveConfig::max_step_per_edge_s_per_m`]
    /// when set (never past what the retries leave of [`MAX_SUBSTEPS_PER_FRAME`]).
    pub fn substeps_for_edge(&self, median_edge_m: f64, fps: f64) -> usize {
        let Some(k) = self.max_step_per_edge_s_per_m else {
            return self.substeps_per_frame;
        };
        let longest_step = k * median_edge_m;
        if !(longest_step > 0.0 && fps > 0.0) {
            return self.substeps_per_frame;
        }
        let factor = self
            .retry
            .substep_factor
            .max(1)
            .saturating_pow(self.retry.max_frame_retries as u32);
        let cap = (MAX_SUBSTEPS_PER_FRAME / factor).max(self.substeps_per_frame);
        let needed = (1.0 / (fps * longest_step)).ceil();
        if needed >= cap as f64 {
            return cap;
        }
        (needed as usize).clamp(self.substeps_per_frame, cap)
    }

    /// The longest step per metre of median rest edge measured to keep the T-shirt smooth
    /// with this config's friction model: [`STABLE_STEP_PER_EDGE_S_PER_M`] with the impulse,
    /// [`IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M`] with the damper in the solve.
    pub fn stable_step_per_edge_s_per_m(&self) -> f64 {
        match self.sim.friction_model {
            crate::FrictionModel::Impulse => STABLE_STEP_PER_EDGE_S_PER_M,
            crate::FrictionModel::Implicit => IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M,
        }
    }

    /// The step [`DriveConfig::substeps_for_edge`] gives, in seconds per metre of the median
    /// rest edge: above [`DriveConfig::stable_step_per_edge_s_per_m`] the cloth may crumple.
    pub fn step_per_edge_s_per_m(&self, median_edge_m: f64, fps: f64) -> f64 {
        1.0 / (fps * self.substeps_for_edge(median_edge_m, fps) as f64 * median_edge_m)
    }

    /// SHA-256 of the config's canonical JSON (serde's field order, no whitespace); stored in
    /// every sequence so outputs made with different settings are told apart.
    pub fn sha256(&self) -> Result<String> {
        let json =
            serde_json::to_vec(self).map_err(|e| Error::invalid("drive config", e.to_string()))?;
        Ok(sha256_hex(&json))
    }

    /// Parse and validate a config from JSON; `path` names the file in errors.
    pub fn from_json(bytes: &[u8], path: &std::path::Path) -> Result<Self> {
        let config: Self = serde_json::from_slice(bytes)
            .map_err(|e| Error::format(path, format!("line {}: {e}", e.line())))?;
        config
            .validate()
            .map_err(|e| Error::format(path, e.to_string()))?;
        Ok(config)
    }
}

/// The body state at the end of one frame.
#[derive(Clone, Debug)]
pub(crate) struct Keyframe {
    phase: Phase,
    motion_frame: Option<usize>,
    betas: Vec<f64>,
    pose: Pose,
}

/// `0` at 0, `1` at 1, cubic in between (C1), as `Motion::blended_from_rest`.
fn ease(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// The rest state the sequence starts from (β = 0, rest pose at the first pose's root position
/// and heading) and the body state at the end of every frame.
fn schedule(
    n_joints: usize,
    betas: &[f64],
    motion: Option<&Motion>,
    config: &DriveConfig,
) -> (Pose, Vec<Keyframe>) {
    let first = motion.map_or_else(|| Pose::rest(n_joints), |m| m.frames()[0].clone());
    let start = Pose {
        root_translation_m: first.root_translation_m,
        root_orientation: split_heading(&first.root_orientation).0,
        ..Pose::rest(n_joints)
    };
    let n = config.blend_frames;
    let mut keys = Vec::with_capacity(n + config.rest_frames + motion.map_or(0, Motion::n_frames));
    for k in 1..=n {
        let s = ease(k as f64 / n as f64);
        keys.push(Keyframe {
            phase: Phase::Blend,
            motion_frame: None,
            betas: betas.iter().map(|b| b * s).collect(),
            pose: interpolate_pose(&start, &first, s),
        });
    }
    for _ in 0..config.rest_frames {
        keys.push(Keyframe {
            phase: Phase::Rest,
            motion_frame: None,
            betas: betas.to_vec(),
            pose: first.clone(),
        });
    }
    for (j, pose) in motion.iter().flat_map(|m| m.frames()).enumerate() {
        keys.push(Keyframe {
            phase: Phase::Motion,
            motion_frame: Some(j),
            betas: betas.to_vec(),
            pose: pose.clone(),
        });
    }
    (start, keys)
}

/// The body region: which body triangles take part in contact.
pub(crate) struct Region {
    /// Per body triangle, whether it is kept.
    pub(crate) kept: Vec<bool>,
}

impl Region {
    /// Every triangle.
    pub(crate) fn whole(body: &BodyModel) -> Self {
        Self {
            kept: vec![true; body.faces().len()],
        }
    }

    /// The triangles near the garment carried along with the body through `keys` (and the
    /// start state `start`): the garment template is shaped by the shape displacement of its
    /// closest template-body point, skinned with transferred skin weights, and every body
    /// triangle with a vertex within `margin_m` of it in some frame is kept.
    pub(crate) fn near_garment(
        body: &BodyModel,
        garment: &Garment,
        start: &Pose,
        keys: &[Keyframe],
        margin_m: f64,
    ) -> Result<Self> {
        let template = body.template().positions();
        let proximity = body.template_proximity()?;
        let anchors = SurfaceAnchors::on(proximity, garment.positions().iter().copied());
        let weights =
            transfer_skin_weights_on(proximity, body.skin_weights(), garment.positions(), 0.0)?;
        let mut kept = vec![false; body.faces().len()];
        let mut poser = BodyPoser::new(body);
        let mut body_posed = vec![Vector3::zeros(); body.n_vertices()];
        let n_g = garment.positions().len();
        let (mut g_shaped, mut g_posed) =
            (vec![Vector3::zeros(); n_g], vec![Vector3::zeros(); n_g]);
        let zeros = vec![0.0; body.n_betas()];
        let states = std::iter::once((zeros.as_slice(), start))
            .chain(keys.iter().map(|k| (k.betas.as_slice(), &k.pose)));
        let mut previous: Option<(&[f64], &Pose)> = None;
        for (betas, pose) in states {
            // Held poses repeat: one look is enough.
            if previous == Some((betas, pose)) {
                continue;
            }
            previous = Some((betas, pose));
            poser.pose_into(betas, pose, &mut body_posed)?;
            let shaped = poser.shaped();
            let faces = body.faces();
            for (i, (g, p)) in g_shaped.iter_mut().zip(garment.positions()).enumerate() {
                *g = p + anchors.displacement(i, shaped, template);
            }
            skin_points(
                &g_shaped,
                &weights,
                poser.transforms(),
                &mut g_posed,
                Parallelism::Sequential,
            )?;
            for f in faces_near(&body_posed, faces, &g_posed, garment.faces(), margin_m)? {
                kept[f as usize] = true;
            }
        }
        Ok(Self { kept })
    }

    fn faces(&self, body: &BodyModel, kept: bool) -> Vec<[u32; 3]> {
        body.faces()
            .iter()
            .zip(&self.kept)
            .filter(|(_, k)| **k == kept)
            .map(|(t, _)| *t)
            .collect()
    }

    /// Number of triangles kept.
    pub(crate) fn n_kept(&self) -> usize {
        self.kept.iter().filter(|k| **k).count()
    }
}

/// Why a frame could not be simulated.
pub(crate) enum FrameError {
    /// A physical failure (retry with more substeps, or report).
    Failure(SequenceFailure),
    /// A programming or input error: stop.
    Hard(Error),
}

impl From<Error> for FrameError {
    fn from(e: Error) -> Self {
        match e {
            Error::Step(f) => Self::Failure(SequenceFailure::Step(f)),
            other => Self::Hard(other),
        }
    }
}

/// What the per-frame checks measured.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct FrameChecks {
    /// Deepest vertex inside the body region, m (0 if none).
    pub(crate) max_penetration_m: f64,
    /// Closest vertex to an excluded triangle, m (`INFINITY` when none is within the search
    /// radius or there is no check).
    pub(crate) min_excluded_distance_m: f64,
    /// Kinetic energy, J.
    pub(crate) kinetic_energy_j: f64,
    /// Largest vertex speed, m/s.
    pub(crate) max_speed_m_per_s: f64,
}

/// The cloth, the body collider and the per-frame machinery: advances one frame at a time with
/// retries. Shared by [`simulate_sequence`] and [`crate::relax_on_body`].
pub(crate) struct FrameStepper {
    pub(crate) sim: Simulator,
    /// The kept body triangles over their own vertices ([`compact_faces`]).
    collider: MeshCollider,
    /// Body vertex of each collider vertex.
    region_vertices: Vec<u32>,
    /// The collider's vertices at the frame's start and end, and at the current substep.
    region_prev: Vec<Vector3<f64>>,
    region_next: Vec<Vector3<f64>>,
    /// Excluded body triangles (for the check), if any.
    guard: Option<MeshProximity>,
    guard_radius_m: f64,
    tolerance_m: f64,
    fps: f64,
    base_substeps: usize,
    retry: RetryConfig,
    saved_x: Vec<Vector3<f64>>,
    saved_v: Vec<Vector3<f64>>,
    pub(crate) totals: SolverTotals,
    pub(crate) timing: SequenceTiming,
    pub(crate) substeps: SubstepStats,
    pub(crate) min_excluded_distance_m: f64,
    /// Per cloth vertex, the last closest face of the check's queries against the region and
    /// the excluded triangles (hints: work saved, answers unchanged).
    check_hints: Vec<u32>,
    guard_hints: Vec<u32>,
    /// Per cloth vertex, the answer of the check's current query (scratch).
    found: Vec<Option<f64>>,
    /// The whole body's triangles, and its signed distance ([`BodyDistance`], built on first
    /// need): the check confirms every vertex the region finds deeper than the tolerance with
    /// the one collision measure before it rejects a frame.
    body_faces: Vec<[u32; 3]>,
    body_distance: Option<BodyDistance>,
    deep: Vec<usize>,
    /// Distance between the cloth's centroid and the contact region's at the start, m.
    start_offset_m: f64,
}

/// How far the garment's centroid may move away from the body's contact region during a
/// sequence, beyond where it started, before the frame check says the cloth was left behind,
/// m. Cloth that follows the body stays within centimetres (the largest mean wrinkle
/// displacement of a CMU training sequence is 0.16 m); a body that jumps in the motion leaves
/// it metres away.
pub const LEFT_BODY_M: f64 = 0.5;

/// The distance between the centroids of two point sets, m.
fn centroid_distance(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    let centroid = |p: &[Vector3<f64>]| p.iter().sum::<Vector3<f64>>() / p.len().max(1) as f64;
    (centroid(a) - centroid(b)).norm()
}

impl FrameStepper {
    /// A stepper for `garment` on the body at `body_start` (all body vertices), in contact with
    /// the triangles `region` keeps; the cloth starts at `cloth_start`.
    pub(crate) fn new(
        body: &BodyModel,
        garment: &Garment,
        material: &Material,
        config: &DriveConfig,
        region: &Region,
        body_start: &[Vector3<f64>],
        cloth_start: &[Vector3<f64>],
        fps: f64,
    ) -> Result<Self> {
        let (region_vertices, region_faces) =
            compact_faces(&region.faces(body, true), body.n_vertices());
        let region_start: Vec<Vector3<f64>> = region_vertices
            .iter()
            .map(|&v| body_start[v as usize])
            .collect();
        let collider =
            MeshCollider::new(&region_start, &region_faces, config.region.search_depth_m)?;
        let excluded = region.faces(body, false);
        let guard = if config.region.check_excluded && !excluded.is_empty() {
            Some(MeshProximity::new(body_start, &excluded)?)
        } else {
            None
        };
        let mut sim = Simulator::new(
            Cloth::from_garment(garment, material.clone())?,
            config.sim.clone(),
        )?;
        sim.set_positions(cloth_start)?;
        let base_substeps = config.substeps_for_edge(sim.cloth().median_rest_edge_m(), fps);
        let n = cloth_start.len();
        let start_offset_m = centroid_distance(cloth_start, &region_start);
        Ok(Self {
            sim,
            collider,
            region_vertices,
            region_prev: region_start.clone(),
            region_next: region_start,
            guard,
            guard_radius_m: config.region.margin_m,
            tolerance_m: config.penetration_tolerance_m,
            fps,
            base_substeps,
            retry: config.retry.clone(),
            saved_x: vec![Vector3::zeros(); n],
            saved_v: vec![Vector3::zeros(); n],
            totals: SolverTotals::default(),
            timing: SequenceTiming::default(),
            substeps: SubstepStats {
                base: base_substeps,
                min: usize::MAX,
                max: 0,
                total: 0,
                retried_frames: 0,
                failed_attempts: 0,
                region_restarts: 0,
            },
            min_excluded_distance_m: f64::INFINITY,
            check_hints: vec![u32::MAX; n],
            guard_hints: vec![u32::MAX; n],
            found: vec![None; n],
            body_faces: body.faces().to_vec(),
            body_distance: None,
            deep: Vec::new(),
            start_offset_m,
        })
    }

    /// The contact thickness, m.
    fn thickness_m(&self) -> f64 {
        self.sim.config().contact_penalty.thickness_m
    }

    /// Simulate one frame while the body goes from `prev` to `next` (all body vertices);
    /// returns the substeps used and what the checks measured. On failure the frame is redone
    /// with more substeps; the last failure is returned with the attempts made.
    pub(crate) fn advance(
        &mut self,
        prev: &[Vector3<f64>],
        next: &[Vector3<f64>],
    ) -> std::result::Result<(usize, FrameChecks), (FrameError, usize)> {
        match self.sim.config().parallelism {
            Parallelism::Sequential => self.advance_here(prev, next),
            // One set of awake workers for all the frame's substeps (see `sartor_core::awake`).
            Parallelism::Rayon => {
                sartor_core::awake::with_workers_awake(|| self.advance_here(prev, next))
            }
        }
    }

    /// [`Self::advance`] on the calling thread.
    fn advance_here(
        &mut self,
        prev: &[Vector3<f64>],
        next: &[Vector3<f64>],
    ) -> std::result::Result<(usize, FrameChecks), (FrameError, usize)> {
        self.saved_x.copy_from_slice(self.sim.positions());
        self.saved_v.copy_from_slice(self.sim.velocities());
        let mut substeps = self.base_substeps;
        let mut attempt = 0;
        loop {
            let mut totals = SolverTotals::default();
            match self.try_frame(substeps, prev, next, &mut totals) {
                Ok(checks) => {
                    self.commit(substeps, attempt, &totals, &checks);
                    return Ok((substeps, checks));
                }
                Err(FrameError::Hard(e)) => return Err((FrameError::Hard(e), attempt + 1)),
                Err(failure) => {
                    self.substeps.failed_attempts += 1;
                    if attempt == self.retry.max_frame_retries {
                        return Err((failure, attempt + 1));
                    }
                    let restore = self
                        .sim
                        .set_positions(&self.saved_x)
                        .and_then(|()| self.sim.set_velocities(&self.saved_v));
                    if let Err(e) = restore {
                        return Err((FrameError::Hard(e), attempt + 1));
                    }
                    substeps *= self.retry.substep_factor;
                    attempt += 1;
                }
            }
        }
    }

    fn commit(&mut self, substeps: usize, attempt: usize, totals: &SolverTotals, c: &FrameChecks) {
        let s = &mut self.substeps;
        s.min = s.min.min(substeps);
        s.max = s.max.max(substeps);
        s.total += substeps;
        if attempt > 0 {
            s.retried_frames += 1;
        }
        let t = &mut self.totals;
        t.newton_iterations += totals.newton_iterations;
        t.linear_iterations += totals.linear_iterations;
        t.obstacle_contacts += totals.obstacle_contacts;
        t.max_obstacle_contacts = t.max_obstacle_contacts.max(totals.max_obstacle_contacts);
        t.self_contacts += totals.self_contacts;
        t.max_self_contacts = t.max_self_contacts.max(totals.max_self_contacts);
        t.projected_vertices += totals.projected_vertices;
        t.cholesky_fallbacks += totals.cholesky_fallbacks;
        t.max_kinetic_energy_j = t.max_kinetic_energy_j.max(c.kinetic_energy_j);
        t.max_speed_m_per_s = t.max_speed_m_per_s.max(c.max_speed_m_per_s);
        t.max_penetration_m = t.max_penetration_m.max(c.max_penetration_m);
        self.min_excluded_distance_m = self.min_excluded_distance_m.min(c.min_excluded_distance_m);
    }

    fn try_frame(
        &mut self,
        substeps: usize,
        prev: &[Vector3<f64>],
        next: &[Vector3<f64>],
        totals: &mut SolverTotals,
    ) -> std::result::Result<FrameChecks, FrameError> {
        let h = 1.0 / (self.fps * substeps as f64);
        // Back to the frame's start pose (a retry's collider is wherever the failure left it).
        let t_body = Instant::now();
        for ((a, b), &v) in self
            .region_prev
            .iter_mut()
            .zip(&mut self.region_next)
            .zip(&self.region_vertices)
        {
            *a = prev[v as usize];
            *b = next[v as usize];
        }
        // The body moves linearly through the substeps: its tree's boxes are fitted at the
        // frame's two poses and interpolated at each substep, not refitted.
        self.collider
            .set_span(&self.region_prev, &self.region_next, h)?;
        self.timing.body_secs += t_body.elapsed().as_secs_f64();
        let mut last = None;
        for s in 1..=substeps {
            let t_body = Instant::now();
            self.collider.move_on_span(s as f64 / substeps as f64, h)?;
            self.timing.body_secs += t_body.elapsed().as_secs_f64();
            if s == substeps {
                // The frame's result obeys the projection guarantee whatever side the skipped
                // vertices' clearance bounds assumed.
                self.sim.query_every_vertex_next_step();
            }
            let stats = self.sim.step(h, &[&self.collider as &dyn Collider])?;
            self.timing.assemble_secs += stats.assemble_secs;
            self.timing.solve_secs += stats.solve_secs;
            self.timing.collision_secs += stats.collision_secs;
            self.timing.self_collision_secs += stats.self_collision_secs;
            self.timing.self_collision_builds += usize::from(stats.self_collision_built);
            self.timing.coefficients_secs += stats.coefficients_secs;
            self.timing.projection_secs += stats.projection_secs;
            self.timing.step_secs += stats.total_secs;
            totals.newton_iterations += stats.newton_iterations;
            totals.linear_iterations += stats.total_linear_iterations;
            totals.obstacle_contacts += stats.obstacle_contacts;
            totals.max_obstacle_contacts =
                totals.max_obstacle_contacts.max(stats.obstacle_contacts);
            totals.self_contacts += stats.self_contacts;
            totals.max_self_contacts = totals.max_self_contacts.max(stats.self_contacts);
            totals.projected_vertices += stats.projected_vertices;
            totals.cholesky_fallbacks += stats.cholesky_fallbacks;
            last = Some(stats);
        }
        let t_check = Instant::now();
        let checks = self.check(next, last.unwrap_or_default());
        self.timing.check_secs += t_check.elapsed().as_secs_f64();
        checks
    }

    /// The end-of-frame checks: the cloth still with the body ([`LEFT_BODY_M`]), penetration
    /// of the body (found by the region's closest points, confirmed by [`BodyDistance`] beyond
    /// the tolerance) and distance to the excluded triangles.
    fn check(
        &mut self,
        next: &[Vector3<f64>],
        last: crate::solver::StepStats,
    ) -> std::result::Result<FrameChecks, FrameError> {
        let mut checks = FrameChecks {
            min_excluded_distance_m: f64::INFINITY,
            kinetic_energy_j: last.kinetic_energy_j,
            max_speed_m_per_s: last.max_speed_m_per_s,
            ..FrameChecks::default()
        };
        let moved =
            centroid_distance(self.sim.positions(), &self.region_next) - self.start_offset_m;
        if moved > LEFT_BODY_M {
            return Err(FrameError::Failure(SequenceFailure::LeftBody {
                offset_mm: moved * 1e3,
                limit_mm: LEFT_BODY_M * 1e3,
            }));
        }
        let mut deepest = None;
        self.deep.clear();
        let par = self.sim.config().parallelism;
        let collider = &self.collider;
        query_every_vertex(
            self.sim.positions(),
            &mut self.check_hints,
            &mut self.found,
            par,
            |p, hint| {
                collider
                    .closest_within_hinted(*p, 0.0, hint)
                    .map(|c| c.distance_m)
            },
        );
        for (i, d) in self.found.iter().enumerate() {
            if let Some(d) = *d {
                if -d > self.tolerance_m {
                    self.deep.push(i);
                } else if -d > checks.max_penetration_m {
                    checks.max_penetration_m = -d;
                    deepest = Some(i);
                }
            }
        }
        // The region's pseudo-normal sign is wrong behind its cut edges and where body parts
        // press together: a vertex it finds too deep is judged by the whole body's signed
        // distance (inside by winding number), the one collision measure.
        if !self.deep.is_empty() {
            let distance = match &mut self.body_distance {
                Some(d) => {
                    d.update_positions(next).map_err(Error::from)?;
                    d
                }
                None => self
                    .body_distance
                    .insert(BodyDistance::new(next, &self.body_faces).map_err(Error::from)?),
            };
            let positions = self.sim.positions();
            for &i in &self.deep {
                let depth = -distance.signed_distance_m(&positions[i]);
                if depth > checks.max_penetration_m {
                    checks.max_penetration_m = depth;
                    deepest = Some(i);
                }
            }
        }
        if let Some(vertex) = deepest
            && checks.max_penetration_m > self.tolerance_m
        {
            return Err(FrameError::Failure(SequenceFailure::Penetration {
                vertex,
                depth_mm: checks.max_penetration_m * 1e3,
                tolerance_mm: self.tolerance_m * 1e3,
            }));
        }
        if let Some(guard) = &mut self.guard {
            // Only distances are read: the pseudo-normals are left to the few answers that
            // need them (bitwise the stored ones), not recomputed for the whole body.
            guard.update_positions_refit(next).map_err(Error::from)?;
            let mut closest = None;
            let (guard, radius) = (&*guard, self.guard_radius_m);
            query_every_vertex(
                self.sim.positions(),
                &mut self.guard_hints,
                &mut self.found,
                par,
                |p, hint| {
                    guard
                        .closest_within_hinted(p, radius, hint)
                        .map(|c| c.signed_distance_m.abs())
                },
            );
            for (i, d) in self.found.iter().enumerate() {
                if let Some(d) = *d
                    && d < checks.min_excluded_distance_m
                {
                    checks.min_excluded_distance_m = d;
                    closest = Some(i);
                }
            }
            let thickness = self.thickness_m();
            if let Some(vertex) = closest
                && checks.min_excluded_distance_m < thickness
            {
                return Err(FrameError::Failure(SequenceFailure::OutsideRegion {
                    vertex,
                    distance_mm: checks.min_excluded_distance_m * 1e3,
                }));
            }
        }
        Ok(checks)
    }
}

/// `out[i] = query(positions[i], hints[i])` for every cloth vertex, on the simulator's threads
/// (each answer depends on its own vertex and hint only: the same on any thread count).
fn query_every_vertex(
    positions: &[Vector3<f64>],
    hints: &mut [u32],
    out: &mut [Option<f64>],
    par: Parallelism,
    query: impl Fn(&Vector3<f64>, &mut u32) -> Option<f64> + Sync,
) {
    let one = |((p, hint), o): ((&Vector3<f64>, &mut u32), &mut Option<f64>)| {
        *o = query(p, hint);
    };
    match par {
        Parallelism::Sequential => positions.iter().zip(hints).zip(out).for_each(one),
        Parallelism::Rayon => positions
            .par_iter()
            .zip(hints.par_iter_mut())
            .zip(out.par_iter_mut())
            .for_each(one),
    }
}

/// Check β and the motion against the body: β padded with zeros to the model's length, the
/// motion resampled to [`sartor_core::FPS`].
fn prepare_inputs(
    body: &BodyModel,
    betas: &[f64],
    motion: Option<&Motion>,
    clearance: Option<&ClearanceOptions>,
) -> Result<(Vec<f64>, Option<Motion>)> {
    body.check_betas(betas)?;
    let mut padded = betas.to_vec();
    padded.resize(body.n_betas(), 0.0);
    let Some(motion) = motion else {
        return Ok((padded, None));
    };
    if motion.joint_names() != body.skeleton().names() {
        return Err(Error::invalid(
            "motion",
            format!(
                "{}: its joints are not the body's ({} vs {} joints, or another order)",
                motion.name(),
                motion.joint_names().len(),
                body.skeleton().n_joints()
            ),
        ));
    }
    let motion = if (motion.fps() - sartor_core::FPS).abs() > 1e-9 {
        motion.resample(sartor_core::FPS)?
    } else {
        motion.clone()
    };
    let motion = match clearance {
        Some(options) => {
            let (frames, _) =
                ArmClearance::new(body)?.apply(body, &padded, motion.frames(), options)?;
            Motion::new(
                motion.name().to_string(),
                motion.fps(),
                motion.joint_names().to_vec(),
                frames,
            )?
        }
        None => motion,
    };
    Ok((padded, Some(motion)))
}

/// A short name of a sequence for messages.
fn sequence_name(garment: &Garment, betas: &[f64], motion: Option<&Motion>) -> String {
    format!(
        "{} on β {:?} / {}",
        garment.name(),
        betas,
        motion.map_or("rest pose", Motion::name)
    )
}

/// Simulate `garment` (of `material`) on `body` with shape `betas` through `motion` (`None`:
/// the rest-pose simulation for the garment fit, see the [module docs](self)), with the
/// paper's protocol: blend, rest, motion. `progress(done, total)` is called after every frame
/// (frames start again from 0 if the sequence restarts with a larger body region).
///
/// `betas` may be shorter than the model's (missing components are zero); the sequence holds
/// it padded. Returns the frames and their header, ready for [`ClothSequence::write`]; a
/// sequence that fails even with the retries of `config.retry` is an
/// [`Error::SequenceFailed`].
pub fn simulate_sequence(
    body: &BodyModel,
    garment: &Garment,
    material: &Material,
    betas: &[f64],
    motion: Option<&Motion>,
    config: &DriveConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ClothSequence> {
    let started = Instant::now();
    config.validate()?;
    let (betas, prepared) = prepare_inputs(body, betas, motion, config.arm_clearance.as_ref())?;
    let betas = betas.as_slice();
    let motion_id = match motion {
        Some(m) => Some(MotionId {
            name: m.name().to_string(),
            sha256: sha256_hex(
                &serde_json::to_vec(m).map_err(|e| Error::invalid("motion", e.to_string()))?,
            ),
            n_frames: prepared.as_ref().map_or(0, Motion::n_frames),
        }),
        None => None,
    };
    let (start, keys) = schedule(body.skeleton().n_joints(), betas, prepared.as_ref(), config);
    let name = sequence_name(garment, betas, motion);
    let mut margin_m = config.region.margin_m;
    let mut restarts = 0;
    loop {
        let mut attempt_config = config.clone();
        attempt_config.region.margin_m = margin_m;
        match run(
            body,
            garment,
            material,
            &start,
            &keys,
            &attempt_config,
            progress,
        ) {
            Ok(mut sequence) => {
                let h = &mut sequence.header;
                h.betas = betas.to_vec();
                h.motion = motion_id;
                h.drive_config = config.clone();
                h.drive_config_sha256 = config.sha256()?;
                h.substeps.region_restarts = restarts;
                if let Some(timing) = &mut sequence.timing {
                    timing.total_secs = started.elapsed().as_secs_f64();
                }
                return Ok(sequence);
            }
            Err((FrameError::Hard(e), _, _)) => return Err(e),
            Err((FrameError::Failure(reason), frame, attempts)) => {
                let outside = matches!(reason, SequenceFailure::OutsideRegion { .. });
                if outside && restarts < config.retry.max_region_restarts {
                    restarts += 1;
                    margin_m *= 2.0;
                    continue;
                }
                return Err(Error::SequenceFailed {
                    sequence: name,
                    frame,
                    attempts,
                    reason,
                });
            }
        }
    }
}

/// The body triangles (ascending indices into `body.faces()`) that take part in contact when
/// [`simulate_sequence`] simulates `garment` on shape `betas` through `motion` with `config`:
/// all of them with [`RegionConfig::whole_body`], else those near the garment carried along
/// with the body (see the [module docs](self)). A sequence that restarted with a larger region
/// used the margin its header records ([`RegionStats::margin_m`]).
pub fn contact_region(
    body: &BodyModel,
    garment: &Garment,
    betas: &[f64],
    motion: Option<&Motion>,
    config: &DriveConfig,
) -> Result<Vec<u32>> {
    config.validate()?;
    let (betas, prepared) = prepare_inputs(body, betas, motion, config.arm_clearance.as_ref())?;
    let (start, keys) = schedule(
        body.skeleton().n_joints(),
        &betas,
        prepared.as_ref(),
        config,
    );
    let region = if config.region.whole_body {
        Region::whole(body)
    } else {
        Region::near_garment(body, garment, &start, &keys, config.region.margin_m)?
    };
    Ok((0..body.faces().len() as u32)
        .filter(|&f| region.kept[f as usize])
        .collect())
}

/// One attempt at a whole sequence with `config.region.margin_m`.
fn run(
    body: &BodyModel,
    garment: &Garment,
    material: &Material,
    start: &Pose,
    keys: &[Keyframe],
    config: &DriveConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> std::result::Result<ClothSequence, (FrameError, usize, usize)> {
    let hard = |e: Error| (FrameError::Hard(e), 0, 0);
    let fps = sartor_core::FPS;
    let t_region = Instant::now();
    let region = if config.region.whole_body {
        Region::whole(body)
    } else {
        Region::near_garment(body, garment, start, keys, config.region.margin_m).map_err(hard)?
    };
    let region_secs = t_region.elapsed().as_secs_f64();

    let mut poser = BodyPoser::new(body);
    let mut prev = vec![Vector3::zeros(); body.n_vertices()];
    let zeros = vec![0.0; body.n_betas()];
    poser
        .pose_into(&zeros, start, &mut prev)
        .map_err(|e| hard(e.into()))?;
    // The template moved rigidly with the start state (identity for a motion starting at the
    // origin): every joint has the root's transform in a rest pose.
    let rigid = poser.transforms()[0];
    let cloth_start: Vec<Vector3<f64>> =
        garment.positions().iter().map(|p| rigid.apply(p)).collect();
    let mut stepper = FrameStepper::new(
        body,
        garment,
        material,
        config,
        &region,
        &prev,
        &cloth_start,
        fps,
    )
    .map_err(hard)?;
    stepper.timing.region_secs = region_secs;

    // The preview's body: the kept triangles over their own vertices.
    let every = config.preview.every_n_frames;
    let (preview_vertices, preview_faces) =
        compact_faces(&region.faces(body, true), body.n_vertices());
    let mut preview_frames = Vec::new();

    let mut next = prev.clone();
    let mut frames = Vec::with_capacity(keys.len());
    for (i, key) in keys.iter().enumerate() {
        poser
            .pose_into(&key.betas, &key.pose, &mut next)
            .map_err(|e| hard(e.into()))?;
        let (substeps, _) = stepper
            .advance(&prev, &next)
            .map_err(|(e, attempts)| (e, i, attempts))?;
        frames.push(SequenceFrame {
            phase: key.phase,
            motion_frame: key.motion_frame,
            substeps,
            betas: key.betas.clone(),
            pose: key.pose.clone(),
            positions: stepper
                .sim
                .positions()
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect(),
        });
        if every > 0 && i % every == 0 {
            preview_frames.push(PreviewFrame {
                frame: i,
                body_positions: preview_vertices
                    .iter()
                    .map(|&v| next[v as usize].map(|c| c as f32).into())
                    .collect(),
            });
        }
        std::mem::swap(&mut prev, &mut next);
        progress(i + 1, keys.len());
    }

    let n_motion = keys.iter().filter(|k| k.phase == Phase::Motion).count();
    if stepper.substeps.min == usize::MAX {
        stepper.substeps.min = 0;
    }
    let header = SequenceHeader {
        format: SEQUENCE_FORMAT.into(),
        version: 1,
        units: "m".into(),
        axes: "+Y up, +Z forward, +X body's left".into(),
        garment: GarmentId {
            asset: garment.asset_id().map_err(hard)?,
            n_vertices: garment.positions().len(),
            n_faces: garment.faces().len(),
        },
        body: BodyId {
            asset: body.asset_id().map_err(|e| hard(e.into()))?,
            n_betas: body.n_betas(),
            joint_names: body.skeleton().names().to_vec(),
        },
        material: material.to_file(),
        drive_config: config.clone(),
        drive_config_sha256: String::new(),
        motion: None,
        betas: Vec::new(),
        fps,
        blend_frames: config.blend_frames,
        rest_frames: config.rest_frames,
        motion_frames: n_motion,
        n_frames: keys.len(),
        region: RegionStats {
            faces_kept: region.n_kept(),
            faces_total: body.faces().len(),
            margin_m: config.region.margin_m,
            min_excluded_distance_m: stepper
                .min_excluded_distance_m
                .is_finite()
                .then_some(stepper.min_excluded_distance_m),
        },
        substeps: stepper.substeps.clone(),
        solver: stepper.totals.clone(),
        preview_frames: preview_frames.len(),
    };
    Ok(ClothSequence {
        header,
        faces: garment.faces().to_vec(),
        frames,
        preview: (every > 0).then_some(SequencePreview {
            every_n_frames: every,
            body_faces: preview_faces,
            frames: preview_frames,
        }),
        timing: Some(stepper.timing),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn implicit_friction_is_asked_for_and_old_configs_keep_their_hash() {
        let old = DriveConfig::default();
        let json = String::from_utf8(serde_json::to_vec(&old).expect("json")).expect("utf-8");
        assert!(!json.contains("friction_model"), "{json}");
        let read: DriveConfig = serde_json::from_str(&json).expect("reads");
        assert_eq!(read.sim.friction_model, crate::FrictionModel::Impulse);
        let mut on = DriveConfig {
            substeps_per_frame: IMPLICIT_FRICTION_SUBSTEPS_PER_FRAME,
            max_step_per_edge_s_per_m: Some(IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M),
            ..DriveConfig::default()
        };
        on.sim.friction_model = crate::FrictionModel::Implicit;
        on.validate().expect("valid");
        let json = serde_json::to_string(&on).expect("json");
        assert!(json.contains(r#""friction_model":"Implicit""#), "{json}");
        let back = DriveConfig::from_json(json.as_bytes(), std::path::Path::new("on.json"))
            .expect("reads");
        assert_eq!(back, on);
        assert_ne!(old.sha256().expect("hash"), on.sha256().expect("hash"));
        assert_eq!(
            old.stable_step_per_edge_s_per_m(),
            STABLE_STEP_PER_EDGE_S_PER_M
        );
        assert_eq!(
            on.stable_step_per_edge_s_per_m(),
            IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M
        );
        // 1 / (30 × 0.135 × edge): 13.5, 19.3, 27.9 and 33.4 for the T-shirts' median edges,
        // never below 20.
        for (edge, substeps) in [(18.28e-3, 20), (12.77e-3, 20), (8.86e-3, 28), (7.40e-3, 34)] {
            assert_eq!(on.substeps_for_edge(edge, 30.0), substeps, "{edge}");
        }
    }

    #[test]
    fn the_substeps_follow_the_edge_only_when_asked_and_old_configs_keep_their_hash() {
        let old = DriveConfig::default();
        let json = String::from_utf8(serde_json::to_vec(&old).expect("json")).expect("utf-8");
        assert!(!json.contains("max_step_per_edge"), "{json}");
        // Off: the configured substeps at any resolution.
        assert_eq!(old.substeps_for_edge(0.002, 30.0), 10);
        let on = DriveConfig {
            max_step_per_edge_s_per_m: Some(STABLE_STEP_PER_EDGE_S_PER_M),
            ..DriveConfig::default()
        };
        on.validate().expect("valid");
        assert_ne!(old.sha256().expect("hash"), on.sha256().expect("hash"));
        // 1 / (30 × 0.066 × edge): 27.6, 39.5 and 68.2 for the T-shirts' median edges.
        assert_eq!(on.substeps_for_edge(18.28e-3, 30.0), 28);
        assert_eq!(on.substeps_for_edge(12.77e-3, 30.0), 40);
        assert_eq!(on.substeps_for_edge(7.40e-3, 30.0), 69);
        for edge in [18.28e-3, 12.77e-3, 7.40e-3] {
            assert!(on.step_per_edge_s_per_m(edge, 30.0) <= STABLE_STEP_PER_EDGE_S_PER_M);
        }
        // The 8,710-triangle shirt at 10 substeps: 0.26 s/m.
        let old_step = old.step_per_edge_s_per_m(12.77e-3, 30.0);
        assert!((old_step - 0.261).abs() < 1e-3, "{old_step}");
        // Never fewer than configured; a coarse cloth keeps the configured 10.
        assert_eq!(on.substeps_for_edge(0.1, 30.0), 10);
        // A degenerate edge asks for more than the retries leave: capped, still valid.
        let capped = on.substeps_for_edge(1e-9, 30.0);
        let most = capped
            * on.retry
                .substep_factor
                .pow(on.retry.max_frame_retries as u32);
        assert!(most <= MAX_SUBSTEPS_PER_FRAME && capped >= 10, "{capped}");
        for k in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let bad = DriveConfig {
                max_step_per_edge_s_per_m: Some(k),
                ..DriveConfig::default()
            };
            assert!(bad.validate().is_err(), "{k}");
        }
    }

    #[test]
    fn defaults_validate_and_hash_stably() {
        let c = DriveConfig::default();
        c.validate().expect("defaults are valid");
        assert_eq!(c.sha256().expect("hash"), c.clone().sha256().expect("hash"));
        let mut d = c.clone();
        d.rest_frames += 1;
        assert_ne!(c.sha256().expect("hash"), d.sha256().expect("hash"));
        let json = serde_json::to_vec(&c).expect("json");
        let back = DriveConfig::from_json(&json, std::path::Path::new("c.json")).expect("parse");
        assert_eq!(back, c);
        let e = DriveConfig::from_json(br#"{"colour": 1}"#, std::path::Path::new("c.json"))
            .expect_err("unknown field");
        assert!(e.to_string().contains("c.json") && e.to_string().contains("colour"));
        let bad = DriveConfig {
            penetration_tolerance_m: 1e-4,
            ..DriveConfig::default()
        };
        assert!(
            bad.validate().is_err(),
            "tolerance below the projection threshold"
        );
    }

    #[test]
    fn arm_clearance_is_off_unless_asked_and_old_configs_keep_their_hash() {
        // A sequence written before the option existed holds a config without it: it must
        // read back as `None` with the hash it was written with.
        let c = DriveConfig::default();
        let json = serde_json::to_string(&c).expect("json");
        assert!(!json.contains("arm_clearance"), "{json}");
        let on: DriveConfig =
            serde_json::from_str(&json.replace(r#""preview""#, r#""arm_clearance":{},"preview""#))
                .expect("parse");
        assert_eq!(on.arm_clearance, Some(ClearanceOptions::default()));
        assert_ne!(on.sha256().expect("hash"), c.sha256().expect("hash"));
        let bad = DriveConfig {
            arm_clearance: Some(ClearanceOptions {
                clearance_m: -0.01,
                ..ClearanceOptions::default()
            }),
            ..DriveConfig::default()
        };
        let e = bad.validate().expect_err("negative clearance");
        assert!(e.to_string().contains("clearance"), "{e}");
    }

    #[test]
    fn schedule_blends_then_rests_then_moves() {
        let config = DriveConfig {
            blend_frames: 4,
            rest_frames: 2,
            ..DriveConfig::default()
        };
        let (start, keys) = schedule(3, &[2.0], None, &config);
        assert_eq!(start, Pose::rest(3));
        assert_eq!(keys.len(), 6);
        assert_eq!(keys[3].betas, vec![2.0], "the blend ends at β");
        assert!(keys[0].betas[0] > 0.0 && keys[0].betas[0] < keys[1].betas[0]);
        assert!(keys[4..].iter().all(|k| k.phase == Phase::Rest));
    }
}
