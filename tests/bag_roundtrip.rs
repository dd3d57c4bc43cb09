//! Bags written by `BagWriter` read back by `BagReader`: rosbag2 layout (profile, encodings,
//! schemas with dependencies, QoS metadata, zstd, `rosbag2` record), counts, time order,
//! typed decoding.

mod bag_support;

use bag_support::T0;
use lhmpp::bag::{
    BagError, BagReader, BagWriter, BagWriterOptions, Durability, QosProfile, Reliability,
};
use lhmpp::msgs::registry::SCHEMA_SEPARATOR;
use lhmpp::msgs::*;

#[test]
fn every_type_comes_back_with_rosbag2_layout_and_counts() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("all.mcap");
    let mut writer = BagWriter::create(&path).unwrap();
    let expected = bag_support::write_every_type(&mut writer, 2);
    assert_eq!(writer.finish().unwrap(), 2 * 18);

    let bag = BagReader::open(&path).unwrap();
    assert!(bag.truncation().is_none());
    assert!(bag.is_ros2());
    assert_eq!(bag.profile(), "ros2");
    assert_eq!(bag.compression(), vec!["zstd".to_string()]);
    assert_eq!(bag.topics().len(), 18);
    for topic in bag.topics() {
        let want = &expected[&topic.name];
        assert_eq!(
            topic.type_name,
            want["type"].as_str().unwrap(),
            "{}",
            topic.name
        );
        assert_eq!(topic.message_count, 2, "{}", topic.name);
        assert_eq!(topic.schema_encoding, "ros2msg");
        assert_eq!(topic.message_encoding, "cdr");
        assert!(topic
            .offered_qos_profiles
            .as_deref()
            .unwrap()
            .contains("reliability: reliable"));
    }
    assert_eq!(bag.time_range(), Some((T0, T0 + 10_000_000)));
    let avatars = bag.read_topic::<GaussianAvatar>("/avatar").unwrap();
    assert_eq!(avatars.len(), 2);
    assert_eq!(avatars[0].1, bag_support::avatar());
    let rosbag2 = &bag.metadata()["rosbag2"];
    assert_eq!(rosbag2["ROS_DISTRO"], "jazzy");
    let yaml: serde_yaml_ng::Value =
        serde_yaml_ng::from_str(&rosbag2["serialized_metadata"]).unwrap();
    let info = &yaml["rosbag2_bagfile_information"];
    assert_eq!(info["message_count"].as_u64(), Some(36));
    assert_eq!(info["storage_identifier"].as_str(), Some("mcap"));
    assert_eq!(
        info["topics_with_message_count"]
            .as_sequence()
            .unwrap()
            .len(),
        18
    );
}

#[test]
fn schemas_carry_dependencies_as_rosbag2_writes_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tf.mcap");
    let mut writer = BagWriter::create(&path).unwrap();
    writer.write("/tf", T0, &TFMessage::default()).unwrap();
    writer.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    let schema = summary.schemas.values().next().unwrap();
    assert_eq!(schema.name, "tf2_msgs/msg/TFMessage");
    assert_eq!(schema.encoding, "ros2msg");
    let text = std::str::from_utf8(&schema.data).unwrap();
    assert!(text.starts_with(TFMessage::DEFINITION.trim_end()));
    assert!(text.contains(&format!(
        "{SCHEMA_SEPARATOR}\nMSG: builtin_interfaces/msg/Time\n"
    )));
    assert_eq!(text.matches(SCHEMA_SEPARATOR).count(), 6);
}

#[test]
fn messages_come_back_in_log_time_order_whatever_the_write_order() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("order.mcap");
    let mut writer = BagWriter::create(&path).unwrap();
    for (i, t) in [30u64, 10, 20, 10, 0].into_iter().enumerate() {
        let topic = if i % 2 == 0 { "/a" } else { "/b" };
        writer
            .write(
                topic,
                T0 + t,
                &Time {
                    sec: i as i32,
                    nanosec: 0,
                },
            )
            .unwrap();
    }
    writer.finish().unwrap();
    let bag = BagReader::open(&path).unwrap();
    let order: Vec<(u64, i32)> = bag
        .messages()
        .iter()
        .map(|m| (m.log_time - T0, bag.decode::<Time>(m).unwrap().sec))
        .collect();
    assert_eq!(order, vec![(0, 4), (10, 1), (10, 3), (20, 2), (30, 0)]);
}

