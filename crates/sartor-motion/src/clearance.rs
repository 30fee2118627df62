//! Keeping the forearms and hands out of the torso of a given body shape.
//!
//! Motion capture is retargeted by bone directions ([`crate::RetargetBody`]): the performer's
//! joint rotations are put on sartor's body as they are. On a body wider than the performer's
//! (or a performer whose hands brushed their own hips), the forearms and hands then pass through
//! the torso. A garment caught between has no position outside the body, and a cloth simulation
//! of it fails. [`ArmClearance`] measures that intersection ([`ArmClearance::depths`]) and
//! removes it ([`ArmClearance::apply`]): per frame, the upper arm is turned about the shoulder,
//! by the smallest rotation found, until every forearm and hand vertex of that side is at least
//! [`ClearanceOptions::clearance_m`] outside the torso; the rotations are then eased in and out
//! over neighbouring frames so that the arm does not jump. Frames that need nothing in reach of
//! a frame that does keep their pose bit for bit.
//! [`ClearanceOnDemand`] gives the same poses one frame at a time, as a player asks for them.
//!
//! With [`ClearanceOptions::upper_arm_clearance_m`] the upper arm is held out of the torso too.
//! Skinning sinks a hanging upper arm into the side of a heavy torso (by up to 40 mm on the CMU
//! clips): a shirt's side caught there has no position outside the body either, and the
//! simulator's contacts, which see only the closest surface, leave it inside the arm. The
//! upper arm's vertices at least [`UPPER_ARM_MIN_LEVER`] of its length from the shoulder, and
//! outside the torso by the clearance in the rest pose, are then held at that clearance; the
//! armpit itself, where arm and torso meet, cannot be and is not.
//!
//! With [`ClearanceOptions::leg_clearance_m`] the legs are held out too, their shin, foot and
//! toe vertices as the forearm and hand, the thigh beyond [`UPPER_ARM_MIN_LEVER`] of its length
//! as the upper arm (where thigh and torso meet at the groin, nothing is held). A leg first
//! swings its knee outwards about the line from its hip to its ankle, which keeps the foot
//! where the motion put it, by up to 20°; then it turns about the hip as an arm
//! does. The foot turns back by as much as the hip, so that it keeps its orientation (a foot
//! flat on the floor stays flat). Motion capture of a performer more supple than the body sinks
//! a raised thigh into the belly, with the shirt caught between: retargeted onto the built-in
//! body at 1.75 m, 9 of the 60 stored CMU clips put a leg more than 10 mm into the torso
//! (playground climbing, modern dance, subject 02's clips, among them a crouch; up to 78 mm,
//! and in 114 of the 559 frames of `cmu/02_06`). Held at [`LEG_CLEARANCE_M`], 7 of them have
//! no leg vertex left inside; `cmu/02_10` keeps 3 frames (of 35; 69 → 21 mm) and the cartwheel
//! of `cmu/05_06` 3 (of 30; 81 → 6 mm). On the 1.90 m heavy male those two keep 2 and 6 frames
//! (75 → 0, 84 → 55 mm), on the 1.60 m light female 10 and 7 (33 → 27, 55 → 26 mm). 33 of the
//! 60 clips keep their legs bit for bit at 1.75 m, the walks among them. Where a turn is needed
//! the feet move: by up to 16 cm in the crouch of `cmu/02_06` (frames 272–283), more where a
//! foot is in the air (a kick, the cartwheel); and a leg within the clearance but not inside
//! can turn too (`cmu/05_11`, a dance: 33°). `apply` over the 60 clips takes some 10 % longer
//! with the legs held.
//!
//! The torso is the body's triangles whose vertices are all dominated (largest skin weight) by
//! the spine, hips, neck or shoulder roots — where a T-shirt is. Inside is decided by the
//! winding number of that open surface ([`BodyDistance`]).

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use sartor_core::{BodyDistance, BodyModel, Error, Pose, PoseBuffers, Result, compact_faces};
use serde::{Deserialize, Serialize};

mod on_demand;

pub use on_demand::{ClearanceJob, ClearanceOnDemand, ClearanceProgress};

/// Options of [`ArmClearance::apply`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClearanceOptions {
    /// How far outside the torso every forearm and hand vertex must be, m. Default 0.025: room
    /// for a garment layer between hand and hip, with its contact thickness on both sides. Of
    /// two CMU sequences measured, 10 mm still let a dancing hand catch the shirt at the hip,
    /// 25 mm did not.
    pub clearance_m: f64,
    /// How far outside the torso the upper arm must be, m, or `None` (the default, and the
    /// behaviour of configurations written before it): the upper arm is left where the motion
    /// puts it. See the [module docs](self).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub upper_arm_clearance_m: Option<f64>,
    /// How far outside the torso the legs must be, m, or `None` (the default, and the
    /// behaviour of configurations written before it): the legs are left where the motion puts
    /// them. Set, the shins and feet are held at it, and the thighs as the upper arms are (at
    /// least [`UPPER_ARM_MIN_LEVER`] of their length from the hip and clear of the torso in
    /// the rest pose), each leg turned about its hip. See the [module docs](self).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub leg_clearance_m: Option<f64>,
    /// Over how many frames before and after a corrected frame its rotation is eased in and
    /// out (linearly). Default 8 (0.27 s at 30 fps).
    pub ramp_frames: usize,
    /// Shoulder rotations tried per frame and pass. Default 8.
    pub max_iterations: usize,
    /// Passes over the motion: each corrects what the easing of the previous one left.
    /// Default 3.
    pub max_passes: usize,
    /// Largest shoulder rotation of one frame, radians. Default 1.0 (57°): beyond it the
    /// intersection is not a brushing arm but a pose this cannot mend.
    pub max_angle_rad: f64,
}

impl Default for ClearanceOptions {
    fn default() -> Self {
        Self {
            clearance_m: 0.025,
            upper_arm_clearance_m: None,
            leg_clearance_m: None,
            ramp_frames: 8,
            max_iterations: 8,
            max_passes: 3,
            max_angle_rad: 1.0,
        }
    }
}

impl ClearanceOptions {
    /// These options with the legs held at [`LEG_CLEARANCE_M`]: how sartor's players
    /// (`sartor demo`, the try-on page) hold the limbs on top of the arms a model's training
    /// motions had.
    pub fn with_player_legs(self) -> Self {
        Self {
            leg_clearance_m: Some(LEG_CLEARANCE_M),
            ..self
        }
    }

