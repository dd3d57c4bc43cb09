//! The whole node against real ROS 2: `lhmpp run` (live, loopback only) and an rclpy node on
//! Fast DDS (rmw_fastrtps_cpp, the ROS 2 default) from the PyPI wheels, using the lhmpp_msgs
//! Python types that colcon builds from msg/ (scripts/build-msgs, called here; cached).
//! The peer (tests/python/rclpy_peer.py) publishes raw and compressed cameras and BodyPose,
//! receives the rendered frames with RELIABLE and BEST_EFFORT QoS, the ReconstructionStatus
//! and the GaussianAvatar as typed messages, and checks increasing revisions, finite
//! Gaussians, and frames that change with the pose. Bounded in time.

mod dds_domain;
mod rclpy_support;

use rclpy_support::{build_msgs, peer_env, peer_result, ros_python, KillOnDrop};

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn node_serves_an_rclpy_fast_dds_peer_with_typed_lhmpp_msgs() {
    let python = ros_python();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let prefix = build_msgs(&root);
    let domain = dds_domain::test_domain(70);
    let sets = [
        format!("domain_id={domain}"),
        "dds_interfaces=[127.0.0.1]".into(),
        "namespace=/rclpy_test".into(),
        "inputs.image_topics=[cam0/image_raw]".into(),
        "inputs.compressed_image_topics=[cam1/image_raw/compressed]".into(),
        "inputs.pose_topic=body_pose".into(),
        // The peer's frames are coloured boxes, not people: whole frames, as without perception.
        "inputs.person_mask=off".into(),
        "frame_store.debounce_ms=50".into(),
        "model.num_points=1024".into(),
        "outputs.virtual_cameras=1".into(),
        "outputs.render_size=64".into(),
        "outputs.render_rate_hz=10".into(),
        "outputs.dir=''".into(),
        "outputs.preview_rate_hz=4".into(),
    ];
    let mut node = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    node.arg("run");
    for s in &sets {
        node.args(["--set", s]);
    }
    let mut node = KillOnDrop(
        node.env_remove("RUST_LOG")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("lhmpp starts"),
    );
    let started = Instant::now();
    let mut peer = Command::new(&python);
    peer.arg(root.join("tests/python/rclpy_peer.py"))
        .args(["--image-topic", "/rclpy_test/cam0/image_raw"])
        .args([
            "--compressed-topic",
            "/rclpy_test/cam1/image_raw/compressed",
        ])
        .args(["--pose-topic", "/rclpy_test/body_pose"])
        .args(["--avatar-topic", "/rclpy_test/avatar"])
        .args(["--status-topic", "/rclpy_test/status"])
        .args(["--render-topic", "/rclpy_test/render/cam0/image_raw"])
        .args(["--preview-topic", "/rclpy_test/avatar/points"])
        .args(["--width", "64", "--height", "96", "--render-side", "64"])
        .args(["--gaussians", "1024", "--person", "person_0"])
        .args(["--min-revisions", "2", "--timeout", "120"])
        .envs(peer_env(&python, &prefix, domain));
    let result = peer_result(peer, "rclpy peer", started);
    assert!(result.starts_with("RESULT ok"), "{result}");
    assert!(started.elapsed() < Duration::from_secs(130));

    // SIGINT stops the node cleanly: exit 0 and the summary.
    let sent = Command::new("kill")
        .args(["-INT", &node.0.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let summary: String = BufReader::new(node.0.stdout.take().unwrap())
        .lines()
        .map_while(Result::ok)
        .collect();
    let deadline = Instant::now() + Duration::from_secs(30);
    let code = loop {
        if let Some(s) = node.0.try_wait().unwrap() {
            break s.code();
        }
        assert!(Instant::now() < deadline, "node did not stop: {summary}");
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(code, Some(0), "node exit status; summary: {summary}");
    eprintln!("node: {summary}");
    assert!(summary.contains("reconstructions"), "{summary}");
}
