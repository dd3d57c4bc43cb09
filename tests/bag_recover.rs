//! `lhmpp bag info` exit status (0 complete, 3 damaged, 1 unreadable) and `lhmpp bag recover`:
//! a damaged bag (one bad chunk of 16, summary and footer cut off) becomes a clean bag that
//! `bag info` reads complete with the 60 surviving messages, and that the Python `mcap_ros2`
//! and `rosbags` readers decode (`LHMPP_TEST_PYTHON`, set by `scripts/test`). The input is
//! never overwritten.

mod bag_support;

use bag_support::{chunked_image_bag, data_end, flip_chunk_crc, image_time, numbered_image};
use lhmpp::bag::BagReader;
use lhmpp::msgs::{Image, RosMessage};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn lhmpp(args: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(args)
        .output()
        .unwrap()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Runs `lhmpp bag recover INPUT -o OUTPUT`.
fn recover(input: &Path, output: &Path) -> Output {
    lhmpp(&[
        "bag".as_ref(),
        "recover".as_ref(),
        input,
        "-o".as_ref(),
        output,
    ])
}

/// A 16-chunk bag whose 8th chunk fails its CRC, cut at its data end (no summary, no footer).
fn damaged_bag(dir: &Path) -> PathBuf {
    let (mut bytes, index) = chunked_image_bag(&dir.join("full.mcap"), 16, 4);
    flip_chunk_crc(&mut bytes, &index[7]);
    let path = dir.join("damaged.mcap");
    std::fs::write(&path, &bytes[..data_end(&bytes)]).unwrap();
    path
}

#[test]
fn bag_info_exit_status_tells_complete_damaged_and_unreadable_apart() {
    let dir = tempfile::tempdir().unwrap();
    let damaged = damaged_bag(dir.path());
    let info = |bag: &Path| lhmpp(&["bag".as_ref(), "info".as_ref(), bag]);

    let out = info(&dir.path().join("full.mcap"));
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("Messages:          64"));

    let out = info(&damaged);
    let stdout = text(&out.stdout);
    println!("{stdout}{}", text(&out.stderr));
    assert_eq!(out.status.code(), Some(3), "{stdout}");
    assert!(stdout.contains("Messages:          60"), "{stdout}");
    assert!(stdout.contains("Count: 60"), "{stdout}");
    assert!(stdout.contains("Skipped:           bytes "), "{stdout}");
    assert!(
        stdout.contains("4 messages, resumed by record length"),
        "{stdout}"
    );
    assert!(
        stdout.contains("Damaged:           skipped 1 unreadable range"),
        "{stdout}"
    );
    assert!(text(&out.stderr).contains("is damaged"));

    let not_mcap = dir.path().join("not.mcap");
    std::fs::write(&not_mcap, b"this is not a bag").unwrap();
    let out = info(&not_mcap);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("not an MCAP file"));
}

#[test]
fn bag_recover_writes_a_clean_bag_and_never_overwrites_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let damaged = damaged_bag(dir.path());
    let before = std::fs::read(&damaged).unwrap();
    let out = recover(&damaged, &damaged);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("will not write"),
        "{}",
        text(&out.stderr)
    );
    assert_eq!(std::fs::read(&damaged).unwrap(), before, "input untouched");

    let recovered = dir.path().join("recovered");
    let out = recover(&damaged, &recovered);
    let stdout = text(&out.stdout);
    println!("{stdout}{}", text(&out.stderr));
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        stdout.contains("recovered 60 messages on 1 topics"),
        "{stdout}"
    );
    assert!(text(&out.stderr).contains("recovering: 60/60 messages"));

    let out = lhmpp(&["bag".as_ref(), "info".as_ref(), &recovered]);
    let info = text(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{info}");
    assert!(info.contains("Messages:          60"), "{info}");
    assert!(!info.contains("Skipped:"), "{info}");
    let bag = BagReader::open(&recovered).unwrap();
    assert!(bag.is_complete());
    assert_eq!(bag.metadata()["rosbag2"]["ROS_DISTRO"], "jazzy");
    let images = bag.read_topic::<Image>("/img").unwrap();
    let expected: Vec<_> = (0..64)
        .filter(|i| i / 4 != 7)
        .map(|i| (image_time(i), numbered_image(i)))
        .collect();
    assert!(images == expected, "recovered messages as written");
    let original = BagReader::open(dir.path().join("full.mcap")).unwrap();
    assert_eq!(bag.topics()[0].schema, original.topics()[0].schema);
    assert_eq!(
        bag.topics()[0].offered_qos_profiles,
        original.topics()[0].offered_qos_profiles
    );
}

#[test]
fn python_readers_decode_the_recovered_bag() {
    bag_support::python();
    let dir = tempfile::tempdir().unwrap();
    let damaged = damaged_bag(dir.path());
    let recovered = dir.path().join("recovered");
    let out = recover(&damaged, &recovered);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let first = numbered_image(0);
    let expected = serde_json::json!({"/img": {"type": Image::TYPE_NAME, "count": 60,
        "fields": {"height": 8, "encoding": "mono8", "data": first.data}}});
    bag_support::check_with_python_readers(&recovered, &expected);
}
