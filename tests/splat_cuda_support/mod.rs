//! Shared by the CUDA rasteriser tests (emulated and on a GPU): the test camera and the image
//! difference.

use glam::Vec3;
use lhmpp::splat::{Camera, Intrinsics};

/// A camera 2.6 m in front of the body-like clouds, `width × height` pixels.
pub fn camera(width: u32, height: u32) -> Camera {
    Camera::look_at(
        Vec3::new(0.4, 1.1, 2.6),
        Vec3::new(0.0, 0.9, 0.0),
        Vec3::Y,
        Intrinsics::from_fov_y(width, height, 0.9),
    )
}

pub use lhmpp::testing::max_abs_diff;
