//! A synthetic person moving in front of fixed cameras, over time: seeded random poses within
//! joint limits as keyframes, eased from one to the next, while the whole body turns slowly
//! about the vertical. Each frame's true pose goes on [`TRUTH_POSE_TOPIC`], not on the node's
//! pose input, so a node replaying the bag must read the motion from the images
//! (`lhmpp synth-motion`, the camera-only demo and its tests).

use super::capture::{
    camera_info, camera_transform, image_topic, info_topic, mask_image, mask_topic, render_views,
    rgb_image, START_NS, TF_STATIC_TOPIC, WORLD_FRAME,
};
use super::person::{SynthError, SyntheticPerson};
use super::random_pose::random_pose;
use super::stream::ring_cameras;
use crate::bag::{BagWriter, BagWriterOptions};
use crate::body::{motion, Pose};
use crate::msgs::{BodyPose, Header, TFMessage, Time};
use glam::Quat;
use std::path::Path;

/// Topic of the true pose of every frame (ground truth, not the node's input).
pub const TRUTH_POSE_TOPIC: &str = "/truth/body_pose";

/// What `lhmpp synth-motion` makes.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionOptions {
    /// Seed of the person, outfit and motion.
    pub seed: u64,
    /// Frames per camera.
    pub frames: usize,
    /// Frames per second.
    pub fps: f32,
    /// Seconds from one keyframe pose to the next.
    pub key_interval_s: f32,
    /// Largest turn of the body about the vertical, degrees (it sways between ±this).
    pub turn_deg: f32,
    /// Fixed cameras on a ring, `cam0` in front of the person.
    pub cameras: usize,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Gaussians on the person.
    pub points: usize,
}

impl Default for MotionOptions {
    fn default() -> Self {
        Self {
            seed: 5,
            frames: 48,
            fps: 12.0,
            key_interval_s: 1.0,
            turn_deg: 35.0,
            cameras: 1,
            width: 320,
            height: 240,
            points: 20_000,
        }
    }
}

/// The pose at `t` seconds: keyframe `k = ⌊t / interval⌋` eased into `k + 1` (every limited
/// bone slerped along a smoothstep), the body turned by `turn · sin(t / 4 · 2π)`, grounded.
pub fn motion_pose(person: &SyntheticPerson, options: &MotionOptions, t: f32) -> Pose {
    let interval = options.key_interval_s.max(1e-3);
    let k = (t / interval).floor();
    let s = t / interval - k;
    let s = s * s * (3.0 - 2.0 * s);
    let a = random_pose(options.seed, k as u32);
    let b = random_pose(options.seed, k as u32 + 1);
    let mut pose = Pose::identity();
    for (bone, qa) in &a.rotations {
        let qb = b.rotations.get(bone).copied().unwrap_or(Quat::IDENTITY);
        pose.rotations.insert(bone.clone(), qa.slerp(qb, s));
    }
    let turn = options.turn_deg.to_radians() * (t / 4.0 * std::f32::consts::TAU).sin();
    pose.root_rotation = Quat::from_rotation_y(turn);
    let feet = motion::foot_vertices(&person.template);
    motion::ground(&person.template, &feet, pose)
}

/// Renders the moving person and writes the bag at `path`: `/tf_static` camera poses, then per
/// frame the true pose on [`TRUTH_POSE_TOPIC`] and, per camera, CameraInfo, the rgb8 image
/// and the true mono8 mask. Returns the messages written.
pub fn write_motion_bag(
    path: &Path,
    options: &MotionOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<u64, SynthError> {
    let person = SyntheticPerson::new(options.seed, options.points)?;
    let cameras = ring_cameras(
        options.cameras.max(1),
        options.width,
        options.height,
        person.template.height(),
    );
    let mut bag = BagWriter::create_with(
        path,
        BagWriterOptions {
            flush_interval: None,
            ..BagWriterOptions::default()
        },
    )?;
    let header = |ns: u64, frame: &str| Header::new(Time::from_nanos(ns as i64), frame);
    bag.write(
        TF_STATIC_TOPIC,
        START_NS,
        &TFMessage {
            transforms: cameras
                .iter()
                .map(|c| camera_transform(c, START_NS))
                .collect(),
        },
    )?;
    let step_ns = (1e9 / options.fps.max(1e-3)) as u64;
    for f in 0..options.frames {
        let ns = START_NS + step_ns * (f as u64 + 1);
        let t = f as f32 / options.fps;
        let pose = motion_pose(&person, options, t);
        bag.write(
            TRUTH_POSE_TOPIC,
            ns,
            &BodyPose::from_pose(header(ns, WORLD_FRAME), "person_0", &pose),
        )?;
        for view in render_views(&person, &pose, &cameras)? {
            let name = &view.rig.name;
            bag.write(&info_topic(name), ns, &camera_info(view.rig, ns))?;
            bag.write(&image_topic(name), ns, &rgb_image(&view, ns))?;
            bag.write(&mask_topic(name), ns, &mask_image(&view, ns))?;
        }
        progress(f + 1, options.frames);
    }
    Ok(bag.finish()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_motion_moves_smoothly_through_its_keyframes() {
        let person = SyntheticPerson::new(3, 500).unwrap();
        let options = MotionOptions::default();
        let at = |t: f32| motion_pose(&person, &options, t);
        let arm = "upperarm01.L";
        let angle = |a: &Pose, b: &Pose| a.rotations[arm].angle_between(b.rotations[arm]);
        // Keyframes differ; a small step in time moves a little.
        assert!(angle(&at(0.0), &at(1.0)) > 0.05);
        assert!(angle(&at(0.5), &at(0.52)) < 0.05);
        // The body turns.
        assert!(at(1.0).root_rotation.angle_between(Quat::IDENTITY) > 0.2);
    }
}
