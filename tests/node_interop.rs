//! Interop with an independent DDS implementation: a `RosNode` (ros2-client / RustDDS) and a
//! PyPI `cyclonedds` peer (tests/python/dds_peer.py) on loopback.
//!
//! The peer publishes sensor_msgs/Image frames of a synthetic person (and malformed ones), and
//! the same frames as PNG sensor_msgs/CompressedImage;
//! the node must decode them into `InputEvent::Frame`s and survive the bad one. The node
//! publishes a GaussianAvatar and a rendered rgb8 Image; the peer checks their layout and
//! prints `RESULT ok ...`. Bounded by a watchdog; loopback only (RustDDS restricted to
//! 127.0.0.1, Cyclone given 127.0.0.1 as its only unicast peer, multicast off).

mod dds_domain;

use lhmpp::body::SkinWeights;
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{GaussianAvatar, GaussianCloud, GaussianColors, Header, Point, Time};
use lhmpp::node::inputs::InputEvent;
use lhmpp::node::ros::PublishOutcome;
use lhmpp::node::ros::{rgb8_image, LiveInputs, RosNode, RosNodeOptions};
use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

const WATCHDOG: Duration = Duration::from_secs(90);
const WIDTH: u32 = 64;
const HEIGHT: u32 = 96;
const RENDER_SIDE: u32 = 32;
const GAUSSIANS: usize = 100;
const PERSON: &str = "person_0";

