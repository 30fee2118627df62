//! Per-frame pose features: what the wrinkle network sees of a pose. The one implementation
//! used by the dataset (training inputs) and the runtime (inference inputs), so the two can
//! never disagree.
//!
//! A [`PoseFeatureSpec`] names the joints whose local rotations enter (with a
//! [`RotationEncoding`]) and the root components ([`RootFeature`]). Bound to a skeleton it
//! becomes [`PoseFeatures`], which fills a caller-owned `f32` slice for each frame without
//! allocating. Layout: the joints in the order given, `encoding.width()` values each, then the
//! root components in the order given.
//!
//! The body frame is split like [`crate::split_heading`]: the world rotation of the root joint
//! `G_0 = heading · tilt`, `heading` about +Y. The root joint's own entry (if listed) encodes
//! `tilt` — the body's orientation relative to gravity, independent of where it faces; the
//! root velocities are expressed in the heading frame, so a walk looks the same in every
//! direction.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::skeleton::{Pose, Skeleton};
use crate::{Error, Result, split_heading};

/// How a rotation is written as numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RotationEncoding {
    /// The first two columns of the rotation matrix, column by column (6 values; continuous,
    /// Zhou et al. 2019).
    Rot6d,
    /// Unit quaternion `(x, y, z, w)` with `w ≥ 0` (4 values).
    Quaternion,
    /// Rotation vector, radians (3 values).
    AxisAngle,
}

impl RotationEncoding {
    /// Values per joint.
    pub fn width(self) -> usize {
        match self {
            Self::Rot6d => 6,
            Self::Quaternion => 4,
            Self::AxisAngle => 3,
        }
    }

    /// Write `q` into `out` (`width()` values).
    pub fn encode(self, q: &UnitQuaternion<f64>, out: &mut [f32]) {
        match self {
            Self::Rot6d => {
                let m: Matrix3<f64> = q.to_rotation_matrix().into_inner();
                for (k, o) in out.iter_mut().take(6).enumerate() {
                    *o = m[(k % 3, k / 3)] as f32;
                }
            }
            Self::Quaternion => {
                let c = q.as_ref().coords;
                let s = if c.w < 0.0 { -1.0 } else { 1.0 };
                for (o, v) in out.iter_mut().zip([c.x, c.y, c.z, c.w]) {
                    *o = (s * v) as f32;
                }
            }
            Self::AxisAngle => {
                let v = q.scaled_axis();
                for (o, v) in out.iter_mut().zip(v.iter()) {
                    *o = *v as f32;
                }
            }
        }
    }
}

/// One scalar describing the root's motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RootFeature {
    /// Root velocity along the heading frame's x (the body's left), m/s.
    VelX,
    /// Root velocity along +Y (up), m/s.
    VelY,
    /// Root velocity along the heading frame's z (forward), m/s.
    VelZ,
    /// Turning rate of the heading about +Y, rad/s.
    YawRate,
}

impl RootFeature {
    /// Every root feature, in the default order.
    pub const ALL: [RootFeature; 4] = [Self::VelX, Self::VelY, Self::VelZ, Self::YawRate];

    /// The feature's name (`vel_x`, `vel_y`, `vel_z`, `yaw_rate`).
    pub fn name(self) -> &'static str {
        match self {
            Self::VelX => "vel_x",
            Self::VelY => "vel_y",
            Self::VelZ => "vel_z",
            Self::YawRate => "yaw_rate",
        }
    }

    /// The feature with this name.
    pub fn from_name(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|f| f.name() == name)
            .ok_or_else(|| {
                Error::invalid(
                    "root feature",
                    format!("unknown root feature {name:?} (known: vel_x, vel_y, vel_z, yaw_rate)"),
                )
            })
    }
}

/// Which pose features a network sees.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseFeatureSpec {
    /// Joints whose local rotation enters, by skeleton name. The root joint (if listed) enters
    /// as its tilt relative to gravity (see the module docs).
    pub joints: Vec<String>,
    /// Encoding of each rotation.
    pub encoding: RotationEncoding,
    /// Root components.
    pub root: Vec<RootFeature>,
}

impl PoseFeatureSpec {
    /// Number of values per frame.
    pub fn width(&self) -> usize {
        self.joints.len() * self.encoding.width() + self.root.len()
    }

