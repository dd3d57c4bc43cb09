//! Several people in one frame, camera-only: MoveNet MultiPose ([`MultiPoseDetector`]) finds
//! the people, then BlazePose's landmark model ([`PoseNetworks::landmarks`]) reads each one from
//! a crop placed the way MediaPipe places it from its own detector (hips' midpoint as the
//! centre, the body's extent as the scale, the hips → shoulders direction up), giving per
//! person 33 landmarks and a full-frame mask.
//!
//! The landmark model segments whatever person fills its crop, so crops of people standing
//! close overlap and so would their masks: where two people's probabilities both reach the
//! mask, the pixel goes to the person with the higher probability, and the masks are disjoint.

use glam::Vec2;
use image::{GrayImage, RgbImage};
use std::f32::consts::FRAC_PI_2;
use std::sync::Arc;

use super::detection::ROI_SCALE;
use super::landmarks::{PoseLandmarks, MIN_PRESENCE};
use super::multipose::{
    Keypoint, MultiPoseDetector, PersonInstance, KEYPOINTS, NATIVE_SIDE, SIDE_MULTIPLE,
};
use super::pose_networks::PoseNetworks;
use super::roi::RotatedRect;
use super::segmentation::ProbabilityMap;
use super::PerceptionError;

/// MoveNet keypoint indices the crop is placed from (COCO order).
const NOSE: usize = 0;
const LEFT_SHOULDER: usize = 5;
const RIGHT_SHOULDER: usize = 6;
const LEFT_HIP: usize = 11;
const RIGHT_HIP: usize = 12;

/// Settings of [`PeopleFinder`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeopleConfig {
    /// MoveNet person score a person needs.
    pub min_score: f32,
    /// MoveNet input `(height, width)` (multiples of 32); `None`: chosen per frame by
    /// [`input_size_for`] from `detector_side`.
    pub input_size: Option<(usize, usize)>,
    /// Short side of MoveNet's input (a multiple of 32; [`NATIVE_SIDE`] is what it was
    /// trained at, larger sides find smaller people at a higher cost).
    pub detector_side: usize,
    /// MoveNet keypoint score from which a keypoint places the crop.
    pub min_keypoint_score: f32,
    /// Landmark-model pose presence a person needs.
    pub min_presence: f32,
    /// Person probability at the mask's edge.
    pub mask_threshold: f32,
    /// Half-width of the mask's soft edge, in probability.
    pub mask_feather: f32,
}

impl Default for PeopleConfig {
    fn default() -> Self {
        Self {
            min_score: 0.2,
            input_size: None,
            detector_side: NATIVE_SIDE,
            min_keypoint_score: 0.3,
            min_presence: MIN_PRESENCE,
            mask_threshold: 0.5,
            mask_feather: 0.1,
        }
    }
}

/// One person found in a frame.
#[derive(Debug, Clone)]
pub struct FoundPerson {
    /// Top-left corner of MoveNet's box, frame pixels.
    pub min: Vec2,
    /// Bottom-right corner of MoveNet's box, frame pixels.
    pub max: Vec2,
    /// MoveNet's person score in [0, 1].
    pub score: f32,
    /// MoveNet's 17 keypoints (COCO order), frame pixels.
    pub keypoints: [Keypoint; KEYPOINTS],
    /// The landmark model's 33 landmarks (image and world), presence and crop.
    pub landmarks: PoseLandmarks,
    /// The person's probability over the whole frame (before the masks were made disjoint).
    pub probability: ProbabilityMap,
    /// The person's feathered mono8 mask over the whole frame, disjoint from the other
    /// people's masks of the same frame (nonzero pixels never overlap).
    pub mask: GrayImage,
}

/// The MoveNet input for a `width × height` frame: the short side `short` (a multiple of 32,
/// [`NATIVE_SIDE`] by default), the long side the multiple of 32 nearest the frame's aspect (at
/// most three times the short side).
pub fn input_size_for(width: u32, height: u32, short: usize) -> (usize, usize) {
    let (w, h) = (width.max(1) as f32, height.max(1) as f32);
    let long = |aspect: f32| {
        let sides = (short as f32 * aspect / SIDE_MULTIPLE as f32).round() as usize;
        (sides * SIDE_MULTIPLE).clamp(short, 3 * short)
    };
    if w >= h {
        (short, long(w / h))
    } else {
        (long(h / w), short)
    }
}

