//! A simulated sequence — one (shape, motion) pair — and its MCAP file.
//!
//! # File layout (`*.mcap`, zstd chunks, written atomically)
//!
//! | record / topic | encoding | content |
//! | --- | --- | --- |
//! | metadata `sartor.cloth_sequence`, key `header` | JSON | [`SequenceHeader`] |
//! | `/cloth/faces` | raw | one message: the garment triangles, u32 little-endian `[F, 3]` |
//! | `/cloth/positions` | raw | one message per frame: cloth vertices, f32 little-endian `[V, 3]`, m |
//! | `/frame` | JSON | one message per frame: [`FrameInfo`] (phase, motion frame, substeps, β, pose) |
//! | `/preview/scene` | protobuf `foxglove.SceneUpdate` | every k-th frame: the cloth and the body region as triangle lists |
//!
//! Frame `i` (0-based) is logged at `(i + 1) / fps` seconds: the simulation starts at time 0
//! from the garment template at rest (not stored). Frames are, in order, `blend_frames` of
//! phase [`Phase::Blend`], `rest_frames` of [`Phase::Rest`] and one [`Phase::Motion`] frame per
//! motion frame. Nothing depends on the wall clock: the same inputs give the same bytes.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use sartor_core::Pose;
use sartor_core::io::read_file;
use sartor_mcap::{McapContents, McapWriter, SceneMesh, decode_scene, read_mcap};
use serde::{Deserialize, Serialize};

use crate::drive::DriveConfig;
use crate::material::MaterialFile;
use crate::{Error, Result};

/// `format` of every sequence header.
pub const SEQUENCE_FORMAT: &str = "sartor-cloth-sequence";
/// Name of the metadata record holding the header.
pub const SEQUENCE_METADATA: &str = "sartor.cloth_sequence";
/// MCAP profile string of sequence files.
const PROFILE: &str = "sartor.cloth_sequence";
const TOPIC_FACES: &str = "/cloth/faces";
const TOPIC_POSITIONS: &str = "/cloth/positions";
const TOPIC_FRAME: &str = "/frame";
const TOPIC_PREVIEW: &str = "/preview/scene";
const CLOTH_ENTITY: &str = "cloth";
const BODY_ENTITY: &str = "body";
const CLOTH_RGBA: [f32; 4] = [0.85, 0.35, 0.2, 1.0];
const BODY_RGBA: [f32; 4] = [0.7, 0.7, 0.75, 0.6];

/// JSON schema of the `/frame` messages (lets Foxglove plot them).
const FRAME_SCHEMA: &str = r#"{
  "type": "object",
  "properties": {
    "frame": {"type": "integer"},
    "phase": {"type": "string", "enum": ["blend", "rest", "motion"]},
    "motion_frame": {"type": ["integer", "null"]},
    "substeps": {"type": "integer"},
    "betas": {"type": "array", "items": {"type": "number"}},
    "pose": {
      "type": "object",
      "properties": {
        "root_translation_m": {"type": "array", "items": {"type": "number"}},
        "root_orientation": {"type": "array", "items": {"type": "number"}},
        "local_rotations": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}
      }
    }
  }
}"#;

/// What a frame of a sequence is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Shape and pose blend from the rest state (β = 0, rest pose) to the sequence's shape and
    /// first pose.
    Blend,
    /// The first pose is held while the cloth settles.
    Rest,
    /// The motion itself (one frame per motion frame).
    Motion,
}

/// Identity of the garment a sequence was simulated with.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GarmentId {
    /// The garment's identity ([`crate::Garment::asset_id`]).
    pub asset: sartor_core::asset::AssetId,
    /// Vertices.
    pub n_vertices: usize,
    /// Triangles.
    pub n_faces: usize,
}

/// Identity of the body model.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyId {
    /// The model's identity ([`sartor_core::BodyModel::asset_id`]).
    pub asset: sartor_core::asset::AssetId,
    /// Length of β.
    pub n_betas: usize,
    /// Joint names, in the order of the poses' rotations.
    pub joint_names: Vec<String>,
}

