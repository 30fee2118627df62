//! [`TryOn`]: one avatar of a shipped garment model on the body, driven by the page — a
//! body shape (phenotype sliders or β), a motion (procedural, stored mocap, the walk cycle or a
//! dropped BVH), a frame to show, and the garment model worn ([`TryOn::set_garment`]). Plain
//! Rust, tested natively; `js.rs` only converts types.
//!
//! Every frame runs [`GarmentAnimator::frame`] (network, skinning, post-process, sequential:
//! there are no threads in the browser) and poses the whole body for display with the one
//! skinning kernel (`sartor_core::skin_points`). Stage times come from the clock given at load
//! (`performance.now()` on the page).

use std::path::Path;
use std::sync::Arc;

use nalgebra::Vector3;
use sartor_core::{
    BodyMeasurements, BodyMeasurer, BodyModel, BoneTransform, FPS, Parallelism, PartialPhenotype,
    Phenotype, PhenotypeRequest, PhenotypeSpace, Pose, skin_points,
};
use sartor_motion::{
    ArmClearance, BvhRetargetOptions, ClearanceOnDemand, ClearanceOptions, ClearanceProgress,
    Motion, RetargetBody, TPOSE_FILE, procedural, retarget_bvh, stored_clip_from_bytes,
};
use sartor_runtime::{
    AnimatorOptions, CollisionOptions, GarmentAnimator, GarmentBinding, GarmentModel,
    GarmentNetwork, GarmentRig, NetworkOptions, Precision, StageTimes, StrainLimit,
};

use crate::error::{Error, Result};
use crate::files::FileSet;
use crate::post::{PostAnswer, PostJob};

/// Frames run before the shown one after a jump (scrubbing, a new shape): the GRU starts from
/// a zero state at the jump, as a training sequence does, and these frames let its wrinkles
/// build up (half a second at 30 fps).
pub const WARMUP_FRAMES: usize = 15;

/// What [`TryOn::load`] sets up besides the files.
#[derive(Clone, Debug)]
pub struct TryOnOptions {
    /// Precision of the weights in memory (the page's files are f16 on the wire; `F32` computes
    /// with exactly those values).
    pub precision: Precision,
    /// The collision post-process (on by default), the cloth triangles pushed out as well as
    /// the vertices (`CollisionOptions::faces`), after the strain limit (`StrainLimit`'s
    /// default: no garment edge beyond 1.5× its rest length).
    pub post_process: bool,
    /// A monotonic clock in milliseconds that times each stage (`None`: no timing).
    pub clock: Option<fn() -> f64>,
    /// The arms held out of the torso of the body's shape, as the model's training motions
    /// held them (its experiment's `simulation.arm_clearance`; the page reads it from
    /// `manifest.json`), or `None` (the default): motions played as they come. Mocap retargeted
    /// onto a wider body sinks hands and upper arms into the torso, and the shirt between ends
    /// inside the body (see the README). Computed frame by frame as frames are shown
    /// ([`ClearanceOnDemand`]), anew for each motion and shape.
    pub arm_clearance: Option<ClearanceOptions>,
}

impl Default for TryOnOptions {
    fn default() -> Self {
        Self {
            precision: Precision::F32,
            post_process: true,
            clock: None,
            arm_clearance: None,
        }
    }
}

/// What a garment's animator is built with ([`TryOnOptions`] less the arms): kept, so that
/// [`TryOn::set_garment`] builds another one alike.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GarmentOptions {
    pub(crate) precision: Precision,
    pub(crate) post_process: bool,
    pub(crate) clock: Option<fn() -> f64>,
}

impl GarmentOptions {
    /// The animator of the garment model in `files` ([`crate::MODEL_FILES`]) on `body`, at
    /// β = 0.
    pub(crate) fn animator(
        &self,
        files: &mut FileSet,
        body: &Arc<BodyModel>,
    ) -> Result<GarmentAnimator> {
        let model_dir = Path::new("model");
        let model = GarmentModel::from_bytes(
            model_dir,
            &files.take("model/model.json")?,
            files.take("model/model.safetensors")?,
        )?;
        let network = GarmentNetwork::with_options(
            model,
            NetworkOptions {
                precision: self.precision,
                output_rank: None,
            },
        )?;
        let binding = GarmentBinding::from_bytes(
            model_dir,
            &files.take("model/binding.json")?,
            files.take("model/binding.safetensors")?,
        )?;
        let animator_options = AnimatorOptions {
            // Edges stretched beyond 1.5× pulled back first: with the arms up the armpit
            // otherwise tears open (see `StrainLimit`).
            strain_limit: self.post_process.then(StrainLimit::default),
            // The triangles pushed out too: on a raised arm the shoulders otherwise show through
            // the sleeves between cloth vertices (see `CollisionOptions::faces`).
            collision: self.post_process.then(|| CollisionOptions {
                faces: true,
                ..CollisionOptions::default()
            }),
            parallelism: Parallelism::Sequential,
            ..AnimatorOptions::default()
        };
        let rig = Arc::new(GarmentRig::new(
            Arc::new(network),
            Arc::new(binding),
            body.clone(),
            animator_options,
        )?);
        let mut animator = GarmentAnimator::new(rig)?;
        animator.set_stage_clock(self.clock);
        Ok(animator)
    }
}