#[test]
fn a_topic_keeps_one_type_and_typed_reads_check_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("types.mcap");
    let mut writer = BagWriter::create(&path).unwrap();
    let qos = QosProfile {
        reliability: Reliability::BestEffort,
        durability: Durability::TransientLocal,
        depth: 1,
    };
    writer
        .add_topic("/status", "lhmpp_msgs/ReconstructionStatus", &qos)
        .unwrap();
    writer
        .write("/status", T0, &ReconstructionStatus::default())
        .unwrap();
    let err = writer.write("/status", T0, &Time::default()).unwrap_err();
    assert!(matches!(err, BagError::TopicTypeMismatch { .. }), "{err}");
    let err = writer
        .write_raw("/x", "nav_msgs/msg/Odometry", T0, &[0, 1, 0, 0])
        .unwrap_err();
    assert!(err.to_string().contains("nav_msgs/msg/Odometry"), "{err}");
    writer.finish().unwrap();

    let bag = BagReader::open(&path).unwrap();
    let status = &bag.topics()[0];
    assert!(status
        .offered_qos_profiles
        .as_deref()
        .unwrap()
        .contains("transient_local"));
    let err = bag.read_topic::<Time>("/status").unwrap_err();
    assert!(
        err.to_string()
            .contains("lhmpp_msgs/msg/ReconstructionStatus"),
        "{err}"
    );
}

#[test]
fn dropping_the_writer_finishes_the_bag() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drop.mcap");
    {
        let mut writer = BagWriter::create_with(
            &path,
            BagWriterOptions {
                zstd: false,
                ..Default::default()
            },
        )
        .unwrap();
        writer
            .write("/t", T0, &Time { sec: 1, nanosec: 2 })
            .unwrap();
    }
    let bytes = std::fs::read(&path).unwrap();
    assert!(
        mcap::read::Summary::read(&bytes).unwrap().is_some(),
        "summary written on drop"
    );
    let bag = BagReader::open(&path).unwrap();
    assert!(bag.truncation().is_none());
    assert!(bag.compression().is_empty());
    assert_eq!(
        bag.read_topic::<Time>("/t").unwrap(),
        vec![(T0, Time { sec: 1, nanosec: 2 })]
    );
}

#[test]
fn non_mcap_files_are_rejected_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("not_a_bag.mcap");
    std::fs::write(&path, b"hello world, this is not mcap").unwrap();
    let err = BagReader::open(&path).unwrap_err();
    assert!(err.to_string().contains("not_a_bag.mcap"), "{err}");
    let err = BagReader::open(dir.path().join("missing.mcap")).unwrap_err();
    assert!(err.to_string().contains("missing.mcap"), "{err}");
}

#[test]
fn a_path_without_mcap_extension_becomes_a_rosbag2_bag_directory() {
    let dir = tempfile::tempdir().unwrap();
    let bag_dir = dir.path().join("session_1");
    let mut writer = BagWriter::create(&bag_dir).unwrap();
    writer
        .write("/t", T0, &Time { sec: 3, nanosec: 4 })
        .unwrap();
    writer
        .write("/t", T0 + 5, &Time { sec: 3, nanosec: 5 })
        .unwrap();
    writer.finish().unwrap();
    let yaml: serde_yaml_ng::Value =
        serde_yaml_ng::from_str(&std::fs::read_to_string(bag_dir.join("metadata.yaml")).unwrap())
            .unwrap();
    let info = &yaml["rosbag2_bagfile_information"];
    assert_eq!(info["version"].as_u64(), Some(9));
    assert_eq!(
        info["relative_file_paths"][0].as_str(),
        Some("session_1_0.mcap")
    );
    assert_eq!(info["duration"]["nanoseconds"].as_u64(), Some(5));
    assert_eq!(
        info["starting_time"]["nanoseconds_since_epoch"].as_u64(),
        Some(T0)
    );
    let bag = BagReader::open(&bag_dir).unwrap();
    assert!(bag.path().ends_with("session_1/session_1_0.mcap"));
    assert_eq!(bag.read_topic::<Time>("/t").unwrap().len(), 2);
}
