//! What the followed person looks like, to notice when the crop the landmarks place has slid
//! onto someone else (two people crossing in front of the camera): the colours of their
//! segmented pixels near their own visible bones (so that little of a person standing behind
//! or in front counts), above the hips (torso, arms) and below (legs), as two normalised
//! histograms (6 levels per channel), compared part by part with the Bhattacharyya
//! coefficient. On synthetic crowd scenes (true person masks, 640 × 480, people 1/8 to 1/2 of
//! the frame high) 6 levels kept a person's likeness to themself a frame later at 0.89 and
//! above (5th percentile) and to anyone else at 0.69 and below; 4 levels let others reach
//! 0.88.

use super::landmark::LandmarkId;
use super::landmarks::PoseLandmarks;
use super::segmentation::ProbabilityMap;
use glam::Vec2;
use image::RgbImage;

/// Levels per colour channel.
const LEVELS: usize = 6;
/// Bins of one part's histogram.
const BINS: usize = LEVELS * LEVELS * LEVELS;
/// Person probability from which a pixel counts as theirs.
const OWN_PIXEL: f32 = 0.5;
/// Pixels a part needs before its colours count.
const MIN_PART_PIXELS: u32 = 12;
/// Visibility both ends of a bone need for its pixels to count.
const MIN_VISIBILITY: f32 = 0.5;
/// How far from a bone a pixel may lie, as a share of the torso's length (shoulders' midpoint
/// to hips' midpoint).
const BONE_REACH: f32 = 0.2;
/// Pixels looked at per frame at most (larger people are sampled on a coarser grid).
const MAX_PIXELS: usize = 6000;

/// Bones above the hips.
const UPPER: [(LandmarkId, LandmarkId); 9] = [
    (LandmarkId::LeftShoulder, LandmarkId::RightShoulder),
    (LandmarkId::LeftShoulder, LandmarkId::LeftHip),
    (LandmarkId::RightShoulder, LandmarkId::RightHip),
    (LandmarkId::LeftShoulder, LandmarkId::RightHip),
    (LandmarkId::RightShoulder, LandmarkId::LeftHip),
    (LandmarkId::LeftShoulder, LandmarkId::LeftElbow),
    (LandmarkId::RightShoulder, LandmarkId::RightElbow),
    (LandmarkId::LeftElbow, LandmarkId::LeftWrist),
    (LandmarkId::RightElbow, LandmarkId::RightWrist),
];
/// Bones below the hips.
const LOWER: [(LandmarkId, LandmarkId); 4] = [
    (LandmarkId::LeftHip, LandmarkId::LeftKnee),
    (LandmarkId::RightHip, LandmarkId::RightKnee),
    (LandmarkId::LeftKnee, LandmarkId::LeftAnkle),
    (LandmarkId::RightKnee, LandmarkId::RightAnkle),
];

/// A person's colours above the hips (torso, arms) and below them (legs).
#[derive(Debug, Clone, PartialEq)]
pub struct Looks {
    /// Per part: the histogram (sums to 1), or `None` when the part showed too few pixels.
    parts: [Option<Vec<f32>>; 2],
}

