//! Import of MakeHuman's keyframed walk cycle (`walkcycles/*.json`, MPFB2's format) onto the
//! built-in 31-joint skeleton.
//!
//! # The source
//!
//! The file holds Blender f-curves (`rotation_euler`, `location`, possibly
//! `rotation_quaternion`; keyframes with Bézier handles) for bones of MakeHuman's **default** rig
//! (`rigs/rig.default.json`: `root`, `spine05`…`spine01`, `neck01`, `head`, `clavicle.L`, ...)
//! plus MPFB2's IK helper bones, made by its "rig helpers" with their default settings:
//!
//! | helper | rest (Blender edit bone) | parent | drives |
//! | --- | --- | --- | --- |
//! | `left_foot_ik` | the `foot.L` bone (head, tail, roll) | none | ankle position and foot rotation |
//! | `left_knee_ik` | head at the knee, along `upperleg02.L`, roll 0 | none | the knee's bend direction (pole) |
//! | `left_hand_ik` | the `wrist.L` bone | `spine01` | wrist position and hand rotation |
//! | `left_elbow_ik` | head at the elbow, along `upperarm02.L`, roll 0 | `spine01` | the elbow's bend direction (pole) |
//!
//! (and the same on the right). Pose-bone semantics are Blender's: a bone's posed matrix is
//! `parent_posed · parent_rest⁻¹ · rest · T(location) · R(rotation)`, `rotation_euler` is mode
//! `XYZ` (`R = Rz · Ry · Rx`), and location is in the bone's rest axes. Bone rest axes come from
//! head, tail and roll exactly as Blender's `vec_roll_to_mat3` computes them.
//!
//! # What the importer does
//!
//! 1. Evaluates every f-curve at the output times: cubic Bézier between keys with the stored
//!    handles (handles shortened as Blender's `correct_bezpart` does, the curve's x solved for
//!    the time), `LINEAR` and `CONSTANT` keys too, constant extrapolation. Frames are Blender
//!    frames at [`BLENDER_FPS`].
//! 2. Loops the cycle (period = the last keyframe, 40 frames) like MPFB2's `walk_cycle_from_dict`:
//!    each cycle adds the root's forward progress. Unlike MPFB2, which also adds the IK targets'
//!    sideways and vertical drift every cycle, the root and the leg targets are made exactly
//!    periodic up to that forward progress (their linear drift over a cycle is removed), so the
//!    loop is seamless and the knees do not turn out a little more every cycle. A curve whose last
//!    key comes before the period end (the toes) gets a wrap key at the period end equal to its
//!    first key.
//! 3. Forward kinematics of the default rig for root, spine, neck, head and clavicles; analytic
//!    two-bone IK for each leg (hip–knee–ankle toward `*_foot_ik`, bending toward `*_knee_ik`)
//!    and arm (shoulder–elbow–wrist toward `*_hand_ik`, bending toward `*_elbow_ik`); feet and
//!    hands copy their IK target's world rotation (MPFB2's `COPY_ROTATION` constraints).
//! 4. Maps default-rig bones onto `cmu_mb` joints through their world rotations (composing split
//!    bones by taking the world rotation of the last bone in the group): `root`→`Hips`,
//!    `pelvis.L`→`LHipJoint`, thigh (IK)→`LeftUpLeg`, shin (IK)→`LeftLeg`, `foot.L`→`LeftFoot`,
//!    `toe1-1.L`→`LeftToeBase`, `spine04·spine03`→`LowerBack`, `spine02`→`Spine`,
//!    `spine01`→`Spine1`, `neck01`→`Neck`, `neck02·neck03`→`Neck1`, `head`→`Head`,
//!    `clavicle.L·shoulder01.L`→`LeftShoulder`, upper arm (IK)→`LeftArm`, forearm
//!    (IK)→`LeftForeArm`, wrist→`LeftHand` (fingers follow the hand); world rotations are
//!    converted from Blender axes (`Blender (x, y, z) = ours (x, −z, y)`), then made local.
//!
//! # Approximations
//!
//! - Geometry: the IK uses the rig's `default_position`s (MPFB2's default human, on which the
//!   cycle's `arm_length` of 0.447 m was measured), not our body; rotations transfer to our
//!   body, the root translation is not rescaled, so on a body with other leg lengths the feet
//!   may slide by the length ratio.
//! - IK: Blender solves the knee/elbow helpers as a second IK target on the thigh/upper arm;
//!   here they only choose the bend plane (the usual pole-target solution), limb lengths are
//!   kept and unreachable targets are approached along the straight limb. Rotation limits of
//!   MPFB2's IK bones and the shin/forearm twist from the target's roll (influence 0.4) are not
//!   modelled.
//! - `spine05` (pelvis→`spine-4`) has no `cmu_mb` counterpart: its rotation reaches the spine
//!   through the world rotations of the bones above, but it does not move `LowerBack`'s head.
//! - The frame rate of the source is not in the file; Blender's default (24 fps) is assumed
//!   (a 1.67 s cycle, 0.79 m per cycle).
//! - `location` keys of bones other than the root and the IK helpers, and `scale` keys, are
//!   ignored (they are all zero / one in the file).