/// Identity of the motion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionId {
    /// The motion's name.
    pub name: String,
    /// SHA-256 of the motion's JSON (as [`sartor_motion::Motion::save_json`] writes it).
    pub sha256: String,
    /// Frames of the motion.
    pub n_frames: usize,
}

/// The body region that took part in contact.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionStats {
    /// Body triangles kept.
    pub faces_kept: usize,
    /// Body triangles in all.
    pub faces_total: usize,
    /// Margin the region was selected with (after any enlargement), m.
    pub margin_m: f64,
    /// Smallest distance of a cloth vertex to an excluded body triangle over all frames, m
    /// (`None` when the whole body took part or the check was off).
    pub min_excluded_distance_m: Option<f64>,
}

/// Substeps per frame actually used.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubstepStats {
    /// Configured substeps per frame.
    pub base: usize,
    /// Fewest used in a frame.
    pub min: usize,
    /// Most used in a frame.
    pub max: usize,
    /// Sum over the frames.
    pub total: usize,
    /// Frames that needed a retry.
    pub retried_frames: usize,
    /// Failed attempts over all frames (each retried with more substeps).
    pub failed_attempts: usize,
    /// Whole-sequence restarts with a larger body region.
    pub region_restarts: usize,
}

/// Deterministic solver totals over the accepted substeps.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverTotals {
    /// Newton iterations.
    pub newton_iterations: usize,
    /// Linear-solver (CG) iterations; 0 with Cholesky.
    pub linear_iterations: usize,
    /// Vertex–body contacts summed over substeps.
    pub obstacle_contacts: usize,
    /// Most vertex–body contacts in a substep.
    pub max_obstacle_contacts: usize,
    /// Self-contact pairs summed over substeps.
    pub self_contacts: usize,
    /// Most self-contact pairs in a substep.
    pub max_self_contacts: usize,
    /// Vertices the projection fallback moved, summed over substeps.
    pub projected_vertices: usize,
    /// Linear solves CG left short that sparse Cholesky redid.
    #[serde(default)]
    pub cholesky_fallbacks: usize,
    /// Largest kinetic energy after a frame, J.
    pub max_kinetic_energy_j: f64,
    /// Largest vertex speed after a frame, m/s.
    pub max_speed_m_per_s: f64,
    /// Deepest cloth vertex inside the body region after a frame, m (0 when none was inside).
    pub max_penetration_m: f64,
}

/// The JSON header of a sequence file (metadata record [`SEQUENCE_METADATA`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequenceHeader {
    /// [`SEQUENCE_FORMAT`].
    pub format: String,
    /// 1.
    pub version: u32,
    /// "m".
    pub units: String,
    /// The axes convention.
    pub axes: String,
    /// The garment.
    pub garment: GarmentId,
    /// The body model.
    pub body: BodyId,
    /// The cloth material.
    pub material: MaterialFile,
    /// The driver settings.
    pub drive_config: DriveConfig,
    /// SHA-256 of `drive_config`'s canonical JSON ([`DriveConfig::sha256`]).
    pub drive_config_sha256: String,
    /// The motion (`None`: the rest-pose simulation for the garment fit Δ_G).
    pub motion: Option<MotionId>,
    /// The body shape β of the sequence (reached at the end of the blend).
    pub betas: Vec<f64>,
    /// Frames per second.
    pub fps: f64,
    /// Frames of [`Phase::Blend`] (N).
    pub blend_frames: usize,
    /// Frames of [`Phase::Rest`] (M).
    pub rest_frames: usize,
    /// Frames of [`Phase::Motion`].
    pub motion_frames: usize,
    /// All frames.
    pub n_frames: usize,
    /// The body region.
    pub region: RegionStats,
    /// Substeps actually used.
    pub substeps: SubstepStats,
    /// Solver totals.
    pub solver: SolverTotals,
    /// Frames with a preview message (every `drive_config.preview.every_n_frames`-th).
    pub preview_frames: usize,
}