    /// Resolve the joint names on `skeleton` (each must exist, none twice).
    pub fn bind(&self, skeleton: &Skeleton) -> Result<PoseFeatures> {
        let mut joints = Vec::with_capacity(self.joints.len());
        for name in &self.joints {
            let j = skeleton.index_of(name).ok_or_else(|| {
                Error::invalid(
                    "pose features",
                    format!("joint {name:?} is not in the skeleton"),
                )
            })?;
            if joints.contains(&j) {
                return Err(Error::invalid(
                    "pose features",
                    format!("joint {name:?} is listed twice"),
                ));
            }
            joints.push(j);
        }
        for (k, f) in self.root.iter().enumerate() {
            if self.root[..k].contains(f) {
                return Err(Error::invalid(
                    "pose features",
                    format!("root feature {} is listed twice", f.name()),
                ));
            }
        }
        Ok(PoseFeatures {
            spec: self.clone(),
            joints,
            root_joint: skeleton.parents().iter().position(|p| p.is_none()),
            n_joints: skeleton.n_joints(),
        })
    }
}

/// A [`PoseFeatureSpec`] bound to a skeleton: computes one frame's features.
#[derive(Clone, Debug)]
pub struct PoseFeatures {
    spec: PoseFeatureSpec,
    joints: Vec<usize>,
    root_joint: Option<usize>,
    n_joints: usize,
}

/// The root joint's world rotation split into heading and tilt.
fn heading_tilt(pose: &Pose, root: usize) -> (UnitQuaternion<f64>, UnitQuaternion<f64>) {
    split_heading(&(pose.root_orientation * pose.local_rotations[root]))
}

impl PoseFeatures {
    /// The spec.
    pub fn spec(&self) -> &PoseFeatureSpec {
        &self.spec
    }

    /// Number of values per frame.
    pub fn width(&self) -> usize {
        self.spec.width()
    }

