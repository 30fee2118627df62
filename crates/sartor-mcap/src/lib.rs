//! # sartor-mcap
//!
//! MCAP files (<https://mcap.dev>): a deterministic writer with `foxglove.SceneUpdate`
//! triangle-list previews, and a validating reader. Used by the simulator's sequence files and
//! the command line's animation previews; a crate of its own because zstd (C code) must stay
//! out of the geometry core and the runtime.
//!
//! The writer is built for reproducible outputs: the file is assembled in memory and written
//! atomically ([`sartor_core::io::write_atomic`]); chunks are zstd-compressed on the calling thread
//! (multi-threaded zstd may frame its output differently); every time stamp comes from the
//! caller (log time = the frame's time in the sequence, never the wall clock); the library
//! string is fixed. The same calls therefore give the same bytes.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use foxglove::messages::{
    Color, Point3, Pose, Quaternion, SceneEntity, SceneUpdate, Timestamp, TriangleListPrimitive,
    Vector3,
};
use foxglove::{Decode, Encode};
use mcap::records::{MessageHeader, Metadata};
use mcap::{Compression, WriteOptions, Writer};

use sartor_core::io::write_atomic;
/// The error type is the core's (file and format faults).
pub use sartor_core::{Error, Result};

/// Schema name of Foxglove's scene messages (protobuf), as Foxglove expects it.
pub const SCENE_UPDATE_SCHEMA: &str = "foxglove.SceneUpdate";

/// The frame every preview entity lives in (Foxglove's 3D panel shows it as the only frame).
pub const SCENE_FRAME_ID: &str = "world";

/// Library string in the MCAP header (fixed, so files do not change with the crate version).
const LIBRARY: &str = "sartor";

/// Largest record the reader accepts, bytes (a corrupt length must not make it allocate
/// without bound; decompressed messages can be larger than the whole compressed file).
const MAX_RECORD_BYTES: usize = 256 << 20;

/// Uncompressed chunk size, bytes: large enough for zstd to find the frame-to-frame
/// redundancy, small enough to stream.
const CHUNK_SIZE: u64 = 4 << 20;

/// One indexed triangle mesh of a preview scene.
#[derive(Clone, Copy, Debug)]
pub struct SceneMesh<'a> {
    /// Entity id; an entity replaces the previous one with the same id on the same topic.
    pub id: &'a str,
    /// Vertex positions, m.
    pub positions: &'a [[f32; 3]],
    /// Triangles (indices into `positions`).
    pub faces: &'a [[u32; 3]],
    /// Colour, RGBA in 0..1.
    pub color_rgba: [f32; 4],
}

/// A preview mesh read back from a `foxglove.SceneUpdate` message.
#[derive(Clone, Debug, PartialEq)]
pub struct OwnedSceneMesh {
    /// Entity id.
    pub id: String,
    /// Vertex positions, m (as written: f32 values carried in protobuf doubles).
    pub positions: Vec<[f32; 3]>,
    /// Triangles.
    pub faces: Vec<[u32; 3]>,
}

/// Writes an MCAP file in memory; [`McapWriter::finish`] writes it atomically.
pub struct McapWriter {
    path: PathBuf,
    writer: Writer<Cursor<Vec<u8>>>,
    scene_schema: Option<u16>,
}

impl McapWriter {
    /// A writer for the file `path` (nothing is written there before [`McapWriter::finish`]).
    /// `profile` goes into the MCAP header (e.g. `"sartor.cloth-sequence"`).
    pub fn new(path: &Path, profile: &str) -> Result<Self> {
        let options = WriteOptions::new()
            .compression(Some(Compression::Zstd))
            .compression_threads(0)
            .profile(profile)
            .library(LIBRARY)
            .chunk_size(Some(CHUNK_SIZE));
        let writer = options
            .create(Cursor::new(Vec::new()))
            .map_err(|e| mcap_error(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            scene_schema: None,
        })
    }

