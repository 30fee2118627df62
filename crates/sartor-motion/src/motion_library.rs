//! Imported motion clips (`datasets/motions/<set>/<clip>`), clip sets and windows of long
//! clips.
//!
//! # Stored clips
//!
//! A mocap clip is imported once ([`StoredClip::from_bvh`], `cargo xtask import-motions`) as
//! the BVH's own skeleton and channel values — not a retargeted motion, so a better retarget
//! never needs a re-import — in two files beside each other:
//!
//! - `<clip>.json` ([`StoredClipHeader`]): the source file and its SHA-256, the hierarchy (names,
//!   parents, offsets, channel order, end sites), the frame rate, which source frames were kept,
//!   whether the converter's T-pose frame was dropped, which channels are stored, and the
//!   SHA-256 of the tensor file;
//! - `<clip>.safetensors`: one f32 tensor `channels`, `frames × stored channels`. Channels that
//!   are zero in every frame of the clip (CMU's hip sockets and collars, the fingers' unused
//!   axes) are not stored.
//!
//! The frames kept: the converter's T-pose frame and blank frames after it are dropped
//! ([`crate::first_performance_frame`]),
//! then every `k`-th frame from the first kept one, `k = source rate / 30` when that is a whole
//! number (CMU's 120 fps → every 4th frame: exactly the frames resampling to [`crate::FPS`]
//! lands on), else every frame at the source rate. f32 holds the files' 4-decimal values to
//! within 3.0e-5 (degrees or CMU units; the largest difference over the 60 CMU clips, listed
//! per clip in `datasets/motions/cmu/PROVENANCE.md`). The 60 clips take 4.5 MB.
//! [`load_stored_clip`] rebuilds the [`Bvh`]; [`crate::load_motion`] retargets it at load.
//! Everything written is deterministic: re-importing reproduces the files byte for byte.
//!
//! # Names, sets, windows
//!
//! - `cmu/05_02`: the stored clip `<motions_dir>/cmu/05_02.json` (any name with a `/` and no
//!   file extension);
//! - `cmu/*`: a set, every stored clip of `<motions_dir>/cmu` in name order
//!   ([`expand_motion_set`]);
//! - `<motion>@<start>+<frames>`: a window of any motion ([`MotionWindow`]), in frames at
//!   [`crate::FPS`] after resampling: `cmu/05_02@120+90` is frames 120..210 (4 s to 7 s). A
//!   window holds exactly those frames of the whole clip, root translation included (it is not
//!   moved back to the origin). [`motion_file_stem`] turns any of these into a file name.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::bvh::{Bvh, BvhChannel, BvhJoint};
use crate::bvh_tpose::{detect_tpose_frame, first_performance_frame};
use crate::{Error, FPS, Motion, Result};
use sartor_core::io::{
    OwnedTensor, TensorFile, read_file, serialize_tensors, sha256_hex, write_atomic,
};

/// The acknowledgement CMU asks to keep wherever its motion capture data, or data derived from
/// it, is shipped.
pub const CMU_ACKNOWLEDGEMENT: &str = "The data used in this project was obtained from \
mocap.cs.cmu.edu. The database was created with funding from NSF EIA-0196217.";

/// Format name in a stored clip's header.
pub const STORED_CLIP_FORMAT: &str = "sartor-bvh-clip";

/// One joint of a stored clip's hierarchy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoredJoint {
    /// Name as in the source file.
    pub name: String,
    /// Index of the parent joint (`None` for the root).
    pub parent: Option<usize>,
    /// Rest offset from the parent, source units.
    pub offset: [f64; 3],
    /// Channel names in file order.
    pub channels: Vec<String>,
    /// End site offset, if any.
    pub end_site: Option<[f64; 3]>,
}

/// Where a stored clip came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClipSource {
    /// The source file's name.
    pub file: String,
    /// SHA-256 of the source file.
    pub sha256: String,
    /// Frames in the source file.
    pub frames: usize,
    /// The source's frame rate.
    pub fps: f64,
}

/// The JSON header of a stored clip (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoredClipHeader {
    /// [`STORED_CLIP_FORMAT`].
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// The clip's name, e.g. `cmu/05_02`.
    pub name: String,
    /// The source file.
    pub source: ClipSource,
    /// What the data's owners ask to keep with it.
    pub acknowledgement: String,
    /// Frames per second of the stored frames.
    pub fps: f64,
    /// Stored frames.
    pub frames: usize,
    /// The source frame the first stored frame is.
    pub first_source_frame: usize,
    /// Source frames between stored frames.
    pub source_frame_step: usize,
    /// Whether the source's frame 0 was a converter's T-pose, dropped.
    pub tpose_frame_dropped: bool,
    /// The hierarchy.
    pub joints: Vec<StoredJoint>,
    /// The source channels (indices in file order) stored as the tensor's columns; every other
    /// channel is zero in every frame.
    pub stored_channels: Vec<usize>,
    /// SHA-256 of `<clip>.safetensors`.
    pub tensors_sha256: String,
}

