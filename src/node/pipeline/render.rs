//! Rendered outputs of the node: virtual cameras orbiting the person, the pose that drives the
//! avatar (latest BodyPose, or the built-in walk for demos), splatting into RGB frames.

use crate::avatar::Avatar;
use crate::body::{motion, BodyTemplate, Pose};
use crate::splat::{render, Camera, Intrinsics, RenderOptions};
use glam::Vec3;
use image::RgbImage;

/// Frames per second of the built-in walk cycle (its keys are 24 fps Blender frames).
const WALK_FPS: f32 = 24.0;

/// Virtual cameras around the canonical body, all looking at its middle.
#[derive(Debug, Clone)]
pub struct VirtualCameras {
    cameras: Vec<Camera>,
}

impl VirtualCameras {
    /// `count` cameras evenly spaced on a ring around a body of `height` metres, `size`²
    /// pixels, camera 0 in front of the person (+Z).
    pub fn ring(count: u32, size: u32, height: f32) -> Self {
        let fov_y = 0.75f32;
        let intrinsics = Intrinsics::from_fov_y(size, size, fov_y);
        let distance = 0.62 * height / (0.5 * fov_y).tan();
        let target = Vec3::new(0.0, 0.5 * height, 0.0);
        let cameras = (0..count as usize)
            .map(|i| {
                Camera::orbit(
                    i,
                    count as usize,
                    distance,
                    0.1 * height,
                    target,
                    intrinsics,
                )
            })
            .collect();
        Self { cameras }
    }

    /// The cameras.
    pub fn cameras(&self) -> &[Camera] {
        &self.cameras
    }
}

/// The pose the avatar is shown in at `time_s`: the latest received pose if any, else the
/// built-in walk cycle.
pub fn display_pose(latest: Option<&Pose>, time_s: f32) -> Pose {
    latest
        .cloned()
        .unwrap_or_else(|| motion::walk_pose(time_s * WALK_FPS))
}

/// Poses `avatar` with `pose` on `template`'s skeleton and renders every virtual camera on a
/// white background.
pub fn render_frames(
    avatar: &Avatar,
    template: &BodyTemplate,
    pose: &Pose,
    cameras: &VirtualCameras,
) -> Vec<RgbImage> {
    let matrices = template.skeleton.skinning_matrices(pose);
    let posed = avatar.animate(&matrices);
    let options = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    cameras
        .cameras()
        .iter()
        .map(|c| render(&posed, c, &options).to_rgb8())
        .collect()
}
