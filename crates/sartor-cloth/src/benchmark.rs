//! Timing the driver on a motion: the figures of `cargo xtask bench sim`.

use std::time::Instant;

use nalgebra::Vector3;
use sartor_core::io::sha256_hex;
use sartor_core::{BodyModel, MeshTopology, face_normals};
use sartor_motion::Motion;
use serde::{Deserialize, Serialize};

use crate::Result;
use crate::drive::{DriveConfig, simulate_sequence};
use crate::garment::Garment;
use crate::material::Material;
use crate::sequence::{Phase, SequenceFrame};

/// What [`benchmark_sequence`] measured. Times are wall-clock (noisy on a shared machine);
/// iteration and contact counts are deterministic.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SequenceBenchmark {
    /// Motion frames timed.
    pub frames_timed: usize,
    /// Mean wall time of a motion frame, ms.
    pub ms_per_frame: f64,
    /// Slowest motion frame, ms.
    pub max_ms_per_frame: f64,
    /// Mean CPU time of a motion frame over all the process's threads, ms (Linux; `None`
    /// elsewhere): unlike wall time, barely affected by other programs on a loaded machine.
    /// With one thread it is the cost of a frame; with several, their sum (wall time shows the
    /// speed-up).
    pub cpu_ms_per_frame: Option<f64>,
    /// Frames simulated in all (blend and rest included).
    pub frames_total: usize,
    /// Substeps over all frames.
    pub substeps_total: usize,
    /// Substeps of a frame without retries ([`DriveConfig::substeps_for_edge`]).
    #[serde(default)]
    pub substeps_per_frame: usize,
    /// Share of the last frame's interior edges whose two triangles fold beyond 90°, %: below
    /// 0.1 on the relaxed T-shirts, 0.5–2 on smooth ones in motion, 10–16 on crumpled ones
    /// (the 8,710- and 26,066-triangle shirts on the walk at 10 substeps per frame). A
    /// benchmark of a crumpled cloth times the wrong thing.
    #[serde(default)]
    pub folded_hinge_percent: f64,
    /// The last frame simulated, to look at (not in the report).
    #[serde(skip)]
    pub last_frame: Option<SequenceFrame>,
    /// Frames that needed a retry with more substeps.
    pub retried_frames: usize,
    /// Newton iterations per substep (all frames).
    pub newton_iterations_per_substep: f64,
    /// CG iterations per substep (0 with Cholesky).
    pub linear_iterations_per_substep: f64,
    /// Vertex–body contacts per substep.
    pub obstacle_contacts_per_substep: f64,
    /// Self-contact pairs per substep.
    pub self_contacts_per_substep: f64,
    /// Vertices moved by the projection fallback, over all substeps.
    pub projected_vertices: usize,
    /// Body triangles in the contact region.
    pub body_faces_kept: usize,
    /// Split of the wall time per frame (all frames), ms: assembly.
    pub assemble_ms_per_frame: f64,
    /// Linear solves, ms per frame.
    pub solve_ms_per_frame: f64,
    /// Contact queries and self-collision detection, ms per frame.
    pub collision_ms_per_frame: f64,
    /// The self-collision detection's part of `collision_ms_per_frame`.
    #[serde(default)]
    pub self_collision_ms_per_frame: f64,
    /// Share of substeps whose self-collision detection rebuilt its candidate lists, %.
    #[serde(default)]
    pub self_collision_builds_percent: f64,
    /// Looking up the frozen membrane stiffness and bending coefficients apart from the
    /// assembly, ms per frame: for Newton iterations after the first and for hinges without the
    /// Gauss–Newton Hessian (the first iteration looks them up while it assembles, and its
    /// time is in `assemble_ms_per_frame`).
    #[serde(default)]
    pub coefficients_ms_per_frame: f64,
    /// Friction, new positions and the projection fallback (its queries included), ms per
    /// frame.
    #[serde(default)]
    pub projection_ms_per_frame: f64,
    /// The simulator's substeps whole, ms per frame: assembly, solve, collision, coefficients,
    /// projection and the rest of a step (its vector updates and checks).
    #[serde(default)]
    pub step_ms_per_frame: f64,
    /// Posing the body and refitting the collider, ms per frame.
    pub body_ms_per_frame: f64,
    /// End-of-frame checks, ms per frame.
    pub check_ms_per_frame: f64,
    /// Region selection (once per sequence), ms.
    pub region_ms: f64,
    /// SHA-256 of every frame's cloth positions (f32, little-endian, in order): two runs with
    /// the same hash simulated the same cloth, bit for bit.
    pub cloth_sha256: String,
}