    /// Check the options: finite clearances ≥ 0 (the upper arm's and the legs' when set), a
    /// finite largest angle > 0.
    pub fn validate(&self) -> Result<()> {
        let clearance_ok = [
            Some(self.clearance_m),
            self.upper_arm_clearance_m,
            self.leg_clearance_m,
        ]
        .into_iter()
        .flatten()
        .all(|c| c.is_finite() && c >= 0.0);
        let angle_ok = self.max_angle_rad.is_finite() && self.max_angle_rad > 0.0;
        if !(clearance_ok && angle_ok) {
            return Err(Error::invalid(
                "arm clearance",
                format!(
                    "clearance_m {}, upper_arm_clearance_m {:?} and leg_clearance_m {:?} must \
                     be finite and ≥ 0, max_angle_rad {} finite and > 0",
                    self.clearance_m,
                    self.upper_arm_clearance_m,
                    self.leg_clearance_m,
                    self.max_angle_rad
                ),
            ));
        }
        Ok(())
    }
}

/// What [`ArmClearance::apply`] did to a motion.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClearanceReport {
    /// Frames whose pose changed.
    pub frames_changed: usize,
    /// The largest shoulder rotation added, radians.
    pub max_angle_rad: f64,
    /// Deepest held vertex (forearm, hand, and the upper arm's with
    /// [`ClearanceOptions::upper_arm_clearance_m`], the legs' with
    /// [`ClearanceOptions::leg_clearance_m`]) inside the torso before and after, m (0: none
    /// inside).
    pub max_depth_before_m: f64,
    /// See `max_depth_before_m`.
    pub max_depth_after_m: f64,
}

/// One arm (or leg): its upper-arm joint (the pivot), the forearm and hand vertices it carries,
/// and the upper arm's own vertices.
#[derive(Clone, Debug)]
struct Arm {
    /// Whether it is a leg: its hip for the shoulder, its shin, foot and toes for the forearm
    /// and hand, its thigh for the upper arm (held only with
    /// [`ClearanceOptions::leg_clearance_m`]).
    leg: bool,
    shoulder: usize,
    /// A leg's knee and ankle joints (the hip's child and the knee's): a leg turns about the
    /// line from its hip to its ankle, which keeps the foot where the motion puts it.
    swivel: Option<[usize; 2]>,
    vertices: Vec<usize>,
    upper: Vec<usize>,
    /// The torso's vertices that turning the shoulder can move (a joint of its subtree among
    /// their weights), ascending, and whether there is one: the poses of a fix differ only in
    /// the shoulder's rotation, which moves these and the arm's own.
    moved_torso: Vec<u32>,
    moves_torso: bool,
}

/// The legs' clearance of sartor's players (`sartor demo`, the try-on page), m, set on top of
/// the arm clearance the shipped model's training motions had
/// ([`ClearanceOptions::leg_clearance_m`]: the training data's legs were left as they came).
/// Measured on the 9 stored CMU clips that sink a leg into the torso at 1.75 m: held at 0,
/// every one of them kept 1–16 frames with a leg inside (a turn stops once the worst vertex is
/// within half a millimetre, and the easing leaves the frames around short), the cartwheel of
/// `cmu/05_06` 9 (62 mm deep); at 10 mm 7 of them none (see the [module docs](self)).
pub const LEG_CLEARANCE_M: f64 = 0.01;

/// How far a leg's knee swings outwards about the line from its hip to its ankle, keeping the
/// foot where the motion puts it, before the leg turns freely about the hip, radians (20°).
/// Measured on the stored CMU clips that need it, at 1.75 m: a swing alone (no free turn) left
/// 12 of `cmu/02_06`'s 114 frames inside instead of none and swung knees by up to 120°; a free
/// turn alone moved the feet by up to 27 cm over that clip; with the swing capped at 20°, 40°
/// and 57°, the feet of its crouch (frames 272–283) moved by up to 16, 6 and 5 cm, and the
/// cartwheel of `cmu/05_06` kept 3, 11 and 13 of its 30 frames inside.
const SWIVEL_MAX_RAD: f64 = 0.35;

/// The largest turn of one iteration of a limb's fix, radians (20°): the first-order step
/// `short / reach` overshoots where the lever is short.
const MAX_STEP_RAD: f64 = 0.35;

/// An upper-arm vertex is held out of the torso only this share of the upper arm's length
/// (shoulder to elbow joint) or farther from the shoulder: nearer, turning the arm hardly moves
/// it, and the armpit is where arm and torso meet.
pub const UPPER_ARM_MIN_LEVER: f64 = 0.4;

/// An upper-arm vertex is held at the clearance only if the rest pose has it this much farther
/// out, m.
const UPPER_ARM_REST_SLACK_M: f64 = 5e-3;

/// A held vertex this little short of its clearance is not chased, m (half a millimetre).
const SLACK_M: f64 = 5e-4;

/// Per arm, the vertices held out of the torso and how far.
type Targets = Vec<ArmTargets>;

/// An arm's held vertices, in groups that share a dominant joint: each group's skinned
/// positions lie within a box known from its joints' transforms alone, and a pose skins and looks at
/// a group only where that box comes within its clearance of the torso's ([`Posing::pose`]).
#[derive(Clone, Debug)]
struct ArmTargets {
    /// `(body vertex, clearance in m)`.
    list: Vec<(usize, f64)>,
    /// Per vertex of `list`, its group.
    group_of: Vec<u16>,
    groups: Vec<Group>,
}

/// Held vertices of one arm that share a dominant joint.
#[derive(Clone, Debug)]
struct Group {
    /// Their body vertices, ascending.
    vertices: Vec<u32>,
    /// The joints among their skin weights.
    joints: Vec<usize>,
    /// The centre and half extent of their box in the shaped rest pose (the extent grown by
    /// [`GROUP_PAD_M`]), m. Skinned, a vertex is a convex blend of its rest position moved by
    /// each of its joints' transforms; each moves the rest box into a box about the moved
    /// centre, so the vertex lies within the box of those boxes.
    center: Vector3<f64>,
    half: Vector3<f64>,
    /// Their largest clearance, m.
    clearance: f64,
}

/// Whether a test turned [`Posing::pose`]'s culling off on its thread (never outside tests).
fn culling_off() -> bool {
    #[cfg(test)]
    return tests::NO_CULLING.with(std::cell::Cell::get);
    #[cfg(not(test))]
    false
}

/// Added to each group's half extent ([`Group::half`]), m: far beyond the rounding of the
/// skinning's blend (its f32 weights sum to one within 1e-7, coordinates are within metres).
const GROUP_PAD_M: f64 = 1e-6;

/// The body's arms and torso, for measuring and removing arm–torso intersection (see the
/// [module docs](self)).
#[derive(Clone, Debug)]
pub struct ArmClearance {
    arms: Vec<Arm>,
    /// The skeleton's root joint (the pelvis): a leg's outside is away from it.
    root: usize,
    torso: Torso,
    /// The body vertices a pose is read at (the torso faces' and the arms'), ascending: the
    /// rest of the body is not skinned.
    needed: Vec<u32>,
}