/// The landmark crop for a MoveNet person: MediaPipe's alignment square (centre the hips'
/// midpoint, radius the farthest confident keypoint from it, turned so that hips → shoulders
/// points up), enlarged by its [`ROI_SCALE`]; the box's square when the hips are not
/// confident.
pub fn person_roi(
    min: Vec2,
    max: Vec2,
    keypoints: &[Keypoint; KEYPOINTS],
    min_keypoint_score: f32,
) -> RotatedRect {
    let seen = |k: usize| (keypoints[k].score >= min_keypoint_score).then(|| keypoints[k].position);
    let midpoint = |a: usize, b: usize| match (seen(a), seen(b)) {
        (Some(p), Some(q)) => Some((p + q) / 2.0),
        (p, q) => p.or(q),
    };
    let box_square = RotatedRect {
        center: (min + max) / 2.0,
        size: max - min,
        rotation: 0.0,
    }
    .square_long_scaled(ROI_SCALE);
    let (Some(hips), true) = (
        midpoint(LEFT_HIP, RIGHT_HIP),
        seen(LEFT_HIP).is_some() && seen(RIGHT_HIP).is_some(),
    ) else {
        return box_square;
    };
    let Some(top) = midpoint(LEFT_SHOULDER, RIGHT_SHOULDER).or_else(|| seen(NOSE)) else {
        return box_square;
    };
    let radius = (0..KEYPOINTS)
        .filter_map(seen)
        .map(|p| p.distance(hips))
        .fold(0.0f32, f32::max);
    let up = (top - hips).normalize_or_zero();
    if radius < 1.0 || up == Vec2::ZERO {
        return box_square;
    }
    RotatedRect::from_alignment(hips, hips + up * radius, FRAC_PI_2).square_long_scaled(ROI_SCALE)
}

/// MoveNet MultiPose and BlazePose's landmark model: every person of a frame with landmarks
/// and a mask.
pub struct PeopleFinder {
    networks: Arc<PoseNetworks>,
    config: PeopleConfig,
    detector: Option<MultiPoseDetector>,
    input: Vec<f32>,
}

impl PeopleFinder {
    /// A finder running the landmark model of `networks` (MoveNet is the embedded model,
    /// loaded at the first frame's input size).
    pub fn new(networks: Arc<PoseNetworks>, config: PeopleConfig) -> Self {
        Self {
            networks,
            config,
            detector: None,
            input: Vec::new(),
        }
    }

    /// The settings.
    pub fn config(&self) -> &PeopleConfig {
        &self.config
    }

    /// MoveNet at the input size for a `width × height` frame (reloaded when it changes).
    fn detector(&mut self, width: u32, height: u32) -> Result<&MultiPoseDetector, PerceptionError> {
        let size = self.input_size(width, height);
        if self.detector.as_ref().map(|d| d.input_size()) != Some(size) {
            self.detector = Some(MultiPoseDetector::embedded_sized(size.0, size.1)?);
        }
        Ok(self.detector.as_ref().expect("set above"))
    }

    /// MoveNet's input `(height, width)` for a `width × height` frame.
    pub fn input_size(&self, width: u32, height: u32) -> (usize, usize) {
        self.config
            .input_size
            .unwrap_or_else(|| input_size_for(width, height, self.config.detector_side))
    }

    /// What looks for people in a `width × height` frame, in words (for messages): MoveNet
    /// and its input size.
    pub fn searched_with(&self, width: u32, height: u32) -> String {
        let (h, w) = self.input_size(width, height);
        format!(
            "MoveNet MultiPose at a {w}×{h} input (short side {})",
            self.config.detector_side
        )
    }

    /// MoveNet's people in `image` (score at least `min_score`), best first, before the
    /// landmark model reads any of them.
    pub fn instances(&mut self, image: &RgbImage) -> Result<Vec<PersonInstance>, PerceptionError> {
        let min_score = self.config.min_score;
        self.detector(image.width(), image.height())?
            .detect(image, min_score)
    }

    /// Every person in `image` (MoveNet score at least `min_score` and landmark presence at
    /// least `min_presence`), best MoveNet score first.
    pub fn find(&mut self, image: &RgbImage) -> Result<Vec<FoundPerson>, PerceptionError> {
        let instances = self.instances(image)?;
        let mut found = Vec::new();
        for person in instances {
            let roi = person_roi(
                person.min,
                person.max,
                &person.keypoints,
                self.config.min_keypoint_score,
            );
            let (landmarks, probability) = self.networks.landmarks(image, &roi, &mut self.input)?;
            if landmarks.presence < self.config.min_presence {
                continue;
            }
            let mask = probability.to_mask(self.config.mask_threshold, self.config.mask_feather);
            found.push(FoundPerson {
                min: person.min,
                max: person.max,
                score: person.score,
                keypoints: person.keypoints,
                landmarks,
                probability,
                mask,
            });
        }
        make_disjoint(&mut found);
        Ok(found)
    }
}

