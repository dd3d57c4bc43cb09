//! `lhmpp record` against an independent DDS publisher: a PyPI `cyclonedds` peer
//! (tests/python/dds_record_peer.py) publishes Images and a BodyPose on loopback while the
//! recorder runs as a child process. (a) After SIGINT the bag is complete and holds every
//! message with its content; (b) after SIGKILL mid-recording the bag still reads up to its last
//! complete chunk, with at least every message the recorder had reported flushed, and the
//! Python `mcap` reader agrees. Needs `LHMPP_TEST_PYTHON` (set by `scripts/test`).
//! Loopback only (RustDDS restricted to 127.0.0.1, Cyclone's only peer 127.0.0.1, no multicast).

mod dds_domain;

use lhmpp::bag::BagReader;
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{BodyPose, Image, RosMessage};
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const IMAGE_TOPIC: &str = "/rec_test/cam0/image_raw";
const POSE_TOPIC: &str = "/rec_test/body_pose";
const WIDTH: u32 = 32;
const HEIGHT: u32 = 24;

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
     </Domain></CycloneDDS>"
        .into()
}

/// A config whose only inputs are one reliable image topic and the pose topic.
fn write_config(dir: &Path, domain: u16) -> PathBuf {
    let mut cfg = NodeConfig {
        domain_id: i32::from(domain),
        namespace: "/rec_test".into(),
        ..NodeConfig::default()
    };
    cfg.inputs.image_topics = vec!["cam0/image_raw".into()];
    cfg.inputs.compressed_image_topics = Vec::new();
    cfg.inputs.camera_info_topics = Vec::new();
    cfg.inputs.mask_topic = String::new();
    cfg.inputs.pose_topic = "body_pose".into();
    cfg.inputs.image_qos = lhmpp::config::ImageQos::Reliable;
    let path = dir.join("record.yaml");
    std::fs::write(&path, cfg.to_param_file()).unwrap();
    path
}

/// Kills a child process if the test ends early.
struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Forwards a child's lines (stdout or stderr) to a channel, echoing them to the test log.
fn lines_of(
    stream: impl std::io::Read + Send + 'static,
    tag: &'static str,
) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stream)
            .lines()
            .map_while(Result::ok)
        {
            eprintln!("{tag}: {line}");
            // Keep draining after the receiver is gone, so the child never writes to a
            // closed pipe.
            let _ = tx.send(line);
        }
    });
    rx
}

fn start_recorder(config: &Path, bag: &Path) -> (ChildGuard, mpsc::Receiver<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args([
            "--log",
            "info,rustdds=error",
            "record",
            "--loopback",
            "--progress",
            "0.5",
        ])
        .arg("--config")
        .arg(config)
        .arg("-o")
        .arg(bag)
        .env("NO_COLOR", "1")
        .env_remove("RUST_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lhmpp record starts");
    let stderr = lines_of(child.stderr.take().unwrap(), "record");
    let _stdout = lines_of(child.stdout.take().unwrap(), "record out");
    (ChildGuard(child), stderr)
}

fn start_peer(domain: u16, count: usize) -> (ChildGuard, mpsc::Receiver<String>) {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/dds_record_peer.py");
    let mut child = Command::new(python())
        .arg(&script)
        .args(["--domain", &domain.to_string()])
        .args(["--image-topic", IMAGE_TOPIC, "--pose-topic", POSE_TOPIC])
        .args(["--count", &count.to_string()])
        .args([
            "--width",
            &WIDTH.to_string(),
            "--height",
            &HEIGHT.to_string(),
        ])
        .args(["--timeout", "40"])
        .env("CYCLONEDDS_URI", cyclone_loopback_config())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python peer starts");
    let stdout = lines_of(child.stdout.take().unwrap(), "peer");
    (ChildGuard(child), stdout)
}

/// Waits for a line that `pick` accepts; panics after `timeout`.
fn wait_line<T>(
    rx: &mpsc::Receiver<String>,
    timeout: Duration,
    pick: impl Fn(&str) -> Option<T>,
) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) => {
                if let Some(v) = pick(&line) {
                    return v;
                }
            }
            Err(e) => panic!("no expected line within {timeout:?}: {e}"),
        }
    }
}

/// `flushed N` from a recorder progress line.
fn flushed_count(line: &str) -> Option<u64> {
    let rest = line.split("(flushed ").nth(1)?;
    rest.split(')').next()?.parse().ok()
}