/// The torso's faces over its own vertices: its distance field is built and refitted over
/// them alone, not over the whole body's vertex array (a refit copies, checks and rounds every
/// vertex it is given: eight times as many, 13,380 for 1,669 on the built-in body).
#[derive(Clone, Debug)]
struct Torso {
    /// Its body vertices, ascending.
    vertices: Vec<u32>,
    /// Its faces, indexing `vertices`.
    faces: Vec<[u32; 3]>,
}

impl Torso {
    /// The torso of the body faces `faces` (of a body of `n_vertices`).
    fn new(faces: &[[u32; 3]], n_vertices: usize) -> Self {
        let (vertices, faces) = compact_faces(faces, n_vertices);
        Self { vertices, faces }
    }
}

/// Whether a joint name is of a forearm or a hand.
fn distal_arm(name: &str) -> bool {
    ["ForeArm", "Hand", "Finger", "Thumb"]
        .iter()
        .any(|k| name.contains(k))
}

/// Whether a joint name is of an upper arm (`LeftArm`, not `LeftForeArm`).
fn upper_arm(name: &str) -> bool {
    name.ends_with("Arm") && !name.ends_with("ForeArm")
}

/// A test of a joint's name ([`upper_arm`], [`distal_arm`], [`thigh`], [`distal_leg`]).
type JointKind = fn(&str) -> bool;

/// Whether a joint name is of a shin, a foot or toes (`LeftLeg`, not `LeftUpLeg`).
fn distal_leg(name: &str) -> bool {
    (name.ends_with("Leg") && !name.ends_with("UpLeg"))
        || name.contains("Foot")
        || name.contains("Toe")
}

/// Whether a joint name is of a thigh (`LeftUpLeg`).
fn thigh(name: &str) -> bool {
    name.ends_with("UpLeg")
}

/// A body of one shape posed once per frame, with the torso's distance field. It does not hold
/// the body: each pose is given it, the same every time (see [`PoseBuffers`]).
#[derive(Clone, Debug)]
struct Posing {
    poser: PoseBuffers,
    betas: Vec<f64>,
    posed: Vec<Vector3<f64>>,
    /// The torso's vertices as posed ([`Torso::vertices`]).
    torso_posed: Vec<Vector3<f64>>,
    /// Over the torso's own vertices.
    distance: Option<BodyDistance>,
    /// Per body vertex, the torso face it was closest to when last asked (a hint that gives
    /// [`BodyDistance::query_hinted`] the same answer for less work).
    hints: Vec<u32>,
    /// Per arm and group of its targets, whether the last pose left the group unskinned: its
    /// box farther than its clearance from the torso's.
    culled: Vec<Vec<bool>>,
    /// The group vertices a pose skins (scratch).
    active: Vec<u32>,
}

impl Posing {
    fn new(body: &BodyModel, betas: &[f64]) -> Result<Self> {
        body.check_betas(betas)?;
        Ok(Self {
            poser: PoseBuffers::default(),
            betas: betas.to_vec(),
            posed: vec![Vector3::zeros(); body.n_vertices()],
            torso_posed: Vec::new(),
            distance: None,
            hints: vec![u32::MAX; body.n_vertices()],
            culled: Vec::new(),
            active: Vec::new(),
        })
    }

    /// The torso's vertices of the posed body into [`Posing::torso_posed`].
    fn gather_torso(&mut self, torso: &Torso) {
        self.torso_posed.clear();
        self.torso_posed
            .extend(torso.vertices.iter().map(|&v| self.posed[v as usize]));
    }

    /// Pose the body at the vertices `needed` (the torso faces' and the arms') and the torso's
    /// distance field.
    fn pose_all(
        &mut self,
        body: &BodyModel,
        pose: &Pose,
        torso: &Torso,
        needed: &[u32],
    ) -> Result<()> {
        self.poser
            .pose_vertices_into(body, &self.betas, pose, needed, &mut self.posed)?;
        self.fit_torso(torso)
    }

    /// Pose the body at the torso's vertices and the torso's distance field, then at the held
    /// vertices of each group of `targets` whose box comes within its clearance of the torso's
    /// (the others are marked in [`Posing::culled`]: [`Posing::worst`] would skip each of their
    /// vertices, farther than its reach from the torso's box): the same bits (tested), `apply`
    /// over five CMU clips × three shapes × the upper arms held or not 2.13 → 1.92 s, and the
    /// page's change of shape (`cargo bench -p sartor-web --bench seek -- shape`) 148.2–148.7 →
    /// 141.9–142.3 ms (AMD EPYC VM, two rounds of old and new builds in turn).
    fn pose(
        &mut self,
        body: &BodyModel,
        pose: &Pose,
        torso: &Torso,
        targets: &Targets,
    ) -> Result<()> {
        // Only the vertices read: the torso faces' (its distance field) and the arms' (the
        // held vertices); the legs, head and the rest are some two thirds of the body.
        self.poser
            .pose_vertices_into(body, &self.betas, pose, &torso.vertices, &mut self.posed)?;
        self.fit_torso(torso)?;
        self.culled.resize(targets.len(), Vec::new());
        self.active.clear();
        for (a, t) in targets.iter().enumerate() {
            self.cull(a, t);
        }
        self.poser
            .pose_vertices_into(body, &self.betas, pose, &self.active, &mut self.posed)
    }

    /// The torso's distance field at the posed torso vertices.
    fn fit_torso(&mut self, torso: &Torso) -> Result<()> {
        self.gather_torso(torso);
        match &mut self.distance {
            // The few closest points asked per pose compute their normals themselves: the
            // torso's normals for every pose were a quarter of `apply`'s time.
            Some(d) => d.update_positions_refit(&self.torso_posed)?,
            None => self.distance = Some(BodyDistance::new(&self.torso_posed, &torso.faces)?),
        }
        Ok(())
    }

    /// Mark the groups of arm `a`'s `targets` whose box lies farther than their clearance
    /// from the torso's ([`Posing::culled`]), from the joints' transforms and the torso's box
    /// of the last pose; the vertices of the others onto [`Posing::active`].
    fn cull(&mut self, a: usize, targets: &ArmTargets) {
        let (lo, hi) = self.distance.as_ref().expect("posed before").bounds();
        let transforms = self.poser.transforms();
        let culled = &mut self.culled[a];
        culled.clear();
        for group in &targets.groups {
            let (mut glo, mut ghi) = (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            );
            for &j in &group.joints {
                let t = &transforms[j];
                let center = t.linear * group.center + t.translation;
                let half = t.linear.abs() * group.half;
                glo = glo.inf(&(center - half));
                ghi = ghi.sup(&(center + half));
            }
            let gap2: f64 = (0..3)
                .map(|k| (lo[k] - ghi[k]).max(glo[k] - hi[k]).max(0.0).powi(2))
                .sum();
            let far = gap2 > (group.clearance + GROUP_PAD_M).powi(2) && !culling_off();
            culled.push(far);
            if !far {
                self.active.extend_from_slice(&group.vertices);
            }
        }
    }

