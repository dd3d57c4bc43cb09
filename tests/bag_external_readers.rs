//! A bag with every message type is read back by two independent Python readers
//! (`mcap_ros2` DecoderFactory and `rosbags` AnyReader) that decode every message and check
//! the field values we wrote. Needs `LHMPP_TEST_PYTHON` (set by `scripts/test`).

mod bag_support;

use lhmpp::bag::BagWriter;
use std::process::Command;

#[test]
fn python_readers_decode_every_message_type_with_the_values_written() {
    bag_support::python();
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("every_type");
    let mut writer = BagWriter::create(&bag).unwrap();
    let expected = bag_support::write_every_type(&mut writer, 3);
    writer.finish().unwrap();
    assert!(bag.join("metadata.yaml").is_file());
    assert!(bag.join("every_type_0.mcap").is_file());
    let size = std::fs::metadata(bag.join("every_type_0.mcap"))
        .unwrap()
        .len();
    println!("bag with 3 x 18 messages: {size} bytes");

    let info = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["bag", "info"])
        .arg(&bag)
        .output()
        .unwrap();
    let info_text = String::from_utf8_lossy(&info.stdout);
    println!("{info_text}");
    assert!(
        info.status.success(),
        "{}",
        String::from_utf8_lossy(&info.stderr)
    );
    assert!(info_text.contains("Messages:          54"), "{info_text}");
    assert!(info_text.contains("Compression:       zstd"), "{info_text}");
    assert_eq!(info_text.matches("Count: 3 |").count(), 18, "{info_text}");

    bag_support::check_with_python_readers(&bag, &expected);
}
