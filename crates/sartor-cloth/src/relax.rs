//! Relaxing a garment template on the template body: the template `T̄_c` of the paper is the
//! garment *at rest* on the body (β = 0, rest pose), not the shape it was cut in.

use nalgebra::Vector3;
use sartor_core::{BodyModel, BodyPoser, MeshProximity, Pose};
use serde::{Deserialize, Serialize};

use crate::drive::{DriveConfig, FrameError, FrameStepper, Region};
use crate::garment::{Garment, self_intersections};
use crate::material::Material;
use crate::{Error, Result};

/// Settings of [`relax_on_body`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelaxConfig {
    /// Frames (at 30 fps) simulated at most before giving up. Default 600 (20 s of simulated
    /// time).
    pub max_frames: usize,
    /// Frames simulated at least. Default 15 (0.5 s): a template cut with ease starts at rest
    /// but not in equilibrium.
    pub min_frames: usize,
    /// At rest when, after a frame, the largest vertex speed is below this, m/s. Default
    /// 2 mm/s.
    pub max_speed_m_per_s: f64,
    /// … and the kinetic energy is below this per kilogram of cloth, J/kg (= ½ v² of the mean
    /// square speed). Default 1e-7 J/kg (an RMS speed of 0.45 mm/s).
    pub kinetic_energy_j_per_kg: f64,
    /// Mass damping α during the relaxation only, 1/s. Default 2/s: the relaxed state is an
    /// equilibrium, not a motion, so damping only shortens the way there (the equilibrium does
    /// not depend on it).
    pub mass_damping_per_s: f64,
    /// The simulation settings (substeps, body region, contact, material model, retries).
    pub drive: DriveConfig,
}

impl Default for RelaxConfig {
    fn default() -> Self {
        Self {
            max_frames: 600,
            min_frames: 15,
            max_speed_m_per_s: 2e-3,
            kinetic_energy_j_per_kg: 1e-7,
            mass_damping_per_s: 2.0,
            drive: DriveConfig::default(),
        }
    }
}

/// What the relaxation did (written into `garment-report.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RelaxReport {
    /// Frames simulated.
    pub frames: usize,
    /// Kinetic energy after the last frame, J.
    pub kinetic_energy_j: f64,
    /// Largest vertex speed after the last frame, m/s.
    pub max_speed_m_per_s: f64,
    /// Smallest signed distance of a relaxed vertex to the (whole) body, mm; negative inside.
    pub min_signed_distance_mm: f64,
    /// Relaxed vertices inside the body.
    pub vertices_inside: usize,
    /// Pairs of relaxed triangles that intersect each other.
    pub self_intersecting_pairs: usize,
    /// Largest distance a vertex moved from the cut template, mm.
    pub max_displacement_mm: f64,
    /// Mean distance a vertex moved, mm.
    pub mean_displacement_mm: f64,
    /// Substeps over all frames (more than frames × substeps when frames were retried).
    pub substeps: usize,
    /// Body triangles that took part in contact.
    pub body_faces_kept: usize,
}

