//! The implicit integrator: backward Euler with one (or a few) linearised Newton steps per
//! substep, as ARCSim.
//!
//! # The step
//!
//! With `M` the lumped masses, `E` the potential (membrane, bending, contact, gravity),
//! `f = −∇E`, `K` the PSD-projected Hessian of `E`, Rayleigh damping `−β K v⁺ − α M v⁺` and
//! step `h`, backward Euler asks for `v⁺` with
//!
//! ```text
//! r(v⁺) = M (v⁺ − v) − h f(x + h v⁺) + h β K v⁺ + h α M v⁺ = 0,     x⁺ = x + h v⁺.
//! ```
//!
//! Newton from `v⁺ = 0` (i.e. linearising at the current positions `x`) gives, in one iteration,
//!
//! ```text
//! (M (1 + h α) + h (h + β) K) Δv = h (f − (h + β) K v − α M v),     v⁺ = v + Δv,
//! ```
//!
//! which is ARCSim's `(M − h (h + β) J) Δv = h (F + (h + β) J v)` with `J = −K` (plus mass
//! damping). [`SimConfig::newton_iterations`] > 1 continues Newton on the same (frozen-stiffness)
//! equations, re-evaluating forces and Hessians at `x + h v⁺`.
//!
//! Frozen per substep, as ARCSim: the tabulated membrane stiffness (looked up from the strain at
//! the start), the bending coefficient `ke l² / (8 (A0 + A1))`, the obstacle contacts (normal and
//! distance linearised at the start positions against the obstacle's *end-of-substep* pose) and
//! the self-contact pairs and sides.
//!
//! # System
//!
//! The simulator numbers the vertices its own way: the given cloth renumbered along a Z-order
//! curve of its rest shape, triangles and hinges sorted to follow
//! ([`Cloth::spatial_order`](crate::Cloth)), so that an element's rows of the system and the
//! vertices a contact query visits one after another are near in memory (at 8,710 triangles
//! the builders' numbering put a triangle's corners 1,900 indices apart in the median). Every
//! vertex it takes or hands out (positions, velocities, pins, forces) is in the given numbering.
//!
//! The block pattern (vertex × vertex 3 × 3 blocks over mesh edges and hinge diagonals) is built
//! once; element contributions are added element by element in index order (triangles, then
//! hinges). The system is symmetric bit for bit (every element's blocks below its diagonal are
//! the transposes of those above), and only its upper triangle is stored and solved with
//! (see `linsolve`'s `upper` module): an element adds its block `(a, b)` to the row that comes
//! first, and the block `(b, a)` is not formed. When [`SimConfig::parallelism`] is `Rayon`, each thread fills a spatially compact
//! set of rows from the elements that touch it, in the same order: the same sums, bit for bit.
//! Obstacle contacts add diagonal blocks; self-contacts add only the diagonal blocks of their
//! (PSD) Hessian, which keeps the pattern fixed (a principal block of a PSD
//! matrix is PSD). Pinned vertices are eliminated symmetrically (their velocity is prescribed).
//!
//! # After the solve
//!
//! 1. Friction: a Coulomb impulse per obstacle contact (see [`crate::energy`]), `μ` =
//!    [`SimConfig::friction_coefficient`], with [`FrictionModel::Impulse`]. With
//!    [`FrictionModel::Implicit`] the friction acted in the solve instead: each obstacle contact
//!    adds ARCSim's tangential damper (frozen at the start of the substep) to its vertex's
//!    diagonal block and right-hand side.
//! 2. Positions `x⁺ = x + h v⁺`.
//! 3. Guarantee: a vertex more than [`SimConfig::max_penetration_m`] inside an obstacle is
//!    projected to its surface and its inward normal velocity (relative to the obstacle) removed.
//!    This is a fallback; [`StepStats::projected_vertices`] counts its use.
//! 4. Checks: every value finite, kinetic energy below `½ M_total max_speed²`; otherwise the step
//!    fails with [`StepFailure`] and the state is left unchanged.
//!
//! After the first step nothing is allocated (except when the number of contacts exceeds every
//! earlier step's).

use std::ops::Range;
use std::time::Instant;

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use sartor_core::{NearFaces, Parallelism};
use serde::{Deserialize, Serialize};

use crate::cloth::Cloth;
use crate::collider::{Collider, Contact, MotionBound};
use crate::energy::{
    BendingHessian, BendingRest, ElementDerivatives, F64x4, FrictionModel, GaussNewtonHinge,
    MembraneRest, ObstacleContact, Penalty, Projection, SelfContact, friction_damping,
    friction_velocity_change, gather_lanes,
};
use crate::error::StepFailure;
use crate::linsolve::{
    BlockPattern, LinearSolveStats, LinearSolver, LinearWorkspace, UpperBlocks, UpperMut,
    block_product,
};
use crate::material::StrainStiffness;
use crate::self_collision::SelfCollisionGrid;
use crate::{Error, Result};

/// Simulation settings. The defaults are ARCSim's body-scene settings where ARCSim has one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Gravity, m/s² (default `(0, −9.81, 0)`).
    pub gravity_m_per_s2: Vector3<f64>,
    /// Rayleigh stiffness damping β, s (ARCSim's material `damping`; default 0).
    pub stiffness_damping_s: f64,
    /// Mass damping α, 1/s (default 0).
    pub mass_damping_per_s: f64,
    /// Newton iterations per substep (default 1, as ARCSim).
    pub newton_iterations: usize,
    /// With several Newton iterations, stop when the largest velocity update is below this, m/s.
    pub newton_tolerance_m_per_s: f64,
    /// Linear solver.
    pub linear_solver: LinearSolver,
    /// Bending Hessian used in the solve (default ARCSim's Gauss–Newton; see [`BendingHessian`]).
    pub bending_hessian: BendingHessian,
    /// Contact penalty (obstacles and self-contact; ARCSim uses one for both).
    pub contact_penalty: Penalty,
    /// Cloth–obstacle friction coefficient μ (ARCSim's `obs_friction`, 0.3).
    pub friction_coefficient: f64,
    /// How friction enters the substep (default [`FrictionModel::Impulse`]; a config that
    /// leaves it out reads as the impulse and keeps its hash). [`FrictionModel::Implicit`]
    /// stays smooth with twice as long substeps
    /// ([`crate::IMPLICIT_FRICTION_STEP_PER_EDGE_S_PER_M`]).
    #[serde(skip_serializing_if = "FrictionModel::is_impulse")]
    pub friction_model: FrictionModel,
    /// Vertex–triangle self-collision repulsion.
    pub self_collision: bool,
    /// Penetration depth beyond which the guarantee step projects a vertex out, m (1 mm).
    pub max_penetration_m: f64,
    /// Kinetic-energy bound as a speed: the step fails if `KE > ½ M_total max_speed²`, m/s.
    pub max_speed_m_per_s: f64,
    /// Run element loops, contact queries, CG and faer's Cholesky on rayon's pool. Element
    /// loops, queries and CG (with its Cholesky fallback, which stays on one thread) give
    /// bit-identical results either way (fixed chunking, fixed summation order); faer's
    /// parallel Cholesky, the `Cholesky` solver's, may differ in the last bits.
    #[serde(skip)]
    pub parallelism: Parallelism,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            gravity_m_per_s2: Vector3::new(0.0, -crate::energy::GRAVITY_M_PER_S2, 0.0),
            stiffness_damping_s: 0.0,
            mass_damping_per_s: 0.0,
            newton_iterations: 1,
            newton_tolerance_m_per_s: 1e-6,
            linear_solver: LinearSolver::Cholesky,
            bending_hessian: BendingHessian::GaussNewton,
            contact_penalty: Penalty::default(),
            friction_coefficient: 0.3,
            friction_model: FrictionModel::Impulse,
            self_collision: true,
            max_penetration_m: 1e-3,
            max_speed_m_per_s: 50.0,
            parallelism: Parallelism::Sequential,
        }
    }
}

impl SimConfig {
    /// Check the settings (finite, non-negative, at least one Newton iteration).
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid("simulation config", m));
        if !self.gravity_m_per_s2.iter().all(|g| g.is_finite()) {
            return bad(format!("gravity {:?} is not finite", self.gravity_m_per_s2));
        }
        for (name, value) in [
            ("stiffness_damping_s", self.stiffness_damping_s),
            ("mass_damping_per_s", self.mass_damping_per_s),
            ("newton_tolerance_m_per_s", self.newton_tolerance_m_per_s),
            ("friction_coefficient", self.friction_coefficient),
            ("max_penetration_m", self.max_penetration_m),
            (
                "contact_penalty.stiffness_n_per_m3",
                self.contact_penalty.stiffness_n_per_m3,
            ),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return bad(format!("{name} must be finite and ≥ 0, got {value}"));
            }
        }
        if !(self.contact_penalty.thickness_m.is_finite() && self.contact_penalty.thickness_m > 0.0)
        {
            return bad(format!(
                "contact_penalty.thickness_m must be positive, got {}",
                self.contact_penalty.thickness_m
            ));
        }
        if self.max_speed_m_per_s.is_nan() || self.max_speed_m_per_s <= 0.0 {
            return bad(format!(
                "max_speed_m_per_s must be positive, got {}",
                self.max_speed_m_per_s
            ));
        }
        if self.newton_iterations == 0 {
            return bad("newton_iterations must be at least 1".into());
        }
        if let LinearSolver::ConjugateGradient {
            max_iterations,
            relative_tolerance,
            ..
        } = self.linear_solver
            && (max_iterations == 0 || !(relative_tolerance > 0.0 && relative_tolerance < 1.0))
        {
            return bad(format!(
                "CG needs max_iterations ≥ 1 and 0 < relative_tolerance < 1, got {max_iterations}, {relative_tolerance}"
            ));
        }
        Ok(())
    }
}

