//! BVH motion capture: a strict parser and retargeting onto the built-in skeleton.
//!
//! # Format
//!
//! `HIERARCHY` (one `ROOT`, nested `JOINT`s and `End Site`s, each with an `OFFSET` and — except
//! end sites — `CHANNELS n` followed by `n` of `Xposition Yposition Zposition Xrotation Yrotation
//! Zrotation` in any order), then `MOTION`, `Frames: N`, `Frame Time: dt` and `N` lines of
//! numbers, one value per channel. Rotations are in degrees and compose in the order listed:
//! `CHANNELS 3 Zrotation Xrotation Yrotation` is `R = Rz · Rx · Ry`. A joint's transform is
//! `T(offset + position channels) · R`, relative to its parent; rest frames are world-aligned.
//! Every fault is reported with the file and the 1-based line. Position channels are read on any
//! joint, but only the root's reach the retargeted motion (the rig's bone lengths are fixed).
//!
//! # Axes and units
//!
//! CMU BVH files are Y-up; in their rest T-pose the left limbs lie on +X, so the subject faces
//! +Z — the same axes as ours (+X the body's left, +Y up, +Z forward). The retargeter checks this
//! on the rest offsets: when the left hip (or arm) lies on −X it turns the data 180° about +Y.
//! The files' length unit varies
//! (CMU's converted files use neither inches nor metres), so it is never guessed: root
//! translations are scaled by `our hip height / BVH hip height`, both measured from the root joint
//! down to the feet (`LeftFoot`/`RightFoot`) in the file's rest posture (ours turned into it by
//! the rest change), a unit-free ratio. Translations are
//! taken relative to the first frame played (the motion starts at the origin; that frame is
//! taken to stand at rest height).
//!
//! A rest pose need not stand: LAFAN1's files point every bone along +X at rest, so that the
//! rest body lies on its side with its legs folded up along the spine. Where the rest head is
//! not above the hips along +Y, the rest is stood up ([`BvhRetargetReport::rest_frame`]: up
//! from the root to the head, left from the right thigh to the left) and the file's rotations
//! are taken relative to that standing rest; the file must then be Y-up in its first frame (a
//! Z-up file is refused), and translations are scaled by the legs' length (thigh and shin)
//! instead, as such a rest has no hip height.
//!
//! # Rest pose and the added T-pose frame
//!
//! Rotations are relative to the file's own rest pose (all channels zero), whatever it is: the
//! rest bone directions come from the offsets ([`crate::SourceRest`]) and
//! [`RetargetBody::rest_change`] turns our rest into it. CMU's converted files rest with the
//! thighs down and outwards, not in a T-pose. Their frame 0 is a T-pose added by the converter:
//! [`crate::detect_tpose_frame`] recognises such a frame from the data and it is dropped unless
//! [`BvhRetargetOptions::keep_tpose_frame`] is set.
//!
//! # Names
//!
//! CMU bone names equal the rig's ([`crate::CMU_MB_JOINTS`]) except `LeftHandIndex1` /
//! `RightHandIndex1`, which are the rig's `LeftHandFinger1` / `RightHandFinger1`
//! ([`cmu_to_rig_name`]). A file whose every joint has a rig joint's name drives them by name;
//! any other (Mixamo, Biovision, Rigify, LAFAN1, DAZ, 3ds Max Biped …) is matched by its
//! skeleton's structure ([`crate::map_bvh_joints`]): its joints that drive nothing (fingers,
//! eyes, end joints) are listed in the report, and their rotations still move their children.
//! Only a skeleton whose structure is not understood needs [`BvhRetargetOptions::lenient`],
//! which then drops the joints without a rig joint's name. Rig joints the file lacks keep their
//! T-pose relation to their parent. A joint name may hold spaces (`JOINT Bip01 L Thigh`). The
//! rest-pose difference is handled by world-orientation retargeting, see
//! [`crate::motion_sources`].

use std::path::{Path, PathBuf};

use nalgebra::{Unit, UnitQuaternion, Vector3};

use sartor_core::io::read_file;

use crate::bvh_map::{BvhJointMap, map_bvh_joints};
use crate::bvh_tpose::{TposeFrame, detect_tpose_frame_mapped, first_performance_frame_mapped};
use crate::rest_pose::SourceRest;
use crate::retarget::{RetargetBody, hip_height};
use crate::{Error, Motion, Result};

/// One channel of a BVH joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BvhChannel {
    /// Translation along X.
    Xposition,
    /// Translation along Y.
    Yposition,
    /// Translation along Z.
    Zposition,
    /// Rotation about X, degrees.
    Xrotation,
    /// Rotation about Y, degrees.
    Yrotation,
    /// Rotation about Z, degrees.
    Zrotation,
}