/// Where the last frame spent its time, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameTimes {
    /// The garment's stages (network, skinning, post-process).
    pub garment: StageTimes,
    /// Posing the whole body for display (not part of the garment model's cost).
    pub body_ms: f64,
    /// Holding the arms out of the torso ([`TryOnOptions::arm_clearance`]): the poses of the
    /// frame shown and of the frames run before it after a jump, as far as not computed before.
    pub arms_ms: f64,
}

/// The slider values of the page's phenotype panel: the command line's phenotype rule
/// (`sartor_core::PhenotypeSpace::betas_for`) with every slider given and the height in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhenotypeSliders {
    /// 0 female … 1 male.
    pub gender: f64,
    /// Standing height, metres (solved on MakeHuman's height slider).
    pub height_m: f64,
    /// 0 minimum, 0.5 average, 1 maximum weight.
    pub weight: f64,
    /// 0 minimum, 0.5 average, 1 maximum muscle.
    pub muscle: f64,
    /// Age in years (1 to 90).
    pub age_years: f64,
}

impl PhenotypeSliders {
    /// The request the command line would build from the same values.
    pub fn request(&self) -> Result<PhenotypeRequest> {
        let slider = |name: &str, v: f64| {
            if v.is_finite() && (0.0..=1.0).contains(&v) {
                Ok(v)
            } else {
                Err(Error::invalid(
                    "phenotype",
                    format!("{name} is {v}, expected a value in [0, 1]"),
                ))
            }
        };
        if !self.height_m.is_finite() {
            return Err(Error::invalid(
                "phenotype",
                format!("height is {} m", self.height_m),
            ));
        }
        Ok(PhenotypeRequest {
            sliders: PartialPhenotype {
                gender: Some(slider("gender", self.gender)?),
                weight: Some(slider("weight", self.weight)?),
                muscle: Some(slider("muscle", self.muscle)?),
                age: Some(Phenotype::age_slider_from_years(self.age_years)?),
                ..PartialPhenotype::default()
            },
            height_m: Some(self.height_m),
            measurements: Default::default(),
        })
    }
}

/// The body posed each frame for display: shaped rest vertices and buffers.
#[derive(Debug)]
struct PosedBody {
    shaped: Vec<Vector3<f32>>,
    rest_joints: Vec<Vector3<f64>>,
    joints: Vec<Vector3<f64>>,
    transforms: Vec<BoneTransform<f64>>,
    transforms_f32: Vec<BoneTransform<f32>>,
    vertices: Vec<Vector3<f32>>,
}

impl PosedBody {
    fn new(body: &BodyModel, betas: &[f64]) -> Result<Self> {
        let shaped: Vec<Vector3<f32>> = body
            .shaped_vertices(betas)?
            .iter()
            .map(|p| p.cast::<f32>())
            .collect();
        let n_joints = body.skeleton().n_joints();
        Ok(Self {
            vertices: shaped.clone(),
            shaped,
            rest_joints: body.shaped_joints(betas)?,
            joints: vec![Vector3::zeros(); n_joints],
            transforms: vec![BoneTransform::identity(); n_joints],
            transforms_f32: vec![BoneTransform::identity(); n_joints],
        })
    }

    fn pose(&mut self, body: &BodyModel, pose: &Pose) -> Result<()> {
        body.skeleton().forward_kinematics_into(
            &self.rest_joints,
            pose,
            &mut self.joints,
            &mut self.transforms,
        )?;
        for (t32, t) in self.transforms_f32.iter_mut().zip(&self.transforms) {
            *t32 = t.to_f32();
        }
        skin_points(
            &self.shaped,
            body.skin_weights(),
            &self.transforms_f32,
            &mut self.vertices,
            Parallelism::Sequential,
        )?;
        Ok(())
    }
}

/// The try-on: assets, one avatar, the motion and the frame shown.
#[derive(Debug)]
pub struct TryOn {
    body: Arc<BodyModel>,
    space: PhenotypeSpace,
    retarget: RetargetBody,
    animator: GarmentAnimator,
    /// β of the body and the garment: the model's components (the rest of the body's are 0).
    betas: Vec<f64>,
    posed_body: PosedBody,
    motion: Motion,
    /// The body's arms and torso and the options, with [`TryOnOptions::arm_clearance`].
    arms: Option<(ArmClearance, ClearanceOptions)>,
    /// The motion's poses with the arms held out for the shape `held_for`, as far as computed.
    cleared: Option<ClearanceOnDemand>,
    /// The model's β the arms of `cleared` are held for: `betas`, but after a preview
    /// ([`TryOn::preview_betas`]) until [`TryOn::settle`] holds them anew.
    held_for: Vec<f64>,
    /// The arms being held anew for `betas` by [`TryOn::settle`], as far as computed (`None`:
    /// not begun).
    settling: Option<ClearanceOnDemand>,
    /// A motion that plays once [`TryOn::settle`] has held its first frames
    /// ([`TryOn::begin_motion`]), and its held arms for `betas` as far as computed.
    next_motion: Option<(Motion, Option<ClearanceOnDemand>)>,
    frame: usize,
    clock: Option<fn() -> f64>,
    /// How the garment's animator was built (for [`TryOn::set_garment`]).
    garment: GarmentOptions,
    times: FrameTimes,
    /// Milliseconds spent on the arms since the last frame shown.
    arms_ms: f64,
    /// The arm clearance's largest shoulder rotation in the frame shown, radians.
    arm_turn_rad: f64,
    /// The body's measurer (`None` where the body has no arms or midline to measure by: then
    /// [`Self::measurements`] says why).
    measurer: Option<BodyMeasurer>,
    /// The fingerprint of the poses the last job given with poses carried
    /// ([`TryOn::arms_job`]): a worker that took every job holds them, so a job of the same
    /// motion names them instead.
    worker_motion: Option<u64>,
    /// Post-process jobs handed out ([`TryOn::step_deferred`]).
    post_jobs: u64,
    /// The id of the job whose answer makes the frame shown, while none was taken up.
    post_pending: Option<u64>,
}

