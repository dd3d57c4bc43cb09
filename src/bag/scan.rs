//! A record-by-record scan of an MCAP file's data section over any `Read + Seek`, expanding
//! chunks (decompressed, CRC-checked). An unreadable record (bad CRC, compression or length) is
//! skipped and reading goes on at the next readable one: after the chunk when its length is
//! sound, else at the next chunk of the summary's chunk index, else at the next chunk record a
//! byte scan finds ([`super::resync`]). Each skip is a [`Skipped`]; an incomplete file's end is a
//! [`Truncation`].

use super::damage::{Resync, Salvage, Skipped, Truncation};
use super::resync;
use mcap::records::{op, Record};
use std::collections::{BTreeSet, VecDeque};
use std::io::{Read, Seek, SeekFrom};

/// Record header: opcode and length.
const RECORD_HEAD: u64 = 9;

/// Yields the records of the data section in file order (chunk contents in place of chunks).
pub(super) struct RecordScanner<R> {
    reader: R,
    pos: u64,
    len: u64,
    pending: VecDeque<Record<'static>>,
    finished: bool,
    /// Message index records after a skipped chunk count its messages while this is set.
    counting: bool,
    /// The summary section, when the footer and summary could be read.
    pub summary: Option<mcap::Summary>,
    /// Where the data end record is, from the footer.
    data_end: Option<u64>,
    /// Chunk starts and lengths from the summary's chunk index, by offset.
    chunk_index: Vec<(u64, u64)>,
    /// What was skipped or cut; final once the scan is over.
    pub salvage: Salvage,
    /// Chunk compressions seen.
    pub compression: BTreeSet<String>,
    /// Complete chunks read.
    pub chunk_count: usize,
}

/// What the record at the scan position turned out to be.
enum Step {
    /// A readable record; the next one starts at the offset.
    Records(Vec<Record<'static>>, u64),
    /// The data section is over.
    End,
    /// An unreadable chunk whose length is sound: it ends at the offset.
    BadChunk(String, u64),
    /// An unreadable record of unknown extent.
    Bad(String),
    /// The file cannot be read on (an I/O error).
    Stop(String),
}

impl<R: Read + Seek> RecordScanner<R> {
    /// Starts a scan of `len` bytes; `None` when they do not begin with the MCAP magic.
    pub fn new(mut reader: R, len: u64) -> Option<Self> {
        let mut magic = [0u8; 8];
        if len < 8 || reader.read_exact(&mut magic).is_err() || magic != mcap::MAGIC {
            return None;
        }
        let data_end = resync::data_end(&mut reader, len);
        let summary = resync::read_summary(&mut reader, len);
        let mut chunk_index: Vec<(u64, u64)> = summary
            .iter()
            .flat_map(|s| &s.chunk_indexes)
            .map(|c| (c.chunk_start_offset, c.chunk_length))
            .filter(|&(start, length)| {
                start >= 8 && start.checked_add(length).is_some_and(|e| e <= len)
            })
            .collect();
        chunk_index.sort_unstable();
        reader.seek(SeekFrom::Start(8)).ok()?;
        let expected_messages = summary
            .as_ref()
            .and_then(|s| s.stats.as_ref())
            .map(|s| s.message_count);
        Some(Self {
            reader,
            pos: 8,
            len,
            pending: VecDeque::new(),
            finished: false,
            counting: false,
            summary,
            data_end,
            chunk_index,
            salvage: Salvage {
                expected_messages,
                ..Salvage::default()
            },
            compression: BTreeSet::new(),
            chunk_count: 0,
        })
    }

    fn stop(&mut self, offset: u64, reason: String) {
        self.finished = true;
        self.salvage.truncation = Some(Truncation { offset, reason });
    }

    fn tail_is_complete(&mut self, end: u64) -> bool {
        let mut magic = [0u8; 8];
        self.len >= end + 8
            && self.reader.seek(SeekFrom::Start(self.len - 8)).is_ok()
            && self.reader.read_exact(&mut magic).is_ok()
            && magic == mcap::MAGIC
    }