impl BvhChannel {
    /// The channel's name as a BVH file writes it (`Xposition`, …, `Zrotation`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Xposition => "Xposition",
            Self::Yposition => "Yposition",
            Self::Zposition => "Zposition",
            Self::Xrotation => "Xrotation",
            Self::Yrotation => "Yrotation",
            Self::Zrotation => "Zrotation",
        }
    }

    /// The channel named `s` as a BVH file writes it.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::parse(s)
    }

    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "Xposition" => Self::Xposition,
            "Yposition" => Self::Yposition,
            "Zposition" => Self::Zposition,
            "Xrotation" => Self::Xrotation,
            "Yrotation" => Self::Yrotation,
            "Zrotation" => Self::Zrotation,
            _ => return None,
        })
    }

    /// The axis (0 = X, 1 = Y, 2 = Z) and whether it is a rotation.
    fn axis(self) -> (usize, bool) {
        match self {
            Self::Xposition => (0, false),
            Self::Yposition => (1, false),
            Self::Zposition => (2, false),
            Self::Xrotation => (0, true),
            Self::Yrotation => (1, true),
            Self::Zrotation => (2, true),
        }
    }
}

/// One joint of a BVH hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhJoint {
    /// Name as written in the file.
    pub name: String,
    /// Index of the parent joint (`None` for the root).
    pub parent: Option<usize>,
    /// Rest offset from the parent, in the file's units.
    pub offset: Vector3<f64>,
    /// Channels in file order.
    pub channels: Vec<BvhChannel>,
    /// Offset of the `End Site` below this joint, if it has one.
    pub end_site: Option<Vector3<f64>>,
}

/// A parsed BVH file: hierarchy and frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    path: PathBuf,
    joints: Vec<BvhJoint>,
    /// Index of each joint's first value in a frame.
    first_channel: Vec<usize>,
    n_channels: usize,
    frame_time_secs: f64,
    /// `n_frames × n_channels`, row-major.
    values: Vec<f64>,
}

/// A whitespace-separated word and its 1-based line.
#[derive(Clone, Copy, Debug)]
struct Token<'a> {
    text: &'a str,
    line: usize,
}

struct Parser<'a> {
    path: &'a Path,
    text: &'a str,
    tokens: Vec<Token<'a>>,
    pos: usize,
    last_line: usize,
}

impl<'a> Parser<'a> {
    fn err(&self, line: usize, message: impl Into<String>) -> Error {
        Error::parse(self.path, line, message)
    }