/// What one substep did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    /// Newton iterations performed.
    pub newton_iterations: usize,
    /// Largest velocity update of the last Newton iteration, m/s.
    pub last_update_m_per_s: f64,
    /// The last linear solve.
    pub linear: LinearSolveStats,
    /// CG iterations summed over the Newton iterations.
    pub total_linear_iterations: usize,
    /// Time computing forces and Hessians and assembling the system, s.
    pub assemble_secs: f64,
    /// Time in linear solves (factorisation + solve, or CG), s.
    pub solve_secs: f64,
    /// Time in contact queries and self-collision detection, s.
    pub collision_secs: f64,
    /// The self-collision detection's part of `collision_secs`, s.
    pub self_collision_secs: f64,
    /// Whether the self-collision detection rebuilt its candidate lists (else it reused them).
    pub self_collision_built: bool,
    /// Time looking up the frozen membrane stiffness and bending coefficients apart from the
    /// assembly (which looks them up itself in the first Newton iteration), s.
    pub coefficients_secs: f64,
    /// Time in friction, the new positions and the projection fallback (its queries
    /// included), s.
    pub projection_secs: f64,
    /// Wall time of the whole substep, s.
    pub total_secs: f64,
    /// Vertex–obstacle contacts within the thickness.
    pub obstacle_contacts: usize,
    /// Vertex–triangle self-contact pairs.
    pub self_contacts: usize,
    /// Vertices the guarantee step projected out of an obstacle.
    pub projected_vertices: usize,
    /// Linear solves CG left short and sparse Cholesky redid.
    pub cholesky_fallbacks: usize,
    /// Kinetic energy after the step, J.
    pub kinetic_energy_j: f64,
    /// Largest vertex speed after the step, m/s.
    pub max_speed_m_per_s: f64,
}

/// Energies of the current state, J (coefficients looked up at the current state).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnergyReport {
    /// `½ Σ m v²`.
    pub kinetic_j: f64,
    /// `−Σ m g·x` (zero at the origin).
    pub gravity_j: f64,
    /// Membrane energy.
    pub membrane_j: f64,
    /// Bending energy.
    pub bending_j: f64,
}

impl EnergyReport {
    /// Sum of all terms.
    pub fn total_j(&self) -> f64 {
        self.kinetic_j + self.gravity_j + self.membrane_j + self.bending_j
    }
}

/// Scratch buffers of a step (sized once).
struct Workspace {
    tri_stiffness: Vec<StrainStiffness>,
    hinge_coefficient: Vec<f64>,
    self_out: Vec<ElementDerivatives<4>>,
    obstacle_contacts: Vec<ObstacleContact>,
    /// Per obstacle contact, [`FrictionModel::Implicit`]'s damping coefficient (N·s/m; empty
    /// with the impulse model).
    friction_damping: Vec<f64>,
    query: Vec<Option<Contact>>,
    /// Per collider and vertex, what the last queries left (see [`QueryState`]).
    query_state: Vec<QueryState>,
    /// Per collider and vertex, the features listed near it (see [`NearState`]).
    near_state: Vec<NearState>,
    /// Per collider, the identity of its [`Collider::motion_bound`] the clearances refer to.
    collider_identity: Vec<Option<u64>>,
    self_contacts: Vec<SelfContact>,
    grid: SelfCollisionGrid,
    /// The system `A` (during the assembly, first the stiffness `K`): its upper triangle, as
    /// the pattern lays it out (the system is symmetric).
    system: UpperBlocks,
    /// `K v⁺` per vertex, with stiffness damping.
    kv: Vec<Vector3<f64>>,
    gradient: Vec<Vector3<f64>>,
    rhs: Vec<Vector3<f64>>,
    update: Vec<Vector3<f64>>,
    v_plus: Vec<Vector3<f64>>,
    x_iter: Vec<Vector3<f64>>,
    x_new: Vec<Vector3<f64>>,
    pin_velocity: Vec<Vector3<f64>>,
    /// The last successful step's solved velocity change per second of step (`(v⁺ − v) / h`
    /// before friction and the fallback), for the next solve's first guess; empty when unknown
    /// (before the first step, after the state was set).
    last_acceleration: Vec<Vector3<f64>>,
    /// This step's, until it succeeds.
    step_acceleration: Vec<Vector3<f64>>,
    linear: LinearWorkspace,
}

/// A share of the assembly: a range of vertices (rows of the system; in the parallel assembly a
/// contiguous run of the simulator's Morton order, hence a spatially compact part of the cloth,
/// one per thread) and every element with a vertex among them, in index order. Each share sums
/// its own rows' contributions in the order of a sequential scatter (triangles, then hinges, by
/// index; then the contacts in list order): bit for bit the same sums, on any number of
/// shares. An element across two shares is computed by both.
#[derive(Clone, Debug)]
struct Share {
    /// Its rows.
    rows: Range<usize>,
    triangles: Vec<u32>,
    hinges: Vec<u32>,
}

impl Share {
    /// `count` shares of about equal work (element-vertex incidences), each a contiguous range
    /// of the cloth's vertices: in the simulator's numbering (a Morton order of the rest shape)
    /// a compact part of the cloth, so that few elements straddle two shares, and a share's
    /// rows are one piece of the system, reached by plain indexing (rows handed out one by one
    /// through a lookup made the assembly's fill 11 % slower: 129 against 116.5 ms per frame
    /// at 8,710 triangles, one thread).
    fn split(cloth: &Cloth, count: usize) -> Vec<Self> {
        let n = cloth.n_vertices();
        let mut weight = vec![0usize; n];
        for f in cloth.faces() {
            for &v in f {
                weight[v as usize] += 1;
            }
        }
        for h in cloth.hinges() {
            for &v in &h.vertices {
                weight[v as usize] += 1;
            }
        }
        let count = count.max(1);
        let total: usize = weight.iter().sum();
        // Share `k` ends at the first vertex where the running weight reaches `(k + 1) / count`
        // of the total.
        let mut ends = Vec::with_capacity(count);
        let mut acc = 0usize;
        for (i, w) in weight.iter().enumerate() {
            while ends.len() + 1 < count && acc * count >= total * (ends.len() + 1) {
                ends.push(i);
            }
            acc += w;
        }
        ends.resize(count, n);
        let mut first = 0;
        ends.into_iter()
            .map(|end| {
                let rows = first..end;
                first = end;
                let touches = |vs: &[u32]| vs.iter().any(|&v| rows.contains(&(v as usize)));
                Self {
                    triangles: (0..cloth.faces().len() as u32)
                        .filter(|&t| touches(&cloth.faces()[t as usize]))
                        .collect(),
                    hinges: (0..cloth.hinges().len() as u32)
                        .filter(|&e| touches(&cloth.hinges()[e as usize].vertices))
                        .collect(),
                    rows,
                }
            })
            .collect()
    }
}

/// How many elements ahead the assembly prefetches the blocks it will add to (see
/// [`Rows::prefetch`]). At 26,066 triangles the system (13 MB in both triangles then) is far larger than the
/// core's cache, and the additions waited for their blocks: assembly 863–944 → 710–761 ms per
/// frame on one thread, the same bits (`cargo xtask bench sim --sizes 26066 --frames 5`, AMD
/// EPYC VM, builds alternated). At 8,710 triangles no change.
const PREFETCH_AHEAD: usize = 8;

/// What every share of the assembly reads.
struct Shared<'a> {
    cloth: &'a Cloth,
    config: &'a SimConfig,
    pattern: &'a BlockPattern,
    tri_places: &'a [[u32; 9]],
    hinge_places: &'a [[u32; 16]],
    stiffness: &'a [StrainStiffness],
    coefficient: &'a [f64],
    /// Whether `x` is the state the coefficients are frozen at (the first Newton iteration):
    /// the membrane stiffness and the Gauss–Newton hinges' coefficients are then looked up
    /// here, from the strain and angle the derivatives compute anyway, not read from
    /// `stiffness` and `coefficient` (bitwise the same numbers).
    frozen_here: bool,
    x: &'a [Vector3<f64>],
    v_plus: &'a [Vector3<f64>],
    velocities: &'a [Vector3<f64>],
    obstacle_contacts: &'a [ObstacleContact],
    /// Per obstacle contact, the friction damper (empty: no damper in the system).
    friction_damping: &'a [f64],
    self_contacts: &'a [SelfContact],
    self_out: &'a [ElementDerivatives<4>],
    h: f64,
}

/// A share's rows of the system being filled: rows `first..first + gradient.len()`, their
/// blocks in the system's upper triangle (from its place `first_place` on), gradients and
/// right-hand sides. `WHOLE`: the share is every row, and every vertex is its own without a
/// test (the sequential assembly; the test cost it 6 %, 121 → 129 ms per frame at 8,710
/// triangles).
struct Rows<'a, const WHOLE: bool> {
    pattern: &'a BlockPattern,
    first: usize,
    first_place: usize,
    upper: UpperMut<'a>,
    gradient: &'a mut [Vector3<f64>],
    rhs: &'a mut [Vector3<f64>],
}

impl<'a, const WHOLE: bool> Rows<'a, WHOLE> {
    /// The rows of `range`, cut from the front of the rest of the system (`upper`,
    /// `gradient`, `rhs`: the rows from `range.start` on), which keeps what follows them.
    fn take(
        pattern: &'a BlockPattern,
        range: Range<usize>,
        upper: &mut UpperMut<'a>,
        gradient: &mut &'a mut [Vector3<f64>],
        rhs: &mut &'a mut [Vector3<f64>],
    ) -> Self {
        let first_place = pattern.upper_start(range.start);
        let blocks = pattern.upper_start(range.end) - first_place;
        let rows = range.len();
        let (upper_here, upper_rest) = std::mem::replace(upper, UpperMut::empty()).split_at(blocks);
        let (gradient_here, gradient_rest) = std::mem::take(gradient).split_at_mut(rows);
        let (rhs_here, rhs_rest) = std::mem::take(rhs).split_at_mut(rows);
        (*upper, *gradient, *rhs) = (upper_rest, gradient_rest, rhs_rest);
        Self {
            pattern,
            first: range.start,
            first_place,
            upper: upper_here,
            gradient: gradient_here,
            rhs: rhs_here,
        }
    }

    /// Rows this share fills.
    fn count(&self) -> usize {
        self.gradient.len()
    }

    /// The vertex of its `k`-th row.
    fn vertex(&self, k: usize) -> usize {
        self.first + k
    }

    /// The index among its rows of vertex `i`'s row, if it is this share's.
    #[inline(always)]
    fn own(&self, i: u32) -> Option<usize> {
        let k = (i as usize).wrapping_sub(self.first);
        (WHOLE || k < self.gradient.len()).then_some(k)
    }

    /// The places of the `k`-th row's blocks among this share's.
    #[inline(always)]
    fn blocks(&self, k: usize) -> Range<usize> {
        let i = self.first + k;
        self.pattern.upper_start(i) - self.first_place
            ..self.pattern.upper_start(i + 1) - self.first_place
    }

