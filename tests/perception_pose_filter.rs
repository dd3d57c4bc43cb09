//! The pose estimator's time behaviour: the One-Euro filter smooths a still, noisy point and
//! follows a step with bounded lag; a segment whose landmarks are hidden holds its last
//! rotation, then eases back to rest.

mod perception_pose_support;

use glam::{Quat, Vec3};
use lhmpp::body::{BodyTemplate, Pose};
use lhmpp::perception::pose::{
    landmarks_to_pose, OneEuroConfig, OneEuroFilter, PoseEstimator, PoseEstimatorConfig, Segment,
};
use lhmpp::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
use lhmpp::synth::random_pose::random_pose;
use perception_pose_support::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const FPS: f64 = 30.0;

fn variance(samples: &[Vec3]) -> f32 {
    let mean = samples.iter().copied().sum::<Vec3>() / samples.len() as f32;
    samples
        .iter()
        .map(|s| (*s - mean).length_squared())
        .sum::<f32>()
        / samples.len() as f32
}

#[test]
fn one_euro_smooths_a_still_noisy_point() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut filter = OneEuroFilter::new(OneEuroConfig::default());
    let centre = Vec3::new(0.2, -0.4, 0.1);
    let (mut raw, mut out) = (Vec::new(), Vec::new());
    for i in 0..600 {
        let x = centre + gaussian3(&mut rng) * 0.01;
        let y = filter.filter(i as f64 / FPS, x);
        if i >= 30 {
            raw.push(x);
            out.push(y);
        }
    }
    let ratio = variance(&raw) / variance(&out);
    let bias = (out.iter().copied().sum::<Vec3>() / out.len() as f32).distance(centre);
    println!(
        "1 cm noise at 30 Hz: variance reduced {ratio:.1}×, mean off by {:.2} mm",
        bias * 1e3
    );
    assert!(ratio > 5.0, "{ratio}");
    assert!(bias < 0.002, "{bias}");
}

#[test]
fn one_euro_follows_a_step_within_a_few_frames() {
    let mut filter = OneEuroFilter::new(OneEuroConfig::default());
    let step = Vec3::new(0.0, 0.3, 0.0);
    for i in 0..30 {
        filter.filter(i as f64 / FPS, Vec3::ZERO);
    }
    let frames_to = |fraction: f32, filter: &mut OneEuroFilter| {
        (30..300)
            .find(|&i| filter.filter(i as f64 / FPS, step).y >= fraction * step.y)
            .map(|i| i - 29)
    };
    let mut a = filter.clone();
    let to_90 = frames_to(0.9, &mut a).unwrap();
    let to_99 = frames_to(0.99, &mut filter).unwrap();
    println!("0.3 m step at 30 Hz: 90 % after {to_90} frames, 99 % after {to_99}");
    assert!(to_90 <= 6 && to_99 <= 15, "{to_90} {to_99}");
    // A plain low-pass at the resting cutoff (beta = 0) lags far more: the speed term matters.
    let mut slow = OneEuroFilter::new(OneEuroConfig {
        beta: 0.0,
        ..OneEuroConfig::default()
    });
    for i in 0..30 {
        slow.filter(i as f64 / FPS, Vec3::ZERO);
    }
    let slow_90 = frames_to(0.9, &mut slow).unwrap();
    println!("the same with beta = 0: 90 % after {slow_90} frames");
    assert!(slow_90 > 2 * to_90, "{slow_90} vs {to_90}");
}

#[test]
fn one_euro_ignores_stale_timestamps_and_passes_the_first_sample() {
    let mut filter = OneEuroFilter::new(OneEuroConfig::default());
    assert_eq!(filter.filter(1.0, Vec3::X), Vec3::X);
    assert_eq!(filter.filter(1.0, Vec3::Y), Vec3::X);
    assert_eq!(filter.filter(0.5, Vec3::Y), Vec3::X);
    assert_ne!(filter.filter(1.1, Vec3::Y), Vec3::X);
}

fn frame(template: &BodyTemplate, pose: &Pose) -> [Landmark; BODY_LANDMARKS] {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    world_landmarks(&posed_landmarks(template, pose), 0.0, 0.0, &mut rng)
}

#[test]
fn hidden_forearm_holds_then_eases_to_rest() {
    let template = BodyTemplate::load_default().unwrap();
    let config = PoseEstimatorConfig {
        filter: None,
        hold_s: 0.5,
        ease_s: 1.0,
        ..PoseEstimatorConfig::default()
    };
    let mut estimator = PoseEstimator::new(&template, config).unwrap();
    let seen = random_pose(4, 0);
    let good = estimator.update(0.0, &frame(&template, &seen));
    let held = good.rotations["lowerarm01.L"];
    assert!(
        held.angle_between(Quat::IDENTITY) > 0.2,
        "the pose bends the elbow"
    );
    // The person moves on, but the left wrist and hand are hidden from t = 0.1 on: last good
    // at t = 0, held until 0.5, at rest from 1.5.
    let mut moved = frame(&template, &random_pose(9, 0));
    use LandmarkId::*;
    for id in [LeftWrist, LeftIndex, LeftPinky, LeftThumb] {
        moved[id.index()].visibility = 0.1;
    }
    let solver = estimator.solver().clone();
    let moved_right = landmarks_to_pose(&solver, &moved).rotations["lowerarm01.R"];
    assert!(moved_right.angle_between(good.rotations["lowerarm01.R"]) > 0.05);
    let mut previous = f32::INFINITY;
    for step in 1..=20 {
        let t = 0.1 * f64::from(step);
        let pose = estimator.update(t, &moved);
        let solved = estimator.last_solved();
        assert!(!solved[Segment::LeftForearm.index()] && !solved[Segment::LeftHand.index()]);
        assert!(solved[Segment::RightForearm.index()] && solved[Segment::LeftUpperArm.index()]);
        let q = pose.rotations["lowerarm01.L"];
        let from_rest = q.angle_between(Quat::IDENTITY);
        if t <= 0.5 + 1e-9 {
            assert!(q.angle_between(held) < 1e-5, "t = {t}: held");
        } else if t >= 1.5 - 1e-9 {
            assert!(from_rest < 1e-5, "t = {t}: at rest");
        } else {
            assert!(from_rest < previous - 1e-4, "t = {t}: easing");
            assert!(from_rest > 1e-3, "t = {t}: not yet at rest");
        }
        previous = from_rest;
        // The right arm keeps following its landmarks meanwhile.
        let right = pose.rotations["lowerarm01.R"];
        assert!(
            right.angle_between(moved_right) < 1e-5,
            "t = {t}: right forearm"
        );
    }
    // Seen again: solved at once.
    let back = estimator.update(2.5, &frame(&template, &seen));
    assert!(back.rotations["lowerarm01.L"].angle_between(held) < 1e-4);
}