use crate::rig::{RigBone, read_rig};
use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde_json::Value;

use sartor_core::io::read_file;
use sartor_core::{FPS, Pose, canonical};
use sartor_motion::{CMU_MB_JOINTS, Motion, cmu_mb_skeleton, pose_from_world};

use crate::{Error, Result};

/// Frames per second of the Blender f-curves (Blender's default scene rate; the file has none).
pub const BLENDER_FPS: f64 = 24.0;
/// Number of cycles the import loops (as MPFB2's default), 6.7 s at [`BLENDER_FPS`].
pub const WALK_CYCLES: usize = 4;
/// The walk cycle file inside the MakeHuman assets folder.
pub const WALK_CYCLE_FILE: &str = "walkcycles/crappy_experimental_female.json";
/// The default rig inside the MakeHuman assets folder.
pub const DEFAULT_RIG_FILE: &str = "rigs/rig.default.json";
/// The `cmu_mb` rig inside the MakeHuman assets folder.
pub const CMU_MB_RIG_FILE: &str = "rigs/rig.cmu_mb.json";

/// Blender axes to ours: ours = `BLENDER_TO_OURS · blender`, i.e. `(x, y, z) ↦ (x, z, −y)`.
fn blender_to_ours() -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0)
}

/// Bone rest axes from its direction and roll, as Blender's `vec_roll_to_mat3_normalized`
/// (columns: the bone's X, Y (= `dir`) and Z axes in armature space).
fn vec_roll_to_mat3(dir: &Vector3<f64>, roll: f64) -> Matrix3<f64> {
    crate::makehuman::blender::vec_roll_to_mat3(&dir.normalize(), roll)
}

/// Rest joint positions of the `cmu_mb` skeleton (in [`CMU_MB_JOINTS`] order, our axes,
/// metres) from `rig.cmu_mb.json`'s default positions: each joint sits at its bone's head. A
/// stand-in for the body model's joints where only the rig is at hand (tests, previews).
pub fn cmu_mb_rest_joints(rig_path: &Path) -> Result<Vec<Vector3<f64>>> {
    let rig = read_rig(rig_path)?;
    let c = blender_to_ours();
    CMU_MB_JOINTS
        .iter()
        .map(|(n, _)| {
            rig.get(*n)
                .map(|b| c * b.head)
                .ok_or_else(|| Error::format(rig_path, format!("missing bone {n:?}")))
        })
        .collect()
}

/// How a key interpolates to the next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Interp {
    Constant,
    Linear,
    Bezier,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Key {
    frame: f64,
    value: f64,
    left: [f64; 2],
    right: [f64; 2],
    interp: Interp,
}

/// One animated scalar: keys sorted by frame.
#[derive(Clone, Debug, PartialEq)]
struct FCurve {
    keys: Vec<Key>,
}

impl FCurve {
    fn eval(&self, t: f64) -> f64 {
        let k = &self.keys;
        if t <= k[0].frame {
            return k[0].value;
        }
        let last = k[k.len() - 1];
        if t >= last.frame {
            return last.value;
        }
        let i = k.partition_point(|key| key.frame <= t) - 1;
        let (a, b) = (k[i], k[i + 1]);
        match a.interp {
            Interp::Constant => a.value,
            Interp::Linear => a.value + (b.value - a.value) * (t - a.frame) / (b.frame - a.frame),
            Interp::Bezier => bezier_segment(&a, &b, t),
        }
    }
}