/// Compute in `held`, taking at most `max_looks` looks, the poses [`TryOn::seek`] asks of a
/// jump to `frame` (the frame before the warm-up, the warm-up frames and `frame`): whether all
/// of them are computed.
fn prepare_jump(
    held: &mut ClearanceOnDemand,
    body: &BodyModel,
    frame: usize,
    max_looks: usize,
) -> Result<bool> {
    prepare_frames(held, body, jump_frames(frame), max_looks)
}

/// Compute in `held`, taking at most `max_looks` looks, the poses of `frames`: whether all of
/// them are computed.
pub(crate) fn prepare_frames(
    held: &mut ClearanceOnDemand,
    body: &BodyModel,
    frames: std::ops::Range<usize>,
    max_looks: usize,
) -> Result<bool> {
    let mut left = max_looks;
    for t in frames {
        let looks = held.looks();
        if !held.prepare(body, t, left)? {
            return Ok(false);
        }
        left -= held.looks() - looks;
    }
    Ok(true)
}

/// `held`'s job of preparing `frames` for a worker, as bytes: with the poses unless the last job
/// that carried poses (`worker_motion`, updated) carried these.
fn job_for(
    held: &ClearanceOnDemand,
    frames: std::ops::Range<usize>,
    worker_motion: &mut Option<u64>,
) -> Vec<u8> {
    let motion = held.motion_fingerprint();
    let job = held.job(frames, *worker_motion != Some(motion));
    *worker_motion = Some(motion);
    job.to_bytes()
}

/// The body model of the body folder's files.
pub(crate) fn load_body(files: &mut FileSet) -> Result<BodyModel> {
    Ok(BodyModel::from_bytes(
        Path::new("body"),
        &files.take("body/model.json")?,
        files.take("body/model.safetensors")?,
    )?)
}

/// The frames [`TryOn::seek`] poses for a jump to `frame`: the frame before the warm-up, the
/// warm-up frames and `frame`.
fn jump_frames(frame: usize) -> std::ops::Range<usize> {
    frame.saturating_sub(WARMUP_FRAMES).saturating_sub(1)..frame + 1
}

/// The model's β as its animator is set to them.
fn shape32(betas: &[f64]) -> Vec<f32> {
    betas.iter().map(|&b| b as f32).collect()
}

/// Flatten points into `x, y, z, x, y, z, …`.
fn flat(points: &[Vector3<f32>]) -> Vec<f32> {
    points.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
}

impl TryOn {
    /// Load the model folder's and the body folder's files (names in [`crate::MODEL_FILES`]
    /// and [`crate::BODY_FILES`]), check that they belong together, and show the template body
    /// (β = 0) standing still.
    pub fn load(mut files: FileSet, options: TryOnOptions) -> Result<Self> {
        let body_dir = Path::new("body");
        let body = Arc::new(load_body(&mut files)?);
        let space = PhenotypeSpace::from_bytes(
            body_dir,
            &files.take("body/phenotype.json")?,
            files.take("body/phenotype.safetensors")?,
        )?;
        let tpose_path = body_dir.join(TPOSE_FILE);
        let tpose: Pose = serde_json::from_slice(&files.take("body/tpose.json")?)
            .map_err(|e| sartor_core::Error::parse(&tpose_path, e.line(), e.to_string()))?;
        tpose
            .validate(body.skeleton().n_joints())
            .map_err(|e| e.in_file(&tpose_path))?;
        let rest = body.shaped_joints(&vec![0.0; body.n_betas()])?;
        let retarget = RetargetBody::new(body.skeleton().clone(), rest, tpose)?;
        let garment = GarmentOptions {
            precision: options.precision,
            post_process: options.post_process,
            clock: options.clock,
        };
        let animator = garment.animator(&mut files, &body)?;
        let betas = vec![0.0; animator.rig().network().n_betas()];
        let posed_body = PosedBody::new(&body, &Self::body_betas(&body, &betas))?;
        let still = Motion::new(
            "rest".into(),
            FPS,
            body.skeleton().names().to_vec(),
            vec![Pose::rest(body.skeleton().n_joints())],
        )?;
        let arms = match options.arm_clearance {
            Some(clearance) => {
                clearance.validate()?;
                Some((ArmClearance::new(&body)?, clearance))
            }
            None => None,
        };
        let measurer = BodyMeasurer::new(&body).ok();
        let mut try_on = Self {
            measurer,
            body,
            space,
            retarget,
            animator,
            held_for: betas.clone(),
            betas,
            posed_body,
            motion: still,
            arms,
            cleared: None,
            settling: None,
            next_motion: None,
            frame: 0,
            clock: options.clock,
            garment,
            times: FrameTimes::default(),
            arms_ms: 0.0,
            arm_turn_rad: 0.0,
            worker_motion: None,
            post_jobs: 0,
            post_pending: None,
        };
        try_on.cleared = try_on.clearance_for(&try_on.motion, &try_on.betas)?;
        try_on.seek(0)?;
        Ok(try_on)
    }