    /// Pose the body at `pose`, which differs from the last pose only in the rotation of arm
    /// `a`'s shoulder: only the torso vertices that turn moves and the arm's held vertices (as
    /// [`Posing::pose`] culls them) are skinned again, and the torso's distance field is
    /// refitted only if a torso vertex is among them (the same bits as [`Posing::pose`]).
    fn pose_turned(
        &mut self,
        body: &BodyModel,
        pose: &Pose,
        (a, arm): (usize, &Arm),
        torso: &Torso,
        targets: &ArmTargets,
    ) -> Result<()> {
        self.poser.pose_vertices_into(
            body,
            &self.betas,
            pose,
            &arm.moved_torso,
            &mut self.posed,
        )?;
        if arm.moves_torso {
            self.gather_torso(torso);
            self.distance
                .as_mut()
                .expect("posed before")
                .update_positions_refit(&self.torso_posed)?;
        }
        self.active.clear();
        self.cull(a, targets);
        self.poser
            .pose_vertices_into(body, &self.betas, pose, &self.active, &mut self.posed)
    }

    /// The worst of an arm's held vertices `targets` in the last pose, if it is more than
    /// `slack` short of its clearance: how far short, the unit direction that takes it out (or
    /// farther out) and its index; and the depth of the deepest one inside the torso (0: none
    /// inside), m.
    ///
    /// Every vertex gets its side (the winding number), but an outside one gets its closest
    /// point only where it could still be the worst: within its clearance less the larger of
    /// `slack` and the worst shortfall so far (a tree search bounded by that distance, from the
    /// face it was nearest when last asked). The answer is that of asking every vertex's signed
    /// distance (the same first vertex of the largest shortfall, the same bits out of
    /// [`ArmClearance::apply`] on five CMU clips, two shapes, with and without the upper arms):
    /// there `apply` took 96 ms a frame, 75 with the hints, 28 without the far vertices'
    /// searches (Intel Xeon VM, release build; 24 with [`ArmClearance::frame_fixes`]). A vertex
    /// farther than that bound from the torso's box is not searched either: of 2.8 million held
    /// vertices two changes of shape on the try-on page looked at (CMU 02_02, two bodies), 2.7
    /// million were searched and 5,600 found a face; now 246,000 are searched, the same bits out
    /// of `apply` (five CMU clips, three shapes, with and without the upper arms), and the page's
    /// change of shape natively 176.6 → 148–151 ms (`cargo bench -p sartor-web --bench seek --
    /// shape`, AMD EPYC VM).
    fn worst(&mut self, a: usize, targets: &ArmTargets, slack: f64) -> (Option<Shortfall>, f64) {
        let d = self.distance.as_ref().expect("posed before");
        let mut worst: Option<Shortfall> = None;
        let mut depth = 0.0f64;
        // Outside the torso's box a vertex is outside the torso (`BodyDistance::bounds`): 95 %
        // of the held vertices of five CMU clips, whose winding numbers were 59 % of the
        // clearance's time.
        let (lo, hi) = d.bounds();
        let culled = &self.culled[a];
        for (&(v, clearance), &g) in targets.list.iter().zip(&targets.group_of) {
            if culled[g as usize] {
                // Unskinned: each of its vertices farther than its reach from the torso's box.
                continue;
            }
            let p = self.posed[v];
            let in_box = (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]);
            let inside = in_box && d.winding_number_fast(&p) > 0.5;
            let floor = worst.as_ref().map_or(slack, |w| w.short);
            // An outside vertex farther than this is no more short than `floor`.
            let reach = if inside {
                f64::INFINITY
            } else {
                clearance - floor
            };
            if reach <= 0.0 {
                continue;
            }
            // Nor is one farther than that from the torso's box, which holds every face.
            let gap2: f64 = (0..3)
                .map(|k| (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0).powi(2))
                .sum();
            if gap2 > reach * reach * (1.0 + 1e-9) {
                continue;
            }
            // (Unbounded, as `BodyDistance::query_hinted`: the whole search if the hinted one
            // finds nothing.)
            let found = d
                .proximity()
                .closest_within_hinted(&p, reach, &mut self.hints[v])
                .or_else(|| inside.then(|| d.proximity().closest(&p)));
            let Some(closest) = found else {
                continue;
            };
            let to_surface = closest.point - p;
            let distance = to_surface.norm();
            let signed = if inside { -distance } else { distance };
            depth = depth.max(-signed);
            let short = clearance - signed;
            if short > floor {
                let out = if inside { to_surface } else { -to_surface };
                worst = Some(Shortfall {
                    short,
                    out: out.try_normalize(1e-12).unwrap_or(closest.normal),
                    vertex: v,
                });
            }
        }
        (worst, depth)
    }
}

/// A held vertex short of its clearance ([`Posing::worst`]).
struct Shortfall {
    /// How far short, m.
    short: f64,
    /// The unit direction that takes it out (or farther out).
    out: Vector3<f64>,
    /// Its body vertex.
    vertex: usize,
}