/// Blender's Bézier segment evaluation: handles shortened so the curve stays a function of time
/// (`correct_bezpart`), x(u) = t solved by bisection, then y(u).
fn bezier_segment(a: &Key, b: &Key, t: f64) -> f64 {
    let p0 = [a.frame, a.value];
    let p3 = [b.frame, b.value];
    let mut p1 = a.right;
    let mut p2 = b.left;
    let h1 = [p0[0] - p1[0], p0[1] - p1[1]];
    let h2 = [p3[0] - p2[0], p3[1] - p2[1]];
    let len = p3[0] - p0[0];
    let (len1, len2) = (h1[0].abs(), h2[0].abs());
    if len1 + len2 > len && len1 + len2 > 0.0 {
        let fac = len / (len1 + len2);
        p1 = [p0[0] - fac * h1[0], p0[1] - fac * h1[1]];
        p2 = [p3[0] - fac * h2[0], p3[1] - fac * h2[1]];
    }
    // Keep the x control points ordered so x(u) is monotonic.
    p1[0] = p1[0].clamp(p0[0], p3[0]);
    p2[0] = p2[0].clamp(p1[0], p3[0]);
    let cubic = |c0: f64, c1: f64, c2: f64, c3: f64, u: f64| {
        let v = 1.0 - u;
        v * v * v * c0 + 3.0 * v * v * u * c1 + 3.0 * v * u * u * c2 + u * u * u * c3
    };
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if cubic(p0[0], p1[0], p2[0], p3[0], mid) < t {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    cubic(p0[1], p1[1], p2[1], p3[1], 0.5 * (lo + hi))
}

/// The animated properties of one bone.
#[derive(Clone, Debug, Default, PartialEq)]
struct BoneCurves {
    location: [Option<FCurve>; 3],
    euler: [Option<FCurve>; 3],
    quaternion: [Option<FCurve>; 4],
}

impl BoneCurves {
    fn location(&self, t: f64) -> Vector3<f64> {
        Vector3::from_fn(|i, _| self.location[i].as_ref().map_or(0.0, |c| c.eval(t)))
    }

    /// Pose rotation in bone-local axes.
    fn rotation(&self, t: f64) -> Matrix3<f64> {
        if self.quaternion.iter().any(Option::is_some) {
            let c = |i: usize, d: f64| self.quaternion[i].as_ref().map_or(d, |c| c.eval(t));
            let q = nalgebra::Quaternion::new(c(0, 1.0), c(1, 0.0), c(2, 0.0), c(3, 0.0));
            if q.norm() > 1e-12 {
                return UnitQuaternion::from_quaternion(q)
                    .to_rotation_matrix()
                    .into_inner();
            }
        }
        let e = |i: usize| self.euler[i].as_ref().map_or(0.0, |c| c.eval(t));
        crate::makehuman::blender_euler_xyz([e(0), e(1), e(2)]).into_inner()
    }

    fn last_frame(&self) -> f64 {
        self.location
            .iter()
            .chain(&self.euler)
            .chain(&self.quaternion)
            .flatten()
            .map(|c| c.keys[c.keys.len() - 1].frame)
            .fold(0.0, f64::max)
    }

    /// Append a key at `period` equal to the first key, to curves ending before it.
    fn wrap(&mut self, period: f64) {
        for c in self
            .location
            .iter_mut()
            .chain(&mut self.euler)
            .chain(&mut self.quaternion)
            .flatten()
        {
            let (first, last) = (c.keys[0], c.keys[c.keys.len() - 1]);
            if last.frame < period - 1e-9 && first.frame <= 1e-9 {
                let h = (period - last.frame) / 3.0;
                c.keys.push(Key {
                    frame: period,
                    value: first.value,
                    left: [period - h, first.value],
                    right: [period + h, first.value],
                    interp: Interp::Bezier,
                });
            }
        }
    }
}

/// Parse MPFB2's animation JSON: `animation_data[bone][frame][property] = {values, metadata}`.
fn read_cycle(path: &Path) -> Result<BTreeMap<String, BoneCurves>> {
    let bytes = read_file(path)?;
    let json: Value =
        serde_json::from_slice(&bytes).map_err(|e| Error::parse(path, e.line(), e.to_string()))?;
    let data = json
        .get("animation_data")
        .and_then(Value::as_object)
        .ok_or_else(|| Error::format(path, "missing object \"animation_data\""))?;
    let mut out = BTreeMap::new();
    for (bone, frames) in data {
        let frames = frames
            .as_object()
            .ok_or_else(|| Error::format(path, format!("bone {bone:?}: expected frames")))?;
        // (property, channel) -> keys
        let mut keys: BTreeMap<(String, usize), Vec<Key>> = BTreeMap::new();
        for (frame_str, props) in frames {
            let fault =
                |m: String| Error::format(path, format!("bone {bone:?} frame {frame_str}: {m}"));
            let frame: f64 = frame_str
                .parse()
                .map_err(|_| fault("frame is not a number".into()))?;
            let props = props
                .as_object()
                .ok_or_else(|| fault("expected properties".into()))?;
            for (prop, p) in props {
                let values = p
                    .get("values")
                    .and_then(Value::as_array)
                    .ok_or_else(|| fault(format!("{prop}: missing values")))?;
                let meta = p
                    .get("metadata")
                    .and_then(Value::as_array)
                    .ok_or_else(|| fault(format!("{prop}: missing metadata")))?;
                for (ch, (v, m)) in values.iter().zip(meta).enumerate() {
                    // Channels without a key at this frame have empty metadata.
                    let Some(m) = m.as_object().filter(|m| !m.is_empty()) else {
                        continue;
                    };
                    let value = v
                        .as_f64()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| fault(format!("{prop}[{ch}]: not a finite number")))?;
                    let handle = |k: &str| -> Result<[f64; 2]> {
                        let h: Vec<f64> = m
                            .get(k)
                            .and_then(Value::as_array)
                            .map(|a| a.iter().filter_map(Value::as_f64).collect())
                            .unwrap_or_default();
                        if h.len() != 2 || !h.iter().all(|x| x.is_finite()) {
                            return Err(fault(format!("{prop}[{ch}]: bad {k}")));
                        }
                        Ok([h[0], h[1]])
                    };
                    let interp = match m.get("interpolation").and_then(Value::as_str) {
                        Some("BEZIER") | None => Interp::Bezier,
                        Some("LINEAR") => Interp::Linear,
                        Some("CONSTANT") => Interp::Constant,
                        Some(other) => {
                            return Err(fault(format!(
                                "{prop}[{ch}]: unsupported interpolation {other:?}"
                            )));
                        }
                    };
                    keys.entry((prop.clone(), ch)).or_default().push(Key {
                        frame,
                        value,
                        left: handle("handle_left")?,
                        right: handle("handle_right")?,
                        interp,
                    });
                }
            }
        }
        let mut curves = BoneCurves::default();
        for ((prop, ch), mut ks) in keys {
            ks.sort_by(|a, b| a.frame.total_cmp(&b.frame));
            let curve = Some(FCurve { keys: ks });
            let slot = match (prop.as_str(), ch) {
                ("location", 0..=2) => &mut curves.location[ch],
                ("rotation_euler", 0..=2) => &mut curves.euler[ch],
                ("rotation_quaternion", 0..=3) => &mut curves.quaternion[ch],
                ("scale", _) => continue,
                _ => {
                    return Err(Error::format(
                        path,
                        format!("bone {bone:?}: unsupported property {prop}[{ch}]"),
                    ));
                }
            };
            *slot = curve;
        }
        out.insert(bone.clone(), curves);
    }
    Ok(out)
}

