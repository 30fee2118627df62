//! Garment animation per avatar: [`GarmentRig`] (the shared, immutable assets of one level of
//! detail), [`GarmentAnimator`] (one avatar: shape cache, GRU state, previous pose, buffers) and
//! [`GarmentCrowd`] (many avatars stepping together, sharing one pass over the weights).
//!
//! One frame of one avatar:
//!
//! 1. the wrinkle input: β and the pose features of `sartor_core::PoseFeatures` (joint
//!    rotations, root velocities from the previous pose), laid out as the model's header says;
//! 2. `Δ_L = R_L(β, θ)`, one GRU step (skipped in fit-only mode: `Δ_L = 0`);
//! 3. `T_c = T̄_c + Δ_G + Δ_L` with `Δ_G = R_G(β)` cached by `set_shape`;
//! 4. `M_c = W(T_c, β, θ, W_c)` by `sartor_core::skin_points`, with the body's skinning
//!    transforms at `J(β)` (cached);
//! 5. the strain limit (optional, off by default, see `strain.rs`): no garment edge beyond a
//!    multiple of its rest length;
//! 6. the collision post-process (optional, see `collision.rs`) against the body region, posed
//!    from `T_b(β)` (cached).
//!
//! After `set_shape`, a frame allocates nothing (the integration tests count allocations).

use std::ops::Range;
use std::sync::Arc;

use nalgebra::Vector3;
use rayon::prelude::*;
use sartor_core::{
    BodyModel, BoneTransform, FPS, Parallelism, Pose, PoseFeatureSpec, PoseFeatures, RootFeature,
    RotationEncoding, SurfaceAnchors, skin_points,
};

use crate::collision::{BodyRegion, CertifyStats, Collider, CollisionOptions};
use crate::error::{Error, Result, check_finite, check_finite_points, check_len};
use crate::format::Feature;
use crate::kernels::Precision;
use crate::network::{GarmentNetwork, NetworkOptions, Workspace};
use crate::strain::{GarmentEdges, LimitScratch, StrainLimit};
use sartor_core::GarmentBinding;

/// Where an avatar's shaped garment `T̄_c + Δ` comes from, set once per shape.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FitMode {
    /// `Δ = Δ_G = R_G(β)`, the fit MLP: the method of the paper.
    #[default]
    Network,
    /// Retargeting, the baseline for new shapes with no learned fit: each cloth vertex moves with
    /// its closest point on the template body (β = 0, rest pose), found once per rig,
    /// `Δ(v) = Σ_k b_k (T_b(β) − T_b(0))[f_k]` over the three vertices `f_k` of that triangle with
    /// barycentric weights `b_k`. The garment follows the body's shape change as if glued to it.
    Retarget,
    /// `Δ = 0`: the template `T̄_c` as it is (with no wrinkles, the LBS baseline: the template
    /// skinned to the posed body).
    Template,
}

/// Where an avatar's per-frame wrinkles `Δ_L` come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum WrinkleMode {
    /// `Δ_L = R_L(β, θ)`, one step of the wrinkle GRU per frame: the method of the paper.
    #[default]
    Gru,
    /// The linear baseline (LR) in place of the GRU: one linear layer of the same inputs, no
    /// state. The model must carry it (`linear_baseline` in its header).
    Linear,
    /// `Δ_L = 0`: the fit-only mode for static try-on (no network cost per frame, no state).
    None,
}

/// What the networks see when the requested body shape lies outside the shapes the model was
/// trained on (the convex hull of `model.json`'s `training_betas`). The body always takes the
/// requested shape; the rule decides the garment. A model without recorded training shapes
/// always extrapolates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BetaOutOfRange {
    /// The networks see β as requested: they extrapolate (a larger body's garment sinks into
    /// it, a smaller one's crumples).
    Extrapolate,
    /// The networks see `β'`, the point of the training shapes' hull nearest β: the garment of
    /// the nearest trained shape, on the requested body.
    Project,
    /// The networks see `β'`, and the garment follows the rest of the body's shape change
    /// geometrically: `Δ_G = R_G(β') + D(β) − D(β')` with `D` the [`FitMode::Retarget`]
    /// displacement (each garment vertex carried by its closest template-body triangle). Inside
    /// the hull `β' = β`: the network alone.
    #[default]
    ProjectAndFollow,
}

/// What an avatar computes per frame (the scene-side half of a [`LevelOfDetail`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnimatorOptions {
    /// The shaped garment: the fit MLP (default) or a baseline.
    pub fit: FitMode,
    /// What the networks see beyond the trained range of β.
    pub beta_out_of_range: BetaOutOfRange,
    /// The wrinkles: the GRU (default), the linear baseline, or none (static try-on).
    pub wrinkles: WrinkleMode,
    /// Strain limiting of the posed garment before the post-process (see [`StrainLimit`]), or
    /// `None`: the paper's method, and the default.
    pub strain_limit: Option<StrainLimit>,
    /// The collision post-process, or `None` to skip it.
    pub collision: Option<CollisionOptions>,
    /// Threads for the network, the skinning and the post-process (results do not depend on it).
    pub parallelism: Parallelism,
    /// Time between frames, seconds (the root velocities of the pose features): the training
    /// data's frame rate, 30 fps.
    pub frame_dt_secs: f64,
}

impl Default for AnimatorOptions {
    /// Wrinkles on, no strain limit, post-process on (defaults of [`CollisionOptions`]), β
    /// beyond the training shapes projected onto them for the networks with the garment
    /// following the body, one thread, 30 fps.
    fn default() -> Self {
        Self {
            fit: FitMode::Network,
            beta_out_of_range: BetaOutOfRange::default(),
            wrinkles: WrinkleMode::Gru,
            strain_limit: None,
            collision: Some(CollisionOptions::default()),
            parallelism: Parallelism::Sequential,
            frame_dt_secs: 1.0 / FPS,
        }
    }
}