/// A clip ready to be written: header and stored values.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredClip {
    /// The header (its `tensors_sha256` is filled in by [`Self::to_bytes`]).
    pub header: StoredClipHeader,
    /// `frames × stored channels`, row-major.
    pub values: Vec<f32>,
}

impl StoredClip {
    /// Import a parsed BVH as clip `name` (`source_sha256`: the file's hash, for provenance):
    /// drop the converter's T-pose frame, keep every `k`-th frame (see the module docs), store
    /// the channels that are not zero throughout.
    pub fn from_bvh(
        bvh: &Bvh,
        name: &str,
        source_sha256: &str,
        acknowledgement: &str,
    ) -> Result<Self> {
        let source_fps = 1.0 / bvh.frame_time_secs();
        let ratio = source_fps / FPS;
        let step = if (ratio - ratio.round()).abs() <= 1e-4 * ratio && ratio.round() >= 1.0 {
            ratio.round() as usize
        } else {
            1
        };
        let fps = if step > 1 { FPS } else { snapped(source_fps) };
        let dropped = detect_tpose_frame(bvh).is_some_and(|t| t.is_added_tpose);
        let first = first_performance_frame(bvh, true);
        let kept: Vec<usize> = (first..bvh.n_frames()).step_by(step).collect();
        if kept.is_empty() {
            return Err(Error::format(
                bvh.path(),
                "no frames after the T-pose frame",
            ));
        }
        let c = bvh.n_channels();
        let stored_channels: Vec<usize> = (0..c)
            .filter(|&k| kept.iter().any(|&i| bvh.values()[i * c + k] != 0.0))
            .collect();
        let mut values = Vec::with_capacity(kept.len() * stored_channels.len());
        for &i in &kept {
            for &k in &stored_channels {
                values.push(bvh.values()[i * c + k] as f32);
            }
        }
        let v3 = |v: &Vector3<f64>| [v.x, v.y, v.z];
        let joints = bvh
            .joints()
            .iter()
            .map(|j| StoredJoint {
                name: j.name.clone(),
                parent: j.parent,
                offset: v3(&j.offset),
                channels: j.channels.iter().map(|c| c.name().to_string()).collect(),
                end_site: j.end_site.as_ref().map(v3),
            })
            .collect();
        let file = bvh
            .path()
            .file_name()
            .map_or_else(String::new, |f| f.to_string_lossy().into_owned());
        Ok(Self {
            header: StoredClipHeader {
                format: STORED_CLIP_FORMAT.into(),
                version: 1,
                name: name.into(),
                source: ClipSource {
                    file,
                    sha256: source_sha256.into(),
                    frames: bvh.n_frames(),
                    fps: snapped(source_fps),
                },
                acknowledgement: acknowledgement.into(),
                fps,
                frames: kept.len(),
                first_source_frame: first,
                source_frame_step: step,
                tpose_frame_dropped: dropped,
                joints,
                stored_channels,
                tensors_sha256: String::new(),
            },
            values,
        })
    }

    /// The two files' bytes: `(json, safetensors)`, deterministic.
    pub fn to_bytes(&self) -> Result<(Vec<u8>, Vec<u8>)> {
        let mut tensors = BTreeMap::new();
        tensors.insert(
            "channels".to_string(),
            OwnedTensor::f32(
                &[self.header.frames, self.header.stored_channels.len()],
                self.values.iter().copied(),
            ),
        );
        let st = serialize_tensors(&tensors, None)?;
        let mut header = self.header.clone();
        header.tensors_sha256 = sha256_hex(&st);
        let mut json = serde_json::to_vec_pretty(&header)
            .map_err(|e| Error::invalid("stored clip", e.to_string()))?;
        json.push(b'\n');
        Ok((json, st))
    }

    /// Write `<dir>/<stem>.json` and `<dir>/<stem>.safetensors` (atomically; the stem is the
    /// part of the name after the last `/`).
    pub fn save(&self, dir: &Path) -> Result<()> {
        let (json, st) = self.to_bytes()?;
        let stem = self
            .header
            .name
            .rsplit('/')
            .next()
            .unwrap_or(&self.header.name);
        write_atomic(&dir.join(format!("{stem}.safetensors")), &st)?;
        write_atomic(&dir.join(format!("{stem}.json")), &json)
    }
}