/// Simulate `garment` on the template body (β = 0, rest pose) until it is at rest (speed and
/// kinetic-energy thresholds of `config`) and check that the result is collision-free (no
/// vertex inside the body, no self-intersection). Returns the garment with the relaxed
/// positions as its template ([`Garment::with_template_positions`]: the rest metric is
/// unchanged) and what happened. Deterministic with the default sequential solver.
pub fn relax_on_body(
    garment: &Garment,
    body: &BodyModel,
    material: &Material,
    config: &RelaxConfig,
) -> Result<(Garment, RelaxReport)> {
    let mut drive = config.drive.clone();
    drive.sim.mass_damping_per_s = config.mass_damping_per_s;
    drive.validate()?;
    if config.min_frames > config.max_frames
        || !(config.max_speed_m_per_s > 0.0 && config.kinetic_energy_j_per_kg > 0.0)
    {
        return Err(Error::invalid(
            "relax config",
            format!("needs min_frames ≤ max_frames and positive thresholds, got {config:?}"),
        ));
    }
    let zeros = vec![0.0; body.n_betas()];
    let rest = Pose::rest(body.skeleton().n_joints());
    let mut body_rest = vec![Vector3::zeros(); body.n_vertices()];
    BodyPoser::new(body).pose_into(&zeros, &rest, &mut body_rest)?;
    let region = if drive.region.whole_body {
        Region::whole(body)
    } else {
        Region::near_garment(body, garment, &rest, &[], drive.region.margin_m)?
    };
    let mut stepper = FrameStepper::new(
        body,
        garment,
        material,
        &drive,
        &region,
        &body_rest,
        garment.positions(),
        sartor_core::FPS,
    )?;
    let mass_kg = stepper.sim.cloth().total_mass_kg();
    let mut frames = 0;
    let mut last = (f64::INFINITY, f64::INFINITY);
    while frames < config.max_frames {
        let (_, checks) =
            stepper
                .advance(&body_rest, &body_rest)
                .map_err(|(e, attempts)| match e {
                    FrameError::Hard(e) => e,
                    FrameError::Failure(reason) => Error::SequenceFailed {
                        sequence: format!("relaxation of {}", garment.name()),
                        frame: frames,
                        attempts,
                        reason,
                    },
                })?;
        frames += 1;
        last = (checks.kinetic_energy_j, checks.max_speed_m_per_s);
        if frames >= config.min_frames
            && checks.max_speed_m_per_s < config.max_speed_m_per_s
            && checks.kinetic_energy_j < config.kinetic_energy_j_per_kg * mass_kg
        {
            break;
        }
    }
    let (kinetic_energy_j, max_speed_m_per_s) = last;
    if !(max_speed_m_per_s < config.max_speed_m_per_s
        && kinetic_energy_j < config.kinetic_energy_j_per_kg * mass_kg)
    {
        return Err(Error::invalid(
            "garment relaxation",
            format!(
                "{} did not come to rest in {frames} frames: kinetic energy {kinetic_energy_j:.3e} J, \
                 largest speed {:.2} mm/s",
                garment.name(),
                max_speed_m_per_s * 1e3
            ),
        ));
    }
    let relaxed = garment.with_template_positions(stepper.sim.positions().to_vec())?;
    let whole = MeshProximity::new(&body_rest, body.faces())?;
    let distances: Vec<f64> = relaxed
        .positions()
        .iter()
        .map(|p| whole.closest(p).signed_distance_m)
        .collect();
    let displacement: Vec<f64> = relaxed
        .positions()
        .iter()
        .zip(garment.positions())
        .map(|(a, b)| (a - b).norm())
        .collect();
    let report = RelaxReport {
        frames,
        kinetic_energy_j,
        max_speed_m_per_s,
        min_signed_distance_mm: distances.iter().copied().fold(f64::INFINITY, f64::min) * 1e3,
        vertices_inside: distances.iter().filter(|d| **d < 0.0).count(),
        self_intersecting_pairs: self_intersections(relaxed.mesh()).len(),
        max_displacement_mm: displacement.iter().copied().fold(0.0, f64::max) * 1e3,
        mean_displacement_mm: displacement.iter().sum::<f64>() / displacement.len() as f64 * 1e3,
        substeps: stepper.substeps.total,
        body_faces_kept: region.n_kept(),
    };
    if report.vertices_inside > 0 || report.self_intersecting_pairs > 0 {
        return Err(Error::invalid(
            "garment relaxation",
            format!(
                "{} is not collision-free at rest: {} vertices inside the body (deepest {:.2} mm), \
                 {} self-intersecting triangle pairs",
                garment.name(),
                report.vertices_inside,
                -report.min_signed_distance_mm,
                report.self_intersecting_pairs
            ),
        ));
    }
    Ok((relaxed, report))
}
