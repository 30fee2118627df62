//! The held limbs computed off the page's thread. After a change of shape, a scrub or a new clip
//! the page waits for the held limbs of the frames it shows (`TryOn::settle`, some 150 ms of
//! looks in the browser); computed on the page's thread, a slice each display frame, they
//! share it with the frames that play on. [`LimbsWorker`] runs in a Web Worker with the body
//! alone: the page hands it [`TryOn::arms_job`]'s bytes (the shape, the motion's poses or,
//! once given, their fingerprint, the frames the page waits on and what it holds already) and
//! takes up its answer with [`TryOn::absorb_arms`], after which the page's own
//! `ClearanceOnDemand` has nothing left to compute for those frames. Both run
//! the same code on the same inputs, so the poses are those the page would compute, bit for
//! bit.

use std::ops::Range;

use sartor_core::BodyModel;
use sartor_motion::{ArmClearance, ClearanceJob, ClearanceOnDemand, ClearanceOptions};

use crate::error::{Error, Result};
use crate::files::FileSet;
#[cfg(doc)]
use crate::session::TryOn;
use crate::session::{load_body, prepare_frames};

/// The worker's side: the body, its limbs and torso, and the held limbs of the last job's
/// motion and shape (a job of the same ones goes on from what was computed). A job is taken
/// ([`Self::begin`]), computed a few looks at a time ([`Self::work`]) so that a newer job can
/// replace it between the steps, and answered ([`Self::answer`]); [`Self::run`] does all three.
#[derive(Debug)]
pub struct LimbsWorker {
    body: BodyModel,
    clearance: ArmClearance,
    options: ClearanceOptions,
    held: Option<ClearanceOnDemand>,
    /// The frames the job in hand asks for (empty: none).
    frames: Range<usize>,
    /// What the job's asker holds already ([`ClearanceJob::known`]).
    known: Vec<bool>,
}

impl LimbsWorker {
    /// The body folder's files ([`crate::BODY_FILES`]; the phenotype files are not needed) and
    /// the options of the limbs held, those the page's `TryOn` was loaded with.
    pub fn load(mut files: FileSet, options: ClearanceOptions) -> Result<Self> {
        options.validate()?;
        let body = load_body(&mut files)?;
        let clearance = ArmClearance::new(&body)?;
        Ok(Self {
            body,
            clearance,
            options,
            held: None,
            frames: 0..0,
            known: Vec::new(),
        })
    }

    /// Take the job `job` ([`TryOn::arms_job`]'s bytes), in place of any in hand: its poses
    /// (given, or named as those of the last job that gave them) must be of the body's skeleton,
    /// its frames within them and its shape within the body's components (an error leaves no
    /// job in hand). What was computed for the same motion and shape is kept.
    pub fn begin(&mut self, job: &[u8]) -> Result<()> {
        self.frames = 0..0;
        let job = ClearanceJob::from_bytes(job)?;
        let fault = |message: String| Error::invalid("arm clearance job", message);
        self.body.check_betas(&job.betas)?;
        let held_motion = self
            .held
            .as_ref()
            .map(ClearanceOnDemand::motion_fingerprint);
        let poses = match job.poses {
            Some(poses) => {
                let joints = self.body.skeleton().n_joints();
                for (t, pose) in poses.iter().enumerate() {
                    pose.validate(joints)
                        .map_err(|e| fault(format!("frame {t}: {e}")))?;
                }
                Some(poses)
            }
            None if held_motion == Some(job.motion) => None,
            None => {
                return Err(fault(format!(
                    "the job names the poses of fingerprint {:016x}, which no job gave",
                    job.motion
                )));
            }
        };
        let fingerprint =
            ClearanceOnDemand::fingerprint_of(&self.body, &job.betas, job.motion, &self.options);
        let held = match self.held.take() {
            Some(held) if held.fingerprint() == fingerprint => held,
            held => {
                let poses = match (poses, held) {
                    (Some(poses), _) => poses,
                    (None, Some(held)) => held.poses().to_vec(),
                    (None, None) => unreachable!("poses named only where held"),
                };
                ClearanceOnDemand::new(
                    &self.clearance,
                    &self.body,
                    &job.betas,
                    poses,
                    &self.options,
                )?
            }
        };
        let n = held.n_frames();
        let entries = 2 * self.options.max_passes.max(1) * n;
        if job.frames.end > n || !(job.known.is_empty() || job.known.len() == entries) {
            let (frames, known) = (job.frames, job.known.len());
            self.held = Some(held);
            return Err(fault(format!(
                "frames {frames:?} and {known} entries known of a motion of {n} frames"
            )));
        }
        self.held = Some(held);
        self.frames = job.frames;
        self.known = job.known;
        Ok(())
    }

    /// Compute the job in hand, at most `max_looks` looks (a look is about 1 to 2 ms in the
    /// browser): `true` once it is all computed (or no job is in hand).
    pub fn work(&mut self, max_looks: usize) -> Result<bool> {
        match &mut self.held {
            Some(held) => prepare_frames(held, &self.body, self.frames.clone(), max_looks),
            None => Ok(true),
        }
    }

    /// Everything computed for the last job's motion and shape that its asker does not hold
    /// already, as bytes for [`TryOn::absorb_arms`]; an error where no job was taken.
    pub fn answer(&self) -> Result<Vec<u8>> {
        match &self.held {
            Some(held) => Ok(held.progress_beyond(&self.known).to_bytes()),
            None => Err(Error::invalid("arm clearance job", "no job was taken")),
        }
    }

    /// [`Self::begin`], [`Self::work`] to the end and [`Self::answer`].
    pub fn run(&mut self, job: &[u8]) -> Result<Vec<u8>> {
        self.begin(job)?;
        self.work(usize::MAX)?;
        self.answer()
    }
}
