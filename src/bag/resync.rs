//! Finding readable records again in a damaged MCAP file: the footer's data end, the summary
//! (chunk index, schemas, channels, statistics) read with the `mcap` crate's summary reader,
//! and a byte scan for the next chunk record that parses, decompresses and passes its CRC.

use mcap::records::{op, Record};
use mcap::sans_io::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use std::io::{Read, Seek, SeekFrom};

/// Footer record (opcode, length, 20-byte body) and closing magic.
const FOOTER_AND_MAGIC: u64 = 1 + 8 + 20 + 8;
/// Data end record: opcode, length, CRC.
const DATA_END_LEN: u64 = 1 + 8 + 4;
/// Chunk body bytes before the compression name: start and end time, uncompressed size, CRC.
const CHUNK_FIXED: usize = 8 + 8 + 8 + 4;
/// Bytes read at a candidate chunk before its whole body: header, fixed fields, name length.
const CANDIDATE_HEAD: usize = 9 + CHUNK_FIXED + 4;
/// Bytes searched at a time.
const BLOCK: usize = 1 << 20;

/// Offset of the data end record, from an intact footer (`None` without one).
pub(super) fn data_end<R: Read + Seek>(reader: &mut R, len: u64) -> Option<u64> {
    if len < 8 + DATA_END_LEN + FOOTER_AND_MAGIC {
        return None;
    }
    let footer_at = len - FOOTER_AND_MAGIC;
    let mut tail = [0u8; FOOTER_AND_MAGIC as usize];
    reader.seek(SeekFrom::Start(footer_at)).ok()?;
    reader.read_exact(&mut tail).ok()?;
    if tail[0] != op::FOOTER || &tail[29..] != mcap::MAGIC {
        return None;
    }
    let Ok(Record::Footer(footer)) = mcap::parse_record(op::FOOTER, &tail[9..29]) else {
        return None;
    };
    let summary_or_footer = match footer.summary_start {
        0 => footer_at,
        start => start,
    };
    let at = summary_or_footer
        .checked_sub(DATA_END_LEN)
        .filter(|&at| at >= 8)?;
    let mut opcode = [0u8; 1];
    reader.seek(SeekFrom::Start(at)).ok()?;
    reader.read_exact(&mut opcode).ok()?;
    (opcode[0] == op::DATA_END).then_some(at)
}

/// The summary section, read with the `mcap` crate's summary reader; `None` when the file has
/// none or it does not read.
pub(super) fn read_summary<R: Read + Seek>(reader: &mut R, len: u64) -> Option<mcap::Summary> {
    let options = SummaryReaderOptions::default().with_file_size(len);
    let mut summary = SummaryReader::new_with_options(options);
    while let Some(event) = summary.next_event() {
        match event {
            Ok(SummaryReadEvent::ReadRequest(n)) => {
                let read = reader.read(summary.insert(n)).ok()?;
                summary.notify_read(read);
            }
            Ok(SummaryReadEvent::SeekRequest(to)) => {
                let pos = reader.seek(to).ok()?;
                summary.notify_seeked(pos);
            }
            Err(e) => {
                tracing::debug!("MCAP summary unreadable: {e}");
                return None;
            }
        }
    }
    summary.finish()
}

/// Offset of the first chunk record in `[from, limit)` that parses, decompresses and passes
/// its CRC.
pub(super) fn find_chunk<R: Read + Seek>(reader: &mut R, from: u64, limit: u64) -> Option<u64> {
    let mut block = vec![0u8; BLOCK];
    let mut at = from;
    while at + 9 <= limit {
        let n = ((limit - at) as usize).min(BLOCK);
        reader.seek(SeekFrom::Start(at)).ok()?;
        reader.read_exact(&mut block[..n]).ok()?;
        for i in (0..n).filter(|&i| block[i] == op::CHUNK) {
            if chunk_at(reader, at + i as u64, limit) {
                return Some(at + i as u64);
            }
        }
        at += n as u64;
    }
    None
}

/// True when a whole readable chunk record starts at `at` and ends by `limit`.
fn chunk_at<R: Read + Seek>(reader: &mut R, at: u64, limit: u64) -> bool {
    let mut head = [0u8; CANDIDATE_HEAD];
    if at + CANDIDATE_HEAD as u64 > limit
        || reader.seek(SeekFrom::Start(at)).is_err()
        || reader.read_exact(&mut head).is_err()
    {
        return false;
    }
    let len = u64::from_le_bytes(head[1..9].try_into().expect("8 bytes"));
    let name_len = u32::from_le_bytes(head[9 + CHUNK_FIXED..].try_into().expect("4 bytes"));
    // Cheap tests first: the record fits, and its compression name is a short one.
    if len > limit - at - 9 || name_len > 16 || (len as usize) < CHUNK_FIXED + 4 + 8 {
        return false;
    }
    let mut body = vec![0u8; len as usize];
    if reader.seek(SeekFrom::Start(at + 9)).is_err() || reader.read_exact(&mut body).is_err() {
        return false;
    }
    match mcap::parse_record(op::CHUNK, &body) {
        Ok(Record::Chunk { header, data }) => super::scan::chunk_records(&header, &data).is_ok(),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    fn bag(chunks: u64) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        let mut writer = mcap::WriteOptions::new()
            .chunk_size(None)
            .create(&mut out)
            .unwrap();
        let channel = writer
            .add_channel(0, "/t", "cdr", &Default::default())
            .unwrap();
        for i in 0..chunks {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            writer.write_to_known_channel(&header, &[7; 64]).unwrap();
            writer.flush().unwrap();
        }
        writer.finish().unwrap();
        drop(writer);
        out.into_inner()
    }

    #[test]
    fn the_scan_finds_each_chunk_and_the_footer_gives_the_data_end() {
        let bytes = bag(3);
        let len = bytes.len() as u64;
        let mut reader = Cursor::new(&bytes);
        let summary = read_summary(&mut reader, len).unwrap();
        let mut starts: Vec<u64> = summary
            .chunk_indexes
            .iter()
            .map(|c| c.chunk_start_offset)
            .collect();
        starts.sort();
        assert_eq!(starts.len(), 3);
        assert_eq!(find_chunk(&mut reader, 8, len), Some(starts[0]));
        assert_eq!(find_chunk(&mut reader, starts[0] + 1, len), Some(starts[1]));
        assert_eq!(find_chunk(&mut reader, starts[2] + 1, len), None);
        let end = data_end(&mut reader, len).unwrap();
        assert_eq!(bytes[end as usize], op::DATA_END);
        assert!(end > starts[2]);
        // A cut file has no footer, so neither data end nor summary.
        let cut = &bytes[..bytes.len() - 3];
        let mut reader = Cursor::new(cut);
        assert_eq!(data_end(&mut reader, cut.len() as u64), None);
        assert!(read_summary(&mut reader, cut.len() as u64).is_none());
    }
}