impl ArmClearance {
    /// Find the arms (forearm and hand vertices by their dominant joint, grouped by the upper
    /// arm above it), the legs (shin, foot and toe vertices, grouped by the thigh above them)
    /// and the torso of `body`.
    pub fn new(body: &BodyModel) -> Result<Self> {
        let skeleton = body.skeleton();
        let names = skeleton.names();
        let dominant: Vec<usize> = (0..body.n_vertices())
            .map(|v| body.skin_weights().dominant_joint(v))
            .collect();
        // The arms first, then the legs: with the legs not held, the arms' turns are those
        // of a body without them, bit for bit.
        let mut arms: Vec<Arm> = Vec::new();
        for leg in [false, true] {
            let (proximal, distal): (JointKind, JointKind) = if leg {
                (thigh, distal_leg)
            } else {
                (upper_arm, distal_arm)
            };
            let pivot = |mut j: usize| loop {
                if proximal(&names[j]) {
                    return Some(j);
                }
                j = skeleton.parents()[j]?;
            };
            let first = arms.len();
            for (v, &j) in dominant.iter().enumerate() {
                let is_distal = distal(&names[j]);
                if !(is_distal || proximal(&names[j])) {
                    continue;
                }
                let Some(shoulder) = pivot(j) else { continue };
                let arm = match arms[first..].iter().position(|a| a.shoulder == shoulder) {
                    Some(a) => &mut arms[first + a],
                    None => {
                        arms.push(Arm {
                            leg,
                            shoulder,
                            swivel: None,
                            vertices: Vec::new(),
                            upper: Vec::new(),
                            moved_torso: Vec::new(),
                            moves_torso: false,
                        });
                        arms.last_mut().expect("pushed")
                    }
                };
                if is_distal {
                    arm.vertices.push(v);
                } else {
                    arm.upper.push(v);
                }
            }
        }
        // A leg's knee and ankle: the hip's child named a leg, and its child named a foot.
        let children =
            |j: usize| (0..names.len()).filter(move |&c| skeleton.parents()[c] == Some(j));
        for arm in arms.iter_mut().filter(|a| a.leg) {
            arm.swivel = children(arm.shoulder)
                .filter(|&k| distal_leg(&names[k]))
                .find_map(|k| Some([k, children(k).find(|&a| names[a].contains("Foot"))?]));
        }
        arms.retain(|a| !a.vertices.is_empty());
        let torso = |v: u32| {
            let name = names[dominant[v as usize]].as_str();
            let trunk = ["Hips", "HipJoint", "LowerBack", "Spine", "Neck", "Shoulder"]
                .iter()
                .any(|k| name.contains(k));
            trunk && !name.contains("Arm") && !distal_arm(name)
        };
        let torso_faces: Vec<[u32; 3]> = body
            .faces()
            .iter()
            .filter(|f| f.iter().all(|&v| torso(v)))
            .copied()
            .collect();
        if arms.iter().all(|a| a.leg) || torso_faces.is_empty() {
            return Err(Error::invalid(
                "arm clearance",
                "the body has no forearm and hand vertices under an upper arm, or no torso",
            ));
        }
        let mut needed: Vec<u32> = torso_faces.iter().flatten().copied().collect();
        for arm in &arms {
            needed.extend(arm.vertices.iter().chain(&arm.upper).map(|&v| v as u32));
        }
        needed.sort_unstable();
        needed.dedup();
        let torso = Torso::new(&torso_faces, body.n_vertices());
        for arm in &mut arms {
            // The shoulder's subtree: joints whose chain of parents reaches it.
            let below = |mut j: usize| loop {
                if j == arm.shoulder {
                    return true;
                }
                match skeleton.parents()[j] {
                    Some(p) => j = p,
                    None => return false,
                }
            };
            let subtree: Vec<bool> = (0..skeleton.n_joints()).map(below).collect();
            arm.moved_torso = torso
                .vertices
                .iter()
                .copied()
                .filter(|&v| {
                    body.skin_weights()
                        .point(v as usize)
                        .any(|(j, _)| subtree[j])
                })
                .collect();
            arm.moves_torso = !arm.moved_torso.is_empty();
        }
        let root = (0..names.len())
            .find(|&j| skeleton.parents()[j].is_none())
            .expect("a skeleton has a root");
        Ok(Self {
            arms,
            root,
            torso,
            needed,
        })
    }

    /// Per pose, the depth of the deepest vertex that `options` holds out (forearms and hands,
    /// with [`ClearanceOptions::upper_arm_clearance_m`] the upper arms beyond the armpit, with
    /// [`ClearanceOptions::leg_clearance_m`] the legs) inside the torso of the body of shape
    /// `betas`, m (0: none inside).
    pub fn depths(
        &self,
        body: &BodyModel,
        betas: &[f64],
        poses: &[Pose],
        options: &ClearanceOptions,
    ) -> Result<Vec<f64>> {
        let mut posing = Posing::new(body, betas)?;
        let targets = self.targets(body, &mut posing, options)?;
        poses
            .iter()
            .map(|pose| {
                posing.pose(body, pose, &self.torso, &targets)?;
                Ok(targets
                    .iter()
                    .enumerate()
                    .map(|(a, t)| posing.worst(a, t, f64::INFINITY).1)
                    .fold(0.0f64, f64::max))
            })
            .collect()
    }

    /// Per arm, the vertices held out of the torso of `posing`'s shape and their clearance:
    /// every forearm and hand vertex at `clearance_m`; with `upper_arm_clearance_m`, the upper
    /// arm's vertices at least [`UPPER_ARM_MIN_LEVER`] of its length from the shoulder and
    /// clear of the torso in the rest pose by that clearance and [`UPPER_ARM_REST_SLACK_M`];
    /// with `leg_clearance_m`, per leg the shin, foot and toe vertices and the thigh's (chosen
    /// as the upper arm's) at it. Without, a leg holds none (and costs next to nothing).
    fn targets(
        &self,
        body: &BodyModel,
        posing: &mut Posing,
        options: &ClearanceOptions,
    ) -> Result<Targets> {
        // Per limb, the clearance of its distal vertices and of its upper part's.
        let clearances: Vec<(Option<f64>, Option<f64>)> = (self.arms.iter())
            .map(|a| match a.leg {
                false => (Some(options.clearance_m), options.upper_arm_clearance_m),
                true => (options.leg_clearance_m, options.leg_clearance_m),
            })
            .collect();
        let mut lists: Vec<Vec<(usize, f64)>> = (self.arms.iter().zip(&clearances))
            .map(|(a, &(distal, _))| match distal {
                Some(c) => a.vertices.iter().map(|&v| (v, c)).collect(),
                None => Vec::new(),
            })
            .collect();
        if clearances.iter().any(|c| c.1.is_some()) {
            let skeleton = body.skeleton();
            let parents = skeleton.parents();
            posing.pose_all(
                body,
                &Pose::rest(skeleton.n_joints()),
                &self.torso,
                &self.needed,
            )?;
            let joints = posing.poser.posed_joints();
            let distance = posing.distance.as_ref().expect("posed");
            for ((arm, list), &(_, upper)) in self.arms.iter().zip(&mut lists).zip(&clearances) {
                let Some(upper) = upper else { continue };
                // The elbow (knee): the farthest child of the shoulder (hip).
                let shoulder = joints[arm.shoulder];
                let length = (0..parents.len())
                    .filter(|&c| parents[c] == Some(arm.shoulder))
                    .map(|c| (joints[c] - shoulder).norm())
                    .fold(0.0, f64::max);
                list.extend(
                    arm.upper
                        .iter()
                        .filter(|&&v| {
                            let p = posing.posed[v];
                            (p - shoulder).norm() >= UPPER_ARM_MIN_LEVER * length
                                && distance.query(&p).signed_distance_m
                                    >= upper + UPPER_ARM_REST_SLACK_M
                        })
                        .map(|&v| (v, upper)),
                );
            }
        }
        // The groups, from the shaped rest pose (not posed through `posing`, whose torso
        // tree is built at its first pose).
        let rest = body.shaped_vertices(&posing.betas)?;
        let weights = body.skin_weights();
        Ok(lists
            .into_iter()
            .map(|list| {
                let mut joint_group: Vec<(usize, usize)> = Vec::new();
                let mut groups: Vec<Group> = Vec::new();
                let group_of = list
                    .iter()
                    .map(|&(v, clearance)| {
                        let dominant = weights.dominant_joint(v);
                        let g = match joint_group.iter().find(|(j, _)| *j == dominant) {
                            Some(&(_, g)) => g,
                            None => {
                                joint_group.push((dominant, groups.len()));
                                groups.push(Group {
                                    vertices: Vec::new(),
                                    joints: Vec::new(),
                                    center: Vector3::zeros(),
                                    half: Vector3::zeros(),
                                    clearance: 0.0,
                                });
                                groups.len() - 1
                            }
                        };
                        let group = &mut groups[g];
                        group.vertices.push(v as u32);
                        group.clearance = group.clearance.max(clearance);
                        for (j, _) in weights.point(v) {
                            if !group.joints.contains(&j) {
                                group.joints.push(j);
                            }
                        }
                        u16::try_from(g).expect("fewer groups than joints")
                    })
                    .collect();
                for group in &mut groups {
                    group.vertices.sort_unstable();
                    let (lo, hi) = group.vertices.iter().fold(
                        (
                            Vector3::repeat(f64::INFINITY),
                            Vector3::repeat(f64::NEG_INFINITY),
                        ),
                        |(lo, hi), &v| (lo.inf(&rest[v as usize]), hi.sup(&rest[v as usize])),
                    );
                    group.center = (lo + hi) * 0.5;
                    group.half = (hi - lo) * 0.5 + Vector3::repeat(GROUP_PAD_M);
                }
                ArmTargets {
                    list,
                    group_of,
                    groups,
                }
            })
            .collect())
    }