/// Posed armature: world rotation delta (`posed · rest⁻¹`) and posed head of every bone.
struct Posed {
    delta: BTreeMap<String, Matrix3<f64>>,
    head: BTreeMap<String, Vector3<f64>>,
}

/// Rest geometry of a two-bone limb, and the solver.
struct Limb {
    upper_len: f64,
    lower_len: f64,
    upper_rest: Vector3<f64>,
    lower_rest: Vector3<f64>,
    normal_rest: Vector3<f64>,
    /// The rest bend direction (unit, ⊥ root→end), used when the pole is on the limb's line.
    bend_rest: Vector3<f64>,
}

impl Limb {
    fn new(
        root: Vector3<f64>,
        mid: Vector3<f64>,
        end: Vector3<f64>,
        fallback_bend: Vector3<f64>,
    ) -> Self {
        let e = (end - root).normalize();
        let m = (mid - root) - (mid - root).dot(&e) * e;
        let bend = if m.norm() > 1e-6 {
            m.normalize()
        } else {
            (fallback_bend - fallback_bend.dot(&e) * e).normalize()
        };
        Self {
            upper_len: (mid - root).norm(),
            lower_len: (end - mid).norm(),
            upper_rest: (mid - root).normalize(),
            lower_rest: (end - mid).normalize(),
            normal_rest: bend.cross(&e).normalize(),
            bend_rest: bend,
        }
    }

    /// World rotation deltas of the upper and lower bone reaching from `root` (posed) toward
    /// `target`, bending toward `pole`; `parent` is the posed rotation delta of the limb's parent
    /// (for the degenerate pole).
    fn solve(
        &self,
        root: Vector3<f64>,
        target: Vector3<f64>,
        pole: Vector3<f64>,
        parent: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        let (a, b) = (self.upper_len, self.lower_len);
        let d = target - root;
        let e = if d.norm() > 1e-9 {
            d.normalize()
        } else {
            parent * (self.upper_rest * a + self.lower_rest * b).normalize()
        };
        let dist = d
            .norm()
            .clamp((a - b).abs() + 1e-9, (a + b) * (1.0 - 1e-12));
        let pv = pole - root;
        let mut m = pv - pv.dot(&e) * e;
        if m.norm() < 1e-9 {
            let f = parent * self.bend_rest;
            m = f - f.dot(&e) * e;
        }
        let m = m.normalize();
        let cos_a = ((a * a + dist * dist - b * b) / (2.0 * a * dist)).clamp(-1.0, 1.0);
        let sin_a = (1.0 - cos_a * cos_a).sqrt();
        let knee = root + a * (cos_a * e + sin_a * m);
        let end = root + dist * e;
        let u = (knee - root).normalize();
        let s = (end - knee).normalize();
        let n = m.cross(&e).normalize();
        let frame =
            |x: &Vector3<f64>, n: &Vector3<f64>| Matrix3::from_columns(&[*x, *n, x.cross(n)]);
        let upper = frame(&u, &n) * frame(&self.upper_rest, &self.normal_rest).transpose();
        let lower = frame(&s, &n) * frame(&self.lower_rest, &self.normal_rest).transpose();
        (upper, lower)
    }
}

