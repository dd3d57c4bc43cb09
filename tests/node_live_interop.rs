//! The whole node against an independent DDS implementation: `lhmpp run` (live mode, loopback
//! only) and the PyPI `cyclonedds` peer of tests/python/dds_peer.py. The peer publishes camera
//! frames of a synthetic person (raw and PNG, some malformed); the node reconstructs and
//! publishes GaussianAvatar revisions and rendered frames, which the peer checks (field layout,
//! sizes, finite values, unit rotations, skin weights, revisions increasing). The peer then
//! vanishes and a new one comes back: the node serves it newer revisions. Bounded in time.

mod dds_domain;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

const CYCLONE_LOOPBACK: &str = "<CycloneDDS><Domain>\
   <General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces>\
     <AllowMulticast>false</AllowMulticast></General>\
   <Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>\
   <Internal><SocketReceiveBufferSize min=\"4MB\"/></Internal>\
 </Domain></CycloneDDS>";

#[test]
fn node_reconstructs_frames_from_a_cyclonedds_peer_and_publishes_avatars_and_renders() {
    let python = PathBuf::from(std::env::var("LHMPP_TEST_PYTHON").expect(
        "LHMPP_TEST_PYTHON is not set: run scripts/test (it installs the cyclonedds peer)",
    ));
    let domain = u32::from(dds_domain::test_domain(50));
    let out = tempfile::tempdir().unwrap();
    let sets = [
        format!("domain_id={domain}"),
        "dds_interfaces=[127.0.0.1]".into(),
        "namespace=/live_test".into(),
        "inputs.image_topics=[cam0/image_raw]".into(),
        "inputs.compressed_image_topics=[cam1/image_raw/compressed]".into(),
        "inputs.pose_topic=''".into(),
        // The peer's frames are coloured boxes, not people: whole frames, as without perception.
        "inputs.person_mask=off".into(),
        "frame_store.debounce_ms=50".into(),
        "model.num_points=1024".into(),
        "outputs.virtual_cameras=1".into(),
        "outputs.render_size=64".into(),
        "outputs.render_rate_hz=5".into(),
        format!("outputs.dir={}", out.path().display()),
    ];
    let mut node = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    node.arg("run");
    for s in &sets {
        node.args(["--set", s]);
    }
    let node = KillOnDrop(
        node.stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("lhmpp starts"),
    );
    let first = run_peer(&python, domain, 0, 0);
    eprintln!("peer: {first}");
    assert!(first.starts_with("RESULT ok"), "{first}");
    // The peer vanishes (its process has exited) and a new one comes back with new views: the
    // node, still running, takes them and publishes newer revisions to it. (It may first get
    // the transient-local history, newest last: RustDDS keeps samples the first peer did not
    // acknowledge before it exited.)
    let again = run_peer(&python, domain, 128, last_revision(&first));
    eprintln!("peer that came back: {again}");
    assert!(again.starts_with("RESULT ok"), "{again}");
    let (before, after) = (last_revision(&first), last_revision(&again));
    assert!(
        after > before,
        "revision {after} after the peer came back, {before} before"
    );

    // SIGINT stops the node cleanly: it exits 0 and prints its summary.
    let mut node = node;
    let sent = Command::new("kill")
        .args(["-INT", &node.0.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let mut summary = String::new();
    for line in BufReader::new(node.0.stdout.take().unwrap())
        .lines()
        .map_while(Result::ok)
    {
        summary.push_str(&line);
    }
    let status = wait_timeout(&mut node.0, Duration::from_secs(30));
    assert_eq!(status, Some(0), "node exit status; summary: {summary}");
    assert!(summary.contains("reconstructions"), "{summary}");
    println!("node summary: {summary}");
    // The peer's bad-step frames are in the summary's rejections, by reason.
    let rejected = summary
        .split("rejected messages ")
        .nth(1)
        .and_then(|rest| rest.split(',').next())
        .unwrap_or_else(|| panic!("no rejections in the summary: {summary}"));
    assert!(
        rejected.ends_with(&format!("(image {})", rejected.split(' ').next().unwrap())),
        "only bad images, at least one: {rejected}"
    );
    assert!(!rejected.starts_with('0'), "{summary}");
}

/// Runs one cyclonedds peer to its RESULT line: it sends frames from index `first_frame` on
/// and waits for two avatar revisions and a rendered frame.
fn run_peer(python: &Path, domain: u32, first_frame: u32, above_revision: u64) -> String {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/dds_peer.py");
    let peer = Command::new(python)
        .arg(&script)
        .args(["--domain", &domain.to_string()])
        .args(["--image-topic", "/live_test/cam0/image_raw"])
        .args(["--compressed-topic", "/live_test/cam1/image_raw/compressed"])
        .args(["--avatar-topic", "/live_test/avatar"])
        .args(["--render-topic", "/live_test/render/cam0/image_raw"])
        .args(["--width", "64", "--height", "96", "--render-side", "64"])
        .args(["--gaussians", "1024", "--person", "person_0"])
        .args(["--first-frame", &first_frame.to_string()])
        .args(["--min-revisions", "2", "--timeout", "150"])
        .args(["--above-revision", &above_revision.to_string()])
        .env("CYCLONEDDS_URI", CYCLONE_LOOPBACK)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", python.display()));
    let mut peer = KillOnDrop(peer);
    let stdout = peer.0.stdout.take().unwrap();
    BufReader::new(stdout)
        .lines()
        .map_while(Result::ok)
        .find(|l| l.starts_with("RESULT"))
        .unwrap_or_else(|| "RESULT fail peer exited without a result".into())
}

/// The highest avatar revision of a peer's `RESULT ok ... revisions=[a, b]` line.
fn last_revision(result: &str) -> u64 {
    result
        .split("revisions=[")
        .nth(1)
        .and_then(|rest| rest.split(']').next())
        .and_then(|list| list.split(',').filter_map(|r| r.trim().parse().ok()).max())
        .unwrap_or_else(|| panic!("no revisions in {result}"))
}

fn wait_timeout(child: &mut Child, limit: Duration) -> Option<i32> {
    let start = std::time::Instant::now();
    while start.elapsed() < limit {
        if let Some(s) = child.try_wait().unwrap() {
            return s.code();
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    None
}