    fn next(&mut self, what: &str) -> Result<Token<'a>> {
        let t = self.tokens.get(self.pos).copied().ok_or_else(|| {
            self.err(
                self.last_line,
                format!("unexpected end of file: expected {what}"),
            )
        })?;
        self.pos += 1;
        Ok(t)
    }

    fn expect(&mut self, word: &str) -> Result<Token<'a>> {
        let t = self.next(&format!("{word:?}"))?;
        if t.text != word {
            return Err(self.err(t.line, format!("expected {word:?}, found {:?}", t.text)));
        }
        Ok(t)
    }

    fn number(&mut self, what: &str) -> Result<f64> {
        let t = self.next(what)?;
        parse_number(t.text).ok_or_else(|| {
            self.err(
                t.line,
                format!("{what}: {:?} is not a finite number", t.text),
            )
        })
    }

    fn vector(&mut self, what: &str) -> Result<Vector3<f64>> {
        Ok(Vector3::new(
            self.number(what)?,
            self.number(what)?,
            self.number(what)?,
        ))
    }

    /// A joint's name: the words up to the `{` or the end of the line (3ds Max writes
    /// `JOINT Bip01 L Thigh`), one space between them.
    fn joint_name(&mut self, what: &str) -> Result<Token<'a>> {
        let first = self.next(what)?;
        let mut name = first;
        while let Some(t) = self.tokens.get(self.pos)
            && t.line == first.line
            && t.text != "{"
        {
            name.text = &self.text[self.offset(first.text)..self.offset(t.text) + t.text.len()];
            self.pos += 1;
        }
        Ok(name)
    }

    /// Where `token` (a slice of the text) starts in the text.
    fn offset(&self, token: &str) -> usize {
        token.as_ptr() as usize - self.text.as_ptr() as usize
    }

    /// Parse the body of a `ROOT`/`JOINT` block after its name; push it and its children.
    fn joint(
        &mut self,
        name: Token<'a>,
        parent: Option<usize>,
        joints: &mut Vec<BvhJoint>,
    ) -> Result<()> {
        if let Some(prev) = joints.iter().find(|j| j.name == name.text) {
            return Err(self.err(
                name.line,
                format!("joint name {:?} appears twice", prev.name),
            ));
        }
        self.expect("{")?;
        self.expect("OFFSET")?;
        let offset = self.vector("OFFSET")?;
        let kw = self.expect("CHANNELS")?;
        let count_tok = self.next("channel count")?;
        let count: usize = count_tok.text.parse().map_err(|_| {
            self.err(
                count_tok.line,
                format!("channel count {:?} is not a whole number", count_tok.text),
            )
        })?;
        if count > 6 {
            return Err(self.err(
                count_tok.line,
                format!("{count} channels: at most 6 are allowed"),
            ));
        }
        let mut channels = Vec::with_capacity(count);
        for _ in 0..count {
            let t = self.next("channel name")?;
            let c = BvhChannel::parse(t.text).ok_or_else(|| {
                if matches!(t.text, "JOINT" | "End" | "}" | "ROOT" | "MOTION") {
                    self.err(
                        t.line,
                        format!(
                            "CHANNELS on line {} declares {count} channels but lists {}",
                            kw.line,
                            channels.len()
                        ),
                    )
                } else {
                    self.err(t.line, format!("unknown channel name {:?}", t.text))
                }
            })?;
            if channels.contains(&c) {
                return Err(self.err(t.line, format!("channel {:?} listed twice", t.text)));
            }
            channels.push(c);
        }
        let index = joints.len();
        joints.push(BvhJoint {
            name: name.text.to_string(),
            parent,
            offset,
            channels,
            end_site: None,
        });
        loop {
            let t = self.next("JOINT, End Site or }")?;
            match t.text {
                "}" => return Ok(()),
                "JOINT" => {
                    let child = self.joint_name("joint name")?;
                    self.joint(child, Some(index), joints)?;
                }
                "End" => {
                    self.expect("Site")?;
                    if joints[index].end_site.is_some() {
                        return Err(self.err(t.line, "a second End Site in one joint"));
                    }
                    self.expect("{")?;
                    self.expect("OFFSET")?;
                    let end = self.vector("End Site OFFSET")?;
                    self.expect("}")?;
                    joints[index].end_site = Some(end);
                }
                "CHANNELS" => {
                    return Err(self.err(
                        t.line,
                        format!(
                            "extra CHANNELS in joint {:?}: the channel count on line {} is \
                             too small",
                            name.text, kw.line
                        ),
                    ));
                }
                other => {
                    return Err(self.err(
                        t.line,
                        format!("expected JOINT, End Site or }}, found {other:?}"),
                    ));
                }
            }
        }
    }
}

/// Parse a finite float (BVH files use plain decimal notation).
fn parse_number(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|x| x.is_finite())
}

