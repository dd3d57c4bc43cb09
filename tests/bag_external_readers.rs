//! A bag with every message type is read back by two independent Python readers
//! (`mcap_ros2` DecoderFactory and `rosbags` AnyReader) that decode every message and check
//! the field values we wrote. Needs `LHMPP_TEST_PYTHON` (set by `scripts/test`).

mod bag_support;

use lhmpp::bag::BagWriter;
use std::path::Path;
use std::process::Command;

fn python() -> String {
    std::env::var("LHMPP_TEST_PYTHON").unwrap_or_else(|_| {
        panic!(
            "LHMPP_TEST_PYTHON is not set: run the tests with `scripts/test`, which installs the \
             Python bag readers (scripts/setup-test-deps) and sets it"
        )
    })
}

#[test]
fn python_readers_decode_every_message_type_with_the_values_written() {
    let python = python();
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

    let expected_path = dir.path().join("expected.json");
    std::fs::write(
        &expected_path,
        serde_json::to_string_pretty(&expected).unwrap(),
    )
    .unwrap();

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_bag.py");
    let output = Command::new(&python)
        .arg(&script)
        .arg(&bag)
        .arg(&expected_path)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!("{stdout}");
    assert!(
        output.status.success() && stdout.contains("OK"),
        "check_bag.py rejected {}:\n{stdout}\n{stderr}",
        bag.display()
    );
}