/// The per-frame JSON message on `/frame`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameInfo {
    /// Frame index in the sequence.
    pub frame: usize,
    /// The frame's phase.
    pub phase: Phase,
    /// Index into the motion for [`Phase::Motion`] frames.
    pub motion_frame: Option<usize>,
    /// Substeps the frame took.
    pub substeps: usize,
    /// The body shape at this frame.
    pub betas: Vec<f64>,
    /// The body pose at this frame (root translation, root orientation, local rotations as
    /// quaternions `[x, y, z, w]`).
    pub pose: Pose,
}

/// One simulated frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SequenceFrame {
    /// The phase.
    pub phase: Phase,
    /// Index into the motion for [`Phase::Motion`] frames.
    pub motion_frame: Option<usize>,
    /// Substeps the frame took.
    pub substeps: usize,
    /// Body shape β.
    pub betas: Vec<f64>,
    /// Body pose.
    pub pose: Pose,
    /// Cloth vertex positions at the end of the frame, m (storage precision, f32).
    pub positions: Vec<[f32; 3]>,
}

impl SequenceFrame {
    /// The cloth positions as vectors.
    pub fn positions_vec3(&self) -> Vec<Vector3<f32>> {
        self.positions.iter().map(|p| Vector3::from(*p)).collect()
    }
}

/// The preview saved with a sequence: the body region's triangles and, every k-th frame, its
/// vertices (the cloth's come from the frames).
#[derive(Clone, Debug, PartialEq)]
pub struct SequencePreview {
    /// Every how many frames a preview is written.
    pub every_n_frames: usize,
    /// Triangles of the body region, indexing `PreviewFrame::body_positions`.
    pub body_faces: Vec<[u32; 3]>,
    /// The preview frames.
    pub frames: Vec<PreviewFrame>,
}

/// The body region at one preview frame.
#[derive(Clone, Debug, PartialEq)]
pub struct PreviewFrame {
    /// Frame index in the sequence.
    pub frame: usize,
    /// Body-region vertex positions, m.
    pub body_positions: Vec<[f32; 3]>,
}

/// Wall-clock timing of the run that produced a sequence. Never written to the file (reruns
/// must give identical bytes); `None` for a sequence read from a file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SequenceTiming {
    /// Whole run, s.
    pub total_secs: f64,
    /// Region selection, s.
    pub region_secs: f64,
    /// Posing the body (skinning) and refitting the collider, s.
    pub body_secs: f64,
    /// Force/Hessian evaluation and assembly, s.
    pub assemble_secs: f64,
    /// Linear solves, s.
    pub solve_secs: f64,
    /// Contact queries and self-collision detection, s.
    pub collision_secs: f64,
    /// The self-collision detection's part of `collision_secs`, s.
    pub self_collision_secs: f64,
    /// Substeps whose self-collision detection rebuilt its candidate lists (the others reused
    /// them).
    pub self_collision_builds: usize,
    /// Frozen material coefficients, s.
    pub coefficients_secs: f64,
    /// Friction, new positions and the projection fallback, s.
    pub projection_secs: f64,
    /// The simulator's substeps, whole (the parts above and the rest of a step), s.
    pub step_secs: f64,
    /// Per-frame checks (penetration, excluded region), s.
    pub check_secs: f64,
}

/// A simulated (shape, motion) sequence: header, garment triangles and frames.
#[derive(Clone, Debug, PartialEq)]
pub struct ClothSequence {
    /// The header.
    pub header: SequenceHeader,
    /// Garment triangles.
    pub faces: Vec<[u32; 3]>,
    /// The frames, in order.
    pub frames: Vec<SequenceFrame>,
    /// The preview, if one is written.
    pub preview: Option<SequencePreview>,
    /// Timing of the run (not stored).
    pub timing: Option<SequenceTiming>,
}

/// Log time of frame `i`, ns.
fn frame_time_ns(i: usize, fps: f64) -> u64 {
    ((i as f64 + 1.0) * 1e9 / fps).round() as u64
}

fn le_bytes_f32(positions: &[[f32; 3]]) -> Vec<u8> {
    positions
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect()
}

