//! Publishing without any reader: never an error (a full reliable window is back-pressure, a
//! latched output holds its newest message), misuse is reported with the offending camera, a
//! late subscriber gets the newest latched message, and every output reaches the subscribers
//! its QoS promises. Loopback only, no peer needed.

mod dds_domain;

use lhmpp::config::NodeConfig;
use lhmpp::msgs::{GaussianAvatar, ReconstructionStatus};
use lhmpp::node::ros::{rgb8_image, PublishOutcome, RosNode, RosNodeOptions};
use std::collections::BTreeMap;

/// Starts the node, loopback only, on this process's domain for `salt` (`dds_domain`).
fn start_node(salt: u32, namespace: &str) -> (RosNode, RosNodeOptions) {
    let cfg = NodeConfig {
        domain_id: i32::from(dds_domain::test_domain(salt)),
        namespace: namespace.into(),
        ..NodeConfig::default()
    };
    let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None)
        .unwrap()
        .loopback_only();
    let (node, _rx) = RosNode::start(&opts).expect("node starts");
    (node, opts)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn publishing_before_any_reader_is_not_an_error() {
    let (node, _) = start_node(30, "/lhmpp_outputs_test");
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

/// A two-worker runtime for the node's tasks (enter it before starting the node).
fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

/// A node of the test's own DDS participant (`ctx`), without rosout.
fn peer_node(ctx: &ros2_client::Context, name: &str) -> ros2_client::Node {
    ctx.new_node(
        ros2_client::NodeName::new("/", name).unwrap(),
        ros2_client::NodeOptions::new().enable_rosout(false),
    )
    .unwrap()
}

/// What one probe subscription received.
struct Probe<M: 'static> {
    what: String,
    sub: ros2_client::dds::Subscription<M>,
    received: usize,
}

fn probe<M>(
    node: &mut ros2_client::dds::Node,
    topic: &str,
    type_name: (&str, &str),
    reliable: bool,
) -> Probe<M>
where
    M: serde::de::DeserializeOwned + 'static,
{
    use ros2_client::qos::{History, QosProfile, Reliability, WhenFull};
    let qos = QosProfile::subscription_default()
        .history(History::KeepLast { depth: 10 })
        .reliability(if reliable {
            Reliability::Reliable {
                when_full: WhenFull::DEFAULT,
            }
        } else {
            Reliability::BestEffort
        });
    let (ns, base) = topic.rsplit_once('/').unwrap();
    let name = ros2_client::Name::new(if ns.is_empty() { "/" } else { ns }, base).unwrap();
    let t = node
        .create_topic(
            &name,
            ros2_client::MessageTypeName::new(type_name.0, type_name.1),
            &qos,
        )
        .unwrap();
    Probe {
        what: format!(
            "{topic} ({})",
            if reliable { "reliable" } else { "best effort" }
        ),
        sub: node.create_subscription::<M>(&t, Some(qos)).unwrap(),
        received: 0,
    }
}

impl<M: serde::de::DeserializeOwned + 'static> Probe<M> {
    fn poll(&mut self) {
        while let Ok(Some(_)) = self.sub.take() {
            self.received += 1;
        }
    }
}

