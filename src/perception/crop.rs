//! Network inputs cut out of a frame: a rotated rectangle of an RGB image resampled into an
//! `H × W × 3` f32 tensor (NHWC, batch 1), as MediaPipe's `ImageToTensorCalculator` does on
//! the CPU: bilinear taps, black outside the frame, values mapped from [0, 255] to a range.

use super::roi::RotatedRect;
use glam::Vec2;
use image::RgbImage;

/// The value range a network expects for pixel values 0..=255.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValueRange {
    /// Value of a black pixel (and of everything outside the frame).
    pub min: f32,
    /// Value of a white pixel.
    pub max: f32,
}

impl ValueRange {
    /// [0, 1] (the landmark models).
    pub const UNIT: Self = Self { min: 0.0, max: 1.0 };
    /// [−1, 1] (the person detector).
    pub const SIGNED: Self = Self {
        min: -1.0,
        max: 1.0,
    };
}

/// Resamples `rect` of `image` into `out` (`height × width × 3`, row-major NHWC).
///
/// Output pixel `(col, row)` samples the frame at the crop point
/// `(col / width, row / height)` (OpenCV's warp maps the rectangle's corners onto the output's
/// pixel corners 0 and `width`), with bilinear interpolation; taps outside the frame are black.
pub fn crop_into(
    image: &RgbImage,
    rect: &RotatedRect,
    width: usize,
    height: usize,
    range: ValueRange,
    out: &mut Vec<f32>,
) {
    out.clear();
    out.resize(width * height * 3, 0.0);
    let (iw, ih) = (image.width() as i64, image.height() as i64);
    let raw = image.as_raw();
    let scale = (range.max - range.min) / 255.0;
    let origin = rect.crop_to_frame(0.0, 0.0);
    let step_u = rect.crop_to_frame(1.0 / width as f32, 0.0) - origin;
    let step_v = rect.crop_to_frame(0.0, 1.0 / height as f32) - origin;
    for row in 0..height {
        let row_start = origin + step_v * row as f32;
        for col in 0..width {
            let p: Vec2 = row_start + step_u * col as f32;
            let (x0, y0) = (p.x.floor(), p.y.floor());
            let (fx, fy) = (p.x - x0, p.y - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let mut rgb = [0.0f32; 3];
            for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
                let y = y0 + dy;
                if wy == 0.0 || y < 0 || y >= ih {
                    continue;
                }
                for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
                    let x = x0 + dx;
                    if wx == 0.0 || x < 0 || x >= iw {
                        continue;
                    }
                    let at = ((y * iw + x) * 3) as usize;
                    let w = wx * wy;
                    for c in 0..3 {
                        rgb[c] += w * f32::from(raw[at + c]);
                    }
                }
            }
            let at = (row * width + col) * 3;
            for c in 0..3 {
                out[at + c] = range.min + rgb[c] * scale;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    #[test]
    fn an_unrotated_crop_of_the_whole_frame_copies_its_pixels() {
        let mut img = RgbImage::new(4, 4);
        for (x, y, p) in img.enumerate_pixels_mut() {
            *p = Rgb([(x * 60) as u8, (y * 60) as u8, 255]);
        }
        let rect = RotatedRect {
            center: glam::Vec2::new(2.0, 2.0),
            size: glam::Vec2::new(4.0, 4.0),
            rotation: 0.0,
        };
        let mut out = Vec::new();
        crop_into(&img, &rect, 4, 4, ValueRange::UNIT, &mut out);
        for y in 0..4 {
            for x in 0..4 {
                let at = (y * 4 + x) * 3;
                assert!((out[at] - (x * 60) as f32 / 255.0).abs() < 1e-6);
                assert!((out[at + 1] - (y * 60) as f32 / 255.0).abs() < 1e-6);
                assert!((out[at + 2] - 1.0).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn outside_the_frame_is_black_in_the_target_range() {
        let img = RgbImage::from_pixel(2, 2, Rgb([255, 255, 255]));
        let rect = RotatedRect {
            center: glam::Vec2::new(100.0, 100.0),
            size: glam::Vec2::new(4.0, 4.0),
            rotation: 0.3,
        };
        let mut out = Vec::new();
        crop_into(&img, &rect, 3, 3, ValueRange::SIGNED, &mut out);
        assert!(out.iter().all(|v| *v == -1.0));
    }

    #[test]
    fn a_quarter_turn_rotates_the_content() {
        // A bright pixel right of the centre appears above the centre in a crop turned a
        // quarter clockwise (the crop's up is the frame's right).
        let mut img = RgbImage::new(9, 9);
        img.put_pixel(8, 4, Rgb([255, 0, 0]));
        let rect = RotatedRect {
            center: glam::Vec2::new(4.0, 4.0),
            size: glam::Vec2::new(9.0, 9.0),
            rotation: std::f32::consts::FRAC_PI_2,
        };
        let mut out = Vec::new();
        crop_into(&img, &rect, 9, 9, ValueRange::UNIT, &mut out);
        let brightest = (0..81)
            .max_by(|a, b| out[a * 3].total_cmp(&out[b * 3]))
            .unwrap();
        let (row, col) = (brightest / 9, brightest % 9);
        assert_eq!(col, 4, "row {row} col {col}");
        assert!(row <= 1, "row {row}");
    }
}