    /// The file this writer will write.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Add a channel. `schema`: `(name, encoding, data)` of its schema, if any (e.g. a JSON
    /// schema; raw binary channels have none). Returns the channel id.
    pub fn add_channel(
        &mut self,
        topic: &str,
        message_encoding: &str,
        schema: Option<(&str, &str, &[u8])>,
        metadata: &BTreeMap<String, String>,
    ) -> Result<u16> {
        let schema_id = match schema {
            Some((name, encoding, data)) => self
                .writer
                .add_schema(name, encoding, data)
                .map_err(|e| mcap_error(&self.path, e))?,
            None => 0,
        };
        self.writer
            .add_channel(schema_id, topic, message_encoding, metadata)
            .map_err(|e| mcap_error(&self.path, e))
    }

    /// Add a `foxglove.SceneUpdate` channel (protobuf), for [`McapWriter::write_scene`].
    pub fn add_scene_channel(&mut self, topic: &str) -> Result<u16> {
        let schema_id = match self.scene_schema {
            Some(id) => id,
            None => {
                let schema = SceneUpdate::get_schema().ok_or_else(|| {
                    Error::format(&self.path, "foxglove has no SceneUpdate schema")
                })?;
                let id = self
                    .writer
                    .add_schema(&schema.name, &schema.encoding, &schema.data)
                    .map_err(|e| mcap_error(&self.path, e))?;
                self.scene_schema = Some(id);
                id
            }
        };
        self.writer
            .add_channel(
                schema_id,
                topic,
                &SceneUpdate::get_message_encoding(),
                &BTreeMap::new(),
            )
            .map_err(|e| mcap_error(&self.path, e))
    }

    /// Write one message at `time_ns` (log and publish time).
    pub fn write_message(
        &mut self,
        channel: u16,
        sequence: u32,
        time_ns: u64,
        data: &[u8],
    ) -> Result<()> {
        let header = MessageHeader {
            channel_id: channel,
            sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| mcap_error(&self.path, e))
    }

    /// Write a `foxglove.SceneUpdate` with one triangle-list entity per mesh (in frame
    /// [`SCENE_FRAME_ID`], replacing the entities of the same ids).
    pub fn write_scene(
        &mut self,
        channel: u16,
        sequence: u32,
        time_ns: u64,
        meshes: &[SceneMesh<'_>],
    ) -> Result<()> {
        let timestamp = Timestamp::new_checked(
            (time_ns / 1_000_000_000) as u32,
            (time_ns % 1_000_000_000) as u32,
        )
        .filter(|_| time_ns / 1_000_000_000 <= u32::MAX as u64)
        .ok_or_else(|| {
            Error::invalid(
                "scene message",
                format!("time {time_ns} ns is out of range"),
            )
        })?;
        let mut entities = Vec::with_capacity(meshes.len());
        for mesh in meshes {
            if let Some(f) = mesh
                .faces
                .iter()
                .position(|t| t.iter().any(|&i| i as usize >= mesh.positions.len()))
            {
                return Err(Error::invalid(
                    "scene mesh",
                    format!(
                        "{}: triangle {f} indexes past {} vertices",
                        mesh.id,
                        mesh.positions.len()
                    ),
                ));
            }
            let [r, g, b, a] = mesh.color_rgba.map(f64::from);
            entities.push(SceneEntity {
                timestamp: Some(timestamp),
                frame_id: SCENE_FRAME_ID.into(),
                id: mesh.id.into(),
                triangles: vec![TriangleListPrimitive {
                    pose: Some(Pose {
                        position: Some(Vector3 {
                            x: 0.0,
                            y: 0.0,
                            z: 0.0,
                        }),
                        orientation: Some(Quaternion {
                            x: 0.0,
                            y: 0.0,
                            z: 0.0,
                            w: 1.0,
                        }),
                    }),
                    points: mesh
                        .positions
                        .iter()
                        .map(|p| Point3 {
                            x: p[0].into(),
                            y: p[1].into(),
                            z: p[2].into(),
                        })
                        .collect(),
                    color: Some(Color { r, g, b, a }),
                    colors: Vec::new(),
                    indices: mesh.faces.iter().flatten().copied().collect(),
                }],
                ..SceneEntity::default()
            });
        }
        let update = SceneUpdate {
            deletions: Vec::new(),
            entities,
        };
        let mut data = Vec::with_capacity(Encode::encoded_len(&update).unwrap_or(0));
        update
            .encode(&mut data)
            .map_err(|e| Error::format(&self.path, format!("encoding a scene update: {e}")))?;
        self.write_message(channel, sequence, time_ns, &data)
    }

    /// Write a metadata record (`name` and string entries).
    pub fn write_metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<()> {
        self.writer
            .write_metadata(&Metadata {
                name: name.into(),
                metadata: entries,
            })
            .map_err(|e| mcap_error(&self.path, e))
    }

    /// Finish the file (summary, indexes, footer) and return its bytes.
    pub fn finish_bytes(mut self) -> Result<Vec<u8>> {
        self.writer
            .finish()
            .map_err(|e| mcap_error(&self.path, e))?;
        Ok(self.writer.into_inner().into_inner())
    }

    /// Finish the file and write it atomically to its path.
    pub fn finish(self) -> Result<()> {
        let path = self.path.clone();
        let bytes = self.finish_bytes()?;
        write_atomic(&path, &bytes)
    }
}

/// One message read from an MCAP file.
#[derive(Clone, Debug, PartialEq)]
pub struct McapMessage {
    /// The channel's topic.
    pub topic: String,
    /// The channel's message encoding.
    pub message_encoding: String,
    /// The channel's schema name, if it has a schema.
    pub schema_name: Option<String>,
    /// Sequence number.
    pub sequence: u32,
    /// Log time, ns.
    pub log_time_ns: u64,
    /// The message bytes.
    pub data: Vec<u8>,
}

/// Everything [`read_mcap`] found in a file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct McapContents {
    /// Metadata records by name (a repeated name is an error).
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// All messages in file order.
    pub messages: Vec<McapMessage>,
}