/// Everything the evaluation needs.
struct WalkRig {
    bones: BTreeMap<String, RigBone>,
    /// Bones, parents first.
    order: Vec<String>,
    axes: BTreeMap<String, Matrix3<f64>>,
    curves: BTreeMap<String, BoneCurves>,
    period: f64,
    /// Per-cycle forward progress (Blender axes) and linear drift of the looped targets.
    progress: Vector3<f64>,
    drift: BTreeMap<&'static str, Vector3<f64>>,
    legs: [Limb; 2],
    arms: [Limb; 2],
}

const SIDES: [(&str, &str); 2] = [("left", "L"), ("right", "R")];
const IK_HELPERS: [&str; 8] = [
    "left_foot_ik",
    "right_foot_ik",
    "left_knee_ik",
    "right_knee_ik",
    "left_hand_ik",
    "right_hand_ik",
    "left_elbow_ik",
    "right_elbow_ik",
];
/// Looped targets whose drift is removed (the root's head and the unparented leg helpers).
const LOOPED: [&str; 5] = [
    "root",
    "left_foot_ik",
    "right_foot_ik",
    "left_knee_ik",
    "right_knee_ik",
];

impl WalkRig {
    fn bone(&self, name: &str) -> Result<&RigBone> {
        self.bones.get(name).ok_or_else(|| {
            Error::invalid(
                "walk cycle",
                format!("the default rig has no bone {name:?}"),
            )
        })
    }

    fn axes_of(&self, name: &str) -> Result<Matrix3<f64>> {
        self.axes.get(name).copied().ok_or_else(|| {
            Error::invalid(
                "walk cycle",
                format!("the default rig has no bone {name:?}"),
            )
        })
    }

    /// Rest head and axes of an IK helper (see the module docs).
    fn helper_rest(&self, helper: &str) -> Result<(Vector3<f64>, Matrix3<f64>)> {
        let (side, kind) = helper
            .split_once('_')
            .ok_or_else(|| Error::invalid("walk cycle", format!("bad helper {helper}")))?;
        let s = if side == "left" { "L" } else { "R" };
        Ok(match kind {
            "foot_ik" => {
                let b = self.bone(&format!("foot.{s}"))?;
                (b.head, self.axes_of(&b.name)?)
            }
            "hand_ik" => {
                let b = self.bone(&format!("wrist.{s}"))?;
                (b.head, self.axes_of(&b.name)?)
            }
            "knee_ik" => {
                let b = self.bone(&format!("upperleg02.{s}"))?;
                (b.tail, vec_roll_to_mat3(&(b.tail - b.head), 0.0))
            }
            "elbow_ik" => {
                let b = self.bone(&format!("upperarm02.{s}"))?;
                (b.tail, vec_roll_to_mat3(&(b.tail - b.head), 0.0))
            }
            _ => {
                return Err(Error::invalid(
                    "walk cycle",
                    format!("unknown helper {helper}"),
                ));
            }
        })
    }

    fn curves_of(&self, name: &str) -> Option<&BoneCurves> {
        self.curves.get(name)
    }

    /// Raw (un-looped) world position of a looped target at cycle time `tau`: the root's head or
    /// an unparented helper's head.
    fn raw_target(&self, name: &str, tau: f64) -> Result<Vector3<f64>> {
        let loc = self
            .curves_of(name)
            .map_or_else(Vector3::zeros, |c| c.location(tau));
        let (head, axes) = if name == "root" {
            (self.bone("root")?.head, self.axes_of("root")?)
        } else {
            self.helper_rest(name)?
        };
        Ok(head + axes * loc)
    }

    /// A looped target at Blender frame `t`.
    fn looped_target(&self, name: &'static str, t: f64) -> Result<Vector3<f64>> {
        let cycle = (t / self.period).floor();
        let tau = t - cycle * self.period;
        let drift = self.drift.get(name).copied().unwrap_or_else(Vector3::zeros);
        Ok(self.raw_target(name, tau)? - (tau / self.period) * drift + cycle * self.progress)
    }