    /// Add `m` to the block at `place` (in the upper triangle's numbering), one of this
    /// share's.
    #[inline(always)]
    fn add(&mut self, place: u32, m: &Matrix3<f64>) {
        self.upper.add(place as usize - self.first_place, m);
    }

    /// Add an element's gradient and blocks (`block(a, b)`, at `places[N a + b]`) to the rows
    /// of its vertices `idx` that are this share's (`N²` places, those of the blocks not
    /// stored [`ELSEWHERE`]).
    ///
    /// Each pair of corners has one stored block, `(a, b)` with `a`'s row first
    /// ([`stored_block`]), found without a branch on the corners' order: that order is as good
    /// as random, and a branch per block (is it `ELSEWHERE`?) mispredicted half the time. The
    /// same blocks go to the same places; each place gets one block from the element, so the
    /// order within it does not matter.
    #[inline(always)]
    fn add_element<const N: usize>(
        &mut self,
        idx: &[u32; N],
        places: &[u32],
        gradient: &[Vector3<f64>; N],
        block: impl Fn(usize, usize) -> Matrix3<f64>,
    ) {
        for a in 0..N {
            if let Some(k) = self.own(idx[a]) {
                self.gradient[k] += gradient[a];
            }
        }
        for a in 0..N {
            for b in a..N {
                let (r, c) = stored_block(idx, a, b);
                if self.own(idx[r]).is_some() {
                    self.add(places[N * r + c], &block(r, c));
                }
            }
        }
    }

    /// [`Self::prefetch`] the blocks of an element with vertices `idx` at `places` (`N²`), the
    /// stored one of each pair as [`Self::add_element`] finds it.
    #[inline(always)]
    fn prefetch_element<const N: usize>(&self, idx: &[u32; N], places: &[u32]) {
        for a in 0..N {
            for b in a..N {
                let (r, c) = stored_block(idx, a, b);
                self.prefetch(idx[r], places[N * r + c]);
            }
        }
    }

    /// Start loading into the cache the block at `place` (in the upper triangle's numbering)
    /// of vertex `i`'s row, if the row is this share's: the assembly asks for the blocks of the
    /// element [`PREFETCH_AHEAD`] places ahead of the one it adds.
    #[inline(always)]
    fn prefetch(&self, i: u32, place: u32) {
        if self.own(i).is_some() {
            let at = (place as usize).wrapping_sub(self.first_place);
            crate::prefetch::prefetch(self.upper.address(at));
        }
    }
}

/// An element's block `(a, b)` whose row `a` comes after its column `b`: not stored (its
/// mirror `(b, a)`, the transpose, is).
const ELSEWHERE: u32 = u32::MAX;

/// Of the corners `a ≤ b` of an element with vertices `idx`, the stored block: `(a, b)` when
/// `a`'s row comes first (or `a = b`), else `(b, a)` (a select, not a branch).
#[inline(always)]
fn stored_block<const N: usize>(idx: &[u32; N], a: usize, b: usize) -> (usize, usize) {
    let swap = usize::from(idx[b] < idx[a]);
    // `(a, b)` or `(b, a)` by arithmetic: `swap` is 0 or 1.
    (a + swap * (b - a), b - swap * (b - a))
}

/// A pass of the assembly over a share's rows.
enum Pass<'a> {
    /// The stiffness and gradient, then the system and right-hand side (no stiffness damping).
    Fill,
    /// The stiffness and gradient only.
    Stiffness,
    /// The system and right-hand side, from every row's `K v⁺`.
    Finish(&'a [Vector3<f64>]),
}

/// [`Shared::run`] as a [`crate::isa::Kernel`].
struct RunPass<'s, 'a, 'r, 'o, const WHOLE: bool>(
    &'s Shared<'a>,
    &'s Pass<'s>,
    &'s Share,
    &'r mut Rows<'o, WHOLE>,
);

impl<const WHOLE: bool> crate::isa::Kernel for RunPass<'_, '_, '_, '_, WHOLE> {
    type Output = ();

    #[inline(always)]
    fn call(self) {
        let RunPass(shared, pass, share, out) = self;
        shared.run(pass, share, out);
    }
}

/// What the assembly writes: the system's upper triangle, the gradients, the right-hand sides.
struct Parts<'a> {
    system: &'a mut UpperBlocks,
    gradient: &'a mut [Vector3<f64>],
    rhs: &'a mut [Vector3<f64>],
}

