//! The landmark model's person segmentation taken back into the frame: sigmoid of the crop's
//! logits, warped into frame pixels (MediaPipe's inverse `WarpAffineCalculator`, black outside
//! the crop), smoothed over time where the mask is uncertain
//! (`SegmentationSmoothingCalculator`), and turned into a thresholded, feathered mono8 mask.

use super::landmarks::LANDMARK_INPUT;
use super::roi::RotatedRect;
use glam::Vec2;
use image::GrayImage;

/// A person-probability map over a whole frame, stored only over the region the landmark crop
/// covered (zero elsewhere), so a 1080p frame costs a fraction of its pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbabilityMap {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Stored region: columns `x0..x1`, rows `y0..y1`.
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    /// Probabilities in [0, 1] over the region, row-major.
    values: Vec<f32>,
}

impl ProbabilityMap {
    /// Warps the crop's segmentation logits (`256 × 256`, the crop `roi` of a
    /// `width × height` frame) into the frame; pixels outside the crop are 0.
    pub fn from_crop_logits(logits: &[f32], roi: &RotatedRect, width: u32, height: u32) -> Self {
        let side = LANDMARK_INPUT;
        let probs: Vec<f32> = logits.iter().map(|&x| sigmoid(x)).collect();
        let (min, max) = roi.bounds();
        let x0 = (min.x.floor().max(0.0) as u32).min(width);
        let y0 = (min.y.floor().max(0.0) as u32).min(height);
        let x1 = (max.x.ceil().max(0.0) as u32).clamp(x0, width);
        let y1 = (max.y.ceil().max(0.0) as u32).clamp(y0, height);
        let mut values = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
        for y in y0..y1 {
            for x in x0..x1 {
                let uv = roi.frame_to_crop(Vec2::new(x as f32, y as f32)) * side as f32;
                values.push(bilinear(&probs, side, uv));
            }
        }
        Self {
            width,
            height,
            x0,
            y0,
            x1,
            y1,
            values,
        }
    }

    /// A map of `width × height` from row-major probabilities over the whole frame.
    pub fn from_values(width: u32, height: u32, values: Vec<f32>) -> Option<Self> {
        (values.len() == width as usize * height as usize).then_some(Self {
            width,
            height,
            x0: 0,
            y0: 0,
            x1: width,
            y1: height,
            values,
        })
    }

    /// The probability at pixel `(x, y)` (0 outside the frame or the stored region).
    pub fn at(&self, x: u32, y: u32) -> f32 {
        if x < self.x0 || x >= self.x1 || y < self.y0 || y >= self.y1 {
            return 0.0;
        }
        self.values[((y - self.y0) * (self.x1 - self.x0) + (x - self.x0)) as usize]
    }

    /// The stored region `(x0, y0, x1, y1)`: columns `x0..x1`, rows `y0..y1` (0 outside).
    pub fn region(&self) -> (u32, u32, u32, u32) {
        (self.x0, self.y0, self.x1, self.y1)
    }

    /// Blends towards `previous` where this map is uncertain (near 0.5): MediaPipe's
    /// polynomial for the binary entropy, weighted by `ratio` (0.7 in its pose graph). Outside
    /// this map's region it is a certain 0 and stays so. Maps of another size are ignored.
    pub fn smooth_with(&mut self, previous: &ProbabilityMap, ratio: f32) {
        if previous.width != self.width || previous.height != self.height {
            return;
        }
        const C: [f32; 5] = [5.68842, -0.748699, -57.8051, 291.309, -624.717];
        let row = (self.x1 - self.x0) as usize;
        for (i, v) in self.values.iter_mut().enumerate() {
            let (x, y) = (self.x0 + (i % row) as u32, self.y0 + (i / row) as u32);
            let p = previous.at(x, y);
            let t = *v - 0.5;
            let x = t * t;
            let certainty = (x * (C[0] + x * (C[1] + x * (C[2] + x * (C[3] + x * C[4]))))).min(1.0);
            *v += (p - *v) * (1.0 - certainty) * ratio;
        }
    }