impl ClothSequence {
    /// The frames of one phase.
    pub fn phase_frames(&self, phase: Phase) -> impl Iterator<Item = &SequenceFrame> {
        self.frames.iter().filter(move |f| f.phase == phase)
    }

    /// The last frame (for a rest-pose sequence: the cloth `S_c(β, 0)` of the garment fit).
    pub fn last_frame(&self) -> Option<&SequenceFrame> {
        self.frames.last()
    }

    /// The bytes of the MCAP file (deterministic); `path` names the file in errors.
    pub fn to_bytes(&self, path: &Path) -> Result<Vec<u8>> {
        self.check_consistent()
            .map_err(|m| Error::invalid("cloth sequence", m))?;
        let h = &self.header;
        let mut w = McapWriter::new(path, PROFILE)?;
        let header_json = serde_json::to_string(h)
            .map_err(|e| Error::invalid("cloth sequence", format!("header: {e}")))?;
        w.write_metadata(
            SEQUENCE_METADATA,
            BTreeMap::from([("header".to_string(), header_json)]),
        )?;
        let meta = |pairs: &[(&str, String)]| -> BTreeMap<String, String> {
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.clone()))
                .collect()
        };
        let faces_channel = w.add_channel(
            TOPIC_FACES,
            "application/octet-stream",
            None,
            &meta(&[
                ("dtype", "u32".into()),
                ("layout", "little-endian [F, 3]".into()),
                ("n_faces", h.garment.n_faces.to_string()),
            ]),
        )?;
        let positions_channel = w.add_channel(
            TOPIC_POSITIONS,
            "application/octet-stream",
            None,
            &meta(&[
                ("dtype", "f32".into()),
                ("layout", "little-endian [V, 3]".into()),
                ("units", "m".into()),
                ("n_vertices", h.garment.n_vertices.to_string()),
            ]),
        )?;
        let frame_channel = w.add_channel(
            TOPIC_FRAME,
            "json",
            Some(("sartor.FrameInfo", "jsonschema", FRAME_SCHEMA.as_bytes())),
            &BTreeMap::new(),
        )?;
        let preview_channel = match &self.preview {
            Some(_) => Some(w.add_scene_channel(TOPIC_PREVIEW)?),
            None => None,
        };
        let faces_bytes: Vec<u8> = self
            .faces
            .iter()
            .flatten()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        w.write_message(faces_channel, 0, 0, &faces_bytes)?;
        let mut previews = self.preview.iter().flat_map(|p| &p.frames).peekable();
        for (i, frame) in self.frames.iter().enumerate() {
            let t = frame_time_ns(i, h.fps);
            let seq = i as u32;
            w.write_message(positions_channel, seq, t, &le_bytes_f32(&frame.positions))?;
            let info = FrameInfo {
                frame: i,
                phase: frame.phase,
                motion_frame: frame.motion_frame,
                substeps: frame.substeps,
                betas: frame.betas.clone(),
                pose: frame.pose.clone(),
            };
            let json = serde_json::to_vec(&info)
                .map_err(|e| Error::invalid("cloth sequence", format!("frame {i}: {e}")))?;
            w.write_message(frame_channel, seq, t, &json)?;
            if let (Some(channel), Some(preview)) = (preview_channel, &self.preview)
                && previews.peek().is_some_and(|p| p.frame == i)
            {
                let p = previews.next().expect("peeked above");
                let meshes = [
                    SceneMesh {
                        id: CLOTH_ENTITY,
                        positions: &frame.positions,
                        faces: &self.faces,
                        color_rgba: CLOTH_RGBA,
                    },
                    SceneMesh {
                        id: BODY_ENTITY,
                        positions: &p.body_positions,
                        faces: &preview.body_faces,
                        color_rgba: BODY_RGBA,
                    },
                ];
                w.write_scene(channel, seq, t, &meshes)?;
            }
        }
        Ok(w.finish_bytes()?)
    }

    /// Write the MCAP file atomically (temporary name, then rename).
    pub fn write(&self, path: &Path) -> Result<()> {
        let bytes = self.to_bytes(path)?;
        Ok(sartor_core::io::write_atomic(path, &bytes)?)
    }

    /// Read and validate a sequence file. Every error names the file.
    pub fn read(path: &Path) -> Result<Self> {
        Self::from_bytes(path, &read_file(path)?)
    }

    /// Parse and validate the bytes of a sequence file read from `path` (named in errors):
    /// MCAP integrity (magics, CRCs), the header, the configuration hash, every frame's size,
    /// order, time, phase, shape and pose, finite positions, face indices, and the preview.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Self> {
        let bad = |m: String| Error::format(path, m);
        let contents = read_mcap(path, bytes)?;
        let header_json = contents
            .metadata
            .get(SEQUENCE_METADATA)
            .and_then(|m| m.get("header"))
            .ok_or_else(|| bad(format!("no {SEQUENCE_METADATA:?} metadata with a header")))?;
        let header: SequenceHeader =
            serde_json::from_str(header_json).map_err(|e| bad(format!("sequence header: {e}")))?;
        check_header(&header).map_err(&bad)?;
        if let Some(m) = contents.messages.iter().find(|m| {
            ![TOPIC_FACES, TOPIC_POSITIONS, TOPIC_FRAME, TOPIC_PREVIEW].contains(&m.topic.as_str())
        }) {
            return Err(bad(format!("unexpected topic {:?}", m.topic)));
        }
        let (n_v, n_f) = (header.garment.n_vertices, header.garment.n_faces);
        let faces = read_faces(&contents, n_v, n_f).map_err(&bad)?;

        let positions: Vec<_> = contents.topic(TOPIC_POSITIONS).collect();
        let infos: Vec<_> = contents.topic(TOPIC_FRAME).collect();
        if positions.len() != header.n_frames || infos.len() != header.n_frames {
            return Err(bad(format!(
                "{} position and {} frame messages for {} frames",
                positions.len(),
                infos.len(),
                header.n_frames
            )));
        }
        let mut frames = Vec::with_capacity(header.n_frames);
        for (i, (p, info)) in positions.iter().zip(&infos).enumerate() {
            let t = frame_time_ns(i, header.fps);
            for m in [p, info] {
                if m.sequence as usize != i || m.log_time_ns != t {
                    return Err(bad(format!(
                        "{} message {i}: sequence {} at {} ns, expected {i} at {t} ns",
                        m.topic, m.sequence, m.log_time_ns
                    )));
                }
            }
            if p.data.len() != n_v * 12 {
                return Err(bad(format!(
                    "frame {i}: {} bytes of positions for {n_v} vertices",
                    p.data.len()
                )));
            }
            let xs: Vec<[f32; 3]> = p
                .data
                .chunks_exact(12)
                .map(|c| {
                    std::array::from_fn(|k| {
                        f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]])
                    })
                })
                .collect();
            if let Some(v) = xs.iter().position(|x| !x.iter().all(|c| c.is_finite())) {
                return Err(bad(format!("frame {i}: vertex {v} is not finite")));
            }
            let info: FrameInfo =
                serde_json::from_slice(&info.data).map_err(|e| bad(format!("frame {i}: {e}")))?;
            check_frame(&header, i, &info).map_err(&bad)?;
            frames.push(SequenceFrame {
                phase: info.phase,
                motion_frame: info.motion_frame,
                substeps: info.substeps,
                betas: info.betas,
                pose: info.pose,
                positions: xs,
            });
        }
        let preview = read_preview(path, &contents, &header, &faces, &frames)?;
        Ok(Self {
            header,
            faces,
            frames,
            preview,
            timing: None,
        })
    }

    /// The invariants [`ClothSequence::to_bytes`] relies on (a sequence made by the driver
    /// always has them).
    fn check_consistent(&self) -> std::result::Result<(), String> {
        let h = &self.header;
        check_header(h)?;
        if self.faces.len() != h.garment.n_faces
            || self
                .faces
                .iter()
                .flatten()
                .any(|&i| i as usize >= h.garment.n_vertices)
        {
            return Err("faces do not match the garment".into());
        }
        if self.frames.len() != h.n_frames {
            return Err(format!(
                "{} frames, header says {}",
                self.frames.len(),
                h.n_frames
            ));
        }
        for (i, f) in self.frames.iter().enumerate() {
            if f.positions.len() != h.garment.n_vertices {
                return Err(format!("frame {i} has {} vertices", f.positions.len()));
            }
            let info = FrameInfo {
                frame: i,
                phase: f.phase,
                motion_frame: f.motion_frame,
                substeps: f.substeps,
                betas: f.betas.clone(),
                pose: f.pose.clone(),
            };
            check_frame(h, i, &info)?;
        }
        let every = h.drive_config.preview.every_n_frames;
        match &self.preview {
            None if h.preview_frames == 0 => {}
            Some(p) if p.every_n_frames == every && p.frames.len() == h.preview_frames => {
                for (k, pf) in p.frames.iter().enumerate() {
                    if pf.frame != k * every || pf.frame >= self.frames.len() {
                        return Err(format!("preview {k} is at frame {}", pf.frame));
                    }
                }
            }
            _ => return Err("preview does not match the header".into()),
        }
        Ok(())
    }
}