impl Shared<'_> {
    /// Run `pass` over every share's rows (`parts`): on the calling thread as one share, or
    /// one share per thread.
    fn over_shares(
        &self,
        pass: Pass<'_>,
        whole: &Share,
        shares: &[Share],
        parts: Parts<'_>,
        par: Parallelism,
    ) {
        let Parts {
            system,
            mut gradient,
            mut rhs,
        } = parts;
        let mut upper = system.view_mut();
        if let Parallelism::Sequential = par {
            let mut rows = Rows::<true>::take(
                self.pattern,
                whole.rows.clone(),
                &mut upper,
                &mut gradient,
                &mut rhs,
            );
            crate::isa::widest(RunPass(self, &pass, whole, &mut rows));
            return;
        }
        // Each share's rows: consecutive pieces of the system.
        let mut work: Vec<Rows<'_, false>> = shares
            .iter()
            .map(|share| {
                Rows::take(
                    self.pattern,
                    share.rows.clone(),
                    &mut upper,
                    &mut gradient,
                    &mut rhs,
                )
            })
            .collect();
        work.par_iter_mut()
            .zip(shares)
            .for_each(|(rows, share)| crate::isa::widest(RunPass(self, &pass, share, rows)));
    }

    /// `pass` over `share`'s rows. `#[inline(always)]`, as is what it calls, so that all of it
    /// is compiled into [`crate::isa::widest`]'s AVX2 version.
    #[inline(always)]
    fn run<const WHOLE: bool>(&self, pass: &Pass<'_>, share: &Share, out: &mut Rows<'_, WHOLE>) {
        match pass {
            Pass::Fill => {
                self.add_stiffness(share, out);
                self.finish(out, None);
            }
            Pass::Stiffness => self.add_stiffness(share, out),
            Pass::Finish(kv) => self.finish(out, Some(kv)),
        }
    }

    /// Fill `share`'s rows (`out`) with the stiffness `K` (in the system's blocks, scaled into
    /// `A` by [`Self::finish`]) and gradient summed over its elements (triangles, then hinges,
    /// by index), then the obstacle contacts and the self-contacts (in list order). Each row
    /// holds its blocks on and above the diagonal; an element adds its block `(a, b)` where
    /// `a`'s row comes first (the block `(b, a)` is its transpose, bit for bit: the system is
    /// symmetric).
    #[inline(always)]
    fn add_stiffness<const WHOLE: bool>(&self, share: &Share, out: &mut Rows<'_, WHOLE>) {
        let (faces, membranes, hinges) = (
            self.cloth.faces(),
            self.cloth.membranes(),
            self.cloth.hinges(),
        );
        let masses = self.cloth.masses_kg();
        let gravity = self.config.gravity_m_per_s2;
        let pattern = self.pattern;
        for k in 0..out.count() {
            let i = out.vertex(k);
            let blocks = out.blocks(k);
            out.upper.zero(blocks);
            out.gradient[k] = -gravity * masses[i];
        }
        let material = self.cloth.material();
        // Four triangles at a time (each lane bitwise its triangle alone, see
        // `crate::energy::Real`), added one after the other in the share's order.
        let groups = share.triangles.chunks_exact(4);
        let leftover = groups.remainder();
        let mut xl = [Vector3::from_element(F64x4([0.0; 4])); 3];
        let mut dl = ElementDerivatives::<3, F64x4>::default();
        // (The prefetches and lane copies are written out: closures here were compiled apart,
        // for the baseline instruction set, and called.)
        for (g, group) in groups.enumerate() {
            let t = [group[0], group[1], group[2], group[3]].map(|t| t as usize);
            for l in 0..4 {
                if let Some(&ahead) = share.triangles.get(4 * g + l + PREFETCH_AHEAD) {
                    let ahead = ahead as usize;
                    out.prefetch_element(&faces[ahead], &self.tri_places[ahead]);
                }
            }
            let corners = [&faces[t[0]], &faces[t[1]], &faces[t[2]], &faces[t[3]]];
            gather_lanes(self.x, corners, &mut xl);
            let stiffness = &self.stiffness;
            let frozen = (!self.frozen_here).then(|| {
                [
                    &stiffness[t[0]],
                    &stiffness[t[1]],
                    &stiffness[t[2]],
                    &stiffness[t[3]],
                ]
            });
            let rests = [
                &membranes[t[0]],
                &membranes[t[1]],
                &membranes[t[2]],
                &membranes[t[3]],
            ];
            let model = material.membrane();
            MembraneRest::derivatives_lanes(rests, &xl, model, frozen, Projection::Psd, &mut dl);
            for (l, &t) in t.iter().enumerate() {
                let gradient = lane_vectors(&dl.gradient, l);
                let block = |a: usize, b: usize| lane_matrix(&dl.hessian[a][b], l);
                out.add_element(&faces[t], &self.tri_places[t], &gradient, block);
            }
        }
        // The element's corners, gathered into one buffer that the derivatives read in place
        // (see [`gather_into`]).
        let mut xt = [Vector3::zeros(); 3];
        let first = share.triangles.len() - leftover.len();
        for (n, &t) in leftover.iter().enumerate() {
            if let Some(&ahead) = share.triangles.get(first + n + PREFETCH_AHEAD) {
                let ahead = ahead as usize;
                out.prefetch_element(&faces[ahead], &self.tri_places[ahead]);
            }
            let (t, f) = (t as usize, faces[t as usize]);
            let m = &membranes[t];
            gather_into(self.x, f, &mut xt);
            let d = if self.frozen_here {
                m.derivatives_frozen_here(&xt, material.membrane(), Projection::Psd)
            } else {
                m.derivatives(&xt, &self.stiffness[t], Projection::Psd)
            };
            let places = &self.tri_places[t];
            out.add_element(&f, places, &d.gradient, |a, b| d.hessian[a][b]);
        }
        let bending_hessian = self.config.bending_hessian;
        // ARCSim's Hessian (the default) four hinges at a time, as the triangles.
        let mut first = 0;
        if bending_hessian == BendingHessian::GaussNewton {
            let groups = share.hinges.chunks_exact(4);
            first = share.hinges.len() - groups.remainder().len();
            let mut xl = [Vector3::from_element(F64x4([0.0; 4])); 4];
            let mut dl = GaussNewtonHinge::<F64x4>::default();
            for (g, group) in groups.enumerate() {
                let e = [group[0], group[1], group[2], group[3]].map(|e| e as usize);
                for l in 0..4 {
                    if let Some(&ahead) = share.hinges.get(4 * g + l + PREFETCH_AHEAD) {
                        let ahead = ahead as usize;
                        out.prefetch_element(&hinges[ahead].vertices, &self.hinge_places[ahead]);
                    }
                }
                let rests = [&hinges[e[0]], &hinges[e[1]], &hinges[e[2]], &hinges[e[3]]];
                let corners = [
                    &rests[0].vertices,
                    &rests[1].vertices,
                    &rests[2].vertices,
                    &rests[3].vertices,
                ];
                gather_lanes(self.x, corners, &mut xl);
                let c = &self.coefficient;
                let frozen = (!self.frozen_here).then(|| [c[e[0]], c[e[1]], c[e[2]], c[e[3]]]);
                let model = material.bending();
                let has = BendingRest::gauss_newton_lanes(rests, &xl, model, frozen, &mut dl);
                for (l, &e) in e.iter().enumerate() {
                    if has[l] {
                        let d = GaussNewtonHinge {
                            energy_j: dl.energy_j.0[l],
                            gradient: lane_vectors(&dl.gradient, l),
                            angle: lane_vectors(&dl.angle, l),
                            curvature: dl.curvature.0[l],
                        };
                        let (v, places) = (&hinges[e].vertices, &self.hinge_places[e]);
                        out.add_element(v, places, &d.gradient, |a, b| d.block(a, b));
                    }
                }
            }
        }
        let mut x = [Vector3::zeros(); 4];
        for (n, &e) in share.hinges.iter().enumerate().skip(first) {
            if let Some(&ahead) = share.hinges.get(n + PREFETCH_AHEAD) {
                let ahead = ahead as usize;
                out.prefetch_element(&hinges[ahead].vertices, &self.hinge_places[ahead]);
            }
            let (e, h) = (e as usize, &hinges[e as usize]);
            gather_into(self.x, h.vertices, &mut x);
            let places = &self.hinge_places[e];
            if bending_hessian == BendingHessian::GaussNewton {
                // ARCSim's Hessian (the default): its blocks made where they are added, the
                // same numbers as `derivatives` gives without holding them all.
                let d = if self.frozen_here {
                    h.gauss_newton_frozen_here(&x, material.bending())
                } else {
                    h.gauss_newton(&x, self.coefficient[e])
                };
                if let Some(d) = d {
                    out.add_element(&h.vertices, places, &d.gradient, |a, b| d.block(a, b));
                }
            } else {
                let d = h.derivatives(&x, self.coefficient[e], bending_hessian);
                out.add_element(&h.vertices, places, &d.gradient, |a, b| d.hessian[a][b]);
            }
        }
        let penalty = self.config.contact_penalty;
        let diag = |i: usize| pattern.upper_start(i) as u32;
        for c in self.obstacle_contacts {
            if let Some(k) = out.own(c.vertex) {
                let i = c.vertex as usize;
                let d = c.derivatives(&self.x[i], &penalty);
                out.gradient[k] += d.gradient[0];
                out.add(diag(i), &d.hessian[0][0]);
            }
        }
        for (c, d) in self.self_contacts.iter().zip(self.self_out) {
            let idx = [c.vertex, c.triangle[0], c.triangle[1], c.triangle[2]];
            for a in 0..4 {
                if let Some(k) = out.own(idx[a]) {
                    out.gradient[k] += d.gradient[a];
                    out.add(diag(idx[a] as usize), &d.hessian[a][a]);
                }
            }
        }
    }

    /// The system and right-hand side of `out`'s rows from their stiffness and gradient:
    /// `A = M (1 + h α) + h (h + β) K`, `−r = −M (v⁺ − v) − h ∇E − h β K v⁺ − h α M v⁺`
    /// (`kv`: every row's `K v⁺`, needed when `β ≠ 0`). Pins are applied afterwards
    /// ([`apply_pins`]).
    #[inline(always)]
    fn finish<const WHOLE: bool>(&self, out: &mut Rows<'_, WHOLE>, kv: Option<&[Vector3<f64>]>) {
        let masses = self.cloth.masses_kg();
        let (h, beta, alpha) = (
            self.h,
            self.config.stiffness_damping_s,
            self.config.mass_damping_per_s,
        );
        let scale = h * (h + beta);
        for k in 0..out.count() {
            let i = out.vertex(k);
            let kv = kv.map_or_else(Vector3::zeros, |kv| kv[i]);
            let blocks = out.blocks(k);
            let diag = blocks.start;
            out.upper.scale(blocks, scale);
            out.upper
                .add_to_diagonal(diag, masses[i] * (1.0 + h * alpha));
            out.rhs[k] = -(self.v_plus[i] - self.velocities[i]) * masses[i]
                - out.gradient[k] * h
                - kv * (h * beta)
                - self.v_plus[i] * (h * alpha * masses[i]);
        }
        // The friction dampers, `f = −c T (v⁺ − v_o)`: `A += h c T`, `rhs += h f`.
        for (c, &damping) in self.obstacle_contacts.iter().zip(self.friction_damping) {
            if damping == 0.0 {
                continue;
            }
            if let Some(k) = out.own(c.vertex) {
                let i = c.vertex as usize;
                let t = Matrix3::identity() - c.normal * c.normal.transpose();
                out.add(self.pattern.upper_start(i) as u32, &(t * (h * damping)));
                out.rhs[k] -= t * (self.v_plus[i] - c.velocity_m_per_s) * (h * damping);
            }
        }
    }
}

/// Pins: the update of a pinned vertex is known, `δ_i = u_i − v⁺_i`. Move its column to the
/// right-hand side (every other row's `rhs_j −= A_ji δ_i`, in the row's column order, before
/// any block is cleared) and replace its row by `M_i δ_i = M_i (u_i − v⁺_i)`.
#[allow(clippy::too_many_arguments)]
fn apply_pins(
    pattern: &BlockPattern,
    upper: &mut UpperBlocks,
    rhs: &mut [Vector3<f64>],
    pinned: &[bool],
    pin_velocity: &[Vector3<f64>],
    v_plus: &[Vector3<f64>],
    masses: &[f64],
) {
    let cols = pattern.cols();
    for (j, rhs) in rhs.iter_mut().enumerate() {
        if pinned[j] {
            continue;
        }
        for s in pattern.row(j) {
            let i = cols[s] as usize;
            if pinned[i] {
                let stored = upper.block(pattern.upper_place(s));
                let a = if j <= i { stored } else { stored.transpose() };
                *rhs -= a * (pin_velocity[i] - v_plus[i]);
            }
        }
    }
    let mut view = upper.view_mut();
    for j in 0..pattern.n_rows() {
        let start = pattern.upper_start(j);
        for (k, s) in (pattern.diag_slot(j)..pattern.row(j).end).enumerate() {
            if pinned[j] || pinned[cols[s] as usize] {
                view.set(start + k, &Matrix3::zeros());
            }
        }
        if pinned[j] {
            view.set(start, &(Matrix3::identity() * masses[j]));
            rhs[j] = (pin_velocity[j] - v_plus[j]) * masses[j];
        }
    }
}

/// A cloth being simulated: the cloth, its state (positions, velocities, pins) and the
/// reusable solver state.
pub struct Simulator {
    /// The cloth as given: the numbering of every vertex the simulator takes or hands out.
    cloth: Cloth,
    /// The cloth it steps: the given one renumbered ([`Cloth::spatial_order`]) so that near
    /// vertices are near in memory. Vertex `k` here is the given cloth's `order[k]`, and given
    /// vertex `i` is `place[i]` here. The state `x`, `v`, `pins`, the system and the contacts
    /// use this numbering.
    sim_cloth: Cloth,
    order: Vec<u32>,
    place: Vec<u32>,
    config: SimConfig,
    x: Vec<Vector3<f64>>,
    v: Vec<Vector3<f64>>,
    pins: Vec<bool>,
    /// Positions, velocities and pins in the given numbering (what the accessors hand out),
    /// brought up to date after every change of the state.
    positions: Vec<Vector3<f64>>,
    velocities: Vec<Vector3<f64>>,
    pinned: Vec<bool>,
    pin_targets: Vec<Vector3<f64>>,
    time_secs: f64,
    pattern: BlockPattern,
    /// The shares of the parallel assembly (see [`Share`]): one per thread of rayon's pool;
    /// and the one share of the sequential assembly.
    shares: Vec<Share>,
    everything: Share,
    /// The place in the system's upper triangle of each (row, column) vertex pair of each
    /// triangle and hinge, [`ELSEWHERE`] where the row comes after the column.
    tri_places: Vec<[u32; 9]>,
    hinge_places: Vec<[u32; 16]>,
    triangle_area_m2: Vec<f64>,
    /// The next step's projection fallback queries every vertex (see
    /// [`Simulator::query_every_vertex_next_step`]).
    exact_projection: bool,
    ws: Workspace,
}

fn gather<const N: usize>(x: &[Vector3<f64>], idx: [u32; N]) -> [Vector3<f64>; N] {
    idx.map(|i| x[i as usize])
}

/// Lane `l` of vectors of [`F64x4`].
#[inline(always)]
fn lane_vectors<const N: usize>(v: &[Vector3<F64x4>; N], l: usize) -> [Vector3<f64>; N] {
    let mut out = [Vector3::zeros(); N];
    for (out, v) in out.iter_mut().zip(v) {
        *out = Vector3::new(v[0].0[l], v[1].0[l], v[2].0[l]);
    }
    out
}

/// Lane `l` of a matrix of [`F64x4`].
#[inline(always)]
fn lane_matrix(m: &Matrix3<F64x4>, l: usize) -> Matrix3<f64> {
    let e = |r: usize, c: usize| m[(r, c)].0[l];
    Matrix3::new(
        e(0, 0),
        e(0, 1),
        e(0, 2),
        e(1, 0),
        e(1, 1),
        e(1, 2),
        e(2, 0),
        e(2, 1),
        e(2, 2),
    )
}

