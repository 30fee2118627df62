//! Linear blend skinning and its inverse: the one implementation the whole project uses.
//!
//! A point with weights `w_j` moves by the blended transform `Σ_j w_j A_j`, where `A_j` is joint
//! `j`'s posed-from-rest transform from forward kinematics. Inverse skinning applies the inverse
//! of that blended (affine, generally non-rigid) transform.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, RealField, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::io::{OwnedTensor, TensorFile};
use crate::{Error, Result};

/// How a kernel may use threads: the one choice every sartor kernel takes (skinning, the
/// simulator, the runtime's matrix kernels). Results never depend on it: work is split into
/// fixed chunks computed with the same arithmetic, so [`Parallelism::Rayon`] is bitwise equal
/// to [`Parallelism::Sequential`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Parallelism {
    /// The calling thread only.
    #[default]
    Sequential,
    /// The current rayon pool (`ThreadPool::install` picks the pool), in fixed-size chunks.
    Rayon,
}

/// Affine transform `p ↦ linear · p + translation`; for a single joint `linear` is a rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoneTransform<T: RealField + Copy> {
    /// Linear part.
    pub linear: Matrix3<T>,
    /// Translation part.
    pub translation: Vector3<T>,
}

impl<T: RealField + Copy> BoneTransform<T> {
    /// The identity.
    pub fn identity() -> Self {
        Self {
            linear: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// Apply to a point.
    #[inline]
    pub fn apply(&self, p: &Vector3<T>) -> Vector3<T> {
        self.linear * p + self.translation
    }
}

impl BoneTransform<f64> {
    /// Convert to f32 (at a crate boundary: simulation in f64, runtime in f32).
    pub fn to_f32(&self) -> BoneTransform<f32> {
        BoneTransform {
            linear: self.linear.cast(),
            translation: self.translation.cast(),
        }
    }
}

/// Sparse skin weights: for each point, a few `(joint, weight)` pairs summing to one (CSR).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkinWeights {
    offsets: Vec<u32>,
    joints: Vec<u32>,
    weights: Vec<f32>,
    n_joints: usize,
}

impl SkinWeights {
    /// Build from CSR arrays. Checks index ranges, finiteness, non-negativity and that each
    /// point's weights sum to one within 1e-3, then renormalises them exactly.
    pub fn new(
        offsets: Vec<u32>,
        joints: Vec<u32>,
        mut weights: Vec<f32>,
        n_joints: usize,
    ) -> Result<Self> {
        let bad = |m: String| Error::invalid("skin weights", m);
        if offsets.first() != Some(&0) {
            return Err(bad("offsets must start at 0".into()));
        }
        if joints.len() != weights.len() || *offsets.last().unwrap_or(&0) as usize != joints.len() {
            return Err(bad(format!(
                "offsets end at {} but there are {} joints and {} weights",
                offsets.last().unwrap_or(&0),
                joints.len(),
                weights.len()
            )));
        }
        for p in 0..offsets.len() - 1 {
            let (a, b) = (offsets[p] as usize, offsets[p + 1] as usize);
            if b <= a {
                return Err(bad(format!("point {p} has no weights (offsets {a}..{b})")));
            }
            if b > joints.len() {
                return Err(bad(format!(
                    "point {p}: offset {b} is past the {} weights",
                    joints.len()
                )));
            }
            let mut sum = 0.0f64;
            for k in a..b {
                if joints[k] as usize >= n_joints {
                    return Err(bad(format!(
                        "point {p} refers to joint {} of {n_joints}",
                        joints[k]
                    )));
                }
                let w = weights[k];
                if !w.is_finite() || w < 0.0 {
                    return Err(bad(format!("point {p} has weight {w}")));
                }
                sum += w as f64;
            }
            if (sum - 1.0).abs() > 1e-3 {
                return Err(bad(format!("weights of point {p} sum to {sum}, not 1")));
            }
            for w in &mut weights[a..b] {
                *w = (*w as f64 / sum) as f32;
            }
        }
        Ok(Self {
            offsets,
            joints,
            weights,
            n_joints,
        })
    }