    /// Wear another garment model (the model folder's files, [`crate::MODEL_FILES`]: another
    /// resolution of the garment, say) on the body shown, built with the options given at load.
    /// The shape, the motion, its held arms (they belong to the body, not the garment) and the
    /// frame stay; the new garment's frame is computed as a jump to it ([`TryOn::seek`]). The
    /// model must take as many β components as the one worn (the body's shape is the model's
    /// β). An error leaves the garment worn as it was.
    pub fn set_garment(&mut self, mut files: FileSet) -> Result<()> {
        let mut animator = self.garment.animator(&mut files, &self.body)?;
        let n = animator.rig().network().n_betas();
        if n != self.betas.len() {
            return Err(Error::invalid(
                "garment model",
                format!(
                    "model/model.json takes {n} shape components, the body shown is set by {}: \
                     load the page anew with it",
                    self.betas.len()
                ),
            ));
        }
        animator.set_shape(&shape32(&self.betas))?;
        let worn = std::mem::replace(&mut self.animator, animator);
        if let Err(e) = self.seek(self.frame) {
            self.animator = worn;
            self.seek(self.frame)?;
            return Err(e);
        }
        Ok(())
    }

    /// The body's β for the model's β (the body's further components are 0).
    fn body_betas(body: &BodyModel, betas: &[f64]) -> Vec<f64> {
        let mut full = betas.to_vec();
        full.resize(body.n_betas(), 0.0);
        full
    }

    /// `motion`'s poses with the arms held out for the model's β `betas`, none computed yet
    /// (`None` without [`TryOnOptions::arm_clearance`]).
    fn clearance_for(&self, motion: &Motion, betas: &[f64]) -> Result<Option<ClearanceOnDemand>> {
        let Some((arms, options)) = &self.arms else {
            return Ok(None);
        };
        let body_betas = Self::body_betas(&self.body, betas);
        Ok(Some(ClearanceOnDemand::new(
            arms,
            &self.body,
            &body_betas,
            motion.frames().to_vec(),
            options,
        )?))
    }

    /// Frame `t` of the motion with the arms held out, or `None` without arm clearance (the
    /// motion's own frame is played; not copied).
    fn held_pose(&mut self, t: usize) -> Result<Option<Pose>> {
        let Some(cleared) = &mut self.cleared else {
            return Ok(None);
        };
        let start = now(self.clock);
        let pose = cleared.pose(&self.body, t)?;
        self.arms_ms += now(self.clock) - start;
        Ok(Some(pose))
    }

    /// Set the body shape β (at most the body's component count, finite; components beyond the
    /// model's are dropped for body and garment alike, as the command line does). Recomputes
    /// the frame shown. Returns the β in use.
    pub fn set_betas(&mut self, betas: &[f64]) -> Result<Vec<f64>> {
        self.shape(betas, true)
    }

    /// [`TryOn::set_betas`] as a preview while a slider moves: the body and the garment take
    /// the new shape at once, but the arms stay held as for the shape they were last held for
    /// (by `set_betas` or [`TryOn::settle`]): holding them anew, for every frame the one shown
    /// depends on, is most of a change of shape's time (`cargo bench -p sartor-web --bench seek
    /// -- shape`: 172–179 ms a change, 15 a preview, on the AMD EPYC VM). Once the slider
    /// settles, hold the arms for the shape with [`TryOn::settle`] a few looks at a time (or set
    /// the shape with `set_betas` at once): either gives the frame that `set_betas` would give
    /// without the previews. Returns the β in use.
    pub fn preview_betas(&mut self, betas: &[f64]) -> Result<Vec<f64>> {
        self.shape(betas, false)
    }

    /// Hold the arms out for the shape in use after a preview ([`TryOn::preview_betas`]), in
    /// steps that keep a page responsive: each call takes at most `max_looks` looks (a look
    /// poses the body at one frame and measures the held limbs: about 0.8 ms natively on the
    /// AMD EPYC VM), the first builds the new shape's torso instead (about 5 ms), and what is
    /// computed is kept between calls. Meanwhile frames play with the arms as held before. Once
    /// every frame that the frame shown depends on is held, the new arms take over and the
    /// frame shown is computed anew (a jump, [`TryOn::seek`]): it is then the frame
    /// [`TryOn::set_betas`] gives, bit for bit. A motion begun ([`TryOn::begin_motion`]) comes
    /// first: once its first frames are held it plays from its first frame, its arms held for
    /// the shape in use, as [`TryOn::set_motion`] would play it. Returns `true` when the arms
    /// are held for the shape in use and the motion begun plays (at once when neither waits,
    /// or without [`TryOnOptions::arm_clearance`]), `false` when there is more to do.
    pub fn settle(&mut self, max_looks: usize) -> Result<bool> {
        if let Some((_, held)) = &mut self.next_motion {
            let ready = match held {
                Some(held) => prepare_jump(held, &self.body, 0, max_looks),
                None => Ok(true),
            };
            match ready {
                Ok(false) => return Ok(false),
                Ok(true) => {
                    let (motion, cleared) = self.next_motion.take().expect("a motion begun");
                    // Held for the shape in use: nothing left to settle.
                    self.switch_motion(motion, cleared)?;
                    return Ok(true);
                }
                Err(e) => {
                    self.next_motion = None;
                    return Err(e);
                }
            }
        }
        if self.arms.is_none() || self.held_for == self.betas {
            return Ok(true);
        }
        let Some(settling) = &mut self.settling else {
            self.settling = self.clearance_for(&self.motion, &self.betas)?;
            return Ok(false);
        };
        if !prepare_jump(settling, &self.body, self.frame, max_looks)? {
            return Ok(false);
        }
        let previous = (
            std::mem::replace(&mut self.cleared, self.settling.take()),
            std::mem::replace(&mut self.held_for, self.betas.clone()),
        );
        if let Err(e) = self.seek(self.frame) {
            // The arms as they were held, at the frame shown.
            (self.cleared, self.held_for) = previous;
            self.seek(self.frame)?;
            return Err(e);
        }
        Ok(true)
    }

