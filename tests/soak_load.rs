//! A minute of load: `lhmpp loadgen` publishes 4 cameras × 30 Hz × 1920×1080 JPEG frames of a
//! walking synthetic person on loopback into `lhmpp run --config launch_configs/soak.yaml`,
//! and samples the node's resident memory every second. The node keeps up by dropping frames
//! by policy (rate limit, drop-oldest input queue), keeps reconstructing, its memory stays
//! under 1 GB, its queue waits stay bounded, and its counters add up. scripts/soak runs the same
//! for 10 minutes and plots the memory (RELIABILITY.md).

mod dds_domain;

mod load_support;

use load_support::{interrupt, lhmpp, number_after, KillOnDrop};
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

#[test]
fn a_minute_of_four_1080p_streams_keeps_the_node_reconstructing_and_the_counters_true() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let domain = dds_domain::test_domain(40);
    let report = tempfile::tempdir().unwrap();
    let node = KillOnDrop(
        lhmpp()
            .current_dir(root)
            .args(["run", "--config", "launch_configs/soak.yaml"])
            .args(["--set", &format!("domain_id={domain}")])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(report.path().join("node.log")).unwrap())
            .spawn()
            .expect("lhmpp run starts"),
    );
    let pid = node.0.id();
    let load = lhmpp()
        .args([
            "loadgen",
            "--seconds",
            "60",
            "--domain",
            &domain.to_string(),
        ])
        .args(["--watch-pid", &pid.to_string()])
        // The input queue fills within ~15 s; fit the second half.
        .args(["--warmup-fraction", "0.5"])
        .arg("--report")
        .arg(report.path())
        .stderr(Stdio::null())
        .output()
        .expect("lhmpp loadgen runs");
    let load_out = String::from_utf8_lossy(&load.stdout).to_string();
    eprintln!("{load_out}");
    assert!(
        load.status.success(),
        "loadgen: {:?}\n{load_out}",
        load.status
    );

    let mut node = node;
    interrupt(pid);
    let mut waited = Duration::ZERO;
    while node.0.try_wait().unwrap().is_none() && waited < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(100));
        waited += Duration::from_millis(100);
    }
    let status = node
        .0
        .try_wait()
        .unwrap()
        .expect("the node stops on SIGINT");
    let mut summary = String::new();
    std::io::Read::read_to_string(node.0.stdout.as_mut().unwrap(), &mut summary).unwrap();
    eprintln!("{summary}");
    assert!(status.success(), "node exit {status:?}");
    // No ERROR line in the node's log under load (a reader-count query on outputs nobody had
    // subscribed to once logged one per publish and poll).
    let log = std::fs::read_to_string(report.path().join("node.log")).unwrap();
    let errors: Vec<_> = log
        .lines()
        .filter(|l| l.contains("ERROR"))
        .take(5)
        .collect();
    assert!(errors.is_empty(), "errors in the node's log: {errors:#?}");

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.path().join("summary.json")).unwrap())
            .unwrap();
    let published = json["published"].as_u64().unwrap();
    let late = json["late"].as_u64().unwrap();
    // The generator held its schedule: every one of the 7,200 frames due was sent or counted late.
    assert!(
        published + late >= 7_100,
        "{published} published, {late} late"
    );
    assert!(published >= 5_000, "{published} published");

    // Memory: flat once the input queue is full. Before latched outputs held their newest
    // message while nobody listened, DDS kept every avatar and preview cloud: +35-42 MB/min.
    let rss = &json["rss"];
    let slope = rss["slope_mb_per_min"].as_f64().unwrap();
    let max = rss["max_mb"].as_f64().unwrap();
    assert!(rss["exited_at_s"].is_null(), "the node died: {rss}");
    assert!(rss["samples"].as_u64().unwrap() >= 55, "{rss}");
    eprintln!("RSS slope {slope:+.1} MB/min, max {max:.0} MB");
    // Frames wait in the input queue encoded (86 KB each), not decoded (6 MB): 113 MB measured;
    // with decoded frames in the queue it was 324 MB.
    assert!(max < 250.0, "RSS max {max:.0} MB: {rss}");
    assert!(
        slope < 10.0,
        "RSS grows {slope:+.1} MB/min after the warm-up: {rss}"
    );
    let csv = std::fs::read_to_string(report.path().join("rss.csv")).unwrap();
    assert!(csv.starts_with("t_s,rss_mb\n") && csv.lines().count() > 55);

    // The node kept reconstructing under load, and its counters add up.
    let run = summary
        .lines()
        .find(|l| l.starts_with("frames "))
        .expect("run summary line");
    let inputs = summary
        .lines()
        .find(|l| l.starts_with("inputs: "))
        .expect("inputs summary line");
    let frames = number_after(run, "frames");
    let reconstructions = number_after(run, "reconstructions");
    // The stream cycles 8 walk phases per camera (32 images for 16 view slots): once the held
    // views cover them, every new frame is a near-duplicate and nothing is left to reconstruct
    // (measured: 4 in a 60 s run, 19 and 138 in 150 s runs, by how the first views fell).
    // Keeping up means taking frames all along and dropping the rest by policy. Frames taken
    // share the 2 cores with the reconstructions: 1677 frames beside 4 reconstructions, 967
    // beside 55 (both measured 2026-12-06 on 2 cores).
    assert!(reconstructions >= 1.0, "no reconstruction: {run}");
    assert!(frames >= 800.0, "{frames} frames taken in a minute: {run}");
    assert!(number_after(run, "views held") >= 8.0, "{run}");
    let received = number_after(inputs, "received");
    let dropped = number_after(inputs, "queue dropped");
    // Each camera frame comes with its CameraInfo: what the endpoint decoded is at most both.
    assert!(received <= 2.0 * published as f64, "{inputs}");
    assert!(frames > 0.0 && frames <= received, "{run}\n{inputs}");
    assert!(dropped <= received, "{inputs}");
    // Queue waits stay bounded (drop-oldest keeps the freshest frames), not growing with time.
    let wait_p99 = number_after(inputs, "p99");
    assert!(wait_p99 < 5_000.0, "queue wait p99 {wait_p99} ms: {inputs}");
}