    /// Reads the record at the scan position.
    fn step(&mut self) -> Step {
        let remaining = self.len - self.pos;
        if remaining == 0 {
            return Step::Bad("the file ends before the data section does (no footer)".into());
        }
        if remaining < RECORD_HEAD {
            return Step::Bad(format!("incomplete record header ({remaining} bytes)"));
        }
        let mut head = [0u8; RECORD_HEAD as usize];
        if let Err(e) = self
            .reader
            .seek(SeekFrom::Start(self.pos))
            .and_then(|_| self.reader.read_exact(&mut head))
        {
            return Step::Stop(format!("read error: {e}"));
        }
        let opcode = head[0];
        let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
        if len == u64::MAX {
            // The MCAP writer patches a chunk's length in when the chunk closes.
            return Step::Bad(format!(
                "record with opcode 0x{opcode:02X} was still being written (length placeholder)"
            ));
        }
        if len > remaining - RECORD_HEAD {
            return Step::Bad(format!(
                "record with opcode 0x{opcode:02X} needs {len} bytes, {} left",
                remaining - RECORD_HEAD
            ));
        }
        let end = self.pos + RECORD_HEAD + len;
        if opcode != op::CHUNK
            && self
                .chunk_index
                .binary_search_by_key(&self.pos, |c| c.0)
                .is_ok()
        {
            return Step::Bad(format!(
                "the chunk index puts a chunk here, the record has opcode 0x{opcode:02X}"
            ));
        }
        if opcode == op::DATA_END || opcode == op::FOOTER {
            // Every message is in; a complete file still ends with footer and magic.
            if !self.tail_is_complete(end) {
                self.stop(
                    end,
                    "the data section is complete but the summary and footer are cut".into(),
                );
            }
            return Step::End;
        }
        let mut body = vec![0u8; len as usize];
        if let Err(e) = self.reader.read_exact(&mut body) {
            return Step::Stop(format!("read error: {e}"));
        }
        let record = match mcap::parse_record(opcode, &body) {
            Ok(record) => record,
            Err(e) => return Step::Bad(format!("malformed record 0x{opcode:02X}: {e}")),
        };
        let Record::Chunk { header, data } = record else {
            return Step::Records(vec![record.into_owned()], end);
        };
        // A chunk length damaged into another that still parses: the index knows the real one.
        let end = match self.chunk_index.binary_search_by_key(&self.pos, |c| c.0) {
            Ok(i) => self.pos + self.chunk_index[i].1.max(RECORD_HEAD),
            Err(_) => end,
        };
        let compression = header.compression.clone();
        let records = chunk_records(&header, &data);
        match records {
            Ok(records) => {
                self.chunk_count += 1;
                if !compression.is_empty() {
                    self.compression.insert(compression);
                }
                Step::Records(records, end)
            }
            Err(e) => Step::BadChunk(format!("unreadable chunk: {e}"), end),
        }
    }

    /// Records a skip of `[self.pos, end)` holding `messages` and resumes reading at `end`;
    /// `counting`: the message index records of a skipped chunk come next and count its
    /// messages.
    fn skip_to(
        &mut self,
        end: u64,
        reason: String,
        resync: Resync,
        messages: Option<u64>,
        counting: bool,
    ) {
        tracing::debug!(offset = self.pos, end, %resync, "skipping unreadable bytes: {reason}");
        self.salvage.skipped.push(Skipped {
            offset: self.pos,
            end,
            reason,
            messages,
            resync,
        });
        self.counting = counting;
        self.pos = end;
    }

    /// Finds the next readable record after an unreadable one of unknown extent at the scan
    /// position; stops the scan as truncated when there is none.
    fn resync(&mut self, reason: String) {
        let from = self.pos;
        let indexed = !self.chunk_index.is_empty();
        if let Some(&(_, length)) = self.chunk_index.iter().find(|c| c.0 == from) {
            // The damaged record is an indexed chunk (its length counts the record header):
            // its message index records follow it.
            let end = from + length.max(RECORD_HEAD);
            return self.skip_to(end, reason, Resync::ChunkIndex, None, true);
        }
        if let Some(&(next, _)) = self.chunk_index.iter().find(|c| c.0 > from) {
            // No chunk starts in the range (a message index record, say): no messages lost.
            return self.skip_to(next, reason, Resync::ChunkIndex, Some(0), false);
        }
        if !indexed {
            let limit = self.data_end.unwrap_or(self.len);
            if let Some(next) = resync::find_chunk(&mut self.reader, from + 1, limit) {
                return self.skip_to(next, reason, Resync::Scan, None, false);
            }
        }
        match self.data_end {
            Some(end) if end > from => {
                let messages = indexed.then_some(0);
                self.skip_to(end, reason, Resync::DataEnd, messages, false)
            }
            _ => self.stop(from, reason),
        }
    }