    /// Keep the `k` largest weights of each dense row (`n_points × n_joints`, row-major), drop
    /// zeros, and renormalise. Rows must have a positive sum.
    pub fn from_dense_top_k(dense: &[f32], n_joints: usize, k: usize) -> Result<Self> {
        if n_joints == 0 || !dense.len().is_multiple_of(n_joints) {
            return Err(Error::invalid(
                "skin weights",
                format!(
                    "{} dense weights is not a multiple of {n_joints} joints",
                    dense.len()
                ),
            ));
        }
        let mut offsets = vec![0u32];
        let (mut joints, mut weights) = (Vec::new(), Vec::new());
        for (p, row) in dense.chunks(n_joints).enumerate() {
            if row.iter().any(|w| !w.is_finite() || *w < 0.0) {
                return Err(Error::invalid(
                    "skin weights",
                    format!("point {p} has a negative or non-finite weight"),
                ));
            }
            let mut order: Vec<usize> = (0..n_joints).filter(|&j| row[j] > 0.0).collect();
            // Largest first; ties by joint index for determinism.
            order.sort_by(|&a, &b| row[b].total_cmp(&row[a]).then(a.cmp(&b)));
            order.truncate(k);
            order.sort_unstable();
            let sum: f64 = order.iter().map(|&j| row[j] as f64).sum();
            if sum <= 0.0 {
                return Err(Error::invalid(
                    "skin weights",
                    format!("point {p} has no positive weight"),
                ));
            }
            for j in order {
                joints.push(j as u32);
                weights.push((row[j] as f64 / sum) as f32);
            }
            offsets.push(joints.len() as u32);
        }
        Self::new(offsets, joints, weights, n_joints)
    }