impl Looks {
    /// The colours of `image` where `probability` reaches [`OWN_PIXEL`] within
    /// [`BONE_REACH`] of one of the person's visible bones; `None` when neither part shows
    /// [`MIN_PART_PIXELS`].
    pub fn of(
        image: &RgbImage,
        probability: &ProbabilityMap,
        pose: &PoseLandmarks,
    ) -> Option<Self> {
        let point = |id: LandmarkId| pose.image[id.index()].position.truncate();
        let seen = |id: LandmarkId| pose.image[id.index()].visibility >= MIN_VISIBILITY;
        let mid = |a, b| (point(a) + point(b)) / 2.0;
        let torso = mid(LandmarkId::LeftShoulder, LandmarkId::RightShoulder)
            .distance(mid(LandmarkId::LeftHip, LandmarkId::RightHip));
        let reach = (BONE_REACH * torso).max(1.5);
        let bones: Vec<(Vec2, Vec2, usize)> = [(&UPPER[..], 0), (&LOWER[..], 1)]
            .iter()
            .flat_map(|(bones, part)| bones.iter().map(move |b| (*b, *part)))
            .filter(|((a, b), _)| seen(*a) && seen(*b))
            .map(|((a, b), part)| (point(a), point(b), part))
            .collect();
        if bones.is_empty() {
            return None;
        }
        let (x0, y0, x1, y1) = probability.region();
        let area = (x1 - x0) as usize * (y1 - y0) as usize;
        let step = ((area as f32 / MAX_PIXELS as f32).sqrt().ceil() as u32).max(1);
        let (width, height) = image.dimensions();
        let mut counts = vec![vec![0u32; BINS]; 2];
        for y in (y0..y1.min(height)).step_by(step as usize) {
            for x in (x0..x1.min(width)).step_by(step as usize) {
                if probability.at(x, y) < OWN_PIXEL {
                    continue;
                }
                let p = Vec2::new(x as f32, y as f32);
                let nearest = bones
                    .iter()
                    .map(|(a, b, part)| (distance_to_segment(p, *a, *b), *part))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let Some((_, part)) = nearest.filter(|(d, _)| *d <= reach) else {
                    continue;
                };
                let [r, g, b] = image
                    .get_pixel(x, y)
                    .0
                    .map(|c| usize::from(c) * LEVELS / 256);
                counts[part][(r * LEVELS + g) * LEVELS + b] += 1;
            }
        }
        let parts = [0, 1].map(|part| {
            let bins = &counts[part];
            let total: u32 = bins.iter().sum();
            (total >= MIN_PART_PIXELS)
                .then(|| bins.iter().map(|&n| n as f32 / total as f32).collect())
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
                (None, Some(t)) => *mine = Some(t.clone()),
                _ => {}
            }
        }
    }
}

/// Distance from `p` to the segment `a`–`b`.
fn distance_to_segment(p: Vec2, a: Vec2, b: Vec2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(f32::EPSILON)).clamp(0.0, 1.0);
    p.distance(a + t * ab)
}

/// Bhattacharyya coefficient of two normalised histograms.
fn coefficient(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(p, q)| (p * q).sqrt()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::perception::landmark::{Landmark, BODY_LANDMARKS};
    use crate::perception::roi::RotatedRect;
    use glam::Vec3;

    /// A standing person in a 40 × 100 frame: shoulders at y 30, hips at y 60, ankles at y
    /// 95, everything person; `top` above the hips, `bottom` below.
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
        for (id, x, y) in [
            (LandmarkId::LeftShoulder, 26.0, 30.0),
            (LandmarkId::RightShoulder, 14.0, 30.0),
            (LandmarkId::LeftElbow, 28.0, 45.0),
            (LandmarkId::RightElbow, 12.0, 45.0),
            (LandmarkId::LeftWrist, 28.0, 57.0),
            (LandmarkId::RightWrist, 12.0, 57.0),
            (LandmarkId::LeftHip, 24.0, 60.0),
            (LandmarkId::RightHip, 16.0, 60.0),
            (LandmarkId::LeftKnee, 24.0, 78.0),
            (LandmarkId::RightKnee, 16.0, 78.0),
            (LandmarkId::LeftAnkle, 24.0, 95.0),
            (LandmarkId::RightAnkle, 16.0, 95.0),
        ] {
            l[id.index()].position = Vec3::new(x, y, 0.0);
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
        // Pixels near the hips lie near upper and lower bones alike, so the parts share a
        // little of both colours.
        let reversed = a.likeness(&looks(blue, red));
        assert!(reversed < 0.3, "{reversed}");
        // The same shirt over other trousers: about half alike.
        let half = a.likeness(&looks(red, [30, 200, 30]));
        assert!((half - 0.5).abs() < 0.1, "{half}");
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
    fn a_person_standing_behind_beside_the_bones_does_not_count() {
        // The followed person's colours near their bones; someone else's far from them.
        let (mut image, p, pose) = person([220, 30, 30], [30, 30, 220]);
        let alone = Looks::of(&image, &p, &pose).unwrap();
        for y in 0..100 {
            for x in 0..6 {
                image.put_pixel(x, y, image::Rgb([250, 250, 0]));
                image.put_pixel(39 - x, y, image::Rgb([250, 250, 0]));
            }
        }
        let beside = Looks::of(&image, &p, &pose).unwrap();
        assert!(
            alone.likeness(&beside) > 0.99,
            "{}",
            alone.likeness(&beside)
        );
    }

    #[test]
    fn nobody_segmented_has_no_looks() {
        let (image, _, pose) = person([1, 2, 3], [4, 5, 6]);
        let empty = ProbabilityMap::from_values(40, 100, vec![0.0; 4000]).unwrap();
        assert_eq!(Looks::of(&image, &empty, &pose), None);
    }
}