    /// A mono8 mask over the whole frame: 255 where the probability is at least
    /// `threshold + feather`, 0 at or below `threshold − feather`, a linear ramp between (a
    /// feathered threshold).
    pub fn to_mask(&self, threshold: f32, feather: f32) -> GrayImage {
        let lo = threshold - feather;
        let span = (2.0 * feather).max(f32::EPSILON);
        let level = |p: f32| (((p - lo) / span).clamp(0.0, 1.0) * 255.0).round() as u8;
        let mut mask = GrayImage::from_pixel(self.width, self.height, image::Luma([level(0.0)]));
        let row = (self.x1 - self.x0) as usize;
        if row > 0 {
            for (i, chunk) in self.values.chunks(row).enumerate() {
                let y = self.y0 + i as u32;
                for (j, &p) in chunk.iter().enumerate() {
                    mask.put_pixel(self.x0 + j as u32, y, image::Luma([level(p)]));
                }
            }
        }
        mask
    }
}

/// Bilinear sample of a `side × side` map at pixel coordinates `p` (centres at integers);
/// taps outside are 0.
fn bilinear(map: &[f32], side: usize, p: Vec2) -> f32 {
    let (x0, y0) = (p.x.floor(), p.y.floor());
    let (fx, fy) = (p.x - x0, p.y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let s = side as i64;
    let mut v = 0.0;
    for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
        for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
            let (x, y) = (x0 + dx, y0 + dy);
            if (0..s).contains(&x) && (0..s).contains(&y) {
                v += wx * wy * map[(y * s + x) as usize];
            }
        }
    }
    v
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square_logits(inside: impl Fn(usize, usize) -> bool) -> Vec<f32> {
        let s = LANDMARK_INPUT;
        (0..s * s)
            .map(|i| if inside(i % s, i / s) { 20.0 } else { -20.0 })
            .collect()
    }

    #[test]
    fn the_crop_mask_lands_where_the_crop_was_taken() {
        // Crop: the 128×128 square centred at (100, 60) of a 200×120 frame, unrotated; the
        // person fills the crop's left half.
        let roi = RotatedRect {
            center: Vec2::new(100.0, 60.0),
            size: Vec2::splat(128.0),
            rotation: 0.0,
        };
        let logits = square_logits(|x, _| x < 128);
        let map = ProbabilityMap::from_crop_logits(&logits, &roi, 200, 120);
        let at = |x: u32, y: u32| map.at(x, y);
        assert!(at(60, 60) > 0.99, "left half of the crop");
        assert!(at(140, 60) < 0.01, "right half of the crop");
        assert!(at(10, 60) < 0.01, "outside the crop");
        let mask = map.to_mask(0.5, 0.1);
        assert_eq!(mask.get_pixel(60, 60).0[0], 255);
        assert_eq!(mask.get_pixel(140, 60).0[0], 0);
    }

    #[test]
    fn smoothing_keeps_confident_pixels_and_steadies_uncertain_ones() {
        let mut current = ProbabilityMap::from_values(2, 1, vec![1.0, 0.5]).unwrap();
        let previous = ProbabilityMap::from_values(2, 1, vec![0.0, 1.0]).unwrap();
        current.smooth_with(&previous, 0.7);
        assert!((current.at(0, 0) - 1.0).abs() < 1e-3);
        assert!((current.at(1, 0) - 0.85).abs() < 1e-6);
    }

    #[test]
    fn feathering_ramps_between_the_bounds() {
        let map = ProbabilityMap::from_values(3, 1, vec![0.4, 0.55, 0.6]).unwrap();
        let m = map.to_mask(0.5, 0.1);
        assert_eq!(m.as_raw(), &vec![0, 191, 255]);
    }
}
