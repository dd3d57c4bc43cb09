//! The LHMPP-Prior body on synthetic files: missing files are named, query points are posed
//! into the official neutral pose, skinning weights come from the volume, and Gaussians map
//! back to the SMPL-X rest pose.

mod official_support;

use glam::{Quat, Vec3};
use lhmpp::body::official::{read_ply_points, OfficialPrior, PriorPaths};
use lhmpp::body::SMPLX_JOINT_NAMES;
use lhmpp::reconstruct::apply_part_rules;
use official_support as synth;

fn joint(name: &str) -> usize {
    SMPLX_JOINT_NAMES.iter().position(|n| *n == name).unwrap()
}

#[test]
fn each_missing_prior_file_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let paths = PriorPaths::in_dir(dir.path());
    let err = OfficialPrior::load(&paths).unwrap_err().to_string();
    assert!(err.contains("dense_sample_points/1_160000.ply"), "{err}");
    synth::write_prior(dir.path(), 500);
    std::fs::remove_file(&paths.volume).unwrap();
    let err = OfficialPrior::load(&paths).unwrap_err().to_string();
    assert!(err.contains("voxel_grid/cano_1_volume.npz"), "{err}");
    synth::write_volume(&paths.volume);
    std::fs::remove_file(&paths.smplx).unwrap();
    let err = OfficialPrior::load(&paths).unwrap_err().to_string();
    assert!(
        err.contains("human_model_files/smplx/SMPLX_NEUTRAL.npz"),
        "{err}"
    );
}

#[test]
fn query_points_stand_in_the_neutral_pose_with_legs_apart() {
    let dir = tempfile::tempdir().unwrap();
    let paths = synth::write_prior(dir.path(), 3000);
    let prior = OfficialPrior::load(&paths).unwrap();
    assert_eq!(prior.len(), 3000);
    assert_eq!(prior.is_body.iter().filter(|b| **b).count(), 2250);
    // Rest points are the file's points in the canonical frame.
    let file = read_ply_points(&paths.points).unwrap();
    for (r, f) in prior.rest_points.iter().zip(&file) {
        assert!((*r + prior.model_offset).abs_diff_eq(*f, 1e-6));
    }
    let joints = synth::joints();
    let neutral = synth::neutral_joints();
    let near = |p: Vec3, j: usize| (p + prior.model_offset).distance(joints[j]) < 0.02;
    let (mut left, mut right, mut head) = (0, 0, 0);
    for i in 0..prior.len() {
        let (r, q) = (prior.rest_points[i], prior.query_points[i]);
        if near(r, joint("left_ankle")) {
            // The ankle cluster turns rigidly with the left leg about the hip, outwards (+x).
            let hip = joints[joint("left_hip")];
            let rot = Quat::from_rotation_z(lhmpp::body::official::NEUTRAL_HIP_ANGLE);
            let want = hip + rot * (r + prior.model_offset - hip) - prior.model_offset;
            assert!(q.abs_diff_eq(want, 1e-5), "{q} vs {want}");
            let ankle = neutral[joint("left_ankle")] - prior.model_offset;
            assert!(q.distance(ankle) < 0.02);
            assert!(q.x > r.x + 0.2);
            left += 1;
        }
        if near(r, joint("right_ankle")) {
            assert!(q.x < r.x - 0.2);
            right += 1;
        }
        if near(r, joint("head")) {
            assert!(q.abs_diff_eq(r, 1e-6), "the head does not move");
            head += 1;
        }
        assert!((prior.query_normals[i].length() - 1.0).abs() < 1e-4);
    }
    assert!(left > 0 && right > 0 && head > 0);
}