impl Bvh {
    /// Parse BVH text; `path` names the file in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let tokens: Vec<Token> = text
            .lines()
            .enumerate()
            .flat_map(|(i, l)| {
                l.split_whitespace().map(move |w| Token {
                    text: w,
                    line: i + 1,
                })
            })
            .collect();
        let last_line = text.lines().count().max(1);
        let mut p = Parser {
            path,
            text,
            tokens,
            pos: 0,
            last_line,
        };
        p.expect("HIERARCHY")?;
        p.expect("ROOT")?;
        let root = p.joint_name("root joint name")?;
        let mut joints = Vec::new();
        p.joint(root, None, &mut joints)?;
        let motion = p.next("MOTION")?;
        if motion.text != "MOTION" {
            let msg = if motion.text == "ROOT" {
                "a second ROOT: only one hierarchy is supported".to_string()
            } else {
                format!("expected \"MOTION\", found {:?}", motion.text)
            };
            return Err(p.err(motion.line, msg));
        }
        p.expect("Frames:")?;
        let n_tok = p.next("frame count")?;
        let n_frames: usize = n_tok.text.parse().map_err(|_| {
            p.err(
                n_tok.line,
                format!("frame count {:?} is not a whole number", n_tok.text),
            )
        })?;
        p.expect("Frame")?;
        p.expect("Time:")?;
        let dt_line = p.tokens.get(p.pos).map_or(p.last_line, |t| t.line);
        let frame_time_secs = p.number("frame time")?;
        if frame_time_secs <= 0.0 {
            return Err(p.err(
                dt_line,
                format!("frame time {frame_time_secs} is not positive"),
            ));
        }
        let mut first_channel = Vec::with_capacity(joints.len());
        let mut n_channels = 0;
        for j in &joints {
            first_channel.push(n_channels);
            n_channels += j.channels.len();
        }
        // Frame values: one line per frame.
        let rest = &p.tokens[p.pos..];
        let mut values = Vec::with_capacity(n_frames * n_channels);
        let mut frames_read = 0;
        let mut i = 0;
        while i < rest.len() {
            let line = rest[i].line;
            let mut k = i;
            while k < rest.len() && rest[k].line == line {
                k += 1;
            }
            if frames_read == n_frames {
                return Err(p.err(
                    line,
                    format!("more frame lines than the {n_frames} declared by \"Frames:\""),
                ));
            }
            if k - i != n_channels {
                return Err(p.err(
                    line,
                    format!(
                        "frame {} has {} values, the hierarchy has {n_channels} channels",
                        frames_read,
                        k - i
                    ),
                ));
            }
            for t in &rest[i..k] {
                let x = parse_number(t.text).ok_or_else(|| {
                    p.err(
                        line,
                        format!("frame {frames_read}: {:?} is not a finite number", t.text),
                    )
                })?;
                values.push(x);
            }
            frames_read += 1;
            i = k;
        }
        if frames_read != n_frames {
            return Err(p.err(
                p.last_line,
                format!(
                    "file ends after {frames_read} frames, \"Frames:\" on line {} declares \
                     {n_frames}",
                    n_tok.line
                ),
            ));
        }
        if n_frames == 0 {
            return Err(p.err(n_tok.line, "no frames"));
        }
        Ok(Self {
            path: path.to_path_buf(),
            joints,
            first_channel,
            n_channels,
            frame_time_secs,
            values,
        })
    }

    /// A BVH from its parts (e.g. a stored clip), validated like a parsed file: joint 0 the only
    /// root, parents before children, unique names, at most one of each channel, finite offsets,
    /// a positive frame time, at least one frame of finite values. `path` names it in errors.
    pub fn from_parts(
        path: PathBuf,
        joints: Vec<BvhJoint>,
        frame_time_secs: f64,
        values: Vec<f64>,
    ) -> Result<Self> {
        let fault = |m: String| Error::format(&path, m);
        if joints.is_empty() {
            return Err(fault("no joints".into()));
        }
        let mut first_channel = Vec::with_capacity(joints.len());
        let mut n_channels = 0;
        for (j, joint) in joints.iter().enumerate() {
            let parent_ok = match (j, joint.parent) {
                (0, None) => true,
                (0, Some(_)) | (_, None) => false,
                (_, Some(p)) => p < j,
            };
            if !parent_ok {
                return Err(fault(format!(
                    "joint {j} ({}): parent {:?} is not a joint before it (joint 0 is the one root)",
                    joint.name, joint.parent
                )));
            }
            if joints[..j].iter().any(|o| o.name == joint.name) {
                return Err(fault(format!("joint name {:?} appears twice", joint.name)));
            }
            let finite = joint.offset.iter().all(|c| c.is_finite())
                && joint
                    .end_site
                    .is_none_or(|e| e.iter().all(|c| c.is_finite()));
            if !finite {
                return Err(fault(format!(
                    "joint {:?}: offset is not finite",
                    joint.name
                )));
            }
            let mut seen = joint.channels.clone();
            seen.sort_by_key(|c| c.axis());
            seen.dedup();
            if seen.len() != joint.channels.len() || joint.channels.len() > 6 {
                return Err(fault(format!(
                    "joint {:?}: channels {:?} repeat one",
                    joint.name, joint.channels
                )));
            }
            first_channel.push(n_channels);
            n_channels += joint.channels.len();
        }
        if !(frame_time_secs.is_finite() && frame_time_secs > 0.0) {
            return Err(fault(format!(
                "frame time {frame_time_secs} is not positive"
            )));
        }
        let this = Self {
            path: path.clone(),
            joints,
            first_channel,
            n_channels,
            frame_time_secs,
            values: Vec::new(),
        };
        this.with_values(values)
    }

    /// Read and parse a `.bvh` file.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = read_file(path)?;
        let text = String::from_utf8(bytes)
            .map_err(|e| Error::format(path, format!("not UTF-8 text: {e}")))?;
        Self::parse(&text, path)
    }

    /// The file this was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Joints, parents before children.
    pub fn joints(&self) -> &[BvhJoint] {
        &self.joints
    }

    /// Seconds per frame.
    pub fn frame_time_secs(&self) -> f64 {
        self.frame_time_secs
    }

    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.values.len() / self.n_channels.max(1)
    }

    /// Values of frame `i` (all channels, file order).
    pub fn frame(&self, i: usize) -> &[f64] {
        &self.values[i * self.n_channels..(i + 1) * self.n_channels]
    }

    /// Local translation (offset + position channels) and rotation of joint `j` in frame `i`.
    pub fn local_transform(&self, i: usize, j: usize) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let joint = &self.joints[j];
        let values = &self.frame(i)[self.first_channel[j]..];
        let mut t = joint.offset;
        let mut r = UnitQuaternion::identity();
        for (c, v) in joint.channels.iter().zip(values) {
            let (axis, is_rotation) = c.axis();
            if is_rotation {
                let mut a = Vector3::zeros();
                a[axis] = 1.0;
                r *= UnitQuaternion::from_axis_angle(&Unit::new_unchecked(a), v.to_radians());
            } else {
                t[axis] += v;
            }
        }
        (t, r)
    }

    /// World rotation of every joint in frame `i`.
    pub fn world_rotations(&self, i: usize) -> Vec<UnitQuaternion<f64>> {
        let mut q: Vec<UnitQuaternion<f64>> = Vec::with_capacity(self.joints.len());
        for (j, joint) in self.joints.iter().enumerate() {
            let (_, r) = self.local_transform(i, j);
            q.push(match joint.parent {
                None => r,
                Some(p) => q[p] * r,
            });
        }
        q
    }

    /// World position of the root joint in frame `i` (offset + position channels).
    pub fn root_position(&self, i: usize) -> Vector3<f64> {
        self.local_transform(i, 0).0
    }

    /// World position of every joint in frame `i` (offsets and position channels turned by the
    /// parents' world rotations), in the file's units.
    pub fn world_positions(&self, i: usize) -> Vec<Vector3<f64>> {
        let q = self.world_rotations(i);
        let mut p: Vec<Vector3<f64>> = Vec::with_capacity(self.joints.len());
        for (j, joint) in self.joints.iter().enumerate() {
            let (t, _) = self.local_transform(i, j);
            p.push(match joint.parent {
                None => t,
                Some(parent) => p[parent] + q[parent] * t,
            });
        }
        p
    }

    /// The same hierarchy with other frames: `values` holds `n × channels` numbers, row-major
    /// (e.g. a range of this file's frames, or one all-zero frame for the rest pose).
    pub fn with_values(&self, values: Vec<f64>) -> Result<Self> {
        let n = self.n_channels.max(1);
        if values.is_empty() || !values.len().is_multiple_of(n) {
            return Err(Error::format(
                &self.path,
                format!(
                    "{} values are not a whole, non-zero number of frames of {n} channels",
                    values.len()
                ),
            ));
        }
        if let Some(k) = values.iter().position(|x| !x.is_finite()) {
            return Err(Error::format(
                &self.path,
                format!("frame {}: value {} is not finite", k / n, values[k]),
            ));
        }
        Ok(Self {
            values,
            ..self.clone()
        })
    }

    /// Frames `start..start + len` of this file (errors when out of range).
    pub fn frames_range(&self, start: usize, len: usize) -> Result<Self> {
        let n = self.n_frames();
        if len == 0 || start + len > n {
            return Err(Error::format(
                &self.path,
                format!("frames {start}..{} of a file of {n} frames", start + len),
            ));
        }
        let c = self.n_channels;
        self.with_values(self.values[start * c..(start + len) * c].to_vec())
    }

    /// The number of values per frame.
    pub fn n_channels(&self) -> usize {
        self.n_channels
    }

    /// All frame values, `n_frames × n_channels`, row-major.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Rest (all channels zero) world positions of the joints, from the offsets.
    pub fn rest_positions(&self) -> Vec<Vector3<f64>> {
        let mut p: Vec<Vector3<f64>> = Vec::with_capacity(self.joints.len());
        for joint in &self.joints {
            let x = match joint.parent {
                None => joint.offset,
                Some(q) => p[q] + joint.offset,
            };
            p.push(x);
        }
        p
    }
}

