//! The live pose from a camera follows the person: a synthetic person moving in front of one
//! camera (`bags/moving_person.mcap`, true poses on `/truth/body_pose`) is tracked frame to
//! frame as the node does (one tracker, One-Euro-filtered pose estimator), and the avatar's
//! joints posed by the camera pose land near the true joints, far nearer than the walk cycle's
//! the node would otherwise play. The node's replay of the same bag animates its avatar with
//! those camera poses.

use glam::Vec3;
use lhmpp::bag::BagReader;
use lhmpp::body::{motion, BodyTemplate, Pose};
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{BodyPose, Image};
use lhmpp::perception::pose::{PoseEstimator, PoseEstimatorConfig};
use lhmpp::perception::{LandmarkModel, PersonTracker, PoseNetworks, TrackerConfig};
use lhmpp::reconstruct::image_decode::{decode_raw, RawImage};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

/// Bones whose joints are compared: shoulders, elbows, wrists, hips, knees, ankles, neck, head.
const JOINTS: [&str; 14] = [
    "upperarm01.L",
    "upperarm01.R",
    "lowerarm01.L",
    "lowerarm01.R",
    "wrist.L",
    "wrist.R",
    "upperleg01.L",
    "upperleg01.R",
    "lowerleg01.L",
    "lowerleg01.R",
    "foot.L",
    "foot.R",
    "neck01",
    "head",
];

fn bag_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/moving_person.mcap")
}

/// The compared joints of `template` posed by `pose`, relative to the mean of the hips.
fn joints(template: &BodyTemplate, pose: &Pose) -> Vec<Vec3> {
    let m = template.skeleton.skinning_matrices(pose);
    let posed = template.skeleton.posed_joints(&m);
    let at = |name: &str| posed[template.skeleton.bone_index(name).expect(name)];
    let hips = 0.5 * (at("upperleg01.L") + at("upperleg01.R"));
    JOINTS.iter().map(|n| at(n) - hips).collect()
}

fn mean_error_mm(a: &[Vec3], b: &[Vec3]) -> f32 {
    1e3 * a.iter().zip(b).map(|(p, q)| p.distance(*q)).sum::<f32>() / a.len() as f32
}

#[test]
fn the_camera_pose_follows_the_person_not_the_walk_cycle() {
    let bag = BagReader::open(bag_path()).unwrap();
    let template = BodyTemplate::load_default().unwrap();
    let networks = Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap());
    let mut tracker = PersonTracker::new(networks, TrackerConfig::default());
    let mut estimator = PoseEstimator::new(&template, PoseEstimatorConfig::default()).unwrap();
    let truths: Vec<Pose> = bag
        .messages()
        .iter()
        .filter(|m| &*m.topic == "/truth/body_pose")
        .map(|m| bag.decode::<BodyPose>(m).unwrap().to_pose().unwrap())
        .collect();
    let frames: Vec<(u64, image::RgbImage)> = bag
        .messages()
        .iter()
        .filter(|m| &*m.topic == "/cam0/image_raw")
        .map(|m| {
            let msg: Image = bag.decode(m).unwrap();
            let image = decode_raw("/cam0/image_raw", &RawImage::from(&msg), 4096).unwrap();
            (m.log_time, image)
        })
        .collect();
    assert_eq!(frames.len(), truths.len());
    let (mut truth_joints, mut camera_joints, mut walk_joints) = (vec![], vec![], vec![]);
    for (f, ((stamp, image), truth)) in frames.iter().zip(&truths).enumerate() {
        let seen = tracker
            .perceive(image)
            .unwrap()
            .unwrap_or_else(|| panic!("frame {f}: the person is not found"));
        let pose = estimator.update(*stamp as f64 * 1e-9, &seen.landmarks.world);
        truth_joints.push(joints(&template, truth));
        camera_joints.push(joints(&template, &pose));
        walk_joints.push(joints(&template, &motion::walk_pose(f as f32 * 2.0)));
    }
    let rest = joints(&template, &Pose::identity());
    let mean = |poses: &[Vec<Vec3>]| {
        poses
            .iter()
            .zip(&truth_joints)
            .map(|(a, b)| mean_error_mm(a, b))
            .sum::<f32>()
            / poses.len() as f32
    };
    let (camera, walk) = (mean(&camera_joints), mean(&walk_joints));
    let rest = mean(&vec![rest; truth_joints.len()]);
    let (follow, walk_follow) = (
        correlation(&truth_joints, &camera_joints),
        correlation(&truth_joints, &walk_joints),
    );
    println!(
        "{} frames; mean joint error, hip-centred: camera pose {camera:.1} mm, walk cycle \
         {walk:.1} mm, rest pose {rest:.1} mm; correlation with the true joint motion: camera \
         {follow:.2}, walk cycle {walk_follow:.2}",
        frames.len()
    );
    // The motion is followed: the joints move with the true ones (the walk cycle does not).
    assert!(follow > 0.6, "camera pose correlation {follow:.2}");
    assert!(walk_follow < 0.3, "walk cycle correlation {walk_follow:.2}");
    // And the joints are nearer the truth than either canned pose puts them (monocular depth
    // keeps the camera pose some 10 cm off).
    assert!(
        camera < 115.0,
        "camera pose {camera:.1} mm off the true joints"
    );
    assert!(
        camera < 0.8 * walk.min(rest),
        "camera pose {camera:.1} mm, walk {walk:.1} mm, rest {rest:.1} mm"
    );
}

/// Mean Pearson correlation, over the joints' coordinates that move by more than 2 cm (standard
/// deviation over the sequence), between the true and the estimated coordinate series.
fn correlation(truth: &[Vec<Vec3>], estimate: &[Vec<Vec3>]) -> f32 {
    let n = truth.len() as f32;
    let mut all = Vec::new();
    for j in 0..JOINTS.len() {
        for k in 0..3 {
            let x: Vec<f32> = truth.iter().map(|v| v[j][k]).collect();
            let y: Vec<f32> = estimate.iter().map(|v| v[j][k]).collect();
            let (mx, my) = (x.iter().sum::<f32>() / n, y.iter().sum::<f32>() / n);
            let sd =
                |v: &[f32], m: f32| (v.iter().map(|a| (a - m).powi(2)).sum::<f32>() / n).sqrt();
            let (sx, sy) = (sd(&x, mx), sd(&y, my));
            if sx < 0.02 {
                continue;
            }
            let cov = x
                .iter()
                .zip(&y)
                .map(|(a, b)| (a - mx) * (b - my))
                .sum::<f32>()
                / n;
            all.push(cov / (sx * sy).max(1e-9));
        }
    }
    all.iter().sum::<f32>() / all.len().max(1) as f32
}

#[test]
fn the_node_animates_the_avatar_with_the_camera_poses() {
    let dir = tempfile::tempdir().unwrap();
    let config = NodeConfig::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("launch_configs/camera_only.yaml"),
        &[format!("outputs.dir={}", dir.path().display())],
    )
    .unwrap();
    let summary = lhmpp::node::run::run(&config, BTreeMap::new()).unwrap();
    let s = &summary.stats;
    assert_eq!(s.frames, 48);
    assert_eq!(s.perception_masked, 48);
    assert_eq!(s.camera_poses, 48, "every frame gives a pose");
    assert!(summary.revision >= 1);
    // The end-of-replay animation replays the 48 camera poses (one virtual camera).
    assert_eq!(summary.animation_frames, 48);
}