/// Header checks shared by the reader and the writer.
fn check_header(h: &SequenceHeader) -> std::result::Result<(), String> {
    if h.format != SEQUENCE_FORMAT || h.version != 1 || h.units != "m" {
        return Err(format!(
            "format {:?} version {} units {:?} is not {SEQUENCE_FORMAT} version 1 in m",
            h.format, h.version, h.units
        ));
    }
    h.drive_config.validate().map_err(|e| e.to_string())?;
    let hash = h.drive_config.sha256().map_err(|e| e.to_string())?;
    if hash != h.drive_config_sha256 {
        return Err(format!(
            "drive_config_sha256 {} does not match the drive config ({hash})",
            h.drive_config_sha256
        ));
    }
    if h.blend_frames != h.drive_config.blend_frames || h.rest_frames != h.drive_config.rest_frames
    {
        return Err("blend_frames / rest_frames differ from the drive config".into());
    }
    if h.n_frames != h.blend_frames + h.rest_frames + h.motion_frames {
        return Err(format!(
            "n_frames {} is not {} + {} + {}",
            h.n_frames, h.blend_frames, h.rest_frames, h.motion_frames
        ));
    }
    if h.motion.as_ref().map_or(0, |m| m.n_frames) != h.motion_frames {
        return Err("motion_frames differs from the motion's frame count".into());
    }
    if !(h.fps.is_finite() && h.fps > 0.0) {
        return Err(format!("fps {} is not positive", h.fps));
    }
    if h.betas.len() != h.body.n_betas || !h.betas.iter().all(|b| b.is_finite()) {
        return Err(format!(
            "betas {:?} for {} components",
            h.betas, h.body.n_betas
        ));
    }
    if h.garment.n_vertices == 0 || h.garment.n_faces == 0 {
        return Err("empty garment".into());
    }
    let every = h.drive_config.preview.every_n_frames;
    let expected_previews = if every == 0 {
        0
    } else {
        h.n_frames.div_ceil(every)
    };
    if h.preview_frames != expected_previews {
        return Err(format!(
            "{} preview frames, expected {expected_previews}",
            h.preview_frames
        ));
    }
    Ok(())
}

