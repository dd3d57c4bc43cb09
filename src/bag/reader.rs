//! [`BagReader`]: opens an MCAP bag, lists its topics and yields its messages in log-time
//! order, recovering what it can from a file cut short by a killed recorder.
//!
//! The whole data section is scanned record by record (chunks decompressed and CRC-checked),
//! so a bag with no summary or footer reads like a complete one up to the first incomplete
//! record, and an unreadable chunk is skipped with reading going on after it. What was skipped
//! and where a cut file ends are its [`Salvage`], logged as warnings.

use super::damage::{Salvage, Truncation};
use super::scan::RecordScanner;
use super::{BagError, MESSAGE_ENCODING, PROFILE};
use crate::msgs::{registry, RosMessage};
use mcap::records::Record;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One topic of a bag.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    /// Topic name.
    pub name: String,
    /// Message type as recorded (schema name), e.g. `sensor_msgs/msg/Image`.
    pub type_name: String,
    /// Message encoding, `cdr` for ROS 2.
    pub message_encoding: String,
    /// Schema encoding, `ros2msg` for ROS 2.
    pub schema_encoding: String,
    /// The schema's definition text (`ros2msg`: the `.msg` with its dependencies); empty when
    /// the schema is unknown.
    pub schema: String,
    /// The `offered_qos_profiles` metadata, if recorded.
    pub offered_qos_profiles: Option<String>,
    /// Messages read on this topic.
    pub message_count: u64,
}

/// One recorded message: its topic, type, times and CDR payload.
#[derive(Debug, Clone, PartialEq)]
pub struct BagMessage {
    /// Topic name.
    pub topic: Arc<str>,
    /// Message type, e.g. `sensor_msgs/msg/Image`.
    pub type_name: Arc<str>,
    /// Time the recorder received it (ns since the epoch).
    pub log_time: u64,
    /// Time it was published (ns since the epoch).
    pub publish_time: u64,
    /// CDR bytes with the encapsulation header.
    pub data: Vec<u8>,
}

/// An opened bag, messages sorted by log time (records with equal times keep file order).
#[derive(Debug)]
pub struct BagReader {
    path: PathBuf,
    file_size: u64,
    profile: String,
    library: String,
    topics: Vec<TopicInfo>,
    messages: Vec<BagMessage>,
    compression: BTreeSet<String>,
    chunk_count: usize,
    metadata: BTreeMap<String, BTreeMap<String, String>>,
    salvage: Salvage,
}

/// Logs what reading a damaged bag skipped and where an incomplete one stopped, naming the
/// file and the byte offsets.
pub(super) fn warn_damaged(path: &Path, salvage: &Salvage, file_size: u64, messages: usize) {
    for s in &salvage.skipped {
        tracing::warn!("bag {}: skipped unreadable {s}", path.display());
    }
    if let Some(t) = &salvage.truncation {
        tracing::warn!(
            "bag {} is incomplete: stopped at byte {} of {file_size}: {}; read {messages} messages before it",
            path.display(),
            t.offset,
            t.reason,
        );
    }
    if !salvage.skipped.is_empty() || salvage.unknown_channel > 0 {
        tracing::warn!(
            "bag {}: {salvage}; read {messages} messages",
            path.display()
        );
    }
}

struct ChannelEntry {
    topic: Arc<str>,
    schema_id: u16,
    message_encoding: String,
    qos: Option<String>,
}

#[derive(Default)]
struct Scan {
    schemas: HashMap<u16, (String, String)>,
    channels: BTreeMap<u16, ChannelEntry>,
    /// (channel id, header, payload) in file order.
    messages: Vec<(u16, mcap::records::MessageHeader, Vec<u8>)>,
    profile: String,
    library: String,
    metadata: BTreeMap<String, BTreeMap<String, String>>,
}

impl Scan {
    /// Starts with the schemas and channels of the summary, so messages after a skipped chunk
    /// that defined them still read.
    fn seeded(summary: Option<&mcap::Summary>) -> Self {
        let mut scan = Self::default();
        for channel in summary.iter().flat_map(|s| s.channels.values()) {
            if let Some(schema) = &channel.schema {
                let text = String::from_utf8_lossy(&schema.data).into_owned();
                scan.schemas.insert(schema.id, (schema.name.clone(), text));
            }
            scan.take(Record::Channel(mcap::records::Channel {
                id: channel.id,
                schema_id: channel.schema.as_ref().map_or(0, |s| s.id),
                topic: channel.topic.clone(),
                message_encoding: channel.message_encoding.clone(),
                metadata: channel.metadata.clone(),
            }));
        }
        scan
    }

