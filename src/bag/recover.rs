//! [`recover`]: writes every readable message of a damaged bag into a new, clean bag in the
//! rosbag2 layout, keeping its schemas, channels (with their QoS) and metadata records.

use super::damage::Salvage;
use super::metadata::RECORD_NAME;
use super::{BagError, BagReader, BagWriter, BagWriterOptions, QosProfile};
use std::path::{Path, PathBuf};

/// What [`recover`] read and wrote.
#[derive(Debug, Clone)]
pub struct Recovery {
    /// The MCAP file written.
    pub output: PathBuf,
    /// Messages written (every message read).
    pub messages: u64,
    /// Topics written.
    pub topics: usize,
    /// What reading the damaged bag skipped.
    pub salvage: Salvage,
}

/// Reads the bag at `input` with the salvaging reader and writes what it read to `output` (an
/// `.mcap` file or a bag directory): profile `ros2`, zstd chunks, the input's schemas, channels
/// and metadata records (the `rosbag2` record rewritten with the recovered counts), messages in
/// log-time order with their log and publish times. `progress(written, total)` is called every
/// `total / 100` messages and at the end. An `output` naming the input's file is refused.
pub fn recover(
    input: &Path,
    output: &Path,
    mut progress: impl FnMut(u64, u64),
) -> Result<Recovery, BagError> {
    let reader = BagReader::open(input)?;
    let (target, _) = BagWriter::files(output);
    if same_file(reader.path(), &target) {
        return Err(BagError::SameFile {
            path: reader.path().to_path_buf(),
        });
    }
    let mut writer = BagWriter::create_with(
        output,
        BagWriterOptions {
            flush_interval: None,
            ..Default::default()
        },
    )?;
    let default_qos = QosProfile::default().offered_profiles_yaml();
    for topic in reader.topics() {
        let qos = topic
            .offered_qos_profiles
            .as_deref()
            .unwrap_or(&default_qos);
        writer.add_topic_as(&topic.name, &topic.type_name, &topic.schema, qos)?;
    }
    for (name, entries) in reader.metadata() {
        if name != RECORD_NAME {
            writer.write_metadata(name, entries.clone())?;
        }
    }
    let total = reader.messages().len() as u64;
    let every = (total / 100).max(1);
    for (i, m) in reader.messages().iter().enumerate() {
        writer.write_raw_at(&m.topic, &m.type_name, m.log_time, m.publish_time, &m.data)?;
        let written = i as u64 + 1;
        if written % every == 0 || written == total {
            progress(written, total);
        }
    }
    let output = writer.path().to_path_buf();
    let messages = writer.finish()?;
    Ok(Recovery {
        output,
        messages,
        topics: reader.topics().len(),
        salvage: reader.salvage().clone(),
    })
}

/// True when both paths name one existing file (or `b` does not exist yet: false).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}