fn signal(child: &Child, name: &str) {
    let status = Command::new("kill")
        .args([name, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success(), "kill {name} failed");
}

/// Checks frame `i` as the peer made it.
fn assert_frame(img: &Image, i: usize) {
    assert_eq!(img.header.frame_id, format!("frame_{i}"));
    assert_eq!((img.width, img.height, img.step), (WIDTH, HEIGHT, WIDTH));
    assert_eq!(img.encoding, "mono8");
    assert_eq!(img.data.len(), (WIDTH * HEIGHT) as usize);
    assert!(img
        .data
        .iter()
        .enumerate()
        .all(|(j, &v)| v as usize == (7 * i + j) % 256));
}

fn frames_of(reader: &BagReader) -> Vec<Image> {
    reader
        .messages()
        .iter()
        .filter(|m| &*m.topic == IMAGE_TOPIC)
        .map(|m| Image::decode_cdr(&m.data).expect("recorded Image decodes"))
        .collect()
}

#[test]
fn sigint_finishes_a_bag_holding_every_published_message() {
    const N: usize = 20;
    let domain = dds_domain::test_domain(10);
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), domain);
    let bag = dir.path().join("rec");
    let (recorder, rec_lines) = start_recorder(&config, &bag);
    wait_line(&rec_lines, Duration::from_secs(30), |l| {
        l.contains("recording").then_some(())
    });
    let (_peer, peer_lines) = start_peer(domain, N);
    let sent: usize = wait_line(&peer_lines, Duration::from_secs(60), |l| {
        assert!(!l.starts_with("FAIL"), "peer: {l}");
        l.strip_prefix("SENT ").map(|n| n.parse().unwrap())
    });
    assert_eq!(sent, N);
    // Wait until the recorder reports all N + 1 messages, then stop it like Ctrl-C does.
    wait_line(&rec_lines, Duration::from_secs(20), |l| {
        l.contains(&format!("recorded {} messages", N + 1))
            .then_some(())
    });
    signal(&recorder.0, "-INT");
    let mut recorder = recorder;
    let status = recorder.0.wait().unwrap();
    assert!(status.success(), "recorder exited with {status}");

    let reader = BagReader::open(&bag).expect("bag opens");
    assert!(reader.truncation().is_none(), "{:?}", reader.truncation());
    let images = reader
        .topics()
        .iter()
        .find(|t| t.name == IMAGE_TOPIC)
        .unwrap();
    assert_eq!(images.type_name, "sensor_msgs/msg/Image");
    assert_eq!(images.message_count, N as u64);
    let qos = images.offered_qos_profiles.as_deref().unwrap();
    assert!(qos.contains("reliability: reliable"), "{qos}");
    let frames = frames_of(&reader);
    assert_eq!(frames.len(), N);
    for (i, f) in frames.iter().enumerate() {
        assert_frame(f, i);
    }
    let poses: Vec<BodyPose> = reader
        .messages()
        .iter()
        .filter(|m| &*m.topic == POSE_TOPIC)
        .map(|m| BodyPose::decode_cdr(&m.data).unwrap())
        .collect();
    assert_eq!(poses.len(), 1);
    let p = &poses[0];
    assert_eq!(p.person_id, "person_0");
    assert_eq!(p.bone_names, ["spine", "head"]);
    assert_eq!((p.rotations[1].y, p.rotations[1].w), (0.6, 0.8));
    assert_eq!((p.root.translation.x, p.root.translation.z), (0.5, -1.25));
    // Output topics were recorded too (no messages, but declared with their QoS).
    let avatar = reader
        .topics()
        .iter()
        .find(|t| t.name == "/rec_test/avatar");
    let avatar_qos = avatar
        .and_then(|t| t.offered_qos_profiles.clone())
        .unwrap_or_default();
    assert!(avatar_qos.contains("transient_local"), "{avatar_qos}");
}

/// Messages the Python `mcap` package's stream reader gets from a (possibly truncated) file
/// before it stops.
fn python_mcap_message_count(mcap_file: &Path) -> usize {
    let code = r#"
import sys
from mcap.stream_reader import StreamReader
from mcap.records import Message
n = 0
try:
    with open(sys.argv[1], "rb") as f:
        for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
            if isinstance(record, Message):
                n += 1
except Exception as e:
    print(f"stopped: {type(e).__name__}: {e}", file=sys.stderr)
print(n)
"#;
    let out = Command::new(python())
        .args(["-c", code])
        .arg(mcap_file)
        .output()
        .unwrap();
    eprintln!("python mcap: {}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    String::from_utf8_lossy(&out.stdout).trim().parse().unwrap()
}

#[test]
fn sigkill_leaves_a_bag_readable_up_to_the_last_flush() {
    let domain = dds_domain::test_domain(11);
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), domain);
    let bag = dir.path().join("killed");
    let (recorder, rec_lines) = start_recorder(&config, &bag);
    wait_line(&rec_lines, Duration::from_secs(30), |l| {
        l.contains("recording").then_some(())
    });
    let (_peer, _peer_lines) = start_peer(domain, 0);
    // Kill as soon as the recorder says a good number of messages are flushed.
    let flushed = wait_line(&rec_lines, Duration::from_secs(40), |l| {
        flushed_count(l).filter(|&n| n >= 25)
    });
    signal(&recorder.0, "-KILL");
    let mut recorder = recorder;
    let status = recorder.0.wait().unwrap();
    assert!(!status.success(), "recorder survived SIGKILL: {status}");
    assert!(
        !bag.join("metadata.yaml").exists(),
        "metadata.yaml is only written on finish"
    );

    let reader = BagReader::open(&bag).expect("killed bag opens");
    let truncation = reader.truncation().expect("a killed bag has no footer");
    eprintln!(
        "read {} messages; flushed before kill {flushed}; stopped at {truncation:?}",
        reader.messages().len()
    );
    assert!(
        reader.messages().len() as u64 >= flushed,
        "{} messages read, {flushed} were flushed",
        reader.messages().len()
    );
    let frames = frames_of(&reader);
    for (i, f) in frames.iter().enumerate() {
        assert_frame(f, i);
    }
    let mcap_file = bag.join("killed_0.mcap");
    assert_eq!(
        python_mcap_message_count(&mcap_file),
        reader.messages().len(),
        "the Python mcap reader reads the same messages"
    );
}
