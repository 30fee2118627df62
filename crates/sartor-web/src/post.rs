//! The garment's post-process computed off the page's thread. It is most of a frame's work on
//! the try-on page (some 3 of 4 ms in headless Chromium for a body beyond the training shapes,
//! the triangles pushed too), which a playing clip spends on the thread that draws the page and
//! answers its sliders. [`PostWorker`] runs in a Web Worker with a garment animator of its own
//! (the same model, body and options): the page makes each frame up to its post-process
//! ([`TryOn::step_deferred`]: the network, the skinning, the body posed) and hands over the
//! job's bytes (the shape, the frame's pose and its garment); the worker runs the strain limit
//! and the collision post-process, and the page shows the frame once it takes up the answer
//! ([`TryOn::absorb_post`]). The post-process's state across
//! frames only warm-starts its search, so the worker's answer is the garment the page's own
//! post-process would have made, bit for bit, whatever frames the worker saw before.

use std::sync::Arc;

use nalgebra::Vector3;
use sartor_core::Pose;
use sartor_core::bytes::{Reader, put_counts, put_floats, put_floats32, put_points, put_pose};
use sartor_runtime::{GarmentAnimator, PostProcessReport, Precision};

use crate::error::{Error, Result};
use crate::files::FileSet;
#[cfg(doc)]
use crate::session::TryOn;
use crate::session::{GarmentOptions, load_body};

/// The first bytes of [`PostJob::bytes`].
const JOB_MAGIC: [u8; 8] = *b"sartorP1";
/// The first bytes of [`PostAnswer::to_bytes`].
const ANSWER_MAGIC: [u8; 8] = *b"sartorQ1";

/// A frame's garment to post-process: what [`TryOn::step_deferred`] hands to the worker.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PostJob {
    /// The page's count of jobs: the answer names it.
    pub id: u64,
    /// The shape the page's animator was set to ([`GarmentAnimator::set_shape`]).
    pub betas: Vec<f32>,
    /// The frame's pose (the limbs held).
    pub pose: Pose,
    /// The frame's garment before the post-process.
    pub vertices: Vec<Vector3<f32>>,
}

impl PostJob {
    /// The bytes of the job `id` of shape `betas`, pose `pose` and garment `vertices`, written
    /// from them (the one allocation is the message). Little-endian: the magic, the id
    /// (`u64`), the counts of β, joints and vertices (`u32`), β (`f32`), the pose (`f64`: the
    /// root translation, orientation and each joint's rotation, quaternions `i, j, k, w`) and
    /// the vertices (`f32`, `x, y, z, …`).
    pub fn bytes(id: u64, betas: &[f32], pose: &Pose, vertices: &[Vector3<f32>]) -> Vec<u8> {
        let joints = pose.local_rotations.len();
        let n = 8 + 8 + 12 + 4 * betas.len() + 8 * (7 + 4 * joints);
        let mut out = Vec::with_capacity(n + 12 * vertices.len());
        out.extend(JOB_MAGIC);
        out.extend(id.to_le_bytes());
        put_counts(&mut out, &[betas.len(), joints, vertices.len()]);
        put_floats32(&mut out, betas);
        put_pose(&mut out, pose);
        put_points(&mut out, vertices);
        out
    }

    /// Read [`Self::bytes`]: an error naming the fault where they are cut short, too long, of
    /// another format or hold a value that is not finite.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let mut r = Reader::open(bytes, "post-process job", JOB_MAGIC)?;
        let id = r.u64()?;
        let (n_betas, joints, n_vertices) = (r.count()?, r.count()?, r.count()?);
        let betas = r.floats32(n_betas)?;
        let pose = r.pose(joints)?;
        let vertices = r.points(n_vertices)?;
        r.end()?;
        Ok(Self {
            id,
            betas,
            pose,
            vertices,
        })
    }
}

/// The worker's answer to a [`PostJob`]: what [`TryOn::absorb_post`] takes up.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PostAnswer {
    /// The job's id.
    pub id: u64,
    /// What the post-processing did, its times by the worker's clock.
    pub report: PostProcessReport,
    /// The garment after the post-processing.
    pub vertices: Vec<Vector3<f32>>,
}

impl PostAnswer {
    /// Little-endian: the magic, the id (`u64`), the edges strain-limited, the vertices pushed
    /// and the vertex count (`u32`), the strain limit's and the collisions' times (`f64`, ms)
    /// and the vertices (`f32`, `x, y, z, …`).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(8 + 8 + 12 + 16 + 12 * self.vertices.len());
        out.extend(ANSWER_MAGIC);
        out.extend(self.id.to_le_bytes());
        let r = &self.report;
        put_counts(&mut out, &[r.strained, r.pushed, self.vertices.len()]);
        put_floats(&mut out, &[r.strain_limit_ms, r.post_process_ms]);
        put_points(&mut out, &self.vertices);
        out
    }

    /// Read [`Self::to_bytes`]'s bytes (faults as [`PostJob::from_bytes`]).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let mut r = Reader::open(bytes, "post-process answer", ANSWER_MAGIC)?;
        let id = r.u64()?;
        let (strained, pushed, n_vertices) = (r.count()?, r.count()?, r.count()?);
        let ms = r.floats(2)?;
        let vertices = r.points(n_vertices)?;
        r.end()?;
        let report = PostProcessReport {
            strained,
            pushed,
            strain_limit_ms: ms[0],
            post_process_ms: ms[1],
        };
        Ok(Self {
            id,
            report,
            vertices,
        })
    }
}

/// The worker's side: the garment model on the body, with the page's post-process, set to the
/// shape of the last job.
#[derive(Debug)]
pub struct PostWorker {
    animator: GarmentAnimator,
    /// The shape `animator` is set to (`None`: none yet).
    betas: Option<Vec<f32>>,
}

impl PostWorker {
    /// The model folder's and the body folder's files (those [`TryOn::load`] takes; the
    /// phenotype files are not needed), with the precision the page's try-on was loaded with
    /// (the garment fitted to each shape is the page's) and a clock that times the
    /// post-process (`None`: untimed).
    pub fn load(
        mut files: FileSet,
        precision: Precision,
        clock: Option<fn() -> f64>,
    ) -> Result<Self> {
        let body = Arc::new(load_body(&mut files)?);
        let options = GarmentOptions {
            precision,
            post_process: true,
            clock,
        };
        Ok(Self {
            animator: options.animator(&mut files, &body)?,
            betas: None,
        })
    }

    /// Post-process the job `job` ([`TryOn::step_deferred`]'s bytes), set to its shape first
    /// where it differs from the last job's, and answer with the bytes
    /// [`TryOn::absorb_post`] takes. An error names the fault of bytes that are not a job, a
    /// shape of another component count, a pose of another skeleton or a garment of another
    /// vertex count.
    pub fn run(&mut self, job: &[u8]) -> Result<Vec<u8>> {
        let job = PostJob::from_bytes(job)?;
        if self.betas.as_ref() != Some(&job.betas) {
            self.betas = None;
            self.animator.set_shape(&job.betas)?;
            self.betas = Some(job.betas);
        }
        let mut vertices = job.vertices;
        let report = self
            .animator
            .post_process(&job.pose, &mut vertices)
            .map_err(|e| Error::invalid("post-process job", e.to_string()))?;
        Ok(PostAnswer {
            id: job.id,
            report,
            vertices,
        }
        .to_bytes())
    }
}
