//! Frames of a synthetic person walking in the middle of a ring of wide cameras, rendered once
//! and cycled by a load generator (`lhmpp loadgen`): consecutive frames differ (the walk
//! moves on), so a node that keeps distinct views sees new content all the time.

use super::capture::render_views;
use super::person::{SynthError, SyntheticPerson};
use super::scene::RigCamera;
use crate::body::motion::{walk_pose, WALK_PERIOD_FRAMES};
use crate::splat::{Camera, Intrinsics};
use glam::Vec3;
use image::RgbImage;

/// Vertical field of view of the stream cameras (radians), wide as a room camera.
const FOV_Y: f32 = 0.9;

/// What to render.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamOptions {
    /// Seed of the person and outfit.
    pub seed: u64,
    /// Cameras on the ring (`cam0..`).
    pub cameras: usize,
    /// Distinct frames per camera: the walk cycle sampled evenly.
    pub frames: usize,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Gaussians on the person.
    pub points: usize,
}

/// Rendered frames: `images[frame][camera]`, and the cameras.
pub struct StreamFrames {
    /// The ring's cameras, `cam0..`.
    pub cameras: Vec<RigCamera>,
    /// RGB frames on white, by frame then camera.
    pub images: Vec<Vec<RgbImage>>,
}

/// `options.cameras` cameras evenly on a ring around a person of `height` metres, all
/// `width`×`height_px`, the whole body in view.
pub fn ring_cameras(cameras: usize, width: u32, height_px: u32, height: f32) -> Vec<RigCamera> {
    let intrinsics = Intrinsics::from_fov_y(width, height_px, FOV_Y);
    let target = Vec3::new(0.0, 0.5 * height, 0.0);
    let distance = 0.62 * height / (0.5 * FOV_Y).tan();
    (0..cameras)
        .map(|i| {
            let angle = std::f32::consts::TAU * i as f32 / cameras.max(1) as f32;
            let eye =
                target + Vec3::new(angle.sin() * distance, 0.1 * height, angle.cos() * distance);
            RigCamera {
                name: format!("cam{i}"),
                camera: Camera::look_at(eye, target, Vec3::Y, intrinsics),
            }
        })
        .collect()
}

/// Renders the frames; `progress(done, total)` after each frame of all cameras.
pub fn render_stream(
    options: &StreamOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<StreamFrames, SynthError> {
    let person = SyntheticPerson::new(options.seed, options.points)?;
    let cameras = ring_cameras(
        options.cameras,
        options.width,
        options.height,
        person.template.height(),
    );
    let frames = options.frames.max(1);
    let mut images = Vec::with_capacity(frames);
    for f in 0..frames {
        let pose = walk_pose(WALK_PERIOD_FRAMES * f as f32 / frames as f32);
        let views = render_views(&person, &pose, &cameras)?;
        images.push(views.iter().map(|v| v.output.to_rgb8()).collect());
        progress(f + 1, frames);
    }
    Ok(StreamFrames { cameras, images })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_show_the_person_and_change_along_the_walk() {
        let options = StreamOptions {
            seed: 3,
            cameras: 2,
            frames: 2,
            width: 96,
            height: 64,
            points: 3000,
        };
        let s = render_stream(&options, |_, _| {}).unwrap();
        assert_eq!(s.cameras.len(), 2);
        assert_eq!(s.images.len(), 2);
        let a = &s.images[0][0];
        assert_eq!((a.width(), a.height()), (96, 64));
        let non_white = a.pixels().filter(|p| p.0.iter().any(|c| *c < 200)).count();
        assert!(non_white > 200, "the person is in view: {non_white} pixels");
        let changed = a
            .pixels()
            .zip(s.images[1][0].pixels())
            .filter(|(p, q)| p != q)
            .count();
        assert!(
            changed > 20,
            "the walk moves on between frames: {changed} pixels"
        );
    }
}
