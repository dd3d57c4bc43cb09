//! A 160,000-Gaussian avatar (the LHMPP-700M layout's count; the embedded `tiny` network with
//! random weights makes it in seconds) reaches a RELIABLE rclpy subscriber (Fast DDS) as
//! `lhmpp_msgs/CompactAvatar` on `avatar/compact` with the host's own `net.core.rmem_max`
//! (4 MiB on the development machine; the 12.8 MB `GaussianAvatar` needs twice its size). The
//! peer (tests/python/compact_peer.py) decodes both blobs. Bounded in time.

mod dds_domain;
mod rclpy_support;

use rclpy_support::{build_msgs, peer_env, peer_result, ros_python, KillOnDrop};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_160k_gaussian_compact_avatar_reaches_an_rclpy_subscriber_with_the_default_rmem_max() {
    let python = ros_python();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let prefix = build_msgs(&root);
    let domain = dds_domain::test_domain(71);
    let sets = [
        format!("domain_id={domain}"),
        "dds_interfaces=[127.0.0.1]".into(),
        "namespace=/compact_test".into(),
        format!("replay.bag={}", root.join("bags/demo.mcap").display()),
        "replay.rate=0".into(),
        "replay.exit_when_done=false".into(),
        "inputs.image_topics=[/cam0/image_raw,/cam1/image_raw,/cam2/image_raw,/cam3/image_raw]"
            .into(),
        "inputs.mask_topics=[/cam0/mask,/cam1/mask,/cam2/mask,/cam3/mask]".into(),
        "model.checkpoint=random".into(),
        "model.num_points=160000".into(),
        "outputs.virtual_cameras=1".into(),
        "outputs.render_size=32".into(),
        "outputs.render_rate_hz=1".into(),
        "outputs.dir=''".into(),
    ];
    let mut node = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    node.arg("run");
    for s in &sets {
        node.args(["--set", s]);
    }
    let _node = KillOnDrop(
        node.env_remove("RUST_LOG")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("lhmpp starts"),
    );
    let started = Instant::now();
    let mut peer = Command::new(&python);
    peer.arg(root.join("tests/python/compact_peer.py"))
        .args(["--compact-topic", "/compact_test/avatar/compact"])
        .args(["--full-topic", "/compact_test/avatar"])
        .args(["--gaussians", "160000", "--timeout", "150"])
        .envs(peer_env(&python, &prefix, domain));
    let result = peer_result(peer, "rclpy compact peer", started);
    assert!(result.starts_with("RESULT ok"), "{result}");
    assert!(started.elapsed() < Duration::from_secs(160));
}
