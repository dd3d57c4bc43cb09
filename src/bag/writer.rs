//! [`BagWriter`]: records ROS 2 messages into an MCAP file in the rosbag2 layout.

use super::metadata::{self, TopicFacts};
use super::{BagError, QosProfile, MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING};
use crate::msgs::{registry, RosMessage};
use mcap::records::{MessageHeader, Metadata};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Options of a new bag.
#[derive(Debug, Clone)]
pub struct BagWriterOptions {
    /// Compress chunks with zstd (as `ros2 bag record --storage-preset-profile zstd_fast`).
    pub zstd: bool,
    /// Target uncompressed chunk size in bytes; a killed recorder loses at most the open chunk.
    pub chunk_size: u64,
    /// ROS distribution written into the `rosbag2` metadata record.
    pub ros_distro: String,
    /// Close and flush the open chunk when it is older than this at a write, so a killed
    /// recorder loses at most about this much; `None`: only when the chunk is full.
    pub flush_interval: Option<Duration>,
}

impl Default for BagWriterOptions {
    fn default() -> Self {
        Self {
            zstd: true,
            chunk_size: 768 * 1024,
            ros_distro: "jazzy".into(),
            flush_interval: Some(Duration::from_secs(1)),
        }
    }
}

struct TopicState {
    channel_id: u16,
    type_name: String,
    qos_yaml: String,
    sequence: u32,
    count: u64,
}

/// Writes an MCAP bag that `ros2 bag`, Foxglove and rosbags can read. Topics are added on
/// first write (or with [`BagWriter::add_topic`] to set their QoS). Finishes on drop.
///
/// A path ending in `.mcap` gives a single file. Any other path is a rosbag2 bag directory,
/// as `ros2 bag record -o PATH -s mcap` makes: `PATH/<name>_0.mcap` plus `PATH/metadata.yaml`
/// written on finish.
pub struct BagWriter {
    path: PathBuf,
    metadata_yaml: Option<PathBuf>,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    ros_distro: String,
    topics: HashMap<String, TopicState>,
    topic_order: Vec<String>,
    schemas: HashMap<String, u16>,
    time_range: Option<(u64, u64)>,
    flush_interval: Option<Duration>,
    last_flush: Instant,
}

