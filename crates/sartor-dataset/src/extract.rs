//! Ground truth from simulations: the cloth binding (`T̄_c`, `W_c`), the fit displacement `Δ_G`
//! and the wrinkle displacements `Δ_L`, and the choice of the joints the network sees.
//!
//! ```text
//! T̄_c  = ρ(garment relaxed on the template body)
//! W_c  = barycentric blend of the body weights at each T̄_c vertex's closest template-body point
//! Δ_G  = ρ(S_c(β, 0)) − T̄_c
//! Δ_L  = W⁻¹(S_c(β, θ), β, θ, W_c) − T̄_c − Δ_G
//! ```
//!
//! The binding is sartor-core's [`GarmentBinding`], the runtime's: `T̄_c` is stored in f32, and
//! both displacements are taken against that stored `T̄_c`, so that the runtime's
//! `T̄_c + Δ_G + Δ_L` adds up to the smoothed simulation with no rounding of its own.
//!
//! `W⁻¹` is sartor-core's inverse skinning ([`sartor_core::unskin_points`]), damped where the
//! blended transform is nearly singular ([`sartor_core::unskin_points_damped`]); the transforms
//! are the body's for shape β and pose θ (root motion included), so the recovered displacement
//! lives in the rest space of the template.

use nalgebra::Vector3;

use sartor_core::{
    BodyModel, DEFAULT_REGION_MARGIN_MM, GarmentBinding, Pose, SkinWeights, unskin_points_damped,
};

use crate::data::DataSource;
use crate::smoothing::Smoother;
use crate::{Error, Result};

/// Skin weights below this are dropped from `W_c` (and the rest renormalised): they move a
/// vertex by less than a tenth of a millimetre per metre of bone motion.
pub const CLOTH_WEIGHT_CUTOFF: f32 = 1e-4;

/// Bind a garment relaxed on the template body (β = 0, rest pose) to it: `T̄_c = ρ(relaxed)`,
/// `W_c` transferred from the body to every template vertex (influences below
/// [`CLOTH_WEIGHT_CUTOFF`] dropped), and the body region within
/// [`DEFAULT_REGION_MARGIN_MM`] of the template. The one binding type of the project, as the
/// runtime reads it.
pub fn bind_garment(
    body: &BodyModel,
    source: &DataSource,
    relaxed: &[Vector3<f64>],
    faces: &[[u32; 3]],
    smoother: &Smoother,
) -> Result<GarmentBinding> {
    let template = smoother.apply(relaxed)?;
    Ok(GarmentBinding::from_body(
        source.garment.clone(),
        &template,
        faces,
        source.body.clone(),
        body,
        DEFAULT_REGION_MARGIN_MM * 1e-3,
        CLOTH_WEIGHT_CUTOFF,
    )?)
}

/// `T̄_c` in f64, as the displacements are computed against it.
fn template64(binding: &GarmentBinding) -> impl Iterator<Item = Vector3<f64>> + '_ {
    binding.template().iter().map(|p| p.cast::<f64>())
}

fn flatten(points: impl Iterator<Item = Vector3<f64>>, out: &mut Vec<f32>) {
    for p in points {
        out.extend([p.x as f32, p.y as f32, p.z as f32]);
    }
}

fn check_frame(what: &'static str, frame: &[Vector3<f64>], n: usize) -> Result<()> {
    if frame.len() != n {
        return Err(Error::invalid(
            what,
            format!("{} cloth vertices for a garment of {n}", frame.len()),
        ));
    }
    if let Some(i) = frame.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(Error::invalid(
            what,
            format!("cloth vertex {i} is not finite"),
        ));
    }
    Ok(())
}

/// `Δ_G = ρ(S_c(β, 0)) − T̄_c`, `[3V]`, from the cloth `rest_cloth` simulated on the body of
/// shape β in the rest pose (no root motion).
pub fn fit_delta(
    binding: &GarmentBinding,
    smoother: &Smoother,
    rest_cloth: &[Vector3<f64>],
) -> Result<Vec<f32>> {
    check_frame("fit displacement", rest_cloth, binding.n_vertices())?;
    let smooth = smoother.apply(rest_cloth)?;
    let mut out = Vec::with_capacity(3 * smooth.len());
    flatten(
        smooth.iter().zip(template64(binding)).map(|(s, t)| s - t),
        &mut out,
    );
    Ok(out)
}

/// Un-poses simulated cloth frames of one shape: `Δ_L` per frame.
pub struct WrinkleExtractor<'a> {
    body: &'a BodyModel,
    binding: &'a GarmentBinding,
    joints: Vec<Vector3<f64>>,
    /// `T̄_c + Δ_G`.
    fitted: Vec<Vector3<f64>>,
    rest: Vec<Vector3<f64>>,
}