    /// `poses` with the forearms and hands moved out of the torso of shape `betas` (see the
    /// [module docs](self)), and what changed.
    pub fn apply(
        &self,
        body: &BodyModel,
        betas: &[f64],
        poses: &[Pose],
        options: &ClearanceOptions,
    ) -> Result<(Vec<Pose>, ClearanceReport)> {
        options.validate()?;
        let mut posing = Posing::new(body, betas)?;
        let targets = self.targets(body, &mut posing, options)?;
        let mut out = poses.to_vec();
        // Per arm and frame, the total correction: a rotation vector in the frame of the upper
        // arm's parent, applied before the upper arm's own local rotation.
        let mut total = vec![vec![Vector3::<f64>::zeros(); poses.len()]; self.arms.len()];
        let mut report = ClearanceReport::default();
        // The deepest held vertex of the poses as they come out, when a pass over them found
        // nothing to turn (it measured them).
        let mut depth_after = None;
        for pass in 0..options.max_passes.max(1) {
            let mut needed = vec![vec![Vector3::<f64>::zeros(); poses.len()]; self.arms.len()];
            let mut any = false;
            let mut depth = 0.0f64;
            for (t, pose) in out.iter().enumerate() {
                let fixes = self.frame_fixes(body, &mut posing, pose, &targets, options)?;
                for (a, (fix, depth_before)) in fixes.into_iter().enumerate() {
                    depth = depth.max(depth_before);
                    if let Some(r) = fix {
                        needed[a][t] = r;
                        any = true;
                    }
                }
            }
            if pass == 0 {
                report.max_depth_before_m = depth;
            }
            if !any {
                depth_after = Some(depth);
                break;
            }
            for (a, needed) in needed.iter().enumerate() {
                let eased = ease(needed, options.ramp_frames);
                for (t, r) in eased.into_iter().enumerate() {
                    total[a][t] = compose(&r, &total[a][t]);
                }
            }
            out = self.corrected(poses, &total);
        }
        report.frames_changed = (0..poses.len())
            .filter(|&t| total.iter().any(|arm| arm[t] != Vector3::zeros()))
            .count();
        report.max_angle_rad = total.iter().flatten().map(|r| r.norm()).fold(0.0, f64::max);
        report.max_depth_after_m = match depth_after {
            Some(depth) => depth,
            None => self
                .depths(body, betas, &out, options)?
                .into_iter()
                .fold(0.0, f64::max),
        };
        Ok((out, report))
    }

    /// `poses` with each arm's correction put before its upper arm's local rotation; frames
    /// without one are the input's.
    fn corrected(&self, poses: &[Pose], total: &[Vec<Vector3<f64>>]) -> Vec<Pose> {
        let mut out = poses.to_vec();
        for (t, pose) in out.iter_mut().enumerate() {
            self.correct(pose, total.iter().map(|arm| &arm[t]));
        }
        out
    }

