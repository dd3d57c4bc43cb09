//! Shared by the tests that run an rclpy peer (Fast DDS, the lhmpp_msgs Python types colcon
//! builds from msg/): the venv's Python, the message package build and a child process that is
//! killed when dropped.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Instant;

/// A child process killed (and reaped) when dropped.
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The Python of the ROS 2 venv (`LHMPP_TEST_ROS_PYTHON`, set by scripts/test).
pub fn ros_python() -> PathBuf {
    PathBuf::from(std::env::var("LHMPP_TEST_ROS_PYTHON").expect(
        "LHMPP_TEST_ROS_PYTHON is not set: run scripts/test (scripts/setup-test-deps installs \
         rclpy and the rosidl generators into target/rosenv)",
    ))
}

/// Builds lhmpp_msgs with colcon (skipped when msg/ is unchanged); returns the install prefix.
pub fn build_msgs(root: &Path) -> PathBuf {
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
        "CompactAvatar",
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

/// The environment an rclpy peer needs for the package at `prefix` on `domain` (loopback
/// discovery, Fast DDS).
pub fn peer_env(python: &Path, prefix: &Path, domain: u16) -> Vec<(String, String)> {
    let venv = python
        .parent()
        .and_then(Path::parent)
        .unwrap()
        .to_path_buf();
    vec![
        ("ROS_DOMAIN_ID".into(), domain.to_string()),
        ("ROS_AUTOMATIC_DISCOVERY_RANGE".into(), "LOCALHOST".into()),
        ("RMW_IMPLEMENTATION".into(), "rmw_fastrtps_cpp".into()),
        (
            "AMENT_PREFIX_PATH".into(),
            format!("{}:{}", prefix.display(), venv.display()),
        ),
        (
            "PYTHONPATH".into(),
            prefix
                .join("lib/python3.11/site-packages")
                .display()
                .to_string(),
        ),
        (
            "LD_LIBRARY_PATH".into(),
            prefix.join("lib").display().to_string(),
        ),
    ]
}

/// Starts the peer `command` (its stderr shown, its stdout read) and returns its `RESULT ...`
/// line (`RESULT fail ...` when it exits without one), logged as `label` with the time since
/// `started`; the peer is killed on return.
pub fn peer_result(mut command: Command, label: &str, started: Instant) -> String {
    let peer = command
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {label}: {e}"));
    let mut peer = KillOnDrop(peer);
    let result = BufReader::new(peer.0.stdout.take().unwrap())
        .lines()
        .map_while(Result::ok)
        .find(|l| l.starts_with("RESULT"))
        .unwrap_or_else(|| "RESULT fail peer exited without a result".into());
    eprintln!(
        "{label} ({:.1} s): {result}",
        started.elapsed().as_secs_f64()
    );
    result
}