/// A small avatar from plain arrays: Gaussians on a helix, a 3-bone chain skeleton.
fn test_avatar() -> GaussianAvatar {
    let n = GAUSSIANS;
    let cloud = GaussianCloud {
        positions: (0..n)
            .map(|i| {
                let t = i as f32 * 0.2;
                [0.2 * t.cos(), 1.8 * i as f32 / n as f32, 0.2 * t.sin()]
            })
            .collect(),
        scales: vec![[0.01, 0.02, 0.015]; n],
        rotations: (0..n)
            .map(|i| {
                let a = i as f32 * 0.05;
                [a.cos(), 0.0, a.sin(), 0.0]
            })
            .collect(),
        opacities: (0..n).map(|i| 0.5 + 0.4 * (i % 2) as f32).collect(),
        colors: GaussianColors::Rgb((0..n).map(|i| [i as f32 / n as f32, 0.5, 0.25]).collect()),
        skin: SkinWeights {
            bones: (0..n).map(|i| [(i * 3 / n) as u16, 0, 0, 0]).collect(),
            weights: (0..n)
                .map(|i| {
                    if i % 2 == 0 {
                        [1.0, 0.0, 0.0, 0.0]
                    } else {
                        [0.75, 0.25, 0.0, 0.0]
                    }
                })
                .collect(),
        },
    };
    let header = Header::new(
        Time::from_nanos(1_700_000_000_000_000_000),
        "avatar_canonical",
    );
    GaussianAvatar {
        gaussians: cloud
            .to_point_cloud(header.clone())
            .expect("consistent cloud"),
        header,
        person_id: PERSON.into(),
        revision: 1,
        views_used: 3,
        body_model: "makehuman-cc0".into(),
        shape_params: Vec::new(),
        sh_degree: 0,
        rgb_display_ready: true,
        neural_renderer: String::new(),
        bone_names: vec!["root".into(), "spine".into(), "head".into()],
        bone_parents: vec![-1, 0, 1],
        bone_rest_positions: vec![
            Point {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
            Point {
                x: 0.0,
                y: 0.6,
                z: 0.0,
            },
            Point {
                x: 0.0,
                y: 1.5,
                z: 0.0,
            },
        ],
    }
}

fn python() -> PathBuf {
    PathBuf::from(std::env::var("LHMPP_TEST_PYTHON").expect(
        "LHMPP_TEST_PYTHON is not set: run scripts/test (it installs the cyclonedds peer in target/pyenv)",
    ))
}

fn cyclone_loopback_config() -> String {
    "<CycloneDDS><Domain>\
       <General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces>\
         <AllowMulticast>false</AllowMulticast></General>\
       <Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>\
       <Internal><SocketReceiveBufferSize min=\"4MB\"/></Internal>\
     </Domain></CycloneDDS>"
        .into()
}

/// Checks a received frame shows the peer's synthetic person: grey corners, red top of torso.
fn assert_person_frame(ev: &InputEvent) {
    let InputEvent::Frame(f) = ev else {
        panic!("expected a frame, got {ev:?}");
    };
    assert_eq!(f.image.dimensions(), (WIDTH, HEIGHT));
    assert_eq!(f.image.get_pixel(0, 0).0, [90, 90, 90]);
    let top = f.image.get_pixel(WIDTH / 2, HEIGHT / 8).0;
    assert!(top[0] > 240 && top[2] < 15, "torso top {top:?}");
    assert!(f.frame_id.starts_with("frame_"), "frame id {}", f.frame_id);
    assert!(
        f.stamp_ns > 1_600_000_000_000_000_000,
        "stamp {}",
        f.stamp_ns
    );
}

/// Kills the peer if the test ends early.
struct PeerGuard(Child);

impl Drop for PeerGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Forwards the peer's stdout lines to a channel (from a plain thread).
fn peer_lines(child: &mut Child) -> mpsc::UnboundedReceiver<String> {
    let stdout = child.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::unbounded_channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits for `n` frames; also returns each one's delay from its header stamp (the peer's
/// wall clock at publish) to its arrival here, both on this host.
async fn wait_for_frames(
    rx: &mut LiveInputs,
    n: usize,
    topics: &[String],
) -> (Vec<InputEvent>, Vec<Duration>) {
    let mut got = Vec::new();
    let mut delays = Vec::new();
    let from = |got: &Vec<InputEvent>, topic: &String| {
        got.iter()
            .filter(|e| matches!(e, InputEvent::Frame(f) if &f.topic == topic))
            .count()
    };
    while topics.iter().any(|t| from(&got, t) < n) {
        match rx.recv().await {
            Some(ev @ InputEvent::Frame(_)) => {
                if let InputEvent::Frame(f) = &ev {
                    let now = std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .unwrap()
                        .as_nanos() as i64;
                    delays.push(Duration::from_nanos((now - f.stamp_ns).max(0) as u64));
                }
                got.push(ev)
            }
            Some(_) => {}
            None => break,
        }
    }
    (got, delays)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclonedds_peer_and_node_exchange_images_and_avatars() {
    let python = python();
    let domain = dds_domain::test_domain(0);
    let mut cfg = NodeConfig {
        domain_id: i32::from(domain),
        namespace: "/lhmpp_test".into(),
        ..NodeConfig::default()
    };
    cfg.inputs.image_topics = vec!["cam0/image_raw".into()];
    cfg.inputs.compressed_image_topics = vec!["cam1/image_raw/compressed".into()];
    cfg.inputs.pose_topic = String::new();
    cfg.outputs.virtual_cameras = 1;
    let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None)
        .unwrap()
        .loopback_only();
    let (node, mut rx) = RosNode::start(&opts).expect("node starts");
    assert_eq!(node.topics().images, vec!["/lhmpp_test/cam0/image_raw"]);

    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/dds_peer.py");
    let child = Command::new(&python)
        .arg(&script)
        .args(["--domain", &domain.to_string()])
        .args(["--image-topic", &node.topics().images[0]])
        .args(["--compressed-topic", &node.topics().compressed_images[0]])
        .args(["--avatar-topic", &node.topics().avatar])
        .args(["--render-topic", &node.topics().frames[0]])
        .args([
            "--width",
            &WIDTH.to_string(),
            "--height",
            &HEIGHT.to_string(),
        ])
        .args(["--render-side", &RENDER_SIDE.to_string()])
        .args(["--gaussians", &GAUSSIANS.to_string(), "--person", PERSON])
        .args(["--timeout", "60"])
        .env("CYCLONEDDS_URI", cyclone_loopback_config())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", python.display()));
    let mut peer = PeerGuard(child);
    let mut lines = peer_lines(&mut peer.0);

    let started = Instant::now();
    // What the test waits for now, for the watchdog's message.
    let stage = std::sync::Mutex::new("discovery: the peer's first frames");
    let outcome = tokio::time::timeout(WATCHDOG, async {
        // 1. Frames from the peer arrive decoded, raw and PNG-compressed.
        let cameras = [
            node.topics().images[0].clone(),
            node.topics().compressed_images[0].clone(),
        ];
        let (frames, delays) = wait_for_frames(&mut rx, 3, &cameras).await;
        let first_frame_after = started.elapsed();
        assert!(frames.len() >= 6, "input queue closed early");
        frames.iter().for_each(assert_person_frame);
        *stage.lock().unwrap() = "a malformed frame counted as rejected";
        // The peer's malformed frames are counted, not fatal.
        let topic = node.topics().images[0].clone();
        while node
            .input_stats()
            .rejected
            .get(&topic)
            .copied()
            .unwrap_or(0)
            == 0
        {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        // 2. Publish a rendered frame (and the avatar) until the peer reports.
        *stage.lock().unwrap() = "the peer's report on our avatar and frame";
        let render = image::RgbImage::from_fn(RENDER_SIDE, RENDER_SIDE, |x, y| {
            image::Rgb([x as u8 * 8, y as u8 * 8, 200])
        });
        let avatar = test_avatar();
        let mut avatar_sent = false;
        let result = loop {
            // Reliable + transient-local: once sent, a late-matching reader still gets it.
            if !avatar_sent {
                avatar_sent = node.publish_avatar(avatar.clone()).expect("publish avatar")
                    == PublishOutcome::Sent;
            }
            node.publish_frame(
                0,
                rgb8_image(&render, 1_700_000_000_000_000_000, "virtual_cam0"),
            )
            .expect("publish frame");
            tokio::select! {
                line = lines.recv() => match line {
                    Some(l) if l.starts_with("RESULT") => break l,
                    Some(l) => eprintln!("peer: {l}"),
                    None => break "RESULT fail peer exited without a result".into(),
                },
                _ = tokio::time::sleep(Duration::from_millis(100)) => {}
            }
        };
        (first_frame_after, delays, result)
    })
    .await;
    let stats = node.input_stats();
    node.shutdown();
    let Ok((first_frame_after, delays, result)) = outcome else {
        panic!(
            "watchdog: interop did not finish in {WATCHDOG:?}, waiting for {}; inputs {stats:?}",
            stage.lock().unwrap()
        );
    };
    eprintln!(
        "first decoded frame after {first_frame_after:?}; stamp-to-event delays {delays:?}; \
         peer said: {result}; {stats:?}"
    );
    assert!(result.starts_with("RESULT ok"), "{result}");
    let topic = "/lhmpp_test/cam0/image_raw";
    assert!(
        stats.accepted.get(topic).copied().unwrap_or(0) >= 3,
        "{stats:?}"
    );
    assert!(
        stats.rejected.get(topic).copied().unwrap_or(0) >= 1,
        "{stats:?}"
    );
    // Counted by reason too, the same messages.
    assert_eq!(
        stats.rejections.total(),
        stats.rejected.values().sum::<u64>(),
        "{stats:?}"
    );
    let status = peer.0.wait().expect("peer exit status");
    assert!(status.success(), "peer exited with {status}");
}
