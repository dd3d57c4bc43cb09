//! The node as a ROS 2 package: `colcon build` of a workspace (target/colcon_ws) whose src/
//! links this repository (package.xml, build type ament_cargo, through colcon-ros-cargo and
//! cargo-ament-build from PyPI: scripts/colcon-setup) and msg/ (lhmpp_msgs, ament_cmake with
//! the rosidl generators of target/rosenv), then the installed binary, found through the ament
//! index as `ros2 run lhmpp lhmpp` finds it, started with `--ros-args --params-file` on the
//! installed launch_configs/camera.yaml (plus `-p` and `-r`) against the rclpy peer of
//! tests/node_rclpy.rs. And every launch_configs/*.yaml through rcl's parameter-file parser
//! (tests/python/params_file_check.py).
//!
//! The workspace's build directory for lhmpp is a link to this test build's cargo target
//! directory, and colcon builds with the same profile and features, so cargo finds the crate
//! up to date: the colcon build costs seconds, not a second release build of the crate.

mod dds_domain;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

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

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs a script of scripts/, asserting success; returns its stdout.
fn script(name: &str) -> String {
    let started = Instant::now();
    let out = Command::new(root().join("scripts").join(name))
        .output()
        .unwrap_or_else(|e| panic!("scripts/{name}: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    eprintln!(
        "scripts/{name} ({:.1} s): {stdout}{}",
        started.elapsed().as_secs_f64(),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "scripts/{name} failed");
    stdout
}

/// `link` made a symbolic link to `target`, whatever was there before.
fn symlink(target: &Path, link: &Path) {
    if std::fs::read_link(link).ok().as_deref() == Some(target) {
        return;
    }
    match std::fs::symlink_metadata(link) {
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(link).unwrap(),
        Ok(_) => std::fs::remove_file(link).unwrap(),
        Err(_) => {}
    }
    std::fs::create_dir_all(link.parent().unwrap()).unwrap();
    std::os::unix::fs::symlink(target, link)
        .unwrap_or_else(|e| panic!("{} -> {}: {e}", link.display(), target.display()));
}

/// `colcon build` of target/colcon_ws; returns the workspace and the build's wall time.
fn build_workspace(python: &Path) -> (PathBuf, Duration) {
    let root = root();
    let venv = python.parent().and_then(Path::parent).unwrap();
    // lhmpp_msgs for the peer, and the links its CMake exports need (cached when msg/ is
    // unchanged).
    script("build-msgs");
    let colcon_bin = PathBuf::from(script("colcon-setup").trim());
    let ws = root.join("target/colcon_ws");
    symlink(&root, &ws.join("src/lhmpp"));
    symlink(&root.join("msg"), &ws.join("src/lhmpp_msgs"));
    // The binary this test was built with is target/<profile>/lhmpp: point colcon's build
    // directory for lhmpp (cargo's --target-dir) at that target directory.
    let exe = PathBuf::from(env!("CARGO_BIN_EXE_lhmpp"));
    let profile_dir = exe.parent().unwrap();
    let target_dir = profile_dir.parent().unwrap();
    symlink(target_dir, &ws.join("build/lhmpp"));
    let mut cargo_args: Vec<&str> = match profile_dir.file_name().unwrap().to_str().unwrap() {
        "release" => vec!["--release"],
        "debug" => vec![],
        other => panic!("profile {other}: expected release or debug"),
    };
    if !cfg!(feature = "avx512") {
        cargo_args.push("--no-default-features");
    }
    if cfg!(feature = "cuda") {
        cargo_args.extend(["--features", "cuda"]);
    }
    let mtime = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).unwrap();
    let exe_before: SystemTime = mtime(&exe);

    let path = format!(
        "{}:{}:{}",
        colcon_bin.display(),
        venv.join("bin").display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let started = Instant::now();
    let out = Command::new(colcon_bin.join("colcon"))
        .current_dir(&ws)
        .args(["--log-base", "log", "build", "--base-paths", "src"])
        .args(["--build-base", "build", "--install-base", "install"])
        .args(["--event-handlers", "console_cohesion-", "--cargo-args"])
        .args(&cargo_args)
        .args(["--cmake-args", "-DBUILD_TESTING=OFF"])
        .arg(format!(
            "-DPython3_EXECUTABLE={}",
            venv.join("bin/python").display()
        ))
        .env("PATH", path)
        .env("AMENT_PREFIX_PATH", venv)
        .env("CMAKE_PREFIX_PATH", venv)
        .env_remove("COLCON_PREFIX_PATH")
        .output()
        .expect("colcon runs");
    let wall = started.elapsed();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("colcon build ({:.1} s):\n{log}", wall.as_secs_f64());
    assert!(out.status.success(), "colcon build failed");
    for pkg in ["lhmpp_msgs", "lhmpp"] {
        assert!(
            log.contains(&format!("Finished <<< {pkg}")),
            "colcon did not build {pkg}"
        );
    }
    // cargo found the test build's artifacts up to date: nothing recompiled or relinked.
    assert_eq!(
        mtime(&exe),
        exe_before,
        "the colcon build rebuilt {}: its cargo arguments {cargo_args:?} or environment \
         differ from the test build's",
        exe.display()
    );
    let installed = ws.join("install/lhmpp/lib/lhmpp/lhmpp");
    assert_eq!(
        std::fs::read(&installed).expect("installed binary"),
        std::fs::read(&exe).unwrap(),
        "{} is not the built binary",
        installed.display()
    );
    for f in std::fs::read_dir(root.join("launch_configs")).unwrap() {
        let name = f.unwrap().file_name();
        let installed = ws
            .join("install/lhmpp/share/lhmpp/launch_configs")
            .join(&name);
        assert!(installed.is_file(), "{} not installed", installed.display());
    }
    assert!(ws.join("install/lhmpp/share/lhmpp/package.xml").is_file());
    (ws, wall)
}

#[test]
fn colcon_builds_the_package_and_its_binary_serves_an_rclpy_peer() {
    let python = ros_python();
    let root = root();
    let (ws, build_time) = build_workspace(&python);
    eprintln!("workspace built in {:.1} s", build_time.as_secs_f64());
    let install = ws.join("install");
    let msgs = install.join("lhmpp_msgs");
    let venv = python.parent().and_then(Path::parent).unwrap();

    let domain = dds_domain::test_domain(60);
    // `ros2 run lhmpp lhmpp ARGS`: source the workspace, find the package's prefix in the ament
    // index, run lib/lhmpp/lhmpp (ros2cli is not among the PyPI wheels, so this is its lookup).
    let params = install.join("lhmpp/share/lhmpp/launch_configs/camera.yaml");
    let ros_args = [
        "--ros-args".to_string(),
        "--params-file".into(),
        params.display().to_string(),
        "-r".into(),
        "__ns:=/colcon_test".into(),
        "-r".into(),
        "/camera/image_raw:=/colcon_test/cam0/image_raw".into(),
        "-p".into(),
        format!("domain_id:={domain}"),
        "-p".into(),
        "dds_interfaces:=[127.0.0.1]".into(),
        "-p".into(),
        "inputs.compressed_image_topics:=[cam1/image_raw/compressed]".into(),
        "-p".into(),
        "inputs.camera_info_topics:=[]".into(),
        "-p".into(),
        "inputs.pose_topic:=body_pose".into(),
        "-p".into(),
        "inputs.person_mask:=off".into(),
        "-p".into(),
        "frame_store.debounce_ms:=50".into(),
        "-p".into(),
        "model.num_points:=1024".into(),
        "-p".into(),
        "outputs.render_size:=64".into(),
        "-p".into(),
        "outputs.render_rate_hz:=10".into(),
        "-p".into(),
        "outputs.dir:=''".into(),
        "-p".into(),
        "outputs.preview_rate_hz:=4".into(),
    ];
    let mut node = Command::new("bash");
    node.arg("-c")
        .arg(
            r#". "$WS/install/setup.sh" && prefix=$("$PY" -c 'from ament_index_python.packages import get_package_prefix as p; print(p("lhmpp"))') && exec "$prefix/lib/lhmpp/lhmpp" "$@""#,
        )
        .arg("ros2-run")
        .args(&ros_args)
        .env("WS", &ws)
        .env("PY", &python)
        .env("AMENT_PREFIX_PATH", venv)
        .env_remove("COLCON_PREFIX_PATH")
        .env_remove("RUST_LOG")
        .current_dir(std::env::temp_dir())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    let mut node = KillOnDrop(node.spawn().expect("the installed lhmpp starts"));

    let started = Instant::now();
    let peer = Command::new(&python)
        .arg(root.join("tests/python/rclpy_peer.py"))
        .args(["--image-topic", "/colcon_test/cam0/image_raw"])
        .args([
            "--compressed-topic",
            "/colcon_test/cam1/image_raw/compressed",
        ])
        .args(["--pose-topic", "/colcon_test/body_pose"])
        .args(["--avatar-topic", "/colcon_test/avatar"])
        .args(["--status-topic", "/colcon_test/status"])
        .args(["--render-topic", "/colcon_test/render/cam0/image_raw"])
        .args(["--preview-topic", "/colcon_test/avatar/points"])
        .args(["--width", "64", "--height", "96", "--render-side", "64"])
        .args(["--gaussians", "1024", "--person", "person_0"])
        .args(["--min-revisions", "2", "--timeout", "120"])
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        .env(
            "AMENT_PREFIX_PATH",
            format!("{}:{}", msgs.display(), venv.display()),
        )
        .env("PYTHONPATH", msgs.join("lib/python3.11/site-packages"))
        .env("LD_LIBRARY_PATH", msgs.join("lib"))
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

    // SIGINT (what ros2 run forwards on Ctrl-C) stops the node cleanly: exit 0, the summary.
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
    eprintln!("node: {summary}");
    assert_eq!(code, Some(0), "node exit status; summary: {summary}");
    assert!(summary.contains("reconstructions"), "{summary}");
}

#[test]
fn every_launch_config_is_a_ros2_params_file_rclpy_reads_whole() {
    let python = ros_python();
    let root = root();
    let mut files: Vec<PathBuf> = std::fs::read_dir(root.join("launch_configs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(files.len() >= 5, "launch configs: {files:?}");
    let out = Command::new(&python)
        .arg(root.join("tests/python/params_file_check.py"))
        .args(&files)
        // Its nodes have no topics; keep their discovery traffic on this machine.
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        .output()
        .expect("params_file_check.py runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{stdout}");
    for f in &files {
        assert!(
            stdout.contains(&format!("ok {} ", f.display())),
            "{} not checked: {stdout}",
            f.display()
        );
    }
    // And lhmpp reads each the same way (`lhmpp config --config FILE` validates it).
    for f in &files {
        let out = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
            .args(["config", "--config"])
            .arg(f)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "lhmpp config --config {}: {}",
            f.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}