/// The phase and motion frame of frame `i`.
pub(crate) fn frame_phase(h: &SequenceHeader, i: usize) -> (Phase, Option<usize>) {
    if i < h.blend_frames {
        (Phase::Blend, None)
    } else if i < h.blend_frames + h.rest_frames {
        (Phase::Rest, None)
    } else {
        (Phase::Motion, Some(i - h.blend_frames - h.rest_frames))
    }
}

fn check_frame(h: &SequenceHeader, i: usize, info: &FrameInfo) -> std::result::Result<(), String> {
    let (phase, motion_frame) = frame_phase(h, i);
    if info.frame != i || info.phase != phase || info.motion_frame != motion_frame {
        return Err(format!(
            "frame {i}: says frame {} phase {:?} motion frame {:?}, expected {phase:?} {motion_frame:?}",
            info.frame, info.phase, info.motion_frame
        ));
    }
    if info.substeps < h.substeps.min || info.substeps > h.substeps.max || info.substeps == 0 {
        return Err(format!(
            "frame {i}: {} substeps outside the header's {}..={}",
            info.substeps, h.substeps.min, h.substeps.max
        ));
    }
    if info.betas.len() != h.body.n_betas || !info.betas.iter().all(|b| b.is_finite()) {
        return Err(format!("frame {i}: bad betas {:?}", info.betas));
    }
    info.pose
        .validate(h.body.joint_names.len())
        .map_err(|e| format!("frame {i}: {e}"))
}

