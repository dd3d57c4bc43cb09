//! Two node processes share three people over DDS (issue: several nodes sharing them).
//!
//! `lhmpp loadgen --people 3` publishes one room camera (JPEG, 10 Hz) of three people walking
//! past one another on loopback; two `lhmpp run` processes with `cluster.members: 2` (index 0
//! and 1) both subscribe to it, perceive and track every person (camera only), and each
//! reconstructs only the persons whose id hashes to it. Checked from their logs:
//! - every person is reconstructed, and no person by both nodes;
//! - after node 1 is killed (SIGKILL: no goodbye), node 0 reconstructs node 1's persons within
//!   the member timeout plus a reconstruction.

mod dds_domain;
mod load_support;

use load_support::{interrupt, lhmpp, without_ansi, KillOnDrop};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Each node's avatars as they are published: person id and when the line arrived.
type Published = Arc<Mutex<Vec<(String, Instant)>>>;

/// Starts cluster member `index` on `domain`; its log lines `avatar published person=…` are
/// collected in the returned list (and the whole log is kept in `log`).
fn member(index: u32, domain: u16, log: &Path) -> (KillOnDrop, Published) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut child = lhmpp()
        .current_dir(root)
        .args([
            "--log",
            "info",
            "run",
            "--config",
            "launch_configs/soak_people.yaml",
        ])
        .args(["--set", &format!("domain_id={domain}")])
        .args(["--set", "cluster.members=2"])
        .args(["--set", &format!("cluster.index={index}")])
        .args([
            "--set",
            "inputs.compressed_image_topics=[/loadgen/cam0/image_raw/compressed]",
        ])
        .args([
            "--set",
            "inputs.camera_info_topics=[/loadgen/cam0/camera_info]",
        ])
        .args(["--set", "outputs.render_rate_hz=0"])
        .args(["--set", "tracking.forget_after=30.0"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lhmpp run starts");
    let stderr = child.stderr.take().unwrap();
    let published: Published = Arc::default();
    let out = published.clone();
    let mut file = std::fs::File::create(log).unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let line = without_ansi(&line);
            use std::io::Write;
            let _ = writeln!(file, "{line}");
            if line.contains("avatar published") {
                if let Some(at) = line.find("person=") {
                    let id = line[at + 7..]
                        .split_whitespace()
                        .next()
                        .unwrap_or("")
                        .trim_matches('"')
                        .to_owned();
                    out.lock().unwrap().push((id, Instant::now()));
                }
            }
        }
    });
    (KillOnDrop(child), published)
}

fn persons(published: &Published) -> BTreeSet<String> {
    published
        .lock()
        .unwrap()
        .iter()
        .map(|(p, _)| p.clone())
        .collect()
}

/// Waits up to `limit` for `done`, polling.
fn wait_for(limit: Duration, mut done: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    done()
}

#[test]
fn two_node_processes_reconstruct_each_person_once_and_hand_over_on_a_kill() {
    let domain = dds_domain::test_domain(100);
    let dir = tempfile::tempdir().unwrap();
    let (node0, published0) = member(0, domain, &dir.path().join("node0.log"));
    let (mut node1, published1) = member(1, domain, &dir.path().join("node1.log"));
    let mut load = KillOnDrop(
        lhmpp()
            .args(["loadgen", "--people", "3", "--cameras", "1", "--rate", "10"])
            .args(["--width", "320", "--height", "240", "--frames", "240"])
            .args(["--seconds", "150", "--seed", "1"])
            .args(["--domain", &domain.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("lhmpp loadgen starts"),
    );
    let logs = || {
        let tail = |name: &str| {
            let text = std::fs::read_to_string(dir.path().join(name)).unwrap_or_default();
            let lines: Vec<&str> = text.lines().collect();
            lines[lines.len().saturating_sub(15)..].join("\n")
        };
        format!(
            "node 0 published {:?}, node 1 published {:?}\n--- node 0:\n{}\n--- node 1:\n{}",
            persons(&published0),
            persons(&published1),
            tail("node0.log"),
            tail("node1.log")
        )
    };
    // Both members reconstruct their share: three persons between them, none twice.
    let shared = wait_for(Duration::from_secs(90), || {
        let (a, b) = (persons(&published0), persons(&published1));
        !a.is_empty() && !b.is_empty() && a.len() + b.len() >= 3
    });
    let (a, b) = (persons(&published0), persons(&published1));
    assert!(
        shared,
        "the nodes did not share the persons in time: {}",
        logs()
    );
    assert!(
        a.is_disjoint(&b),
        "a person reconstructed by both nodes: {}",
        logs()
    );

    // Node 1 dies without a word; node 0 takes its persons over.
    node1.0.kill().unwrap();
    let killed = Instant::now();
    let _ = node1.0.wait();
    let handed = wait_for(Duration::from_secs(30), || {
        let now = persons(&published0);
        b.iter().all(|p| now.contains(p))
    });
    let taken: BTreeMap<String, Duration> = published0
        .lock()
        .unwrap()
        .iter()
        .filter(|(p, at)| b.contains(p) && *at > killed)
        .map(|(p, at)| (p.clone(), *at - killed))
        .fold(BTreeMap::new(), |mut m, (p, d)| {
            m.entry(p).or_insert(d);
            m
        });
    eprintln!(
        "node 0 reconstructed {a:?}, node 1 {b:?}; after the kill node 0 took over {taken:?}"
    );
    assert!(handed, "node 1's persons not taken over: {}", logs());
    // Member timeout (2 s) plus a reconstruction of the tiny preset on a busy machine.
    let slowest = taken.values().max().copied().unwrap_or_default();
    assert!(
        slowest < Duration::from_secs(20),
        "hand-over took {slowest:?}"
    );

    let _ = load.0.kill();
    interrupt(node0.0.id());
    let _ = load.0.wait();
}
