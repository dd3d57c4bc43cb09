//! The pose solver on an SMPL-X skeleton (a small synthetic model with SMPL-X's 55 joints,
//! parents and T-pose-like rest, from `official_support`): MakeHuman landmarks drive it to
//! the same segment directions, and its own landmarks round-trip like MakeHuman's.

#[path = "official_support/mod.rs"]
mod official_support;
mod perception_pose_support;

use glam::{Quat, Vec3};
use lhmpp::body::{load_smplx, BodyTemplate, Pose};
use lhmpp::perception::pose::{landmarks_to_pose, PoseSolver, SkeletonKind, SolverConfig};
use lhmpp::perception::{LandmarkId, BODY_LANDMARKS};
use lhmpp::synth::random_pose::random_pose;
use perception_pose_support::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn smplx_template() -> (tempfile::TempDir, BodyTemplate) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("SMPLX_NEUTRAL.npz");
    official_support::write_smplx(&path);
    let template = load_smplx(&path, &[]).unwrap();
    (dir, template)
}

/// Segment vectors compared between the two bodies.
fn segments(x: &[Vec3; BODY_LANDMARKS]) -> Vec<(&'static str, Vec3)> {
    use LandmarkId::*;
    let at = |id: LandmarkId| x[id.index()];
    let mut out = Vec::new();
    for (name, a, b) in [
        ("left upper arm", LeftShoulder, LeftElbow),
        ("left forearm", LeftElbow, LeftWrist),
        ("right upper arm", RightShoulder, RightElbow),
        ("right forearm", RightElbow, RightWrist),
        ("left thigh", LeftHip, LeftKnee),
        ("left shin", LeftKnee, LeftAnkle),
        ("right thigh", RightHip, RightKnee),
        ("right shin", RightKnee, RightAnkle),
        ("hip line", RightHip, LeftHip),
        ("shoulder line", RightShoulder, LeftShoulder),
        ("ear line", RightEar, LeftEar),
        ("left foot", LeftHeel, LeftFootIndex),
        ("right foot", RightHeel, RightFootIndex),
    ] {
        out.push((name, at(b) - at(a)));
    }
    for (name, wrist, index, pinky) in [
        ("left hand", LeftWrist, LeftIndex, LeftPinky),
        ("right hand", RightWrist, RightIndex, RightPinky),
    ] {
        out.push((name, 0.5 * (at(index) + at(pinky)) - at(wrist)));
    }
    out
}

/// SMPL-X poses solved from MakeHuman's random poses, with their worst segment-direction
/// error (degrees) against the MakeHuman landmarks.
fn smplx_poses_from_makehuman(smplx: &BodyTemplate) -> (Vec<Pose>, f32) {
    let makehuman = BodyTemplate::load_default().unwrap();
    let solver = PoseSolver::new(smplx, SolverConfig::default()).unwrap();
    assert_eq!(solver.bone_map().kind, SkeletonKind::SmplX);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (mut poses, mut worst) = (Vec::new(), 0.0f32);
    for seed in 0..60 {
        let seen = posed_landmarks(&makehuman, &random_pose(seed, 0));
        let yaw = rng.gen_range(-std::f32::consts::PI..std::f32::consts::PI);
        let pose = landmarks_to_pose(&solver, &world_landmarks(&seen, yaw, 0.0, &mut rng));
        let got = posed_landmarks(smplx, &pose);
        let turn = Quat::from_rotation_y(yaw);
        for ((name, want), (_, have)) in segments(&seen).into_iter().zip(segments(&got)) {
            let angle = (turn * want).angle_between(have).to_degrees();
            assert!(angle < 1.0, "seed {seed}, {name}: {angle}°");
            worst = worst.max(angle);
        }
        assert!(pose.rotations.contains_key("left_elbow") && pose.rotations.contains_key("spine2"));
        poses.push(pose);
    }
    (poses, worst)
}

#[test]
fn makehuman_motion_drives_smplx_to_the_same_segment_directions() {
    let (_dir, smplx) = smplx_template();
    let (_, worst) = smplx_poses_from_makehuman(&smplx);
    println!("SMPL-X driven by MakeHuman landmarks: worst segment direction error {worst:.3}°");
}

#[test]
fn smplx_round_trip_recovers_its_joints() {
    let (_dir, smplx) = smplx_template();
    let (truths, _) = smplx_poses_from_makehuman(&smplx);
    let solver = PoseSolver::new(&smplx, SolverConfig::default()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    for (noise, mean_floor, max_floor) in [(0.0, 1.5, 12.0), (0.01, 30.0, 130.0)] {
        let mut errors = Vec::new();
        for truth in &truths {
            let truth = Pose {
                root_rotation: Quat::IDENTITY,
                ..truth.clone()
            };
            let seen = posed_landmarks(&smplx, &truth);
            let yaw = rng.gen_range(-std::f32::consts::PI..std::f32::consts::PI);
            let world = world_landmarks(&seen, yaw, noise, &mut rng);
            let solved = landmarks_to_pose(&solver, &world);
            errors.extend(joint_errors(
                &smplx,
                &truth,
                yaw,
                &solved,
                &SMPLX_MAJOR,
                ["left_hip", "right_hip"],
            ));
        }
        let (mean, max) = mean_max_mm(&errors);
        println!("SMPL-X round trip, noise {noise} m: joints mean {mean:.2} mm, max {max:.2} mm");
        assert!(
            mean < mean_floor && max < max_floor,
            "{noise}: {mean} {max}"
        );
    }
}