    fn take(&mut self, record: Record<'_>) {
        match record {
            Record::Header(h) => {
                self.profile = h.profile;
                self.library = h.library;
            }
            Record::Schema { header, data } => {
                let text = String::from_utf8_lossy(&data).into_owned();
                self.schemas.insert(header.id, (header.name, text));
            }
            Record::Channel(c) => {
                self.channels.insert(
                    c.id,
                    ChannelEntry {
                        topic: c.topic.as_str().into(),
                        schema_id: c.schema_id,
                        message_encoding: c.message_encoding,
                        qos: c.metadata.get("offered_qos_profiles").cloned(),
                    },
                );
            }
            Record::Message { header, data } => {
                self.messages
                    .push((header.channel_id, header, data.into_owned()))
            }
            Record::Metadata(m) => {
                self.metadata.insert(m.name, m.metadata);
            }
            _ => {}
        }
    }
}

impl BagReader {
    /// Opens and scans the bag at `path`: an MCAP file, or a rosbag2 bag directory holding
    /// one. A truncated bag opens with a warning; see [`BagReader::truncation`].
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let path = Self::mcap_file(path.as_ref())?;
        let bytes = std::fs::read(&path).map_err(|source| BagError::Io {
            path: path.clone(),
            source,
        })?;
        Self::from_bytes(path, &bytes)
    }

    /// The MCAP file of a bag path: the path itself, or the first `.mcap` in a directory.
    pub(super) fn mcap_file(path: &Path) -> Result<PathBuf, BagError> {
        if !path.is_dir() {
            return Ok(path.to_path_buf());
        }
        let io_error = |source| BagError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(path)
            .map_err(io_error)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
            .collect();
        files.sort();
        if files.len() > 1 {
            tracing::warn!(
                "bag {} has {} MCAP files; reading only {}",
                path.display(),
                files.len(),
                files[0].display()
            );
        }
        files.into_iter().next().ok_or_else(|| {
            io_error(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "no .mcap file in the bag directory",
            ))
        })
    }

    /// Scans an in-memory bag; `path` names it in messages.
    pub fn from_bytes(path: PathBuf, bytes: &[u8]) -> Result<Self, BagError> {
        let mut scanner = RecordScanner::new(Cursor::new(bytes), bytes.len() as u64)
            .ok_or_else(|| BagError::NotMcap { path: path.clone() })?;
        let mut scan = Scan::seeded(scanner.summary.as_ref());
        for record in scanner.by_ref() {
            scan.take(record);
        }
        let reader = Self::assemble(
            path,
            bytes.len() as u64,
            scan,
            scanner.compression,
            scanner.chunk_count,
            scanner.salvage,
        );
        let file_size = reader.file_size;
        warn_damaged(
            &reader.path,
            &reader.salvage,
            file_size,
            reader.messages.len(),
        );
        Ok(reader)
    }

    fn assemble(
        path: PathBuf,
        file_size: u64,
        mut scan: Scan,
        compression: BTreeSet<String>,
        chunk_count: usize,
        mut salvage: Salvage,
    ) -> Self {
        let mut counts: HashMap<u16, u64> = HashMap::new();
        let unknown: Arc<str> = Arc::from("");
        let types: HashMap<u16, Arc<str>> = scan
            .channels
            .iter()
            .map(|(id, c)| {
                let type_name = scan
                    .schemas
                    .get(&c.schema_id)
                    .map(|(name, _)| Arc::from(name.as_str()))
                    .unwrap_or_else(|| unknown.clone());
                (*id, type_name)
            })
            .collect();
        let mut messages = Vec::with_capacity(scan.messages.len());
        for (channel_id, header, data) in std::mem::take(&mut scan.messages) {
            let Some(channel) = scan.channels.get(&channel_id) else {
                tracing::debug!(
                    "bag {}: message on unknown channel {channel_id} skipped",
                    path.display()
                );
                salvage.unknown_channel += 1;
                continue;
            };
            *counts.entry(channel_id).or_default() += 1;
            messages.push(BagMessage {
                topic: channel.topic.clone(),
                type_name: types[&channel_id].clone(),
                log_time: header.log_time,
                publish_time: header.publish_time,
                data,
            });
        }
        messages.sort_by_key(|m| m.log_time);
        let topics = scan
            .channels
            .iter()
            .map(|(id, c)| TopicInfo {
                name: c.topic.to_string(),
                type_name: types[id].to_string(),
                message_encoding: c.message_encoding.clone(),
                schema_encoding: scan
                    .schemas
                    .get(&c.schema_id)
                    .map(|_| super::SCHEMA_ENCODING.to_string())
                    .unwrap_or_default(),
                schema: scan
                    .schemas
                    .get(&c.schema_id)
                    .map(|(_, text)| text.clone())
                    .unwrap_or_default(),
                offered_qos_profiles: c.qos.clone(),
                message_count: counts.get(id).copied().unwrap_or(0),
            })
            .collect();
        Self {
            path,
            file_size,
            profile: scan.profile,
            library: scan.library,
            topics,
            messages,
            compression,
            chunk_count,
            metadata: scan.metadata,
            salvage,
        }
    }

    /// The bag file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// File size in bytes.
    pub fn file_size(&self) -> u64 {
        self.file_size
    }

    /// MCAP profile (`ros2` for rosbag2 bags).
    pub fn profile(&self) -> &str {
        &self.profile
    }

    /// True when the profile is `ros2` and every topic is CDR.
    pub fn is_ros2(&self) -> bool {
        self.profile == PROFILE
            && self
                .topics
                .iter()
                .all(|t| t.message_encoding == MESSAGE_ENCODING)
    }

    /// Library that wrote the bag, as recorded in its header.
    pub fn library(&self) -> &str {
        &self.library
    }

    /// Topics in channel order.
    pub fn topics(&self) -> &[TopicInfo] {
        &self.topics
    }

    /// All messages, sorted by log time.
    pub fn messages(&self) -> &[BagMessage] {
        &self.messages
    }

    /// First and last log time, `None` for a bag without messages.
    pub fn time_range(&self) -> Option<(u64, u64)> {
        Some((
            self.messages.first()?.log_time,
            self.messages.last()?.log_time,
        ))
    }

    /// Chunk compressions used (`zstd`, `lz4`); empty when uncompressed.
    pub fn compression(&self) -> Vec<String> {
        self.compression.iter().cloned().collect()
    }

    /// Number of complete chunks read.
    pub fn chunk_count(&self) -> usize {
        self.chunk_count
    }

    /// Metadata records by name (rosbag2 writes `rosbag2`).
    pub fn metadata(&self) -> &BTreeMap<String, BTreeMap<String, String>> {
        &self.metadata
    }

    /// Where reading stopped in an incomplete bag; `None` for a complete one.
    pub fn truncation(&self) -> Option<&Truncation> {
        self.salvage.truncation.as_ref()
    }

    /// What reading skipped as unreadable and where an incomplete file ends.
    pub fn salvage(&self) -> &Salvage {
        &self.salvage
    }

    /// True when the whole bag was read: nothing skipped, nothing cut.
    pub fn is_complete(&self) -> bool {
        self.salvage.is_complete()
    }

    /// Decodes a message as `M`, checking the recorded type first.
    pub fn decode<M: RosMessage>(&self, message: &BagMessage) -> Result<M, BagError> {
        if registry::full_type_name(&message.type_name) != M::TYPE_NAME {
            return Err(BagError::WrongType {
                path: self.path.clone(),
                topic: message.topic.to_string(),
                bag_type: message.type_name.to_string(),
                requested: M::TYPE_NAME.into(),
            });
        }
        M::decode_cdr(&message.data).map_err(|source| BagError::Message {
            path: self.path.clone(),
            topic: message.topic.to_string(),
            source,
        })
    }

    /// The messages of one topic decoded as `M`, with their log times, in log-time order.
    pub fn read_topic<M: RosMessage>(&self, topic: &str) -> Result<Vec<(u64, M)>, BagError> {
        self.messages
            .iter()
            .filter(|m| &*m.topic == topic)
            .map(|m| Ok((m.log_time, self.decode::<M>(m)?)))
            .collect()
    }
}
