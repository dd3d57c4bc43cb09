//! A person's appearance for re-identification across cameras and absences: a normalised
//! colour histogram of their pixels (4 levels per channel, 64 bins), compared with the
//! Bhattacharyya coefficient (1 for equal distributions, 0 for disjoint ones).

use image::{GrayImage, RgbImage};

/// Levels per colour channel.
const LEVELS: usize = 4;
/// Histogram bins.
const BINS: usize = LEVELS * LEVELS * LEVELS;

/// A normalised colour histogram of a person's pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Appearance {
    bins: [f32; BINS],
}

impl Appearance {
    /// The histogram of the pixels of `image` where `mask` is at least 128 (same size), inside
    /// `bbox` when given; `None` when no pixel qualifies.
    pub fn from_masked(
        image: &RgbImage,
        mask: &GrayImage,
        bbox: Option<super::BoxPx>,
    ) -> Option<Self> {
        let (w, h) = image.dimensions();
        if mask.dimensions() != (w, h) {
            return None;
        }
        let (x0, y0, x1, y1) = match bbox {
            Some(b) => (
                b.min[0].max(0.0) as u32,
                b.min[1].max(0.0) as u32,
                (b.max[0].ceil().max(0.0) as u32).min(w),
                (b.max[1].ceil().max(0.0) as u32).min(h),
            ),
            None => (0, 0, w, h),
        };
        let mut bins = [0.0f32; BINS];
        let mut count = 0.0f32;
        for y in y0..y1 {
            for x in x0..x1 {
                if mask.get_pixel(x, y)[0] < 128 {
                    continue;
                }
                let p = image.get_pixel(x, y);
                let q = |c: u8| c as usize * LEVELS / 256;
                bins[(q(p[0]) * LEVELS + q(p[1])) * LEVELS + q(p[2])] += 1.0;
                count += 1.0;
            }
        }
        (count > 0.0).then(|| {
            bins.iter_mut().for_each(|b| *b /= count);
            Self { bins }
        })
    }

    /// A histogram from bin weights (normalised here); `None` if they sum to zero or less.
    pub fn from_bins(weights: &[f32; BINS]) -> Option<Self> {
        let sum: f32 = weights.iter().map(|w| w.max(0.0)).sum();
        (sum > 0.0).then(|| Self {
            bins: weights.map(|w| w.max(0.0) / sum),
        })
    }

    /// Bhattacharyya coefficient with `other`: 1 for the same distribution, 0 for disjoint.
    pub fn similarity(&self, other: &Appearance) -> f32 {
        self.bins
            .iter()
            .zip(&other.bins)
            .map(|(a, b)| (a * b).sqrt())
            .sum::<f32>()
            .min(1.0)
    }

    /// This appearance moved towards `newer` by `rate` (0..1), still normalised.
    pub fn blend(&self, newer: &Appearance, rate: f32) -> Appearance {
        let mut bins = [0.0; BINS];
        for (i, b) in bins.iter_mut().enumerate() {
            *b = (1.0 - rate) * self.bins[i] + rate * newer.bins[i];
        }
        Appearance { bins }
    }
}