impl BagWriter {
    /// Creates (or truncates) the bag file at `path` with default options.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, BagError> {
        Self::create_with(path, BagWriterOptions::default())
    }

    /// Creates (or truncates) the bag at `path` (a `.mcap` file or a bag directory).
    pub fn create_with(
        path: impl AsRef<Path>,
        options: BagWriterOptions,
    ) -> Result<Self, BagError> {
        let (path, metadata_yaml) = Self::layout(path.as_ref())?;
        let file = File::create(&path).map_err(|source| BagError::Io {
            path: path.clone(),
            source,
        })?;
        let writer = mcap::WriteOptions::new()
            .profile(PROFILE)
            .library(concat!("lhmpp ", env!("CARGO_PKG_VERSION")))
            .compression(options.zstd.then_some(mcap::Compression::Zstd))
            .chunk_size(Some(options.chunk_size))
            .create(BufWriter::new(file))
            .map_err(|source| BagError::Mcap {
                path: path.clone(),
                source,
            })?;
        Ok(Self {
            path,
            metadata_yaml,
            writer: Some(writer),
            ros_distro: options.ros_distro,
            topics: HashMap::new(),
            topic_order: Vec::new(),
            schemas: HashMap::new(),
            time_range: None,
            flush_interval: options.flush_interval,
            last_flush: Instant::now(),
        })
    }

    /// The MCAP file and, for a bag directory, its `metadata.yaml`.
    fn layout(path: &Path) -> Result<(PathBuf, Option<PathBuf>), BagError> {
        let (file, yaml) = Self::files(path);
        if yaml.is_some() {
            std::fs::create_dir_all(path).map_err(|source| BagError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        }
        Ok((file, yaml))
    }

    /// The MCAP file a bag at `path` is written to and, for a bag directory, its
    /// `metadata.yaml`; creates nothing.
    pub(super) fn files(path: &Path) -> (PathBuf, Option<PathBuf>) {
        if path.extension().is_some_and(|e| e == "mcap") {
            return (path.to_path_buf(), None);
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_else(|| "bag".into());
        (
            path.join(format!("{name}_0.mcap")),
            Some(path.join("metadata.yaml")),
        )
    }

    /// The MCAP file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn mcap_err(&self, source: mcap::McapError) -> BagError {
        BagError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    fn writer(&mut self) -> Result<&mut mcap::Writer<BufWriter<File>>, BagError> {
        match self.writer.as_mut() {
            Some(w) => Ok(w),
            None => Err(BagError::Finished {
                path: self.path.clone(),
            }),
        }
    }

    /// Declares `topic` with its type (`pkg/msg/Type` or `pkg/Type`) and offered QoS. A topic
    /// added twice must keep its type; the first QoS stays.
    pub fn add_topic(
        &mut self,
        topic: &str,
        type_name: &str,
        qos: &QosProfile,
    ) -> Result<(), BagError> {
        let message_error = |source| BagError::Message {
            path: self.path.clone(),
            topic: topic.to_string(),
            source,
        };
        let (full_type, _) = registry::lookup(type_name).map_err(message_error)?;
        if let Some(existing) = self.topics.get(topic) {
            if existing.type_name != full_type {
                return Err(BagError::TopicTypeMismatch {
                    path: self.path.clone(),
                    topic: topic.to_string(),
                    existing: existing.type_name.clone(),
                    given: full_type.to_string(),
                });
            }
            return Ok(());
        }
        let schema_id = match self.schemas.get(full_type) {
            Some(id) => *id,
            None => {
                let schema = registry::ros2msg_schema(full_type).map_err(message_error)?;
                let id = self
                    .writer()?
                    .add_schema(full_type, SCHEMA_ENCODING, schema.as_bytes());
                let id = id.map_err(|e| self.mcap_err(e))?;
                self.schemas.insert(full_type.to_string(), id);
                id
            }
        };
        self.add_channel(topic, full_type, schema_id, qos.offered_profiles_yaml())
    }

    /// Declares `topic` as another bag holds it: its type name, `ros2msg` schema text and
    /// `offered_qos_profiles` YAML kept as they are (types this crate does not know too). A
    /// topic added twice keeps its first declaration.
    pub fn add_topic_as(
        &mut self,
        topic: &str,
        type_name: &str,
        schema: &str,
        qos_yaml: &str,
    ) -> Result<(), BagError> {
        if self.topics.contains_key(topic) {
            return Ok(());
        }
        let full_type = registry::full_type_name(type_name);
        let schema_id = match self.schemas.get(&full_type) {
            Some(id) => *id,
            None => {
                let id = self
                    .writer()?
                    .add_schema(&full_type, SCHEMA_ENCODING, schema.as_bytes());
                let id = id.map_err(|e| self.mcap_err(e))?;
                self.schemas.insert(full_type.clone(), id);
                id
            }
        };
        self.add_channel(topic, &full_type, schema_id, qos_yaml.to_string())
    }

    fn add_channel(
        &mut self,
        topic: &str,
        full_type: &str,
        schema_id: u16,
        qos_yaml: String,
    ) -> Result<(), BagError> {
        let channel_metadata = BTreeMap::from([("offered_qos_profiles".into(), qos_yaml.clone())]);
        let channel_id =
            self.writer()?
                .add_channel(schema_id, topic, MESSAGE_ENCODING, &channel_metadata);
        let channel_id = channel_id.map_err(|e| self.mcap_err(e))?;
        self.topics.insert(
            topic.to_string(),
            TopicState {
                channel_id,
                type_name: full_type.to_string(),
                qos_yaml,
                sequence: 0,
                count: 0,
            },
        );
        self.topic_order.push(topic.to_string());
        Ok(())
    }

    /// Writes a metadata record other than the `rosbag2` one, which [`BagWriter::finish`]
    /// writes (a record of that name is refused).
    pub fn write_metadata(
        &mut self,
        name: &str,
        entries: BTreeMap<String, String>,
    ) -> Result<(), BagError> {
        if name == metadata::RECORD_NAME {
            return Err(BagError::ReservedMetadata {
                path: self.path.clone(),
                name: name.into(),
            });
        }
        let record = Metadata {
            name: name.into(),
            metadata: entries,
        };
        let result = self.writer()?.write_metadata(&record);
        result.map_err(|e| self.mcap_err(e))
    }

    /// Records `message` on `topic` at `time_ns` (log and publish time, nanoseconds since the
    /// epoch).
    pub fn write<M: RosMessage>(
        &mut self,
        topic: &str,
        time_ns: u64,
        message: &M,
    ) -> Result<(), BagError> {
        self.write_raw(topic, M::TYPE_NAME, time_ns, &message.encode_cdr())
    }

    /// Records an already encoded CDR message (with its encapsulation header) of `type_name`.
    pub fn write_raw(
        &mut self,
        topic: &str,
        type_name: &str,
        time_ns: u64,
        cdr: &[u8],
    ) -> Result<(), BagError> {
        self.write_raw_at(topic, type_name, time_ns, time_ns, cdr)
    }

    /// Records an encoded CDR message with its own log and publish times (ns since the epoch).
    pub fn write_raw_at(
        &mut self,
        topic: &str,
        type_name: &str,
        log_time: u64,
        publish_time: u64,
        cdr: &[u8],
    ) -> Result<(), BagError> {
        let time_ns = log_time;
        if !self.topics.contains_key(topic) {
            self.add_topic(topic, type_name, &QosProfile::default())?;
        }
        let full_type = registry::full_type_name(type_name);
        let state = self.topics.get_mut(topic).expect("added above");
        if state.type_name != full_type {
            return Err(BagError::TopicTypeMismatch {
                path: self.path.clone(),
                topic: topic.to_string(),
                existing: state.type_name.clone(),
                given: full_type,
            });
        }
        let header = MessageHeader {
            channel_id: state.channel_id,
            sequence: state.sequence,
            log_time,
            publish_time,
        };
        state.sequence = state.sequence.wrapping_add(1);
        state.count += 1;
        self.time_range = Some(match self.time_range {
            None => (time_ns, time_ns),
            Some((start, end)) => (start.min(time_ns), end.max(time_ns)),
        });
        let result = self.writer()?.write_to_known_channel(&header, cdr);
        result.map_err(|e| self.mcap_err(e))?;
        if self
            .flush_interval
            .is_some_and(|interval| self.last_flush.elapsed() >= interval)
        {
            self.flush()?;
        }
        Ok(())
    }

    /// Closes the open chunk and flushes it to disk, so a crash after this loses nothing
    /// written before.
    pub fn flush(&mut self) -> Result<(), BagError> {
        self.last_flush = Instant::now();
        let result = self.writer()?.flush();
        result.map_err(|e| self.mcap_err(e))
    }

    /// Writes the `rosbag2` metadata record, the summary and the footer, and closes the file.
    /// Returns the number of messages written.
    pub fn finish(mut self) -> Result<u64, BagError> {
        self.finish_in_place()
    }

    fn finish_in_place(&mut self) -> Result<u64, BagError> {
        let file_name = self
            .path
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_default();
        let facts: Vec<TopicFacts> = self
            .topic_order
            .iter()
            .map(|name| {
                let t = &self.topics[name];
                TopicFacts {
                    name: name.clone(),
                    type_name: t.type_name.clone(),
                    qos_yaml: t.qos_yaml.clone(),
                    message_count: t.count,
                }
            })
            .collect();
        let count = facts.iter().map(|t| t.message_count).sum();
        let serialized =
            metadata::serialized_metadata(&file_name, &self.ros_distro, self.time_range, facts);
        if let Some(yaml_path) = &self.metadata_yaml {
            std::fs::write(yaml_path, &serialized).map_err(|source| BagError::Io {
                path: yaml_path.clone(),
                source,
            })?;
        }
        let record = Metadata {
            name: metadata::RECORD_NAME.into(),
            metadata: BTreeMap::from([
                ("serialized_metadata".into(), serialized),
                ("ROS_DISTRO".into(), self.ros_distro.clone()),
            ]),
        };
        let mut writer = self.writer.take().ok_or_else(|| BagError::Finished {
            path: self.path.clone(),
        })?;
        writer
            .write_metadata(&record)
            .and_then(|_| writer.finish().map(|_| ()))
            .map_err(|e| self.mcap_err(e))?;
        let mut inner = writer.into_inner();
        std::io::Write::flush(&mut inner).map_err(|source| BagError::Io {
            path: self.path.clone(),
            source,
        })?;
        Ok(count)
    }
}

impl Drop for BagWriter {
    fn drop(&mut self) {
        if self.writer.is_some() {
            if let Err(e) = self.finish_in_place() {
                tracing::warn!("closing bag on drop failed: {e}");
            }
        }
    }
}
