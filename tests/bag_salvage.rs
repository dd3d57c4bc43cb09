//! A 16-chunk bag with one unreadable chunk in the middle (bad CRC, bad compression, garbage
//! data, a length too large or too small) yields every message of the 15 intact chunks, with
//! its summary intact (resynced by record length or chunk index) and with summary and footer
//! cut off (resynced by record length or a scan for the next chunk); the skipped byte range
//! and, where the message index says, its message count are reported.

mod bag_support;

use bag_support::{
    chunk_index, chunked_image_bag, data_end, flip_chunk_crc, flushed_chunks, image_time,
    numbered_image,
};
use lhmpp::bag::{BagReader, BagStream, Resync};
use lhmpp::msgs::Image;
use mcap::records::ChunkIndex;

const CHUNKS: u32 = 16;
const PER_CHUNK: u32 = 4;
/// The damaged chunk.
const BAD: usize = 7;

#[derive(Debug, Clone, Copy)]
enum Damage {
    Crc,
    Compression,
    Data,
    LengthTooLarge,
    LengthTooSmall,
}

impl Damage {
    const ALL: [Damage; 5] = [
        Damage::Crc,
        Damage::Compression,
        Damage::Data,
        Damage::LengthTooLarge,
        Damage::LengthTooSmall,
    ];

    /// True when the chunk's own length stays sound.
    fn keeps_length(self) -> bool {
        matches!(self, Damage::Crc | Damage::Compression | Damage::Data)
    }

    fn apply(self, bytes: &mut [u8], chunk: &ChunkIndex) {
        let start = chunk.chunk_start_offset as usize;
        let body = start + 9;
        let put_len = |bytes: &mut [u8], len: u64| {
            bytes[start + 1..body].copy_from_slice(&len.to_le_bytes());
        };
        match self {
            Damage::Crc => flip_chunk_crc(bytes, chunk),
            Damage::Compression => {
                assert_eq!(&bytes[body + 32..body + 36], b"zstd");
                bytes[body + 35] = b'x';
            }
            Damage::Data => {
                let middle = start + chunk.chunk_length as usize / 2;
                bytes[middle..middle + 24].fill(0xAA);
            }
            Damage::LengthTooLarge => put_len(bytes, 1 << 40),
            Damage::LengthTooSmall => put_len(bytes, chunk.chunk_length - 9 - 50),
        }
    }
}

/// The messages of every chunk but [`BAD`], as written.
fn intact_images() -> Vec<(u64, Image)> {
    (0..CHUNKS * PER_CHUNK)
        .filter(|i| (i / PER_CHUNK) as usize != BAD)
        .map(|i| (image_time(i), numbered_image(i)))
        .collect()
}

fn check(name: &str, bytes: &[u8], index: &[ChunkIndex], damage: Damage, summary: bool) {
    let bag = BagReader::from_bytes(name.into(), bytes).unwrap();
    let images = bag.read_topic::<Image>("/img").unwrap();
    assert_eq!(images.len(), 60, "{name}: messages of the 15 intact chunks");
    assert!(
        images == intact_images(),
        "{name}: messages intact, in order"
    );
    assert_eq!(bag.chunk_count(), 15, "{name}");
    let salvage = bag.salvage();
    assert!(!bag.is_complete(), "{name}");
    assert_eq!(salvage.skipped.len(), 1, "{name}: {salvage:?}");
    let skipped = &salvage.skipped[0];
    let bad = &index[BAD];
    assert_eq!(skipped.offset, bad.chunk_start_offset, "{name}");
    let (end, resync, messages) = match (damage.keeps_length(), summary) {
        (true, _) => (
            bad.chunk_start_offset + bad.chunk_length,
            Resync::RecordLength,
            Some(4),
        ),
        (false, true) => (
            bad.chunk_start_offset + bad.chunk_length,
            Resync::ChunkIndex,
            Some(4),
        ),
        (false, false) => (index[BAD + 1].chunk_start_offset, Resync::Scan, None),
    };
    assert_eq!(
        (skipped.end, skipped.resync, skipped.messages),
        (end, resync, messages),
        "{name}: {skipped}"
    );
    if summary {
        assert_eq!(salvage.truncation, None, "{name}");
        assert_eq!(salvage.expected_messages, Some(64), "{name}");
    } else {
        let t = salvage.truncation.as_ref().expect("no footer");
        assert_eq!(t.offset, bytes.len() as u64, "{name}: {t:?}");
    }
    let file = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(file.path(), bytes).unwrap();
    let mut stream = BagStream::open(file.path()).unwrap();
    let streamed: Vec<_> = stream.by_ref().collect();
    assert_eq!(streamed, bag.messages(), "{name}: streamed as read");
    assert_eq!(stream.salvage(), salvage, "{name}");
}