    /// Compute, taking at most `max_looks` looks, the held arms a jump to `frame` (clamped to
    /// the motion) needs ([`TryOn::seek`] poses the frame and the warm-up frames before it):
    /// `true` once that `seek` would look at no frame (it then costs the garment's part of a
    /// jump alone), `false` while there is more to do; what is computed is kept. A page that
    /// scrubs through a clip whose frames need their arms held calls it between display
    /// frames and seeks when it is ready, instead of waiting on `seek` (up to some 200 ms).
    /// Without [`TryOnOptions::arm_clearance`], `true`.
    pub fn prepare_seek(&mut self, frame: usize, max_looks: usize) -> Result<bool> {
        let frame = frame.min(self.motion.n_frames() - 1);
        match &mut self.cleared {
            Some(cleared) => prepare_jump(cleared, &self.body, frame, max_looks),
            None => Ok(true),
        }
    }

    /// The held-limb work the page waits on, as bytes for a worker ([`crate::LimbsWorker`]),
    /// or `None` when it waits on none: the first frames of a motion begun
    /// ([`TryOn::begin_motion`]), else the frames of a jump to `seek` (a scrub's frame,
    /// [`TryOn::prepare_seek`]), else the frames shown held for the shape in use after a preview
    /// ([`TryOn::settle`]; the first call builds the new shape's torso, about 5 ms). Hand the
    /// worker's answer to [`TryOn::absorb_arms`]; then `settle` or `prepare_seek` finds that
    /// work done. The job holds the shape, the motion's poses (some 1 kB a frame; only their
    /// fingerprint where the last job that carried poses carried these: give the worker every
    /// job, in order) and a bit for each look and sum of turns computed here (the answer leaves
    /// those out).
    pub fn arms_job(&mut self, seek: Option<usize>) -> Result<Option<Vec<u8>>> {
        let body = &self.body;
        let (held, frame) = match (&mut self.next_motion, seek) {
            (Some((_, held)), _) => (held.as_mut(), 0),
            (None, Some(frame)) => {
                let frame = frame.min(self.motion.n_frames() - 1);
                (self.cleared.as_mut(), frame)
            }
            (None, None) if self.arms.is_none() || self.held_for == self.betas => (None, 0),
            (None, None) => {
                if self.settling.is_none() {
                    self.settling = self.clearance_for(&self.motion, &self.betas)?;
                }
                (self.settling.as_mut(), self.frame)
            }
        };
        let Some(held) = held else {
            return Ok(None);
        };
        if prepare_jump(held, body, frame, 0)? {
            return Ok(None);
        }
        Ok(Some(job_for(
            held,
            jump_frames(frame),
            &mut self.worker_motion,
        )))
    }

    /// The held limbs the motion playing will need next, as bytes for a worker (as
    /// [`TryOn::arms_job`]'s): where nothing waits (no motion begun, the arms held for the
    /// shape in use) and a frame among the next `min_frames` after the one shown (the motion
    /// loops) is not computed yet, the job of the next `max_frames` from the first such frame
    /// (up to the motion's end); else `None`. Its answer, taken up by [`TryOn::absorb_arms`],
    /// leaves the frames played no look to compute.
    pub fn arms_ahead_job(
        &mut self,
        min_frames: usize,
        max_frames: usize,
    ) -> Result<Option<Vec<u8>>> {
        if self.next_motion.is_some() || self.held_for != self.betas {
            return Ok(None);
        }
        let Some(held) = &mut self.cleared else {
            return Ok(None);
        };
        let n = held.n_frames();
        let ahead = |k: usize| (self.frame + 1 + k) % n;
        // (Asked every frame played: a check that allocates nothing.)
        for k in 0..min_frames.min(n) {
            if !held.is_computed(ahead(k)) {
                let start = ahead(k);
                let end = (start + max_frames.max(1)).min(n);
                return Ok(Some(job_for(held, start..end, &mut self.worker_motion)));
            }
        }
        Ok(None)
    }