    /// Features of `pose`, with velocities by backward difference from `previous` (the pose
    /// `dt_secs` earlier; `None` at the start of a stream, which gives zero velocities).
    /// Writes exactly [`PoseFeatures::width`] values. Allocation-free.
    pub fn compute(
        &self,
        previous: Option<&Pose>,
        pose: &Pose,
        dt_secs: f64,
        out: &mut [f32],
    ) -> Result<()> {
        if out.len() != self.width() {
            return Err(Error::invalid(
                "pose features",
                format!(
                    "output has {} values, the layout {}",
                    out.len(),
                    self.width()
                ),
            ));
        }
        if !(dt_secs.is_finite() && dt_secs > 0.0) {
            return Err(Error::invalid(
                "pose features",
                format!("time step must be finite and positive, got {dt_secs}"),
            ));
        }
        pose.validate(self.n_joints)?;
        if let Some(p) = previous {
            p.validate(self.n_joints)?;
        }
        let width = self.spec.encoding.width();
        let (heading, tilt) = match self.root_joint {
            Some(r) => heading_tilt(pose, r),
            None => (UnitQuaternion::identity(), UnitQuaternion::identity()),
        };
        for (k, &j) in self.joints.iter().enumerate() {
            let q = if Some(j) == self.root_joint {
                tilt
            } else {
                pose.local_rotations[j]
            };
            self.spec
                .encoding
                .encode(&q, &mut out[k * width..(k + 1) * width]);
        }
        let (velocity, yaw_rate) = match (previous, self.root_joint) {
            (Some(prev), Some(r)) => {
                let world = (pose.root_translation_m - prev.root_translation_m) / dt_secs;
                let v: Vector3<f64> = heading.inverse() * world;
                let (prev_heading, _) = heading_tilt(prev, r);
                let turn = prev_heading.inverse() * heading;
                // A rotation about +Y: its angle, signed by the axis.
                let yaw = turn.scaled_axis().y;
                (v, yaw / dt_secs)
            }
            _ => (Vector3::zeros(), 0.0),
        };
        let root = &mut out[self.joints.len() * width..];
        for (o, f) in root.iter_mut().zip(&self.spec.root) {
            *o = match f {
                RootFeature::VelX => velocity.x,
                RootFeature::VelY => velocity.y,
                RootFeature::VelZ => velocity.z,
                RootFeature::YawRate => yaw_rate,
            } as f32;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn skeleton() -> Skeleton {
        Skeleton::new(
            vec!["hips".into(), "spine".into(), "arm".into()],
            vec![None, Some(0), Some(1)],
        )
        .expect("valid skeleton")
    }

    fn spec() -> PoseFeatureSpec {
        PoseFeatureSpec {
            joints: vec!["hips".into(), "arm".into()],
            encoding: RotationEncoding::Rot6d,
            root: RootFeature::ALL.to_vec(),
        }
    }

    #[test]
    fn rot6d_of_identity_is_two_unit_columns() {
        let mut out = [0.0f32; 6];
        RotationEncoding::Rot6d.encode(&UnitQuaternion::identity(), &mut out);
        assert_eq!(out, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn encodings_recover_the_rotation() {
        let q = UnitQuaternion::from_euler_angles(0.3, -1.2, 2.9);
        let mut six = [0.0f32; 6];
        RotationEncoding::Rot6d.encode(&q, &mut six);
        let m = q.to_rotation_matrix();
        for k in 0..6 {
            assert!((six[k] as f64 - m[(k % 3, k / 3)]).abs() < 1e-6);
        }
        let mut quat = [0.0f32; 4];
        RotationEncoding::Quaternion.encode(&q, &mut quat);
        assert!(quat[3] >= 0.0);
        let back = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            quat[3] as f64,
            quat[0] as f64,
            quat[1] as f64,
            quat[2] as f64,
        ));
        assert!(back.angle_to(&q) < 1e-6);
        let mut aa = [0.0f32; 3];
        RotationEncoding::AxisAngle.encode(&q, &mut aa);
        let v = Vector3::new(aa[0] as f64, aa[1] as f64, aa[2] as f64);
        assert!(UnitQuaternion::from_scaled_axis(v).angle_to(&q) < 1e-6);
    }

    #[test]
    fn velocities_are_in_the_heading_frame() {
        let features = spec().bind(&skeleton()).expect("joints exist");
        assert_eq!(features.width(), 16);
        // Facing +X (heading 90° about +Y), walking forward at 1.5 m/s, turning at 0.5 rad/s.
        let dt = 1.0 / 30.0;
        let heading = std::f64::consts::FRAC_PI_2;
        let mut prev = Pose::rest(3);
        prev.root_orientation = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), heading);
        let mut pose = prev.clone();
        pose.root_orientation =
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), heading + 0.5 * dt);
        let forward = pose.root_orientation * Vector3::z();
        pose.root_translation_m = forward * (1.5 * dt);
        let mut out = vec![0.0f32; 16];
        features
            .compute(Some(&prev), &pose, dt, &mut out)
            .expect("valid poses");
        let root = &out[12..];
        assert!(root[0].abs() < 1e-6, "sideways {}", root[0]);
        assert!(root[1].abs() < 1e-6);
        assert!((root[2] - 1.5).abs() < 1e-4, "forward {}", root[2]);
        assert!((root[3] - 0.5).abs() < 1e-4, "yaw rate {}", root[3]);
        // The heading does not leak into the root joint's entry: still the identity.
        assert_eq!(&out[..6], &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn tilt_enters_and_heading_does_not() {
        let features = spec().bind(&skeleton()).expect("joints exist");
        let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.4);
        let mut a = Pose::rest(3);
        a.local_rotations[0] = tilt;
        let mut b = a.clone();
        b.root_orientation = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 2.0);
        let (mut fa, mut fb) = (vec![0.0f32; 16], vec![0.0f32; 16]);
        features.compute(None, &a, 0.1, &mut fa).expect("valid");
        features.compute(None, &b, 0.1, &mut fb).expect("valid");
        for k in 0..16 {
            assert!(
                (fa[k] - fb[k]).abs() < 1e-6,
                "value {k}: {} vs {}",
                fa[k],
                fb[k]
            );
        }
        assert!((fa[4] as f64 - 0.4f64.cos()).abs() < 1e-6);
    }

    #[test]
    fn bad_specs_and_inputs_are_errors() {
        let mut s = spec();
        s.joints.push("tail".into());
        assert!(s.bind(&skeleton()).is_err());
        let mut s = spec();
        s.joints.push("hips".into());
        assert!(s.bind(&skeleton()).is_err());
        let mut s = spec();
        s.root.push(RootFeature::VelX);
        assert!(s.bind(&skeleton()).is_err());
        let features = spec().bind(&skeleton()).expect("valid");
        let mut out = vec![0.0f32; 15];
        assert!(
            features
                .compute(None, &Pose::rest(3), 0.1, &mut out)
                .is_err()
        );
        let mut out = vec![0.0f32; 16];
        assert!(
            features
                .compute(None, &Pose::rest(2), 0.1, &mut out)
                .is_err()
        );
        let mut nan = Pose::rest(3);
        nan.root_translation_m.x = f64::NAN;
        assert!(features.compute(None, &nan, 0.1, &mut out).is_err());
        assert!(RootFeature::from_name("vel_w").is_err());
        assert_eq!(
            RootFeature::from_name("yaw_rate").expect("known"),
            RootFeature::YawRate
        );
    }
}
