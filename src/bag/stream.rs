//! [`BagStream`]: messages of a bag read lazily in file order, one chunk in memory at a time,
//! for replaying recordings too large to load whole.

use super::damage::{Salvage, Truncation};
use super::reader::{warn_damaged, BagMessage, BagReader};
use super::scan::RecordScanner;
use super::BagError;
use mcap::records::Record;
use std::collections::HashMap;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Iterates a bag's messages in file order (the recording order of a single recorder) without
/// loading the file; skips unreadable chunks and stops at the end of a cut bag, like
/// [`BagReader`].
pub struct BagStream {
    path: PathBuf,
    file_size: u64,
    scanner: RecordScanner<BufReader<File>>,
    schemas: HashMap<u16, Arc<str>>,
    channels: HashMap<u16, (Arc<str>, Arc<str>)>,
    yielded: usize,
    /// Messages dropped on unknown channels, added to the salvage at the end.
    unknown_channel: u64,
    warned: bool,
}

impl BagStream {
    /// Opens the bag at `path` (an MCAP file or a bag directory) for streaming.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let path = BagReader::mcap_file(path.as_ref())?;
        let io_error = |source| BagError::Io {
            path: path.clone(),
            source,
        };
        let file = File::open(&path).map_err(io_error)?;
        let file_size = file.metadata().map_err(io_error)?.len();
        let scanner = RecordScanner::new(BufReader::new(file), file_size)
            .ok_or_else(|| BagError::NotMcap { path: path.clone() })?;
        // The summary's channels, so messages after a skipped chunk that defined them read.
        let channels = scanner.summary.iter().flat_map(|s| s.channels.values());
        let channels = channels
            .map(|c| {
                let type_name = c.schema.as_ref().map_or("", |s| s.name.as_str());
                (c.id, (c.topic.as_str().into(), type_name.into()))
            })
            .collect();
        Ok(Self {
            path,
            file_size,
            scanner,
            schemas: HashMap::new(),
            channels,
            yielded: 0,
            unknown_channel: 0,
            warned: false,
        })
    }

    /// The topics and message types the bag's summary lists (empty for a bag cut before its
    /// summary), sorted by topic.
    pub fn summary_topics(&self) -> Vec<(String, String)> {
        let mut topics: Vec<(String, String)> = self
            .channels
            .values()
            .map(|(topic, type_name)| (topic.to_string(), type_name.to_string()))
            .collect();
        topics.sort();
        topics.dedup();
        topics
    }

    /// Where reading stopped in an incomplete bag; known once the iterator has ended.
    pub fn truncation(&self) -> Option<&Truncation> {
        self.scanner.salvage.truncation.as_ref()
    }

    /// What was skipped so far and where an incomplete bag ends; final once the iterator has
    /// ended.
    pub fn salvage(&self) -> &Salvage {
        &self.scanner.salvage
    }
}

impl Iterator for BagStream {
    type Item = BagMessage;

    fn next(&mut self) -> Option<BagMessage> {
        for record in self.scanner.by_ref() {
            match record {
                Record::Schema { header, .. } => {
                    self.schemas.insert(header.id, header.name.as_str().into());
                }
                Record::Channel(c) => {
                    let type_name = self.schemas.get(&c.schema_id).cloned();
                    let type_name = type_name.unwrap_or_else(|| Arc::from(""));
                    self.channels
                        .insert(c.id, (c.topic.as_str().into(), type_name));
                }
                Record::Message { header, data } => {
                    let Some((topic, type_name)) = self.channels.get(&header.channel_id) else {
                        tracing::debug!(
                            "bag {}: message on unknown channel {} skipped",
                            self.path.display(),
                            header.channel_id
                        );
                        self.unknown_channel += 1;
                        continue;
                    };
                    self.yielded += 1;
                    return Some(BagMessage {
                        topic: topic.clone(),
                        type_name: type_name.clone(),
                        log_time: header.log_time,
                        publish_time: header.publish_time,
                        data: data.into_owned(),
                    });
                }
                _ => {}
            }
        }
        if !self.warned {
            self.warned = true;
            self.scanner.salvage.unknown_channel += self.unknown_channel;
            warn_damaged(
                &self.path,
                &self.scanner.salvage,
                self.file_size,
                self.yielded,
            );
        }
        None
    }
}
