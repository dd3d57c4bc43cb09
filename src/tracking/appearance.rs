//! A person's appearance for re-identification: normalised colour histograms (4 levels per
//! channel, 64 bins) of their pixels, compared with the Bhattacharyya coefficient (1 for equal
//! distributions, 0 for disjoint ones). One histogram per horizontal band of their box (head
//! and shoulders, torso, legs; [`Appearance::similarity`]) tells a red shirt over blue
//! trousers from the reverse, within one camera; one over the whole box
//! ([`Appearance::whole_similarity`]) holds better across cameras and absences, where the box
//! is cut differently.

use image::{GrayImage, RgbImage};

/// Levels per colour channel.
const LEVELS: usize = 4;
/// Histogram bins per band.
const BINS: usize = LEVELS * LEVELS * LEVELS;
/// Horizontal bands of the box, top to bottom.
const BANDS: usize = 3;
/// Where each band ends, as a fraction of the box height from its top.
const BAND_ENDS: [f32; BANDS] = [0.3, 0.55, 1.0];
/// Pixels a band needs before its colours count.
const MIN_BAND_PIXELS: f32 = 16.0;

/// Normalised colour histograms of a person's pixels, one per band of their box.
#[derive(Debug, Clone, PartialEq)]
pub struct Appearance {
    /// Per band: the histogram (sums to 1) and how much it counts (0 when the band showed
    /// fewer than `MIN_BAND_PIXELS`, else 1).
    bands: [([f32; BINS], f32); BANDS],
    /// The histogram of all the pixels (sums to 1).
    whole: [f32; BINS],
}

impl Appearance {
    /// The histograms of the pixels of `image` where `mask` is at least 128 (same size), in
    /// the bands of `bbox` (the whole image when `None`); `None` when no band has
    /// `MIN_BAND_PIXELS` (16) of them.
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
        let top = bbox.map_or(0.0, |b| b.min[1]);
        let height = bbox.map_or(h as f32, |b| b.max[1] - b.min[1]).max(1.0);
        let mut counts = [[0.0f32; BINS]; BANDS];
        for y in y0..y1 {
            let along = (y as f32 + 0.5 - top) / height;
            let band = BAND_ENDS
                .iter()
                .position(|&end| along < end)
                .unwrap_or(BANDS - 1);
            for x in x0..x1 {
                if mask.get_pixel(x, y)[0] < 128 {
                    continue;
                }
                let p = image.get_pixel(x, y);
                let q = |c: u8| c as usize * LEVELS / 256;
                counts[band][(q(p[0]) * LEVELS + q(p[1])) * LEVELS + q(p[2])] += 1.0;
            }
        }
        let mut whole = [0.0f32; BINS];
        for bins in &counts {
            for (w, b) in whole.iter_mut().zip(bins) {
                *w += b;
            }
        }
        let total: f32 = whole.iter().sum();
        whole.iter_mut().for_each(|w| *w /= total.max(1.0));
        let bands = counts.map(|bins| {
            let total: f32 = bins.iter().sum();
            if total >= MIN_BAND_PIXELS {
                (bins.map(|b| b / total), 1.0)
            } else {
                ([0.0; BINS], 0.0)
            }
        });
        bands
            .iter()
            .any(|(_, weight)| *weight > 0.0)
            .then_some(Self { bands, whole })
    }

    /// Bhattacharyya coefficient of the whole-box histograms: 1 for the same colours, 0 for
    /// disjoint ones, wherever in the box they are.
    pub fn whole_similarity(&self, other: &Appearance) -> f32 {
        bhattacharyya(&self.whole, &other.whole)
    }

    /// Bhattacharyya coefficient with `other`, averaged over the bands both saw (weighted by
    /// how much each counts): 1 for the same colours, 0 for disjoint ones or no band in
    /// common.
    pub fn similarity(&self, other: &Appearance) -> f32 {
        let (mut sum, mut weight) = (0.0f32, 0.0f32);
        for ((a, wa), (b, wb)) in self.bands.iter().zip(&other.bands) {
            let w = wa * wb;
            if w > 0.0 {
                sum += w * bhattacharyya(a, b);
                weight += w;
            }
        }
        if weight > 0.0 {
            sum / weight
        } else {
            0.0
        }
    }

    /// This appearance moved towards `newer` by `rate` (0..1), still normalised; a band only
    /// one of them saw is taken from that one.
    pub fn blend(&self, newer: &Appearance, rate: f32) -> Appearance {
        let mut bands = self.bands;
        for ((bins, weight), (new_bins, new_weight)) in bands.iter_mut().zip(&newer.bands) {
            if *new_weight <= 0.0 {
                continue;
            }
            if *weight <= 0.0 {
                *bins = *new_bins;
                *weight = *new_weight;
                continue;
            }
            for (b, n) in bins.iter_mut().zip(new_bins) {
                *b = (1.0 - rate) * *b + rate * n;
            }
        }
        let mut whole = self.whole;
        for (w, n) in whole.iter_mut().zip(&newer.whole) {
            *w = (1.0 - rate) * *w + rate * n;
        }
        Appearance { bands, whole }
    }
}

/// Bhattacharyya coefficient of two normalised histograms.
fn bhattacharyya(a: &[f32; BINS], b: &[f32; BINS]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x * y).sqrt())
        .sum::<f32>()
        .min(1.0)
}
