//! Logging of `lhmpp run`: quiet by default (the node's own lines at info, RustDDS and
//! ros2-client only at error), `--log` opens everything, a clean shutdown logs no error, and
//! a config that cannot run fails with one line before any DDS participant exists.

mod dds_domain;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn lhmpp() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    c.env_remove("RUST_LOG")
        .env_remove("RUST_BACKTRACE")
        .env_remove("ROS_DOMAIN_ID");
    c
}

/// Runs `lhmpp [log] run` live (no publisher, loopback) for 10 s, stops it with SIGINT;
/// returns (exit code, stdout + stderr lines).
fn live_run_for_10_s(log: Option<&str>, domain: u32) -> (Option<i32>, Vec<String>) {
    let mut cmd = lhmpp();
    if let Some(filter) = log {
        cmd.args(["--log", filter]);
    }
    let out = tempfile::tempdir().unwrap();
    let child = cmd
        .arg("run")
        .args(["--set", &format!("domain_id={domain}")])
        .args(["--set", "dds_interfaces=[127.0.0.1]"])
        .args(["--set", "namespace=/quiet_logs_test"])
        .args(["--set", &format!("outputs.dir={}", out.path().display())])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lhmpp starts");
    let pid = child.id();
    let waiter = std::thread::spawn(move || child.wait_with_output().unwrap());
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(10) && !waiter.is_finished() {
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status();
    let output = waiter.join().unwrap();
    let text = String::from_utf8_lossy(&output.stdout).into_owned()
        + &String::from_utf8_lossy(&output.stderr);
    (
        output.status.code(),
        text.lines().map(str::to_owned).collect(),
    )
}

#[test]
fn a_ten_second_run_is_quiet_by_default_and_log_opens_everything() {
    let domain = u32::from(dds_domain::test_domain(80));
    let verbose_domain = u32::from(dds_domain::test_domain(81));
    let verbose = std::thread::spawn(move || live_run_for_10_s(Some("info"), verbose_domain));
    let (code, lines) = live_run_for_10_s(None, domain);
    let (verbose_code, verbose_lines) = verbose.join().unwrap();
    eprintln!(
        "default level: {} lines; --log info: {} lines",
        lines.len(),
        verbose_lines.len()
    );
    let all = lines.join("\n");
    assert_eq!(code, Some(0), "clean SIGINT stop exits 0:\n{all}");
    assert!(lines.len() < 50, "{} lines:\n{all}", lines.len());
    // Nobody publishes the camera topic here: the one warning is the one naming it (after 5 s),
    // once.
    let silent: Vec<&String> = lines
        .iter()
        .filter(|l| l.contains("no message on camera topic /camera/image_raw"))
        .collect();
    assert_eq!(silent.len(), 1, "one silent-camera warning:\n{all}");
    let rest: Vec<&String> = lines
        .iter()
        .filter(|l| !l.contains("no message on camera topic"))
        .collect();
    assert!(
        !rest
            .iter()
            .any(|l| l.contains("ERROR") || l.contains("WARN")),
        "no other error or warning at a clean run and shutdown:\n{all}"
    );
    assert!(
        !all.contains("rustdds") && !all.contains("ros2_client"),
        "dependencies are at error by default:\n{all}"
    );
    assert!(
        all.contains("lhmpp::node"),
        "the node's own info lines show:\n{all}"
    );
    assert!(
        all.contains("reconstructions"),
        "the summary is printed:\n{all}"
    );

    let verbose_all = verbose_lines.join("\n");
    assert_eq!(verbose_code, Some(0), "{verbose_all}");
    assert!(
        verbose_all.contains("rustdds::"),
        "--log info shows the DDS library's lines:\n{verbose_all}"
    );
    // Even with everything open, shutdown logs no error of ours or of ros2-client's; the one
    // RustDDS error left is its multicast-leave on loopback-only sockets (see
    // DEFAULT_LOG_FILTER in src/cli/mod.rs).
    let errors: Vec<_> = verbose_lines
        .iter()
        .filter(|l| l.contains("ERROR") && !l.contains("leave_multicast_group"))
        .collect();
    assert!(errors.is_empty(), "errors at a clean shutdown: {errors:#?}");
}

/// Runs `lhmpp --log info run ARGS` (everything open) and returns (exit code, stderr lines).
fn failing_run(args: &[&str]) -> (Option<i32>, Vec<String>) {
    let output = lhmpp()
        .args(["--log", "info", "run"])
        .args(args)
        .args(["--set", "dds_interfaces=[127.0.0.1]"])
        .output()
        .expect("lhmpp runs");
    let stderr = String::from_utf8_lossy(&output.stderr);
    (
        output.status.code(),
        stderr
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(str::to_owned)
            .collect(),
    )
}

fn assert_one_clear_line(what: &str, code: Option<i32>, lines: &[String], expected: &[&str]) {
    let all = lines.join("\n");
    assert_eq!(code, Some(1), "{what} fails:\n{all}");
    assert!(
        !all.contains("rustdds") && !all.contains("ros2_client") && !all.contains("ROS 2 node"),
        "{what} fails before DDS starts:\n{all}"
    );
    let errors: Vec<_> = lines.iter().filter(|l| !l.contains(" INFO ")).collect();
    assert_eq!(errors.len(), 1, "{what}: one error line:\n{all}");
    assert!(errors[0].starts_with("Error: "), "{all}");
    for e in expected {
        assert!(errors[0].contains(e), "{what}: `{e}` in:\n{all}");
    }
}

#[test]
fn a_config_that_cannot_run_fails_with_one_line_before_joining_dds() {
    let (code, lines) = failing_run(&["--set", "model.checkpoint=/nonexistent/lhmpp.safetensors"]);
    assert_one_clear_line(
        "missing checkpoint",
        code,
        &lines,
        &["/nonexistent/lhmpp.safetensors", "does not exist"],
    );
    // The released-weights config asks for CUDA; a CPU build says so before anything else.
    if !cfg!(feature = "cuda") {
        let official = concat!(env!("CARGO_MANIFEST_DIR"), "/launch_configs/official.yaml");
        let (code, lines) = failing_run(&["--config", official]);
        assert_one_clear_line("CUDA device in a CPU build", code, &lines, &["cuda"]);
    }
    // At the default level the whole output is the one line.
    let output = lhmpp()
        .args([
            "run",
            "--set",
            "model.checkpoint=/nonexistent/lhmpp.safetensors",
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(output.stdout.is_empty());
}
