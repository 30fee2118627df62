//! [`ArmClearance::apply`] frame by frame, for a player.

use std::ops::Range;

use nalgebra::Vector3;
use sartor_core::bytes::{Reader, put_bits, put_counts, put_floats, put_poses};
use sartor_core::{BodyModel, Error, Pose, Result};

use crate::fnv::Fnv;

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
    /// Of the poses alone ([`motion_fingerprint`]).
    motion: u64,
    /// Of the motion, the body's shape and the options ([`fingerprint`]).
    fingerprint: u64,
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
        let motion = motion_fingerprint(&poses);
        let fingerprint = fingerprint(body, betas, motion, options);
        Ok(Self {
            motion,
            fingerprint,
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

    /// Whether frame `t`'s pose is computed ([`Self::pose`] of it then looks at no frame and
    /// composes nothing): a check that allocates nothing, for a player that asks every frame.
    pub fn is_computed(&self, t: usize) -> bool {
        self.total
            .last()
            .and_then(|totals| totals.get(t))
            .is_some_and(Option::is_some)
    }

    /// How many times a frame was looked at (the body posed and the held vertices measured)
    /// so far: the work done.
    pub fn looks(&self) -> usize {
        self.looks
    }

    /// The motion's poses, as given.
    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }

    /// What was computed so far, for another `ClearanceOnDemand` of the same motion, body shape
    /// and options to take up ([`Self::absorb`]).
    pub fn progress(&self) -> ClearanceProgress {
        self.progress_beyond(&[])
    }

    /// [`Self::progress`] without the entries `known` marks (a [`ClearanceJob`]'s: what the
    /// asker holds already; shorter than the entries, the rest count as not known).
    pub fn progress_beyond(&self, known: &[bool]) -> ClearanceProgress {
        let mut entries = self.needed.iter().chain(&self.total).flatten();
        let lists = (0..2 * self.needed.len()).map(|list| {
            (0..self.poses.len())
                .map(|t| {
                    let entry = entries.next().expect("an entry per pass and frame");
                    let i = list * self.poses.len() + t;
                    if known.get(i).copied().unwrap_or(false) {
                        None
                    } else {
                        entry.clone()
                    }
                })
                .collect()
        });
        let mut needed: Vec<PerFrame> = lists.collect();
        let total = needed.split_off(self.needed.len());
        ClearanceProgress {
            fingerprint: self.fingerprint,
            n_limbs: self.clearance.arms.len(),
            needed,
            total,
        }
    }

    /// Take up what `progress` computed (of another `ClearanceOnDemand`, on another thread, say):
    /// every look and sum of turns not computed here yet. The poses are then those this one
    /// would compute, bit for bit, since each depends on the motion, the body and the options
    /// alone. Returns how many it took up; an error, changing nothing, where `progress` is of
    /// another motion, shape or options.
    pub fn absorb(&mut self, progress: &ClearanceProgress) -> Result<usize> {
        if progress.fingerprint != self.fingerprint
            || progress.n_limbs != self.clearance.arms.len()
            || progress.needed.len() != self.needed.len()
            || progress.needed.iter().any(|p| p.len() != self.poses.len())
        {
            return Err(Error::invalid(
                "arm clearance",
                "the held limbs handed over are of another motion, body shape or options",
            ));
        }
        let mut taken = 0;
        let ours = self.needed.iter_mut().chain(self.total.iter_mut());
        let theirs = progress.needed.iter().chain(progress.total.iter());
        for (ours, theirs) in ours.zip(theirs) {
            for (ours, theirs) in ours.iter_mut().zip(theirs) {
                if ours.is_none() && theirs.is_some() {
                    ours.clone_from(theirs);
                    taken += 1;
                }
            }
        }
        Ok(taken)
    }

    /// Of the motion, the body's shape and the options: equal for two `ClearanceOnDemand`s that
    /// compute the same poses (given the same body).
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    /// Of the motion's poses alone ([`Self::motion_fingerprint_of`]).
    pub fn motion_fingerprint(&self) -> u64 {
        self.motion
    }

    /// The fingerprint of a motion's poses, every bit of them.
    pub fn motion_fingerprint_of(poses: &[Pose]) -> u64 {
        motion_fingerprint(poses)
    }

    /// The fingerprint a `ClearanceOnDemand::new` of these would have (`motion`: the poses',
    /// [`Self::motion_fingerprint_of`]).
    pub fn fingerprint_of(
        body: &BodyModel,
        betas: &[f64],
        motion: u64,
        options: &ClearanceOptions,
    ) -> u64 {
        fingerprint(body, betas, motion, options)
    }

    /// The work of preparing `frames` ([`Self::prepare`]) as another thread would take it up:
    /// this one's shape and motion (the poses where `with_poses`, else only their fingerprint,
    /// for a thread that holds them from an earlier job) and what it computed already
    /// ([`ClearanceJob`]).
    pub fn job(&self, frames: Range<usize>, with_poses: bool) -> ClearanceJob {
        let known = self.needed.iter().chain(&self.total).flatten();
        ClearanceJob {
            betas: self.posing.betas.clone(),
            motion: self.motion,
            poses: with_poses.then(|| self.poses.clone()),
            frames,
            known: known.map(Option::is_some).collect(),
        }
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

/// A hash (FNV-1a over 64-bit words) of every bit of a motion's poses.
fn motion_fingerprint(poses: &[Pose]) -> u64 {
    let mut h = Fnv::default();
    h.word(poses.len() as u64);
    for pose in poses {
        h.floats(pose.root_translation_m.as_slice());
        h.floats(pose.root_orientation.coords.as_slice());
        h.word(pose.local_rotations.len() as u64);
        for q in &pose.local_rotations {
            h.floats(q.coords.as_slice());
        }
    }
    h.0
}

/// A hash of what a [`ClearanceOnDemand`]'s poses depend on: the body's size, the shape, the
/// motion ([`motion_fingerprint`]) and the options.
fn fingerprint(body: &BodyModel, betas: &[f64], motion: u64, options: &ClearanceOptions) -> u64 {
    let mut h = Fnv::default();
    h.word(body.n_vertices() as u64);
    h.word(body.skeleton().n_joints() as u64);
    h.floats(betas);
    h.word(motion);
    let ClearanceOptions {
        clearance_m,
        upper_arm_clearance_m,
        leg_clearance_m,
        ramp_frames,
        max_iterations,
        max_passes,
        max_angle_rad,
    } = options;
    h.floats(&[*clearance_m, *max_angle_rad]);
    for m in [upper_arm_clearance_m, leg_clearance_m] {
        h.floats(&[m.unwrap_or(f64::NAN)]);
    }
    for n in [ramp_frames, max_iterations, max_passes] {
        h.word(*n as u64);
    }
    h.0
}

/// What a [`ClearanceOnDemand`] computed ([`ClearanceOnDemand::progress`]), to be taken up by
/// another of the same motion, body shape and options ([`ClearanceOnDemand::absorb`]); as bytes
/// ([`Self::to_bytes`]) it crosses to another thread (the try-on page computes the held limbs
/// in a worker).
#[derive(Clone, Debug, PartialEq)]
pub struct ClearanceProgress {
    fingerprint: u64,
    n_limbs: usize,
    needed: Vec<PerFrame>,
    total: Vec<PerFrame>,
}

/// The first bytes of [`ClearanceProgress::to_bytes`] (a format version in the last).
const PROGRESS_MAGIC: [u8; 8] = *b"sartorC2";

impl ClearanceProgress {
    /// Of the `ClearanceOnDemand` it was taken from ([`ClearanceOnDemand::fingerprint`]).
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    /// How many looks and sums of turns it holds.
    pub fn len(&self) -> usize {
        self.entries().filter(|e| e.is_some()).count()
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Per look and sum of turns, in the order of [`ClearanceJob::known`], whether it holds it.
    pub fn held(&self) -> impl Iterator<Item = bool> + '_ {
        self.entries().map(Option::is_some)
    }

    fn entries(&self) -> impl Iterator<Item = &Option<Box<[Vector3<f64>]>>> {
        self.needed.iter().chain(&self.total).flatten()
    }

    /// Little-endian: the magic, the fingerprint, then passes, frames and limbs as `u32`, then
    /// a bit per pass and frame of the looks and then of the sums of turns (1: held; bytes
    /// filled from their lowest bit), then the held ones' three `f64` a limb, in that order.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = PROGRESS_MAGIC.to_vec();
        out.extend(self.fingerprint.to_le_bytes());
        let frames = self.needed.first().map_or(0, Vec::len);
        put_counts(&mut out, &[self.needed.len(), frames, self.n_limbs]);
        put_bits(&mut out, self.entries().map(Option::is_some));
        for turns in self.entries().flatten() {
            for r in turns {
                put_floats(&mut out, r.as_slice());
            }
        }
        out
    }

    /// Read [`Self::to_bytes`]'s bytes: an error naming the fault where they are cut short,
    /// too long, of another format or hold a value that is not finite.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let mut r = Reader::open(bytes, "arm clearance progress", PROGRESS_MAGIC)?;
        let fingerprint = r.u64()?;
        let (passes, frames, n_limbs) = (r.count()?, r.count()?, r.count()?);
        if passes == 0 || frames == 0 {
            return Err(r.fault(format!("{passes} passes of {frames} frames")));
        }
        // (A bit an entry: no more entries than the bytes can mark.)
        let held = r.bits(2usize.saturating_mul(passes).saturating_mul(frames))?;
        let mut held = held.into_iter();
        let mut lists: Vec<PerFrame> = Vec::with_capacity(2 * passes);
        for _ in 0..2 * passes {
            let mut list: PerFrame = Vec::with_capacity(frames);
            for _ in 0..frames {
                let entry = if held.next().expect("a bit an entry") {
                    let v = r.floats(n_limbs.saturating_mul(3))?;
                    Some(v.chunks_exact(3).map(Vector3::from_column_slice).collect())
                } else {
                    None
                };
                list.push(entry);
            }
            lists.push(list);
        }
        r.end()?;
        let total = lists.split_off(passes);
        Ok(Self {
            fingerprint,
            n_limbs,
            needed: lists,
            total,
        })
    }
}

