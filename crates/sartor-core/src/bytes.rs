//! Checked little-endian bytes, for what one thread hands another (the try-on page and its
//! workers): [`Reader`] reads values in order and names the fault of bytes cut short, too long,
//! of another format or holding a value that is not finite; the `put_*` functions write them.
//! Counts are `u32`, values `f64` or `f32`, poses the root translation, the root orientation and
//! each joint's rotation (quaternions as `i, j, k, w`), `f64`.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::{Error, Pose, Result};

/// Bytes read in order; a fault names `what`.
#[derive(Debug)]
pub struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    /// A reader of `bytes`, which must start with `magic`; a fault names `what`.
    pub fn open(bytes: &'a [u8], what: &'static str, magic: [u8; 8]) -> Result<Self> {
        let mut r = Self { bytes, at: 0, what };
        if r.take(8)? != magic {
            let magic = String::from_utf8_lossy(&magic);
            return Err(r.fault(format!("not one of sartor's (no `{magic}` at the start)")));
        }
        Ok(r)
    }

    /// An error of these bytes (named by `what`).
    pub fn fault(&self, message: String) -> Error {
        Error::invalid(self.what, message)
    }

    /// Bytes read so far.
    pub fn position(&self) -> usize {
        self.at
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self.at.saturating_add(n);
        if end > self.bytes.len() {
            let have = self.bytes.len();
            return Err(self.fault(format!("cut short: {have} bytes, {end} needed")));
        }
        let taken = &self.bytes[self.at..end];
        self.at = end;
        Ok(taken)
    }

    /// The next `N` bytes.
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N]> {
        Ok(self.take(N)?.try_into().expect("N bytes"))
    }

    /// A `u64`.
    pub fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    /// A count (`u32`).
    pub fn count(&mut self) -> Result<usize> {
        Ok(u32::from_le_bytes(self.array()?) as usize)
    }

    /// `n` finite `f64` values.
    pub fn floats(&mut self, n: usize) -> Result<Vec<f64>> {
        self.finite(n, f64::from_le_bytes, |v| v.is_finite())
    }

    /// `n` finite `f32` values.
    pub fn floats32(&mut self, n: usize) -> Result<Vec<f32>> {
        self.finite(n, f32::from_le_bytes, |v| v.is_finite())
    }

    /// `n` values of `N` bytes each, read by `read`, each `finite`.
    fn finite<T: std::fmt::Display, const N: usize>(
        &mut self,
        n: usize,
        read: fn([u8; N]) -> T,
        finite: fn(&T) -> bool,
    ) -> Result<Vec<T>> {
        let at = self.at;
        let bytes = self.take(n.saturating_mul(N))?;
        let values: Vec<T> = bytes
            .chunks_exact(N)
            .map(|b| read(b.try_into().expect("N bytes")))
            .collect();
        match values.iter().position(|v| !finite(v)) {
            Some(i) => Err(self.fault(format!("a value of {} at byte {}", values[i], at + N * i))),
            None => Ok(values),
        }
    }

    /// `n` bits ([`put_bits`]).
    pub fn bits(&mut self, n: usize) -> Result<Vec<bool>> {
        let bytes = self.take(n.div_ceil(8))?;
        Ok((0..n).map(|i| bytes[i / 8] >> (i % 8) & 1 == 1).collect())
    }

    /// `n` points of finite `f32` coordinates ([`put_points`]).
    pub fn points(&mut self, n: usize) -> Result<Vec<Vector3<f32>>> {
        let at = self.at;
        let bytes = self.take(n.saturating_mul(12))?;
        let value = |b: &[u8]| f32::from_le_bytes(b.try_into().expect("4 bytes"));
        let points: Vec<Vector3<f32>> = bytes
            .chunks_exact(12)
            .map(|p| Vector3::new(value(&p[..4]), value(&p[4..8]), value(&p[8..])))
            .collect();
        let bad = points.iter().enumerate().find_map(|(i, p)| {
            let k = p.iter().position(|v| !v.is_finite())?;
            Some((p[k], at + 12 * i + 4 * k))
        });
        match bad {
            Some((v, byte)) => Err(self.fault(format!("a value of {v} at byte {byte}"))),
            None => Ok(points),
        }
    }

    /// A pose of `joints` joints ([`put_pose`]; its rotations are the caller's to check,
    /// [`Pose::validate`]).
    pub fn pose(&mut self, joints: usize) -> Result<Pose> {
        let v = self.floats(joints.saturating_mul(4).saturating_add(7))?;
        let quaternion =
            |q: &[f64]| UnitQuaternion::new_unchecked(Quaternion::new(q[3], q[0], q[1], q[2]));
        Ok(Pose {
            root_translation_m: Vector3::new(v[0], v[1], v[2]),
            root_orientation: quaternion(&v[3..7]),
            local_rotations: v[7..].chunks_exact(4).map(quaternion).collect(),
        })
    }

    /// Poses: their count and joints, then each ([`put_poses`]).
    pub fn poses(&mut self) -> Result<Vec<Pose>> {
        let (n_poses, joints) = (self.count()?, self.count()?);
        let per_pose = joints.saturating_mul(4).saturating_add(7);
        if n_poses.saturating_mul(per_pose).saturating_mul(8) > self.bytes.len() {
            let n = self.bytes.len();
            return Err(self.fault(format!("{n_poses} poses of {joints} joints in {n} bytes")));
        }
        (0..n_poses).map(|_| self.pose(joints)).collect()
    }

    /// Every byte read.
    pub fn end(&self) -> Result<()> {
        match self.bytes.len() - self.at {
            0 => Ok(()),
            n => Err(self.fault(format!("{n} bytes after the end"))),
        }
    }
}

