//! Where a detected person stands: the bottom centre of their box cast onto the floor through
//! a calibrated camera.

use super::BoxPx;
use glam::{Affine3A, Vec3};

/// A calibrated pinhole camera, as the floor position needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorCamera {
    /// Focal lengths and principal point, pixels: `[fx, fy, cx, cy]`.
    pub intrinsics: [f32; 4],
    /// The camera's optical frame (+Z forward, +Y down the image) in the world (+Y up, the
    /// floor at `y = 0`).
    pub world_from_camera: Affine3A,
}

/// How far (metres, on the floor, away from the camera) a person stands beyond the point the
/// bottom of their box casts onto the floor: the lowest point of a person in the image is the
/// tip of their nearer foot, not the middle of where they stand. Chosen as the distance that
/// makes two cameras agree best on where the same person stands: over 914 pairs of sightings
/// of one true person by both cameras at once (16 synthetic crowd scenes, MoveNet boxes), the
/// median disagreement is 0.35 m at 0, 0.20 at 0.1, 0.16 at 0.15 and 0.2, 0.21 at 0.25.
pub const BOX_BOTTOM_TO_STANDING: f32 = 0.15;

/// Where a person whose box is `bbox` stands: the bottom centre of the box cast onto the floor
/// (the world's `y = 0` plane, +Y up), then [`BOX_BOTTOM_TO_STANDING`] further from the camera,
/// as (x, z); `None` when the ray misses the floor.
pub fn floor_point(camera: &FloorCamera, bbox: &BoxPx) -> Option<[f32; 2]> {
    let [fx, fy, cx, cy] = camera.intrinsics;
    let (u, v) = (0.5 * (bbox.min[0] + bbox.max[0]), bbox.max[1]);
    let dir_cam = Vec3::new((u - cx) / fx, (v - cy) / fy, 1.0);
    let origin = Vec3::from(camera.world_from_camera.translation);
    let dir = camera.world_from_camera.transform_vector3(dir_cam);
    if dir.y >= -1e-6 {
        return None;
    }
    let t = -origin.y / dir.y;
    let hit = origin + dir * t;
    let beyond = glam::Vec2::new(dir.x, dir.z).normalize_or_zero() * BOX_BOTTOM_TO_STANDING;
    (t > 0.0).then_some([hit.x + beyond.x, hit.z + beyond.y])
}