    /// `pose` with each arm's correction (in the order of `self.arms`) put before its upper
    /// arm's local rotation ([`turn`]).
    fn correct<'r>(&self, pose: &mut Pose, per_arm: impl IntoIterator<Item = &'r Vector3<f64>>) {
        for (arm, r) in self.arms.iter().zip(per_arm) {
            turn(pose, arm, r);
        }
    }

    /// Per arm, [`ArmClearance::frame_fix`] at `pose`: the body posed once for every arm's
    /// first look, and again only where an arm that turned left it posed otherwise. With the
    /// last pass's measure standing for the final check where it turned nothing, a clip that
    /// needs no turn is posed once a frame instead of three times: CMU 05_06 (60 frames) 43 →
    /// 2.7 ms a frame, clips that need turning 28 → 24 ms (same bits).
    fn frame_fixes(
        &self,
        body: &BodyModel,
        posing: &mut Posing,
        pose: &Pose,
        targets: &Targets,
        options: &ClearanceOptions,
    ) -> Result<Vec<(Option<Vector3<f64>>, f64)>> {
        posing.pose(body, pose, &self.torso, targets)?;
        let firsts: Vec<_> = (targets.iter().enumerate())
            .map(|(a, t)| posing.worst(a, t, SLACK_M))
            .collect();
        let mut at_pose = true;
        let mut fixes = Vec::with_capacity(self.arms.len());
        for (a, (arm, worst_depth)) in self.arms.iter().zip(firsts).enumerate() {
            let (Some(worst), depth) = worst_depth else {
                fixes.push((None, worst_depth.1));
                continue;
            };
            if !at_pose {
                posing.pose(body, pose, &self.torso, targets)?;
            }
            let (fix, posed_again) =
                self.frame_fix(body, posing, pose, (a, arm), targets, worst, options)?;
            at_pose &= !posed_again;
            fixes.push((fix, depth));
        }
        Ok(fixes)
    }

    /// The rotation (vector, in the upper arm's parent frame) that takes arm `a`'s held
    /// vertices (of `targets`) their clearance out of the torso in `pose`, starting from `posing` posed at
    /// `pose` and the worst of them there (more than [`SLACK_M`] short), `None` if it cannot
    /// turn; and whether it posed the body otherwise.
    fn frame_fix(
        &self,
        body: &BodyModel,
        posing: &mut Posing,
        pose: &Pose,
        (a, arm): (usize, &Arm),
        targets: &Targets,
        worst: Shortfall,
        options: &ClearanceOptions,
    ) -> Result<(Option<Vector3<f64>>, bool)> {
        let j = arm.shoulder;
        let parent = body.skeleton().parents()[j];
        let mut trial = pose.clone();
        let mut world = UnitQuaternion::identity();
        let mut local = UnitQuaternion::identity();
        let mut worst = Some(worst);
        let mut posed_again = false;
        // A leg's swing of the knee so far, radians.
        let mut swivel = 0.0;
        for iteration in 0..options.max_iterations.max(1) {
            if iteration > 0 {
                posing.pose_turned(body, &trial, (a, arm), &self.torso, &targets[a])?;
                posed_again = true;
                worst = posing.worst(a, &targets[a], SLACK_M).0;
            }
            let Some(Shortfall {
                short,
                out,
                vertex: v,
            }) = worst.take()
            else {
                break;
            };
            let joints = posing.poser.posed_joints();
            let lever = posing.posed[v] - joints[j];
            // Turning by α about a unit axis `a` through the shoulder moves the vertex
            // α·(a × lever) (to first order): an arm turns about `lever × out`, which moves it
            // by α·|lever × out| along `out`; a leg about the line from its hip to its ankle.
            let free = || {
                let axis = lever.cross(&out);
                let reach = axis.norm();
                (axis / reach, reach)
            };
            let (axis, reach) = match arm.swivel {
                None => free(),
                Some([knee, ankle]) => {
                    // The knee swung outwards about the line from hip to ankle while that takes
                    // the vertex out, up to `SWIVEL_MAX_RAD`; then the leg turned freely.
                    let a = (joints[ankle] - joints[j]).normalize();
                    let rate = a.cross(&lever).dot(&out);
                    let knee_moves = a.cross(&(joints[knee] - joints[j])) * rate.signum();
                    let outwards = knee_moves.dot(&(joints[j] - joints[self.root])) > 0.0;
                    let step = (short / rate.abs()).min(MAX_STEP_RAD);
                    if outwards && rate.abs() >= 1e-3 && swivel + step <= SWIVEL_MAX_RAD {
                        swivel += step;
                        (a * rate.signum(), rate.abs())
                    } else {
                        free()
                    }
                }
            };
            if reach < 1e-3 || !reach.is_finite() {
                break;
            }
            let angle = (short / reach).min(MAX_STEP_RAD);
            world = UnitQuaternion::from_scaled_axis(axis * angle) * world;
            let over = world.angle() - options.max_angle_rad;
            if over > 0.0 {
                // Clamp to the largest rotation and stop.
                world = UnitQuaternion::from_scaled_axis(
                    world.scaled_axis() * (options.max_angle_rad / world.angle()),
                );
            }
            let parent_world = parent_rotation(posing, pose, parent);
            local = parent_world.inverse() * world * parent_world;
            match arm.swivel {
                None => trial.local_rotations[j] = local * pose.local_rotations[j],
                Some([_, ankle]) => {
                    // As `correct` will turn it.
                    for k in [j, ankle] {
                        trial.local_rotations[k] = pose.local_rotations[k];
                    }
                    turn(&mut trial, arm, &local.scaled_axis());
                }
            }
            if over > 0.0 {
                break;
            }
        }
        if local.angle() == 0.0 {
            return Ok((None, posed_again));
        }
        Ok((Some(local.scaled_axis()), posed_again))
    }
}

/// Arm `arm`'s correction `r` (a rotation vector in the frame of its upper arm's parent) put
/// before its upper arm's local rotation in `pose`. A leg's foot turns back by as much: with the
/// knee's world rotation `W = P H K` turned by the hip's `T` (in the hip's parent frame:
/// `W' = P T H K`), the foot's local rotation `(H K)⁻¹ T⁻¹ (H K) F` keeps its world rotation
/// `W F`; and a turn about the line from hip to ankle keeps the ankle where it was.
fn turn(pose: &mut Pose, arm: &Arm, r: &Vector3<f64>) {
    if *r == Vector3::zeros() {
        return;
    }
    let j = arm.shoulder;
    let t = UnitQuaternion::from_scaled_axis(*r);
    if let Some([knee, ankle]) = arm.swivel {
        let hip_knee = pose.local_rotations[j] * pose.local_rotations[knee];
        let foot = &mut pose.local_rotations[ankle];
        *foot = hip_knee.inverse() * t.inverse() * hip_knee * *foot;
    }
    let q = &mut pose.local_rotations[j];
    *q = t * *q;
}

/// The world rotation of joint `parent` (the root orientation for none) in the last posing.
fn parent_rotation(posing: &Posing, pose: &Pose, parent: Option<usize>) -> UnitQuaternion<f64> {
    parent.map_or(pose.root_orientation, |p| {
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
            posing.poser.transforms()[p].linear,
        ))
    })
}

/// `a` after `b`, as a rotation vector.
fn compose(a: &Vector3<f64>, b: &Vector3<f64>) -> Vector3<f64> {
    if *b == Vector3::zeros() {
        return *a;
    }
    if *a == Vector3::zeros() {
        return *b;
    }
    (UnitQuaternion::from_scaled_axis(*a) * UnitQuaternion::from_scaled_axis(*b)).scaled_axis()
}

/// Per frame, the correction eased over `ramp` frames each side, in two steps: a dilation (the
/// neighbour, itself included, whose correction scaled by `1 − |Δt| / (ramp + 1)` is largest,
/// so scaled), so that a correction is reached gradually; then a moving average over
/// `ramp / 2` frames each side, so that neighbouring frames' corrections of different axes
/// blend instead of switching. The average can leave a frame short of its own correction;
/// [`ArmClearance::apply`]'s next pass adds what is missing. Frames farther than
/// `ramp + ramp / 2` from every corrected frame get none.
fn ease(needed: &[Vector3<f64>], ramp: usize) -> Vec<Vector3<f64>> {
    let dilated: Vec<Vector3<f64>> = (0..needed.len())
        .map(|t| dilated_at(|s| needed[s], needed.len(), t, ramp))
        .collect();
    (0..needed.len())
        .map(|t| eased_at(|s| dilated[s], needed.len(), t, ramp))
        .collect()
}