    /// Take up a worker's answer to [`TryOn::arms_job`]: `true` where it is of a motion and
    /// shape the page holds limbs for (a motion begun, the motion shown for the shape its arms
    /// are held for, or for the shape in use), `false` where none is any longer (a shape
    /// previewed or a clip chosen since: nothing changes). An error where the bytes are not an
    /// answer.
    pub fn absorb_arms(&mut self, progress: &[u8]) -> Result<bool> {
        let progress = ClearanceProgress::from_bytes(progress)?;
        let begun = self
            .next_motion
            .as_mut()
            .and_then(|(_, held)| held.as_mut());
        let holders = [begun, self.settling.as_mut(), self.cleared.as_mut()].into_iter();
        match holders
            .flatten()
            .find(|h| h.fingerprint() == progress.fingerprint())
        {
            Some(held) => {
                held.absorb(&progress)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// [`TryOn::set_betas`], the arms held anew for the shape when `hold_arms`, else as they
    /// are held ([`TryOn::preview_betas`]).
    fn shape(&mut self, betas: &[f64], hold_arms: bool) -> Result<Vec<f64>> {
        self.body.check_betas(betas)?;
        let n = self.betas.len();
        let mut model_betas: Vec<f64> = betas.iter().copied().take(n).collect();
        model_betas.resize(n, 0.0);
        let cleared = if hold_arms {
            Some(self.clearance_for(&self.motion, &model_betas)?)
        } else {
            None
        };
        // A motion begun holds its arms for the new shape.
        let next_cleared = match &self.next_motion {
            Some((motion, _)) => Some(self.clearance_for(motion, &model_betas)?),
            None => None,
        };
        let posed_body = PosedBody::new(&self.body, &Self::body_betas(&self.body, &model_betas))?;
        self.animator.set_shape(&shape32(&model_betas))?;
        self.posed_body = posed_body;
        if let Some(cleared) = cleared {
            self.cleared = cleared;
            self.held_for = model_betas.clone();
        }
        self.settling = None;
        if let (Some((_, held)), Some(cleared)) = (&mut self.next_motion, next_cleared) {
            *held = cleared;
        }
        self.betas = model_betas;
        self.seek(self.frame)?;
        Ok(self.betas.clone())
    }

    /// [`TryOn::preview_betas`] from the phenotype sliders (see [`TryOn::set_phenotype`]).
    pub fn preview_phenotype(&mut self, sliders: &PhenotypeSliders) -> Result<Vec<f64>> {
        let (_, betas) = self.space.betas_for(&self.body, &sliders.request()?)?;
        self.preview_betas(&betas)
    }

    /// Set the shape from the phenotype sliders (the command line's rule); returns β.
    pub fn set_phenotype(&mut self, sliders: &PhenotypeSliders) -> Result<Vec<f64>> {
        self.set_phenotype_request(&sliders.request()?)
    }

    /// Set the shape from a phenotype text as the command line takes it (`"female, 1.70 m,
    /// heavy"`); returns β.
    pub fn set_phenotype_text(&mut self, text: &str) -> Result<Vec<f64>> {
        self.set_phenotype_request(&PhenotypeRequest::parse(text)?)
    }

    /// [`TryOn::set_phenotype_text`] as a preview ([`TryOn::preview_betas`]: the arms held as
    /// before until [`TryOn::settle`] holds them for it); returns β.
    pub fn preview_phenotype_text(&mut self, text: &str) -> Result<Vec<f64>> {
        let (_, betas) = self
            .space
            .betas_for(&self.body, &PhenotypeRequest::parse(text)?)?;
        self.preview_betas(&betas)
    }

    fn set_phenotype_request(&mut self, request: &PhenotypeRequest) -> Result<Vec<f64>> {
        let (_, betas) = self.space.betas_for(&self.body, request)?;
        self.set_betas(&betas)
    }

    /// Play `motion` (the body's skeleton, any frame rate: resampled to 30 fps) from its first
    /// frame.
    pub fn set_motion(&mut self, motion: Motion) -> Result<()> {
        let (motion, cleared) = self.playable(motion)?;
        self.next_motion = None;
        self.switch_motion(motion, cleared)
    }

    /// [`TryOn::set_motion`] once [`TryOn::settle`] has held the arms of its first frames (the
    /// frame shown and the warm-up of a jump to it, a few looks a call), while the motion
    /// playing plays on: a page keeps drawing instead of waiting for them. The motion is
    /// checked at once (an error leaves everything as it was); another `begin_motion` or
    /// `set_motion` replaces it.
    pub fn begin_motion(&mut self, motion: Motion) -> Result<()> {
        self.next_motion = Some(self.playable(motion)?);
        Ok(())
    }

    /// `motion` checked against the body and resampled to 30 fps, and its held arms for the
    /// shape in use (none computed yet).
    fn playable(&self, motion: Motion) -> Result<(Motion, Option<ClearanceOnDemand>)> {
        if motion.joint_names() != self.body.skeleton().names() {
            return Err(Error::invalid(
                "motion",
                format!(
                    "{} is for another skeleton than the body {}",
                    motion.name(),
                    self.body.name()
                ),
            ));
        }
        if motion.n_frames() == 0 {
            return Err(Error::invalid(
                "motion",
                format!("{} has no frames", motion.name()),
            ));
        }
        let motion = if (motion.fps() - FPS).abs() > 1e-9 {
            motion.resample(FPS)?
        } else {
            motion
        };
        let cleared = self.clearance_for(&motion, &self.betas)?;
        Ok((motion, cleared))
    }

    /// Play `motion`, its arms held as `cleared` holds them, from its first frame.
    fn switch_motion(&mut self, motion: Motion, cleared: Option<ClearanceOnDemand>) -> Result<()> {
        let previous = (
            std::mem::replace(&mut self.motion, motion),
            std::mem::replace(&mut self.cleared, cleared),
            std::mem::replace(&mut self.held_for, self.betas.clone()),
            self.settling.take(),
        );
        if let Err(e) = self.seek(0) {
            // Back to the motion that played, at its frame.
            (self.motion, self.cleared, self.held_for, self.settling) = previous;
            self.seek(self.frame)?;
            return Err(e);
        }
        Ok(())
    }

    /// A procedural clip by name (see [`procedural_clip_names`]).
    pub fn motion_procedural(name: &str) -> Result<Motion> {
        Ok(procedural::clip(name)?)
    }

    /// A saved JSON motion (the imported walk cycle, `datasets/motions/walk.json`).
    pub fn motion_json(name: &str, bytes: &[u8]) -> Result<Motion> {
        Ok(Motion::from_json_bytes(Path::new(name), bytes)?)
    }

    /// A stored mocap clip (`datasets/motions/cmu/<clip>.json` + `.safetensors`), retargeted
    /// onto the body as `sartor_motion::load_motion` does (`name` as `cmu/05_06`).
    pub fn motion_stored(&self, name: &str, json: &[u8], tensors: Vec<u8>) -> Result<Motion> {
        let json_path = Path::new(name).with_extension("json");
        let bvh = stored_clip_from_bytes(&json_path, json, tensors)?;
        // The T-pose frame was dropped at import; the first stored frame is the performance's.
        let options = BvhRetargetOptions {
            lenient: false,
            keep_tpose_frame: true,
        };
        Ok(retarget_bvh(&bvh, &self.retarget, &options)?
            .0
            .renamed(name.to_string()))
    }

    /// A BVH file's text (`name` is its file name, for errors), retargeted onto the body as
    /// the command line does (`sartor demo --motion file.bvh`).
    pub fn motion_bvh(&self, name: &str, text: &str) -> Result<Motion> {
        let path = Path::new(name);
        let bvh = sartor_motion::Bvh::parse(text, path)?;
        let options = BvhRetargetOptions {
            lenient: false,
            keep_tpose_frame: false,
        };
        Ok(retarget_bvh(&bvh, &self.retarget, &options)?
            .0
            .renamed(name.to_string()))
    }

    /// Show frame `frame` (clamped to the motion): the GRU restarts [`WARMUP_FRAMES`] before
    /// it (from the pose before, as a training sequence starts) and runs up to it, the network
    /// alone ([`GarmentAnimator::advance`]) until the frame shown.
    pub fn seek(&mut self, frame: usize) -> Result<()> {
        let frame = frame.min(self.motion.n_frames() - 1);
        let start = frame.saturating_sub(WARMUP_FRAMES);
        self.arms_ms = 0.0;
        match start.checked_sub(1) {
            Some(before) => {
                let held = self.held_pose(before)?;
                let pose = held.as_ref().unwrap_or(&self.motion.frames()[before]);
                self.animator.reset_from(pose)?;
            }
            None => self.animator.reset(),
        }
        // Only the network steps: the garments of these frames are never shown.
        for t in start..frame {
            let held = self.held_pose(t)?;
            let pose = held.as_ref().unwrap_or(&self.motion.frames()[t]);
            self.animator.advance(pose)?;
        }
        self.show(frame)
    }

    /// Advance one frame; after the last, start the motion again (GRU state reset). Returns the
    /// frame shown.
    pub fn step(&mut self) -> Result<usize> {
        if self.frame + 1 >= self.motion.n_frames() {
            self.seek(0)?;
        } else {
            self.arms_ms = 0.0;
            self.show(self.frame + 1)?;
        }
        Ok(self.frame)
    }

    /// [`TryOn::step`] with the garment's post-processing (the strain limit and the collision
    /// post-process) left to a [`crate::PostWorker`]: the next frame made up to it (the
    /// network, the skinning; the body posed), and the job's bytes for the worker: the shape,
    /// the frame's pose and its garment. The frame is shown once [`TryOn::absorb_post`] takes
    /// up the worker's answer; until then [`TryOn::garment_vertices`] are the garment before
    /// the post-processing. `None` where the frame was shown whole, on this thread: after the
    /// motion's last frame (it starts again, a jump), or without a post-process
    /// ([`TryOnOptions::post_process`]). Any other frame shown meanwhile (a scrub, a shape, a
    /// garment, [`TryOn::step`]) makes the answer stale.
    pub fn step_deferred(&mut self) -> Result<Option<Vec<u8>>> {
        if !self.garment.post_process || self.frame + 1 >= self.motion.n_frames() {
            self.step()?;
            return Ok(None);
        }
        self.arms_ms = 0.0;
        self.show_with(self.frame + 1, false)
    }

    /// Take up a [`crate::PostWorker`]'s answer to the job of [`TryOn::step_deferred`]: where it
    /// answers the job of the frame shown (none shown since), the frame's garment is the
    /// answer's (the page's own post-processing's, bit for bit) and its strain limit's and
    /// post-process's times the worker's; `true`. A stale answer changes nothing (`false`). An
    /// error names the fault of bytes that are not an answer or a garment of another vertex
    /// count.
    pub fn absorb_post(&mut self, answer: &[u8]) -> Result<bool> {
        let answer = PostAnswer::from_bytes(answer)?;
        if self.post_pending != Some(answer.id) {
            return Ok(false);
        }
        self.animator
            .take_post_processed(&answer.vertices, &answer.report)?;
        self.times.garment.strain_limit_ms = answer.report.strain_limit_ms;
        self.times.garment.post_process_ms = answer.report.post_process_ms;
        self.post_pending = None;
        Ok(true)
    }

    /// Compute frame `frame` (the animator is at the frame before it) and pose the body.
    fn show(&mut self, frame: usize) -> Result<()> {
        self.show_with(frame, true).map(|_| ())
    }

    /// [`TryOn::show`]; where not `resolve`, without the garment's post-process: the job's
    /// bytes for the worker ([`TryOn::step_deferred`]).
    fn show_with(&mut self, frame: usize, resolve: bool) -> Result<Option<Vec<u8>>> {
        self.post_pending = None;
        let held = self.held_pose(frame)?;
        self.arm_turn_rad = match &mut self.cleared {
            // Kept from computing the pose.
            Some(cleared) => cleared.angle_rad(&self.body, frame)?,
            None => 0.0,
        };
        let pose = held.as_ref().unwrap_or(&self.motion.frames()[frame]);
        let job = if resolve {
            self.animator.frame(pose)?;
            None
        } else {
            let vertices = self.animator.frame_deferred(pose)?;
            self.post_jobs += 1;
            self.post_pending = Some(self.post_jobs);
            let betas = shape32(&self.betas);
            Some(PostJob::bytes(self.post_jobs, &betas, pose, vertices))
        };
        let start = now(self.clock);
        self.posed_body.pose(&self.body, pose)?;
        self.times = FrameTimes {
            garment: self.animator.stage_times().unwrap_or_default(),
            body_ms: now(self.clock) - start,
            arms_ms: std::mem::take(&mut self.arms_ms),
        };
        self.frame = frame;
        Ok(job)
    }

    /// Looks (a frame posed and its held limbs measured) the held limbs of the motion playing,
    /// for the shape they are held for, took on this thread so far (0 without arm clearance):
    /// what [`TryOn::absorb_arms`] spares it.
    pub fn arm_looks(&self) -> usize {
        self.cleared.as_ref().map_or(0, ClearanceOnDemand::looks)
    }

    /// The largest shoulder (or, with the legs held, hip) rotation the arm clearance added to
    /// the frame shown, degrees (0: the motion's own pose, or no arm clearance).
    pub fn arm_turn_deg(&self) -> f64 {
        self.arm_turn_rad.to_degrees()
    }

    /// The frame shown.
    pub fn frame(&self) -> usize {
        self.frame
    }

    /// Frames of the motion.
    pub fn n_frames(&self) -> usize {
        self.motion.n_frames()
    }

    /// The motion's name.
    pub fn motion_name(&self) -> &str {
        self.motion.name()
    }

    /// β in use (the model's components).
    pub fn betas(&self) -> &[f64] {
        &self.betas
    }

    /// The size-chart measurements of the body shown (`sartor_core::BodyMeasurer`: height,
    /// chest, waist and hip girths, mass).
    pub fn measurements(&self) -> Result<BodyMeasurements> {
        let betas = Self::body_betas(&self.body, &self.betas);
        let v = self.body.shaped_vertices(&betas)?;
        let measured = match &self.measurer {
            Some(m) => m.measure(&self.body, &v, &betas),
            None => BodyMeasurer::new(&self.body).and_then(|m| m.measure(&self.body, &v, &betas)),
        };
        Ok(measured?)
    }

    /// Standing height of the body shown, metres.
    pub fn height_m(&self) -> Result<f64> {
        Ok(self
            .body
            .height_m(&Self::body_betas(&self.body, &self.betas))?)
    }

    /// Garment vertices of the frame shown, `x, y, z, …` (metres).
    pub fn garment_vertices(&self) -> Vec<f32> {
        flat(self.animator.vertices())
    }

    /// Body vertices of the frame shown, `x, y, z, …` (metres).
    pub fn body_vertices(&self) -> Vec<f32> {
        flat(&self.posed_body.vertices)
    }

    /// Garment triangles, three vertex indices each.
    pub fn garment_faces(&self) -> Vec<u32> {
        self.animator.faces().iter().flatten().copied().collect()
    }

    /// Body triangles, three vertex indices each.
    pub fn body_faces(&self) -> Vec<u32> {
        self.body.faces().iter().flatten().copied().collect()
    }

    /// Garment vertices the post-process moved in the frame shown.
    pub fn pushed(&self) -> usize {
        self.animator.last_frame_pushed()
    }

    /// Where the frame shown spent its time (zeros without a clock).
    pub fn times(&self) -> FrameTimes {
        self.times
    }
}

/// `clock`'s time, ms (0 without one).
fn now(clock: Option<fn() -> f64>) -> f64 {
    clock.map_or(0.0, |clock| clock())
}

/// The procedural clips the page offers (all of sartor-motion's library).
pub fn procedural_clip_names() -> Vec<String> {
    procedural::clip_names()
}