/// Append `values`, little-endian.
pub fn put_floats(out: &mut Vec<u8>, values: &[f64]) {
    for v in values {
        out.extend(v.to_le_bytes());
    }
}

/// Append `values`, little-endian.
pub fn put_floats32(out: &mut Vec<u8>, values: &[f32]) {
    for v in values {
        out.extend(v.to_le_bytes());
    }
}

/// Append `points`' coordinates, `x, y, z, x, …`, little-endian.
pub fn put_points(out: &mut Vec<u8>, points: &[Vector3<f32>]) {
    for p in points {
        put_floats32(out, p.as_slice());
    }
}

/// Append `counts` as `u32`, little-endian.
pub fn put_counts(out: &mut Vec<u8>, counts: &[usize]) {
    for &n in counts {
        out.extend((n as u32).to_le_bytes());
    }
}

/// Append `bits`, eight a byte, each byte filled from its lowest bit.
pub fn put_bits(out: &mut Vec<u8>, bits: impl Iterator<Item = bool>) {
    let (mut byte, mut n) = (0u8, 0);
    for bit in bits {
        byte |= u8::from(bit) << n;
        n += 1;
        if n == 8 {
            out.push(byte);
            (byte, n) = (0, 0);
        }
    }
    if n > 0 {
        out.push(byte);
    }
}

/// Append `pose`: the root translation, the root orientation and each joint's rotation.
pub fn put_pose(out: &mut Vec<u8>, pose: &Pose) {
    put_floats(out, pose.root_translation_m.as_slice());
    put_floats(out, pose.root_orientation.coords.as_slice());
    for q in &pose.local_rotations {
        put_floats(out, q.coords.as_slice());
    }
}

/// Append `poses` (all of one skeleton): their count and joints, then each.
pub fn put_poses(out: &mut Vec<u8>, poses: &[Pose]) {
    let joints = poses.first().map_or(0, |p| p.local_rotations.len());
    put_counts(out, &[poses.len(), joints]);
    for pose in poses {
        debug_assert_eq!(pose.local_rotations.len(), joints, "one skeleton");
        put_pose(out, pose);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_points_and_poses_come_back_and_faults_are_named() {
        let mut pose = Pose::rest(2);
        pose.root_translation_m = Vector3::new(0.1, 0.9, -0.2);
        pose.local_rotations[1] = UnitQuaternion::from_euler_angles(0.3, -0.2, 0.1);
        let points = [
            Vector3::new(1.0f32, -2.5, 3.25),
            Vector3::new(0.0, 1e-3, -7.0),
        ];
        let mut out = b"sartorT1".to_vec();
        put_counts(&mut out, &[2]);
        put_floats32(&mut out, &[0.5, -1.5]);
        put_points(&mut out, &points);
        put_poses(&mut out, std::slice::from_ref(&pose));
        put_bits(&mut out, [true, false, true].into_iter());
        let mut r = Reader::open(&out, "test bytes", *b"sartorT1").expect("magic");
        assert_eq!(r.count().unwrap(), 2);
        assert_eq!(r.floats32(2).unwrap(), [0.5, -1.5]);
        assert_eq!(r.points(2).unwrap(), points);
        assert_eq!(r.poses().unwrap(), [pose]);
        assert_eq!(r.bits(3).unwrap(), [true, false, true]);
        r.end().expect("every byte read");

        // A coordinate that is not finite, named with its byte; bytes cut short; another magic.
        let mut nan = b"sartorT1".to_vec();
        put_points(&mut nan, &[Vector3::new(0.0, f32::NAN, 1.0)]);
        let e = Reader::open(&nan, "test bytes", *b"sartorT1")
            .and_then(|mut r| r.points(1))
            .unwrap_err();
        assert!(e.to_string().contains("a value of NaN at byte 12"), "{e}");
        let e = Reader::open(&nan[..15], "test bytes", *b"sartorT1")
            .and_then(|mut r| r.points(1))
            .unwrap_err();
        assert!(
            e.to_string().contains("cut short: 15 bytes, 20 needed"),
            "{e}"
        );
        let e = Reader::open(&nan, "test bytes", *b"sartorX1").unwrap_err();
        assert!(e.to_string().contains("test bytes"), "{e}");
    }
}