    /// FK of the default rig at cycle time `tau` with the root's head at `root_head`.
    fn forward(&self, tau: f64, root_head: Vector3<f64>) -> Result<Posed> {
        let mut delta: BTreeMap<String, Matrix3<f64>> = BTreeMap::new();
        let mut head: BTreeMap<String, Vector3<f64>> = BTreeMap::new();
        for name in &self.order {
            let b = &self.bones[name];
            let axes = self.axes[name];
            let local = self
                .curves_of(name)
                .map_or_else(Matrix3::identity, |c| c.rotation(tau));
            let own = axes * local * axes.transpose();
            let (d, h) = match &b.parent {
                None => {
                    let h = if name == "root" { root_head } else { b.head };
                    (own, h)
                }
                Some(p) => {
                    let pd = delta[p];
                    let ph = head[p];
                    (pd * own, ph + pd * (b.head - self.bones[p].head))
                }
            };
            delta.insert(name.clone(), d);
            head.insert(name.clone(), h);
        }
        Ok(Posed { delta, head })
    }

    /// World rotation deltas (Blender axes) of the 31 `cmu_mb` joints and the posed pelvis at
    /// Blender frame `t`.
    fn evaluate(&self, t: f64) -> Result<(Vec<Matrix3<f64>>, Vector3<f64>)> {
        let cycle = (t / self.period).floor();
        let tau = t - cycle * self.period;
        let root_head = self.looped_target("root", t)?;
        let posed = self.forward(tau, root_head)?;
        let d = |n: &str| {
            posed.delta.get(n).copied().ok_or_else(|| {
                Error::invalid("walk cycle", format!("the default rig has no bone {n:?}"))
            })
        };
        let h = |n: &str| {
            posed.head.get(n).copied().ok_or_else(|| {
                Error::invalid("walk cycle", format!("the default rig has no bone {n:?}"))
            })
        };
        let helper_rot = |name: &str, parent: &Matrix3<f64>| -> Result<Matrix3<f64>> {
            let (_, axes) = self.helper_rest(name)?;
            let r = self
                .curves_of(name)
                .map_or_else(Matrix3::identity, |c| c.rotation(tau));
            Ok(parent * axes * r * axes.transpose())
        };
        // Helpers parented to spine01.
        let spine_d = d("spine01")?;
        let spine_h = h("spine01")?;
        let spine_rest = self.bone("spine01")?.head;
        let on_spine = |name: &str| -> Result<Vector3<f64>> {
            let (head, axes) = self.helper_rest(name)?;
            let loc = self
                .curves_of(name)
                .map_or_else(Vector3::zeros, |c| c.location(tau));
            Ok(spine_h + spine_d * (head + axes * loc - spine_rest))
        };
        let mut world: BTreeMap<String, Matrix3<f64>> = BTreeMap::new();
        for (cmu, bone) in [
            ("Hips", "root"),
            ("LowerBack", "spine03"),
            ("Spine", "spine02"),
            ("Spine1", "spine01"),
            ("Neck", "neck01"),
            ("Neck1", "neck03"),
            ("Head", "head"),
        ] {
            world.insert(cmu.to_string(), d(bone)?);
        }
        for (i, (side, s)) in SIDES.iter().enumerate() {
            let cmu = if *side == "left" { "Left" } else { "Right" };
            let cmu_hip = if *side == "left" {
                "LHipJoint"
            } else {
                "RHipJoint"
            };
            let cmu_thumb = if *side == "left" { "LThumb" } else { "RThumb" };
            // Leg.
            let pelvis = format!("pelvis.{s}");
            let hip = h(&format!("upperleg01.{s}"))?;
            let foot_name: &'static str = if i == 0 {
                "left_foot_ik"
            } else {
                "right_foot_ik"
            };
            let knee_name: &'static str = if i == 0 {
                "left_knee_ik"
            } else {
                "right_knee_ik"
            };
            let target = self.looped_target(foot_name, t)?;
            let pole = self.looped_target(knee_name, t)?;
            let (thigh, shin) = self.legs[i].solve(hip, target, pole, &d(&pelvis)?);
            let foot = helper_rot(foot_name, &Matrix3::identity())?;
            let toe_name = format!("toe1-1.{s}");
            let toe_axes = self.axes_of(&toe_name)?;
            let toe_local = self
                .curves_of(&toe_name)
                .map_or_else(Matrix3::identity, |c| c.rotation(tau));
            world.insert(cmu_hip.to_string(), d(&pelvis)?);
            world.insert(format!("{cmu}UpLeg"), thigh);
            world.insert(format!("{cmu}Leg"), shin);
            world.insert(format!("{cmu}Foot"), foot);
            world.insert(
                format!("{cmu}ToeBase"),
                foot * toe_axes * toe_local * toe_axes.transpose(),
            );
            // Arm.
            let shoulder = h(&format!("upperarm01.{s}"))?;
            let hand_name = format!("{side}_hand_ik");
            let elbow_name = format!("{side}_elbow_ik");
            let target = on_spine(&hand_name)?;
            let pole = on_spine(&elbow_name)?;
            let clav = d(&format!("shoulder01.{s}"))?;
            let (upper, fore) = self.arms[i].solve(shoulder, target, pole, &clav);
            let hand = helper_rot(&hand_name, &spine_d)?;
            world.insert(format!("{cmu}Shoulder"), clav);
            world.insert(format!("{cmu}Arm"), upper);
            world.insert(format!("{cmu}ForeArm"), fore);
            world.insert(format!("{cmu}Hand"), hand);
            world.insert(format!("{cmu}FingerBase"), hand);
            world.insert(format!("{cmu}HandFinger1"), hand);
            world.insert(cmu_thumb.to_string(), hand);
        }
        let mut out = Vec::with_capacity(CMU_MB_JOINTS.len());
        for (n, _) in CMU_MB_JOINTS {
            out.push(world.get(n).copied().ok_or_else(|| {
                Error::invalid("walk cycle", format!("no rotation for joint {n}"))
            })?);
        }
        let pelvis = h("spine05")?;
        Ok((out, pelvis))
    }
}