/// Frames `t − half ..= t + half` of `0..len`.
fn window(len: usize, t: usize, half: usize) -> std::ops::Range<usize> {
    t.saturating_sub(half)..(t + half + 1).min(len)
}

/// [`ease`]'s dilation at frame `t` of `len` frames, from each frame's correction `needed`.
fn dilated_at(
    needed: impl Fn(usize) -> Vector3<f64>,
    len: usize,
    t: usize,
    ramp: usize,
) -> Vector3<f64> {
    window(len, t, ramp)
        .map(|s| needed(s) * (1.0 - t.abs_diff(s) as f64 / (ramp + 1) as f64))
        .max_by(|a, b| a.norm().total_cmp(&b.norm()))
        .unwrap_or_else(Vector3::zeros)
}

/// [`ease`]'s moving average at frame `t` of `len` frames, from each frame's dilation.
fn eased_at(
    dilated: impl Fn(usize) -> Vector3<f64>,
    len: usize,
    t: usize,
    ramp: usize,
) -> Vector3<f64> {
    let w = window(len, t, ramp / 2);
    let n = w.len() as f64;
    let sum: Vector3<f64> = w.map(dilated).sum();
    if sum == Vector3::zeros() {
        sum
    } else {
        sum / n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;
    use std::path::PathBuf;

    thread_local! {
        /// Set by a test on its own thread: every group is skinned and looked at.
        pub(super) static NO_CULLING: Cell<bool> = const { Cell::new(false) };
    }

    fn data(path: &str) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../datasets")
            .join(path)
    }

    /// A real clip at two shapes beyond the training range, the upper arms held too: the
    /// groups' boxes hold every held vertex as skinned in each pose of the clip, and `apply`
    /// with the groups culled (its fixes' trial poses too) gives the poses and report of
    /// `apply` skinning and looking at every held vertex, bit for bit.
    #[test]
    fn culled_groups_hold_their_vertices_and_change_no_bit() {
        use crate::{MotionSourceOptions, RetargetBody, load_motion};
        let body = BodyModel::load(&data("body/makehuman")).expect("built-in body");
        let options = MotionSourceOptions {
            motions_dir: data("motions"),
            body: Some(RetargetBody::load(&data("body/makehuman")).expect("body")),
            ..MotionSourceOptions::default()
        };
        let clip = load_motion("cmu/02_02@8+30", &options).expect("clip");
        let clearance = ArmClearance::new(&body).expect("arms");
        let held = ClearanceOptions {
            upper_arm_clearance_m: Some(0.005),
            ..ClearanceOptions::default()
        };
        let mut culled = 0;
        for betas in [vec![0.0, 2.5], vec![3.0, -2.0, 1.0]] {
            let mut posing = Posing::new(&body, &betas).expect("posing");
            let targets = clearance
                .targets(&body, &mut posing, &held)
                .expect("targets");
            let mut all = Posing::new(&body, &betas).expect("posing");
            for pose in clip.frames() {
                posing
                    .pose(&body, pose, &clearance.torso, &targets)
                    .expect("pose");
                all.pose_all(&body, pose, &clearance.torso, &clearance.needed)
                    .expect("pose");
                let transforms = posing.poser.transforms();
                for (a, t) in targets.iter().enumerate() {
                    for (g, group) in t.groups.iter().enumerate() {
                        culled += usize::from(posing.culled[a][g]);
                        for &v in &group.vertices {
                            let p = all.posed[v as usize];
                            let inside = group.joints.iter().fold(
                                (
                                    Vector3::repeat(f64::INFINITY),
                                    Vector3::repeat(f64::NEG_INFINITY),
                                ),
                                |(lo, hi), &j| {
                                    let c = transforms[j].linear * group.center
                                        + transforms[j].translation;
                                    let h = transforms[j].linear.abs() * group.half;
                                    (lo.inf(&(c - h)), hi.sup(&(c + h)))
                                },
                            );
                            assert!(
                                (0..3).all(|k| p[k] >= inside.0[k] && p[k] <= inside.1[k]),
                                "vertex {v} outside its group's box"
                            );
                        }
                    }
                }
            }
            let (poses, report) = clearance
                .apply(&body, &betas, clip.frames(), &held)
                .expect("apply");
            NO_CULLING.with(|c| c.set(true));
            let (poses_all, report_all) = clearance
                .apply(&body, &betas, clip.frames(), &held)
                .expect("apply");
            NO_CULLING.with(|c| c.set(false));
            assert_eq!(report, report_all);
            for (p, q) in poses.iter().zip(&poses_all) {
                for (r, s) in p.local_rotations.iter().zip(&q.local_rotations) {
                    assert_eq!(r.coords.map(f64::to_bits), s.coords.map(f64::to_bits));
                }
            }
        }
        // Most groups lie far from the torso in most poses: the test would pass vacuously
        // were none culled.
        assert!(culled > 0, "no group culled");
    }

    #[test]
    fn easing_ramps_in_and_out_and_reaches_no_farther() {
        let mut needed = vec![Vector3::zeros(); 15];
        needed[7] = Vector3::new(0.0, 0.0, 0.4);
        let eased = ease(&needed, 4);
        let z: Vec<f64> = eased.iter().map(|r| r.z).collect();
        // Reach: 4 + 2 frames each side.
        assert_eq!(z[0], 0.0, "{z:?}");
        assert_eq!(z[14], 0.0, "{z:?}");
        assert!(z[1] > 0.0 && z[13] > 0.0, "{z:?}");
        for t in 0..7 {
            assert!((z[t] - z[14 - t]).abs() < 1e-12, "symmetric: {z:?}");
            assert!(z[t] < z[t + 1], "rising: {z:?}");
        }
        // The average keeps most of the peak (the tent's mean over ±2 frames: 0.4 · 0.76).
        assert!((z[7] - 0.4 * 0.76).abs() < 1e-12, "{z:?}");
        assert!(
            ease(&[Vector3::zeros(); 5], 4)
                .iter()
                .all(|r| *r == Vector3::zeros())
        );
    }

    #[test]
    fn composing_rotation_vectors_matches_quaternions() {
        let a = Vector3::new(0.3, -0.1, 0.2);
        let b = Vector3::new(-0.2, 0.4, 0.1);
        let q = UnitQuaternion::from_scaled_axis(compose(&a, &b));
        let want = UnitQuaternion::from_scaled_axis(a) * UnitQuaternion::from_scaled_axis(b);
        assert!(q.angle_to(&want) < 1e-12);
        assert_eq!(compose(&a, &Vector3::zeros()), a);
    }
}
