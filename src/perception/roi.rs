//! Regions of interest: rotated rectangles in frame pixels, the way MediaPipe places its
//! landmark crop around a person (a square aligned with the hips → head axis), and the maps
//! between a crop's normalised coordinates and the frame.

use glam::Vec2;
use std::f32::consts::PI;

/// How much larger than a person's box the upright crop around it is
/// ([`RotatedRect::around_box`]).
pub const BOX_CROP_SCALE: f32 = 1.25;

/// A rectangle in frame pixels, rotated about its centre.
///
/// Pixel coordinates have x to the right and y down, pixel centres at integers (as OpenCV).
/// `rotation` turns the rectangle clockwise on screen (radians): a crop point `(u, v)` in
/// [0, 1]² lies at `center + R(rotation) · ((u − ½)·width, (v − ½)·height)` with
/// `R(θ) = [[cos θ, −sin θ], [sin θ, cos θ]]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RotatedRect {
    /// Centre, pixels.
    pub center: Vec2,
    /// Width and height, pixels.
    pub size: Vec2,
    /// Clockwise rotation on screen, radians in (−π, π].
    pub rotation: f32,
}

impl RotatedRect {
    /// The square that MediaPipe's `AlignmentPointsRectsCalculator` makes from two keypoints:
    /// centred on `center`, side twice the distance to `scale_point`, rotated so that the
    /// direction `center → scale_point` points at `target_angle` (radians, counter-clockwise
    /// from +x with y up; π/2 = straight up on screen) in the crop.
    pub fn from_alignment(center: Vec2, scale_point: Vec2, target_angle: f32) -> Self {
        let side = 2.0 * center.distance(scale_point);
        let d = scale_point - center;
        let rotation = normalize_radians(target_angle - (-d.y).atan2(d.x));
        Self {
            center,
            size: Vec2::splat(side),
            rotation,
        }
    }

    /// The whole `width × height` frame letterboxed into a square (`keep_aspect_ratio`): a
    /// square of the longer side, centred, unrotated.
    pub fn letterbox(width: u32, height: u32) -> Self {
        let side = width.max(height) as f32;
        Self {
            center: Vec2::new(width as f32 / 2.0, height as f32 / 2.0),
            size: Vec2::splat(side),
            rotation: 0.0,
        }
    }

    /// The upright crop around a person known only by a box (`min`–`max`, pixels, e.g. a
    /// given mask's): a square of the box's longer side, scaled by [`BOX_CROP_SCALE`], as
    /// large around the person as a detection's crop.
    pub fn around_box(min: Vec2, max: Vec2) -> Self {
        let side = (max - min).max_element().max(1.0);
        Self {
            center: 0.5 * (min + max),
            size: Vec2::splat(side),
            rotation: 0.0,
        }
        .square_long_scaled(BOX_CROP_SCALE)
    }

    /// MediaPipe's `RectTransformationCalculator` with `square_long`: a square of the longer
    /// side, scaled by `scale`.
    pub fn square_long_scaled(self, scale: f32) -> Self {
        let side = self.size.x.max(self.size.y) * scale;
        Self {
            size: Vec2::splat(side),
            ..self
        }
    }

    /// The frame point at normalised crop coordinates `(u, v)` ([0, 1] spans the rectangle).
    pub fn crop_to_frame(&self, u: f32, v: f32) -> Vec2 {
        let local = Vec2::new((u - 0.5) * self.size.x, (v - 0.5) * self.size.y);
        self.center + rotate(local, self.rotation)
    }

    /// Normalised crop coordinates of frame point `p` (the inverse of
    /// [`RotatedRect::crop_to_frame`]).
    pub fn frame_to_crop(&self, p: Vec2) -> Vec2 {
        let local = rotate(p - self.center, -self.rotation);
        Vec2::new(local.x / self.size.x + 0.5, local.y / self.size.y + 0.5)
    }

    /// A direction or offset of the crop (x right, y down) turned into frame axes.
    pub fn rotate_to_frame(&self, v: Vec2) -> Vec2 {
        rotate(v, self.rotation)
    }

    /// Axis-aligned bounds of the rectangle's corners: `(min, max)`.
    pub fn bounds(&self) -> (Vec2, Vec2) {
        let corners =
            [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)].map(|(u, v)| self.crop_to_frame(u, v));
        let min = corners
            .iter()
            .fold(Vec2::splat(f32::INFINITY), |a, c| a.min(*c));
        let max = corners
            .iter()
            .fold(Vec2::splat(f32::NEG_INFINITY), |a, c| a.max(*c));
        (min, max)
    }
}

/// `v` turned by `angle` (clockwise on screen for y-down pixel axes).
fn rotate(v: Vec2, angle: f32) -> Vec2 {
    let (s, c) = angle.sin_cos();
    Vec2::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

/// `angle` wrapped into (−π, π].
pub fn normalize_radians(angle: f32) -> f32 {
    let mut a = angle % (2.0 * PI);
    if a <= -PI {
        a += 2.0 * PI;
    } else if a > PI {
        a -= 2.0 * PI;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upright_person_gives_an_unrotated_square_around_the_hips() {
        let hips = Vec2::new(100.0, 200.0);
        let above_head = Vec2::new(100.0, 50.0);
        let r = RotatedRect::from_alignment(hips, above_head, PI / 2.0);
        assert!(r.rotation.abs() < 1e-6, "{}", r.rotation);
        assert_eq!(r.size, Vec2::splat(300.0));
        // The crop's top centre is above the head point.
        let top = r.crop_to_frame(0.5, 0.0);
        assert!(top.abs_diff_eq(Vec2::new(100.0, 50.0), 1e-3), "{top}");
    }

    #[test]
    fn a_person_lying_to_the_right_turns_the_crop_so_the_head_is_up_in_it() {
        // Head to the right of the hips: the crop must be turned a quarter so that the
        // hips→head direction points up in the crop.
        let hips = Vec2::new(100.0, 100.0);
        let head = Vec2::new(200.0, 100.0);
        let r = RotatedRect::from_alignment(hips, head, PI / 2.0);
        let head_in_crop = r.frame_to_crop(head);
        assert!(
            head_in_crop.abs_diff_eq(Vec2::new(0.5, 0.0), 1e-5),
            "{head_in_crop}"
        );
    }

    #[test]
    fn crop_and_frame_maps_invert_each_other() {
        let r = RotatedRect {
            center: Vec2::new(320.0, 240.0),
            size: Vec2::new(200.0, 150.0),
            rotation: 0.7,
        };
        for (u, v) in [(0.0, 0.0), (0.3, 0.9), (1.0, 0.5)] {
            let back = r.frame_to_crop(r.crop_to_frame(u, v));
            assert!(back.abs_diff_eq(Vec2::new(u, v), 1e-5), "{back}");
        }
    }

    #[test]
    fn square_long_takes_the_longer_side() {
        let r = RotatedRect {
            center: Vec2::ZERO,
            size: Vec2::new(10.0, 20.0),
            rotation: 0.0,
        }
        .square_long_scaled(1.25);
        assert_eq!(r.size, Vec2::splat(25.0));
    }

    #[test]
    fn angles_wrap_into_the_half_open_range() {
        assert!((normalize_radians(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-5);
        assert!((normalize_radians(-PI) - PI).abs() < 1e-5);
    }
}