/// Import the walk cycle from a MakeHuman assets folder (holding [`WALK_CYCLE_FILE`] and
/// [`DEFAULT_RIG_FILE`]) as a 30 fps [`Motion`] named `walk` on the `cmu_mb` skeleton, looping the
/// cycle [`WALK_CYCLES`] times. Deterministic: the same inputs give the same values.
pub fn import_walk_cycle(makehuman_dir: &Path) -> Result<Motion> {
    let rig_path = makehuman_dir.join(DEFAULT_RIG_FILE);
    let cycle_path = makehuman_dir.join(WALK_CYCLE_FILE);
    let bones = read_rig(&rig_path)?;
    let mut curves = read_cycle(&cycle_path)?;
    for name in curves.keys() {
        if !bones.contains_key(name) && !IK_HELPERS.contains(&name.as_str()) {
            return Err(Error::format(
                &cycle_path,
                format!("bone {name:?} is neither in {DEFAULT_RIG_FILE} nor an IK helper"),
            ));
        }
    }
    let period = curves
        .values()
        .map(BoneCurves::last_frame)
        .fold(0.0, f64::max);
    if period <= 0.0 {
        return Err(Error::format(&cycle_path, "no keyframes after frame 0"));
    }
    for c in curves.values_mut() {
        c.wrap(period);
    }
    // Parents-first order (names sorted among siblings: deterministic).
    let mut order: Vec<String> = Vec::with_capacity(bones.len());
    let mut placed = std::collections::BTreeSet::new();
    while order.len() < bones.len() {
        let before = order.len();
        for (n, b) in &bones {
            if !placed.contains(n) && b.parent.as_ref().is_none_or(|p| placed.contains(p)) {
                order.push(n.clone());
            }
        }
        for n in &order[before..] {
            placed.insert(n.clone());
        }
        if order.len() == before {
            return Err(Error::format(&rig_path, "the bone parents form a cycle"));
        }
    }
    let axes = bones
        .iter()
        .map(|(n, b)| (n.clone(), b.rest_axes()))
        .collect();
    let limb = |upper0: &str, upper1: &str, lower1: &str, bend: Vector3<f64>| -> Result<Limb> {
        let get = |n: &str| {
            bones
                .get(n)
                .ok_or_else(|| Error::format(&rig_path, format!("missing bone {n:?}")))
        };
        Ok(Limb::new(
            get(upper0)?.head,
            get(upper1)?.tail,
            get(lower1)?.tail,
            bend,
        ))
    };
    // Fallback bend directions (Blender axes): knees forward (−Y), elbows backward (+Y).
    let forward = Vector3::new(0.0, -1.0, 0.0);
    let legs = [
        limb("upperleg01.L", "upperleg02.L", "lowerleg02.L", forward)?,
        limb("upperleg01.R", "upperleg02.R", "lowerleg02.R", forward)?,
    ];
    let arms = [
        limb("upperarm01.L", "upperarm02.L", "lowerarm02.L", -forward)?,
        limb("upperarm01.R", "upperarm02.R", "lowerarm02.R", -forward)?,
    ];
    let mut rig = WalkRig {
        bones,
        order,
        axes,
        curves,
        period,
        progress: Vector3::zeros(),
        drift: BTreeMap::new(),
        legs,
        arms,
    };
    let root_step = rig.raw_target("root", period)? - rig.raw_target("root", 0.0)?;
    rig.progress = Vector3::new(0.0, root_step.y, 0.0);
    for name in LOOPED {
        let step = rig.raw_target(name, period)? - rig.raw_target(name, 0.0)?;
        rig.drift.insert(name, step - rig.progress);
    }

    let c = blender_to_ours();
    let pelvis_rest = rig.bone("spine05")?.head;
    let duration_secs = WALK_CYCLES as f64 * period / BLENDER_FPS;
    let n = (duration_secs * FPS + 1e-9).floor() as usize + 1;
    let skeleton = cmu_mb_skeleton();
    let mut frames: Vec<Pose> = Vec::with_capacity(n);
    let mut origin = Vector3::zeros();
    for i in 0..n {
        let t = i as f64 / FPS * BLENDER_FPS;
        let (world_b, pelvis) = rig.evaluate(t)?;
        let world: Vec<UnitQuaternion<f64>> = world_b
            .iter()
            .map(|m| {
                let r = Rotation3::from_matrix(&(c * m * c.transpose()));
                canonical(UnitQuaternion::from_rotation_matrix(&r))
            })
            .collect();
        let mut d = c * (pelvis - pelvis_rest);
        if i == 0 {
            origin = Vector3::new(d.x, 0.0, d.z);
        }
        d -= origin;
        frames.push(pose_from_world(&skeleton, &world, d));
    }
    Motion::new("walk".into(), FPS, skeleton.names().to_vec(), frames)
        .map_err(|e| e.in_file(&cycle_path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec_roll_matches_blender_cases() {
        // Bone along +Z, roll 0: X stays +X, Z becomes −Y.
        let m = vec_roll_to_mat3(&Vector3::new(0.0, 0.0, 1.0), 0.0);
        assert!((m.column(0) - Vector3::x()).norm() < 1e-12);
        assert!((m.column(2) + Vector3::y()).norm() < 1e-12);
        // Straight down −Z: Z axis becomes +Y.
        let m = vec_roll_to_mat3(&Vector3::new(0.0, 0.0, -1.0), 0.0);
        assert!((m.column(2) - Vector3::y()).norm() < 1e-12);
        // Almost exactly −Y: the symmetric fallback.
        let m = vec_roll_to_mat3(&Vector3::new(0.0, -1.0, 0.0), 0.0);
        assert!((m.column(0) + Vector3::x()).norm() < 1e-12);
        // Always a rotation.
        for d in [Vector3::new(0.3, -0.9, 0.05), Vector3::new(-0.2, 0.1, 0.9)] {
            let m = vec_roll_to_mat3(&d, 1.1);
            assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-9);
            assert!((m.determinant() - 1.0).abs() < 1e-9);
            assert!((m.column(1) - d.normalize()).norm() < 1e-12);
        }
    }

    #[test]
    fn bezier_hits_keys_and_handles_shape_it() {
        let k = |frame: f64, value: f64, slope: f64| Key {
            frame,
            value,
            left: [frame - 1.0, value - slope],
            right: [frame + 1.0, value + slope],
            interp: Interp::Bezier,
        };
        let c = FCurve {
            keys: vec![k(0.0, 0.0, 0.0), k(3.0, 1.0, 0.0)],
        };
        assert_eq!(c.eval(-1.0), 0.0);
        assert_eq!(c.eval(5.0), 1.0);
        assert!((c.eval(1.5) - 0.5).abs() < 1e-9, "symmetric ease");
        assert!(c.eval(0.3) < 0.1, "flat handles ease in");
        // Linear handles (on the chord) give a straight line.
        let c = FCurve {
            keys: vec![k(0.0, 0.0, 1.0 / 3.0), k(3.0, 1.0, 1.0 / 3.0)],
        };
        assert!((c.eval(1.0) - 1.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn two_bone_ik_reaches_and_keeps_rest() {
        let limb = Limb::new(
            Vector3::zeros(),
            Vector3::new(0.0, -0.05, -1.0),
            Vector3::new(0.0, 0.0, -2.0),
            Vector3::new(0.0, -1.0, 0.0),
        );
        let id = Matrix3::identity();
        // Rest target and a pole in front: identity.
        let (u, l) = limb.solve(
            Vector3::zeros(),
            Vector3::new(0.0, 0.0, -2.0),
            Vector3::new(0.0, -3.0, -1.0),
            &id,
        );
        assert!((u - id).norm() < 1e-9 && (l - id).norm() < 1e-9);
        // A reachable target is reached, the knee bends toward the pole.
        let target = Vector3::new(0.3, -0.6, -1.2);
        let (u, l) = limb.solve(Vector3::zeros(), target, Vector3::new(0.0, -3.0, 0.0), &id);
        let knee = u * Vector3::new(0.0, -0.05, -1.0);
        let end = knee + l * (Vector3::new(0.0, 0.0, -2.0) - Vector3::new(0.0, -0.05, -1.0));
        assert!((end - target).norm() < 1e-9);
        assert!(knee.y < -0.3, "knee toward the pole: {knee:?}");
    }
}
