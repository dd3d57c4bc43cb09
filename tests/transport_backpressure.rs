//! A subscriber that never reads, or that is killed with SIGKILL, never blocks the publisher;
//! a publisher restarted after a SIGKILL finds the service usable (stale resources cleaned);
//! the segments are readable only by their owner.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use lhmpp::transport::{FrameView, PayloadBody, ShmNode, ShmOptions, ShmPublisher, Stamp};

static COUNTER: AtomicUsize = AtomicUsize::new(0);

/// Environment variable that turns this test binary into a publisher child process.
const CHILD_ENV: &str = "LHMPP_TEST_CHILD_PUBLISHER";

/// A bound no healthy run comes near; the point is that publishing never waits on readers.
const GENEROUS: Duration = Duration::from_secs(60);

fn unique_person(tag: &str) -> String {
    format!(
        "{tag}{}x{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

fn frame_pixels() -> Vec<u8> {
    (0..64 * 48 * 4).map(|i| (i % 253) as u8).collect()
}

fn frame(pixels: &[u8]) -> PayloadBody<'_> {
    PayloadBody::Frame(FrameView {
        width: 64,
        height: 48,
        channels: 4,
        pixels,
        alpha: None,
        depth: None,
    })
}

/// Publishes revisions 1..=1000; returns the time taken and the (still connected) publisher.
fn publish_1000_frames(node: &ShmNode, person: &str) -> (Duration, ShmPublisher) {
    let publisher = node.frame_publisher(person, "cam0").unwrap();
    let pixels = frame_pixels();
    let started = Instant::now();
    for revision in 1..=1000 {
        publisher
            .publish(Stamp::now(revision), &frame(&pixels))
            .unwrap();
    }
    (started.elapsed(), publisher)
}

/// Spawns `lhmpp shm-echo` for `person` and returns once it has subscribed.
fn spawn_echo(person: &str) -> Child {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args([
            "shm-echo",
            "--person",
            person,
            "--camera",
            "cam0",
            "--timeout",
            "120",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn lhmpp shm-echo");
    let mut line = String::new();
    BufReader::new(child.stdout.as_mut().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.starts_with("ready "), "{line:?}");
    child
}

fn sigkill(child: &mut Child) {
    child.kill().unwrap(); // SIGKILL on Unix
    child.wait().unwrap();
}

#[test]
fn subscriber_that_never_reads_does_not_block_the_publisher() {
    let person = unique_person("idle");
    let node = ShmNode::new(&format!("{person}-test"), ShmOptions::default()).unwrap();
    let idle = node.subscriber(&person, &["cam0"]).unwrap();
    let (took, _publisher) = publish_1000_frames(&node, &person);
    assert!(took < GENEROUS, "1000 publishes took {took:?}");
    drop(idle);
}

#[test]
fn killed_subscriber_does_not_block_the_publisher_and_others_still_receive() {
    let person = unique_person("killsub");
    let mut echo = spawn_echo(&person);
    sigkill(&mut echo);
    let node = ShmNode::new(&format!("{person}-test"), ShmOptions::default()).unwrap();
    let mut live = node.subscriber(&person, &["cam0"]).unwrap();
    let (took, _publisher) = publish_1000_frames(&node, &person);
    assert!(took < GENEROUS, "1000 publishes took {took:?}");
    // The live subscriber's latest-wins queue holds the newest frame.
    let mut last = None;
    while let Some(sample) = live.try_receive().unwrap() {
        last = Some(sample.decode().unwrap().stamp.revision);
    }
    assert_eq!(last, Some(1000));
}

/// A subscriber killed mid-stream, while it is reading (and may hold loaned samples), does not
/// block the publisher, and a live subscriber receives the stream to its end.
#[test]
fn subscriber_killed_mid_stream_does_not_block_the_publisher() {
    let person = unique_person("midstream");
    let node = ShmNode::new(&format!("{person}-test"), ShmOptions::default()).unwrap();
    let mut live = node.subscriber(&person, &["cam0"]).unwrap();
    let publisher = node.frame_publisher(&person, "cam0").unwrap();
    let mut echo = spawn_echo(&person);
    let pixels = frame_pixels();
    let started = Instant::now();
    let publish = |revisions: std::ops::RangeInclusive<u64>| {
        for revision in revisions {
            publisher
                .publish(Stamp::now(revision), &frame(&pixels))
                .unwrap();
        }
    };
    publish(1..=999);
    sigkill(&mut echo);
    publish(1000..=2000);
    let took = started.elapsed();
    assert!(took < 2 * GENEROUS, "2000 publishes took {took:?}");
    let mut last = None;
    while let Some(sample) = live.try_receive().unwrap() {
        last = Some(sample.decode().unwrap().stamp.revision);
    }
    assert_eq!(last, Some(2000));
}

#[test]
fn publisher_restarted_after_sigkill_starts_cleanly() {
    let person = unique_person("restart");
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "child_publisher_process",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, &person)
        .stdout(Stdio::piped())
        .spawn()
        .expect("re-run this test binary as a publisher");
    let mut reader = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    // libtest prints `test child_publisher_process ... ` before the child's own output.
    while !line.contains("published") {
        line.clear();
        assert!(
            reader.read_line(&mut line).unwrap() > 0,
            "child publisher ended early"
        );
    }
    sigkill(&mut child);

    // One publisher per service is allowed: this only works if the dead one was cleaned up.
    let node = ShmNode::new(&format!("{person}-new"), ShmOptions::default()).unwrap();
    let mut subscriber = node.subscriber(&person, &["cam0"]).unwrap();
    let publisher = node.frame_publisher(&person, "cam0").unwrap();
    let pixels = frame_pixels();
    assert_eq!(
        publisher.publish(Stamp::now(7), &frame(&pixels)).unwrap(),
        1
    );
    let sample = subscriber
        .try_receive()
        .unwrap()
        .expect("frame from the new publisher");
    assert_eq!(sample.decode().unwrap().stamp.revision, 7);
}

/// Not a check on its own: when `CHILD_ENV` is set (by the restart test), this process
/// becomes a frame publisher that announces itself and then waits to be killed.
#[test]
fn child_publisher_process() {
    let Ok(person) = std::env::var(CHILD_ENV) else {
        return;
    };
    let node = ShmNode::new(&format!("{person}-old"), ShmOptions::default()).unwrap();
    let publisher = node.frame_publisher(&person, "cam0").unwrap();
    publisher
        .publish(Stamp::now(1), &frame(&frame_pixels()))
        .unwrap();
    println!("published");
    loop {
        std::thread::park(); // until SIGKILL
    }
}

/// Shared-memory segments are readable only by their owner: every file the publishers and a
/// subscriber add to /dev/shm has no group or other permission bits (iceoryx2's one shared
/// management counter, `*.global_mgmt`, excepted; it holds no payload).
#[test]
fn shared_memory_segments_are_readable_only_by_their_owner() {
    use std::os::unix::fs::PermissionsExt;
    let listing = || -> std::collections::BTreeSet<String> {
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect()
    };
    let before = listing();
    let person = unique_person("perm");
    let node = ShmNode::new(&format!("{person}-test"), ShmOptions::default()).unwrap();
    let mut subscriber = node.subscriber(&person, &["cam0"]).unwrap();
    let publisher = node.frame_publisher(&person, "cam0").unwrap();
    let _avatars = node.avatar_publisher(&person).unwrap();
    let pixels = frame_pixels();
    publisher.publish(Stamp::now(1), &frame(&pixels)).unwrap();
    assert!(subscriber.try_receive().unwrap().is_some());
    let added: Vec<String> = listing().difference(&before).cloned().collect();
    assert!(!added.is_empty(), "no shared-memory file was created");
    for name in added.iter().filter(|n| !n.ends_with(".global_mgmt")) {
        let Ok(meta) = std::fs::metadata(format!("/dev/shm/{name}")) else {
            continue; // removed meanwhile by a test running beside this one
        };
        let mode = meta.permissions().mode() & 0o777;
        assert_eq!(mode & 0o077, 0, "/dev/shm/{name} has mode {mode:o}");
    }
}
