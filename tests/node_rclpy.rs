//! The whole node against real ROS 2: `lhmpp run` (live, loopback only) and an rclpy node on
//! Fast DDS (rmw_fastrtps_cpp, the ROS 2 default) from the PyPI wheels, using the lhmpp_msgs
//! Python types that colcon builds from msg/ (scripts/build-msgs, called here; cached).
//! The peer (tests/python/rclpy_peer.py) publishes raw and compressed cameras and BodyPose,
//! receives the rendered frames with RELIABLE and BEST_EFFORT QoS, the ReconstructionStatus
//! and the GaussianAvatar as typed messages, and checks increasing revisions, finite
//! Gaussians, and frames that change with the pose. Bounded in time.

mod dds_domain;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn ros_python() -> PathBuf {
    PathBuf::from(std::env::var("LHMPP_TEST_ROS_PYTHON").expect(
        "LHMPP_TEST_ROS_PYTHON is not set: run scripts/test (scripts/setup-test-deps installs \
         rclpy and the rosidl generators into target/rosenv)",
    ))
}

/// Builds lhmpp_msgs with colcon (skipped when msg/ is unchanged); returns the install prefix.
fn build_msgs(root: &Path) -> PathBuf {
    let started = Instant::now();
    let out = Command::new(root.join("scripts/build-msgs"))
        .output()
        .expect("scripts/build-msgs runs");
    eprintln!(
        "scripts/build-msgs ({:.1} s): {}{}",
        started.elapsed().as_secs_f64(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "colcon build of msg/ failed");
    let prefix = root.join("target/msgs_ws/install/lhmpp_msgs");
    for t in [
        "GaussianAvatar",
        "BodyPose",
        "BodyShape",
        "ReconstructionStatus",
    ] {
        let json = prefix.join(format!("share/lhmpp_msgs/msg/{t}.json"));
        let text =
            std::fs::read_to_string(&json).unwrap_or_else(|e| panic!("{}: {e}", json.display()));
        assert!(text.contains("RIHS01_"), "{t}: no RIHS01 type hash");
    }
    // The fields added to the .msg files after the first hand build are in the package.
    let idl = |t: &str| {
        std::fs::read_to_string(prefix.join(format!("share/lhmpp_msgs/msg/{t}.idl"))).unwrap()
    };
    let avatar = idl("GaussianAvatar");
    assert!(avatar.contains("rgb_display_ready") && avatar.contains("neural_renderer"));
    assert!(idl("ReconstructionStatus").contains("last_render_ms"));
    prefix
}

#[test]
fn node_serves_an_rclpy_fast_dds_peer_with_typed_lhmpp_msgs() {
    let python = ros_python();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let prefix = build_msgs(&root);
    let venv = python
        .parent()
        .and_then(Path::parent)
        .unwrap()
        .to_path_buf();
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
    let site = prefix.join("lib/python3.11/site-packages");
    let started = Instant::now();
    let peer = Command::new(&python)
        .arg(root.join("tests/python/rclpy_peer.py"))
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
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        .env(
            "AMENT_PREFIX_PATH",
            format!("{}:{}", prefix.display(), venv.display()),
        )
        .env("PYTHONPATH", &site)
        .env("LD_LIBRARY_PATH", prefix.join("lib"))
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", python.display()));
    let mut peer = KillOnDrop(peer);
    let result = BufReader::new(peer.0.stdout.take().unwrap())
        .lines()
        .map_while(Result::ok)
        .find(|l| l.starts_with("RESULT"))
        .unwrap_or_else(|| "RESULT fail peer exited without a result".into());
    eprintln!(
        "rclpy peer ({:.1} s): {result}",
        started.elapsed().as_secs_f64()
    );
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