/// A level of detail: everything a scene may trade for speed, in one place. Each field's cost and
/// error is measured by `cargo xtask bench runtime` and the trade-off report.
///
/// | option | where | effect |
/// | --- | --- | --- |
/// | `network.precision` | load | f32 / f16 / int8 weights: memory and bandwidth ÷1 / ÷2 / ÷4 |
/// | `network.output_rank` | load | rank-`r` output (PCA prefix or truncated SVD) |
/// | `animator.wrinkles` | per rig | fit-only mode for static try-on (no GRU) |
/// | `animator.strain_limit` | per rig | strain limit (bench `postprocess`; eval `ours_strain_limit`) |
/// | `animator.collision` | per rig | collision post-process on / off, and its query |
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LevelOfDetail {
    /// How the network is loaded.
    pub network: NetworkOptions,
    /// What each avatar computes.
    pub animator: AnimatorOptions,
}

impl LevelOfDetail {
    /// The full model in f32 with the post-process: the reference.
    pub fn full() -> Self {
        Self::default()
    }

    /// A light setting for crowds: int8 weights, rank-64 output, post-process on.
    pub fn reduced() -> Self {
        Self {
            network: NetworkOptions {
                precision: Precision::Int8,
                output_rank: Some(64),
            },
            animator: AnimatorOptions::default(),
        }
    }

    /// Static try-on: fit only (no GRU), post-process on.
    pub fn static_try_on() -> Self {
        Self {
            network: NetworkOptions::default(),
            animator: AnimatorOptions {
                wrinkles: WrinkleMode::None,
                ..AnimatorOptions::default()
            },
        }
    }
}

/// How the wrinkle input vector is filled: β at one range, each pose block by its own
/// `PoseFeatures` into its own range.
#[derive(Clone, Debug)]
struct InputMap {
    betas: Range<usize>,
    blocks: Vec<(Range<usize>, PoseFeatures)>,
}

impl InputMap {
    fn new(network: &GarmentNetwork, body: &BodyModel) -> Result<Self> {
        let mut betas = 0..0;
        let mut blocks = Vec::new();
        for block in &network.header().wrinkle_inputs {
            let range = block.offset..block.offset + block.len;
            let spec = match &block.feature {
                Feature::Betas => {
                    betas = range;
                    continue;
                }
                Feature::JointRotations { encoding, joints } => PoseFeatureSpec {
                    joints: joints.clone(),
                    encoding: *encoding,
                    root: Vec::new(),
                },
                Feature::Root { components } => PoseFeatureSpec {
                    joints: Vec::new(),
                    encoding: RotationEncoding::Rot6d,
                    root: components
                        .iter()
                        .map(|c| RootFeature::from_name(c))
                        .collect::<sartor_core::Result<_>>()?,
                },
            };
            blocks.push((range, spec.bind(body.skeleton())?));
        }
        Ok(Self { betas, blocks })
    }
}

/// The assets one level of detail of one garment shares across all its avatars: network,
/// binding, body model (each `Arc`-shared, so several rigs can share weights or bodies), the
/// options, the input layout and the body region. Immutable.
#[derive(Debug)]
pub struct GarmentRig {
    network: Arc<GarmentNetwork>,
    binding: Arc<GarmentBinding>,
    body: Arc<BodyModel>,
    options: AnimatorOptions,
    inputs: InputMap,
    region: BodyRegion,
    /// For [`FitMode::Retarget`] and [`BetaOutOfRange::ProjectAndFollow`]: each cloth vertex
    /// anchored on the template body.
    retarget: Option<SurfaceAnchors>,
    /// The garment's edges, where [`AnimatorOptions::strain_limit`] is set.
    edges: Option<GarmentEdges>,
}

impl GarmentRig {
    /// Check that the three assets belong together (the binding against the model's header and
    /// the body, the model's joints against the body's skeleton, β counts) and prepare the
    /// input layout and the body region.
    pub fn new(
        network: Arc<GarmentNetwork>,
        binding: Arc<GarmentBinding>,
        body: Arc<BodyModel>,
        options: AnimatorOptions,
    ) -> Result<Self> {
        network.header().check_binding(&binding)?;
        binding.check_body(&body)?;
        if network.n_betas() > body.n_betas() {
            return Err(Error::invalid(
                "garment rig",
                format!(
                    "the model takes {} betas, the body {:?} has {}",
                    network.n_betas(),
                    body.name(),
                    body.n_betas()
                ),
            ));
        }
        if !(options.frame_dt_secs.is_finite() && options.frame_dt_secs > 0.0) {
            return Err(Error::invalid(
                "animator options",
                format!(
                    "frame_dt_secs must be finite and positive, got {}",
                    options.frame_dt_secs
                ),
            ));
        }
        if let Some(c) = &options.collision {
            c.validate()?;
        }
        if let Some(l) = &options.strain_limit {
            l.validate()?;
        }
        if options.wrinkles == WrinkleMode::Linear && !network.has_linear_baseline() {
            return Err(Error::invalid(
                "animator options",
                "the linear baseline was asked for, but the model has none",
            ));
        }
        let inputs = InputMap::new(&network, &body)?;
        let region = BodyRegion::new(&body, binding.region_faces())?;
        let follow = options.fit == FitMode::Network
            && options.beta_out_of_range == BetaOutOfRange::ProjectAndFollow
            && network.header().training_betas.is_some();
        let retarget = match options.fit {
            FitMode::Retarget => Some(retarget_binding(&body, binding.template())?),
            FitMode::Network if follow => Some(retarget_binding(&body, binding.template())?),
            FitMode::Network | FitMode::Template => None,
        };
        let edges = options
            .strain_limit
            .map(|_| GarmentEdges::new(binding.template().len(), binding.faces()));
        Ok(Self {
            network,
            binding,
            body,
            options,
            inputs,
            region,
            retarget,
            edges,
        })
    }

