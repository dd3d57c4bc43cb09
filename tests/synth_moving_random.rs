//! `lhmpp synth --camera moving` and `--pose random`: a moving camera has its own pose and
//! calibration at every frame and its bag replays through the node; random poses stay inside
//! the joint limits and depend only on the seed.

use std::collections::BTreeMap;
use std::path::Path;

use glam::Vec3;
use lhmpp::bag::BagReader;
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{BodyPose, CameraInfo, Image, TFMessage};
use lhmpp::synth::random_pose::{random_pose, JOINT_LIMITS};
use lhmpp::synth::{write_synthetic_bag, CameraMode, SynthOptions, SynthPose};

fn small(seed: u64, camera: CameraMode, pose: SynthPose) -> SynthOptions {
    SynthOptions {
        seed,
        views: 4,
        heldout: 2,
        size: 64,
        points: 3000,
        pose,
        camera,
        publish_shape: false,
        contrasting_back: false,
    }
}

fn decode_all<T: lhmpp::msgs::RosMessage>(bag: &BagReader, topic: &str) -> Vec<T> {
    bag.messages()
        .iter()
        .filter(|m| &*m.topic == topic)
        .map(|m| bag.decode(m).unwrap())
        .collect()
}

#[test]
fn moving_camera_bag_has_a_distinct_pose_and_calibration_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("moving.mcap");
    write_synthetic_bag(&path, &small(4, CameraMode::Moving, SynthPose::Walk(8.0))).unwrap();
    let bag = BagReader::open(&path).unwrap();

    let images: Vec<Image> = decode_all(&bag, "/cam0/image_raw");
    let infos: Vec<CameraInfo> = decode_all(&bag, "/cam0/camera_info");
    let tfs: Vec<TFMessage> = decode_all(&bag, "/tf");
    assert_eq!((images.len(), infos.len(), tfs.len()), (4, 4, 4));
    assert!(decode_all::<Image>(&bag, "/cam1/image_raw").is_empty());
    let mut eyes: Vec<Vec3> = Vec::new();
    for ((image, info), tf) in images.iter().zip(&infos).zip(&tfs) {
        // Each frame's calibration and pose carry the image's own stamp.
        assert_eq!(info.header.stamp, image.header.stamp);
        assert_eq!(tf.transforms.len(), 1);
        let t = &tf.transforms[0];
        assert_eq!(t.header.stamp, image.header.stamp);
        assert_eq!(t.child_frame_id, "cam0_optical_frame");
        assert_eq!(t.header.frame_id, "world");
        eyes.push(t.transform.translation.into());
    }
    for (i, a) in eyes.iter().enumerate() {
        for b in &eyes[i + 1..] {
            assert!(a.distance(*b) > 0.3, "camera stood still: {a} vs {b}");
        }
    }
    // Consecutive frames differ in content too (the view moved).
    assert!(images.windows(2).all(|w| w[0].data != w[1].data));
    // Held-out cameras stay fixed on /tf_static for scoring.
    let statics: Vec<TFMessage> = decode_all(&bag, "/tf_static");
    let names: Vec<&str> = statics[0]
        .transforms
        .iter()
        .map(|t| t.child_frame_id.as_str())
        .collect();
    assert_eq!(names, ["heldout0_optical_frame", "heldout1_optical_frame"]);
}

#[test]
fn moving_camera_bag_replays_through_the_node() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("moving.mcap");
    write_synthetic_bag(&bag, &small(2, CameraMode::Moving, SynthPose::Walk(8.0))).unwrap();
    let out = dir.path().join("out");
    let config = NodeConfig::load(
        Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/launch_configs/demo.yaml"
        )),
        &[
            format!("outputs.dir={}", out.display()),
            format!("replay.bag={}", bag.display()),
            "inputs.image_topics=[/cam0/image_raw]".into(),
            "inputs.camera_info_topics=[/cam0/camera_info]".into(),
            "inputs.mask_topics=[/cam0/mask]".into(),
            "outputs.virtual_cameras=1".into(),
        ],
    )
    .unwrap();
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    // Every frame of the one moving camera reaches the pipeline, which reconstructs.
    assert_eq!(summary.stats.frames, 4);
    assert_eq!(
        summary.stats.masked, 4,
        "every frame is cropped by its own mask"
    );
    assert!(summary.stats.reconstructions >= 1);
    assert!(summary.revision >= 1);
    assert!(out.join("avatar_person_0.ply").exists());
}

#[test]
fn random_poses_stay_within_joint_limits_and_depend_only_on_the_seed() {
    for seed in 0..50 {
        let pose = random_pose(seed, 0);
        assert_eq!(pose.rotations.len(), JOINT_LIMITS.len());
        for limit in JOINT_LIMITS {
            let q = pose.rotations[limit.bone];
            assert!(limit.contains(q, 0.01), "seed {seed}: {} = {q}", limit.bone);
        }
        assert_eq!(pose, random_pose(seed, 0));
    }
    assert_ne!(random_pose(1, 0), random_pose(2, 0));
    assert_ne!(
        random_pose(1, 0),
        random_pose(1, 1),
        "people under one seed differ"
    );
    // Every limited bone actually moves across seeds (not stuck at the rest pose).
    for limit in JOINT_LIMITS {
        let angles: Vec<_> = (0..10)
            .map(|s| random_pose(s, 0).rotations[limit.bone])
            .collect();
        assert!(angles.windows(2).any(|w| w[0] != w[1]), "{}", limit.bone);
    }
}

#[test]
fn random_pose_bag_is_seed_deterministic_and_carries_the_limited_pose() {
    let dir = tempfile::tempdir().unwrap();
    let options = small(7, CameraMode::Ring, SynthPose::Random);
    let [a, b] = ["a.mcap", "b.mcap"].map(|n| {
        let path = dir.path().join(n);
        write_synthetic_bag(&path, &options).unwrap();
        BagReader::open(&path).unwrap()
    });
    assert_eq!(a.messages().len(), b.messages().len());
    for (x, y) in a.messages().iter().zip(b.messages()) {
        assert!(x.data == y.data, "{} differs between runs", x.topic);
    }
    let pose: Vec<BodyPose> = decode_all(&a, "/lhmpp/body_pose");
    let pose = pose[0].to_pose().unwrap();
    for limit in JOINT_LIMITS {
        assert!(
            limit.contains(pose.rotations[limit.bone], 0.01),
            "{}",
            limit.bone
        );
    }
    // Grounded: the root is only shifted vertically.
    assert_eq!(
        (pose.root_translation.x, pose.root_translation.z),
        (0.0, 0.0)
    );
}

#[test]
fn eval_uses_every_frame_of_a_moving_camera_as_a_view() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("moving.mcap");
    write_synthetic_bag(&bag, &small(5, CameraMode::Moving, SynthPose::Walk(8.0))).unwrap();
    let model = NodeConfig::default().model;
    let rows = lhmpp::eval::heldout::evaluate_bag(
        &bag,
        &model,
        &[1, 4, 8],
        &lhmpp::eval::heldout::EvalStages {
            crop: lhmpp::eval::heldout::InputCrop::FullFrame,
            ..Default::default()
        },
    )
    .unwrap();
    // One camera topic with 4 frames gives 4 input views (8 is clamped to 4).
    let counts: Vec<usize> = rows.iter().map(|r| r.views).collect();
    assert_eq!(counts, vec![1, 4]);
    for row in &rows {
        assert_eq!(row.per_view.len(), 2);
        let (psnr, ssim, iou) = row.means();
        assert!(psnr.is_finite() && (0.0..=1.0).contains(&ssim) && (0.0..=1.0).contains(&iou));
    }
}