/// [`gather`] into `out`, for the assembly's hot loops, which reuse one buffer: a gathered
/// array returned by value was copied on, in 16-byte pieces across the 24-byte vectors just
/// stored, and each piece waited for its two stores to retire (a store-to-load forwarding
/// failure).
#[inline(always)]
fn gather_into<const N: usize>(x: &[Vector3<f64>], idx: [u32; N], out: &mut [Vector3<f64>; N]) {
    for (o, &i) in out.iter_mut().zip(&idx) {
        *o = x[i as usize];
    }
}

/// Obstacles farther than the contact thickness plus this are not looked at again until
/// their clearance bound runs out (see [`QueryState`]), m.
const CLEARANCE_LOOKAHEAD_M: f64 = 0.02;

/// The margin of the features listed near a vertex (see [`QueryState`]), m.
const NEAR_MARGIN_M: f64 = 4e-3;

/// The listed features serve while the vertex has moved by at most this since, m: under half
/// [`NEAR_MARGIN_M`], so that the roundings of the motion's measure cannot matter.
const NEAR_REUSE_M: f64 = 0.49 * NEAR_MARGIN_M;

/// What the queries of one vertex against one collider leave for the next ones.
///
/// - `hint`: the collider's hint ([`Collider::closest_within_hinted`]): work saved, answers
///   unchanged.
/// - `clearance_m`: a lower bound on the distance from the vertex to the collider's surface,
///   on its outside, when the vertex was at `anchor_m + T` and the collider's [`MotionBound`]
///   read `(T, anchor_travel_m)` (0: unknown, or inside). The distance is 1-Lipschitz in the
///   point, unchanged when point and surface translate together, and its side cannot change
///   while it stays positive; so with [`QueryState::bound`] (the clearance less the vertex's
///   motion relative to the collider's translation and the collider's travel beyond it) above
///   the contact thickness the vertex cannot be a contact, and above 0 it cannot be inside:
///   its queries are skipped. The same contacts and projections as querying every vertex
///   every time, except for a vertex deeper inside than the collider looks (which the
///   end-of-frame check rejects) and where the collider's own sign is not a true inside test.
#[derive(Clone, Copy, Debug)]
struct QueryState {
    hint: u32,
    clearance_m: f64,
    anchor_m: Vector3<f64>,
    anchor_travel_m: f64,
}

impl QueryState {
    const UNKNOWN: Self = Self {
        hint: u32::MAX,
        clearance_m: 0.0,
        anchor_m: Vector3::new(0.0, 0.0, 0.0),
        anchor_travel_m: 0.0,
    };

    /// The clearance of the vertex at `x` now, with the collider's motion `motion` (`None`:
    /// unknown, 0).
    fn bound(&self, x: &Vector3<f64>, motion: Option<&MotionBound>) -> f64 {
        motion.map_or(0.0, |m| {
            self.clearance_m
                - (x - m.translation_m - self.anchor_m).norm()
                - (m.travel_m - self.anchor_travel_m)
        })
    }

    /// Record the answer of a query at `x` made with `lookahead_m` as its distance.
    fn record(
        &mut self,
        contact: Option<&Contact>,
        lookahead_m: f64,
        x: &Vector3<f64>,
        motion: Option<&MotionBound>,
    ) {
        self.clearance_m = contact.map_or(lookahead_m, |c| c.distance_m.max(0.0));
        if let Some(m) = motion {
            self.anchor_m = x - m.translation_m;
            self.anchor_travel_m = m.travel_m;
        }
    }
}

/// The collider's features near one vertex, listed with a margin of [`NEAR_MARGIN_M`] when the
/// vertex was at `anchor_m + T` and the collider's [`MotionBound`] read `(T, travel_m)`
/// ([`Collider::closest_within_listing`]). The vertex's queries take their answer from them
/// ([`Collider::closest_within_near`]: the same answer, no tree walk) while its motion since,
/// measured as for the clearance ([`QueryState`]), is at most [`NEAR_REUSE_M`]. Apart from
/// [`QueryState`], which every substep reads for every vertex: only queried vertices touch these.
#[derive(Clone, Copy, Debug)]
struct NearState {
    faces: NearFaces,
    anchor_m: Vector3<f64>,
    travel_m: f64,
}

impl NearState {
    const NONE: Self = Self {
        faces: NearFaces::EMPTY,
        anchor_m: Vector3::new(0.0, 0.0, 0.0),
        travel_m: 0.0,
    };

    /// The collider's answer for the vertex at `x` (`closest_within_hinted` with
    /// `lookahead_m` and the vertex's `hint`): from the listed features while they serve, else
    /// by a query that lists them anew. Without a motion bound, a plain query.
    fn query(
        &mut self,
        collider: &dyn Collider,
        x: &Vector3<f64>,
        lookahead_m: f64,
        hint: &mut u32,
        motion: Option<&MotionBound>,
    ) -> Option<Contact> {
        let Some(m) = motion else {
            return collider.closest_within_hinted(*x, lookahead_m, hint);
        };
        let moved = (x - m.translation_m - self.anchor_m).norm() + (m.travel_m - self.travel_m);
        if !self.faces.is_empty() && moved <= NEAR_REUSE_M {
            return collider.closest_within_near(*x, lookahead_m, hint, &self.faces);
        }
        self.anchor_m = x - m.translation_m;
        self.travel_m = m.travel_m;
        collider.closest_within_listing(*x, lookahead_m, hint, NEAR_MARGIN_M, &mut self.faces)
    }
}

/// Query the vertices at `x` against `collider`, with `lookahead_m` as the queries' distance:
/// `asked(bound)` of each vertex's clearance bound ([`QueryState::bound`]) says whether it is
/// queried and, if so, below what signed distance its answer is kept in `query` (else `None`).
#[allow(clippy::too_many_arguments)]
fn query_vertices(
    query: &mut [Option<Contact>],
    states: &mut [QueryState],
    near: &mut [NearState],
    par: Parallelism,
    collider: &dyn Collider,
    x: &[Vector3<f64>],
    motion: Option<&MotionBound>,
    lookahead_m: f64,
    asked: impl Fn(f64) -> Option<f64> + Sync,
) {
    let one =
        |i: usize,
         ((q, state), near): ((&mut Option<Contact>, &mut QueryState), &mut NearState)| {
            let Some(keep_below) = asked(state.bound(&x[i], motion)) else {
                *q = None;
                return;
            };
            let c = near.query(collider, &x[i], lookahead_m, &mut state.hint, motion);
            state.record(c.as_ref(), lookahead_m, &x[i], motion);
            *q = c.filter(|c| c.distance_m < keep_below);
        };
    match par {
        Parallelism::Sequential => (query.iter_mut().zip(states).zip(near).enumerate())
            .for_each(|(i, items)| one(i, items)),
        Parallelism::Rayon => (query.par_iter_mut().zip(states).zip(near).enumerate())
            .for_each(|(i, items)| one(i, items)),
    }
}

/// Apply `f(i, &mut item)` to every item, on rayon's pool or not.
fn for_each_indexed<T: Send>(items: &mut [T], par: Parallelism, f: impl Fn(usize, &mut T) + Sync) {
    match par {
        Parallelism::Sequential => items.iter_mut().enumerate().for_each(|(i, t)| f(i, t)),
        Parallelism::Rayon => items.par_iter_mut().enumerate().for_each(|(i, t)| f(i, t)),
    }
}

impl Simulator {
    /// Start a simulation at the cloth's rest shape, at rest.
    pub fn new(cloth: Cloth, config: SimConfig) -> Result<Self> {
        config.validate()?;
        // Our own numbering (module docs, "System").
        let order = cloth.spatial_order();
        let sim_cloth = cloth.renumbered(&order)?;
        let mut place = vec![0u32; order.len()];
        for (k, &i) in order.iter().enumerate() {
            place[i as usize] = k as u32;
        }
        let n = sim_cloth.n_vertices();
        let mut pairs: Vec<[u32; 2]> = Vec::new();
        for t in sim_cloth.faces() {
            pairs.extend([[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]]);
        }
        for h in sim_cloth.hinges() {
            pairs.push([h.vertices[2], h.vertices[3]]);
        }
        let pattern = BlockPattern::new(n, &pairs);
        let upper_place = |a: u32, b: u32| {
            if a > b {
                return ELSEWHERE;
            }
            let slot = pattern
                .slot(a as usize, b as usize)
                .expect("element pairs are in the pattern");
            pattern.upper_place(slot) as u32
        };
        let tri_places: Vec<[u32; 9]> = sim_cloth
            .faces()
            .iter()
            .map(|t| std::array::from_fn(|k| upper_place(t[k / 3], t[k % 3])))
            .collect();
        let hinge_places: Vec<[u32; 16]> = sim_cloth
            .hinges()
            .iter()
            .map(|h| std::array::from_fn(|k| upper_place(h.vertices[k / 4], h.vertices[k % 4])))
            .collect();
        let everything = Share::split(&sim_cloth, 1).remove(0);
        let shares = match config.parallelism {
            Parallelism::Sequential => Vec::new(),
            Parallelism::Rayon => Share::split(&sim_cloth, rayon::current_num_threads()),
        };
        let zeros = vec![Vector3::zeros(); n];
        let ws = Workspace {
            tri_stiffness: vec![StrainStiffness::default(); sim_cloth.faces().len()],
            hinge_coefficient: vec![0.0; sim_cloth.hinges().len()],
            self_out: Vec::new(),
            obstacle_contacts: Vec::new(),
            friction_damping: Vec::new(),
            query: vec![None; n],
            query_state: Vec::new(),
            near_state: Vec::new(),
            collider_identity: Vec::new(),
            self_contacts: Vec::new(),
            grid: SelfCollisionGrid::default(),
            system: UpperBlocks::zeros(pattern.n_upper()),
            gradient: zeros.clone(),
            rhs: zeros.clone(),
            update: zeros.clone(),
            v_plus: zeros.clone(),
            x_iter: zeros.clone(),
            x_new: zeros.clone(),
            pin_velocity: zeros.clone(),
            kv: Vec::new(),
            last_acceleration: Vec::with_capacity(n),
            step_acceleration: Vec::with_capacity(n),
            linear: LinearWorkspace::new(&pattern),
        };
        Ok(Self {
            x: sim_cloth.rest_mesh().positions().to_vec(),
            positions: cloth.rest_mesh().positions().to_vec(),
            velocities: zeros.clone(),
            pinned: vec![false; n],
            v: zeros,
            pins: vec![false; n],
            pin_targets: vec![Vector3::zeros(); n],
            time_secs: 0.0,
            triangle_area_m2: sim_cloth.membranes().iter().map(|m| m.area_m2).collect(),
            exact_projection: false,
            pattern,
            shares,
            everything,
            tri_places,
            hinge_places,
            cloth,
            sim_cloth,
            order,
            place,
            config,
            ws,
        })
    }