    /// Number of points.
    pub fn n_points(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Number of joints the weights refer to.
    pub fn n_joints(&self) -> usize {
        self.n_joints
    }

    /// The `(joint, weight)` pairs of point `p`.
    pub fn point(&self, p: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let (a, b) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
        self.joints[a..b]
            .iter()
            .zip(&self.weights[a..b])
            .map(|(&j, &w)| (j as usize, w))
    }

    /// The joint with the largest weight at point `p` (the lowest-numbered of equal weights).
    pub fn dominant_joint(&self, p: usize) -> usize {
        self.point(p)
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
            .map_or(0, |(j, _)| j)
    }

    /// Per face (three point indices), the joint with the largest weight summed over its
    /// corners (the lowest-numbered of equal sums): the body part the face belongs to.
    pub fn face_dominant_joints(&self, faces: &[[u32; 3]]) -> Vec<usize> {
        let mut sums = vec![0.0f32; self.n_joints];
        faces
            .iter()
            .map(|t| {
                sums.fill(0.0);
                for &v in t {
                    for (j, w) in self.point(v as usize) {
                        sums[j] += w;
                    }
                }
                (0..sums.len())
                    .max_by(|&a, &b| sums[a].total_cmp(&sums[b]).then(b.cmp(&a)))
                    .unwrap_or(0)
            })
            .collect()
    }

    /// CSR arrays `(offsets, joints, weights)`.
    pub fn csr(&self) -> (&[u32], &[u32], &[f32]) {
        (&self.offsets, &self.joints, &self.weights)
    }

    /// Store the weights in `tensors` as CSR: `{prefix}offsets` (i32 `[P + 1]`),
    /// `{prefix}joints` (i32 `[nnz]`) and `{prefix}weights` (f32 `[nnz]`). Every sartor file
    /// that carries skin weights (body model, dataset binding, runtime binding) uses this layout.
    pub fn insert_tensors(&self, tensors: &mut BTreeMap<String, OwnedTensor>, prefix: &str) {
        let i32s = |xs: &[u32]| xs.iter().map(|&x| x as i32).collect::<Vec<_>>();
        tensors.insert(
            format!("{prefix}offsets"),
            OwnedTensor::i32(&[self.offsets.len()], i32s(&self.offsets)),
        );
        tensors.insert(
            format!("{prefix}joints"),
            OwnedTensor::i32(&[self.joints.len()], i32s(&self.joints)),
        );
        tensors.insert(
            format!("{prefix}weights"),
            OwnedTensor::f32(&[self.weights.len()], self.weights.iter().copied()),
        );
    }

    /// Read weights stored by [`Self::insert_tensors`]: `n_points` rows over `n_joints` joints,
    /// validated as [`Self::new`] does; errors name the file.
    pub fn from_tensors(
        file: &TensorFile,
        prefix: &str,
        n_points: usize,
        n_joints: usize,
    ) -> Result<Self> {
        let (_, offsets) = file.u32(&format!("{prefix}offsets"), &[Some(n_points + 1)])?;
        let (_, joints) = file.u32(&format!("{prefix}joints"), &[None])?;
        let (_, weights) = file.f32(&format!("{prefix}weights"), &[Some(joints.len())])?;
        Self::new(offsets, joints, weights, n_joints).map_err(|e| e.in_file(file.path()))
    }

    /// Dense `n_points × n_joints` row-major copy.
    pub fn to_dense(&self) -> Vec<f32> {
        let mut dense = vec![0.0; self.n_points() * self.n_joints];
        for p in 0..self.n_points() {
            for (j, w) in self.point(p) {
                dense[p * self.n_joints + j] += w;
            }
        }
        dense
    }

    /// The blended transform of point `p`.
    #[inline]
    pub fn blend<T: RealField + Copy>(
        &self,
        p: usize,
        transforms: &[BoneTransform<T>],
    ) -> BoneTransform<T> {
        let mut linear = Matrix3::zeros();
        let mut translation = Vector3::zeros();
        for (j, w) in self.point(p) {
            let w: T = nalgebra::convert(w as f64);
            linear += transforms[j].linear * w;
            translation += transforms[j].translation * w;
        }
        BoneTransform {
            linear,
            translation,
        }
    }

    fn check_sizes<T: RealField + Copy>(
        &self,
        n_in: usize,
        n_out: usize,
        transforms: &[BoneTransform<T>],
    ) -> Result<()> {
        if n_in != self.n_points() || n_out != self.n_points() || transforms.len() != self.n_joints
        {
            return Err(Error::invalid(
                "skinning",
                format!(
                    "{} weighted points over {} joints, but {n_in} input points, {n_out} outputs and {} transforms",
                    self.n_points(),
                    self.n_joints,
                    transforms.len()
                ),
            ));
        }
        Ok(())
    }
}

const CHUNK: usize = 1024;

/// Linear blend skinning: `out[i] = (Σ_j w_ij A_j) · rest[i]`. Allocation-free.
pub fn skin_points<T: RealField + Copy>(
    rest: &[Vector3<T>],
    weights: &SkinWeights,
    transforms: &[BoneTransform<T>],
    out: &mut [Vector3<T>],
    par: Parallelism,
) -> Result<()> {
    weights.check_sizes(rest.len(), out.len(), transforms)?;
    let kernel = |start: usize, out: &mut [Vector3<T>]| {
        for (k, o) in out.iter_mut().enumerate() {
            *o = skin_point(rest, weights, transforms, start + k);
        }
    };
    match par {
        Parallelism::Sequential => kernel(0, out),
        Parallelism::Rayon => out
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, o)| kernel(c * CHUNK, o)),
    }
    Ok(())
}