    /// The network.
    pub fn network(&self) -> &Arc<GarmentNetwork> {
        &self.network
    }

    /// The binding.
    pub fn binding(&self) -> &Arc<GarmentBinding> {
        &self.binding
    }

    /// The body model.
    pub fn body(&self) -> &Arc<BodyModel> {
        &self.body
    }

    /// The options.
    pub fn options(&self) -> &AnimatorOptions {
        &self.options
    }

    /// The body region the post-process uses.
    pub fn region(&self) -> &BodyRegion {
        &self.region
    }

    /// Garment vertices `V`.
    pub fn n_vertices(&self) -> usize {
        self.binding.n_vertices()
    }
}

/// Each cloth vertex anchored to its closest point on the template body (β = 0, rest pose)
/// ([`FitMode::Retarget`]).
fn retarget_binding(body: &BodyModel, template: &[Vector3<f32>]) -> Result<SurfaceAnchors> {
    Ok(SurfaceAnchors::on(
        body.template_proximity()?,
        template.iter().map(|p| p.cast::<f64>()),
    ))
}

/// Add to `fit` (`3V` values) each cloth vertex's displacement with its anchor from the body
/// `from` to the body `to` (every body vertex).
fn add_retarget(
    fit: &mut [f32],
    anchors: &SurfaceAnchors,
    to: &[Vector3<f64>],
    from: &[Vector3<f64>],
) {
    for (i, d) in fit.chunks_exact_mut(3).enumerate() {
        let delta = anchors.displacement(i, to, from);
        for (x, dx) in d.iter_mut().zip(delta.iter()) {
            *x += *dx as f32;
        }
    }
}

/// Counts of cloth vertices against the exact closest point of the posed body region.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CollisionCount {
    /// Vertices inside the body (negative signed distance).
    pub inside: usize,
    /// Vertices closer than `margin − tolerance` (inside ones included).
    pub within_margin: usize,
}

/// Where one [`GarmentAnimator::frame`] spent its time, in milliseconds of the clock given to
/// [`GarmentAnimator::set_stage_clock`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// The wrinkle input and the network step (GRU and output layer, or the linear baseline).
    pub network_ms: f64,
    /// Forward kinematics and the garment's skinning.
    pub skinning_ms: f64,
    /// The strain limit ([`AnimatorOptions::strain_limit`]; 0 without it).
    pub strain_limit_ms: f64,
    /// The collision post-process (posing the body region and pushing vertices out).
    pub post_process_ms: f64,
}

/// What a garment's post-processing did ([`GarmentAnimator::post_process`]): the strain limit,
/// then the collision post-process, each where the rig has it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PostProcessReport {
    /// Edge projections of the strain limit.
    pub strained: usize,
    /// Garment vertices the collision post-process moved.
    pub pushed: usize,
    /// The strain limit's time, ms of the animator's stage clock (0 without one).
    pub strain_limit_ms: f64,
    /// The collision post-process's time, ms of the stage clock (0 without one).
    pub post_process_ms: f64,
}

/// One avatar's state, everything but the network buffers (which a crowd batches).
#[derive(Clone, Debug)]
struct Avatar {
    betas: Vec<f32>,
    rest_joints: Vec<Vector3<f64>>,
    fit: Vec<f32>,
    cloth_rest: Vec<Vector3<f32>>,
    unposed: Vec<Vector3<f32>>,
    posed_joints: Vec<Vector3<f64>>,
    transforms: Vec<BoneTransform<f64>>,
    transforms_f32: Vec<BoneTransform<f32>>,
    previous: Pose,
    has_previous: bool,
    collider: Option<Collider>,
    /// Per garment edge, its longest allowed length at this shape (strain limit only).
    edge_limits: Vec<f32>,
    limit_scratch: LimitScratch,
    /// Edge projections of the strain limit in the last frame.
    strained: usize,
    vertices: Vec<Vector3<f32>>,
    pushed: usize,
    /// A clock in milliseconds that times the stages of a frame (none: not timed).
    clock: Option<fn() -> f64>,
    times: StageTimes,
}

impl Avatar {
    fn new(rig: &GarmentRig) -> Self {
        let (v, j) = (rig.n_vertices(), rig.body.skeleton().n_joints());
        Self {
            betas: Vec::new(),
            rest_joints: vec![Vector3::zeros(); j],
            fit: vec![0.0; 3 * v],
            cloth_rest: vec![Vector3::zeros(); v],
            unposed: vec![Vector3::zeros(); v],
            posed_joints: vec![Vector3::zeros(); j],
            transforms: vec![BoneTransform::identity(); j],
            transforms_f32: vec![BoneTransform::identity(); j],
            previous: Pose::rest(j),
            has_previous: false,
            collider: None,
            edge_limits: Vec::new(),
            limit_scratch: LimitScratch::default(),
            strained: 0,
            vertices: rig.binding.template().to_vec(),
            pushed: 0,
            clock: None,
            times: StageTimes::default(),
        }
    }

    /// The clock's reading, or 0 without a clock.
    fn now(&self) -> f64 {
        self.clock.map_or(0.0, |clock| clock())
    }

