//! [`ArmClearance::apply`] frame by frame, for a player.

use nalgebra::Vector3;
use sartor_core::{BodyModel, Error, Pose, Result};

use super::{
    ArmClearance, ClearanceOptions, Posing, Targets, compose, dilated_at, eased_at, window,
};

/// Per frame, one correction (rotation vector) per arm, once computed.
type PerFrame = Vec<Option<Box<[Vector3<f64>]>>>;

/// Why the computation of a frame stopped before its answer.
enum Halt {
    /// [`ClearanceOnDemand::prepare`]'s looks ran out (what was computed is kept).
    Looks,
    Failed(Error),
}

type Halting<T> = std::result::Result<T, Halt>;

impl From<Error> for Halt {
    fn from(e: Error) -> Self {
        Self::Failed(e)
    }
}

/// A computation that no look allowance limits: it halts only on an error.
fn unlimited<T>(result: Halting<T>) -> Result<T> {
    result.map_err(|halt| match halt {
        Halt::Failed(e) => e,
        Halt::Looks => unreachable!("no look allowance was set"),
    })
}

/// A motion's poses with the arms held out of the torso of one body shape, each frame computed
/// when first asked for: the poses of [`ArmClearance::apply`], bit for bit, for a player that
/// shows a motion as it goes and changes the shape between frames (the try-on page), where
/// the whole clip at once would keep it waiting (apply takes 2 to 6 ms a frame on the AMD EPYC
/// VM).
///
/// `apply` is a few passes, each looking at every frame and easing the turns it found over the
/// frames around; a frame's final pose depends on the motion within `max_passes × (ramp_frames
/// + ramp_frames / 2)` frames of it (36 with the defaults). Here every pass's look at a frame
/// and every frame's sum of turns is kept once computed, and computed only when a frame asked
/// for needs it: the first frame asked for costs its window (73 looks at most with the
/// defaults), each next frame of a playing motion about one look per pass, and a frame whose
/// pose no earlier pass turned is not looked at again (its look is the previous pass's). A new
/// shape is a new `ClearanceOnDemand`. A player that must not stall while a frame's window is
/// computed (the page after a change of shape) does the work a few looks at a time with
/// [`ClearanceOnDemand::prepare`], which keeps what it computed between calls.
#[derive(Clone, Debug)]
pub struct ClearanceOnDemand {
    clearance: ArmClearance,
    options: ClearanceOptions,
    poses: Vec<Pose>,
    posing: Posing,
    targets: Targets,
    /// Per pass: the turns its look at each frame found (zero for an arm it did not turn).
    needed: Vec<PerFrame>,
    /// Per pass: each frame's correction after it (the composed eased turns of it and the
    /// passes before).
    total: Vec<PerFrame>,
    looks: usize,
    /// Looks the call in progress may still take (`None`: no limit; see [`Self::prepare`]).
    allowance: Option<usize>,
}

impl ClearanceOnDemand {
    /// Clearance of `poses` for the body `body` of shape `betas` (give the same `body` to
    /// every later call).
    pub fn new(
        clearance: &ArmClearance,
        body: &BodyModel,
        betas: &[f64],
        poses: Vec<Pose>,
        options: &ClearanceOptions,
    ) -> Result<Self> {
        options.validate()?;
        let mut posing = Posing::new(body, betas)?;
        let targets = clearance.targets(body, &mut posing, options)?;
        let passes = options.max_passes.max(1);
        let n = poses.len();
        Ok(Self {
            clearance: clearance.clone(),
            options: options.clone(),
            posing,
            targets,
            needed: vec![vec![None; n]; passes],
            total: vec![vec![None; n]; passes],
            poses,
            looks: 0,
            allowance: None,
        })
    }

    /// Frames of the motion.
    pub fn n_frames(&self) -> usize {
        self.poses.len()
    }

    /// Frame `t` with the arms held out, as [`ArmClearance::apply`] gives it.
    pub fn pose(&mut self, body: &BodyModel, t: usize) -> Result<Pose> {
        let total = unlimited(self.final_total(body, t))?;
        let mut pose = self.poses[t].clone();
        self.clearance.correct(&mut pose, total.iter());
        Ok(pose)
    }

