//! Shared helpers of the pose-solver tests: synthetic BlazePose frames from posed templates
//! and the joint-error measure.

#![allow(dead_code)]

use glam::{Quat, Vec3};
use lhmpp::body::{BodyTemplate, Pose};
use lhmpp::perception::pose::template_landmarks;
use lhmpp::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Camera axes from canonical ones: the half turn about x (its own inverse).
pub fn camera_from_canonical() -> Quat {
    Quat::from_rotation_x(std::f32::consts::PI)
}

/// BlazePose world landmarks of canonical-frame points: hip-centred, seen by a camera that
/// faces the person after they turned by `yaw` about +Y, with Gaussian noise of `noise`
/// metres per coordinate (drawn from `rng`), all visible.
pub fn world_landmarks(
    canonical: &[Vec3; BODY_LANDMARKS],
    yaw: f32,
    noise: f32,
    rng: &mut ChaCha8Rng,
) -> [Landmark; BODY_LANDMARKS] {
    let hips =
        0.5 * (canonical[LandmarkId::LeftHip.index()] + canonical[LandmarkId::RightHip.index()]);
    let turn = Quat::from_rotation_y(yaw);
    let to_camera = camera_from_canonical();
    std::array::from_fn(|i| Landmark {
        position: to_camera * (turn * (canonical[i] - hips)) + gaussian3(rng) * noise,
        visibility: 1.0,
        presence: 1.0,
    })
}

/// Three independent standard normal draws (Box–Muller).
pub fn gaussian3(rng: &mut ChaCha8Rng) -> Vec3 {
    let mut g = || {
        let u: f32 = rng.gen_range(1e-7..1.0);
        let v: f32 = rng.gen_range(0.0..1.0);
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    };
    Vec3::new(g(), g(), g())
}

/// Posed joint positions of `bones`, less the midpoint of the two `hips` bones' joints.
pub fn root_aligned_joints(
    template: &BodyTemplate,
    pose: &Pose,
    bones: &[&str],
    hips: [&str; 2],
) -> Vec<Vec3> {
    let s = &template.skeleton;
    let posed = s.posed_joints(&s.skinning_matrices(pose));
    let at = |name: &str| posed[s.bone_index(name).unwrap_or_else(|| panic!("{name}"))];
    let centre = 0.5 * (at(hips[0]) + at(hips[1]));
    bones.iter().map(|b| at(b) - centre).collect()
}

/// The major joints of the MakeHuman rig: shoulders, elbows, wrists, hips, knees, ankles,
/// neck and head.
pub const MAKEHUMAN_MAJOR: [&str; 14] = [
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

/// The same joints of SMPL-X.
pub const SMPLX_MAJOR: [&str; 14] = [
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "neck",
    "head",
];

/// Joint errors (metres) of `solved` against `truth` turned by `yaw`, both root-aligned.
pub fn joint_errors(
    template: &BodyTemplate,
    truth: &Pose,
    yaw: f32,
    solved: &Pose,
    bones: &[&str],
    hips: [&str; 2],
) -> Vec<f32> {
    let turned = Pose {
        root_rotation: Quat::from_rotation_y(yaw) * truth.root_rotation,
        ..truth.clone()
    };
    let a = root_aligned_joints(template, &turned, bones, hips);
    let b = root_aligned_joints(template, solved, bones, hips);
    a.iter().zip(&b).map(|(a, b)| a.distance(*b)).collect()
}

/// The landmarks of `template` posed by `pose` (canonical frame).
pub fn posed_landmarks(template: &BodyTemplate, pose: &Pose) -> [Vec3; BODY_LANDMARKS] {
    template_landmarks(template, pose).unwrap()
}

/// Mean and max of `errors`, millimetres.
pub fn mean_max_mm(errors: &[f32]) -> (f32, f32) {
    let mean = errors.iter().sum::<f32>() / errors.len() as f32;
    let max = errors.iter().copied().fold(0.0, f32::max);
    (mean * 1000.0, max * 1000.0)
}

/// Swaps every left landmark with its right counterpart (a solver reading the labels the
/// wrong way round).
pub fn swap_left_right(world: &[Landmark; BODY_LANDMARKS]) -> [Landmark; BODY_LANDMARKS] {
    let other = |name: &str| -> String {
        for (a, b) in [("left", "right"), ("right", "left")] {
            if let Some(rest) = name.strip_prefix(a) {
                return format!("{b}{rest}");
            }
            if let Some(rest) = name.strip_suffix(a) {
                return format!("{rest}{b}");
            }
        }
        name.to_string()
    };
    std::array::from_fn(|i| {
        let name = other(LandmarkId::ALL[i].name());
        let j = LandmarkId::ALL
            .iter()
            .position(|id| id.name() == name)
            .unwrap_or_else(|| panic!("{name}"));
        world[j]
    })
}