    /// Cache `R_G(β)`, `T̄_c + Δ_G`, `J(β)` and the shaped body region; the networks see β
    /// through the rig's [`BetaOutOfRange`] rule.
    fn set_shape(&mut self, rig: &GarmentRig, betas: &[f32], ws: &mut Workspace) -> Result<()> {
        check_len("betas", betas.len(), rig.network.n_betas())?;
        check_finite("betas", betas)?;
        let par = rig.options.parallelism;
        let betas64: Vec<f64> = betas.iter().map(|&b| f64::from(b)).collect();
        // What the networks see.
        let mut seen = betas.to_vec();
        // Unknown (no training shapes recorded): taken as within.
        let mut beyond_training = false;
        if let Some(shapes) = &rig.network.header().training_betas {
            shapes.project(betas, &mut seen);
            beyond_training = seen != betas;
            if rig.options.beta_out_of_range == BetaOutOfRange::Extrapolate {
                seen.copy_from_slice(betas);
            }
        }
        match (rig.options.fit, &rig.retarget) {
            (FitMode::Network, None) => rig.network.fit(&seen, &mut self.fit, ws, par)?,
            (FitMode::Network, Some(bound)) => {
                // Project and follow: the network at the projected shape, plus the body's shape
                // change from the projected to the requested shape.
                rig.network.fit(&seen, &mut self.fit, ws, par)?;
                if seen != betas {
                    let seen64: Vec<f64> = seen.iter().map(|&b| f64::from(b)).collect();
                    let (to, from) = (
                        rig.body.shaped_vertices(&betas64)?,
                        rig.body.shaped_vertices(&seen64)?,
                    );
                    add_retarget(&mut self.fit, bound, &to, &from);
                }
            }
            (FitMode::Retarget, Some(bound)) => {
                self.fit.fill(0.0);
                let shaped = rig.body.shaped_vertices(&betas64)?;
                add_retarget(
                    &mut self.fit,
                    bound,
                    &shaped,
                    rig.body.template().positions(),
                );
            }
            (FitMode::Template, _) | (FitMode::Retarget, None) => self.fit.fill(0.0),
        }
        let rest_joints = rig.body.shaped_joints(&betas64)?;
        let template = rig.binding.template();
        let cloth_rest: Vec<Vector3<f32>> = template
            .iter()
            .zip(self.fit.chunks_exact(3))
            .map(|(t, d)| t + Vector3::new(d[0], d[1], d[2]))
            .collect();
        let collider = match &rig.options.collision {
            Some(options) => {
                let shaped = rig.body.shaped_vertices(&betas64)?;
                let mut collider =
                    Collider::new(&rig.region, &shaped, &cloth_rest, options, beyond_training)?;
                // The last shape's nearest faces start the new shape's searches: a change of
                // shape's first frame on the heavy 1.90 m body took some 30 ms cold.
                if let Some(old) = &self.collider {
                    collider.warm_from(old);
                }
                Some(collider)
            }
            None => None,
        };
        if let (Some(edges), Some(limit)) = (&rig.edges, &rig.options.strain_limit) {
            edges.limits(
                template,
                &cloth_rest,
                limit.max_stretch,
                &mut self.edge_limits,
            );
            self.limit_scratch.reserve(self.edge_limits.len());
        }
        self.betas = seen;
        self.rest_joints = rest_joints;
        self.cloth_rest = cloth_rest;
        self.collider = collider;
        Ok(())
    }

    /// The wrinkle input of `pose` (β, then the pose blocks) into `x`.
    fn features(&self, rig: &GarmentRig, pose: &Pose, x: &mut [f32]) -> Result<()> {
        x[rig.inputs.betas.clone()].copy_from_slice(&self.betas);
        let previous = self.has_previous.then_some(&self.previous);
        for (range, features) in &rig.inputs.blocks {
            features.compute(
                previous,
                pose,
                rig.options.frame_dt_secs,
                &mut x[range.clone()],
            )?;
        }
        Ok(())
    }

    /// Compose, skin and post-process one frame; `wrinkle` is `Δ_L` (`None`: zero).
    /// `resolve`: whether the post-process runs (else it is left to
    /// [`GarmentAnimator::post_process`], elsewhere).
    fn finish(
        &mut self,
        rig: &GarmentRig,
        pose: &Pose,
        wrinkle: Option<&[f32]>,
        par: Parallelism,
        resolve: bool,
    ) -> Result<()> {
        let start = self.now();
        self.pose_bones(rig, pose)?;
        for (t32, t) in self.transforms_f32.iter_mut().zip(&self.transforms) {
            *t32 = t.to_f32();
        }
        match wrinkle {
            Some(w) => {
                for ((u, r), d) in self
                    .unposed
                    .iter_mut()
                    .zip(&self.cloth_rest)
                    .zip(w.chunks_exact(3))
                {
                    *u = r + Vector3::new(d[0], d[1], d[2]);
                }
            }
            None => self.unposed.copy_from_slice(&self.cloth_rest),
        }
        skin_points(
            &self.unposed,
            rig.binding.skin_weights(),
            &self.transforms_f32,
            &mut self.vertices,
            par,
        )?;
        let skinned = self.now();
        let report = if resolve {
            // (Taken out and put back: no allocation.)
            let mut vertices = std::mem::take(&mut self.vertices);
            let report = self.post_process(rig, &mut vertices, par);
            self.vertices = vertices;
            report?
        } else {
            PostProcessReport::default()
        };
        self.strained = report.strained;
        self.pushed = report.pushed;
        self.times.skinning_ms = skinned - start;
        self.times.strain_limit_ms = report.strain_limit_ms;
        self.times.post_process_ms = report.post_process_ms;
        self.remember(pose);
        Ok(())
    }

    /// The strain limit and the collision post-process of `vertices`, skinned by this
    /// avatar's transforms (posed for the frame), each where the rig has it.
    fn post_process(
        &mut self,
        rig: &GarmentRig,
        vertices: &mut [Vector3<f32>],
        par: Parallelism,
    ) -> Result<PostProcessReport> {
        let start = self.now();
        let mut strained = 0;
        if let (Some(edges), Some(limit)) = (&rig.edges, &rig.options.strain_limit) {
            strained = edges.limit(vertices, &self.edge_limits, limit, &mut self.limit_scratch);
        }
        let limited = self.now();
        let mut pushed = 0;
        if let Some(collider) = &mut self.collider {
            collider.pose(&rig.region, &self.transforms, par)?;
            pushed = collider.resolve(vertices, rig.binding.faces(), par);
        }
        Ok(PostProcessReport {
            strained,
            pushed,
            strain_limit_ms: limited - start,
            post_process_ms: self.now() - limited,
        })
    }