impl McapContents {
    /// The messages of one topic, in file order.
    pub fn topic<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = &'a McapMessage> + 'a {
        self.messages.iter().filter(move |m| m.topic == topic)
    }
}

/// Read and check a whole MCAP file held in `bytes` (read from `path`, which errors name), in
/// one pass: both magics, every record, the chunk, data-section and summary CRCs,
/// decompression, and that every message's channel was declared. A truncated file is an error.
pub fn read_mcap(path: &Path, bytes: &[u8]) -> Result<McapContents> {
    use mcap::records::Record;
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let options = LinearReaderOptions::default()
        .with_validate_chunk_crcs(true)
        .with_validate_data_section_crc(true)
        .with_validate_summary_section_crc(true)
        .with_check_finishes_after_end_magic(true)
        .with_record_length_limit(MAX_RECORD_BYTES.max(bytes.len()));
    let mut reader = LinearReader::new_with_options(options);
    let mut offset = 0;
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    // Channel id → (topic, message encoding, schema name).
    let mut channels: BTreeMap<u16, (String, String, Option<String>)> = BTreeMap::new();
    let mut contents = McapContents::default();
    let mut in_summary = false;
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| mcap_error(path, e))? {
            LinearReadEvent::ReadRequest(n) => {
                let n = n.min(bytes.len() - offset);
                reader.insert(n).copy_from_slice(&bytes[offset..offset + n]);
                reader.notify_read(n);
                offset += n;
            }
            LinearReadEvent::Record { data, opcode } => {
                let record = mcap::parse_record(opcode, data).map_err(|e| mcap_error(path, e))?;
                match record {
                    // The summary repeats schemas and channels; the data section is the truth.
                    Record::DataEnd(_) => in_summary = true,
                    _ if in_summary => {}
                    Record::Schema { header, .. } => {
                        schemas.insert(header.id, header.name);
                    }
                    Record::Channel(c) => {
                        let schema = match c.schema_id {
                            0 => None,
                            id => Some(schemas.get(&id).cloned().ok_or_else(|| {
                                Error::format(
                                    path,
                                    format!("channel {:?} uses unknown schema {id}", c.topic),
                                )
                            })?),
                        };
                        channels.insert(c.id, (c.topic, c.message_encoding, schema));
                    }
                    Record::Message { header, data } => {
                        let (topic, encoding, schema) =
                            channels.get(&header.channel_id).ok_or_else(|| {
                                Error::format(
                                    path,
                                    format!(
                                        "message {} on undeclared channel {}",
                                        header.sequence, header.channel_id
                                    ),
                                )
                            })?;
                        contents.messages.push(McapMessage {
                            topic: topic.clone(),
                            message_encoding: encoding.clone(),
                            schema_name: schema.clone(),
                            sequence: header.sequence,
                            log_time_ns: header.log_time,
                            data: data.into_owned(),
                        });
                    }
                    Record::Metadata(m) => {
                        if contents.metadata.contains_key(&m.name) {
                            return Err(Error::format(
                                path,
                                format!("metadata record {:?} appears twice", m.name),
                            ));
                        }
                        contents.metadata.insert(m.name, m.metadata);
                    }
                    _ => {}
                }
            }
        }
    }
    Ok(contents)
}