/// The rig's name for a CMU BVH bone name.
pub fn cmu_to_rig_name(name: &str) -> &str {
    match name {
        "LeftHandIndex1" => "LeftHandFinger1",
        "RightHandIndex1" => "RightHandFinger1",
        other => other,
    }
}

/// Options of [`retarget_bvh`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BvhRetargetOptions {
    /// For a skeleton [`crate::map_bvh_joints`] cannot match by its structure: drop the joints
    /// without a rig joint's name (listed in the report) instead of failing.
    pub lenient: bool,
    /// Keep frame 0 even when it is a T-pose added by the converter
    /// ([`crate::detect_tpose_frame`]); by default such a frame is dropped.
    pub keep_tpose_frame: bool,
}

/// What [`retarget_bvh`] did besides producing the motion.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhRetargetReport {
    /// Which rig joint each joint of the file drives, and how they were matched.
    pub joint_map: BvhJointMap,
    /// BVH joints that drive no rig joint (file order): fingers, eyes, end joints of a file
    /// matched by its structure; those a lenient retarget dropped.
    pub dropped_joints: Vec<String>,
    /// Rig joints the file does not drive (they keep their rest relation to their parent).
    pub undriven_joints: Vec<String>,
    /// Factor from the file's length unit to metres (our hip height / the file's).
    pub translation_scale: f64,
    /// Whether the file's subject faced −Z and was turned 180° about +Y.
    pub turned_around: bool,
    /// For a file whose rest pose does not stand (head not above the hips along +Y: LAFAN1's),
    /// the rotation from a standing rest facing +Z to the file's: up from the root to the head,
    /// left from the right thigh to the left (`None`: the file's rest stands).
    pub rest_frame: Option<UnitQuaternion<f64>>,
    /// The file's frame rate.
    pub source_fps: f64,
    /// What the T-pose detector measured on frame 0 (`None`: too few frames or limbs).
    pub tpose_frame: Option<TposeFrame>,
    /// Whether frame 0 was dropped as an added T-pose (the motion starts at frame 1).
    pub tpose_frame_dropped: bool,
}

