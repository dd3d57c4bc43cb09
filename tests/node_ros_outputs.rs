//! Publishing without any reader: never an error (a full reliable window is back-pressure),
//! and misuse is reported with the offending camera. Loopback only, no peer needed.

use lhmpp::config::NodeConfig;
use lhmpp::msgs::{GaussianAvatar, ReconstructionStatus};
use lhmpp::node::ros::{rgb8_image, PublishOutcome, RosNode, RosNodeOptions};
use std::collections::BTreeMap;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn publishing_before_any_reader_is_not_an_error() {
    let cfg = NodeConfig {
        domain_id: 200 + (std::process::id() % 30) as i32,
        namespace: "/lhmpp_outputs_test".into(),
        ..NodeConfig::default()
    };
    let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None)
        .unwrap()
        .loopback_only();
    let (node, _rx) = RosNode::start(&opts).expect("node starts");
    assert_eq!(node.avatar_subscribers(), 0);
    let frame = image::RgbImage::new(16, 16);
    let mut outcomes = Vec::new();
    for revision in 1..=50u32 {
        let avatar = GaussianAvatar {
            person_id: "p".into(),
            revision,
            ..GaussianAvatar::default()
        };
        outcomes.push(
            node.publish_avatar(avatar)
                .expect("avatar publish is not an error"),
        );
        outcomes.push(
            node.publish_status(ReconstructionStatus::default())
                .expect("status publish is not an error"),
        );
        outcomes.push(
            node.publish_frame(0, rgb8_image(&frame, 0, "cam0"))
                .expect("frame publish is not an error"),
        );
    }
    let back_pressure = outcomes
        .iter()
        .filter(|o| **o == PublishOutcome::BackPressure)
        .count() as u64;
    assert_eq!(back_pressure, node.back_pressure_count());
    let e = node
        .publish_frame(3, rgb8_image(&frame, 0, "cam3"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("render camera 3") && e.contains("1 virtual cameras"),
        "{e}"
    );
    let stats = node.input_stats();
    assert!(stats.accepted.is_empty() && stats.rejected.is_empty());
    node.shutdown();
}
