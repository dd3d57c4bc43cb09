//! A view the avatar is fitted to: the person's part of a frame (cropped to their mask, scaled
//! down to a bounded size), their mask, the camera that saw them and their pose.

use super::RefineError;
use crate::splat::{Camera, Intrinsics};
use glam::Mat4;
use image::{GrayImage, RgbImage};

/// One view of the person, ready for fitting.
#[derive(Debug, Clone, PartialEq)]
pub struct RefineView {
    /// Name for logs and errors (camera or topic).
    pub name: String,
    /// The camera of the cropped, scaled frame.
    pub camera: Camera,
    /// The frame's colours in `[0, 1]`, `H × W × 3`.
    pub rgb: Vec<f32>,
    /// The person's mask in `[0, 1]`, `H × W`.
    pub mask: Vec<f32>,
    /// Skinning matrices of the person's pose in the camera's world frame.
    pub skinning: Vec<Mat4>,
    /// The view's exposure offset (log luminance) where a key light was fitted to the views'
    /// colours ([`crate::reconstruct::delight::KeyLight::exposure`]); 0 otherwise.
    pub exposure: f32,
}

/// Share of the mask's bounding box added on each side of the crop (room for an avatar that
/// is larger than the person, which the silhouette must then see).
const CROP_MARGIN: f32 = 0.2;

impl RefineView {
    /// The view of `frame` (with the person's `mask`, 255 = person, of the same size) seen by
    /// `camera` (intrinsics in `frame`'s pixels), cropped to the mask's bounding box with a
    /// margin and scaled so that its longer side is at most `max_side` pixels.
    pub fn new(
        name: impl Into<String>,
        frame: &RgbImage,
        mask: &GrayImage,
        camera: Camera,
        skinning: Vec<Mat4>,
        max_side: u32,
    ) -> Result<Self, RefineError> {
        let name = name.into();
        if frame.dimensions() != mask.dimensions() {
            return Err(RefineError::View {
                view: name,
                why: format!(
                    "mask is {}×{}, frame {}×{}",
                    mask.width(),
                    mask.height(),
                    frame.width(),
                    frame.height()
                ),
            });
        }
        let k = camera.intrinsics;
        if (k.width, k.height) != frame.dimensions() {
            return Err(RefineError::View {
                view: name,
                why: format!(
                    "camera is {}×{}, frame {}×{}",
                    k.width,
                    k.height,
                    frame.width(),
                    frame.height()
                ),
            });
        }
        let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
        for (x, y, v) in mask.enumerate_pixels() {
            if v[0] >= 128 {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x + 1);
                y1 = y1.max(y + 1);
            }
        }
        if x1 <= x0 || y1 <= y0 {
            return Err(RefineError::View {
                view: name,
                why: "the mask is empty".into(),
            });
        }
        let margin = CROP_MARGIN * (x1 - x0).max(y1 - y0) as f32;
        let clamp = |v: f32, hi: u32| v.round().clamp(0.0, hi as f32) as u32;
        let (cx0, cy0) = (
            clamp(x0 as f32 - margin, frame.width()),
            clamp(y0 as f32 - margin, frame.height()),
        );
        let (cx1, cy1) = (
            clamp(x1 as f32 + margin, frame.width()),
            clamp(y1 as f32 + margin, frame.height()),
        );
        let (cw, ch) = (cx1 - cx0, cy1 - cy0);
        let scale = (max_side.max(16) as f32 / cw.max(ch) as f32).min(1.0);
        let (w, h) = (
            ((cw as f32 * scale).round() as u32).max(1),
            ((ch as f32 * scale).round() as u32).max(1),
        );
        let (sx, sy) = (w as f32 / cw as f32, h as f32 / ch as f32);
        let rgb_crop = image::imageops::crop_imm(frame, cx0, cy0, cw, ch).to_image();
        let mask_crop = image::imageops::crop_imm(mask, cx0, cy0, cw, ch).to_image();
        let filter = image::imageops::FilterType::Triangle;
        let (rgb_img, mask_img) = if (w, h) == (cw, ch) {
            (rgb_crop, mask_crop)
        } else {
            (
                image::imageops::resize(&rgb_crop, w, h, filter),
                image::imageops::resize(&mask_crop, w, h, filter),
            )
        };
        // Pixel centres sit at integer coordinates: scale about the crop's corner at -0.5.
        let intrinsics = Intrinsics {
            fx: k.fx * sx,
            fy: k.fy * sy,
            cx: (k.cx - cx0 as f32 + 0.5) * sx - 0.5,
            cy: (k.cy - cy0 as f32 + 0.5) * sy - 0.5,
            width: w,
            height: h,
        };
        Ok(Self {
            name,
            camera: Camera {
                intrinsics,
                world_from_camera: camera.world_from_camera,
            },
            rgb: rgb_img.as_raw().iter().map(|v| *v as f32 / 255.0).collect(),
            mask: mask_img
                .as_raw()
                .iter()
                .map(|v| *v as f32 / 255.0)
                .collect(),
            skinning,
            exposure: 0.0,
        })
    }

    /// Pixels in the view.
    pub fn pixels(&self) -> usize {
        self.mask.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Affine3A, Vec3};

    /// A world point lands on the same place of the person in the crop as in the frame.
    #[test]
    fn the_crop_keeps_the_camera_on_the_person() {
        let (w, h) = (640, 480);
        let camera = Camera::look_at(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            Intrinsics::from_fov_y(w, h, 0.8),
        );
        let mut mask = GrayImage::new(w, h);
        for y in 100..400 {
            for x in 300..360 {
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        let view =
            RefineView::new("cam0", &RgbImage::new(w, h), &mask, camera, Vec::new(), 128).unwrap();
        assert!(view.camera.intrinsics.height <= 128 && view.camera.intrinsics.width <= 128);
        let p = Vec3::new(0.05, 1.2, 0.1);
        let full = camera.project_camera_point(camera.camera_from_world().transform_point3(p));
        let crop = view
            .camera
            .project_camera_point(view.camera.camera_from_world().transform_point3(p));
        // Back to the frame: the crop starts 20 % of 300 px above and left of the mask's box.
        let scale = 128.0 / 420.0;
        let back = (crop + 0.5) / scale - 0.5 + glam::Vec2::new(300.0 - 60.0, 100.0 - 60.0);
        assert!(back.distance(full) < 0.5, "{back} vs {full}");
        assert!(view.mask.iter().any(|m| *m > 0.99));
        let _ = Affine3A::IDENTITY;
    }

    #[test]
    fn an_empty_mask_or_a_mismatched_camera_is_named() {
        let camera = Camera::look_at(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            Intrinsics::from_fov_y(64, 48, 0.8),
        );
        let err = RefineView::new(
            "cam7",
            &RgbImage::new(64, 48),
            &GrayImage::new(64, 48),
            camera,
            Vec::new(),
            64,
        )
        .unwrap_err();
        assert!(err.to_string().contains("cam7") && err.to_string().contains("empty"));
        let err = RefineView::new(
            "cam8",
            &RgbImage::new(32, 48),
            &GrayImage::new(32, 48),
            camera,
            Vec::new(),
            64,
        )
        .unwrap_err();
        assert!(err.to_string().contains("cam8"), "{err}");
    }
}
