//! A bag cut short (a recorder killed mid-write) still opens: no panic, every message up to
//! the last complete chunk comes back intact, and the cut is reported with its byte offset.

mod bag_support;

use bag_support::numbered_image as image;
use lhmpp::bag::{BagReader, BagStream, BagWriter, BagWriterOptions};
use lhmpp::msgs::{Image, RosMessage};

const T0: u64 = 1_000_000_000;

/// Writes 40 images in 4 flushed chunks of 10; returns the bag bytes and the file size after
/// each flush (chunk boundaries).
fn chunked_bag(dir: &std::path::Path) -> (Vec<u8>, Vec<u64>) {
    let path = dir.join("full.mcap");
    let mut writer = BagWriter::create_with(&path, bag_support::flushed_chunks()).unwrap();
    let mut boundaries = Vec::new();
    for chunk in 0..4u32 {
        for k in 0..10u32 {
            let i = chunk * 10 + k;
            writer.write("/img", T0 + i as u64, &image(i)).unwrap();
        }
        writer.flush().unwrap();
        boundaries.push(std::fs::metadata(&path).unwrap().len());
    }
    writer.finish().unwrap();
    (std::fs::read(&path).unwrap(), boundaries)
}

fn read_cut(bytes: &[u8], cut: usize) -> BagReader {
    BagReader::from_bytes(format!("cut_at_{cut}.mcap").into(), &bytes[..cut])
        .unwrap_or_else(|e| panic!("cut at {cut}: {e}"))
}

#[test]
fn cut_bags_return_every_complete_chunk_intact_and_report_the_offset() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, boundaries) = chunked_bag(dir.path());
    // At each chunk boundary, and in the middle of each following chunk.
    for (complete_chunks, &end) in boundaries.iter().enumerate() {
        let complete_chunks = complete_chunks + 1;
        for cut in [end as usize, end as usize + 37] {
            if cut >= bytes.len() {
                continue;
            }
            let bag = read_cut(&bytes, cut);
            let truncation = bag
                .truncation()
                .expect("a cut bag is reported as truncated");
            assert_eq!(
                truncation.offset, end,
                "cut at {cut} stops at the chunk boundary"
            );
            let images = bag.read_topic::<Image>("/img").unwrap();
            assert_eq!(images.len(), 10 * complete_chunks, "cut at {cut}");
            for (i, (t, img)) in images.iter().enumerate() {
                assert_eq!(*t, T0 + i as u64);
                assert_eq!(*img, image(i as u32), "message {i} intact");
            }
        }
    }
}

#[test]
fn a_cut_in_the_middle_of_a_chunk_drops_only_that_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, boundaries) = chunked_bag(dir.path());
    let middle = ((boundaries[1] + boundaries[2]) / 2) as usize;
    let bag = read_cut(&bytes, middle);
    assert_eq!(bag.read_topic::<Image>("/img").unwrap().len(), 20);
    let truncation = bag.truncation().unwrap();
    assert_eq!(truncation.offset, boundaries[1]);
    assert!(truncation.reason.contains("needs"), "{}", truncation.reason);
}

#[test]
fn every_cut_offset_opens_without_panicking_and_never_invents_messages() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, _) = chunked_bag(dir.path());
    let full = BagReader::from_bytes("full.mcap".into(), &bytes).unwrap();
    assert!(full.truncation().is_none());
    assert_eq!(full.messages().len(), 40);
    let mut previous = 0;
    for cut in (0..bytes.len()).step_by(7) {
        match BagReader::from_bytes(format!("cut_{cut}.mcap").into(), &bytes[..cut]) {
            Err(e) => assert!(cut < 8, "only a cut inside the magic is an error: {e}"),
            Ok(bag) => {
                assert!(bag.truncation().is_some(), "cut at {cut} not reported");
                let n = bag.messages().len();
                assert!(n >= previous, "longer prefix, fewer messages at {cut}");
                previous = n;
                for m in bag.messages() {
                    Image::decode_cdr(&m.data).unwrap();
                }
            }
        }
    }
    assert_eq!(previous, 40, "the summary section holds no messages");
}