    /// Reads the next top-level record; `false` when the scan is over.
    fn advance(&mut self) -> bool {
        if self.finished {
            return false;
        }
        match self.step() {
            Step::Records(records, end) => {
                for record in records {
                    match &record {
                        Record::MessageIndex(index) if self.counting => {
                            if let Some(last) = self.salvage.skipped.last_mut() {
                                *last.messages.get_or_insert(0) += index.records.len() as u64;
                            }
                        }
                        Record::MessageIndex(_) => {}
                        _ => {
                            self.counting = false;
                            self.pending.push_back(record);
                        }
                    }
                }
                self.pos = end;
            }
            Step::End => self.finished = true,
            Step::BadChunk(reason, end) => {
                self.skip_to(end, reason, Resync::RecordLength, None, true)
            }
            Step::Bad(reason) => self.resync(reason),
            Step::Stop(reason) => self.stop(self.pos, reason),
        }
        !self.finished || !self.pending.is_empty()
    }
}

impl<R: Read + Seek> Iterator for RecordScanner<R> {
    type Item = Record<'static>;

    fn next(&mut self) -> Option<Record<'static>> {
        loop {
            if let Some(record) = self.pending.pop_front() {
                return Some(record);
            }
            if !self.advance() && self.pending.is_empty() {
                return None;
            }
        }
    }
}

/// The records of a chunk: decompressed here (the output bounded by the declared size),
/// checked against the declared size and CRC, then split with every record length checked
/// against what is left. (The `mcap` crate's chunk reader aborts the process on a damaged
/// chunk that declares a huge record or size, and panics on others: found by `lhmpp fuzz
/// mcap`.)
pub(super) fn chunk_records(
    header: &mcap::records::ChunkHeader,
    data: &[u8],
) -> Result<Vec<Record<'static>>, String> {
    let declared = header.uncompressed_size;
    if let Some(reason) = implausible_chunk_size(&header.compression, data.len(), declared) {
        return Err(reason);
    }
    let bytes: std::borrow::Cow<'_, [u8]> = match header.compression.as_str() {
        "" => data.into(),
        "zstd" => {
            let decoder =
                zstd::stream::read::Decoder::new(data).map_err(|e| format!("zstd: {e}"))?;
            read_bounded(decoder, declared)
                .map_err(|e| format!("zstd: {e}"))?
                .into()
        }
        "lz4" => {
            let decoder = lz4::Decoder::new(data).map_err(|e| format!("lz4: {e}"))?;
            read_bounded(decoder, declared)
                .map_err(|e| format!("lz4: {e}"))?
                .into()
        }
        other => return Err(format!("unsupported compression `{other}`")),
    };
    if bytes.len() as u64 != declared {
        return Err(format!(
            "decompressed to {}{} bytes, the header declares {declared}",
            if bytes.len() as u64 > declared {
                "more than "
            } else {
                ""
            },
            bytes.len().min(declared as usize)
        ));
    }
    let crc = header.uncompressed_crc;
    if crc != 0 && crc32fast::hash(&bytes) != crc {
        return Err(format!("CRC mismatch (the header says {crc:#010x})"));
    }
    let mut records = Vec::new();
    let mut pos = 0usize;
    while pos < bytes.len() {
        let left = bytes.len() - pos;
        if left < RECORD_HEAD as usize {
            return Err(format!("{left} stray bytes at the chunk's end"));
        }
        let opcode = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().expect("8 bytes"));
        let body_left = (left - RECORD_HEAD as usize) as u64;
        if len > body_left {
            return Err(format!(
                "record 0x{opcode:02X} of {len} bytes overruns the chunk ({body_left} left)"
            ));
        }
        let body = &bytes[pos + 9..pos + 9 + len as usize];
        let record = mcap::parse_record(opcode, body)
            .map_err(|e| format!("malformed record 0x{opcode:02X} in the chunk: {e}"))?;
        records.push(record.into_owned());
        pos += 9 + len as usize;
    }
    Ok(records)
}