/// A rate within 0.01 % of a whole number is that number (files write `0.0083333`).
fn snapped(fps: f64) -> f64 {
    let whole = fps.round();
    if whole >= 1.0 && (fps - whole).abs() <= 1e-4 * whole {
        whole
    } else {
        fps
    }
}

/// The header of stored clip `name` in `motions_dir`, if its JSON exists.
fn header_path(motions_dir: &Path, name: &str) -> PathBuf {
    motions_dir.join(format!("{name}.json"))
}

/// Whether `name` is a stored clip in `motions_dir` (its header exists).
pub fn is_stored_clip(motions_dir: &Path, name: &str) -> bool {
    !name.contains('.') && name.contains('/') && header_path(motions_dir, name).is_file()
}

/// Load stored clip `name` (e.g. `cmu/05_02`) from `motions_dir` as a [`Bvh`] (frames as
/// stored: the T-pose frame already dropped), checking the tensor file's hash.
pub fn load_stored_clip(motions_dir: &Path, name: &str) -> Result<Bvh> {
    let json_path = header_path(motions_dir, name);
    let json = read_file(&json_path)?;
    let tensors = read_file(&json_path.with_extension("safetensors"))?;
    stored_clip_from_bytes(&json_path, &json, tensors)
}

/// [`load_stored_clip`] from the bytes of the clip's JSON header (read from `json_path`, named
/// in errors only) and of its safetensors file beside it: how a web page, which has no file
/// system, loads a clip it fetched.
pub fn stored_clip_from_bytes(json_path: &Path, json: &[u8], tensor_bytes: Vec<u8>) -> Result<Bvh> {
    let header: StoredClipHeader = serde_json::from_slice(json)
        .map_err(|e| Error::parse(json_path, e.line(), e.to_string()))?;
    let fault = |m: String| Error::format(json_path, m);
    if header.format != STORED_CLIP_FORMAT || header.version != 1 {
        return Err(fault(format!(
            "format {:?} version {} is not {STORED_CLIP_FORMAT} version 1",
            header.format, header.version
        )));
    }
    let st_path = json_path.with_extension("safetensors");
    let bytes = tensor_bytes;
    if sha256_hex(&bytes) != header.tensors_sha256 {
        return Err(Error::format(
            &st_path,
            format!(
                "SHA-256 differs from the one {} records",
                json_path.display()
            ),
        ));
    }
    let tensors = TensorFile::from_bytes(&st_path, bytes)?;
    let k = header.stored_channels.len();
    let (_, values) = tensors.f32("channels", &[Some(header.frames), Some(k)])?;
    let mut joints = Vec::with_capacity(header.joints.len());
    for j in &header.joints {
        let channels = j
            .channels
            .iter()
            .map(|c| {
                BvhChannel::from_name(c)
                    .ok_or_else(|| fault(format!("joint {:?}: unknown channel {c:?}", j.name)))
            })
            .collect::<Result<Vec<_>>>()?;
        joints.push(BvhJoint {
            name: j.name.clone(),
            parent: j.parent,
            offset: Vector3::from(j.offset),
            channels,
            end_site: j.end_site.map(Vector3::from),
        });
    }
    let n_channels: usize = joints.iter().map(|j| j.channels.len()).sum();
    if let Some(&bad) = header.stored_channels.iter().find(|&&c| c >= n_channels) {
        return Err(fault(format!(
            "stored channel {bad} of a hierarchy with {n_channels} channels"
        )));
    }
    let mut full = vec![0.0; header.frames * n_channels];
    for i in 0..header.frames {
        for (col, &c) in header.stored_channels.iter().enumerate() {
            full[i * n_channels + c] = f64::from(values[i * k + col]);
        }
    }
    if !(header.fps.is_finite() && header.fps > 0.0) {
        return Err(fault(format!("frame rate {} is not positive", header.fps)));
    }
    Bvh::from_parts(st_path, joints, 1.0 / header.fps, full)
}

/// The stored clips of set `spec` (`<set>/*`, e.g. `cmu/*`) in `motions_dir`, in name order:
/// every `<motions_dir>/<set>/<clip>.json` that is a stored clip's header.
pub fn expand_motion_set(motions_dir: &Path, spec: &str) -> Result<Vec<String>> {
    let set = spec.strip_suffix("/*").ok_or_else(|| {
        Error::invalid("motion set", format!("{spec:?} is not of the form <set>/*"))
    })?;
    let dir = motions_dir.join(set);
    let entries = std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut names = Vec::new();
    for e in entries {
        let path = e.map_err(|e| Error::io(&dir, e))?.path();
        if path.extension().is_some_and(|x| x == "json")
            && path.with_extension("safetensors").is_file()
            && let Some(stem) = path.file_stem()
        {
            names.push(format!("{set}/{}", stem.to_string_lossy()));
        }
    }
    names.sort();
    if names.is_empty() {
        return Err(Error::invalid(
            "motion set",
            format!("{spec:?}: no stored clips in {}", dir.display()),
        ));
    }
    Ok(names)
}