/// Starts the node with `frame_qos`, subscribes to every output with a reliable and a
/// best-effort probe (volatile: what `ros2 topic echo` and RViz2 ask for), publishes until every
/// probe that should match has received something; returns (probe, received) pairs.
fn receive_outputs(frame_qos: &str, namespace: &str, domain: i32) -> Vec<(String, usize)> {
    let runtime = runtime();
    let _guard = runtime.enter();
    let cfg = NodeConfig::from_yaml(
        "lhmpp:\n  ros__parameters: {}\n",
        "<test>".as_ref(),
        &[
            format!("domain_id={domain}"),
            format!("namespace={namespace}"),
            format!("outputs.frame_qos={frame_qos}"),
        ],
    )
    .unwrap();
    let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None)
        .unwrap()
        .loopback_only();
    let (node, _rx) = RosNode::start(&opts).expect("node starts");
    let topics = node.topics().clone();

    let peer_ctx = lhmpp::node::ros::create_context(&opts.participant).unwrap();
    let mut peer = peer_node(&peer_ctx, "qos_probe");
    let avatar_type = ("lhmpp_msgs", "GaussianAvatar");
    let status_type = ("lhmpp_msgs", "ReconstructionStatus");
    let image_type = ("sensor_msgs", "Image");
    let mut avatars = vec![
        probe::<GaussianAvatar>(&mut peer, &topics.avatar, avatar_type, true),
        probe::<GaussianAvatar>(&mut peer, &topics.avatar, avatar_type, false),
    ];
    let mut statuses = vec![
        probe::<ReconstructionStatus>(&mut peer, &topics.status, status_type, true),
        probe::<ReconstructionStatus>(&mut peer, &topics.status, status_type, false),
    ];
    let mut frames = vec![
        probe::<lhmpp::msgs::Image>(&mut peer, &topics.frames[0], image_type, true),
        probe::<lhmpp::msgs::Image>(&mut peer, &topics.frames[0], image_type, false),
    ];
    let cloud_type = ("sensor_msgs", "PointCloud2");
    let tf_type = ("tf2_msgs", "TFMessage");
    let mut previews = vec![
        probe::<lhmpp::msgs::PointCloud2>(&mut peer, &topics.preview, cloud_type, true),
        probe::<lhmpp::msgs::PointCloud2>(&mut peer, &topics.preview, cloud_type, false),
    ];
    let mut tfs = vec![
        probe::<lhmpp::msgs::TFMessage>(&mut peer, &topics.tf, tf_type, true),
        probe::<lhmpp::msgs::TFMessage>(&mut peer, &topics.tf, tf_type, false),
    ];
    let posed = lhmpp::splat::Gaussians {
        positions: vec![glam::Vec3::new(0.0, 1.0, 0.0); 3],
        scales: vec![glam::Vec3::splat(0.01); 3],
        rotations: vec![glam::Quat::IDENTITY; 3],
        opacities: vec![1.0; 3],
        sh_degree: 0,
        sh: vec![[0.5, 0.0, -0.5]; 3],
        feature_channels: 0,
        features: vec![],
    };
    let expect_reliable_frames = frame_qos == "reliable";
    let frame = image::RgbImage::new(16, 16);
    let start = std::time::Instant::now();
    let mut revision = 0;
    while start.elapsed() < std::time::Duration::from_secs(30) {
        revision += 1;
        let avatar = GaussianAvatar {
            person_id: "p".into(),
            revision,
            ..GaussianAvatar::default()
        };
        node.publish_avatar(avatar).unwrap();
        node.publish_status(ReconstructionStatus::default())
            .unwrap();
        node.publish_frame(0, rgb8_image(&frame, 0, "cam0"))
            .unwrap();
        node.publish_preview(&posed, 0).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(100));
        avatars.iter_mut().for_each(Probe::poll);
        statuses.iter_mut().for_each(Probe::poll);
        frames.iter_mut().for_each(Probe::poll);
        previews.iter_mut().for_each(Probe::poll);
        tfs.iter_mut().for_each(Probe::poll);
        let latched_done = avatars.iter().all(|p| p.received > 0)
            && statuses.iter().all(|p| p.received > 0)
            && previews.iter().all(|p| p.received > 0)
            && tfs.iter().all(|p| p.received > 0);
        let frames_done =
            frames[1].received > 0 && (!expect_reliable_frames || frames[0].received > 0);
        // Keep going 1 s after the expected probes are served, so a wrongly matching
        // reliable frame probe (best_effort case) would show up.
        if latched_done && frames_done && start.elapsed() > std::time::Duration::from_secs(3) {
            break;
        }
    }
    let result = avatars
        .iter()
        .map(|p| (p.what.clone(), p.received))
        .chain(statuses.iter().map(|p| (p.what.clone(), p.received)))
        .chain(frames.iter().map(|p| (p.what.clone(), p.received)))
        .chain(previews.iter().map(|p| (p.what.clone(), p.received)))
        .chain(tfs.iter().map(|p| (p.what.clone(), p.received)))
        .collect();
    drop((avatars, statuses, frames, previews, tfs));
    node.shutdown();
    result
}

