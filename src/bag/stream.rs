//! [`BagStream`]: messages of a bag read lazily in file order, one chunk in memory at a time,
//! for replaying recordings too large to load whole.

use super::reader::{warn_truncated, BagMessage, BagReader, Truncation};
use super::scan::RecordScanner;
use super::BagError;
use mcap::records::Record;
use std::collections::HashMap;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Iterates a bag's messages in file order (the recording order of a single recorder) without
/// loading the file; stops at the first incomplete record of a cut bag, like [`BagReader`].
pub struct BagStream {
    path: PathBuf,
    file_size: u64,
    scanner: RecordScanner<BufReader<File>>,
    schemas: HashMap<u16, Arc<str>>,
    channels: HashMap<u16, (Arc<str>, Arc<str>)>,
    yielded: usize,
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
        Ok(Self {
            path,
            file_size,
            scanner,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            yielded: 0,
            warned: false,
        })
    }

    /// Where reading stopped in an incomplete bag; known once the iterator has ended.
    pub fn truncation(&self) -> Option<&Truncation> {
        self.scanner.truncation.as_ref()
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
                        tracing::warn!(
                            "bag {}: message on unknown channel {} skipped",
                            self.path.display(),
                            header.channel_id
                        );
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
            if let Some(t) = &self.scanner.truncation {
                warn_truncated(&self.path, t, self.file_size, self.yielded);
            }
        }
        None
    }
}