/// The file's rest pose as [`SourceRest`] directions for `skeleton` (`rig_of_bvh`: the rig
/// joint of each BVH joint), turned by `turn`.
fn bvh_source_rest(
    bvh: &Bvh,
    skeleton: &sartor_core::Skeleton,
    bvh_of_rig: &[Option<usize>],
    turn: &UnitQuaternion<f64>,
) -> Result<SourceRest> {
    let rest = bvh.rest_positions();
    let positions: Vec<Option<Vector3<f64>>> = bvh_of_rig
        .iter()
        .map(|b| b.map(|b| turn * rest[b]))
        .collect();
    SourceRest::from_positions(skeleton.names(), &positions, |j, c| {
        match (bvh_of_rig[j], bvh_of_rig[c]) {
            (Some(bj), Some(bc)) => bvh.joints[bc].parent == Some(bj),
            _ => false,
        }
    })
    .map_err(|e| e.in_file(bvh.path()))
}

/// Retarget a BVH onto `body`, at the file's frame rate (see the module docs for the rules).
pub fn retarget_bvh_native_rate(
    bvh: &Bvh,
    body: &RetargetBody,
    options: &BvhRetargetOptions,
) -> Result<(Motion, BvhRetargetReport)> {
    let path = bvh.path();
    let skeleton = body.skeleton();
    // Map BVH joints onto rig joints.
    let joint_map = match map_bvh_joints(bvh) {
        Ok(map) => map,
        Err(why) => name_map_leniently(bvh, options, &why)?,
    };
    let mut bvh_of_rig: Vec<Option<usize>> = vec![None; skeleton.n_joints()];
    let mut dropped_joints = Vec::new();
    for (b, (r, joint)) in joint_map.rig_joints.iter().zip(&bvh.joints).enumerate() {
        match r.and_then(|r| skeleton.index_of(r)) {
            Some(r) => {
                if let Some(prev) = bvh_of_rig[r] {
                    return Err(Error::format(
                        path,
                        format!(
                            "joints {:?} and {:?} both map onto rig joint {:?}",
                            bvh.joints[prev].name,
                            joint.name,
                            skeleton.names()[r]
                        ),
                    ));
                }
                bvh_of_rig[r] = Some(b);
            }
            None => dropped_joints.push(joint.name.clone()),
        }
    }
    // The hips: the file's root, or a joint below a reference node (whose motion reaches it).
    let Some(hips) = bvh_of_rig[0] else {
        return Err(Error::format(
            path,
            format!(
                "no joint drives the rig's root {:?} (the file's root is {:?})",
                skeleton.names()[0],
                bvh.joints[0].name
            ),
        ));
    };
    let hips_position = |i: usize| {
        if hips == 0 {
            bvh.root_position(i)
        } else {
            bvh.world_positions(i)[hips]
        }
    };
    let undriven_joints = bvh_of_rig
        .iter()
        .enumerate()
        .filter(|(_, b)| b.is_none())
        .map(|(r, _)| skeleton.names()[r].clone())
        .collect();

    // Axes: Y up; left on +X, else turn around. A rest pose that does not stand (LAFAN1's
    // lies along +X) is stood up first.
    let rest = bvh.rest_positions();
    let bvh_names = joint_map.names(bvh);
    let find = |n: &str| bvh_names.iter().position(|x| x == n);
    let stands = |p: &[Vector3<f64>]| {
        find("Head").is_none_or(|head| {
            let up = p[head] - p[hips];
            up.y > up.x.abs().max(up.z.abs())
        })
    };
    let rest_frame = if stands(&rest) {
        None
    } else {
        let frame = standing_frame(&rest, &find).ok_or_else(|| {
            Error::format(
                path,
                "the rest pose does not stand (head above the hips along +Y) and lacks a \
                 head or two thighs to stand it up by",
            )
        })?;
        if !stands(&bvh.world_positions(0)) {
            let up =
                bvh.world_positions(0)[find("Head").expect("stands() found it")] - hips_position(0);
            return Err(Error::format(
                path,
                format!(
                    "neither the rest pose nor frame 1 has the head above the hips: in frame 1 \
                     it lies at {up:?} from the root; expected a Y-up file"
                ),
            ));
        }
        Some(frame)
    };
    let stood: Vec<Vector3<f64>> = match &rest_frame {
        Some(r) => rest.iter().map(|p| r.inverse() * p).collect(),
        None => rest.clone(),
    };
    let turned_around = [("LeftUpLeg", "RightUpLeg"), ("LeftArm", "RightArm")]
        .iter()
        .find_map(|(l, r)| Some(stood[find(l)?].x < stood[find(r)?].x))
        .unwrap_or(false);
    let turn = if turned_around {
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI)
    } else {
        UnitQuaternion::identity()
    };
    let orient = match &rest_frame {
        Some(r) => turn * r.inverse(),
        None => turn,
    };

    let rest_change = body.rest_change(&bvh_source_rest(bvh, skeleton, &bvh_of_rig, &orient)?)?;

    // Units: hip heights, both in the file's rest posture.
    // A rest that does not stand need not hold the legs below the hips (LAFAN1's points every
    // bone along +X): there, thigh and shin lengths, both legs' mean.
    let (bvh_hip, our_hip) = if rest_frame.is_none() {
        (
            hip_height(&bvh_names, &stood),
            body.hip_height_in_m(&rest_change)?,
        )
    } else {
        let ours: Vec<String> = skeleton.names().to_vec();
        (
            leg_length(&bvh_names, &rest).unwrap_or(f64::NAN),
            leg_length(&ours, body.rest_joints_m()).unwrap_or(f64::NAN),
        )
    };
    if !(bvh_hip > 0.0 && our_hip > 0.0) {
        return Err(Error::format(
            path,
            format!(
                "cannot scale translations: rest hip height (or leg length) {bvh_hip} in the \
                 file, {our_hip} m in the body"
            ),
        ));
    }
    let scale = our_hip / bvh_hip;

    let tpose_frame = detect_tpose_frame_mapped(bvh, &joint_map);
    let tpose_frame_dropped =
        !options.keep_tpose_frame && tpose_frame.as_ref().is_some_and(|t| t.is_added_tpose);
    // After the T-pose, blank frames (every channel 0) go too.
    let start = first_performance_frame_mapped(bvh, &joint_map, !options.keep_tpose_frame);
    let first = hips_position(start);
    let mut frames = Vec::with_capacity(bvh.n_frames() - start);
    let mut source = vec![None; skeleton.n_joints()];
    for i in start..bvh.n_frames() {
        let q = bvh.world_rotations(i);
        for (r, b) in bvh_of_rig.iter().enumerate() {
            source[r] = b.map(|b| match &rest_frame {
                Some(frame) => turn * q[b] * turn.inverse() * frame,
                None => turn * q[b] * turn.inverse(),
            });
        }
        let d = turn * (hips_position(i) - first) * scale;
        frames.push(body.pose_from_source(&rest_change, &source, d));
    }
    let name = path
        .file_stem()
        .map_or_else(|| "bvh".to_string(), |s| s.to_string_lossy().into_owned());
    let source_fps = snapped_rate(bvh.frame_time_secs);
    let motion = Motion::new(name, source_fps, skeleton.names().to_vec(), frames)
        .map_err(|e| e.in_file(path))?;
    Ok((
        motion,
        BvhRetargetReport {
            joint_map,
            rest_frame,
            dropped_joints,
            undriven_joints,
            translation_scale: scale,
            turned_around,
            source_fps,
            tpose_frame,
            tpose_frame_dropped,
        },
    ))
}