/// The inputs of a [`ClearanceOnDemand`] (with the body and options, which the other side holds)
/// and the frames to prepare: what a player hands to a worker thread, as bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct ClearanceJob {
    /// The body's shape.
    pub betas: Vec<f64>,
    /// The fingerprint of the motion's poses ([`ClearanceOnDemand::motion_fingerprint_of`]).
    pub motion: u64,
    /// The motion's poses, or `None` where the other side holds them from an earlier job
    /// (`motion` names them).
    pub poses: Option<Vec<Pose>>,
    /// The frames to prepare.
    pub frames: Range<usize>,
    /// Per look and sum of turns (each pass's looks, then each pass's sums, frame by frame),
    /// whether the asker holds it already: the answer leaves those out
    /// ([`ClearanceOnDemand::progress_beyond`]).
    pub known: Vec<bool>,
}

/// The first bytes of [`ClearanceJob::to_bytes`].
const JOB_MAGIC: [u8; 8] = *b"sartorJ2";

impl ClearanceJob {
    /// Little-endian: the magic, the frames to prepare (start, end), the shape's length and
    /// values, the motion's fingerprint, a byte (1: the poses follow), then where they do the
    /// poses' count and joints and per pose the root translation, the root orientation and
    /// each joint's rotation (quaternions as `i, j, k, w`), all `f64`; then the count of
    /// `known` and its bits (bytes filled from their lowest bit).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = JOB_MAGIC.to_vec();
        put_counts(
            &mut out,
            &[self.frames.start, self.frames.end, self.betas.len()],
        );
        put_floats(&mut out, &self.betas);
        out.extend(self.motion.to_le_bytes());
        match &self.poses {
            None => out.push(0),
            Some(poses) => {
                out.push(1);
                put_poses(&mut out, poses);
            }
        }
        put_counts(&mut out, &[self.known.len()]);
        put_bits(&mut out, self.known.iter().copied());
        out
    }

    /// Read [`Self::to_bytes`]'s bytes: an error naming the fault where they are cut short, too
    /// long, of another format, hold a value that is not finite, poses whose fingerprint is not
    /// the one named, or frames beyond the poses given. (The poses' joints are the caller's to
    /// check against its body, [`Pose::validate`]; and where no poses are given, the frames
    /// against those it holds.)
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let mut r = Reader::open(bytes, "arm clearance job", JOB_MAGIC)?;
        let (start, end, n_betas) = (r.count()?, r.count()?, r.count()?);
        let betas = r.floats(n_betas)?;
        let motion = r.u64()?;
        let poses = match r.take(1)?[0] {
            0 => None,
            1 => Some(r.poses()?),
            flag => {
                let at = r.position() - 1;
                return Err(r.fault(format!("poses flag {flag} at byte {at}")));
            }
        };
        let n_known = r.count()?;
        let known = r.bits(n_known)?;
        r.end()?;
        if start > end {
            return Err(r.fault(format!("frames {start}..{end}")));
        }
        if let Some(poses) = &poses {
            if end > poses.len() {
                return Err(r.fault(format!("frames {start}..{end} of {}", poses.len())));
            }
            let got = motion_fingerprint(poses);
            if got != motion {
                return Err(r.fault(format!(
                    "poses of fingerprint {got:016x}, named {motion:016x}"
                )));
            }
        }
        Ok(Self {
            betas,
            motion,
            poses,
            frames: start..end,
            known,
        })
    }
}