    /// The largest shoulder rotation added to frame `t`, radians (0: the motion's own pose).
    pub fn angle_rad(&mut self, body: &BodyModel, t: usize) -> Result<f64> {
        Ok(unlimited(self.final_total(body, t))?
            .iter()
            .map(|r| r.norm())
            .fold(0.0, f64::max))
    }

    /// How many times a frame was looked at (the body posed and the held vertices measured)
    /// so far: the work done.
    pub fn looks(&self) -> usize {
        self.looks
    }

    /// Compute what frame `t`'s pose needs, taking at most `max_looks` looks: `true` once all
    /// of it is computed ([`Self::pose`] and [`Self::angle_rad`] of `t` then look at no frame),
    /// `false` when the looks ran out first (what was computed is kept: call again). The poses
    /// are the same bit for bit however the work is split: each look and each frame's sum of
    /// turns is kept only once complete, and depends on the motion, the body and the options
    /// alone.
    pub fn prepare(&mut self, body: &BodyModel, t: usize, max_looks: usize) -> Result<bool> {
        self.allowance = Some(max_looks);
        let result = self.final_total(body, t);
        self.allowance = None;
        match result {
            Ok(_) => Ok(true),
            Err(Halt::Looks) => Ok(false),
            Err(Halt::Failed(e)) => Err(e),
        }
    }

    fn final_total(&mut self, body: &BodyModel, t: usize) -> Halting<Box<[Vector3<f64>]>> {
        if t >= self.poses.len() {
            return Err(Error::invalid(
                "arm clearance",
                format!("frame {t} of a motion of {} frames", self.poses.len()),
            )
            .into());
        }
        self.total(body, self.needed.len(), t)
    }

    /// Frame `t`'s correction after `passes` passes.
    fn total(&mut self, body: &BodyModel, passes: usize, t: usize) -> Halting<Box<[Vector3<f64>]>> {
        let Some(pass) = passes.checked_sub(1) else {
            return Ok(vec![Vector3::zeros(); self.clearance.arms.len()].into());
        };
        if let Some(total) = &self.total[pass][t] {
            return Ok(total.clone());
        }
        let before = self.total(body, pass, t)?;
        // The pass's looks at every frame its easing reaches from `t`.
        let (ramp, len) = (self.options.ramp_frames, self.poses.len());
        let reach = window(len, t, ramp + ramp / 2);
        for s in reach.clone() {
            self.needed(body, pass, s)?;
        }
        let needed = &self.needed[pass];
        let look = |s: usize, a: usize| needed[s].as_ref().expect("looked")[a];
        let total: Box<[Vector3<f64>]> = before
            .iter()
            .enumerate()
            .map(|(a, before)| {
                let eased = eased_at(|u| dilated_at(|s| look(s, a), len, u, ramp), len, t, ramp);
                compose(&eased, before)
            })
            .collect();
        self.total[pass][t] = Some(total.clone());
        Ok(total)
    }

    /// Pass `pass`'s look at frame `t`, kept in `self.needed`.
    fn needed(&mut self, body: &BodyModel, pass: usize, t: usize) -> Halting<()> {
        if self.needed[pass][t].is_some() {
            return Ok(());
        }
        let total = self.total(body, pass, t)?;
        if pass > 0 && self.total(body, pass - 1, t)? == total {
            // The pose the previous pass looked at.
            self.needed(body, pass - 1, t)?;
            self.needed[pass][t] = self.needed[pass - 1][t].clone();
            return Ok(());
        }
        match &mut self.allowance {
            Some(0) => return Err(Halt::Looks),
            Some(left) => *left -= 1,
            None => {}
        }
        let mut pose = self.poses[t].clone();
        self.clearance.correct(&mut pose, total.iter());
        let fixes = self.clearance.frame_fixes(
            body,
            &mut self.posing,
            &pose,
            &self.targets,
            &self.options,
        )?;
        self.looks += 1;
        self.needed[pass][t] = Some(
            fixes
                .into_iter()
                .map(|(fix, _)| fix.unwrap_or_else(Vector3::zeros))
                .collect(),
        );
        Ok(())
    }
}