#[test]
fn every_output_reaches_reliable_and_best_effort_subscribers() {
    let domain = i32::from(dds_domain::test_domain(32));
    let got = receive_outputs("reliable", "/lhmpp_qos_reliable", domain);
    eprintln!("frame_qos reliable: {got:?}");
    for (what, received) in &got {
        assert!(*received > 0, "{what} received nothing: {got:?}");
    }
}

#[test]
fn best_effort_frames_reach_only_best_effort_subscribers() {
    let domain = i32::from(dds_domain::test_domain(33));
    let got = receive_outputs("best_effort", "/lhmpp_qos_best_effort", domain);
    eprintln!("frame_qos best_effort: {got:?}");
    let count = |what: &str| got.iter().find(|(w, _)| w.ends_with(what)).unwrap().1;
    for (what, received) in got.iter().filter(|(w, _)| !w.contains("image_raw")) {
        assert!(*received > 0, "{what} received nothing: {got:?}");
    }
    assert!(count("image_raw (best effort)") > 0, "{got:?}");
    assert_eq!(count("image_raw (reliable)"), 0, "{got:?}");
}

#[test]
fn a_late_subscriber_gets_the_newest_avatar_held_while_nobody_listened() {
    use ros2_client::qos::{Durability, History, QosProfile, Reliability, WhenFull};
    let runtime = runtime();
    let _guard = runtime.enter();
    let (node, opts) = start_node(31, "/lhmpp_latched_test");
    // Nobody listens: each avatar is held (the newest replaces the older), none goes to DDS,
    // whose transient-local history would otherwise keep every one of them.
    for revision in 1..=40u32 {
        let avatar = GaussianAvatar {
            person_id: "p".into(),
            revision,
            ..GaussianAvatar::default()
        };
        assert_eq!(node.publish_avatar(avatar).unwrap(), PublishOutcome::Held);
    }

    let peer_ctx = lhmpp::node::ros::create_context(&opts.participant).unwrap();
    let mut peer = peer_node(&peer_ctx, "late_reader");
    let qos = QosProfile::subscription_default()
        .history(History::KeepLast { depth: 10 })
        .durability(Durability::TransientLocal)
        .reliability(Reliability::Reliable {
            when_full: WhenFull::DEFAULT,
        });
    let (ns, base) = node.topics().avatar.rsplit_once('/').unwrap();
    let name = ros2_client::Name::new(ns, base).unwrap();
    let topic = peer
        .create_topic(
            &name,
            ros2_client::MessageTypeName::new("lhmpp_msgs", "GaussianAvatar"),
            &qos,
        )
        .unwrap();
    let sub = peer
        .create_subscription::<GaussianAvatar>(&topic, Some(qos))
        .unwrap();
    let mut revisions = Vec::new();
    let start = std::time::Instant::now();
    while start.elapsed() < std::time::Duration::from_secs(20) && revisions.is_empty() {
        std::thread::sleep(std::time::Duration::from_millis(50));
        while let Ok(Some(avatar)) = sub.take() {
            revisions.push(avatar.0.revision);
        }
    }
    // A little longer, so an older avatar delivered after the newest would show up.
    std::thread::sleep(std::time::Duration::from_millis(500));
    while let Ok(Some(avatar)) = sub.take() {
        revisions.push(avatar.0.revision);
    }
    assert_eq!(revisions, vec![40], "the late reader got {revisions:?}");
    assert_eq!(node.avatar_subscribers(), 1);
    // With a reader matched, publishing goes straight to DDS again.
    let next = GaussianAvatar {
        person_id: "p".into(),
        revision: 41,
        ..GaussianAvatar::default()
    };
    assert_eq!(node.publish_avatar(next).unwrap(), PublishOutcome::Sent);
    drop(sub);
    node.shutdown();
}