    /// The cloth (as given to [`Simulator::new`]).
    pub fn cloth(&self) -> &Cloth {
        &self.cloth
    }

    /// The settings.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// Replace the settings (validated).
    pub fn set_config(&mut self, config: SimConfig) -> Result<()> {
        config.validate()?;
        if matches!(config.parallelism, Parallelism::Rayon) && self.shares.is_empty() {
            self.shares = Share::split(&self.sim_cloth, rayon::current_num_threads());
        }
        self.config = config;
        Ok(())
    }

    /// Current positions, m.
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Current velocities, m/s.
    pub fn velocities(&self) -> &[Vector3<f64>] {
        &self.velocities
    }

    /// Simulated time, s.
    pub fn time_secs(&self) -> f64 {
        self.time_secs
    }

    fn check_state(&self, values: &[Vector3<f64>], what: &'static str) -> Result<()> {
        if values.len() != self.x.len() {
            return Err(Error::invalid(
                "cloth state",
                format!("{} {what} for {} vertices", values.len(), self.x.len()),
            ));
        }
        if let Some(i) = values.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(Error::invalid(
                "cloth state",
                format!("{what} of vertex {i} is not finite"),
            ));
        }
        Ok(())
    }

    /// Set all positions (e.g. a garment placed on a body), m.
    pub fn set_positions(&mut self, positions: &[Vector3<f64>]) -> Result<()> {
        self.check_state(positions, "positions")?;
        self.positions.copy_from_slice(positions);
        for (x, &i) in self.x.iter_mut().zip(&self.order) {
            *x = positions[i as usize];
        }
        self.forget_clearances();
        self.ws.last_acceleration.clear();
        Ok(())
    }

    /// Forget what the queries learnt about the distance to the colliders (after the state
    /// changed other than by a step).
    fn forget_clearances(&mut self) {
        self.ws
            .query_state
            .iter_mut()
            .for_each(|s| s.clearance_m = 0.0);
    }

    /// Set all velocities, m/s.
    pub fn set_velocities(&mut self, velocities: &[Vector3<f64>]) -> Result<()> {
        self.check_state(velocities, "velocities")?;
        self.velocities.copy_from_slice(velocities);
        for (v, &i) in self.v.iter_mut().zip(&self.order) {
            *v = velocities[i as usize];
        }
        self.ws.last_acceleration.clear();
        Ok(())
    }

    /// Make the next step's projection fallback query every vertex instead of skipping those
    /// whose clearance bound (the collider's [`MotionBound`]) proves them outside. The bound holds for the
    /// distance to an obstacle, not for the side a mesh obstacle's query reads: where a body
    /// region is open or intersects itself (a forearm pressed into the torso), a vertex inside
    /// one part whose nearest point lies on another reads as outside, and turns inside when
    /// the first part becomes the nearer, without ever meeting the surface. Querying every
    /// vertex at the last substep of a frame makes every frame's result obey the guarantee;
    /// every substep would cost about a fifth more at 8,710 triangles.
    pub fn query_every_vertex_next_step(&mut self) {
        self.exact_projection = true;
    }

    /// Pin a vertex: at the end of every following step it is at `target_m` (update the target
    /// before each step to move it). Its velocity becomes `(target − x) / h`.
    pub fn pin(&mut self, vertex: usize, target_m: Vector3<f64>) -> Result<()> {
        if vertex >= self.x.len() || !target_m.iter().all(|c| c.is_finite()) {
            return Err(Error::invalid(
                "pin",
                format!("vertex {vertex} (of {}) at {target_m:?}", self.x.len()),
            ));
        }
        let k = self.place[vertex] as usize;
        self.pins[k] = true;
        self.pin_targets[k] = target_m;
        self.pinned[vertex] = true;
        Ok(())
    }

    /// Release a pinned vertex.
    pub fn unpin(&mut self, vertex: usize) {
        if vertex < self.pins.len() {
            self.pins[self.place[vertex] as usize] = false;
            self.pinned[vertex] = false;
        }
    }

    /// Whether each vertex is pinned.
    pub fn pinned(&self) -> &[bool] {
        &self.pinned
    }

    /// Energies of the current state.
    pub fn energy(&self) -> EnergyReport {
        let x = &self.x;
        let masses = self.sim_cloth.masses_kg();
        let mut report = EnergyReport::default();
        for i in 0..x.len() {
            report.kinetic_j += 0.5 * masses[i] * self.v[i].norm_squared();
            report.gravity_j -= masses[i] * self.config.gravity_m_per_s2.dot(&x[i]);
        }
        let material = self.sim_cloth.material();
        for (m, t) in self
            .sim_cloth
            .membranes()
            .iter()
            .zip(self.sim_cloth.faces())
        {
            let xt = gather(x, *t);
            let k = material.membrane().stiffness(&m.green_strain(&xt));
            report.membrane_j += m.energy(&xt, &k);
        }
        for h in self.sim_cloth.hinges() {
            let xh = gather(x, h.vertices);
            report.bending_j += h.energy(&xh, h.coefficient(&xh, material.bending()));
        }
        report
    }

    /// The elastic forces `−∇E` (membrane and bending, coefficients looked up at the current
    /// state) on every vertex, N. Useful for reaction forces at pins.
    pub fn elastic_forces(&self) -> Vec<Vector3<f64>> {
        let x = &self.x;
        let material = self.sim_cloth.material();
        let mut f = vec![Vector3::zeros(); x.len()];
        for (m, t) in self
            .sim_cloth
            .membranes()
            .iter()
            .zip(self.sim_cloth.faces())
        {
            let xt = gather(x, *t);
            let k = material.membrane().stiffness(&m.green_strain(&xt));
            let d = m.derivatives(&xt, &k, Projection::Psd);
            for a in 0..3 {
                f[t[a] as usize] -= d.gradient[a];
            }
        }
        for h in self.sim_cloth.hinges() {
            let xh = gather(x, h.vertices);
            let c = h.coefficient(&xh, material.bending());
            let d = h.derivatives(&xh, c, BendingHessian::GaussNewton);
            for a in 0..4 {
                f[h.vertices[a] as usize] -= d.gradient[a];
            }
        }
        let mut given = vec![Vector3::zeros(); f.len()];
        for (f, &i) in f.iter().zip(&self.order) {
            given[i as usize] = *f;
        }
        given
    }

    /// Advance by one substep of `dt_secs`. `colliders` must already be at their pose for the
    /// end of the substep. On failure the state is unchanged.
    pub fn step(&mut self, dt_secs: f64, colliders: &[&dyn Collider]) -> Result<StepStats> {
        match self.config.parallelism {
            Parallelism::Sequential => self.step_here(dt_secs, colliders),
            // The parallel loops find rayon's other workers awake (see `sartor_core::awake`).
            Parallelism::Rayon => {
                sartor_core::awake::with_workers_awake(|| self.step_here(dt_secs, colliders))
            }
        }
    }

    /// [`Simulator::step`] on the calling thread.
    fn step_here(&mut self, dt_secs: f64, colliders: &[&dyn Collider]) -> Result<StepStats> {
        if !(dt_secs.is_finite() && dt_secs > 0.0) {
            return Err(Error::invalid(
                "time step",
                format!("must be finite and positive, got {dt_secs}"),
            ));
        }
        let start = Instant::now();
        let mut stats = StepStats::default();
        let par = self.config.parallelism;
        // The first Newton iteration linearises at `x` itself, where the coefficients are frozen:
        // its assembly looks them up (see `Shared::frozen_here`); they are stored only for the
        // iterations after it, and for hinges whose Hessian is not the Gauss–Newton one.
        let gauss_newton = self.config.bending_hessian == BendingHessian::GaussNewton;
        let t_coefficients = Instant::now();
        self.freeze_coefficients(false, !gauss_newton);
        stats.coefficients_secs = t_coefficients.elapsed().as_secs_f64();
        let t_collision = Instant::now();
        (stats.self_collision_secs, stats.self_collision_built) = self.find_contacts(colliders);
        stats.collision_secs = t_collision.elapsed().as_secs_f64();
        stats.obstacle_contacts = self.ws.obstacle_contacts.len();
        stats.self_contacts = self.ws.self_contacts.len();

        let h = dt_secs;
        let n = self.x.len();
        self.freeze_friction(h);
        for i in 0..n {
            self.ws.pin_velocity[i] = if self.pins[i] {
                (self.pin_targets[i] - self.x[i]) / h
            } else {
                Vector3::zeros()
            };
        }
        // Newton on v⁺, starting from v⁺ = 0 (linearisation at x: the first iteration is ARCSim's
        // step).
        self.ws
            .v_plus
            .iter_mut()
            .for_each(|v| *v = Vector3::zeros());
        for iteration in 0..self.config.newton_iterations {
            if iteration == 1 {
                let t_coefficients = Instant::now();
                self.freeze_coefficients(true, gauss_newton);
                stats.coefficients_secs += t_coefficients.elapsed().as_secs_f64();
            }
            let t_assemble = Instant::now();
            for i in 0..n {
                self.ws.x_iter[i] = self.x[i] + self.ws.v_plus[i] * h;
            }
            self.assemble_system(h, iteration == 0);
            stats.assemble_secs += t_assemble.elapsed().as_secs_f64();
            // Warm start: the current velocity continued by the last step's acceleration,
            // v + a h, as the guess for v⁺ (Δ = v + a h − v⁺). The system and its tolerance
            // are the same; the guess only saves iterations (about a third at 8,710 triangles).
            let extrapolate = iteration == 0 && self.ws.last_acceleration.len() == n;
            for i in 0..n {
                self.ws.update[i] = self.v[i] - self.ws.v_plus[i];
                if extrapolate {
                    self.ws.update[i] += self.ws.last_acceleration[i] * h;
                }
            }
            let linear = match self.config.linear_solver {
                LinearSolver::Cholesky => self.ws.linear.solve_cholesky(
                    &self.pattern,
                    &self.ws.system,
                    &self.ws.rhs,
                    &mut self.ws.update,
                    par,
                ),
                LinearSolver::ConjugateGradient {
                    max_iterations,
                    relative_tolerance,
                    fallback_to_cholesky,
                } => match self.ws.linear.solve_cg(
                    &self.pattern,
                    &self.ws.system,
                    &self.ws.rhs,
                    &mut self.ws.update,
                    max_iterations,
                    relative_tolerance,
                    par,
                ) {
                    // CG stopped short on a badly conditioned system (stiff contacts in a fast
                    // motion): the direct solve of the same system rescues the step. On one
                    // thread whatever `par`: faer's parallel factorisation differs in the last
                    // bits, and with it the two-thread 26,066-triangle walk drifted from the
                    // one-thread run (202 against 199 CG iterations per substep over 25
                    // frames); CG on threads is bit for bit the sequential CG, and so is this.
                    Err(StepFailure::SolverNotConverged { .. }) if fallback_to_cholesky => {
                        stats.cholesky_fallbacks += 1;
                        self.ws.linear.solve_cholesky(
                            &self.pattern,
                            &self.ws.system,
                            &self.ws.rhs,
                            &mut self.ws.update,
                            Parallelism::Sequential,
                        )
                    }
                    other => other,
                },
            }?;
            stats.solve_secs += linear.factor_secs + linear.solve_secs;
            stats.total_linear_iterations += linear.iterations;
            stats.linear = linear;
            stats.newton_iterations = iteration + 1;
            let mut largest: f64 = 0.0;
            for i in 0..n {
                self.ws.v_plus[i] += self.ws.update[i];
                largest = largest.max(self.ws.update[i].amax());
            }
            if !largest.is_finite() {
                return Err(StepFailure::NonFinite {
                    what: "velocity update",
                }
                .into());
            }
            stats.last_update_m_per_s = largest;
            if iteration > 0 && largest < self.config.newton_tolerance_m_per_s {
                break;
            }
        }

        let t_projection = Instant::now();
        self.ws.step_acceleration.clear();
        self.ws
            .step_acceleration
            .extend((0..n).map(|i| (self.ws.v_plus[i] - self.v[i]) / h));
        self.apply_friction(h);
        for i in 0..n {
            self.ws.x_new[i] = self.x[i] + self.ws.v_plus[i] * h;
        }
        stats.projected_vertices = self.project_out(colliders);
        stats.projection_secs = t_projection.elapsed().as_secs_f64();

        let masses = self.sim_cloth.masses_kg();
        let mut kinetic = 0.0;
        let mut max_speed: f64 = 0.0;
        for i in 0..n {
            let (x, v) = (&self.ws.x_new[i], &self.ws.v_plus[i]);
            if !(x.iter().chain(v.iter()).all(|c| c.is_finite())) {
                // The clearances describe the rejected positions.
                self.forget_clearances();
                return Err(StepFailure::NonFinite {
                    what: "cloth state",
                }
                .into());
            }
            kinetic += 0.5 * masses[i] * v.norm_squared();
            max_speed = max_speed.max(v.norm());
        }
        let bound = 0.5 * self.sim_cloth.total_mass_kg() * self.config.max_speed_m_per_s.powi(2);
        if kinetic > bound {
            self.forget_clearances();
            return Err(StepFailure::EnergyBlowUp {
                kinetic_energy_j: kinetic,
                bound_j: bound,
            }
            .into());
        }
        std::mem::swap(&mut self.x, &mut self.ws.x_new);
        std::mem::swap(&mut self.v, &mut self.ws.v_plus);
        std::mem::swap(
            &mut self.ws.last_acceleration,
            &mut self.ws.step_acceleration,
        );
        for (k, &i) in self.order.iter().enumerate() {
            self.positions[i as usize] = self.x[k];
            self.velocities[i as usize] = self.v[k];
        }
        self.time_secs += h;
        stats.kinetic_energy_j = kinetic;
        stats.max_speed_m_per_s = max_speed;
        stats.total_secs = start.elapsed().as_secs_f64();
        Ok(stats)
    }

    /// Look up the per-step material stiffness (`membranes`) and bending coefficients
    /// (`hinges`) at the current state.
    fn freeze_coefficients(&mut self, membranes: bool, hinges: bool) {
        let par = self.config.parallelism;
        let x = &self.x;
        let material = self.sim_cloth.material();
        if membranes {
            let (rest, faces) = (self.sim_cloth.membranes(), self.sim_cloth.faces());
            for_each_indexed(&mut self.ws.tri_stiffness, par, |t, k| {
                *k = material
                    .membrane()
                    .stiffness(&rest[t].green_strain(&gather(x, faces[t])));
            });
        }
        if hinges {
            let rest = self.sim_cloth.hinges();
            for_each_indexed(&mut self.ws.hinge_coefficient, par, |e, c| {
                *c = rest[e].coefficient(&gather(x, rest[e].vertices), material.bending());
            });
        }
    }

    /// Obstacle contacts (at the start positions, against the end-of-substep obstacles) and
    /// self-contact pairs; returns the seconds the self-contacts took.
    fn find_contacts(&mut self, colliders: &[&dyn Collider]) -> (f64, bool) {
        let par = self.config.parallelism;
        let penalty = self.config.contact_penalty;
        let x = &self.x;
        let n = x.len();
        self.ws.obstacle_contacts.clear();
        if self.ws.query_state.len() != n * colliders.len() {
            self.ws.query_state.clear();
            self.ws
                .query_state
                .resize(n * colliders.len(), QueryState::UNKNOWN);
            self.ws.near_state.clear();
            (self.ws.near_state).resize(n * colliders.len(), NearState::NONE);
            self.ws.collider_identity.clear();
            self.ws.collider_identity.resize(colliders.len(), None);
        }
        let thickness = penalty.thickness_m;
        let lookahead = thickness + CLEARANCE_LOOKAHEAD_M;
        for (ci, collider) in colliders.iter().enumerate() {
            let states = &mut self.ws.query_state[ci * n..(ci + 1) * n];
            // Clearances measured against another collider say nothing about this one.
            let motion = collider.motion_bound();
            let identity = motion.map(|m| m.identity);
            if self.ws.collider_identity[ci] != identity {
                states.iter_mut().for_each(|s| s.clearance_m = 0.0);
                self.ws.near_state[ci * n..(ci + 1) * n]
                    .iter_mut()
                    .for_each(|s| s.faces.clear());
                self.ws.collider_identity[ci] = identity;
            }
            let motion = motion.as_ref();
            let near = &mut self.ws.near_state[ci * n..(ci + 1) * n];
            let query = &mut self.ws.query;
            query_vertices(
                query,
                states,
                near,
                par,
                *collider,
                x,
                motion,
                lookahead,
                |bound| (bound < thickness).then_some(thickness),
            );
            for (i, q) in self.ws.query.iter().enumerate() {
                if let Some(c) = q {
                    self.ws.obstacle_contacts.push(ObstacleContact {
                        vertex: i as u32,
                        collider: ci as u32,
                        query_point: x[i],
                        distance_m: c.distance_m,
                        normal: c.normal,
                        velocity_m_per_s: c.velocity_m_per_s,
                        area_m2: self.sim_cloth.vertex_areas_m2()[i],
                    });
                }
            }
        }
        let t_self = Instant::now();
        let mut built = false;
        if self.config.self_collision {
            built = self.ws.grid.detect(
                x,
                self.sim_cloth.faces(),
                self.sim_cloth.topology(),
                self.sim_cloth.vertex_areas_m2(),
                &self.triangle_area_m2,
                2.0 * penalty.thickness_m,
                par,
                &mut self.ws.self_contacts,
            );
        } else {
            self.ws.self_contacts.clear();
        }
        self.ws
            .self_out
            .resize(self.ws.self_contacts.len(), ElementDerivatives::default());
        (t_self.elapsed().as_secs_f64(), built)
    }

    /// The gradient of the potential and its PSD Hessian at `x_iter`, then the system
    /// `A = M (1 + h α) + h (h + β) K` and `rhs = −r(v⁺)` with pinned vertices eliminated: row
    /// by row, in shares of the rows (see [`Share`]; one share when sequential).
    fn assemble_system(&mut self, h: f64, frozen_here: bool) {
        let par = self.config.parallelism;
        let penalty = self.config.contact_penalty;
        let ws = &mut self.ws;
        let x = &ws.x_iter;
        // The self-contacts' derivatives first (each touches four rows).
        let self_contacts = &ws.self_contacts;
        for_each_indexed(&mut ws.self_out, par, |s, out| {
            let c = &self_contacts[s];
            let idx = [c.vertex, c.triangle[0], c.triangle[1], c.triangle[2]];
            *out = c.derivatives(&gather(x, idx), &penalty, Projection::Psd);
        });
        let shared = Shared {
            cloth: &self.sim_cloth,
            config: &self.config,
            pattern: &self.pattern,
            tri_places: &self.tri_places,
            hinge_places: &self.hinge_places,
            stiffness: &ws.tri_stiffness,
            coefficient: &ws.hinge_coefficient,
            frozen_here,
            x,
            v_plus: &ws.v_plus,
            velocities: &self.v,
            obstacle_contacts: &ws.obstacle_contacts,
            friction_damping: &ws.friction_damping,
            self_contacts: &ws.self_contacts,
            self_out: &ws.self_out,
            h,
        };
        let pattern = &self.pattern;
        let parts = Parts {
            system: &mut ws.system,
            gradient: &mut ws.gradient,
            rhs: &mut ws.rhs,
        };
        let (whole, shares) = (&self.everything, &self.shares[..]);
        if self.config.stiffness_damping_s == 0.0 {
            shared.over_shares(Pass::Fill, whole, shares, parts, par);
        } else {
            shared.over_shares(Pass::Stiffness, whole, shares, parts, par);
            // `K v⁺` needs every row's `K`, complete: after the fill, before `A` replaces it.
            ws.kv.resize(pattern.n_rows(), Vector3::zeros());
            block_product(pattern, &ws.system, &ws.v_plus, &mut ws.kv, par);
            let parts = Parts {
                system: &mut ws.system,
                gradient: &mut ws.gradient,
                rhs: &mut ws.rhs,
            };
            shared.over_shares(Pass::Finish(&ws.kv), whole, shares, parts, par);
        }
        if self.pins.iter().any(|&p| p) {
            apply_pins(
                pattern,
                &mut ws.system,
                &mut ws.rhs,
                &self.pins,
                &ws.pin_velocity,
                &ws.v_plus,
                self.sim_cloth.masses_kg(),
            );
        }
    }

    /// [`FrictionModel::Implicit`]'s damper per obstacle contact, from the state at the start
    /// of the substep (none with the impulse model, or without friction).
    fn freeze_friction(&mut self, h: f64) {
        let ws = &mut self.ws;
        ws.friction_damping.clear();
        let mu = self.config.friction_coefficient;
        if self.config.friction_model != FrictionModel::Implicit || mu == 0.0 {
            return;
        }
        let penalty = self.config.contact_penalty;
        let masses = self.sim_cloth.masses_kg();
        ws.friction_damping
            .extend(ws.obstacle_contacts.iter().map(|c| {
                let i = c.vertex as usize;
                if self.pins[i] {
                    return 0.0;
                }
                let (_, de, _) = penalty.evaluate(c.distance_at(&self.x[i]), c.area_m2);
                let relative = self.v[i] - c.velocity_m_per_s;
                friction_damping(&relative, &c.normal, mu, -de, masses[i], h)
            }));
    }

    /// Coulomb friction impulses on `v⁺` for every obstacle contact (see [`crate::energy`]),
    /// with [`FrictionModel::Impulse`] (the damper of [`FrictionModel::Implicit`] acted in the
    /// solve).
    fn apply_friction(&mut self, h: f64) {
        let mu = self.config.friction_coefficient;
        if mu == 0.0 || self.config.friction_model != FrictionModel::Impulse {
            return;
        }
        let penalty = self.config.contact_penalty;
        let masses = self.sim_cloth.masses_kg();
        for c in &self.ws.obstacle_contacts {
            let i = c.vertex as usize;
            if self.pins[i] {
                continue;
            }
            let x_end = self.x[i] + self.ws.v_plus[i] * h;
            let (_, de, _) = penalty.evaluate(c.distance_at(&x_end), c.area_m2);
            let normal_impulse = (-de).max(0.0) * h;
            let relative = self.ws.v_plus[i] - c.velocity_m_per_s;
            self.ws.v_plus[i] +=
                friction_velocity_change(&relative, &c.normal, mu, normal_impulse, masses[i]);
        }
    }

    /// The guarantee step on `x_new` / `v_plus`; returns how many vertices it moved.
    fn project_out(&mut self, colliders: &[&dyn Collider]) -> usize {
        let every = std::mem::take(&mut self.exact_projection);
        let tolerance = self.config.max_penetration_m;
        let par = self.config.parallelism;
        let lookahead = self.config.contact_penalty.thickness_m + CLEARANCE_LOOKAHEAD_M;
        let mut moved = 0;
        let n = self.ws.x_new.len();
        for (ci, collider) in colliders.iter().enumerate() {
            let x = &self.ws.x_new;
            let states = &mut self.ws.query_state[ci * n..(ci + 1) * n];
            // The same collider pose as the contact query: only the vertex moved.
            let motion = collider.motion_bound();
            let motion = motion.as_ref();
            let near = &mut self.ws.near_state[ci * n..(ci + 1) * n];
            let query = &mut self.ws.query;
            query_vertices(
                query,
                states,
                near,
                par,
                *collider,
                x,
                motion,
                lookahead,
                |bound| (every || bound <= 0.0).then_some(-tolerance),
            );
            for (i, q) in self.ws.query.iter().enumerate() {
                let Some(c) = q else { continue };
                if self.pins[i] {
                    continue;
                }
                // On the surface now.
                self.ws.query_state[ci * n + i].clearance_m = 0.0;
                self.ws.x_new[i] -= c.normal * c.distance_m;
                let vn = (self.ws.v_plus[i] - c.velocity_m_per_s).dot(&c.normal);
                if vn < 0.0 {
                    self.ws.v_plus[i] -= c.normal * vn;
                }
                moved += 1;
            }
        }
        moved
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloth::rectangle_sheet;

    /// The system's upper triangle as assembled is, bit for bit, the upper half of the full
    /// system summed element by element (each element's sixteen or nine blocks into both
    /// triangles, in element order), whose lower half is its transpose: a sheet pinned at
    /// two corners sags, on one thread and on shares.
    #[test]
    fn the_upper_triangle_is_the_full_system_s_and_the_full_system_is_symmetric() {
        let sheet = rectangle_sheet(
            Vector3::new(-0.15, 0.12, 0.15),
            Vector3::x() * 0.3,
            Vector3::z() * -0.3,
            14,
            14,
        )
        .expect("a sheet");
        let h = 1.0 / 300.0;
        for parallelism in [Parallelism::Sequential, Parallelism::Rayon] {
            let cloth = Cloth::new(
                sheet.clone(),
                crate::material::Material::gray_interlock(),
                None,
            )
            .expect("a cloth");
            let config = SimConfig {
                linear_solver: LinearSolver::ConjugateGradient {
                    max_iterations: 1000,
                    relative_tolerance: 1e-8,
                    fallback_to_cholesky: false,
                },
                parallelism,
                ..SimConfig::default()
            };
            let mut sim = Simulator::new(cloth, config).expect("a simulator");
            let last = sim.positions().len() - 1;
            for v in [0, last] {
                sim.pin(v, sim.positions()[v]).expect("a pin");
            }
            for _ in 0..20 {
                sim.step(h, &[]).expect("a step");
            }
            // The last step's system, summed here into both triangles.
            let (cloth, pattern, ws) = (&sim.sim_cloth, &sim.pattern, &sim.ws);
            let x = &ws.x_iter;
            let n = cloth.n_vertices();
            let mut full = vec![Matrix3::zeros(); n * n];
            let material = cloth.material();
            for (f, m) in cloth.faces().iter().zip(cloth.membranes()) {
                let d =
                    m.derivatives_frozen_here(&gather(x, *f), material.membrane(), Projection::Psd);
                for a in 0..3 {
                    for b in 0..3 {
                        full[f[a] as usize * n + f[b] as usize] += d.hessian[a][b];
                    }
                }
            }
            for hinge in cloth.hinges() {
                let v = hinge.vertices;
                if let Some(d) = hinge.gauss_newton_frozen_here(&gather(x, v), material.bending()) {
                    for a in 0..4 {
                        for b in 0..4 {
                            full[v[a] as usize * n + v[b] as usize] += d.block(a, b);
                        }
                    }
                }
            }
            let masses = cloth.masses_kg();
            for i in 0..n {
                for j in 0..n {
                    full[i * n + j] *= h * h;
                    if sim.pins[i] || sim.pins[j] {
                        full[i * n + j] = Matrix3::zeros();
                    }
                }
                full[i * n + i] += Matrix3::identity() * masses[i];
            }
            let bits = |m: &Matrix3<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            for i in 0..n {
                for s in pattern.row(i) {
                    let j = pattern.cols()[s] as usize;
                    let stored = ws.system.block(pattern.upper_place(s));
                    let expected = full[i * n + j];
                    if j >= i {
                        assert_eq!(
                            bits(&stored),
                            bits(&expected),
                            "{parallelism:?}: block ({i}, {j})"
                        );
                    } else {
                        assert_eq!(
                            bits(&stored.transpose()),
                            bits(&expected),
                            "{parallelism:?}: block ({i}, {j}), from its mirror"
                        );
                    }
                }
            }
        }
    }

    /// The shares of a 40 × 30 sheet in the simulator's numbering: consecutive ranges that
    /// cover every vertex once, of about equal work, each listing exactly the elements that
    /// touch it, with few elements in two shares.
    #[test]
    fn shares_are_consecutive_balanced_and_list_what_they_touch() {
        let sheet = rectangle_sheet(Vector3::zeros(), Vector3::x(), Vector3::y() * 0.75, 40, 30)
            .expect("a sheet");
        let cloth =
            Cloth::new(sheet, crate::material::Material::gray_interlock(), None).expect("a cloth");
        let cloth = cloth
            .renumbered(&cloth.spatial_order())
            .expect("a permutation");
        let n = cloth.n_vertices();
        let weight = |rows: &Range<usize>| {
            let count = |vs: &[u32]| vs.iter().filter(|&&v| rows.contains(&(v as usize))).count();
            cloth.faces().iter().map(|f| count(f)).sum::<usize>()
                + cloth
                    .hinges()
                    .iter()
                    .map(|h| count(&h.vertices))
                    .sum::<usize>()
        };
        let total = weight(&(0..n));
        let heaviest = (0..n).map(|v| weight(&(v..v + 1))).max().unwrap_or(0) as f64;
        for count in [1, 2, 3, 8] {
            let shares = Share::split(&cloth, count);
            assert_eq!(shares.len(), count);
            let mut next = 0;
            for share in &shares {
                assert_eq!(share.rows.start, next, "{count} shares: consecutive");
                next = share.rows.end;
                // Within the heaviest vertex's weight of an equal part.
                let w = weight(&share.rows) as f64;
                assert!(
                    (w - total as f64 / count as f64).abs() <= heaviest,
                    "{count} shares: {w} of {total}"
                );
                let touches = |vs: &[u32]| vs.iter().any(|&v| share.rows.contains(&(v as usize)));
                let triangles: Vec<u32> = (0..cloth.faces().len() as u32)
                    .filter(|&t| touches(&cloth.faces()[t as usize]))
                    .collect();
                assert_eq!(share.triangles, triangles);
                let hinges: Vec<u32> = (0..cloth.hinges().len() as u32)
                    .filter(|&e| touches(&cloth.hinges()[e as usize].vertices))
                    .collect();
                assert_eq!(share.hinges, hinges);
            }
            assert_eq!(next, n, "{count} shares cover every vertex");
            let listed: usize = shares.iter().map(|s| s.triangles.len()).sum();
            let extra = listed - cloth.faces().len();
            // A straight cut across the sheet's short side straddles 60 triangles; a cut along
            // the Morton order is a staircase, up to twice as long.
            assert!(
                extra <= 2 * 60 * (count - 1),
                "{count} shares: {extra} triangles listed more than once"
            );
        }
    }
}