/// A window of a motion: `frames` frames from frame `start`, at [`crate::FPS`] after
/// resampling. Written `<motion>@<start>+<frames>` (e.g. `cmu/05_02@120+90`).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct MotionWindow {
    /// The whole motion's spec.
    pub motion: String,
    /// First frame.
    pub start: usize,
    /// Number of frames.
    pub frames: usize,
}

impl MotionWindow {
    /// Parse `<motion>@<start>+<frames>`; `None` when `spec` has no window suffix. Errors on a
    /// malformed or empty window.
    pub fn parse(spec: &str) -> Result<Option<Self>> {
        let Some((motion, window)) = spec.rsplit_once('@') else {
            return Ok(None);
        };
        let bad = || {
            Error::invalid(
                "motion window",
                format!("{spec:?}: expected <motion>@<start>+<frames> (frames at 30 fps)"),
            )
        };
        let (start, frames) = window.split_once('+').ok_or_else(bad)?;
        let start: usize = start.parse().map_err(|_| bad())?;
        let frames: usize = frames.parse().map_err(|_| bad())?;
        if motion.is_empty() || frames == 0 {
            return Err(bad());
        }
        Ok(Some(Self {
            motion: motion.to_string(),
            start,
            frames,
        }))
    }

    /// Cut the window out of the whole motion (a motion at [`crate::FPS`]); the result is named
    /// like the window.
    pub fn cut(&self, whole: &Motion) -> Result<Motion> {
        let end = self.start + self.frames;
        if end > whole.n_frames() {
            return Err(Error::invalid(
                "motion window",
                format!(
                    "{self}: frames {}..{end} of a motion of {} frames",
                    self.start,
                    whole.n_frames()
                ),
            ));
        }
        let frames = whole.frames()[self.start..end].to_vec();
        Motion::new(
            self.to_string(),
            whole.fps(),
            whole.joint_names().to_vec(),
            frames,
        )
    }
}

impl std::fmt::Display for MotionWindow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}@{}+{}", self.motion, self.start, self.frames)
    }
}

/// A file-name stem for a motion spec (a name, a set member, a window or a file path): the
/// path's stem for a file path (`/data/05_02.bvh` → `05_02`, keeping a window suffix), else
/// the spec with `/` turned into `-` (`cmu/05_02@120+90` → `cmu-05_02@120+90`). Characters
/// other than ASCII letters, digits and `-_@+.` become `_`.
pub fn motion_file_stem(spec: &str) -> String {
    let (motion, window) = match spec.rsplit_once('@') {
        Some((m, w)) if MotionWindow::parse(spec).is_ok_and(|w| w.is_some()) => {
            (m, format!("@{w}"))
        }
        _ => (spec, String::new()),
    };
    let lower = motion.to_ascii_lowercase();
    let base = if [".bvh", ".npz", ".json"].iter().any(|e| lower.ends_with(e)) {
        Path::new(motion)
            .file_stem()
            .map_or_else(|| motion.to_string(), |s| s.to_string_lossy().into_owned())
    } else {
        motion.replace('/', "-")
    };
    format!("{base}{window}")
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_@+.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_parse_and_format() {
        let w = MotionWindow::parse("cmu/05_02@120+90")
            .expect("valid")
            .expect("a window");
        assert_eq!(
            (w.motion.as_str(), w.start, w.frames),
            ("cmu/05_02", 120, 90)
        );
        assert_eq!(w.to_string(), "cmu/05_02@120+90");
        assert_eq!(MotionWindow::parse("cmu/05_02").expect("no window"), None);
        for bad in ["x@1", "x@a+2", "x@1+0", "@1+2", "x@1+-2"] {
            assert!(MotionWindow::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn file_stems_are_flat() {
        assert_eq!(motion_file_stem("cmu/05_02@120+90"), "cmu-05_02@120+90");
        assert_eq!(motion_file_stem("cmu/05_02"), "cmu-05_02");
        assert_eq!(motion_file_stem("/data/clips/05_02.bvh"), "05_02");
        assert_eq!(motion_file_stem("/data/clips/05_02.BVH@3+4"), "05_02@3+4");
        assert_eq!(motion_file_stem("walk_normal"), "walk_normal");
        assert_eq!(motion_file_stem("a b/c"), "a_b-c");
    }
}