    /// The joints and skinning transforms of `pose` at this shape.
    fn pose_bones(&mut self, rig: &GarmentRig, pose: &Pose) -> Result<()> {
        Ok(rig.body.skeleton().forward_kinematics_into(
            &self.rest_joints,
            pose,
            &mut self.posed_joints,
            &mut self.transforms,
        )?)
    }

    /// Keep `pose` as the pose before the next frame (validated against the skeleton).
    fn remember(&mut self, pose: &Pose) {
        // Field by field: the derived `Pose::clone_from` would allocate a new rotation vector
        // (the lengths agree: the pose was validated against the skeleton).
        self.previous.root_translation_m = pose.root_translation_m;
        self.previous.root_orientation = pose.root_orientation;
        self.previous
            .local_rotations
            .copy_from_slice(&pose.local_rotations);
        self.has_previous = true;
    }

    fn collision_count(
        &self,
        vertices: &[Vector3<f32>],
        tolerance_m: f64,
    ) -> Option<CollisionCount> {
        let collider = self.collider.as_ref()?;
        let margin = collider.margin_m() - tolerance_m;
        let mut count = CollisionCount::default();
        collider.exact_each(vertices, |c| {
            let d = c.signed_distance_m;
            count.inside += usize::from(d < 0.0);
            count.within_margin += usize::from(d < margin);
        });
        Some(count)
    }
}

/// One avatar wearing the garment: `set_shape` once, then `frame` per pose. Carries the GRU state
/// and the previous pose between frames; `reset` starts a new sequence.
///
/// ```no_run
/// use std::sync::Arc;
/// use sartor_runtime::{GarmentAnimator, GarmentBinding, GarmentNetwork, GarmentRig, LevelOfDetail};
///
/// let dir = std::path::Path::new("datasets/models/default");
/// let body_dir = std::path::Path::new("datasets/body/makehuman");
/// let lod = LevelOfDetail::full();
/// let rig = Arc::new(GarmentRig::new(
///     Arc::new(GarmentNetwork::load_with(dir, lod.network)?),
///     Arc::new(GarmentBinding::load(dir)?),
///     Arc::new(sartor_core::BodyModel::load(body_dir)?),
///     lod.animator,
/// )?);
/// let mut avatar = GarmentAnimator::new(rig.clone())?;
/// avatar.set_shape(&[0.5, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])?;
/// for pose in sartor_motion::procedural::clip("walk_normal")?.frames() {
///     let garment = avatar.frame(pose)?; // V posed vertices, metres
///     let _ = garment;
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct GarmentAnimator {
    rig: Arc<GarmentRig>,
    avatar: Avatar,
    ws: Workspace,
    state: Vec<f32>,
    x: Vec<f32>,
    wrinkle: Vec<f32>,
}

impl GarmentAnimator {
    /// An avatar of shape β = 0 at the start of a sequence.
    pub fn new(rig: Arc<GarmentRig>) -> Result<Self> {
        let net = &rig.network;
        let mut s = Self {
            avatar: Avatar::new(&rig),
            ws: net.workspace(1),
            state: net.initial_state(),
            x: vec![0.0; net.input_size()],
            wrinkle: vec![0.0; net.output_size()],
            rig,
        };
        let zeros = vec![0.0; s.rig.network.n_betas()];
        s.set_shape(&zeros)?;
        Ok(s)
    }

    /// The shared assets.
    pub fn rig(&self) -> &Arc<GarmentRig> {
        &self.rig
    }

    /// Set the body shape β (`n_betas` of the model, finite): caches `R_G(β)`, `J(β)` and the
    /// shaped body region (and the candidate faces of the post-process). Allocates; call it once
    /// per avatar, not per frame. Does not reset the sequence.
    pub fn set_shape(&mut self, betas: &[f32]) -> Result<()> {
        self.avatar.set_shape(&self.rig, betas, &mut self.ws)
    }

    /// The β the networks see (the requested β through the rig's [`BetaOutOfRange`] rule).
    pub fn betas(&self) -> &[f32] {
        &self.avatar.betas
    }

    /// Start a new sequence: zero GRU state, no previous pose (zero root velocity next frame).
    pub fn reset(&mut self) {
        self.state.fill(0.0);
        self.avatar.has_previous = false;
    }

    /// Start a new sequence that continues from `previous` (zero GRU state, `previous` as the
    /// pose before the next frame, for its root velocities): how the training data begins a
    /// motion after the rest frames, and how an application resumes a character standing still.
    pub fn reset_from(&mut self, previous: &Pose) -> Result<()> {
        previous.validate(self.rig.body.skeleton().n_joints())?;
        self.reset();
        self.avatar.previous.clone_from(previous);
        self.avatar.has_previous = true;
        Ok(())
    }

    /// Animate one frame; returns the garment's `V` posed vertices (metres). Errors (leaving the
    /// avatar as it was) on a pose that is not finite, not unit, or of another skeleton.
    /// Allocation-free.
    ///
    /// Under [`Parallelism::Rayon`] the whole frame runs inside
    /// [`with_workers_awake`](sartor_core::awake::with_workers_awake), on a worker of the pool
    /// with the others polling for its parallel steps (the network's products, the skinning,
    /// the post-process's first pass), so that none finds its helpers asleep: until 2026-12-02
    /// only the network step did, and on the 2-core Intel Xeon VM two threads ran the shipped
    /// model's frame with post-process no faster than one (a thread woken for the
    /// post-process's split first pass joined it some 90 µs late). The same bits either way.
    pub fn frame(&mut self, pose: &Pose) -> Result<&[Vector3<f32>]> {
        self.frame_with(pose, true)
    }

