//! Camera-only perception in the node, through bag replay: frames without a mask topic are
//! cropped by perception's mask, frames showing nobody never reach the frame store, mask topics
//! still win where they exist, and the pose read from the cameras drives the animation.

use lhmpp::bag::BagWriter;
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{Header, Image, Time};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn demo_config(out: &Path, bag: &Path, extra: &[&str]) -> NodeConfig {
    let mut overrides = vec![
        format!("outputs.dir={}", out.display()),
        format!("replay.bag={}", bag.display()),
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

fn demo_bag() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/demo.mcap")
}

/// The demo bag through perception (no mask topics), one virtual camera, with `extra`.
fn run_perceived_demo(extra: &[&str]) -> lhmpp::node::run::RunSummary {
    let dir = tempfile::tempdir().unwrap();
    let mut overrides = vec!["inputs.mask_topics=[]", "outputs.virtual_cameras=1"];
    overrides.extend_from_slice(extra);
    let config = demo_config(dir.path(), &demo_bag(), &overrides);
    lhmpp::node::run::run(&config, BTreeMap::new()).unwrap()
}

#[test]
fn without_mask_topics_perception_crops_every_frame_to_the_person() {
    let summary = run_perceived_demo(&[]);
    let s = &summary.stats;
    assert_eq!(s.frames, 4);
    assert_eq!(s.perceived, 4, "every frame goes through perception");
    assert_eq!(s.perception_masked, 4, "the person is found in every view");
    assert_eq!(s.masked, 0, "no mask topic");
    assert_eq!(s.no_person, 0);
    assert_eq!(summary.views_held, 4);
    assert!(s.camera_poses >= 1, "the cameras give the pose");
    assert_eq!(
        s.calibrated_views, 4,
        "CameraInfo, /tf_static and the pose topic place every view's colours"
    );
    // At the end of the replay the avatar is refined against the calibrated views (refine
    // is on by default) and published under a revision of its own when the fit beat the
    // network's avatar on the view it held out.
    assert_eq!(s.refinements, 1, "one refinement at the end of the replay");
    assert_eq!(s.refinements_kept, 1, "the fit beats the network's avatar");
    assert!(s.refine_steps > 0);
    assert!(summary.revision >= 2, "revision {}", summary.revision);
}

#[test]
fn refinement_off_publishes_the_networks_avatar_only() {
    let summary = run_perceived_demo(&["refine.enabled=false"]);
    assert_eq!(summary.stats.refinements, 0);
    assert_eq!(summary.stats.refine_steps, 0);
    // One reconstruction of the four views; a loaded machine may let the debounce run one on
    // the first views too. Either way the last revision is the network's own.
    let runs = summary.stats.reconstructions;
    assert!((1..=2).contains(&runs), "{runs} reconstructions");
    assert_eq!(summary.revision, runs, "every revision is a network avatar");
}

#[test]
fn views_are_not_calibrated_in_another_world_frame() {
    // The bag's cameras and pose are in `world`: a node working in another frame cannot place
    // them and falls back to cameras fitted to the landmarks.
    let summary = run_perceived_demo(&["outputs.world_frame=map"]);
    assert_eq!(summary.stats.perception_masked, 4);
    assert_eq!(summary.stats.calibrated_views, 0);
}

#[test]
fn mask_topics_win_and_off_means_whole_frames() {
    let dir = tempfile::tempdir().unwrap();
    // person_mask: off ignores the mask topics and perceives nothing.
    let config = demo_config(
        dir.path(),
        &demo_bag(),
        &["inputs.person_mask=off", "outputs.virtual_cameras=1"],
    );
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    assert_eq!(summary.stats.masked, 0);
    assert_eq!(summary.stats.perceived, 0);
    assert_eq!(summary.views_held, 4);
    // pose_source: camera with the masks off perceives the frames for the pose only.
    let config = demo_config(
        dir.path(),
        &demo_bag(),
        &[
            "inputs.person_mask=off",
            "inputs.pose_source=camera",
            "outputs.virtual_cameras=1",
        ],
    );
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    assert_eq!(summary.stats.perceived, 4);
    assert_eq!(summary.stats.perception_masked, 0);
    assert_eq!(summary.stats.read_in_given_masks, 0);
    assert!(summary.stats.camera_poses >= 1);
}

/// Mean PSNR (dB) of the rendered frames two replays wrote under the same names.
fn frames_psnr(a: &Path, b: &Path) -> (f64, usize) {
    let mut total = 0.0;
    let mut count = 0;
    for entry in std::fs::read_dir(a.join("frames")).unwrap() {
        let path = entry.unwrap().path();
        let x = image::open(&path).unwrap().to_rgb8();
        let y = image::open(b.join("frames").join(path.file_name().unwrap()))
            .unwrap()
            .to_rgb8();
        let mse = x
            .as_raw()
            .iter()
            .zip(y.as_raw())
            .map(|(&p, &q)| (f64::from(p) - f64::from(q)).powi(2))
            .sum::<f64>()
            / x.as_raw().len() as f64;
        total += 10.0 * (255.0f64.powi(2) / mse.max(1e-3)).log10();
        count += 1;
    }
    (total / count.max(1) as f64, count)
}

#[test]
fn inside_a_topics_masks_perception_reads_the_person_and_the_avatar_matches_camera_only() {
    // With every camera masked by its topic, perception reads the person inside each mask:
    // the pose, the calibrated views' colours and the refinement, as camera-only has them.
    let topic = tempfile::tempdir().unwrap();
    let config = demo_config(topic.path(), &demo_bag(), &["outputs.virtual_cameras=1"]);
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    let s = &summary.stats;
    assert_eq!(s.masked, 4, "every frame has its topic's mask");
    assert_eq!(s.perceived, 4);
    assert_eq!(
        s.read_in_given_masks, 4,
        "the person is read inside every mask"
    );
    assert_eq!(s.perception_masked, 0, "the topic's masks crop the frames");
    assert_eq!(s.calibrated_views, 4);
    assert!(s.camera_poses >= 1);
    assert_eq!(s.refinements, 1);
    // The same bag through camera-only perception: the masks nearly agree, and so do the
    // avatars' renders.
    let camera_only = tempfile::tempdir().unwrap();
    let config = demo_config(
        camera_only.path(),
        &demo_bag(),
        &["inputs.mask_topics=[]", "outputs.virtual_cameras=1"],
    );
    lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    let (psnr, frames) = frames_psnr(topic.path(), camera_only.path());
    assert!(frames >= 4, "{frames} frames");
    eprintln!("topic masks vs perception's masks: {psnr:.2} dB over {frames} frames");
    assert!(psnr >= 30.0, "{psnr:.2} dB");
}

/// A bag of `frames` empty grey frames on `/cam0/image_raw`.
fn empty_room_bag(dir: &Path, frames: usize) -> PathBuf {
    let path = dir.join("empty.mcap");
    let mut bag = BagWriter::create(&path).unwrap();
    for i in 0..frames {
        let t = 1_700_000_000_000_000_000u64 + i as u64 * 33_000_000;
        let image = Image {
            header: Header::new(Time::from_nanos(t as i64), "cam0_optical"),
            height: 240,
            width: 320,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 320 * 3,
            data: (0..240 * 320 * 3)
                .map(|i| (90 + (i % 7) * 3) as u8)
                .collect(),
        };
        bag.write("/cam0/image_raw", t, &image).unwrap();
    }
    bag.finish().unwrap();
    path
}

#[test]
fn frames_with_nobody_never_reach_the_frame_store() {
    let dir = tempfile::tempdir().unwrap();
    let bag = empty_room_bag(dir.path(), 3);
    let config = demo_config(
        dir.path(),
        &bag,
        &[
            "inputs.image_topics=[/cam0/image_raw]",
            "inputs.camera_info_topics=[]",
            "inputs.mask_topics=[]",
            "outputs.virtual_cameras=1",
        ],
    );
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    assert_eq!(summary.stats.frames, 3);
    assert_eq!(summary.stats.perceived, 3);
    assert_eq!(summary.stats.no_person, 3);
    assert_eq!(summary.views_held, 0);
    assert_eq!(summary.stats.reconstructions, 0);
    assert_eq!(summary.revision, 0);
}

#[test]
fn the_body_height_is_read_from_calibrated_views_without_a_shape_topic() {
    use lhmpp::synth::{write_synthetic_bag, SynthOptions, SynthPose, SyntheticPerson};
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("ring.mcap");
    let seed = 23;
    let options = SynthOptions {
        seed,
        views: 6,
        heldout: 1,
        size: 256,
        points: 20_000,
        pose: SynthPose::Random,
        ..SynthOptions::default()
    };
    write_synthetic_bag(&bag, &options).unwrap();
    let truth = SyntheticPerson::new(seed, 500).unwrap().height_scale;
    let list = |kind: &str| {
        let topics: Vec<String> = (0..6).map(|i| format!("/cam{i}/{kind}")).collect();
        format!("[{}]", topics.join(","))
    };
    let run = |extra: &[&str]| {
        let mut set = vec![
            format!("inputs.image_topics={}", list("image_raw")),
            format!("inputs.camera_info_topics={}", list("camera_info")),
            "inputs.mask_topics=[]".to_string(),
            "inputs.shape_topic=\"\"".to_string(),
            "outputs.virtual_cameras=1".to_string(),
        ];
        set.extend(extra.iter().map(|s| s.to_string()));
        let set: Vec<&str> = set.iter().map(String::as_str).collect();
        let config = demo_config(dir.path(), &bag, &set);
        lhmpp::node::run::run(&config, BTreeMap::new()).unwrap()
    };
    let summary = run(&[]);
    let [height, girth] = summary.shape_params[..] else {
        panic!("no shape read: {:?}", summary.shape_params);
    };
    println!("height scale read {height:.4}, true {truth:.4}");
    assert!((height / truth - 1.0).abs() < 0.03, "{height} vs {truth}");
    assert_eq!(girth, 1.0);
    // Off: the template's shape.
    let summary = run(&["perception.estimate_shape=false"]);
    assert!(
        summary.shape_params.is_empty(),
        "{:?}",
        summary.shape_params
    );
}
