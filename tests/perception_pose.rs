//! Pose solver round trip on the MakeHuman template: seeded random poses (the synthetic
//! data's joint ranges, plus random hand rotations) → posed template → its 33 landmarks as
//! BlazePose world landmarks (hip-centred, camera axes, any camera yaw, with or without
//! noise) → solver → posed template again, compared joint by joint, root-aligned. A solver
//! fed left/right-swapped landmarks, or one that skips the camera-axis conversion, fails the
//! same floors by far.

mod perception_pose_support;

use glam::{EulerRot, Quat, Vec3};
use lhmpp::body::{BodyTemplate, Pose};
use lhmpp::perception::pose::{landmarks_to_pose, PoseSolver, SolverConfig};
use lhmpp::perception::{Landmark, BODY_LANDMARKS};
use lhmpp::synth::random_pose::random_pose;
use perception_pose_support::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const HIPS: [&str; 2] = ["upperleg01.L", "upperleg01.R"];
const POSES: u64 = 100;

/// Noise-free floors (measured: mean 1.6 mm, max 12.0 mm, at the head).
const MEAN_MM: f32 = 2.5;
const MAX_MM: f32 = 16.0;

/// `random_pose` plus random forearm twists (±60°) and wrist rotations (±30°, ±10°, ±30°),
/// which the synthetic poses leave at rest.
fn truth_pose(template: &BodyTemplate, seed: u64, rng: &mut ChaCha8Rng) -> Pose {
    let s = &template.skeleton;
    let joint = |name: &str| s.joints[s.bone_index(name).unwrap()];
    let mut pose = random_pose(seed, 0);
    let mut deg = |range: f32| rng.gen_range(-range..range).to_radians();
    for side in ["L", "R"] {
        let forearm = joint(&format!("wrist.{side}")) - joint(&format!("lowerarm01.{side}"));
        let twist = Quat::from_axis_angle(forearm.normalize(), deg(60.0));
        pose.rotations.insert(format!("lowerarm02.{side}"), twist);
        let wrist = Quat::from_euler(EulerRot::ZYX, deg(30.0), deg(10.0), deg(30.0));
        pose.rotations.insert(format!("wrist.{side}"), wrist);
    }
    pose
}

/// Joint errors (metres) and landmark errors over the seeded poses, each frame passed
/// through `corrupt` before solving.
fn round_trip(
    config: SolverConfig,
    noise: f32,
    corrupt: impl Fn(&[Landmark; BODY_LANDMARKS]) -> [Landmark; BODY_LANDMARKS],
) -> (Vec<f32>, Vec<f32>) {
    let template = BodyTemplate::load_default().unwrap();
    let solver = PoseSolver::new(&template, config).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut joints, mut landmarks) = (Vec::new(), Vec::new());
    for seed in 0..POSES {
        let truth = truth_pose(&template, seed, &mut rng);
        let seen = posed_landmarks(&template, &truth);
        let yaw = rng.gen_range(-std::f32::consts::PI..std::f32::consts::PI);
        let world = corrupt(&world_landmarks(&seen, yaw, noise, &mut rng));
        let solved = landmarks_to_pose(&solver, &world);
        joints.extend(joint_errors(
            &template,
            &truth,
            yaw,
            &solved,
            &MAKEHUMAN_MAJOR,
            HIPS,
        ));
        let got = posed_landmarks(&template, &solved);
        let turn = Quat::from_rotation_y(yaw);
        let hips = |x: &[Vec3; BODY_LANDMARKS]| 0.5 * (x[23] + x[24]);
        let (h0, h1) = (hips(&seen), hips(&got));
        landmarks
            .extend((0..BODY_LANDMARKS).map(|i| (turn * (seen[i] - h0)).distance(got[i] - h1)));
    }
    (joints, landmarks)
}

#[test]
fn noise_free_round_trip_recovers_the_major_joints_within_millimetres() {
    let (joints, landmarks) = round_trip(SolverConfig::default(), 0.0, |w| *w);
    let (mean, max) = mean_max_mm(&joints);
    let (lm_mean, lm_max) = mean_max_mm(&landmarks);
    println!("noise-free: joints mean {mean:.2} mm, max {max:.2} mm; all 33 landmarks mean {lm_mean:.2} mm, max {lm_max:.2} mm");
    assert!(mean < MEAN_MM && max < MAX_MM, "joints {mean} {max}");
    // Face, hand and foot landmarks follow too (head, hand and foot orientations).
    assert!(
        lm_mean < 4.0 && lm_max < MAX_MM,
        "landmarks {lm_mean} {lm_max}"
    );
}

#[test]
fn noisy_round_trip_stays_within_a_few_centimetres() {
    for (noise, mean_floor, max_floor) in [(0.01, 25.0, 100.0), (0.02, 50.0, 190.0)] {
        let (joints, _) = round_trip(SolverConfig::default(), noise, |w| *w);
        let (mean, max) = mean_max_mm(&joints);
        println!("noise {noise} m per coordinate: joints mean {mean:.1} mm, max {max:.1} mm");
        assert!(
            mean < mean_floor && max < max_floor,
            "{noise}: {mean} {max}"
        );
    }
}