/// [`skin_points`] at the points `indices` only: `out[i]` gets the same bits there and is left
/// as it was elsewhere (`rest` and `out` hold every point). For a caller that reads a few parts
/// of a mesh per pose. Allocation-free.
pub fn skin_points_at<T: RealField + Copy>(
    rest: &[Vector3<T>],
    weights: &SkinWeights,
    transforms: &[BoneTransform<T>],
    indices: &[u32],
    out: &mut [Vector3<T>],
) -> Result<()> {
    weights.check_sizes(rest.len(), out.len(), transforms)?;
    if let Some(&i) = indices.iter().find(|&&i| i as usize >= rest.len()) {
        return Err(Error::invalid(
            "skinning",
            format!("vertex {i} asked of {} weighted points", rest.len()),
        ));
    }
    for &i in indices {
        out[i as usize] = skin_point(rest, weights, transforms, i as usize);
    }
    Ok(())
}

/// Point `i` of `rest` skinned: the one kernel of [`skin_points`] and [`skin_points_at`].
#[inline(always)]
fn skin_point<T: RealField + Copy>(
    rest: &[Vector3<T>],
    weights: &SkinWeights,
    transforms: &[BoneTransform<T>],
    i: usize,
) -> Vector3<T> {
    weights.blend(i, transforms).apply(&rest[i])
}

/// Inverse linear blend skinning: `out[i] = (Σ_j w_ij A_j)⁻¹ · posed[i]`, un-posing points
/// given their weights. Fails if a blended transform is singular (e.g. weights split evenly
/// between two joints rotated 180° apart).
pub fn unskin_points<T: RealField + Copy>(
    posed: &[Vector3<T>],
    weights: &SkinWeights,
    transforms: &[BoneTransform<T>],
    out: &mut [Vector3<T>],
    par: Parallelism,
) -> Result<()> {
    weights.check_sizes(posed.len(), out.len(), transforms)?;
    let min_det: T = nalgebra::convert(1e-6);
    let kernel = |start: usize, out: &mut [Vector3<T>]| -> Result<()> {
        for (k, o) in out.iter_mut().enumerate() {
            let i = start + k;
            let b = weights.blend(i, transforms);
            let inv = b
                .linear
                .try_inverse()
                .filter(|_| b.linear.determinant().abs() > min_det)
                .ok_or_else(|| {
                    Error::invalid(
                        "inverse skinning",
                        format!("blended transform of point {i} is singular"),
                    )
                })?;
            *o = inv * (posed[i] - b.translation);
        }
        Ok(())
    };
    match par {
        Parallelism::Sequential => kernel(0, out),
        Parallelism::Rayon => out
            .par_chunks_mut(CHUNK)
            .enumerate()
            .try_for_each(|(c, o)| kernel(c * CHUNK, o)),
    }
}