    /// [`GarmentAnimator::frame`] without its post-processing (the strain limit and the
    /// collision post-process): the garment skinned for `pose`, to be post-processed elsewhere
    /// by [`GarmentAnimator::post_process`] of an animator of the same rig at the same shape
    /// (the try-on page's worker thread), whose answer [`GarmentAnimator::take_post_processed`]
    /// then makes this frame's garment. Until then [`GarmentAnimator::vertices`] are these and
    /// [`GarmentAnimator::last_frame_pushed`] is 0. The same as `frame` where the rig has no
    /// post-processing. Errors as `frame`. Allocation-free.
    pub fn frame_deferred(&mut self, pose: &Pose) -> Result<&[Vector3<f32>]> {
        self.frame_with(pose, false)
    }

    /// [`GarmentAnimator::frame`], the post-processing run only where `resolve`.
    fn frame_with(&mut self, pose: &Pose, resolve: bool) -> Result<&[Vector3<f32>]> {
        match self.rig.options.parallelism {
            Parallelism::Sequential => self.frame_now(pose, resolve)?,
            Parallelism::Rayon => {
                sartor_core::awake::with_workers_awake(|| self.frame_now(pose, resolve))?;
            }
        }
        Ok(&self.avatar.vertices)
    }

    /// The post-processing of [`GarmentAnimator::frame`] (the strain limit, then the collision
    /// post-process, each where the rig has it) on `vertices`, a garment that
    /// [`GarmentAnimator::frame_deferred`] of an animator of the same rig at the same shape made
    /// for `pose`: the body region posed by `pose` at this animator's shape. The result is that
    /// frame's garment bit for bit (the post-process's state across frames only warm-starts
    /// its search; the runtime's tests compare them over a real clip, jumps included). Nothing
    /// else of this animator changes (its GRU state, previous pose and
    /// [`GarmentAnimator::vertices`] stay); its [`GarmentAnimator::stage_times`] hold this
    /// post-processing alone. Errors, moving nothing, on a pose not of the body's skeleton, on
    /// vertices of another count or not finite, or where the rig has neither.
    pub fn post_process(
        &mut self,
        pose: &Pose,
        vertices: &mut [Vector3<f32>],
    ) -> Result<PostProcessReport> {
        let rig = &*self.rig;
        pose.validate(rig.body.skeleton().n_joints())?;
        check_len("garment vertices", vertices.len(), rig.n_vertices())?;
        check_finite_points("garment vertices", vertices)?;
        let strain_limit = rig.edges.is_some() && rig.options.strain_limit.is_some();
        if self.avatar.collider.is_none() && !strain_limit {
            return Err(Error::invalid(
                "post-process",
                "the rig has neither a strain limit nor a collision post-process",
            ));
        }
        let avatar = &mut self.avatar;
        let par = rig.options.parallelism;
        let mut run = || -> Result<PostProcessReport> {
            avatar.pose_bones(rig, pose)?;
            let report = avatar.post_process(rig, vertices, par)?;
            avatar.times = StageTimes {
                strain_limit_ms: report.strain_limit_ms,
                post_process_ms: report.post_process_ms,
                ..StageTimes::default()
            };
            Ok(report)
        };
        match par {
            Parallelism::Sequential => run(),
            Parallelism::Rayon => sartor_core::awake::with_workers_awake(run),
        }
    }

    /// Make `vertices`, the answer of [`GarmentAnimator::post_process`] (elsewhere) to the
    /// garment of the last [`GarmentAnimator::frame_deferred`], this frame's garment, with what
    /// it reported: afterwards the animator is as after `frame`. Errors, changing nothing, on
    /// vertices of another count or not finite.
    pub fn take_post_processed(
        &mut self,
        vertices: &[Vector3<f32>],
        report: &PostProcessReport,
    ) -> Result<()> {
        check_len("garment vertices", vertices.len(), self.rig.n_vertices())?;
        check_finite_points("garment vertices", vertices)?;
        self.avatar.vertices.copy_from_slice(vertices);
        self.avatar.strained = report.strained;
        self.avatar.pushed = report.pushed;
        self.avatar.times.strain_limit_ms = report.strain_limit_ms;
        self.avatar.times.post_process_ms = report.post_process_ms;
        Ok(())
    }

    /// Step the sequence by `pose` without making its garment: the wrinkle network's state and
    /// the previous pose advance as in [`GarmentAnimator::frame`], but nothing is skinned or
    /// post-processed ([`GarmentAnimator::vertices`] keep the last frame's). For the frames
    /// before a jump's first shown one (the try-on page runs 15 after each seek), whose
    /// garments nobody sees: a later `frame` gives the same bits as after `frame` on those
    /// poses with the certified and exact queries (the default; their state across frames
    /// only warm-starts the search), while the band query refreshes its candidates on its
    /// own count of post-processed frames. Errors (leaving the avatar as it was) as `frame`.
    /// Allocation-free.
    pub fn advance(&mut self, pose: &Pose) -> Result<()> {
        let step = |s: &mut Self| -> Result<()> {
            pose.validate(s.rig.body.skeleton().n_joints())?;
            s.network_step(pose)?;
            s.avatar.times.skinning_ms = 0.0;
            s.avatar.times.post_process_ms = 0.0;
            s.avatar.remember(pose);
            Ok(())
        };
        match self.rig.options.parallelism {
            Parallelism::Sequential => step(self),
            Parallelism::Rayon => sartor_core::awake::with_workers_awake(|| step(self)),
        }
    }