/// The joints of a file whose structure [`map_bvh_joints`] did not understand (`why`), by name
/// where [`BvhRetargetOptions::lenient`] allows: joints without a rig joint's name are dropped;
/// otherwise an error naming them.
fn name_map_leniently(bvh: &Bvh, options: &BvhRetargetOptions, why: &str) -> Result<BvhJointMap> {
    let map = BvhJointMap::by_name(bvh);
    if !options.lenient {
        let (_, unknown) = map.pairs(bvh);
        return Err(Error::format(
            bvh.path(),
            format!(
                "joints not in the rig: {}; matching by the skeleton's structure failed: {why} \
                 (retarget leniently to drop them)",
                unknown.join(", ")
            ),
        ));
    }
    Ok(map)
}

/// Thigh plus shin length, the mean of both legs, of the joints `joints` named `names` (rig
/// names); `None` without both legs' hip, knee and ankle.
fn leg_length(names: &[String], joints: &[Vector3<f64>]) -> Option<f64> {
    let at = |n: &str| Some(joints[names.iter().position(|x| x == n)?]);
    let leg = |side: &str| -> Option<f64> {
        let (hip, knee) = (at(&format!("{side}UpLeg"))?, at(&format!("{side}Leg"))?);
        Some((knee - hip).norm() + (at(&format!("{side}Foot"))? - knee).norm())
    };
    Some(0.5 * (leg("Left")? + leg("Right")?))
}

