//! Camera-only perception under load: `lhmpp loadgen` publishes 2 cameras × 30 Hz × 640×480
//! JPEG frames of a walking synthetic person on loopback into
//! `lhmpp run --config launch_configs/perception_load.yaml` (no mask topic: every frame goes
//! to perception). Perception runs on its own worker, newest frame per camera wins: the
//! pipeline keeps taking frames and reconstructing, perception holds a steady rate and drops
//! the frames it cannot take (counted), memory stays bounded. `scripts/perception-load` runs
//! the same for longer.

mod dds_domain;

mod load_support;

use load_support::{interrupt, lhmpp, number_after, KillOnDrop};
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

const SECONDS: u64 = 30;

#[test]
fn two_vga_streams_are_perceived_at_a_steady_rate_without_stalling_the_pipeline() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let domain = dds_domain::test_domain(41);
    let report = tempfile::tempdir().unwrap();
    let mut node = KillOnDrop(
        lhmpp()
            .current_dir(root)
            .args(["run", "--config", "launch_configs/perception_load.yaml"])
            .args(["--set", &format!("domain_id={domain}")])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(report.path().join("node.log")).unwrap())
            .spawn()
            .expect("lhmpp run starts"),
    );
    let pid = node.0.id();
    let load = lhmpp()
        .args(["loadgen", "--seconds", &SECONDS.to_string()])
        .args(["--cameras", "2", "--width", "640", "--height", "480"])
        .args(["--domain", &domain.to_string()])
        .args(["--watch-pid", &pid.to_string()])
        .args(["--report", report.path().to_str().unwrap()])
        .output()
        .expect("lhmpp loadgen runs");
    assert!(
        load.status.success(),
        "{}",
        String::from_utf8_lossy(&load.stderr)
    );
    eprintln!("{}", String::from_utf8_lossy(&load.stdout));
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
    let log = std::fs::read_to_string(report.path().join("node.log")).unwrap();
    let errors: Vec<_> = log
        .lines()
        .filter(|l| l.contains("ERROR"))
        .take(5)
        .collect();
    assert!(errors.is_empty(), "errors in the node's log: {errors:#?}");

    let run = summary
        .lines()
        .find(|l| l.starts_with("frames "))
        .expect("run line");
    let perception = summary
        .lines()
        .find(|l| l.starts_with("perception: "))
        .expect("perception summary line");
    let frames = number_after(run, "frames");
    let perceived = number_after(perception, "frames");
    let masked = number_after(perception, "cropped by its mask");
    let nobody = number_after(perception, "nobody found");
    let dropped = number_after(perception, "dropped for newer");
    let poses = number_after(perception, "camera poses");
    // Every frame the pipeline took went to perception: perceived, or replaced by a newer
    // frame of its camera (at most the last one per camera is still pending at the stop).
    assert!(
        perceived + dropped <= frames && frames <= perceived + dropped + 8.0,
        "{run}\n{perception}"
    );
    // Perception holds a rate (measured about 20 Hz for the two cameras on 2 busy cores) and
    // finds the person in nearly every frame it reads.
    let rate = perceived / SECONDS as f64;
    assert!(rate >= 8.0, "perception at {rate:.1} Hz: {perception}");
    assert!(nobody <= 0.05 * perceived, "{perception}");
    assert!(masked + nobody == perceived, "{perception}");
    assert!(poses >= 0.9 * masked.min(perceived) / 2.0, "{perception}");
    // The pipeline was not stalled by perception: it kept reconstructing.
    assert!(number_after(run, "reconstructions") >= 1.0, "{run}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.path().join("summary.json")).unwrap())
            .unwrap();
    let max = json["rss"]["max_mb"].as_f64().unwrap();
    assert!(max < 300.0, "RSS max {max:.0} MB: {}", json["rss"]);
}