    /// [`GarmentAnimator::frame_with`] on this thread.
    fn frame_now(&mut self, pose: &Pose, resolve: bool) -> Result<()> {
        pose.validate(self.rig.body.skeleton().n_joints())?;
        let wrinkle = self.network_step(pose)?;
        let rig = &*self.rig;
        let wrinkle = wrinkle.then_some(&self.wrinkle[..]);
        self.avatar
            .finish(rig, pose, wrinkle, rig.options.parallelism, resolve)
    }

    /// The wrinkle network's step for `pose` (validated) into `self.wrinkle`, timed; whether
    /// the rig has wrinkles (`Δ_L`) at all.
    fn network_step(&mut self, pose: &Pose) -> Result<bool> {
        let rig = &*self.rig;
        let par_net = rig.options.parallelism;
        let start = self.avatar.now();
        let wrinkle = match rig.options.wrinkles {
            WrinkleMode::Gru => {
                self.avatar.features(rig, pose, &mut self.x)?;
                rig.network.wrinkle_step(
                    &self.x,
                    &mut self.state,
                    &mut self.wrinkle,
                    &mut self.ws,
                    par_net,
                )?;
                true
            }
            WrinkleMode::Linear => {
                self.avatar.features(rig, pose, &mut self.x)?;
                rig.network
                    .linear_baseline(&self.x, &mut self.wrinkle, &mut self.ws, par_net)?;
                true
            }
            WrinkleMode::None => false,
        };
        self.avatar.times.network_ms = self.avatar.now() - start;
        Ok(wrinkle)
    }

    /// Time the stages of every later frame with `clock`, a monotonic clock in milliseconds
    /// (`None`: stop timing). The runtime reads no clock itself: a native caller passes one
    /// built on `std::time::Instant`, a web page one that calls `performance.now()` (where
    /// `Instant` is not available).
    pub fn set_stage_clock(&mut self, clock: Option<fn() -> f64>) {
        self.avatar.clock = clock;
        self.avatar.times = StageTimes::default();
    }

    /// Where the last frame spent its time (`None` unless a clock was set with
    /// [`GarmentAnimator::set_stage_clock`]).
    pub fn stage_times(&self) -> Option<StageTimes> {
        self.avatar.clock.map(|_| self.avatar.times)
    }

    /// [`GarmentAnimator::frame`], copying the vertices into `out` (`V` entries).
    pub fn frame_into(&mut self, pose: &Pose, out: &mut [Vector3<f32>]) -> Result<()> {
        check_len("garment output", out.len(), self.rig.n_vertices())?;
        out.copy_from_slice(self.frame(pose)?);
        Ok(())
    }

    /// The garment's posed vertices of the last frame (the template before the first).
    pub fn vertices(&self) -> &[Vector3<f32>] {
        &self.avatar.vertices
    }

    /// Garment triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        self.rig.binding.faces()
    }

    /// The unposed garment of the last frame, `T̄_c + Δ_G + Δ_L` (before skinning).
    pub fn unposed(&self) -> &[Vector3<f32>] {
        &self.avatar.unposed
    }

    /// `Δ_G = R_G(β)`, `3V` values (metres), cached by `set_shape`.
    pub fn fit_displacement(&self) -> &[f32] {
        &self.avatar.fit
    }

    /// The GRU state (`H` values).
    pub fn state(&self) -> &[f32] {
        &self.state
    }

    /// Vertices the post-process moved in the last frame (0 when it is off).
    pub fn last_frame_pushed(&self) -> usize {
        self.avatar.pushed
    }

    /// Edge projections of the strain limit in the last frame (0 when it is off).
    pub fn last_frame_strained(&self) -> usize {
        self.avatar.strained
    }

    /// The body region posed in the last frame, as region vertices (see
    /// [`crate::BodyRegion`]); `None` when the post-process is off.
    pub fn posed_region(&self) -> Option<&[Vector3<f64>]> {
        self.avatar.collider.as_ref().map(|c| c.posed())
    }

    /// Count the last frame's cloth vertices inside the posed body region or within
    /// `margin − tolerance_m` of it, by the exact (tree) query, whatever the configured query;
    /// `None` when the post-process is off. For checks and reports, not per frame in a game.
    pub fn collision_count(&self, tolerance_m: f64) -> Option<CollisionCount> {
        self.avatar
            .collision_count(&self.avatar.vertices, tolerance_m)
    }

    /// [`GarmentAnimator::collision_count`] of other vertices (`V` of them) against this
    /// avatar's body as posed in the last frame: e.g. the same frame from an animator without
    /// the post-process, or the ground truth. `None` when the post-process is off.
    pub fn collision_count_of(
        &self,
        vertices: &[Vector3<f32>],
        tolerance_m: f64,
    ) -> Result<Option<CollisionCount>> {
        check_len("garment vertices", vertices.len(), self.rig.n_vertices())?;
        Ok(self.avatar.collision_count(vertices, tolerance_m))
    }

    /// What the certified query did in the last frame's first pass: vertices certified, vertices
    /// answered exactly, candidate faces (zeros for the other queries; `None` when the
    /// post-process is off).
    pub fn certify_stats(&self) -> Option<CertifyStats> {
        self.avatar.collider.as_ref().map(|c| c.stats())
    }

    /// Mean candidate faces per cloth vertex of the candidate query (0 for the BVH, `None`
    /// when the post-process is off).
    pub fn mean_candidates(&self) -> Option<f64> {
        self.avatar.collider.as_ref().map(|c| c.mean_candidates())
    }
}

/// `N` avatars of one rig stepping together: the GRU and output layer run once per frame for all
/// of them, sharing one pass over the weights (the batched kernels); each avatar's result is
/// bitwise equal to animating it alone with a [`GarmentAnimator`]. With
/// [`Parallelism::Rayon`] the per-avatar skinning and post-process run on rayon's pool, one
/// avatar per task, each splitting further where a lone animator would
/// ([`GarmentCrowd::frame`]).
#[derive(Clone, Debug)]
pub struct GarmentCrowd {
    rig: Arc<GarmentRig>,
    avatars: Vec<Avatar>,
    ws: Workspace,
    states: Vec<f32>,
    xs: Vec<f32>,
    wrinkles: Vec<f32>,
}