/// Reads `reader` to its end, but at most `limit + 1` bytes (one more shows an overrun).
fn read_bounded(reader: impl Read, limit: u64) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::with_capacity(limit as usize);
    reader.take(limit + 1).read_to_end(&mut out)?;
    Ok(out)
}

/// Largest uncompressed chunk read (the `mcap` crate allocates the declared size up front, and
/// a failed allocation aborts the process).
const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// Largest compression ratio believed for a compressed chunk.
const MAX_CHUNK_RATIO: u64 = 1024;

/// Why a chunk's declared uncompressed size cannot be right, if it cannot: a stored chunk
/// whose two sizes differ, a size over [`MAX_CHUNK_BYTES`], or a ratio over
/// [`MAX_CHUNK_RATIO`].
fn implausible_chunk_size(compression: &str, stored: usize, uncompressed: u64) -> Option<String> {
    let stored = stored as u64;
    if compression.is_empty() && stored != uncompressed {
        Some(format!(
            "an uncompressed chunk of {stored} bytes declares {uncompressed}"
        ))
    } else if uncompressed > MAX_CHUNK_BYTES {
        Some(format!(
            "declares {uncompressed} uncompressed bytes, over the {MAX_CHUNK_BYTES}-byte limit"
        ))
    } else if uncompressed > stored.saturating_mul(MAX_CHUNK_RATIO).max(1 << 20) {
        Some(format!(
            "declares {uncompressed} uncompressed bytes from {stored} {compression} bytes"
        ))
    } else {
        None
    }
}

#[cfg(test)]
mod chunk_tests {
    use super::*;
    use mcap::records::ChunkHeader;

    fn header(compression: &str, uncompressed_size: u64) -> ChunkHeader {
        ChunkHeader {
            message_start_time: 0,
            message_end_time: 0,
            uncompressed_size,
            uncompressed_crc: 0,
            compression: compression.into(),
            compressed_size: 0,
        }
    }

    /// One record of `opcode` whose length field says `len`, followed by `body`.
    fn record(opcode: u8, len: u64, body: &[u8]) -> Vec<u8> {
        let mut out = vec![opcode];
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(body);
        out
    }

    #[test]
    fn damaged_chunks_are_errors_not_panics_or_huge_allocations() {
        // A record inside the chunk that claims more bytes than the chunk holds (the mcap
        // crate reserves the claimed size and aborts).
        let data = record(op::MESSAGE, u64::MAX / 3, &[0; 16]);
        let err = chunk_records(&header("", data.len() as u64), &data).unwrap_err();
        assert!(err.contains("overruns the chunk"), "{err}");
        // A stored chunk whose two sizes disagree.
        let err = chunk_records(&header("", 999), &data).unwrap_err();
        assert!(err.contains("declares 999"), "{err}");
        // A compressed chunk declaring far more than it can hold.
        let err = chunk_records(&header("zstd", 1 << 40), &data).unwrap_err();
        assert!(err.contains("limit"), "{err}");
        // Stray bytes after the last record.
        let mut data = record(op::MESSAGE_INDEX, 6, &[0; 6]);
        data.extend_from_slice(&[1, 2, 3]);
        let err = chunk_records(&header("", data.len() as u64), &data).unwrap_err();
        assert!(err.contains("stray bytes"), "{err}");
    }

    #[test]
    fn a_zstd_chunk_round_trips_and_a_wrong_crc_is_caught() {
        // A message index record for channel 1 with no entries: 2 + 4 bytes.
        let raw = record(op::MESSAGE_INDEX, 6, &[1, 0, 0, 0, 0, 0]);
        let packed = zstd::encode_all(&raw[..], 3).unwrap();
        let mut good = header("zstd", raw.len() as u64);
        good.uncompressed_crc = crc32fast::hash(&raw);
        assert_eq!(chunk_records(&good, &packed).unwrap().len(), 1);
        good.uncompressed_crc ^= 1;
        let err = chunk_records(&good, &packed).unwrap_err();
        assert!(err.contains("CRC mismatch"), "{err}");
    }
}
