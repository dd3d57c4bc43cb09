//! Replay tests: the committed bags played through the whole node pipeline (decode →
//! frame store → scheduler → network → avatar → render → files), as `lhmpp run` does.

use lhmpp::config::NodeConfig;
use lhmpp::splat::read_ply;
use lhmpp::testing::bytes_under;
use std::collections::BTreeMap;
use std::path::Path;

fn demo_config(out: &Path, extra: &[&str]) -> NodeConfig {
    let mut overrides = vec![
        format!("outputs.dir={}", out.display()),
        format!("replay.bag={}/bags/demo.mcap", env!("CARGO_MANIFEST_DIR")),
    ];
    overrides.extend(extra.iter().map(|s| s.to_string()));
    NodeConfig::load(
        Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/launch_configs/demo.yaml"
        )),
        &overrides,
    )
    .unwrap()
}

#[test]
fn demo_bag_replays_into_an_avatar_and_rendered_frames() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), &[]);
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    // The demo bag holds 4 input views; all are distinct, so all are held and encoded once.
    assert_eq!(summary.stats.frames, 4);
    // Each camera's mask follows its frame in the bag: every frame waited for and got its own.
    assert_eq!(summary.stats.masked, 4);
    assert_eq!(summary.views_held, 4);
    assert_eq!(summary.encoded_views, 4);
    // Perception reads the person inside each mask, so the calibrated views are refined at
    // the end of the replay: the views are reconstructed once more and the fit, when it beats
    // the network's avatar on its held-out view, is published as a revision of its own.
    assert_eq!(summary.stats.read_in_given_masks, 4);
    assert_eq!(summary.stats.refinements, 1);
    assert_eq!(
        summary.stats.reconstructions, 2,
        "the views, then their rerun to refine"
    );
    // The refined avatar, when the fit beat the network's, is published under a later revision.
    assert_eq!(summary.revision > 1, summary.stats.refinements_kept == 1);
    let avatar = read_ply(&dir.path().join("avatar_person_0.ply")).unwrap();
    // The refinement may grow Gaussians where the silhouettes ask for them.
    assert!(avatar.gaussians.len() >= config.model.num_points);
    assert!(avatar.skin.is_some(), "the avatar PLY carries its skinning");
    assert!(avatar
        .gaussians
        .positions
        .iter()
        .all(|p| p.is_finite() && p.y > -0.6 && p.y < 2.3));
    // 24 animation frames from each of the 4 virtual cameras.
    assert_eq!(summary.animation_frames, 24 * 4);
    let frame = image::open(dir.path().join("frames/person_0_cam0_012.png")).unwrap();
    assert_eq!(frame.width(), config.outputs.render_size);
}

/// The files stay within `outputs.max_disk_mb`: the 96 end-of-replay frames do not fit beside
/// the avatar, so the oldest frames go; the avatar (latest only by default: no numbered
/// revision files) stays whole, and the summary counts what was written and removed.
#[test]
fn outputs_stay_within_max_disk_mb_and_keep_the_latest_avatar() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), &["outputs.max_disk_mb=1.2"]);
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    assert_eq!(summary.animation_frames, 24 * 4);
    let files = summary.files.expect("files were written");
    let on_disk = bytes_under(dir.path());
    assert_eq!(files.held_bytes, on_disk);
    assert!(on_disk <= 1_200_000, "{files}");
    // The network's avatar, the refined one when the fit beat it, and the frames.
    assert!(
        (1 + 24 * 4..=2 + 24 * 4).contains(&files.written_files),
        "{files}"
    );
    assert!(files.removed_files > 0, "{files}");
    // A later avatar replaces the latest file by a rename (counted neither held nor removed).
    let replaced = files.written_files - 24 * 4 - 1;
    assert_eq!(
        files.held_files + files.removed_files + replaced,
        files.written_files,
        "{files}"
    );
    let avatar = read_ply(&dir.path().join("avatar_person_0.ply")).unwrap();
    // The refinement may grow Gaussians where the silhouettes ask for them.
    assert!(avatar.gaussians.len() >= config.model.num_points);
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".ply"))
        .collect();
    assert_eq!(names, ["avatar_person_0.ply"]);
    // The newest frame is kept.
    assert!(dir.path().join("frames/person_0_cam3_023.png").is_file());
}

#[test]
fn only_subscribed_topics_reach_the_frame_store() {
    // Subscribe to one input camera and one held-out camera: exactly those 2 views arrive.
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(
        dir.path(),
        &[
            "inputs.image_topics=[/cam0/image_raw, /heldout0/image_raw]",
            "inputs.camera_info_topics=[]",
            "inputs.mask_topics=[/cam0/mask]",
            "outputs.virtual_cameras=1",
        ],
    );
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    assert_eq!(summary.stats.frames, 2);
    // Only cam0 has a mask topic: the held-out camera's frame goes on whole.
    assert_eq!(summary.stats.masked, 1);
    assert_eq!(summary.views_held, 2);
    assert_eq!(summary.stats.reconstructions, 1);
}

#[test]
fn a_missing_bag_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), &["replay.bag=/nonexistent/x.mcap"]);
    let err = lhmpp::node::run::run(&config, BTreeMap::new())
        .expect_err("missing bag must fail")
        .to_string();
    assert!(err.contains("/nonexistent/x.mcap"), "{err}");
}

#[test]
fn replayed_avatar_reaches_a_shared_memory_subscriber_in_another_process() {
    let dir = tempfile::tempdir().unwrap();
    let person = format!("replay{}", std::process::id());
    let mut echo = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args([
            "shm-echo",
            "--person",
            &person,
            "--count",
            "1",
            "--timeout",
            "120",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(echo.stdout.take().unwrap()));
    // Wait until the subscriber is attached, so the one avatar is not missed.
    let ready = lines.next().unwrap().unwrap();
    assert!(ready.starts_with("ready"), "{ready}");
    let config = demo_config(
        dir.path(),
        &["outputs.shm=true", &format!("person_id={person}")],
    );
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    assert_eq!(summary.revision, 1);
    let line = lines.next().unwrap().unwrap();
    assert!(echo.wait().unwrap().success());
    assert!(
        line.contains(&format!("person={person}"))
            && line.contains("rev=1")
            && line.contains(&format!("gaussians={}", config.model.num_points)),
        "{line}"
    );
}