impl GarmentCrowd {
    /// `n` avatars (at least 1) of shape β = 0 at the start of a sequence.
    pub fn new(rig: Arc<GarmentRig>, n: usize) -> Result<Self> {
        if n == 0 {
            return Err(Error::invalid("crowd", "needs at least one avatar"));
        }
        let net = &rig.network;
        let mut ws = net.workspace(n);
        let zeros = vec![0.0; net.n_betas()];
        let mut avatars = Vec::with_capacity(n);
        for _ in 0..n {
            let mut a = Avatar::new(&rig);
            a.set_shape(&rig, &zeros, &mut ws)?;
            avatars.push(a);
        }
        Ok(Self {
            avatars,
            ws,
            states: vec![0.0; n * net.state_size()],
            xs: vec![0.0; n * net.input_size()],
            wrinkles: vec![0.0; n * net.output_size()],
            rig,
        })
    }

    /// Number of avatars.
    pub fn len(&self) -> usize {
        self.avatars.len()
    }

    /// Always false (a crowd has at least one avatar).
    pub fn is_empty(&self) -> bool {
        self.avatars.is_empty()
    }

    fn avatar_index(&self, i: usize) -> Result<usize> {
        if i < self.avatars.len() {
            Ok(i)
        } else {
            Err(Error::invalid(
                "crowd",
                format!("avatar {i} of {}", self.avatars.len()),
            ))
        }
    }

    /// Set avatar `i`'s shape (see [`GarmentAnimator::set_shape`]).
    pub fn set_shape(&mut self, i: usize, betas: &[f32]) -> Result<()> {
        let i = self.avatar_index(i)?;
        self.avatars[i].set_shape(&self.rig, betas, &mut self.ws)
    }

    /// Start a new sequence for avatar `i`.
    pub fn reset(&mut self, i: usize) -> Result<()> {
        let i = self.avatar_index(i)?;
        let h = self.rig.network.state_size();
        self.states[i * h..(i + 1) * h].fill(0.0);
        self.avatars[i].has_previous = false;
        Ok(())
    }

    /// Animate one frame of every avatar, `poses[i]` for avatar `i`. Allocation-free with
    /// [`Parallelism::Sequential`].
    ///
    /// Under [`Parallelism::Rayon`] the frame runs inside
    /// [`with_workers_awake`](sartor_core::awake::with_workers_awake), as
    /// [`GarmentAnimator::frame`] does, and each avatar's skinning and post-process may split
    /// over the threads too (rayon's tasks nest): a thread that has finished its avatars takes
    /// part of another's, so a crowd of fewer avatars than threads, or of a count that does
    /// not divide among them, still keeps every thread at work. The same bits either way.
    pub fn frame(&mut self, poses: &[Pose]) -> Result<()> {
        match self.rig.options.parallelism {
            Parallelism::Sequential => self.frame_now(poses),
            Parallelism::Rayon => sartor_core::awake::with_workers_awake(|| self.frame_now(poses)),
        }
    }

    /// [`GarmentCrowd::frame`] on this thread.
    fn frame_now(&mut self, poses: &[Pose]) -> Result<()> {
        check_len("crowd poses", poses.len(), self.avatars.len())?;
        let rig = &*self.rig;
        let n = self.avatars.len();
        let (n_in, n_out) = (rig.network.input_size(), rig.network.output_size());
        let j = rig.body.skeleton().n_joints();
        for pose in poses {
            pose.validate(j)?;
        }
        let wrinkles = rig.options.wrinkles != WrinkleMode::None;
        if wrinkles {
            for ((a, pose), x) in self
                .avatars
                .iter()
                .zip(poses)
                .zip(self.xs.chunks_exact_mut(n_in))
            {
                a.features(rig, pose, x)?;
            }
        }
        match rig.options.wrinkles {
            WrinkleMode::Gru => rig.network.wrinkle_step_batch(
                &self.xs,
                n,
                &mut self.states,
                &mut self.wrinkles,
                &mut self.ws,
                rig.options.parallelism,
            )?,
            WrinkleMode::Linear => {
                for (x, out) in self
                    .xs
                    .chunks_exact(n_in)
                    .zip(self.wrinkles.chunks_exact_mut(n_out))
                {
                    rig.network
                        .linear_baseline(x, out, &mut self.ws, rig.options.parallelism)?;
                }
            }
            WrinkleMode::None => {}
        }
        let par = rig.options.parallelism;
        let finish = |((a, pose), w): ((&mut Avatar, &Pose), &[f32])| {
            a.finish(rig, pose, wrinkles.then_some(w), par, true)
        };
        match rig.options.parallelism {
            Parallelism::Sequential => self
                .avatars
                .iter_mut()
                .zip(poses)
                .zip(self.wrinkles.chunks_exact(n_out))
                .try_for_each(finish),
            Parallelism::Rayon => self
                .avatars
                .par_iter_mut()
                .zip(poses)
                .zip(self.wrinkles.par_chunks_exact(n_out))
                .try_for_each(finish),
        }
    }

    /// Avatar `i`'s posed garment vertices of the last frame.
    pub fn vertices(&self, i: usize) -> Result<&[Vector3<f32>]> {
        let i = self.avatar_index(i)?;
        Ok(&self.avatars[i].vertices)
    }

    /// Vertices the post-process moved in avatar `i`'s last frame.
    pub fn last_frame_pushed(&self, i: usize) -> Result<usize> {
        let i = self.avatar_index(i)?;
        Ok(self.avatars[i].pushed)
    }
}
