//! What the followed person looks like, to notice when the crop the landmarks place has slid
//! onto someone else (two people crossing in front of the camera): the colours of their
//! segmented pixels above and below the hips, as two normalised histograms (4 levels per
//! channel), compared part by part with the Bhattacharyya coefficient.

use super::landmark::{LandmarkId, BODY_LANDMARKS};
use super::landmarks::PoseLandmarks;
use super::segmentation::ProbabilityMap;
use glam::Vec2;
use image::RgbImage;

/// Levels per colour channel.
const LEVELS: usize = 4;
/// Bins of one part's histogram.
const BINS: usize = LEVELS * LEVELS * LEVELS;
/// Person probability from which a pixel counts as theirs.
const OWN_PIXEL: f32 = 0.5;
/// Pixels a part needs before its colours count.
const MIN_PART_PIXELS: u32 = 12;

/// A person's colours above the hips (torso, arms, head) and below them (legs).
#[derive(Debug, Clone, PartialEq)]
pub struct Looks {
    /// Per part: the histogram (sums to 1), or `None` when the part showed too few pixels.
    parts: [Option<[f32; BINS]>; 2],
}

impl Looks {
    /// The colours of `image` where `probability` reaches [`OWN_PIXEL`], split by the line
    /// through the hips square to the hips → shoulders direction; `None` when neither part
    /// shows [`MIN_PART_PIXELS`].
    pub fn of(
        image: &RgbImage,
        probability: &ProbabilityMap,
        pose: &PoseLandmarks,
    ) -> Option<Self> {
        let at = |a: LandmarkId, b: LandmarkId| {
            (pose.image[a.index()].position.truncate() + pose.image[b.index()].position.truncate())
                / 2.0
        };
        debug_assert_eq!(pose.image.len(), BODY_LANDMARKS);
        let hips = at(LandmarkId::LeftHip, LandmarkId::RightHip);
        let up = at(LandmarkId::LeftShoulder, LandmarkId::RightShoulder) - hips;
        let mut counts = [[0u32; BINS]; 2];
        let (width, height) = image.dimensions();
        for (x, y) in probability.pixels_at_least(OWN_PIXEL) {
            if x >= width || y >= height {
                continue;
            }
            let part = usize::from((Vec2::new(x as f32, y as f32) - hips).dot(up) < 0.0);
            let [r, g, b] = image
                .get_pixel(x, y)
                .0
                .map(|c| usize::from(c) * LEVELS / 256);
            counts[part][(r * LEVELS + g) * LEVELS + b] += 1;
        }
        let parts = counts.map(|bins| {
            let total: u32 = bins.iter().sum();
            (total >= MIN_PART_PIXELS).then(|| bins.map(|n| n as f32 / total as f32))
        });
        parts.iter().any(Option::is_some).then_some(Self { parts })
    }

    /// How alike two looks are: the Bhattacharyya coefficient averaged over the parts both
    /// show (1 the same colours, 0 none in common, or no part in common).
    pub fn likeness(&self, other: &Looks) -> f32 {
        let shared: Vec<f32> = self
            .parts
            .iter()
            .zip(&other.parts)
            .filter_map(|(a, b)| Some(coefficient(a.as_ref()?, b.as_ref()?)))
            .collect();
        if shared.is_empty() {
            0.0
        } else {
            shared.iter().sum::<f32>() / shared.len() as f32
        }
    }

    /// Moves these looks towards `newer` by `rate` (0..1); a part only `newer` shows is taken
    /// from it.
    pub fn learn(&mut self, newer: &Looks, rate: f32) {
        for (mine, theirs) in self.parts.iter_mut().zip(&newer.parts) {
            match (mine.as_mut(), theirs) {
                (Some(m), Some(t)) => m.iter_mut().zip(t).for_each(|(a, b)| *a += rate * (b - *a)),
                (None, Some(t)) => *mine = Some(*t),
                _ => {}
            }
        }
    }
}

/// Bhattacharyya coefficient of two normalised histograms.
fn coefficient(a: &[f32; BINS], b: &[f32; BINS]) -> f32 {
    a.iter().zip(b).map(|(p, q)| (p * q).sqrt()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::perception::landmark::Landmark;
    use crate::perception::roi::RotatedRect;
    use glam::Vec3;

    /// A standing person in a 40 × 100 frame: shoulders at y 30, hips at y 60, everything
    /// person; `top` above the hips, `bottom` below.
    fn person(top: [u8; 3], bottom: [u8; 3]) -> (RgbImage, ProbabilityMap, PoseLandmarks) {
        let image = RgbImage::from_fn(40, 100, |_, y| {
            image::Rgb(if y < 60 { top } else { bottom })
        });
        let probability = ProbabilityMap::from_values(40, 100, vec![1.0; 4000]).unwrap();
        let mut l = [Landmark {
            position: Vec3::new(20.0, 50.0, 0.0),
            visibility: 1.0,
            presence: 1.0,
        }; BODY_LANDMARKS];
        for (id, y) in [
            (LandmarkId::LeftShoulder, 30.0),
            (LandmarkId::RightShoulder, 30.0),
            (LandmarkId::LeftHip, 60.0),
            (LandmarkId::RightHip, 60.0),
        ] {
            l[id.index()].position = Vec3::new(20.0, y, 0.0);
        }
        let roi = RotatedRect {
            center: Vec2::new(20.0, 50.0),
            size: Vec2::splat(100.0),
            rotation: 0.0,
        };
        let pose = PoseLandmarks {
            image: l,
            world: l,
            presence: 1.0,
            roi,
            next_roi: roi,
        };
        (image, probability, pose)
    }

    fn looks(top: [u8; 3], bottom: [u8; 3]) -> Looks {
        let (image, p, pose) = person(top, bottom);
        Looks::of(&image, &p, &pose).unwrap()
    }

    #[test]
    fn the_same_colours_are_alike_and_a_red_shirt_over_blue_trousers_is_not_the_reverse() {
        let (red, blue) = ([220, 30, 30], [30, 30, 220]);
        let a = looks(red, blue);
        assert!((a.likeness(&a) - 1.0).abs() < 1e-5);
        assert!(a.likeness(&looks(blue, red)) < 0.01);
        // The same shirt over other trousers: half alike.
        let half = a.likeness(&looks(red, [30, 200, 30]));
        assert!((half - 0.5).abs() < 1e-5, "{half}");
    }

    #[test]
    fn learning_moves_towards_the_newer_looks() {
        let (red, blue, green) = ([220, 30, 30], [30, 30, 220], [30, 200, 30]);
        let mut a = looks(red, blue);
        let b = looks(red, green);
        let before = a.likeness(&b);
        a.learn(&b, 0.5);
        assert!(a.likeness(&b) > before);
        a.learn(&b, 1.0);
        assert!((a.likeness(&b) - 1.0).abs() < 1e-5);
    }

    #[test]
    fn nobody_segmented_has_no_looks() {
        let (image, _, pose) = person([1, 2, 3], [4, 5, 6]);
        let empty = ProbabilityMap::from_values(40, 100, vec![0.0; 4000]).unwrap();
        assert_eq!(Looks::of(&image, &empty, &pose), None);
    }
}
