//! Motion: a sequence of poses at a fixed frame rate.

use std::path::Path;

use serde::{Deserialize, Serialize};

use sartor_core::io::{read_file, write_atomic};
use sartor_core::{Pose, interpolate_pose};

use crate::{Error, Result};

/// Poses sampled at `fps` frames per second, for the joints named in `joint_names` (the
/// skeleton's order).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Motion {
    name: String,
    fps: f64,
    joint_names: Vec<String>,
    frames: Vec<Pose>,
}

impl Motion {
    /// Build a motion, checking the frame rate, that there is at least one frame, and every pose.
    pub fn new(
        name: String,
        fps: f64,
        joint_names: Vec<String>,
        frames: Vec<Pose>,
    ) -> Result<Self> {
        if !(fps.is_finite() && fps > 0.0) {
            return Err(Error::invalid(
                "motion",
                format!("{name}: frame rate {fps} is not positive"),
            ));
        }
        if frames.is_empty() {
            return Err(Error::invalid("motion", format!("{name}: no frames")));
        }
        for (i, f) in frames.iter().enumerate() {
            f.validate(joint_names.len())
                .map_err(|e| Error::invalid("motion", format!("{name}: frame {i}: {e}")))?;
        }
        Ok(Self {
            name,
            fps,
            joint_names,
            frames,
        })
    }

    /// The motion's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The same motion under another name.
    pub fn renamed(mut self, name: String) -> Self {
        self.name = name;
        self
    }

    /// Frames per second.
    pub fn fps(&self) -> f64 {
        self.fps
    }

    /// Joint names, in the order of each pose's rotations.
    pub fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    /// The poses.
    pub fn frames(&self) -> &[Pose] {
        &self.frames
    }

    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.frames.len()
    }

    /// Duration in seconds (time of the last frame).
    pub fn duration_secs(&self) -> f64 {
        (self.frames.len() - 1) as f64 / self.fps
    }

    /// The pose at time `t_secs`, interpolated (slerp for rotations, lerp for translation) and
    /// clamped to the motion's range.
    pub fn sample(&self, t_secs: f64) -> Pose {
        let x = (t_secs * self.fps).clamp(0.0, (self.frames.len() - 1) as f64);
        let i = (x.floor() as usize).min(self.frames.len() - 1);
        let j = (i + 1).min(self.frames.len() - 1);
        interpolate_pose(&self.frames[i], &self.frames[j], x - i as f64)
    }

    /// Resample to `fps` (e.g. [`FPS`]) over the same duration.
    pub fn resample(&self, fps: f64) -> Result<Self> {
        if !(fps.is_finite() && fps > 0.0) {
            return Err(Error::invalid(
                "motion",
                format!("target frame rate {fps} is not positive"),
            ));
        }
        let n = (self.duration_secs() * fps + 1e-9).floor() as usize + 1;
        let frames = (0..n).map(|k| self.sample(k as f64 / fps)).collect();
        Self::new(self.name.clone(), fps, self.joint_names.clone(), frames)
    }

    /// Prepend `n_blend` frames that go from the rest pose (at the motion's first root translation
    /// and heading-free orientation) to the first frame, with a smooth (cubic ease) blend, so a
    /// simulation can start from rest.
    pub fn blended_from_rest(&self, n_blend: usize) -> Self {
        let first = &self.frames[0];
        let rest = Pose {
            root_translation_m: first.root_translation_m,
            ..Pose::rest(self.joint_names.len())
        };
        let mut frames = Vec::with_capacity(n_blend + self.frames.len());
        for k in 0..n_blend {
            let s = k as f64 / n_blend as f64;
            let eased = s * s * (3.0 - 2.0 * s);
            frames.push(interpolate_pose(&rest, first, eased));
        }
        frames.extend(self.frames.iter().cloned());
        Self {
            name: self.name.clone(),
            fps: self.fps,
            joint_names: self.joint_names.clone(),
            frames,
        }
    }

    /// A copy holding only frames `range`.
    pub fn slice(&self, range: std::ops::Range<usize>) -> Result<Self> {
        let frames = self
            .frames
            .get(range.clone())
            .ok_or_else(|| {
                Error::invalid(
                    "motion",
                    format!("frames {range:?} of {}", self.frames.len()),
                )
            })?
            .to_vec();
        Self::new(
            self.name.clone(),
            self.fps,
            self.joint_names.clone(),
            frames,
        )
    }

    /// Save as JSON (atomically).
    pub fn save_json(&self, path: &Path) -> Result<()> {
        let json = serde_json::to_vec(self).map_err(|e| Error::invalid("motion", e.to_string()))?;
        write_atomic(path, &json)
    }

    /// Load from JSON, validating every pose.
    pub fn load_json(path: &Path) -> Result<Self> {
        Self::from_json_bytes(path, &read_file(path)?)
    }

    /// Parse JSON bytes read from `path` (used in error messages only), validating every pose.
    pub fn from_json_bytes(path: &Path, bytes: &[u8]) -> Result<Self> {
        let raw: Motion = serde_json::from_slice(bytes)
            .map_err(|e| Error::parse(path, e.line(), e.to_string()))?;
        Self::new(raw.name, raw.fps, raw.joint_names, raw.frames).map_err(|e| e.in_file(path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};
    use sartor_core::FPS;

    fn swing(n: usize, fps: f64) -> Motion {
        let frames = (0..n)
            .map(|k| {
                let mut p = Pose::rest(2);
                p.local_rotations[1] =
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.01 * k as f64);
                p.root_translation_m.z = 0.1 * k as f64 / fps;
                p
            })
            .collect();
        Motion::new("swing".into(), fps, vec!["a".into(), "b".into()], frames).expect("valid")
    }

    #[test]
    fn resample_keeps_duration_and_interpolates() {
        let m = swing(121, 120.0); // 1 s
        let r = m.resample(FPS).expect("resample");
        assert_eq!(r.n_frames(), 31);
        assert!((r.duration_secs() - 1.0).abs() < 1e-12);
        // Frame 1 at 30 fps is frame 4 at 120 fps.
        assert!(
            r.frames()[1].local_rotations[1].angle_to(&m.frames()[4].local_rotations[1]) < 1e-12
        );
        assert!((r.frames()[30].root_translation_m.z - 0.1).abs() < 1e-12);
    }

    #[test]
    fn blend_starts_at_rest() {
        let m = swing(10, 30.0);
        let b = m.blended_from_rest(5);
        assert_eq!(b.n_frames(), 15);
        assert_eq!(b.frames()[0].local_rotations[1], UnitQuaternion::identity());
        assert_eq!(b.frames()[5], m.frames()[0]);
    }

    #[test]
    fn rejects_bad_motion() {
        assert!(Motion::new("x".into(), 0.0, vec![], vec![Pose::rest(0)]).is_err());
        assert!(Motion::new("x".into(), 30.0, vec!["a".into()], vec![]).is_err());
        assert!(Motion::new("x".into(), 30.0, vec!["a".into()], vec![Pose::rest(2)]).is_err());
    }
}