#[test]
fn a_corrupted_chunk_is_skipped_and_reading_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let (mut bytes, boundaries) = chunked_bag(dir.path());
    let inside_second_chunk = (boundaries[0] + boundaries[1]) as usize / 2;
    bytes[inside_second_chunk] ^= 0xFF;
    let bag = BagReader::from_bytes("corrupt.mcap".into(), &bytes).unwrap();
    let images = bag.read_topic::<Image>("/img").unwrap();
    assert_eq!(images.len(), 30, "chunks 1, 3 and 4");
    assert_eq!(images[10].1, image(20));
    assert!(bag.truncation().is_none());
    let skipped = &bag.salvage().skipped;
    assert_eq!(skipped.len(), 1);
    assert_eq!(skipped[0].offset, boundaries[0]);
    assert_eq!(skipped[0].messages, Some(10));
    assert!(skipped[0].reason.contains("chunk"), "{}", skipped[0].reason);
}

#[test]
fn a_recorder_that_dies_without_closing_keeps_everything_it_flushed() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.mcap");
    let options = BagWriterOptions {
        flush_interval: None,
        ..Default::default()
    };
    let mut writer = BagWriter::create_with(&path, options).unwrap();
    for i in 0..25u32 {
        writer.write("/img", T0 + i as u64, &image(i)).unwrap();
        if i == 14 {
            writer.flush().unwrap();
        }
    }
    // Like SIGKILL: no finish, no drop, the open chunk never reaches the file.
    std::mem::forget(writer);
    let bag = BagReader::open(&path).unwrap();
    let truncation = bag.truncation().expect("no footer");
    assert!(
        truncation.reason.contains("still being written")
            || truncation.reason.contains("no footer"),
        "{}",
        truncation.reason
    );
    let images = bag.read_topic::<Image>("/img").unwrap();
    assert_eq!(images.len(), 15);
    assert_eq!(images[14].1, image(14));
}

#[test]
fn a_flush_interval_bounds_what_a_killed_recorder_loses() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("interval.mcap");
    let options = BagWriterOptions {
        flush_interval: Some(std::time::Duration::ZERO),
        ..Default::default()
    };
    let mut writer = BagWriter::create_with(&path, options).unwrap();
    for i in 0..5u32 {
        writer.write("/img", T0 + i as u64, &image(i)).unwrap();
    }
    std::mem::forget(writer);
    let bag = BagReader::open(&path).unwrap();
    assert!(bag.truncation().is_some());
    assert_eq!(bag.read_topic::<Image>("/img").unwrap().len(), 5);
    assert_eq!(bag.chunk_count(), 5, "one chunk per flushed write");
}

#[test]
fn streaming_a_cut_bag_yields_what_the_reader_yields_and_reports_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, boundaries) = chunked_bag(dir.path());
    let full = dir.path().join("full.mcap");
    let streamed: Vec<_> = BagStream::open(&full).unwrap().collect();
    assert_eq!(streamed, BagReader::open(&full).unwrap().messages());
    assert_eq!(streamed.len(), 40);

    let cut_at = ((boundaries[2] + boundaries[3]) / 2) as usize;
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..cut_at]).unwrap();
    let mut stream = BagStream::open(&cut).unwrap();
    let messages: Vec<_> = stream.by_ref().collect();
    assert_eq!(messages, BagReader::open(&cut).unwrap().messages());
    assert_eq!(messages.len(), 30);
    assert_eq!(stream.truncation().unwrap().offset, boundaries[2]);
    for (i, m) in messages.iter().enumerate() {
        assert_eq!(Image::decode_cdr(&m.data).unwrap(), image(i as u32));
    }
}