/// Where several people's masks are nonzero, keeps only the mask of the person with the
/// highest probability there (the earlier on ties).
pub fn make_disjoint(people: &mut [FoundPerson]) {
    if people.len() < 2 {
        return;
    }
    let (w, h) = people[0].mask.dimensions();
    for y in 0..h {
        for x in 0..w {
            let mut owner: Option<(usize, f32)> = None;
            let mut shared = false;
            for (i, p) in people.iter().enumerate() {
                if p.mask.get_pixel(x, y).0[0] == 0 {
                    continue;
                }
                let prob = p.probability.at(x, y);
                match owner {
                    Some((_, best)) if prob <= best => shared = true,
                    Some(_) => {
                        shared = true;
                        owner = Some((i, prob));
                    }
                    None => owner = Some((i, prob)),
                }
            }
            if let (true, Some((keep, _))) = (shared, owner) {
                for (i, p) in people.iter_mut().enumerate() {
                    if i != keep {
                        p.mask.put_pixel(x, y, image::Luma([0]));
                    }
                }
            }
        }
    }
}

/// Tints the pixels of `image` under `mask` (same size) towards `colour`, a full mask pixel
/// by `alpha` (0..1).
pub fn tint_mask(image: &mut RgbImage, mask: &GrayImage, colour: [u8; 3], alpha: f32) {
    if mask.dimensions() != image.dimensions() {
        return;
    }
    for (p, m) in image.pixels_mut().zip(mask.pixels()) {
        let a = alpha * f32::from(m.0[0]) / 255.0;
        for (channel, tint) in p.0.iter_mut().zip(colour) {
            *channel = (f32::from(*channel) * (1.0 - a) + f32::from(tint) * a).round() as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keypoints(at: &[(usize, Vec2)]) -> [Keypoint; KEYPOINTS] {
        let mut k = [Keypoint {
            position: Vec2::ZERO,
            score: 0.0,
        }; KEYPOINTS];
        for &(i, p) in at {
            k[i] = Keypoint {
                position: p,
                score: 0.9,
            };
        }
        k
    }

    #[test]
    fn input_size_follows_the_frame_aspect() {
        assert_eq!(input_size_for(1920, 1080, NATIVE_SIDE), (256, 448));
        assert_eq!(input_size_for(1080, 1920, NATIVE_SIDE), (448, 256));
        assert_eq!(input_size_for(500, 500, NATIVE_SIDE), (256, 256));
        assert_eq!(input_size_for(10_000, 100, NATIVE_SIDE), (256, 768));
        assert_eq!(input_size_for(640, 480, 384), (384, 512));
    }

    #[test]
    fn an_upright_person_gets_an_unrotated_square_around_the_hips() {
        let k = keypoints(&[
            (LEFT_HIP, Vec2::new(110.0, 200.0)),
            (RIGHT_HIP, Vec2::new(90.0, 200.0)),
            (LEFT_SHOULDER, Vec2::new(115.0, 120.0)),
            (RIGHT_SHOULDER, Vec2::new(85.0, 120.0)),
            (NOSE, Vec2::new(100.0, 90.0)),
            (15, Vec2::new(100.0, 310.0)),
        ]);
        let roi = person_roi(Vec2::ZERO, Vec2::splat(10.0), &k, 0.3);
        assert!(roi.rotation.abs() < 1e-5, "{roi:?}");
        assert!(roi.center.abs_diff_eq(Vec2::new(100.0, 200.0), 1e-4));
        assert!(
            (roi.size.x - 2.0 * 110.0 * ROI_SCALE).abs() < 1e-3,
            "{roi:?}"
        );
    }

    #[test]
    fn without_hips_the_box_places_the_crop() {
        let k = keypoints(&[(NOSE, Vec2::new(50.0, 20.0))]);
        let roi = person_roi(Vec2::new(20.0, 0.0), Vec2::new(80.0, 100.0), &k, 0.3);
        assert!(roi.center.abs_diff_eq(Vec2::new(50.0, 50.0), 1e-5));
        assert_eq!(roi.size, Vec2::splat(100.0 * ROI_SCALE));
        assert_eq!(roi.rotation, 0.0);
    }
}