/// Decode a `foxglove.SceneUpdate` message written by [`McapWriter::write_scene`] (`path`
/// names the file in errors): one mesh per triangle-list entity.
pub fn decode_scene(path: &Path, data: &[u8]) -> Result<Vec<OwnedSceneMesh>> {
    let update = SceneUpdate::decode(data)
        .map_err(|e| Error::format(path, format!("bad foxglove.SceneUpdate: {e}")))?;
    let mut meshes = Vec::new();
    for entity in update.entities {
        for list in &entity.triangles {
            let positions: Vec<[f32; 3]> = list
                .points
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect();
            if list.indices.len() % 3 != 0
                || list.indices.iter().any(|&i| i as usize >= positions.len())
            {
                return Err(Error::format(
                    path,
                    format!("scene entity {:?}: bad triangle indices", entity.id),
                ));
            }
            meshes.push(OwnedSceneMesh {
                id: entity.id.clone(),
                faces: list
                    .indices
                    .chunks_exact(3)
                    .map(|c| [c[0], c[1], c[2]])
                    .collect(),
                positions,
            });
        }
    }
    Ok(meshes)
}

fn mcap_error(path: &Path, e: mcap::McapError) -> Error {
    Error::format(path, format!("MCAP: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(path: &Path) -> Vec<u8> {
        let mut w = McapWriter::new(path, "test").expect("writer");
        let raw = w
            .add_channel("/raw", "application/octet-stream", None, &BTreeMap::new())
            .expect("channel");
        let scene = w.add_scene_channel("/scene").expect("scene channel");
        let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]];
        let faces = [[0, 1, 2]];
        for k in 0..3u32 {
            w.write_message(raw, k, u64::from(k) * 1000, &[k as u8; 5])
                .expect("message");
        }
        let mesh = SceneMesh {
            id: "tri",
            positions: &positions,
            faces: &faces,
            color_rgba: [1.0, 0.0, 0.0, 1.0],
        };
        w.write_scene(scene, 0, 0, &[mesh]).expect("scene");
        w.write_metadata(
            "info",
            BTreeMap::from([("json".to_string(), "{}".to_string())]),
        )
        .expect("metadata");
        w.finish_bytes().expect("finish")
    }

    #[test]
    fn round_trip_is_deterministic_and_checked() {
        let path = Path::new("test.mcap");
        let bytes = sample(path);
        assert_eq!(bytes, sample(path), "same calls, same bytes");
        let contents = read_mcap(path, &bytes).expect("read back");
        assert_eq!(contents.metadata["info"]["json"], "{}");
        let raw: Vec<_> = contents.topic("/raw").collect();
        assert_eq!(raw.len(), 3);
        assert_eq!(raw[2].data, vec![2; 5]);
        assert_eq!(raw[2].log_time_ns, 2000);
        let scene: Vec<_> = contents.topic("/scene").collect();
        assert_eq!(scene[0].schema_name.as_deref(), Some(SCENE_UPDATE_SCHEMA));
        let meshes = decode_scene(path, &scene[0].data).expect("decode");
        assert_eq!(meshes[0].faces, vec![[0, 1, 2]]);
        assert_eq!(meshes[0].positions[2], [0.0, 1.0, 0.5]);

        for cut in [bytes.len() - 1, bytes.len() / 2, 10] {
            let e = read_mcap(path, &bytes[..cut]).expect_err("truncated");
            assert!(e.to_string().contains("test.mcap"), "{e}");
        }
        // Every byte is covered by a magic or a CRC.
        for at in (0..bytes.len()).step_by(37) {
            let mut flipped = bytes.clone();
            flipped[at] ^= 0x5a;
            assert!(
                read_mcap(path, &flipped).is_err(),
                "flipped byte {at} not caught"
            );
        }
    }
}