#[test]
fn limits_leave_the_solved_natural_poses_alone() {
    let free = SolverConfig {
        apply_limits: false,
        ..SolverConfig::default()
    };
    let (limited, _) = round_trip(SolverConfig::default(), 0.0, |w| *w);
    let (unlimited, _) = round_trip(free, 0.0, |w| *w);
    let worst = limited
        .iter()
        .zip(&unlimited)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst < 1e-4, "limits moved a joint by {worst} m");
}

#[test]
fn swapped_left_and_right_fail_the_floor() {
    let (joints, _) = round_trip(SolverConfig::default(), 0.0, swap_left_right);
    let (mean, max) = mean_max_mm(&joints);
    println!("left/right swapped: joints mean {mean:.1} mm, max {max:.1} mm");
    assert!(mean > 20.0 * MEAN_MM && max > 10.0 * MAX_MM, "{mean} {max}");
}

#[test]
fn skipping_the_camera_axis_conversion_fails_the_floor() {
    let unconverted = SolverConfig {
        canonical_from_camera: Quat::IDENTITY,
        ..SolverConfig::default()
    };
    let (joints, _) = round_trip(unconverted, 0.0, |w| *w);
    let (mean, max) = mean_max_mm(&joints);
    println!("no axis conversion: joints mean {mean:.1} mm, max {max:.1} mm");
    assert!(mean > 20.0 * MEAN_MM && max > 10.0 * MAX_MM, "{mean} {max}");
}

#[test]
fn a_person_facing_the_camera_gets_the_identity_root() {
    let template = BodyTemplate::load_default().unwrap();
    let solver = PoseSolver::new(&template, SolverConfig::default()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let rest = posed_landmarks(&template, &Pose::identity());
    for (yaw, expected) in [(0.0, Quat::IDENTITY), (1.0, Quat::from_rotation_y(1.0))] {
        let world = world_landmarks(&rest, yaw, 0.0, &mut rng);
        // Facing the camera: the left shoulder is on the image's right (+x), the head up (−y),
        // the face towards the camera (−z).
        if yaw == 0.0 {
            let at = |id: lhmpp::perception::LandmarkId| world[id.index()].position;
            use lhmpp::perception::LandmarkId::*;
            assert!(at(LeftShoulder).x > at(RightShoulder).x);
            assert!(at(Nose).y < at(LeftHip).y && at(Nose).z < at(LeftEar).z);
        }
        let pose = landmarks_to_pose(&solver, &world);
        assert!(
            pose.root_rotation.angle_between(expected) < 1e-3,
            "{yaw}: {}",
            pose.root_rotation
        );
        for (bone, q) in &pose.rotations {
            assert!(q.angle_between(Quat::IDENTITY) < 2e-3, "{bone}: {q}");
        }
    }
}

/// Twist of `q` about unit `axis`, degrees.
fn twist_deg(q: Quat, axis: Vec3) -> f32 {
    let along = Vec3::new(q.x, q.y, q.z).dot(axis);
    let t = 2.0 * along.atan2(q.w);
    let t = (t + std::f32::consts::PI).rem_euclid(std::f32::consts::TAU) - std::f32::consts::PI;
    t.to_degrees()
}

#[test]
fn a_knee_seen_bending_forwards_is_clamped_by_the_limits() {
    use lhmpp::perception::LandmarkId::*;
    let template = BodyTemplate::load_default().unwrap();
    let s = &template.skeleton;
    let joint = |name: &str| s.joints[s.bone_index(name).unwrap()];
    // The left shin bent 60° forwards about the knee (the foot goes with it): a knee that
    // cannot bend that way, so the only exact fit twists the thigh half a turn. Within the
    // limits the solver reads it as a straight, untwisted leg.
    let mut seen = posed_landmarks(&template, &Pose::identity());
    let knee = joint("lowerleg01.L");
    let bend = Quat::from_rotation_x(-60f32.to_radians());
    for id in [LeftAnkle, LeftHeel, LeftFootIndex] {
        seen[id.index()] = knee + bend * (seen[id.index()] - knee);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let world = world_landmarks(&seen, 0.0, 0.0, &mut rng);
    let thigh_axis = (joint("lowerleg01.L") - joint("upperleg01.L")).normalize();
    let solve = |apply_limits: bool| {
        let config = SolverConfig {
            apply_limits,
            ..SolverConfig::default()
        };
        let pose = landmarks_to_pose(&PoseSolver::new(&template, config).unwrap(), &world);
        let twist = twist_deg(pose.rotations["upperleg01.L"], thigh_axis);
        let knee = pose.rotations["lowerleg01.L"];
        (twist, knee)
    };
    let (free_twist, _) = solve(false);
    let (twist, knee) = solve(true);
    println!("thigh twist without limits {free_twist:.1}°, with {twist:.1}°");
    assert!(free_twist.abs() > 150.0, "{free_twist}");
    assert!(twist.abs() < 15.0, "{twist}");
    // The knee bends at most 10° backwards past straight (its rest pose is bent a little).
    let rest_bend = (joint("lowerleg01.L") - joint("upperleg01.L"))
        .angle_between(joint("foot.L") - joint("lowerleg01.L"))
        .to_degrees();
    let bend_deg = twist_deg(knee, Vec3::X);
    println!("knee bend {bend_deg:.1}° from rest (rest bend {rest_bend:.1}°)");
    assert!(bend_deg >= -10.0 - rest_bend - 0.5, "{bend_deg}");
}
