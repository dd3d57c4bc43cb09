//! Pinhole camera in ROS conventions.
//!
//! Intrinsics follow `sensor_msgs/CameraInfo`: `K = [fx 0 cx; 0 fy cy; 0 0 1]`, pixel `(u, v)`
//! has its centre at integer coordinates, `u` to the right, `v` down. The camera's optical frame
//! is `+Z` forward, `+X` right, `+Y` down (REP 103 `*_optical_frame`). `world_from_camera` maps
//! optical-frame points to world points; its translation is the camera centre.

use glam::{Affine3A, Mat3, Vec3};

/// Pinhole intrinsics and image size (pixels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length along `u` (pixels).
    pub fx: f32,
    /// Focal length along `v` (pixels).
    pub fy: f32,
    /// Principal point `u` (pixels).
    pub cx: f32,
    /// Principal point `v` (pixels).
    pub cy: f32,
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
}

impl Intrinsics {
    /// Square pixels, centred principal point, vertical field of view `fov_y` (radians).
    pub fn from_fov_y(width: u32, height: u32, fov_y: f32) -> Self {
        let f = 0.5 * height as f32 / (0.5 * fov_y).tan();
        Self {
            fx: f,
            fy: f,
            cx: 0.5 * (width as f32 - 1.0),
            cy: 0.5 * (height as f32 - 1.0),
            width,
            height,
        }
    }

    /// Reads a row-major `sensor_msgs/CameraInfo` `K` matrix.
    pub fn from_k(k: [f64; 9], width: u32, height: u32) -> Self {
        Self {
            fx: k[0] as f32,
            fy: k[4] as f32,
            cx: k[2] as f32,
            cy: k[5] as f32,
            width,
            height,
        }
    }

    /// The row-major `K` matrix as `sensor_msgs/CameraInfo` stores it.
    pub fn k(&self) -> [f64; 9] {
        let (fx, fy, cx, cy) = (
            self.fx as f64,
            self.fy as f64,
            self.cx as f64,
            self.cy as f64,
        );
        [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    }
}

/// A posed pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Intrinsics and image size.
    pub intrinsics: Intrinsics,
    /// Optical frame → world (rigid).
    pub world_from_camera: Affine3A,
}

impl Camera {
    /// A camera from `sensor_msgs/CameraInfo` `K`, image size and its pose in the world.
    pub fn from_camera_info(
        k: [f64; 9],
        width: u32,
        height: u32,
        world_from_camera: Affine3A,
    ) -> Self {
        Self {
            intrinsics: Intrinsics::from_k(k, width, height),
            world_from_camera,
        }
    }

    /// A camera at `eye` looking at `target`; image "up" (`-Y` optical) points along the part of
    /// `up` orthogonal to the viewing direction. `up` must not be parallel to `target - eye`.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, intrinsics: Intrinsics) -> Self {
        let z = (target - eye).normalize();
        let y = (-up).reject_from_normalized(z).normalize();
        let x = y.cross(z);
        let rotation = Mat3::from_cols(x, y, z);
        Self {
            intrinsics,
            world_from_camera: Affine3A::from_mat3_translation(rotation, eye),
        }
    }

    /// View `i` of `n` on a circle around `target`, in a world with `+Y` up (the body's canonical
    /// frame): `radius` from the vertical axis through `target`, `height` above `target`; view 0
    /// sits on the `+Z` side, views advance counter-clockwise seen from above.
    pub fn orbit(
        i: usize,
        n: usize,
        radius: f32,
        height: f32,
        target: Vec3,
        intrinsics: Intrinsics,
    ) -> Self {
        Self::orbit_about(i, n, radius, height, target, Vec3::Y, Vec3::Z, intrinsics)
    }

    /// Like [`Camera::orbit`] about an arbitrary unit `up` axis, starting on the `start` side.
    #[allow(clippy::too_many_arguments)]
    pub fn orbit_about(
        i: usize,
        n: usize,
        radius: f32,
        height: f32,
        target: Vec3,
        up: Vec3,
        start: Vec3,
        intrinsics: Intrinsics,
    ) -> Self {
        let angle = std::f32::consts::TAU * i as f32 / n.max(1) as f32;
        let start = start.reject_from_normalized(up).normalize();
        let dir = glam::Quat::from_axis_angle(up, angle) * start;
        let eye = target + dir * radius + up * height;
        Self::look_at(eye, target, up, intrinsics)
    }

    /// World → optical frame.
    pub fn camera_from_world(&self) -> Affine3A {
        self.world_from_camera.inverse()
    }

    /// Camera centre in the world.
    pub fn center(&self) -> Vec3 {
        self.world_from_camera.translation.into()
    }

    /// Pixel coordinates of a point in the optical frame (no check that `z > 0`).
    pub fn project_camera_point(&self, p: Vec3) -> glam::Vec2 {
        let k = &self.intrinsics;
        glam::Vec2::new(k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intr() -> Intrinsics {
        Intrinsics::from_fov_y(64, 48, 1.0)
    }

    #[test]
    fn look_at_puts_the_target_at_the_principal_point() {
        let cam = Camera::look_at(
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            intr(),
        );
        let p = cam
            .camera_from_world()
            .transform_point3(Vec3::new(0.0, 1.0, 0.0));
        let uv = cam.project_camera_point(p);
        assert!(p.z > 0.0);
        assert!(
            (uv.x - intr().cx).abs() < 1e-4 && (uv.y - intr().cy).abs() < 1e-4,
            "{uv}"
        );
    }

    #[test]
    fn world_up_appears_towards_the_top_of_the_image() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, intr());
        let above =
            cam.project_camera_point(cam.camera_from_world().transform_point3(Vec3::Y * 0.5));
        let right =
            cam.project_camera_point(cam.camera_from_world().transform_point3(Vec3::X * 0.5));
        assert!(above.y < intr().cy, "v decreases upwards");
        // Looking along -Z with +Y up, world -X... the camera's right is world +X.
        assert!(right.x > intr().cx);
    }

    #[test]
    fn camera_info_k_round_trips() {
        let k = [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0];
        let cam = Camera::from_camera_info(k, 640, 480, Affine3A::IDENTITY);
        assert_eq!(cam.intrinsics.k(), k);
    }

    #[test]
    fn orbit_views_keep_radius_and_height() {
        for i in 0..8 {
            let cam = Camera::orbit(i, 8, 3.0, 0.5, Vec3::new(0.0, 1.0, 0.0), intr());
            let c = cam.center();
            assert!(((c.x * c.x + c.z * c.z).sqrt() - 3.0).abs() < 1e-4);
            assert!((c.y - 1.5).abs() < 1e-5);
        }
        assert!(Camera::orbit(0, 8, 3.0, 0.0, Vec3::ZERO, intr()).center().z > 2.9);
    }
}