fn read_faces(
    contents: &McapContents,
    n_v: usize,
    n_f: usize,
) -> std::result::Result<Vec<[u32; 3]>, String> {
    let messages: Vec<_> = contents.topic(TOPIC_FACES).collect();
    let [m] = messages.as_slice() else {
        return Err(format!(
            "{} messages on {TOPIC_FACES}, expected 1",
            messages.len()
        ));
    };
    if m.data.len() != n_f * 12 {
        return Err(format!(
            "{} bytes of faces for {n_f} triangles",
            m.data.len()
        ));
    }
    let faces: Vec<[u32; 3]> = m
        .data
        .chunks_exact(12)
        .map(|c| {
            std::array::from_fn(|k| {
                u32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]])
            })
        })
        .collect();
    if let Some(f) = faces
        .iter()
        .position(|t| t.iter().any(|&i| i as usize >= n_v))
    {
        return Err(format!("triangle {f} indexes past {n_v} vertices"));
    }
    Ok(faces)
}

fn read_preview(
    path: &Path,
    contents: &McapContents,
    header: &SequenceHeader,
    faces: &[[u32; 3]],
    frames: &[SequenceFrame],
) -> Result<Option<SequencePreview>> {
    let bad = |m: String| Error::format(path, m);
    let every = header.drive_config.preview.every_n_frames;
    let messages: Vec<_> = contents.topic(TOPIC_PREVIEW).collect();
    if messages.len() != header.preview_frames {
        return Err(bad(format!(
            "{} preview messages, header says {}",
            messages.len(),
            header.preview_frames
        )));
    }
    if every == 0 {
        return Ok(None);
    }
    let mut body_faces: Option<Vec<[u32; 3]>> = None;
    let mut out = Vec::with_capacity(messages.len());
    for (k, m) in messages.iter().enumerate() {
        let frame = k * every;
        if m.sequence as usize != frame || m.log_time_ns != frame_time_ns(frame, header.fps) {
            return Err(bad(format!(
                "preview message {k} is for frame {}, expected {frame}",
                m.sequence
            )));
        }
        let meshes = decode_scene(path, &m.data)?;
        let (Some(cloth), Some(body), 2) = (
            meshes.iter().find(|s| s.id == CLOTH_ENTITY),
            meshes.iter().find(|s| s.id == BODY_ENTITY),
            meshes.len(),
        ) else {
            return Err(bad(format!(
                "preview message {k} does not hold exactly a cloth and a body"
            )));
        };
        if cloth.faces != faces || cloth.positions != frames[frame].positions {
            return Err(bad(format!(
                "preview message {k}: the cloth differs from frame {frame}"
            )));
        }
        match &body_faces {
            None => body_faces = Some(body.faces.clone()),
            Some(f) if *f == body.faces => {}
            Some(_) => {
                return Err(bad(format!(
                    "preview message {k}: body triangles change between previews"
                )));
            }
        }
        out.push(PreviewFrame {
            frame,
            body_positions: body.positions.clone(),
        });
    }
    Ok(Some(SequencePreview {
        every_n_frames: every,
        body_faces: body_faces.unwrap_or_default(),
        frames: out,
    }))
}
