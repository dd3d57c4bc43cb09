//! The `rosbag2` metadata record that rosbag2's MCAP storage writes when it closes a bag: the
//! bag's `metadata.yaml` content (version 9, Jazzy) plus the ROS distribution.

use serde::Serialize;

/// Name of the MCAP metadata record rosbag2 writes.
pub const RECORD_NAME: &str = "rosbag2";

/// Per-topic facts for the metadata.
pub struct TopicFacts {
    /// Topic name.
    pub name: String,
    /// Full message type.
    pub type_name: String,
    /// `offered_qos_profiles` YAML.
    pub qos_yaml: String,
    /// Messages written.
    pub message_count: u64,
}

#[derive(Serialize)]
struct Document {
    rosbag2_bagfile_information: BagfileInformation,
}

#[derive(Serialize)]
struct BagfileInformation {
    version: u32,
    storage_identifier: &'static str,
    duration: Nanoseconds,
    starting_time: SinceEpoch,
    message_count: u64,
    topics_with_message_count: Vec<TopicWithCount>,
    compression_format: &'static str,
    compression_mode: &'static str,
    relative_file_paths: Vec<String>,
    files: Vec<FileInformation>,
    custom_data: Option<()>,
    ros_distro: String,
}

#[derive(Serialize)]
struct Nanoseconds {
    nanoseconds: u64,
}

#[derive(Serialize)]
struct SinceEpoch {
    nanoseconds_since_epoch: u64,
}

#[derive(Serialize)]
struct TopicWithCount {
    topic_metadata: TopicMetadata,
    message_count: u64,
}

#[derive(Serialize)]
struct TopicMetadata {
    name: String,
    #[serde(rename = "type")]
    type_name: String,
    serialization_format: &'static str,
    offered_qos_profiles: String,
}

#[derive(Serialize)]
struct FileInformation {
    path: String,
    starting_time: SinceEpoch,
    duration: Nanoseconds,
    message_count: u64,
}

/// The `serialized_metadata` YAML for a bag file named `file_name` whose messages span
/// `start..=end` nanoseconds.
pub fn serialized_metadata(
    file_name: &str,
    ros_distro: &str,
    time_range: Option<(u64, u64)>,
    topics: Vec<TopicFacts>,
) -> String {
    let (start, end) = time_range.unwrap_or((0, 0));
    let message_count = topics.iter().map(|t| t.message_count).sum();
    let document = Document {
        rosbag2_bagfile_information: BagfileInformation {
            version: 9,
            storage_identifier: "mcap",
            duration: Nanoseconds {
                nanoseconds: end - start,
            },
            starting_time: SinceEpoch {
                nanoseconds_since_epoch: start,
            },
            message_count,
            topics_with_message_count: topics
                .into_iter()
                .map(|t| TopicWithCount {
                    message_count: t.message_count,
                    topic_metadata: TopicMetadata {
                        name: t.name,
                        type_name: t.type_name,
                        serialization_format: super::MESSAGE_ENCODING,
                        offered_qos_profiles: t.qos_yaml,
                    },
                })
                .collect(),
            // rosbag2 leaves these empty for MCAP's own chunk compression.
            compression_format: "",
            compression_mode: "",
            relative_file_paths: vec![file_name.to_string()],
            files: vec![FileInformation {
                path: file_name.to_string(),
                starting_time: SinceEpoch {
                    nanoseconds_since_epoch: start,
                },
                duration: Nanoseconds {
                    nanoseconds: end - start,
                },
                message_count,
            }],
            custom_data: None,
            ros_distro: ros_distro.to_string(),
        },
    };
    serde_yaml_ng::to_string(&document).expect("plain structs serialise to YAML")
}