/// Simulate `garment` on the body at rest shape through `motion` with `config` and time every
/// frame: the mean over the motion's frames (blend and rest frames are simulated, not timed),
/// the split of the time and the solver's statistics.
pub fn benchmark_sequence(
    body: &BodyModel,
    garment: &Garment,
    material: &Material,
    motion: &Motion,
    config: &DriveConfig,
) -> Result<SequenceBenchmark> {
    let betas = vec![0.0; body.n_betas()];
    let mut stamps =
        Vec::with_capacity(motion.n_frames() + config.blend_frames + config.rest_frames);
    let mut cpu_stamps = Vec::with_capacity(stamps.capacity());
    let start = Instant::now();
    let sequence = simulate_sequence(
        body,
        garment,
        material,
        &betas,
        Some(motion),
        config,
        &mut |done, _| {
            // A region restart starts again from frame 0: keep the last run's times.
            stamps.truncate(done - 1);
            stamps.push(start.elapsed().as_secs_f64());
            cpu_stamps.truncate(done - 1);
            cpu_stamps.push(process_cpu_secs());
        },
    )?;
    let first_motion = sequence
        .frames
        .iter()
        .position(|f| f.phase == Phase::Motion)
        .unwrap_or(sequence.frames.len());
    let frame_ms: Vec<f64> = (first_motion..stamps.len())
        .map(|i| (stamps[i] - if i == 0 { 0.0 } else { stamps[i - 1] }) * 1e3)
        .collect();
    // The CPU time from the end of the last frame before the motion to the end of the last.
    let cpu_ms_per_frame = match (
        first_motion.checked_sub(1).and_then(|i| cpu_stamps.get(i)),
        cpu_stamps.last(),
    ) {
        (Some(Some(a)), Some(Some(b))) if !frame_ms.is_empty() => {
            Some((b - a) * 1e3 / frame_ms.len() as f64)
        }
        _ => None,
    };
    let h = &sequence.header;
    let substeps = h.substeps.total.max(1) as f64;
    let n_frames = sequence.frames.len().max(1) as f64;
    let timing = sequence.timing.unwrap_or_default();
    let per_frame = |secs: f64| secs * 1e3 / n_frames;
    Ok(SequenceBenchmark {
        frames_timed: frame_ms.len(),
        ms_per_frame: frame_ms.iter().sum::<f64>() / frame_ms.len().max(1) as f64,
        max_ms_per_frame: frame_ms.iter().copied().fold(0.0, f64::max),
        cpu_ms_per_frame,
        frames_total: sequence.frames.len(),
        substeps_total: h.substeps.total,
        substeps_per_frame: h.substeps.base,
        folded_hinge_percent: sequence
            .frames
            .last()
            .map_or(0.0, |f| folded_hinge_percent(&f.positions, &sequence.faces)),
        retried_frames: h.substeps.retried_frames,
        newton_iterations_per_substep: h.solver.newton_iterations as f64 / substeps,
        linear_iterations_per_substep: h.solver.linear_iterations as f64 / substeps,
        obstacle_contacts_per_substep: h.solver.obstacle_contacts as f64 / substeps,
        self_contacts_per_substep: h.solver.self_contacts as f64 / substeps,
        projected_vertices: h.solver.projected_vertices,
        body_faces_kept: h.region.faces_kept,
        assemble_ms_per_frame: per_frame(timing.assemble_secs),
        solve_ms_per_frame: per_frame(timing.solve_secs),
        collision_ms_per_frame: per_frame(timing.collision_secs),
        self_collision_ms_per_frame: per_frame(timing.self_collision_secs),
        self_collision_builds_percent: 100.0 * timing.self_collision_builds as f64 / substeps,
        coefficients_ms_per_frame: per_frame(timing.coefficients_secs),
        projection_ms_per_frame: per_frame(timing.projection_secs),
        step_ms_per_frame: per_frame(timing.step_secs),
        body_ms_per_frame: per_frame(timing.body_secs),
        check_ms_per_frame: per_frame(timing.check_secs),
        region_ms: timing.region_secs * 1e3,
        last_frame: sequence.frames.last().cloned(),
        cloth_sha256: sha256_hex(
            &sequence
                .frames
                .iter()
                .flat_map(|f| f.positions.iter().flatten())
                .flat_map(|c| c.to_le_bytes())
                .collect::<Vec<u8>>(),
        ),
    })
}

/// Share of the interior edges of the mesh `positions` / `faces` whose two triangles' normals
/// differ by more than 90° (a fold back beyond a right angle), %; 0 without interior edges.
/// Degenerate triangles count as unfolded.
pub fn folded_hinge_percent(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> f64 {
    let positions: Vec<Vector3<f64>> = positions
        .iter()
        .map(|c| Vector3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2])))
        .collect();
    let normals = face_normals(&positions, faces);
    let topology = MeshTopology::new(positions.len(), faces);
    let (mut interior, mut folded) = (0usize, 0usize);
    for edge_faces in &topology.edge_faces {
        if let &[a, b] = edge_faces.as_slice() {
            interior += 1;
            if normals[a as usize].dot(&normals[b as usize]) < 0.0 {
                folded += 1;
            }
        }
    }
    if interior == 0 {
        return 0.0;
    }
    100.0 * folded as f64 / interior as f64
}

/// CPU time used so far by all threads of this process, s: the sum of every thread's
/// `/proc/self/task/*/schedstat` (nanoseconds; Linux only). Threads that have exited are not
/// counted, which is why a benchmark reads it while its pool is alive.
fn process_cpu_secs() -> Option<f64> {
    let mut total_ns: u64 = 0;
    for entry in std::fs::read_dir("/proc/self/task").ok()? {
        let path = entry.ok()?.path().join("schedstat");
        let text = std::fs::read_to_string(path).ok()?;
        total_ns += text.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(total_ns as f64 * 1e-9)
}
