//! A record-by-record scan of an MCAP file's data section over any `Read + Seek`, expanding
//! chunks (decompressed, CRC-checked) and stopping cleanly at the first incomplete or
//! unreadable record, which it reports as a [`Truncation`].

use super::reader::Truncation;
use mcap::records::Record;
use std::collections::{BTreeSet, VecDeque};
use std::io::{Read, Seek, SeekFrom};

/// Opcodes that end the data section.
const DATA_END: u8 = 0x0F;
const FOOTER: u8 = 0x02;

/// Yields the records of the data section in file order (chunk contents in place of chunks).
pub(super) struct RecordScanner<R> {
    reader: R,
    pos: u64,
    len: u64,
    pending: VecDeque<Record<'static>>,
    finished: bool,
    /// Where and why the scan stopped early; set once the scan is over.
    pub truncation: Option<Truncation>,
    /// Chunk compressions seen.
    pub compression: BTreeSet<String>,
    /// Complete chunks read.
    pub chunk_count: usize,
}

impl<R: Read + Seek> RecordScanner<R> {
    /// Starts a scan of `len` bytes; `None` when they do not begin with the MCAP magic.
    pub fn new(mut reader: R, len: u64) -> Option<Self> {
        let mut magic = [0u8; 8];
        if len < 8 || reader.read_exact(&mut magic).is_err() || magic != mcap::MAGIC {
            return None;
        }
        Some(Self {
            reader,
            pos: 8,
            len,
            pending: VecDeque::new(),
            finished: false,
            truncation: None,
            compression: BTreeSet::new(),
            chunk_count: 0,
        })
    }

    fn stop(&mut self, reason: String) {
        self.finished = true;
        self.truncation = Some(Truncation {
            offset: self.pos,
            reason,
        });
    }

    fn tail_is_complete(&mut self, end: u64) -> bool {
        let mut magic = [0u8; 8];
        self.len >= end + 8
            && self.reader.seek(SeekFrom::Start(self.len - 8)).is_ok()
            && self.reader.read_exact(&mut magic).is_ok()
            && magic == mcap::MAGIC
    }

    /// Reads the next top-level record; `false` when the scan is over.
    fn advance(&mut self) -> bool {
        if self.finished {
            return false;
        }
        let remaining = self.len - self.pos;
        if remaining == 0 {
            self.stop("the file ends before the data section does (no footer)".into());
            return false;
        }
        if remaining < 9 {
            self.stop(format!("incomplete record header ({remaining} bytes)"));
            return false;
        }
        let mut head = [0u8; 9];
        if let Err(e) = self.reader.read_exact(&mut head) {
            self.stop(format!("read error: {e}"));
            return false;
        }
        let opcode = head[0];
        let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
        if len == u64::MAX {
            // The MCAP writer patches a chunk's length in when the chunk closes.
            self.stop(format!(
                "record with opcode 0x{opcode:02X} was still being written (length placeholder)"
            ));
            return false;
        }
        if len > remaining - 9 {
            self.stop(format!(
                "record with opcode 0x{opcode:02X} needs {len} bytes, {} left",
                remaining - 9
            ));
            return false;
        }
        let end = self.pos + 9 + len;
        if opcode == DATA_END || opcode == FOOTER {
            // Every message is in; a complete file still ends with footer and magic.
            if !self.tail_is_complete(end) {
                self.pos = end;
                self.stop("the data section is complete but the summary and footer are cut".into());
            }
            self.finished = true;
            return false;
        }
        let mut body = vec![0u8; len as usize];
        if let Err(e) = self.reader.read_exact(&mut body) {
            self.stop(format!("read error: {e}"));
            return false;
        }
        let record = match mcap::parse_record(opcode, &body) {
            Ok(record) => record,
            Err(e) => {
                self.stop(format!("malformed record 0x{opcode:02X}: {e}"));
                return false;
            }
        };
        if let Record::Chunk { header, data } = record {
            let compression = header.compression.clone();
            let records: Result<Vec<Record<'_>>, _> =
                mcap::read::ChunkReader::new(header, &data).and_then(|r| r.collect());
            match records {
                Ok(records) => {
                    self.pending
                        .extend(records.into_iter().map(Record::into_owned));
                    self.chunk_count += 1;
                    if !compression.is_empty() {
                        self.compression.insert(compression);
                    }
                }
                Err(e) => {
                    self.stop(format!("unreadable chunk: {e}"));
                    return false;
                }
            }
        } else {
            self.pending.push_back(record.into_owned());
        }
        self.pos = end;
        true
    }
}

impl<R: Read + Seek> Iterator for RecordScanner<R> {
    type Item = Record<'static>;

    fn next(&mut self) -> Option<Record<'static>> {
        loop {
            if let Some(record) = self.pending.pop_front() {
                return Some(record);
            }
            if !self.advance() {
                return None;
            }
        }
    }
}