/// The rotation from our axes (+X left, +Y up, +Z forward) to a rest pose's own: up from the
/// hips to the head, left from the right thigh to the left one (made square to up), forward
/// their cross product; `None` without a head and two thighs (`find` gives a rig joint's file
/// joint), or where they do not span a frame.
fn standing_frame(
    rest: &[Vector3<f64>],
    find: &impl Fn(&str) -> Option<usize>,
) -> Option<UnitQuaternion<f64>> {
    let up = (rest[find("Head")?] - rest[find("Hips")?]).try_normalize(1e-9)?;
    let left = rest[find("LeftUpLeg")?] - rest[find("RightUpLeg")?];
    let left = (left - up * left.dot(&up)).try_normalize(1e-9)?;
    let forward = left.cross(&up);
    let basis = nalgebra::Matrix3::from_columns(&[left, up, forward]);
    Some(UnitQuaternion::from_matrix(&basis))
}

/// Frames per second for a frame time. Files write the frame time with few digits (CMU's
/// `0.0083333`), so a rate within 0.01 % of a whole number is taken as that number.
fn snapped_rate(frame_time_secs: f64) -> f64 {
    let fps = 1.0 / frame_time_secs;
    let whole = fps.round();
    if whole >= 1.0 && (fps - whole).abs() <= 1e-4 * whole {
        whole
    } else {
        fps
    }
}

/// Retarget a BVH onto `body` and resample to [`sartor_core::FPS`].
pub fn retarget_bvh(
    bvh: &Bvh,
    body: &RetargetBody,
    options: &BvhRetargetOptions,
) -> Result<(Motion, BvhRetargetReport)> {
    let (m, report) = retarget_bvh_native_rate(bvh, body, options)?;
    let m = m
        .resample(sartor_core::FPS)
        .map_err(|e| e.in_file(bvh.path()))?;
    Ok((m, report))
}

/// Read a `.bvh` file, retarget it onto `body` and resample to [`sartor_core::FPS`].
pub fn load_bvh_motion(
    path: &Path,
    body: &RetargetBody,
    options: &BvhRetargetOptions,
) -> Result<(Motion, BvhRetargetReport)> {
    retarget_bvh(&Bvh::load(path)?, body, options)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT LeftUpLeg
  {
    OFFSET 1 -1 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -4 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0083333
0 10 0 0 0 0 0 0 0
1 10 2 0 90 0 30 0 0
";

    #[test]
    fn parses_a_tiny_file() {
        let b = Bvh::parse(TINY, Path::new("tiny.bvh")).expect("parse");
        assert_eq!(b.joints().len(), 2);
        assert_eq!(b.n_frames(), 2);
        assert_eq!(b.joints()[1].end_site, Some(Vector3::new(0.0, -4.0, 0.0)));
        assert_eq!(b.root_position(1), Vector3::new(1.0, 10.0, 2.0));
        let q = b.world_rotations(1);
        // Root: Zrot 0, Yrot 90, Xrot 0.
        let want = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 90f64.to_radians());
        assert!(q[0].angle_to(&want) < 1e-12);
        let z30 = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 30f64.to_radians());
        assert!(q[1].angle_to(&(want * z30)) < 1e-12);
    }

    #[test]
    fn errors_name_file_and_line() {
        let bad = TINY.replace("Yrotation\n", "Wrotation\n");
        let e = Bvh::parse(&bad, Path::new("t.bvh")).expect_err("unknown channel");
        assert!(e.to_string().starts_with("t.bvh:9:"), "{e}");
        let e = Bvh::parse(&TINY.replace("Frames: 2", "Frames: 3"), Path::new("t.bvh"))
            .expect_err("missing frame");
        assert!(e.to_string().starts_with("t.bvh:20:"), "{e}");
    }
}