#[test]
fn skinning_comes_from_the_volume_and_gaussians_return_to_the_rest_pose() {
    let dir = tempfile::tempdir().unwrap();
    let paths = synth::write_prior(dir.path(), 3000);
    let prior = OfficialPrior::load(&paths).unwrap();
    let joints = synth::joints();
    let mut checked = 0;
    for i in 0..prior.len() {
        let w = prior.skin.weights[i];
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        // The synthetic volume is one-hot on the nearest neutral joint; points sitting on a
        // knee cluster get exactly that joint.
        let r = prior.rest_points[i] + prior.model_offset;
        if r.distance(joints[joint("left_knee")]) < 0.02 {
            assert_eq!(prior.skin.bones[i][0] as usize, joint("left_knee"));
            assert_eq!(w[0], 1.0);
            // Neutral → rest: the Gaussian at the query point goes back to the file's point,
            // and its orientation loses the hip rotation.
            let q = Quat::from_rotation_y(0.3);
            let (p, rot, row) = prior.to_rest(i, prior.query_points[i], q);
            assert_eq!(row.0[0] as usize, joint("left_knee"));
            assert!(p.abs_diff_eq(prior.rest_points[i], 1e-5), "{p}");
            let hip = Quat::from_rotation_z(-lhmpp::body::official::NEUTRAL_HIP_ANGLE);
            assert!(rot.dot(hip * q).abs() > 1.0 - 1e-5);
            checked += 1;
        }
    }
    assert!(checked > 0);
}

#[test]
fn subsampling_keeps_the_body_head_ratio() {
    let dir = tempfile::tempdir().unwrap();
    let paths = synth::write_prior(dir.path(), 4000);
    let prior = OfficialPrior::load(&paths).unwrap().subsample(400);
    assert_eq!(prior.len(), 400);
    assert_eq!(prior.skin.len(), 400);
    assert_eq!(prior.is_body.iter().filter(|b| **b).count(), 300);
}

#[test]
fn ascii_and_big_endian_ply_files_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let ascii = dir.path().join("a.ply");
    std::fs::write(
        &ascii,
        "ply\nformat ascii 1.0\ncomment pytorch3d\nelement vertex 2\nproperty float x\n\
         property float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_index\n\
         end_header\n1 2 3\n-1 0.5 4\n",
    )
    .unwrap();
    assert_eq!(
        read_ply_points(&ascii).unwrap(),
        vec![Vec3::new(1., 2., 3.), Vec3::new(-1., 0.5, 4.)]
    );
    let be = dir.path().join("b.ply");
    let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double z\n\
property double y\nproperty double x\nend_header\n"
        .to_vec();
    for v in [3.0f64, 2.0, 1.0] {
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    std::fs::write(&be, bytes).unwrap();
    assert_eq!(read_ply_points(&be).unwrap(), vec![Vec3::new(1., 2., 3.)]);
    std::fs::write(&be, "ply\nformat ascii 1.0\nelement face 1\nend_header\n").unwrap();
    let err = read_ply_points(&be).unwrap_err().to_string();
    assert!(err.contains("b.ply") && err.contains("vertex"), "{err}");
}

#[test]
fn gaussians_take_the_volume_weights_where_they_land_except_on_hands_and_head() {
    let dir = tempfile::tempdir().unwrap();
    let paths = synth::write_prior(dir.path(), 3000);
    let prior = OfficialPrior::load(&paths).unwrap();
    let joints = synth::joints();
    let neutral = synth::neutral_joints();
    let off = prior.model_offset;
    let find = |j: usize| {
        (0..prior.len())
            .find(|&i| (prior.rest_points[i] + off).distance(joints[j]) < 0.015)
            .unwrap()
    };
    // A knee Gaussian predicted at the (neutral) ankle follows the ankle.
    let knee = find(joint("left_knee"));
    let at_ankle = neutral[joint("left_ankle")] - off;
    let (_, _, row) = prior.to_rest(knee, at_ankle, Quat::IDENTITY);
    assert_eq!(row.0[0] as usize, joint("left_ankle"));
    // A hand Gaussian keeps its vertex's weights wherever it lands.
    let finger = find(joint("right_index2"));
    assert!(prior.is_hand[finger]);
    let (_, _, row) = prior.to_rest(finger, at_ankle, Quat::IDENTITY);
    assert_eq!(row.0[0] as usize, joint("right_index2"));
    // all_to_rest applies the same per Gaussian and returns one row each.
    let mut pos = prior.query_points.clone();
    let mut rot = vec![Quat::IDENTITY; prior.len()];
    let skin = prior.all_to_rest(&mut pos, &mut rot);
    assert_eq!(skin.len(), prior.len());
    assert!(pos[knee].abs_diff_eq(prior.rest_points[knee], 1e-5));
}