impl<'a> WrinkleExtractor<'a> {
    /// For shape `betas` with fit displacement `fit_delta` (`[3V]`).
    pub fn new(
        body: &'a BodyModel,
        binding: &'a GarmentBinding,
        betas: &[f64],
        fit_delta: &[f32],
    ) -> Result<Self> {
        let n = binding.n_vertices();
        if fit_delta.len() != 3 * n {
            return Err(Error::invalid(
                "wrinkle extraction",
                format!(
                    "fit displacement has {} values for {n} vertices",
                    fit_delta.len()
                ),
            ));
        }
        if binding.skin_weights().n_joints() != body.skeleton().n_joints() {
            return Err(Error::invalid(
                "wrinkle extraction",
                format!(
                    "cloth weights over {} joints, body has {}",
                    binding.skin_weights().n_joints(),
                    body.skeleton().n_joints()
                ),
            ));
        }
        let joints = body.shaped_joints(betas)?;
        let fitted = template64(binding)
            .enumerate()
            .map(|(v, t)| {
                t + Vector3::new(
                    fit_delta[3 * v] as f64,
                    fit_delta[3 * v + 1] as f64,
                    fit_delta[3 * v + 2] as f64,
                )
            })
            .collect();
        Ok(Self {
            body,
            binding,
            joints,
            fitted,
            rest: vec![Vector3::zeros(); n],
        })
    }

    /// Append `Δ_L` (`3V` values) of one frame: `cloth` simulated at `pose`.
    pub fn push_frame(
        &mut self,
        pose: &Pose,
        cloth: &[Vector3<f64>],
        out: &mut Vec<f32>,
    ) -> Result<()> {
        check_frame("wrinkle extraction", cloth, self.binding.n_vertices())?;
        let (_, transforms) = self
            .body
            .skeleton()
            .forward_kinematics(&self.joints, pose)?;
        unskin_points_damped(
            cloth,
            self.binding.skin_weights(),
            &transforms,
            UNSKIN_MIN_SINGULAR,
            &mut self.rest,
        )?;
        flatten(self.rest.iter().zip(&self.fitted).map(|(r, f)| r - f), out);
        Ok(())
    }
}

/// Blended skinning transforms whose smallest singular value is below this are inverted with
/// damping ([`unskin_points_damped`]): on the CMU data the exact inverse of such vertices gave
/// rest positions up to 14.5 m away, targets that would dominate the networks' squared loss.
pub const UNSKIN_MIN_SINGULAR: f64 = 0.25;

/// The joints whose rotations the wrinkle network sees: every joint that carries at least
/// `min_weight` of some garment vertex's cloth skin weight, plus all their ancestors (a joint's
/// rotation moves everything below it). In skeleton order. For a T-shirt this is the spine,
/// neck, shoulders and arms down to where the sleeves end, and the root (whose entry is its
/// tilt relative to gravity; see [`sartor_core::PoseFeatures`]).
pub fn select_joints(body: &BodyModel, weights: &SkinWeights, min_weight: f32) -> Vec<String> {
    let skeleton = body.skeleton();
    let mut used = vec![false; skeleton.n_joints()];
    for p in 0..weights.n_points() {
        for (j, w) in weights.point(p) {
            if w >= min_weight {
                used[j] = true;
            }
        }
    }
    for j in (0..skeleton.n_joints()).rev() {
        if used[j]
            && let Some(parent) = skeleton.parents()[j]
        {
            used[parent] = true;
        }
    }
    // Parents come before children in the skeleton order, so one reverse pass closes the set.
    skeleton
        .names()
        .iter()
        .zip(&used)
        .filter(|(_, u)| **u)
        .map(|(n, _)| n.clone())
        .collect()
}

#[cfg(test)]
mod tests {
    use nalgebra::{Rotation3, Vector3};
    use sartor_core::{BoneTransform, Parallelism, SkinWeights, unskin_points};

    use super::*;

    fn turned(angle: f64) -> BoneTransform<f64> {
        BoneTransform {
            linear: Rotation3::from_axis_angle(&Vector3::x_axis(), angle).into_inner(),
            translation: Vector3::new(0.1, 0.0, 0.0),
        }
    }

    #[test]
    fn damped_unskinning_is_exact_where_well_conditioned_and_bounded_where_not() {
        // Point 0 on one joint; point 1 split evenly between two joints 179.8° apart.
        let weights = SkinWeights::new(vec![0, 1, 3], vec![0, 0, 1], vec![1.0, 0.5, 0.5], 2)
            .expect("weights");
        let transforms = [turned(0.0), turned(std::f64::consts::PI - 0.004)];
        let posed = [Vector3::new(0.2, 0.3, -0.1), Vector3::new(0.15, 0.02, 0.01)];
        let mut exact = [Vector3::zeros(); 2];
        unskin_points(
            &posed,
            &weights,
            &transforms,
            &mut exact,
            Parallelism::Sequential,
        )
        .expect("exact");
        let mut damped = [Vector3::zeros(); 2];
        unskin_points_damped(
            &posed,
            &weights,
            &transforms,
            UNSKIN_MIN_SINGULAR,
            &mut damped,
        )
        .expect("damped");
        assert_eq!(damped[0], exact[0], "well conditioned: bit for bit");
        // The exact inverse of the near-singular blend goes far; the damped one stays within
        // |x − t| / s₀ and still maps back close to the posed point.
        let offset = (posed[1] - weights.blend(1, &transforms).translation).norm();
        assert!(exact[1].norm() > 5.0, "{}", exact[1].norm());
        assert!(damped[1].norm() <= offset / UNSKIN_MIN_SINGULAR + 1e-12);
        let back = weights.blend(1, &transforms).apply(&damped[1]);
        assert!((back - posed[1]).norm() < offset, "{:?}", back - posed[1]);
        // Sizes are checked.
        assert!(
            unskin_points_damped(
                &posed[..1],
                &weights,
                &transforms,
                UNSKIN_MIN_SINGULAR,
                &mut damped
            )
            .is_err()
        );
    }
}