/// [`unskin_points`], except where a point's blended transform `M` is nearly singular (smallest
/// singular value σ below `min_singular` = s₀: weights split between joints turned far apart,
/// the "candy wrapper" of linear blend skinning). There the exact inverse sends the rest position
/// far away for a small posed offset; such points get the damped inverse
/// `(MᵀM + λI)⁻¹ Mᵀ (x − t)` with `λ = s₀² − σ²`: λ is 0 at σ = s₀ (no jump) and the result stays
/// within about `|x − t| / s₀`. Elsewhere it is [`unskin_points`]' exact inverse, bit for bit.
/// Sequential.
pub fn unskin_points_damped(
    posed: &[Vector3<f64>],
    weights: &SkinWeights,
    transforms: &[BoneTransform<f64>],
    min_singular: f64,
    out: &mut [Vector3<f64>],
) -> Result<()> {
    weights.check_sizes(posed.len(), out.len(), transforms)?;
    let s0 = min_singular;
    for (i, o) in out.iter_mut().enumerate() {
        let b = weights.blend(i, transforms);
        let gram = b.linear.transpose() * b.linear;
        let smallest = gram.symmetric_eigenvalues().min().max(0.0);
        let inverse = if smallest >= s0 * s0 {
            b.linear.try_inverse()
        } else {
            let damped = gram + Matrix3::identity() * (s0 * s0 - smallest);
            damped.try_inverse().map(|d| d * b.linear.transpose())
        };
        let inverse = inverse.ok_or_else(|| {
            Error::invalid(
                "inverse skinning",
                format!("blended transform of point {i} is singular"),
            )
        })?;
        *o = inverse * (posed[i] - b.translation);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validates_weights() {
        assert!(SkinWeights::new(vec![0, 1], vec![0], vec![1.0], 1).is_ok());
        assert!(SkinWeights::new(vec![0, 1], vec![1], vec![1.0], 1).is_err());
        assert!(SkinWeights::new(vec![0, 1], vec![0], vec![0.5], 1).is_err());
        assert!(SkinWeights::new(vec![0, 1], vec![0], vec![f32::NAN], 1).is_err());
        assert!(SkinWeights::new(vec![0, 0], vec![], vec![], 1).is_err());
        // Non-monotone offsets that end at the right length (found by fuzzing).
        let e = SkinWeights::new(vec![0, 9, 2, 3], vec![0; 3], vec![1.0; 3], 1).unwrap_err();
        assert!(e.to_string().contains("past"), "{e}");
        let w = SkinWeights::from_dense_top_k(&[0.1, 0.6, 0.3, 0.0], 4, 2).expect("valid");
        let pairs: Vec<_> = w.point(0).collect();
        assert_eq!(pairs.len(), 2);
        assert_eq!(pairs[0].0, 1);
        assert!((pairs[0].1 - 2.0 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn the_dominant_joint_is_the_heaviest_and_the_lowest_of_equals() {
        // Points: joint 2 heaviest; joints 1 and 3 equal; joint 0 alone.
        let w = SkinWeights::new(
            vec![0, 2, 4, 5],
            vec![0, 2, 3, 1, 0],
            vec![0.25, 0.75, 0.5, 0.5, 1.0],
            4,
        )
        .expect("valid");
        assert_eq!(
            (0..3).map(|p| w.dominant_joint(p)).collect::<Vec<_>>(),
            [2, 1, 0]
        );
        // Face (0, 1, 2) sums 1.25 on joint 0 and 0.75 on joint 2; face (1, 1, 0) 1.0 on joints 1
        // and 3, 0.25 on 0 and 0.75 on 2.
        assert_eq!(w.face_dominant_joints(&[[0, 1, 2], [1, 1, 0]]), [0, 1]);
    }

    #[test]
    fn identity_transforms_leave_points() {
        let w = SkinWeights::from_dense_top_k(&[0.5, 0.5, 1.0, 0.0], 2, 4).expect("valid");
        let rest = vec![Vector3::new(1.0f32, 2.0, 3.0), Vector3::new(-1.0, 0.5, 0.0)];
        let mut out = vec![Vector3::zeros(); 2];
        skin_points(
            &rest,
            &w,
            &[BoneTransform::identity(); 2],
            &mut out,
            Parallelism::Sequential,
        )
        .expect("sizes");
        assert_eq!(out, rest);
        assert!(
            skin_points(
                &rest,
                &w,
                &[BoneTransform::identity(); 3],
                &mut out,
                Parallelism::Sequential
            )
            .is_err()
        );
    }

    #[test]
    fn singular_blend_is_an_error() {
        let w = SkinWeights::from_dense_top_k(&[0.5, 0.5], 2, 2).expect("valid");
        let flip = BoneTransform {
            linear: nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
                .into_inner(),
            translation: Vector3::zeros(),
        };
        let mut out = vec![Vector3::zeros()];
        let err = unskin_points(
            &[Vector3::new(1.0, 0.0, 0.0)],
            &w,
            &[BoneTransform::identity(), flip],
            &mut out,
            Parallelism::Sequential,
        );
        assert!(err.is_err());
    }
}