#[test]
fn official_part_rules_fix_hand_opacity_and_clamp_upper_body_scales() {
    let dir = tempfile::tempdir().unwrap();
    let paths = synth::write_prior(dir.path(), 3000);
    let prior = OfficialPrior::load(&paths).unwrap();
    let n = prior.len();
    let mut scales = vec![Vec3::splat(0.04); n];
    let mut opacities = vec![0.3; n];
    apply_part_rules(&prior, &mut scales, &mut opacities);
    let (mut hands, mut upper, mut other) = (0, 0, 0);
    let joints = synth::joints();
    for i in 0..n {
        let dominant = prior.skin.bones[i][0] as usize;
        let r = prior.rest_points[i] + prior.model_offset;
        if prior.is_hand[i] {
            assert_eq!(opacities[i], 0.95);
            hands += 1;
        } else {
            assert_eq!(opacities[i], 0.3);
        }
        if prior.is_upper_body[i] {
            assert_eq!(scales[i], Vec3::splat(0.02));
            upper += 1;
        } else {
            assert_eq!(scales[i], Vec3::splat(0.04));
        }
        // Elbows are upper body; knees are not.
        if r.distance(joints[joint("left_elbow")]) < 0.015 {
            assert!(prior.is_upper_body[i] && dominant == joint("left_elbow"));
        }
        if r.distance(joints[joint("left_knee")]) < 0.015 {
            assert!(!prior.is_upper_body[i] && !prior.is_hand[i]);
            other += 1;
        }
    }
    assert!(hands > 0 && upper > 0 && other > 0);
}

#[test]
fn motion_frames_pose_the_prior_where_smplx_puts_the_body_in_camera_space() {
    use lhmpp::body::motion::official::SmplxFrame;
    let dir = tempfile::tempdir().unwrap();
    let paths = synth::write_prior(dir.path(), 500);
    let prior = OfficialPrior::load(&paths).unwrap();
    let mut body = vec![[0.0f32; 3]; 21];
    body[3] = [0.7, 0.0, 0.0]; // left_knee
    let json = serde_json::json!({
        "betas": vec![0.0f32; 10], "root_pose": [std::f32::consts::PI, 0.0, 0.0], "body_pose": body,
        "jaw_pose": [0.0, 0.0, 0.0], "leye_pose": [0.0, 0.0, 0.0], "reye_pose": [0.0, 0.0, 0.0],
        "lhand_pose": vec![[0.0f32; 3]; 15], "rhand_pose": vec![[0.0f32; 3]; 15],
        "trans": [0.1, 0.2, 3.0], "focal": [1000.0, 1000.0], "princpt": [256.0, 256.0]
    });
    let path = dir.path().join("frame.json");
    std::fs::write(&path, json.to_string()).unwrap();
    let frame = SmplxFrame::from_file(&path).unwrap();
    let pose = prior.motion_pose(&frame);
    let t = &prior.template;
    let posed = t
        .skeleton
        .posed_joints(&t.skeleton.skinning_matrices(&pose));
    // SMPL-X: joints rotate about the pelvis by root_pose, then move by trans.
    let j = synth::joints();
    let root = Quat::from_rotation_x(std::f32::consts::PI);
    let trans = Vec3::new(0.1, 0.2, 3.0);
    let pelvis = j[0];
    for name in ["pelvis", "head", "left_wrist", "left_knee"] {
        let k = joint(name);
        let want = root * (j[k] - pelvis) + pelvis + trans;
        assert!(
            posed[k].abs_diff_eq(want, 1e-5),
            "{name}: {} vs {want}",
            posed[k]
        );
    }
    // The knee bend moves the ankle: rotate the shin about the knee, then the root.
    let k = joint("left_ankle");
    let knee = joint("left_knee");
    let local = j[knee] + Quat::from_rotation_x(0.7) * (j[k] - j[knee]);
    let want = root * (local - pelvis) + pelvis + trans;
    assert!(posed[k].abs_diff_eq(want, 1e-5), "{} vs {want}", posed[k]);
    // Upside-down SMPL-X body in the camera frame: the head is above (smaller y) the pelvis.
    assert!(posed[joint("head")].y < posed[0].y);
}