#[test]
fn one_unreadable_chunk_in_sixteen_loses_only_its_own_messages() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, index) = chunked_image_bag(&dir.path().join("full.mcap"), CHUNKS, PER_CHUNK);
    let full = BagReader::from_bytes("full.mcap".into(), &bytes).unwrap();
    assert!(full.is_complete());
    assert_eq!(full.messages().len(), 64);
    let end = data_end(&bytes);
    for damage in Damage::ALL {
        let mut damaged = bytes.clone();
        damage.apply(&mut damaged, &index[BAD]);
        check(&format!("{damage:?}"), &damaged, &index, damage, true);
        let cut = &damaged[..end];
        check(
            &format!("{damage:?} without summary"),
            cut,
            &index,
            damage,
            false,
        );
    }
}

#[test]
fn two_damaged_chunks_in_a_row_are_one_skip_each_or_one_scan() {
    let dir = tempfile::tempdir().unwrap();
    let (mut bytes, index) = chunked_image_bag(&dir.path().join("two.mcap"), CHUNKS, PER_CHUNK);
    Damage::LengthTooLarge.apply(&mut bytes, &index[3]);
    Damage::Crc.apply(&mut bytes, &index[4]);
    let bag = BagReader::from_bytes("two.mcap".into(), &bytes).unwrap();
    assert_eq!(bag.messages().len(), 56);
    assert_eq!(bag.salvage().skipped.len(), 2);
    assert_eq!(bag.salvage().lost_messages(), (8, true));
    let end = data_end(&bytes);
    let cut = BagReader::from_bytes("two_cut.mcap".into(), &bytes[..end]).unwrap();
    assert_eq!(cut.messages().len(), 56);
    // The scan passes the bad-CRC chunk by, so both chunks are one range of unknown count.
    let skipped = &cut.salvage().skipped;
    assert_eq!(skipped.len(), 1, "{skipped:?}");
    assert_eq!(
        (skipped[0].offset, skipped[0].end),
        (index[3].chunk_start_offset, index[5].chunk_start_offset)
    );
}

#[test]
fn messages_on_a_channel_defined_in_the_lost_chunk_need_the_summary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("late.mcap");
    let mut writer = lhmpp::bag::BagWriter::create_with(&path, flushed_chunks()).unwrap();
    // Chunk 0: /img; chunk 1 defines /late (damaged below); chunk 2: /late again.
    for (chunk, topics) in [["/img", "/img"], ["/late", "/img"], ["/late", "/img"]]
        .iter()
        .enumerate()
    {
        for (k, topic) in topics.iter().enumerate() {
            let i = (chunk * 2 + k) as u32;
            writer
                .write(topic, image_time(i), &numbered_image(i))
                .unwrap();
        }
        writer.flush().unwrap();
    }
    writer.finish().unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let index = chunk_index(&bytes);
    Damage::Crc.apply(&mut bytes, &index[1]);
    let bag = BagReader::from_bytes("late.mcap".into(), &bytes).unwrap();
    assert_eq!(bag.messages().len(), 4, "the summary names /late");
    assert_eq!(bag.salvage().unknown_channel, 0);
    let end = data_end(&bytes);
    let cut = BagReader::from_bytes("late_cut.mcap".into(), &bytes[..end]).unwrap();
    assert_eq!(
        cut.messages().len(),
        3,
        "chunk 2's /late message has no channel"
    );
    assert_eq!(cut.salvage().unknown_channel, 1);
    assert!(cut.salvage().to_string().contains("dropped 1 messages"));
}
